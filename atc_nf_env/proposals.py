"""Random waypoint proposals around an aircraft: the distribution the MCMC-MPC draws its
candidates from and the safety filter its sampled alternatives.

A waypoint lies at a distance ~ N(``distance_mean_nm``, σ) from its aircraft, in a
direction drawn from a mixture per aircraft: uniform in ±``angle_range_rad`` around the
line to its destination (the paper's proposal, section IV-C), or, with probability
``heading_share``, uniform in ±``recovery_angle_rad`` around its heading (which lets an
aircraft that has missed its destination turn back). The core keeps the distribution so
that the safety filter needs no import of the controller built on the core.

Units: nautical miles, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class ProposalShape(Protocol):
    """What ``homing_mixture_draws`` reads of its settings (``WaypointProposal``, or the
    MCMC-MPC's ``MPCSettings``, which has the same fields)."""

    distance_mean_nm: float
    angle_range_rad: float
    recovery_angle_rad: float


@dataclass(frozen=True)
class WaypointProposal:
    """The proposal's parameters; the defaults are the MCMC-MPC's.

    Attributes:
        distance_mean_nm, distance_std_nm: a waypoint's distance from its aircraft, nm.
        angle_range_rad: the paper's angle is uniform in ±this around the line to the
            destination, rad.
        recovery_fraction: the probability that an aircraft's angle is drawn around its
            heading instead.
        recovery_angle_rad: that angle is uniform in ±this around the heading, rad.
    """

    distance_mean_nm: float = 100.0
    distance_std_nm: float = 10.0
    angle_range_rad: float = math.pi / 2
    recovery_fraction: float = 0.25
    recovery_angle_rad: float = math.pi / 3

    def __post_init__(self) -> None:
        for name in ("distance_mean_nm", "distance_std_nm", "angle_range_rad"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a finite number > 0")
        if isinstance(self.recovery_fraction, bool) or not (
            isinstance(self.recovery_fraction, (int, float)) and 0.0 <= self.recovery_fraction <= 1.0
        ):
            raise ValueError(f"recovery_fraction = {self.recovery_fraction!r}: must be a number in [0, 1]")
        if isinstance(self.recovery_angle_rad, bool) or not (
            isinstance(self.recovery_angle_rad, (int, float)) and 0.0 < self.recovery_angle_rad < math.pi / 2
        ):
            raise ValueError(f"recovery_angle_rad = {self.recovery_angle_rad!r}: must be a number in (0, π/2)")


#: The field names of ``WaypointProposal``.
PROPOSAL_FIELDS = tuple(WaypointProposal.__dataclass_fields__)


def inside_workspace(waypoints: np.ndarray, limit_nm: float) -> np.ndarray:
    """Waypoints (..., 2) nm pulled toward the centre to within ``limit_nm`` of it, in place;
    returns them. (The safety filter's compiled alternatives use the scalar counterpart,
    ``atc_nf_env.shield_prediction._inside``.)"""
    radius = np.hypot(waypoints[..., 0], waypoints[..., 1])
    waypoints *= np.minimum(1.0, limit_nm / np.maximum(radius, 1e-12))[..., None]
    return waypoints


def homing_mixture_draws(
    rng: np.random.Generator,
    settings: ProposalShape,
    heading: np.ndarray,
    bearing: np.ndarray,
    count: int,
    heading_share: float,
    distance_std_nm: float,
    turn_limit_rad: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` draws of the "homing" proposal's waypoints of N aircraft: directions (count,
    N) rad and distances (count, N) nm.

    Per aircraft, a mixture: with probability ``heading_share`` an angle uniform in
    ±``settings.recovery_angle_rad`` around its heading (N,) rad, otherwise uniform in
    ±``settings.angle_range_rad`` around its bearing (N,) rad to the destination; the
    distance is normal around ``settings.distance_mean_nm`` with ``distance_std_nm``. The
    MCMC-MPC draws its candidates from it, and the safety filter its sampled alternatives.
    ``turn_limit_rad``: (N,) each aircraft's own half-width around its heading instead of
    ``settings.recovery_angle_rad``, rad (the MPC widens it near home:
    ``MPCSettings.approach_angle_rad``).
    """
    n = heading.shape[0]
    turn = settings.recovery_angle_rad if turn_limit_rad is None else np.asarray(turn_limit_rad, dtype=float)[None, :]
    distance = rng.normal(settings.distance_mean_nm, distance_std_nm, (count, n))
    around_heading = rng.random((count, n)) < heading_share
    angle = rng.uniform(-1.0, 1.0, (count, n))
    direction = np.where(
        around_heading,
        heading[None, :] + turn * angle,
        bearing[None, :] + settings.angle_range_rad * angle,
    )
    return direction, distance


__all__ = ["PROPOSAL_FIELDS", "WaypointProposal", "homing_mixture_draws", "inside_workspace"]
