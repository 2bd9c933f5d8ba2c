"""Observations: ego-centric, normalized, fixed-size, float32.

Per aircraft i, in its ego frame (x forward along its heading, y to its left), with
distances in units of ``DISTANCE_SCALE_NM`` = 100 nm:

==========  ==================  ==========================================================
index       name                meaning
==========  ==================  ==========================================================
0           alive               1 while flying, 0 once arrived or left (its final obs)
1           airspeed            (u − c) / h with c, h the envelope's centre and
                                half-width (453, 87 kt): inside the envelope iff
                                ``|value| <= 1``
2           dest_distance       distance to go / 100 nm
3, 4        dest_cos, dest_sin  bearing to the destination relative to the heading
5, 6        wp_forward,         current waypoint relative to the aircraft / 100 nm
            wp_left
7           time                elapsed time / the episode's time limit
8 .. 7+5K   neighbours          5 values for each neighbour k = 0..K-1 (from 8 + 5 k),
                                nearest first, only aircraft still flying: mask
                                (1 = present), forward, left (relative position /
                                100 nm), vel_forward, vel_left (relative air velocity /
                                454 kt); absent neighbours are all zeros
8+5K, 9+5K  wind_forward,       wind / 50 kt, only with ``expose_wind=True``
            wind_left
==========  ==================  ==========================================================

The relative velocity of two aircraft is the same over the air and over the ground
(the wind is uniform), so the neighbours' features reveal nothing of the wind. Every
value is clipped to ± ``OBS_LIMIT`` (never reached in the workspace: it only makes
the Box bounds finite).

The global state (``state()`` of the PettingZoo env) is, per aircraft slot,
[flying, arrived, x, y (/100 nm, workspace frame), cos θ, sin θ, airspeed (normalized
as above), dest_x, dest_y, wp_x, wp_y (/100 nm)], then the elapsed time fraction, then
the wind (/50 kt) only with ``expose_wind=True``. Padding slots are zeros.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from numba import njit

from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import (
    ABSENT,
    ARRIVED,
    FLYING,
    S_AIRSPEED,
    S_DEST_X,
    S_DEST_Y,
    S_HEADING,
    S_STATUS,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
)
from atc_nf_env.units import AIRSPEED_NOMINAL_KT
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: Unit of every distance in the observations, nm.
DISTANCE_SCALE_NM: float = 100.0
#: Unit of relative velocities, kt.
SPEED_SCALE_KT: float = AIRSPEED_NOMINAL_KT
#: Unit of the wind (when exposed), kt.
WIND_SCALE_KT: float = 50.0
#: Every observation value is clipped to ±OBS_LIMIT (the Box bounds).
OBS_LIMIT: float = 50.0

OWN_FEATURES: tuple[str, ...] = (
    "alive",
    "airspeed",
    "dest_distance",
    "dest_cos",
    "dest_sin",
    "wp_forward",
    "wp_left",
    "time",
)
NEIGHBOUR_FEATURES: tuple[str, ...] = ("mask", "forward", "left", "vel_forward", "vel_left")
WIND_FEATURES: tuple[str, ...] = ("wind_forward", "wind_left")
STATE_SLOT_FEATURES: tuple[str, ...] = (
    "flying",
    "arrived",
    "x",
    "y",
    "cos_heading",
    "sin_heading",
    "airspeed",
    "dest_x",
    "dest_y",
    "wp_x",
    "wp_y",
)

_N_OWN = len(OWN_FEATURES)
_N_NEIGHBOUR = len(NEIGHBOUR_FEATURES)


@njit(cache=True, fastmath=False, error_model="numpy")
def _observe(
    state: np.ndarray,
    time_fraction: np.ndarray,
    wind: np.ndarray,
    n_neighbours: int,
    expose_wind: bool,
    scales: np.ndarray,
    out: np.ndarray,
    nearest: np.ndarray,
) -> None:
    """Fill out (B, M, D) from state (B, N, S), N <= M; slots >= N and ABSENT ones are zeros.
    nearest (B, M): distance to the nearest other aircraft still flying, nm (inf if none)."""
    n_worlds = state.shape[0]
    n = state.shape[1]
    inv_dist = 1.0 / scales[0]
    centre = scales[1]
    inv_half = 1.0 / scales[2]
    inv_speed = 1.0 / scales[3]
    inv_wind = 1.0 / scales[4]
    limit = scales[5]
    dim = out.shape[2]
    out[:] = 0.0
    nearest[:] = np.inf
    dist2 = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    for b in range(n_worlds):
        for i in range(n):
            status = state[b, i, S_STATUS]
            if status == ABSENT:
                continue
            x = state[b, i, S_X]
            y = state[b, i, S_Y]
            heading = state[b, i, S_HEADING]
            ch = math.cos(heading)
            sh = math.sin(heading)
            u = state[b, i, S_AIRSPEED]
            row = out[b, i]
            row[0] = 1.0 if status == FLYING else 0.0
            row[1] = (u - centre) * inv_half
            dx = state[b, i, S_DEST_X] - x
            dy = state[b, i, S_DEST_Y] - y
            dist = math.sqrt(dx * dx + dy * dy)
            row[2] = dist * inv_dist
            if dist > 0.0:
                row[3] = (ch * dx + sh * dy) / dist
                row[4] = (-sh * dx + ch * dy) / dist
            else:
                row[3] = 1.0
                row[4] = 0.0
            wx = state[b, i, S_WP_X] - x
            wy = state[b, i, S_WP_Y] - y
            row[5] = (ch * wx + sh * wy) * inv_dist
            row[6] = (-sh * wx + ch * wy) * inv_dist
            row[7] = time_fraction[b]
            # The K nearest aircraft still flying, nearest first.
            m = 0
            for j in range(n):
                if j == i or state[b, j, S_STATUS] != FLYING:
                    continue
                ex = state[b, j, S_X] - x
                ey = state[b, j, S_Y] - y
                dist2[m] = ex * ex + ey * ey
                order[m] = j
                m += 1
                if dist2[m - 1] < nearest[b, i]:
                    nearest[b, i] = dist2[m - 1]
            if m > 0:
                nearest[b, i] = math.sqrt(nearest[b, i])
            vx = u * ch
            vy = u * sh
            for k in range(min(n_neighbours, m)):
                best = k
                for q in range(k + 1, m):
                    if dist2[q] < dist2[best]:
                        best = q
                if best != k:
                    d_tmp = dist2[k]
                    dist2[k] = dist2[best]
                    dist2[best] = d_tmp
                    o_tmp = order[k]
                    order[k] = order[best]
                    order[best] = o_tmp
                j = order[k]
                ex = state[b, j, S_X] - x
                ey = state[b, j, S_Y] - y
                uj = state[b, j, S_AIRSPEED]
                hj = state[b, j, S_HEADING]
                rvx = uj * math.cos(hj) - vx
                rvy = uj * math.sin(hj) - vy
                base = _N_OWN + _N_NEIGHBOUR * k
                row[base] = 1.0
                row[base + 1] = (ch * ex + sh * ey) * inv_dist
                row[base + 2] = (-sh * ex + ch * ey) * inv_dist
                row[base + 3] = (ch * rvx + sh * rvy) * inv_speed
                row[base + 4] = (-sh * rvx + ch * rvy) * inv_speed
            if expose_wind:
                row[dim - 2] = (ch * wind[b, 0] + sh * wind[b, 1]) * inv_wind
                row[dim - 1] = (-sh * wind[b, 0] + ch * wind[b, 1]) * inv_wind
            for f in range(dim):
                if row[f] > limit:
                    row[f] = limit
                elif row[f] < -limit:
                    row[f] = -limit


@dataclass(frozen=True)
class ObservationSpec:
    """Layout and normalization of the observations and of the global state.

    Attributes:
        n_neighbours: K, the number of nearest neighbours observed (padded, masked).
        expose_wind: append the true wind (ego frame) to the observations and the state.
        airspeed_centre_kt, airspeed_half_width_kt: the airspeed normalization (the
            envelope's centre and half-width, so the envelope maps to [-1, 1]).
    """

    n_neighbours: int = 4
    expose_wind: bool = False
    airspeed_centre_kt: float = 453.0
    airspeed_half_width_kt: float = 87.0

    @classmethod
    def for_config(cls, config: SimConfig, n_neighbours: int, expose_wind: bool) -> "ObservationSpec":
        return cls(
            n_neighbours=n_neighbours,
            expose_wind=expose_wind,
            airspeed_centre_kt=0.5 * (config.airspeed_min_kt + config.airspeed_max_kt),
            airspeed_half_width_kt=0.5 * (config.airspeed_max_kt - config.airspeed_min_kt),
        )

    @property
    def dim(self) -> int:
        """Length of one aircraft's observation."""
        return _N_OWN + _N_NEIGHBOUR * self.n_neighbours + (2 if self.expose_wind else 0)

    def labels(self) -> list[str]:
        """Names of the observation's entries, in order."""
        names = list(OWN_FEATURES)
        for k in range(self.n_neighbours):
            names += [f"n{k}_{name}" for name in NEIGHBOUR_FEATURES]
        if self.expose_wind:
            names += list(WIND_FEATURES)
        return names

    def _bounds(self, labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
        low = np.full(len(labels), -OBS_LIMIT, dtype=np.float32)
        high = np.full(len(labels), OBS_LIMIT, dtype=np.float32)
        for index, name in enumerate(labels):
            if name in ("alive", "time", "flying", "arrived") or name.endswith("_mask"):
                low[index], high[index] = 0.0, 1.0
            elif name.endswith(("_cos", "_sin", "cos_heading", "sin_heading")):
                low[index], high[index] = -1.0, 1.0
        return low, high

    def space(self) -> spaces.Box:
        """Box of one aircraft's observation."""
        low, high = self._bounds(self.labels())
        return spaces.Box(low=low, high=high, dtype=np.float32)

    def flat_space(self, n_slots: int) -> spaces.Box:
        """Box of the concatenated observations of ``n_slots`` aircraft (centralized env)."""
        low, high = self._bounds(self.labels())
        return spaces.Box(low=np.tile(low, n_slots), high=np.tile(high, n_slots), dtype=np.float32)

    @functools.cached_property
    def _scales(self) -> np.ndarray:
        return np.array(
            [
                DISTANCE_SCALE_NM,
                self.airspeed_centre_kt,
                self.airspeed_half_width_kt,
                SPEED_SCALE_KT,
                WIND_SCALE_KT,
                OBS_LIMIT,
            ]
        )

    def observe(
        self,
        state: np.ndarray,
        time_fraction: np.ndarray,
        wind_kt: np.ndarray,
        n_slots: int | None = None,
    ) -> np.ndarray:
        """Observations (B, n_slots, dim) float32 of every aircraft of B worlds.

        Args:
            state: (B, N, N_STATE) kernel state.
            time_fraction: (B,) elapsed time / time limit.
            wind_kt: (B, 2) wind, kt (used only with ``expose_wind``).
            n_slots: M >= N slots (padding is zeros); N by default.
        """
        return self.observe_with_nearest(state, time_fraction, wind_kt, n_slots)[0]

    def observe_into(
        self,
        state: np.ndarray,
        time_fraction: np.ndarray,
        wind_kt: np.ndarray,
        out: np.ndarray,
        nearest: np.ndarray,
    ) -> None:
        """``observe_with_nearest`` into the caller's buffers, for a caller that decides
        often and keeps them (``agents.policy.SB3AgentPolicy``): ``state`` (B, N, N_STATE),
        ``time_fraction`` (B,) and ``wind_kt`` (B, 2) C-contiguous float64, ``out`` (B, M,
        dim) float32 and ``nearest`` (B, M) float64 with M >= N; nothing is converted or
        allocated."""
        _observe(state, time_fraction, wind_kt, self.n_neighbours, self.expose_wind, self._scales, out, nearest)

    def observe_with_nearest(
        self,
        state: np.ndarray,
        time_fraction: np.ndarray,
        wind_kt: np.ndarray,
        n_slots: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``observe``'s observations and (B, n_slots) float64: each aircraft's distance to
        the nearest other aircraft still flying, nm (inf if none, and for padding)."""
        n_slots = state.shape[1] if n_slots is None else n_slots
        out = np.empty((state.shape[0], n_slots, self.dim), dtype=np.float32)
        nearest = np.empty((state.shape[0], n_slots))
        _observe(
            state,
            np.ascontiguousarray(time_fraction, dtype=np.float64),
            np.ascontiguousarray(wind_kt, dtype=np.float64),
            self.n_neighbours,
            self.expose_wind,
            self._scales,
            out,
            nearest,
        )
        return out, nearest

    # ------------------------------------------------------------------ global state

    def state_labels(self, n_slots: int) -> list[str]:
        names = [f"a{i}_{name}" for i in range(n_slots) for name in STATE_SLOT_FEATURES]
        names.append("time")
        if self.expose_wind:
            names += ["wind_x", "wind_y"]
        return names

    def state_space(self, n_slots: int) -> spaces.Box:
        labels = self.state_labels(n_slots)
        low, high = self._bounds([name.split("_", 1)[1] if name[0] == "a" else name for name in labels])
        return spaces.Box(low=low, high=high, dtype=np.float32)

    def global_state(
        self, state: np.ndarray, time_fraction: np.ndarray, wind_kt: np.ndarray, n_slots: int | None = None
    ) -> np.ndarray:
        """Global states (B, state_dim) float32 (see the module docstring)."""
        n_worlds, n, _ = state.shape
        n_slots = n if n_slots is None else n_slots
        k = len(STATE_SLOT_FEATURES)
        present = state[..., S_STATUS] != ABSENT
        slot = np.zeros((n_worlds, n_slots, k))
        heading = state[..., S_HEADING]
        columns = [
            state[..., S_STATUS] == FLYING,
            state[..., S_STATUS] == ARRIVED,
            state[..., S_X] / DISTANCE_SCALE_NM,
            state[..., S_Y] / DISTANCE_SCALE_NM,
            np.cos(heading),
            np.sin(heading),
            (state[..., S_AIRSPEED] - self.airspeed_centre_kt) / self.airspeed_half_width_kt,
            state[..., S_DEST_X] / DISTANCE_SCALE_NM,
            state[..., S_DEST_Y] / DISTANCE_SCALE_NM,
            state[..., S_WP_X] / DISTANCE_SCALE_NM,
            state[..., S_WP_Y] / DISTANCE_SCALE_NM,
        ]
        slot[:, :n] = np.where(present[..., None], np.stack(columns, axis=-1), 0.0)
        parts = [slot.reshape(n_worlds, n_slots * k), np.asarray(time_fraction, dtype=np.float64)[:, None]]
        if self.expose_wind:
            parts.append(np.asarray(wind_kt, dtype=np.float64) / WIND_SCALE_KT)
        return np.clip(np.concatenate(parts, axis=1), -OBS_LIMIT, OBS_LIMIT).astype(np.float32)


__all__ = [
    "DISTANCE_SCALE_NM",
    "NEIGHBOUR_FEATURES",
    "OBS_LIMIT",
    "OWN_FEATURES",
    "ObservationSpec",
    "SPEED_SCALE_KT",
    "STATE_SLOT_FEATURES",
    "WIND_SCALE_KT",
]
