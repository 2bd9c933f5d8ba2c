"""The safety filter's prediction, compiled: candidate waypoint sets of one world flown one
after another over the look-ahead until the first safe one.

``SafetyFilter`` asks, at every decision, whether the proposed waypoints are safe and, if
not, which of its alternatives (in the order it would choose them) is the first safe one.
Each answer is one or two kernel flights of one world over a period of T = 5 min. Asked
through ``kernel.advance``, every flight paid its Python call, the allocation of its
``Trace`` and a Python computation of the homing waypoints of the look-ahead period, about
as much again as the flight itself for a few aircraft; an intervention tried several
alternatives, each paying it again. Here the whole sequence is one compiled call that
flies the kernel's own ``_advance_world`` (the same compiled flight as ``advance``, so a
prediction is bit for bit the kernel's) on buffers kept between calls.

Units: nautical miles, knots, seconds, radians.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from atc_nf_env import kernel
from atc_nf_env.kernel import (
    FLYING,
    N_COMMAND,
    N_RECORD,
    N_STATE,
    S_DEST_X,
    S_DEST_Y,
    S_HEADING,
    S_STATUS,
    S_X,
    S_Y,
)
from atc_nf_env.nf import FAST_MATH_FLAGS

#: ``PlanPredictor.first_safe`` when no candidate is safe.
NONE_SAFE = -1
_NON_FINITE = -2


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _homing_waypoints(
    world: np.ndarray, keep: np.ndarray, distance_nm: float, max_turn_rad: float, limit_nm: float, out: np.ndarray
) -> None:
    """Each flying aircraft of ``world`` (N, N_STATE) aimed at its destination
    ``distance_nm`` out, turned at most ``max_turn_rad`` from its heading (a waypoint behind
    an aircraft commands a reverse airspeed) and pulled inside ``limit_nm`` of the centre,
    into ``out`` (N, 2) nm; an aircraft not flying keeps its row of ``keep``."""
    for i in range(world.shape[0]):
        if world[i, S_STATUS] != FLYING:
            out[i, 0] = keep[i, 0]
            out[i, 1] = keep[i, 1]
            continue
        x = world[i, S_X]
        y = world[i, S_Y]
        heading = world[i, S_HEADING]
        bearing = math.atan2(world[i, S_DEST_Y] - y, world[i, S_DEST_X] - x)
        error = (bearing - heading + math.pi) % (2.0 * math.pi) - math.pi
        direction = heading + min(max(error, -max_turn_rad), max_turn_rad)
        wx = x + distance_nm * math.cos(direction)
        wy = y + distance_nm * math.sin(direction)
        out[i, 0], out[i, 1] = _inside(wx, wy, limit_nm)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def _inside(x: float, y: float, limit_nm: float) -> tuple[float, float]:
    """A waypoint pulled toward the centre to within ``limit_nm`` of it, nm."""
    scale = min(1.0, limit_nm / max(math.sqrt(x * x + y * y), 1e-12))
    return x * scale, y * scale


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _structured_alternatives(
    state: np.ndarray,
    planned: np.ndarray,
    suspects: np.ndarray,
    joint: bool,
    turns_rad: np.ndarray,
    distances_nm: np.ndarray,
    home_distances_nm: np.ndarray,
    max_turn_rad: float,
    limit_nm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The safety filter's structured alternatives to ``planned`` (N, 2) nm in world
    ``state`` (N, N_STATE): candidate waypoint sets (M, N, 2) nm and which aircraft each
    changes (M, N).

    The variants of an aircraft's waypoint, in this order: its planned waypoint turned
    about the aircraft by each of ``turns_rad``; (not ``joint``) moved to each of
    ``distances_nm`` in the same direction; aimed home at each of ``home_distances_nm``
    (``_homing_waypoints``); each pulled inside ``limit_nm``. Not ``joint``: for each
    aircraft of ``suspects`` in turn, every variant of its waypoint with every other
    aircraft keeping ``planned`` (M = suspects × variants). ``joint``: every flying
    aircraft takes the same variant at once (M = variants)."""
    n = state.shape[0]
    n_dist = 0 if joint else distances_nm.shape[0]
    n_variants = turns_rad.shape[0] + n_dist + home_distances_nm.shape[0]
    variants = np.empty((n_variants, n, 2))
    home = np.empty((n, 2))
    for h in range(home_distances_nm.shape[0]):
        _homing_waypoints(state, planned, home_distances_nm[h], max_turn_rad, limit_nm, home)
        v = turns_rad.shape[0] + n_dist + h
        for i in range(n):
            variants[v, i, 0] = home[i, 0]
            variants[v, i, 1] = home[i, 1]
    for i in range(n):
        x = state[i, S_X]
        y = state[i, S_Y]
        ox = planned[i, 0] - x
        oy = planned[i, 1] - y
        distance = math.sqrt(ox * ox + oy * oy)
        direction = math.atan2(oy, ox)
        for t in range(turns_rad.shape[0]):
            angle = direction + turns_rad[t]
            variants[t, i, 0], variants[t, i, 1] = _inside(
                x + distance * math.cos(angle), y + distance * math.sin(angle), limit_nm
            )
        for d in range(n_dist):
            v = turns_rad.shape[0] + d
            variants[v, i, 0], variants[v, i, 1] = _inside(
                x + distances_nm[d] * math.cos(direction), y + distances_nm[d] * math.sin(direction), limit_nm
            )
    n_candidates = n_variants if joint else suspects.shape[0] * n_variants
    candidates = np.empty((n_candidates, n, 2))
    changed = np.zeros((n_candidates, n), dtype=np.bool_)
    for m in range(n_candidates):
        for i in range(n):
            candidates[m, i, 0] = planned[i, 0]
            candidates[m, i, 1] = planned[i, 1]
    if joint:
        for v in range(n_variants):
            for i in range(n):
                if state[i, S_STATUS] == FLYING:
                    candidates[v, i, 0] = variants[v, i, 0]
                    candidates[v, i, 1] = variants[v, i, 1]
                    changed[v, i] = True
    else:
        for k in range(suspects.shape[0]):
            i = suspects[k]
            for v in range(n_variants):
                m = k * n_variants + v
                candidates[m, i, 0] = variants[v, i, 0]
                candidates[m, i, 1] = variants[v, i, 1]
                changed[m, i] = True
    return candidates, changed


