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
    N_AIRCRAFT_LANE,
    N_COMMAND,
    N_RECORD,
    N_STATE,
    S_DEST_X,
    S_DEST_Y,
    S_HEADING,
    S_STATUS,
    S_TIME,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
)
from atc_nf_env.nf import FAST_MATH_FLAGS
from atc_nf_env.units import SECONDS_PER_HOUR
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: ``PlanPredictor.first_safe`` when no candidate is safe.
NONE_SAFE = -1
_NON_FINITE = -2
_NON_FINITE_MESSAGE = ("the safety filter's prediction produced NaN or inf; the scenario or gains lie outside the "
                       "range the NF is calibrated for")

#: ``PlanPredictor.screen``'s verdicts on a proposal: safe as proposed, unsafe, some
#: aircraft handed over by the progress rule (not predicted: the caller changes their waypoints
#: first), no aircraft flying (nothing to check), a NaN or inf in the proposal.
SCREEN_SAFE, SCREEN_UNSAFE, SCREEN_HOMED, SCREEN_NONE_FLYING, SCREEN_NOT_FINITE = range(5)


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
    aircraft_lanes: np.ndarray,
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
                world, waypoints, wind[0], wind[1], period_steps, params, grad, command, aircraft_lanes,
                min_airspeed, max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, record, 1, True,
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


class DecisionMemory:
    """What the safety filter carries from one decision to the next, as arrays that the
    compiled ``PlanPredictor.screen`` reads and updates in place.

    Attributes (N aircraft, P = ``progress_periods``):
        wind_kt: (2,) the wind estimate (east, north), kt.
        predicted: (N, 2) where the applied waypoints were predicted to put each aircraft
            after one period, nm, and ``predicted_alive`` (N,) whether it was still flying;
            valid while ``timing[0]`` is 1, for the decision at ``timing[1]`` s.
        distances: (P + 1, N) each aircraft's distance to its destination at the last
            decisions one period apart, nm (the progress rule's window), at the times
            ``history_time`` (P + 1,) s; ``counts[0]`` rows are filled.
        homebound: (N,) aircraft handed over by the progress rule until they arrive.
        counts: (2,) int64: the rows of ``distances`` filled, and the aircraft handed over
            by the progress rule so far.
    """

    def __init__(self, n_aircraft: int, progress_periods: int) -> None:
        self.wind_kt = np.zeros(2)
        self.predicted = np.zeros((n_aircraft, 2))
        self.predicted_alive = np.zeros(n_aircraft, dtype=np.bool_)
        self.timing = np.zeros(2)
        self.distances = np.zeros((progress_periods + 1, n_aircraft))
        self.history_time = np.zeros(progress_periods + 1)
        self.homebound = np.zeros(n_aircraft, dtype=np.bool_)
        self.counts = np.zeros(2, dtype=np.int64)
        self.planned = np.zeros((1, n_aircraft, 2))

    def remember(self, time_s: float, positions: np.ndarray, alive: np.ndarray) -> None:
        """Keep the positions (N, 2) nm and flying flags (N,) predicted for ``time_s``."""
        self.predicted[:] = positions
        self.predicted_alive[:] = alive
        self.timing[0] = 1.0
        self.timing[1] = time_s

    def forget(self) -> None:
        """No prediction to correct the wind estimate by at the next decision."""
        self.timing[0] = 0.0


