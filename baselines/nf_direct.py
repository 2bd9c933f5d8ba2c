"""The navigation function alone (paper IV-B): every aircraft aims at its destination."""

from __future__ import annotations

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView


class NFDirect:
    """The NF alone: each aircraft's waypoint is its final destination, with the
    scenario's arrival heading as θ_d, for the whole flight. No constraint is enforced:
    this is the baseline whose envelope violations and wind failures the MPC fixes."""

    name = "nf"

    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Nothing to prepare: the policy has no state."""

    def act(self, view: WorldView) -> np.ndarray:
        """The destinations (N, 2), nm."""
        return view.destinations.copy()