@njit(cache=True, error_model="numpy")
def _first_safe(
    state: np.ndarray,
    candidates: np.ndarray,
    wind: np.ndarray,
    params: np.ndarray,
    period_steps: int,
    lookahead_periods: int,
    home_distance_nm: float,
    max_turn_rad: float,
    limit_nm: float,
    world: np.ndarray,
    home: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    worst_excursion: np.ndarray,
    violation_steps: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    record: np.ndarray,
    survived: np.ndarray,
    blamed: np.ndarray,
    positions: np.ndarray,
    alive: np.ndarray,
) -> int:
    """Index of the first safe candidate (M, N, 2), ``NONE_SAFE``, or ``_NON_FINITE`` when a
    flight produced a NaN or inf. For each candidate flown: ``survived[m]``, the integration
    steps it stayed safe (the whole look-ahead when safe), and ``blamed[m]``, the aircraft
    that left the envelope or lost separation. ``positions``/``alive``: the first safe
    candidate's positions and flying flags after the first period. Compiled without
    fast-math: its finiteness checks would be compiled away under no-NaN, no-inf flags."""
    n = state.shape[0]
    for m in range(candidates.shape[0]):
        for i in range(n):
            blamed[m, i] = False
            for field in range(state.shape[1]):
                world[i, field] = state[i, field]
        offset = 0
        safe = True
        for period in range(lookahead_periods):
            if period == 0:
                waypoints = candidates[m]
            else:
                any_alive = False
                for i in range(n):
                    any_alive |= world[i, S_STATUS] == FLYING
                if not any_alive:
                    break
                _homing_waypoints(world, candidates[m], home_distance_nm, max_turn_rad, limit_nm, home)
                waypoints = home
            _, done, violated = kernel._advance_world(
                world, waypoints, wind[0], wind[1], period_steps, params, grad, command, min_airspeed,
                max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, record, 1,
            )
            if not kernel._all_finite(world):
                return _NON_FINITE
            if violated:
                survived[m] = offset + done - 1
                for i in range(n):
                    pair = False
                    for j in range(n):
                        pair |= los_pairs[i, j] != 0
                    blamed[m, i] = violation_steps[i] > 0 or pair
                safe = False
                break
            if period == 0:
                for i in range(n):
                    positions[i, 0] = world[i, S_X]
                    positions[i, 1] = world[i, S_Y]
                    alive[i] = world[i, S_STATUS] == FLYING
            offset += period_steps
        if safe:
            survived[m] = lookahead_periods * period_steps
            return m
    return NONE_SAFE


