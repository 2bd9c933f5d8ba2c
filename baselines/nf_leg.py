"""The navigation function aimed along the line home, one leg at a time: the NF alone as
a fair floor where destinations lie far beyond the distance the NF is calibrated for."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.proposals import inside_workspace
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView
from baselines.mcmc_mpc import MPCSettings

_MPC_DEFAULTS = MPCSettings()
#: The leg's default length: the MPC's homing distance (``MPCSettings.home_distance_nm``), nm.
DEFAULT_LEG_NM: float = _MPC_DEFAULTS.home_distance_nm
#: The default largest turn from the heading: the MPC's ``recovery_angle_rad`` (60°), rad.
DEFAULT_MAX_TURN_RAD: float = _MPC_DEFAULTS.recovery_angle_rad
#: The allowed leg lengths, nm: (0, LEG_NM_MAX].
LEG_NM_MAX: float = 1000.0


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to [−π, π), rad."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


#: How an aircraft ends its flight (``NFLeg``'s ``final_approach``).
FINAL_APPROACHES: tuple[str, ...] = ("through", "destination")


class NFLeg:
    """The NF alone, aimed every period at a point ``leg_nm`` ahead on the straight line
    to the destination.

    ``NFDirect`` aims at the destination for the whole flight. The NF's gains are
    calibrated for waypoints about 100 nm away: aimed at a destination 500 nm across a
    traffic stream's sector it commands airspeeds far outside the envelope. ``NFLeg``
    keeps the NF's waypoint one leg ahead, as the MPC's homing proposal starts its chain
    (``baselines.MCMCMPC``'s Θ_0: every aircraft aimed home, ``home_distance_nm`` out,
    turned at most ``recovery_angle_rad`` from its heading), and is otherwise the NF
    alone: no prediction, no constraint, no memory. It is the floor a traffic stream's
    policies should beat.

    The final approach (``final_approach``):

    - ``"through"`` (default, as the MPC's Θ_0): the waypoint stays a leg ahead on the
      line through the destination, also when the destination is closer than a leg, so
      the aircraft crosses its destination at cruise airspeed (an aircraft has arrived
      when its path passes within Δ of its destination).
    - ``"destination"``: once the destination is closer than a leg (and within the turn
      limit), the waypoint is the destination itself, with the scenario's arrival
      heading as θ_d. The NF's field vanishes at its waypoint, so the aircraft slows
      down toward it, well below the envelope's 366 kt, before it arrives.

    The waypoint's desired orientation θ_d is the kernel's: the bearing from the aircraft
    to a leg point (the aircraft starts on the dipole's axis, flying toward it), the
    arrival heading at the destination itself (the waypoint is then the destination bit
    for bit, as ``NFDirect``'s). A leg point is pulled inside the workspace as the MPC's
    waypoints are.

    Turns are limited as in the MPC's Θ_0: the leg's direction turns at most
    ``max_turn_rad`` from the aircraft's heading. The NF answers a waypoint behind the
    aircraft with a reverse airspeed (u = −F when P_i > 0), so an aircraft that has
    passed its destination without arriving, or been pushed off its line by a conflict,
    would otherwise fly backwards far outside the envelope; with the limit it turns back
    over a few periods, flying forward. ``max_turn_rad = π`` removes the limit.

    Args:
        leg_nm: the leg's length, nm, in (0, 1000]; default the MPC's homing distance
            (``MPCSettings.home_distance_nm``, 130 nm).
        max_turn_rad: the largest angle between the heading and the leg's direction, rad,
            in (0, π]; default the MPC's ``recovery_angle_rad`` (π/3, 60°).
        final_approach: "through" or "destination" (above).

    Raises:
        ValueError: a setting out of its range (the message names the range).
        TypeError: an unknown keyword argument.
    """

    name = "nf-leg"

    def __init__(self, leg_nm: float = DEFAULT_LEG_NM, max_turn_rad: float = DEFAULT_MAX_TURN_RAD,
                 final_approach: str = "through", **unknown: Any) -> None:
        if unknown:
            raise TypeError(f"NFLeg got unknown settings {sorted(unknown)}; allowed: leg_nm, max_turn_rad, "
                            "final_approach")
        if isinstance(leg_nm, bool) or not (isinstance(leg_nm, (int, float, np.integer, np.floating))
                                            and 0.0 < leg_nm <= LEG_NM_MAX):
            raise ValueError(f"leg_nm = {leg_nm!r}: must be a number in (0, {LEG_NM_MAX:g}] nm")
        if isinstance(max_turn_rad, bool) or not (isinstance(max_turn_rad, (int, float, np.integer, np.floating))
                                                  and 0.0 < max_turn_rad <= math.pi):
            raise ValueError(f"max_turn_rad = {max_turn_rad!r}: must be a number in (0, π] rad")
        if final_approach not in FINAL_APPROACHES:
            raise ValueError(f"final_approach = {final_approach!r}: allowed: {', '.join(FINAL_APPROACHES)}")
        self.leg_nm = float(leg_nm)
        self.max_turn_rad = float(max_turn_rad)
        self.final_approach = final_approach
        self._waypoint_limit_nm = math.inf

    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Note the workspace: a leg point stays inside it, as the MPC's waypoints do."""
        self._waypoint_limit_nm = 0.99 * (scenario.workspace_radius_nm - config.aircraft_radius_nm)

    def act(self, view: WorldView) -> np.ndarray:
        """The waypoints (N, 2), nm: the leg points, or under ``final_approach =
        "destination"`` the destination where it is within a leg and the turn limit."""
        position = view.positions
        destination = view.destinations
        to_dest = destination - position
        bearing = np.arctan2(to_dest[:, 1], to_dest[:, 0])
        heading = view.headings
        off = _wrap(bearing - heading)
        if self.max_turn_rad >= math.pi:
            direction = bearing  # exactly the line home, not a round trip through the heading
        else:
            direction = heading + np.clip(off, -self.max_turn_rad, self.max_turn_rad)
        leg = position + self.leg_nm * np.stack([np.cos(direction), np.sin(direction)], axis=-1)
        leg = inside_workspace(leg, self._waypoint_limit_nm)
        if self.final_approach == "through":
            return leg
        close = (np.hypot(to_dest[:, 0], to_dest[:, 1]) <= self.leg_nm) & (np.abs(off) <= self.max_turn_rad)
        return np.where(close[:, None], destination, leg)
