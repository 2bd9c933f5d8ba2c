"""Reference policies: the navigation function alone and the paper's MCMC-MPC."""

from baselines.nf_direct import NFDirect

__all__ = ["NFDirect"]
