"""The policy interface: what the episode runner and the evaluator need of a policy.

The NF-only baseline, the MCMC-MPC and trained agents all implement it, so they are
evaluated alike. A policy is called every decision period (T = 5 min) with what it
may observe — the aircraft's states, not the wind — and returns one waypoint per
aircraft.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView


@runtime_checkable
class Policy(Protocol):
    """A waypoint policy.

    Attributes:
        name: a short label used in reports.
    """

    name: str

    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Prepare for a new episode of ``scenario`` flown with ``config``."""

    def act(self, view: WorldView) -> np.ndarray:
        """Waypoints (N, 2), nm, for every aircraft (those no longer flying are ignored)."""
