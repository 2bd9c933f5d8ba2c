"""Reference policies: the navigation function alone and the paper's MCMC-MPC."""

from baselines.mcmc_mpc import MCMCMPC, MPCSettings
from baselines.nf_direct import NFDirect

__all__ = ["MCMCMPC", "MPCSettings", "NFDirect"]
