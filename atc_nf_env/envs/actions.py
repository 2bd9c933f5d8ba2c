"""Actions of the environments: a normalized pair in [-1, 1]² per aircraft, mapped to
an intermediate waypoint relative to the bearing to the aircraft's destination::

    distance = distance_nm + distance_span_nm · a[0]              (nm)
    angle    = bearing_to_destination + angle_span_deg · a[1]     (counter-clockwise)
    waypoint = position + distance · [cos angle, sin angle]

The defaults (100 ± 40 nm, ±90°) cover the paper's MPC proposal (distance ~ N(100, 10)
nm, angle ~ U[−90°, 90°] around the line to the destination): a = (0, 0) is a waypoint
100 nm ahead on the straight line to the destination, which is where the calibrated NF
commands the nominal airspeed (454 kt).

A waypoint that would fall outside the workspace is pulled toward the centre, along
the ray from the centre, to ``workspace_radius_nm − aircraft_radius − 1 nm``
(``Simulation.advance`` rejects waypoints on or beyond the boundary). With the default
1500 nm workspace and 250 nm encounters this never happens in ordinary flight.

Everything here is vectorized over any leading batch shape (..., 2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

import numpy as np
from numba import njit

from atc_nf_env.envs.coerce import coerce_settings
from atc_nf_env.kernel import FLYING, S_DEST_X, S_DEST_Y, S_STATUS, S_WP_X, S_WP_Y, S_X, S_Y
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: Distance kept between a clamped waypoint and the edge of the allowed disk, nm.
WORKSPACE_MARGIN_NM: float = 1.0


@dataclass(frozen=True)
class ActionMapping:
    """How a normalized action a ∈ [-1, 1]² becomes a waypoint.

    Attributes:
        distance_nm: waypoint distance at a[0] = 0, nm.
        distance_span_nm: the distance moves by ± this at a[0] = ±1, nm (so the
            default covers [60, 140] nm).
        angle_span_deg: the angle off the bearing to the destination at a[1] = ±1,
            degrees (counter-clockwise positive; at most 180).
    """

    distance_nm: float = 100.0
    distance_span_nm: float = 40.0
    angle_span_deg: float = 90.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"ActionMapping.{field.name} = {value!r}: must be a finite number")
        if self.distance_span_nm < 0:
            raise ValueError(f"ActionMapping.distance_span_nm = {self.distance_span_nm!r}: must be >= 0")
        if self.distance_nm - self.distance_span_nm <= 0:
            raise ValueError(
                f"ActionMapping: distance_nm - distance_span_nm = "
                f"{self.distance_nm - self.distance_span_nm!r} nm; the shortest waypoint distance must be > 0"
            )
        if not 0 <= self.angle_span_deg <= 180:
            raise ValueError(f"ActionMapping.angle_span_deg = {self.angle_span_deg!r}: must be in [0, 180]")

    @property
    def distance_range_nm(self) -> tuple[float, float]:
        """(shortest, longest) waypoint distance, nm."""
        return (self.distance_nm - self.distance_span_nm, self.distance_nm + self.distance_span_nm)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def coerce(cls, value: "ActionMapping | Mapping[str, Any] | None") -> "ActionMapping":
        """An ActionMapping from itself, a dict of (some of) its fields, or None (the defaults)."""
        return coerce_settings(cls, value, "action_mapping")


DEFAULT_MAPPING = ActionMapping()


def nonfinite_actions(actions: np.ndarray) -> str | None:
    """None if every action of ``actions`` (..., 2) is finite; else a short text naming the
    first NaN or inf (its world, aircraft and component where the shape says so) and how
    many there are, for an error message that stays one line whatever the batch."""
    bad = ~np.isfinite(actions)
    if not bad.any():
        return None
    index = np.unravel_index(int(np.argmax(bad)), bad.shape)
    names = ("world", "aircraft")[-(actions.ndim - 1):] if 2 <= actions.ndim <= 3 else ()
    where = [f"{name} {int(k)}" for name, k in zip(names, index)]
    if actions.ndim <= 3:
        where.append(("distance", "angle")[int(index[-1])] if actions.shape[-1] == 2 else f"component {int(index[-1])}")
    else:
        where = [f"index {tuple(int(k) for k in index)}"]
    count = int(bad.sum())
    return (f"{float(actions[index])} at {', '.join(where)} ({count} non-finite value{'s' if count > 1 else ''} "
            f"in an array of shape {actions.shape})")


def clip_actions(actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clip actions (..., 2) to [-1, 1]; returns (clipped float64 copy, (...,) bool: was clipped).

    Raises:
        ValueError: if any action is NaN or infinite (clipping would hide it).
    """
    actions = np.asarray(actions, dtype=np.float64)
    bad = nonfinite_actions(actions)
    if bad is not None:
        raise ValueError(f"actions contain NaN or inf: {bad}; each must be finite, in [-1, 1]")
    clipped = np.clip(actions, -1.0, 1.0)
    return clipped, (clipped != actions).any(axis=-1)


