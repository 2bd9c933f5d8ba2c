"""Reference policies: the navigation function alone (aimed at the destination, or one leg
at a time along the line to it) and the paper's MCMC-MPC."""

from baselines.mcmc_mpc import MCMCMPC, MPCSettings
from baselines.nf_direct import NFDirect
from baselines.nf_leg import NFLeg

__all__ = ["MCMCMPC", "MPCSettings", "NFDirect", "NFLeg"]