def _check_inputs(state: np.ndarray, candidates: np.ndarray, wind_kt: np.ndarray) -> None:
    """``PlanPredictor.first_safe``'s inputs: exact float64 C-contiguous arrays of matching
    shapes, all finite (a few attribute look-ups on the common path)."""
    for name, array, ndim in (("state", state, 2), ("candidates", candidates, 3), ("wind_kt", wind_kt, 1)):
        if not (isinstance(array, np.ndarray) and array.dtype == np.float64 and array.ndim == ndim
                and array.flags.c_contiguous):
            raise ValueError(
                f"{name} is {type(array).__name__} with shape {getattr(array, 'shape', None)} and dtype "
                f"{getattr(array, 'dtype', None)}; expected a C-contiguous float64 array of {ndim} dimensions"
            )
    n = state.shape[0]
    if state.shape[1] != N_STATE or n < 1:
        raise ValueError(f"state has shape {state.shape}; expected (N, {N_STATE}) with N >= 1")
    if candidates.shape[1:] != (n, 2) or candidates.shape[0] < 1:
        raise ValueError(f"candidates has shape {candidates.shape}; expected (M, N, 2) = (M >= 1, {n}, 2) nm")
    if wind_kt.shape != (2,):
        raise ValueError(f"wind_kt has shape {wind_kt.shape}; expected (2,) kt")
    for name, array in (("state", state), ("candidates", candidates), ("wind_kt", wind_kt)):
        if not np.isfinite(array).all():
            raise ValueError(f"{name} contains NaN or inf; all values must be finite")