@njit(cache=True, error_model="numpy")
def _screen(
    state: np.ndarray,
    proposal: np.ndarray,
    time_s: float,
    period_s: float,
    progress_on: bool,
    progress_asked_nm: float,
    arrival_nm: float,
    wind: np.ndarray,
    timing: np.ndarray,
    predicted: np.ndarray,
    predicted_alive: np.ndarray,
    distances: np.ndarray,
    history_time: np.ndarray,
    homebound: np.ndarray,
    counts: np.ndarray,
    planned: np.ndarray,
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
    aircraft_lanes: np.ndarray,
    per_aircraft: np.ndarray,
    per_aircraft_counts: np.ndarray,
    los_pairs: np.ndarray,
    record: np.ndarray,
    survived: np.ndarray,
    blamed: np.ndarray,
    positions: np.ndarray,
    alive: np.ndarray,
) -> int:
    """The safety filter's decision up to its verdict on the proposal, in one compiled call
    (``PlanPredictor.screen``): the wind estimate corrected by the drift from the last
    prediction, the progress rule's window, the planned waypoints (the proposal for the
    flying aircraft, the current waypoints for the others) and, unless the progress rule
    hands an aircraft over, their prediction. Compiled without fast-math: the finiteness
    checks would be compiled away under no-NaN, no-inf flags, and the sums must round as
    the Python they replace did."""
    n = state.shape[0]
    for i in range(n):
        if not (math.isfinite(proposal[i, 0]) and math.isfinite(proposal[i, 1])):
            return SCREEN_NOT_FINITE
    # The wind estimate: the mean drift of the aircraft from where the last prediction put
    # them, per period (the MCMC-MPC's "estimated" wind model).
    if timing[0] != 0.0 and abs(time_s - timing[1]) <= 1e-6:
        drift_x = 0.0
        drift_y = 0.0
        count = 0
        for i in range(n):
            # Only an aircraft that flew the whole period was predicted: in a traffic stream a
            # slot emptied by an arrival may hold a flight that entered at this instant.
            if state[i, S_STATUS] == FLYING and predicted_alive[i] and state[i, S_TIME] >= period_s - 1e-6:
                drift_x += state[i, S_X] - predicted[i, 0]
                drift_y += state[i, S_Y] - predicted[i, 1]
                count += 1
        if count:
            hours = period_s / SECONDS_PER_HOUR
            wind[0] = wind[0] + drift_x / count / hours
            wind[1] = wind[1] + drift_y / count / hours
        timing[0] = 0.0
    any_flying = False
    for i in range(n):
        flying = state[i, S_STATUS] == FLYING
        any_flying |= flying
        if not flying or state[i, S_TIME] < period_s - 1e-6:
            homebound[i] = False  # a slot's hand-over ends with its flight (a stream reuses the slot)
        planned[0, i, 0] = proposal[i, 0] if flying else state[i, S_WP_X]
        planned[0, i, 1] = proposal[i, 1] if flying else state[i, S_WP_Y]
    if not any_flying:
        return SCREEN_NONE_FLYING
    homed = False
    if progress_on:
        # The progress rule's window: one row per decision, restarted where a decision is
        # not one period after the last; an aircraft that came less than the progress asked
        # closer to home over the window is handed over until it arrives.
        rows = counts[0]
        if rows > 0 and abs(time_s - history_time[rows - 1] - period_s) > 1e-6:
            rows = 0
        history_time[rows] = time_s
        for i in range(n):
            distances[rows, i] = math.hypot(state[i, S_DEST_X] - state[i, S_X], state[i, S_DEST_Y] - state[i, S_Y])
        rows += 1
        if rows > distances.shape[0] - 1:
            for i in range(n):
                # Within the progress asked of home (plus the arrival tolerance) at the
                # window's start, an aircraft is asked to close all of it, i.e. to arrive:
                # asking a fraction of what is left would let it close in geometrically
                # and never arrive.
                asked = min(progress_asked_nm, distances[0, i] - arrival_nm)
                # Judged only over a window the aircraft flew whole (time flown counts from
                # its entry): a stream's slot may have held another flight at its start.
                whole = state[i, S_TIME] >= history_time[rows - 1] - history_time[0] - 1e-6
                if (state[i, S_STATUS] == FLYING and not homebound[i] and whole
                        and distances[rows - 1, i] > distances[0, i] - asked):
                    homebound[i] = True
                    counts[1] += 1
            for r in range(rows - 1):
                history_time[r] = history_time[r + 1]
                for i in range(n):
                    distances[r, i] = distances[r + 1, i]
            rows -= 1
        counts[0] = rows
        for i in range(n):
            homed |= homebound[i] and state[i, S_STATUS] == FLYING
    if homed:
        return SCREEN_HOMED
    index = _first_safe(
        state, planned, wind, params, period_steps, lookahead_periods, home_distance_nm, max_turn_rad, limit_nm,
        world, home, grad, command, aircraft_lanes, per_aircraft[0], per_aircraft[1], per_aircraft[2],
        per_aircraft_counts[0], per_aircraft_counts[1], los_pairs, record, survived, blamed, positions, alive,
    )
    if index == _NON_FINITE:
        return _NON_FINITE
    if index == NONE_SAFE:
        return SCREEN_UNSAFE
    for i in range(n):
        predicted[i, 0] = positions[i, 0]
        predicted[i, 1] = positions[i, 1]
        predicted_alive[i] = alive[i]
    timing[0] = 1.0
    timing[1] = time_s + period_s
    return SCREEN_SAFE


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
            self._aircraft_lanes = np.zeros((N_AIRCRAFT_LANE, n))
            self._per_aircraft = np.zeros((3, n))  # lowest and highest airspeed, worst excursion
            self._counts = np.zeros((2, n), dtype=np.int64)  # violation steps, steps flown
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
            self._world, self._home, grad, command, self._aircraft_lanes, min_airspeed, max_airspeed, worst,
            violation_steps, steps_flown, self._los_pairs, self._record, self.survived, self.blamed, self.positions,
            self.alive,
        )
        if index == _NON_FINITE:
            raise FloatingPointError(_NON_FINITE_MESSAGE)
        return index

    def screen(
        self,
        state: np.ndarray,
        proposal: np.ndarray,
        time_s: float,
        period_s: float,
        memory: DecisionMemory,
        progress_asked_nm: float | None,
        arrival_nm: float = 0.0,
    ) -> int:
        """The safety filter's routine decision in one compiled call: correct
        ``memory.wind_kt`` by the drift from the last prediction, update the progress rule's
        window and hand over (``memory.homebound``) every flying aircraft that came less than
        ``progress_asked_nm`` closer to home over it, or, when it was within
        ``progress_asked_nm + arrival_nm`` of home at the window's start, did not arrive
        (``progress_asked_nm`` None: no rule), plan the proposal (N, 2) nm for the flying
        aircraft (``memory.planned[0]``) and, unless the rule hands an aircraft over,
        predict it from ``state`` (N, N_STATE), a C-contiguous float64 array, at
        ``time_s`` s, with periods of ``period_s`` s. Safe: ``memory`` remembers where the
        prediction puts the aircraft after one period.

        Returns:
            A ``SCREEN_*`` verdict. ``SCREEN_UNSAFE``: ``survived[0]`` and ``blamed[0]`` as
            after ``first_safe``.

        Raises:
            FloatingPointError: if the flight produced a NaN or inf state.
        """
        n = state.shape[0]
        self._buffers(n, 1)
        self.survived[0] = -1
        grad, command = self._grad, self._command
        verdict = _screen(
            state, proposal, time_s, period_s, progress_asked_nm is not None,
            0.0 if progress_asked_nm is None else progress_asked_nm, arrival_nm, memory.wind_kt, memory.timing,
            memory.predicted, memory.predicted_alive, memory.distances, memory.history_time, memory.homebound,
            memory.counts, memory.planned, self.params, self.period_steps, self.lookahead_periods, *self._homing,
            self._world, self._home, grad, command, self._aircraft_lanes, self._per_aircraft, self._counts,
            self._los_pairs, self._record, self.survived, self.blamed, self.positions, self.alive,
        )
        if verdict == _NON_FINITE:
            raise FloatingPointError(_NON_FINITE_MESSAGE)
        return verdict


__all__ = ["NONE_SAFE", "SCREEN_HOMED", "SCREEN_NONE_FLYING", "SCREEN_NOT_FINITE", "SCREEN_SAFE", "SCREEN_UNSAFE",
           "DecisionMemory", "PlanPredictor"]