def _bearing(position: np.ndarray, destination: np.ndarray) -> np.ndarray:
    delta = np.asarray(destination, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    return np.arctan2(delta[..., 1], delta[..., 0])


def clamp_to_workspace(
    waypoints: np.ndarray, workspace_radius_nm: float, aircraft_radius_nm: float = 2.5
) -> np.ndarray:
    """Pull waypoints (..., 2) nm lying outside the allowed disk toward the centre (in place
    on a float64 copy): the allowed radius is ``workspace_radius_nm − aircraft_radius_nm −
    WORKSPACE_MARGIN_NM``."""
    waypoints = np.array(waypoints, dtype=np.float64)
    limit = workspace_radius_nm - aircraft_radius_nm - WORKSPACE_MARGIN_NM
    radius = np.hypot(waypoints[..., 0], waypoints[..., 1])
    outside = radius > limit
    if outside.any():
        waypoints[outside] *= (limit / radius[outside])[:, None]
    return waypoints


def action_to_waypoint(
    action: np.ndarray,
    position: np.ndarray,
    destination: np.ndarray,
    mapping: ActionMapping = DEFAULT_MAPPING,
    workspace_radius_nm: float | None = None,
    aircraft_radius_nm: float = 2.5,
) -> np.ndarray:
    """Absolute waypoints (..., 2) nm from normalized actions (..., 2).

    Args:
        action: (..., 2) in [-1, 1] (values outside are clipped; NaN raises ValueError).
        position: (..., 2) aircraft positions, nm.
        destination: (..., 2) destinations, nm.
        mapping: the distance and angle ranges.
        workspace_radius_nm: if given, waypoints outside the workspace are pulled
            toward the centre (see the module docstring).
        aircraft_radius_nm: r_i, nm (for the workspace clamp).
    """
    action, _ = clip_actions(action)
    position = np.asarray(position, dtype=np.float64)
    distance = mapping.distance_nm + mapping.distance_span_nm * action[..., 0]
    angle = _bearing(position, destination) + math.radians(mapping.angle_span_deg) * action[..., 1]
    waypoint = np.empty(np.broadcast_shapes(position.shape, action.shape))
    waypoint[..., 0] = position[..., 0] + distance * np.cos(angle)
    waypoint[..., 1] = position[..., 1] + distance * np.sin(angle)
    if workspace_radius_nm is not None:
        waypoint = clamp_to_workspace(waypoint, workspace_radius_nm, aircraft_radius_nm)
    return waypoint


def waypoint_to_action(
    waypoint: np.ndarray,
    position: np.ndarray,
    destination: np.ndarray,
    mapping: ActionMapping = DEFAULT_MAPPING,
) -> np.ndarray:
    """The normalized action (..., 2) float32 that maps to ``waypoint`` (inverse of
    ``action_to_waypoint``), clipped to [-1, 1] where the waypoint lies outside the
    mapping's range (then the action maps to the nearest reachable waypoint in distance
    and in angle separately).

    Useful to express another policy's waypoints (the MPC's, say) as actions, e.g. for
    imitation learning.
    """
    waypoint = np.asarray(waypoint, dtype=np.float64)
    position = np.asarray(position, dtype=np.float64)
    delta = waypoint - position
    distance = np.hypot(delta[..., 0], delta[..., 1])
    angle = np.arctan2(delta[..., 1], delta[..., 0]) - _bearing(position, destination)
    angle = (angle + math.pi) % (2 * math.pi) - math.pi
    action = np.zeros(np.broadcast_shapes(waypoint.shape, position.shape))
    if mapping.distance_span_nm > 0:
        action[..., 0] = (distance - mapping.distance_nm) / mapping.distance_span_nm
    if mapping.angle_span_deg > 0:
        action[..., 1] = angle / math.radians(mapping.angle_span_deg)
    return np.clip(action, -1.0, 1.0).astype(np.float32)


@njit(cache=True, error_model="numpy")
def _waypoints_from_state(
    actions: np.ndarray,
    state: np.ndarray,
    distance_nm: float,
    span_nm: float,
    angle_span_rad: float,
    limit_nm: float,
    out: np.ndarray,
) -> None:
    for b in range(state.shape[0]):
        for i in range(state.shape[1]):
            if state[b, i, S_STATUS] != FLYING:
                out[b, i, 0] = state[b, i, S_WP_X]
                out[b, i, 1] = state[b, i, S_WP_Y]
                continue
            x = state[b, i, S_X]
            y = state[b, i, S_Y]
            bearing = math.atan2(state[b, i, S_DEST_Y] - y, state[b, i, S_DEST_X] - x)
            a0 = min(max(actions[b, i, 0], -1.0), 1.0)
            a1 = min(max(actions[b, i, 1], -1.0), 1.0)
            distance = distance_nm + span_nm * a0
            angle = bearing + angle_span_rad * a1
            wx = x + distance * math.cos(angle)
            wy = y + distance * math.sin(angle)
            radius = math.sqrt(wx * wx + wy * wy)
            if radius > limit_nm:
                wx *= limit_nm / radius
                wy *= limit_nm / radius
            out[b, i, 0] = wx
            out[b, i, 1] = wy


def waypoints_for_state(
    actions: np.ndarray,
    state: np.ndarray,
    mapping: ActionMapping,
    workspace_radius_nm: float,
    aircraft_radius_nm: float = 2.5,
) -> np.ndarray:
    """Waypoints (B, N, 2) nm for the aircraft of a kernel state (B, N, N_STATE) from
    finite actions (B, N, 2) (clipped to [-1, 1] here): ``action_to_waypoint`` with the
    workspace clamp, compiled. Aircraft not flying keep their current waypoint."""
    out = np.empty((state.shape[0], state.shape[1], 2))
    _waypoints_from_state(
        np.ascontiguousarray(actions, dtype=np.float64),
        state,
        float(mapping.distance_nm),
        float(mapping.distance_span_nm),
        math.radians(mapping.angle_span_deg),
        workspace_radius_nm - aircraft_radius_nm - WORKSPACE_MARGIN_NM,
        out,
    )
    return out


__all__ = [
    "ActionMapping",
    "DEFAULT_MAPPING",
    "WORKSPACE_MARGIN_NM",
    "action_to_waypoint",
    "clamp_to_workspace",
    "clip_actions",
    "nonfinite_actions",
    "waypoint_to_action",
    "waypoints_for_state",
]