class PlanPredictor:
    """Predicts waypoint sets of one world over ``lookahead_periods`` periods: the first
    with the waypoints, a second (if 2) with every aircraft re-aimed home (see
    ``_homing_waypoints``), checking the envelope and separation of ``params`` at every
    integration step (``params`` built with ``stop_on_violation=True``).

    Args:
        params: the kernel's parameter vector (``SimConfig.to_params``).
        period_steps: integration steps of one period.
        lookahead_periods: 1 or 2.
        home_distance_nm, max_turn_rad, limit_nm: the homing waypoints' distance (nm),
            largest turn from the heading (rad) and distance limit from the centre (nm).
    """

    def __init__(
        self,
        params: np.ndarray,
        period_steps: int,
        lookahead_periods: int,
        home_distance_nm: float,
        max_turn_rad: float,
        limit_nm: float,
    ) -> None:
        kernel._check_params(params)
        if not params[kernel.nf.P_STOP_ON_VIOLATION]:
            raise ValueError("params must be built with stop_on_violation=True: a prediction stops at its first breach")
        if isinstance(lookahead_periods, bool) or lookahead_periods not in (1, 2):
            raise ValueError(f"lookahead_periods = {lookahead_periods!r}: allowed: 1, 2")
        if isinstance(period_steps, bool) or not isinstance(period_steps, (int, np.integer)) or period_steps < 1:
            raise ValueError(f"period_steps = {period_steps!r}: must be an integer >= 1")
        for name, value in (("home_distance_nm", home_distance_nm), ("max_turn_rad", max_turn_rad),
                            ("limit_nm", limit_nm)):
            if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a finite number > 0")
        self.params = params
        self.period_steps = int(period_steps)
        self.lookahead_periods = int(lookahead_periods)
        self.full_steps = self.lookahead_periods * self.period_steps
        self._homing = (float(home_distance_nm), float(max_turn_rad), float(limit_nm))
        self._n_aircraft = -1
        self._capacity = 0

    def _buffers(self, n_aircraft: int, n_candidates: int) -> None:
        if n_aircraft != self._n_aircraft:
            n = n_aircraft
            self._world = np.zeros((n, N_STATE))
            self._home = np.zeros((n, 2))
            self._grad = np.zeros((n, n, 2))
            self._command = np.zeros((n, N_COMMAND))
            self._per_aircraft = [np.zeros(n) for _ in range(3)]
            self._counts = [np.zeros(n, dtype=np.int64) for _ in range(2)]
            self._los_pairs = np.zeros((n, n), dtype=np.uint8)
            self._record = np.zeros((0, n, N_RECORD))
            self.positions = np.zeros((n, 2))
            self.alive = np.zeros(n, dtype=np.bool_)
            self._n_aircraft = n
            self._capacity = 0
        if n_candidates > self._capacity:
            self._capacity = max(n_candidates, 2 * self._capacity, 16)
            self.survived = np.full(self._capacity, -1, dtype=np.int64)
            self.blamed = np.zeros((self._capacity, n_aircraft), dtype=np.bool_)

    def first_safe(self, state: np.ndarray, candidates: np.ndarray, wind_kt: np.ndarray, *, checked: bool = True) -> int:
        """Fly ``candidates`` (M, N, 2) nm one after another from a copy of ``state``
        (N, N_STATE) under the constant ``wind_kt`` (2,) kt, until one is safe.

        Returns:
            The index of the first safe candidate, or ``NONE_SAFE``. Then ``survived[:M]``
            holds, for the candidates flown (up to and including that one; −1 after it),
            the integration steps each stayed safe (``full_steps`` when safe), and
            ``blamed[:M]`` (M, N) the aircraft each breach involved; ``positions`` (N, 2)
            and ``alive`` (N,) are the safe candidate's after the first period.

        ``checked=False`` skips the checks of the inputs, for a caller that built them itself
        (the safety filter: a few µs of every decision).

        Raises:
            ValueError: on a wrong shape, dtype or layout, or a NaN or inf in any input (the
                compiled flight reads its inputs unchecked).
            FloatingPointError: if a flight produced a NaN or inf state.
        """
        if checked:
            _check_inputs(state, candidates, wind_kt)
        n_candidates, n_aircraft = candidates.shape[0], state.shape[0]
        self._buffers(n_aircraft, n_candidates)
        self.survived[:n_candidates] = -1
        grad, command = self._grad, self._command
        min_airspeed, max_airspeed, worst = self._per_aircraft
        violation_steps, steps_flown = self._counts
        index = _first_safe(
            state, candidates, wind_kt, self.params, self.period_steps, self.lookahead_periods, *self._homing,
            self._world, self._home, grad, command, min_airspeed, max_airspeed, worst, violation_steps,
            steps_flown, self._los_pairs, self._record, self.survived, self.blamed, self.positions, self.alive,
        )
        if index == _NON_FINITE:
            raise FloatingPointError(
                "the safety filter's prediction produced NaN or inf; the scenario or gains lie outside the "
                "range the NF is calibrated for"
            )
        return index


__all__ = ["NONE_SAFE", "PlanPredictor"]
