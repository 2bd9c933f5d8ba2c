"""One world's consecutive ordinary steps flown with its flying aircraft kept in lanes
between steps, against the kernel's one-world flight: the same bits, and how much faster,
per check and inside the safety filter?

``kernel._advance_world`` flies a step where nothing couples the aircraft (no neighbour
within the sensing radius, no guard acting, no arrival or departure within reach) by
``_ordinary_step``, one aircraft after another, reading and writing the state's rows at
every step. ``one_world_aircraft_lanes.py`` moved that step's arithmetic into lanes (one
lane per aircraft) but copied the state in and out at every step, and gained nothing. Here
``_ordinary_run`` keeps the flying aircraft in lanes (structure of arrays) for as many
consecutive ordinary steps as come, and writes the state back once, when a step is not
ordinary (the scalar path flies it) or the flight ends. The lane step's arithmetic is
the kernel's own (``nf.own_gradient_alone``, ``trig``'s inlined polynomials,
``_lane_feedback``, ``_lane_move``), operation for operation.

Part 1: the safety filter's checks of ``finetuned_ppo``'s proposals on seeds 0..SEEDS-1
(recorded in situ), each flown 120 steps by both flights, with the envelope stop on and
off and with and without a record of every step: states, outcome arrays, records and
return values compared bit for bit; then both timed in alternating order over 15 rounds,
the first dropped (medians per check; quartiles of the per-round ratio).

Part 2: the filter with its prediction compiled on this flight (a copy of
``shield_prediction`` bound to a copy of the kernel module whose ``_advance_world`` is
this one) against the filter as shipped, around one agent, episode by episode in
alternating order in one process (``_alternating.fly_alternately``: it stops if they ever
apply different waypoints).

Not adopted (README, "Safety filter"): the kernel's one-world flight would need the lane
buffers from every caller (the batch's worlds, the lane path's fallback, the filter), and
the gain does not bring the filter's mean to its goal on six aircraft.

Run: python bench/experiments/one_world_persistent_lanes.py [--seeds 8] [--ab-seeds 30]
     [--scenarios converging-6,random-6,converging-4]
"""
import argparse
import importlib.util
import inspect
import math
import sys
import time
import types

import numpy as np
from numba import njit

from atc_nf_env import kernel, nf, shield_prediction, trig
from atc_nf_env.kernel import (
    C_FLEW,
    C_STEP_MAX,
    C_STEP_MIN,
    FLYING,
    N_COMMAND,
    N_RECORD,
    P_DELTA,
    P_DT,
    P_K_THETA,
    P_R_WORLD,
    P_RADIUS,
    P_SEP_MIN,
    P_U_CAP,
    P_U_MAX,
    P_U_MIN,
    S_AIRSPEED,
    S_COS_D,
    S_DEST_X,
    S_DEST_Y,
    S_FRESH,
    S_HEADING,
    S_LAST_SUBSTEPS,
    S_OMEGA_PREV,
    S_PATH,
    S_SIN_D,
    S_STATUS,
    S_THETA_D,
    S_THETA_NH,
    S_TIME,
    S_VX_PREV,
    S_VY_PREV,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
    _flown_airspeed,
    _lane_feedback,
    _lane_move,
    _record_step,
)
from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS

# lane fields
L_X, L_Y, L_HEADING, L_AIRSPEED, L_THETA_NH, L_WP_X, L_WP_Y, L_THETA_D, L_DEST_X, L_DEST_Y, L_TIME, L_PATH, L_FRESH, \
    L_COS_D, L_SIN_D, L_VX_PREV, L_VY_PREV, L_OMEGA_PREV, L_LAST_SUB = range(19)
# step scratch
Q_GX, Q_GY, Q_AX, Q_TH, Q_SIN, Q_COS, Q_X1, Q_Y1, Q_H1, Q_VX, Q_VY, Q_OM, Q_U, Q_NH, Q_STEP, Q_BAD = range(16)
N_L, N_Q = 19, 16
STATE_OF = (S_X, S_Y, S_HEADING, S_AIRSPEED, S_THETA_NH, S_WP_X, S_WP_Y, S_THETA_D, S_DEST_X, S_DEST_Y, S_TIME, S_PATH,
            S_FRESH, S_COS_D, S_SIN_D, S_VX_PREV, S_VY_PREV, S_OMEGA_PREV, S_LAST_SUBSTEPS)

@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _ordinary_run(state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                  violation_steps, worst_excursion, steps_flown, max_steps, stop_on_violation, lanes, q, index,
                  record, record_every, step0):
    """As many consecutive ordinary steps as come (up to ``max_steps``), the flying aircraft
    in ``lanes`` (N_L, N) and the step's values in ``q`` (N_Q, N) between them; ``index``
    (N,) maps lanes to aircraft. Each step is ``_ordinary_step``'s: it is abandoned, nothing
    written, at a neighbour within the sensing radius, an unusual aircraft or a loss of
    separation (the scalar path flies it). Returns (steps flown, whether one left the
    envelope, the smallest squared separation so far, nm²)."""
    n = state.shape[0]
    inv_len = nf_consts[0]
    r_sense2 = nf_consts[7]
    dt = params[P_DT]
    inv_dt = 1.0 / dt
    k_theta = params[P_K_THETA]
    u_cap = params[P_U_CAP]
    delta = params[P_DELTA]
    sep_min = params[P_SEP_MIN]
    exit_radius = params[P_R_WORLD] - params[P_RADIUS]
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    count = 0
    for i in range(n):
        if state[i, S_STATUS] == FLYING:
            index[count] = i
            count += 1
    if count == 0:
        return 0, False, min_sep2
    for k in range(count):
        i = index[k]
        for f in range(N_L):
            lanes[f, k] = state[i, STATE_OF[f]]
    flown = 0
    violated = False
    while flown < max_steps:
        # no two flying aircraft within the sensing radius, in the NF's arithmetic
        near = False
        for a in range(count):
            xa = lanes[L_X, a] * inv_len
            ya = lanes[L_Y, a] * inv_len
            for b in range(a + 1, count):
                rx = xa - lanes[L_X, b] * inv_len
                ry = ya - lanes[L_Y, b] * inv_len
                near |= rx * rx + ry * ry < r_sense2
        if near:
            break
        for k in range(count):
            gx, gy, _, sgn_along = nf.own_gradient_alone(lanes[L_X, k], lanes[L_Y, k], lanes[L_WP_X, k], lanes[L_WP_Y, k],
                                                         lanes[L_COS_D, k], lanes[L_SIN_D, k], nf_consts)
            q[Q_GX, k] = gx
            q[Q_GY, k] = gy
            q[Q_AX, k] = sgn_along * gx
            q[Q_TH, k] = sgn_along * gy
        for k in range(count):
            q[Q_TH, k] = trig.poly_atan2_inlined(q[Q_TH, k], q[Q_AX, k])
        for k in range(count):
            q[Q_SIN, k], q[Q_COS, k] = trig.poly_sincos_inlined(lanes[L_HEADING, k])
        for k in range(count):
            c = q[Q_COS, k]
            s = q[Q_SIN, k]
            x0 = lanes[L_X, k]
            y0 = lanes[L_Y, k]
            u, theta_nh = _lane_feedback(q[Q_GX, k], q[Q_GY, k], c, s, (x0 - lanes[L_WP_X, k]) * inv_len,
                                         (y0 - lanes[L_WP_Y, k]) * inv_len, q[Q_TH, k], lanes[L_THETA_D, k], params)
            x1, y1, heading1, vx, vy, omega, far = _lane_move(
                u, c, s, wind_x, wind_y, x0, y0, lanes[L_HEADING, k], theta_nh, lanes[L_THETA_NH, k], lanes[L_FRESH, k],
                lanes[L_LAST_SUB, k], lanes[L_VX_PREV, k], lanes[L_VY_PREV, k], lanes[L_OMEGA_PREV, k], dt, inv_dt,
                k_theta)
            step_nm = math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
            ex = x1 - lanes[L_DEST_X, k]
            ey = y1 - lanes[L_DEST_Y, k]
            reach = delta + step_nm
            bad = (not ((-u_cap < u) & (u < u_cap))) | far | (ex * ex + ey * ey <= reach * reach) | (
                x1 * x1 + y1 * y1 >= exit_radius * exit_radius)
            q[Q_BAD, k] = 1.0 if bad else 0.0
            q[Q_X1, k] = x1
            q[Q_Y1, k] = y1
            q[Q_H1, k] = heading1
            q[Q_VX, k] = vx
            q[Q_VY, k] = vy
            q[Q_OM, k] = omega
            q[Q_U, k] = u
            q[Q_NH, k] = theta_nh
            q[Q_STEP, k] = step_nm
        unusual = False
        for k in range(count):
            unusual |= q[Q_BAD, k] != 0.0
        if unusual:
            break
        new_min_sep2 = min_sep2
        lost = False
        for a in range(count):
            for b in range(a + 1, count):
                sx = q[Q_X1, a] - q[Q_X1, b]
                sy = q[Q_Y1, a] - q[Q_Y1, b]
                sep2 = sx * sx + sy * sy
                lost |= sep2 < sep_min * sep_min
                new_min_sep2 = min(new_min_sep2, sep2)
        if lost:
            break
        min_sep2 = new_min_sep2
        step_violation = False
        for k in range(count):
            u = q[Q_U, k]
            lanes[L_VX_PREV, k] = q[Q_VX, k]
            lanes[L_VY_PREV, k] = q[Q_VY, k]
            lanes[L_OMEGA_PREV, k] = q[Q_OM, k]
            lanes[L_LAST_SUB, k] = 1.0
            lanes[L_X, k] = q[Q_X1, k]
            lanes[L_Y, k] = q[Q_Y1, k]
            lanes[L_HEADING, k] = q[Q_H1, k]
            lanes[L_AIRSPEED, k] = u
            lanes[L_THETA_NH, k] = q[Q_NH, k]
            lanes[L_FRESH, k] = 0.0
            lanes[L_TIME, k] += dt
            lanes[L_PATH, k] += q[Q_STEP, k]
        for k in range(count):
            i = index[k]
            u = q[Q_U, k]
            min_airspeed[i], max_airspeed[i], worst_excursion[i], excursion = _flown_airspeed(
                u, steps_flown[i] == 0, min_airspeed[i], max_airspeed[i], worst_excursion[i], u_min, u_max)
            if excursion > 0.0:
                step_violation = True
                violation_steps[i] += 1
            steps_flown[i] += 1
        flown += 1
        if record.shape[0] > 0:
            for i in range(n):
                command[i, C_FLEW] = 0.0  # the aircraft not flying, as ``_ordinary_step`` leaves them
            for k in range(count):
                i = index[k]
                for f in range(N_L):
                    state[i, STATE_OF[f]] = lanes[f, k]
                command[i, C_FLEW] = 1.0
                command[i, C_STEP_MIN] = q[Q_U, k]
                command[i, C_STEP_MAX] = q[Q_U, k]
            _record_step(state, command, record, step0 + flown, record_every)
        if step_violation:
            violated = True
            if stop_on_violation:
                break
    if flown > 0:
        for k in range(count):
            i = index[k]
            for f in range(N_L):
                state[i, STATE_OF[f]] = lanes[f, k]
    return flown, violated, min_sep2


# ``_advance_world`` with ``_ordinary_run`` in place of its one-step ``_ordinary_step``.
_source = inspect.getsource(kernel._advance_world.py_func)
_source = _source[_source.index("def _advance_world"):]
_source = _source.replace("def _advance_world(", "def _advance_world_persistent(lanes, q, index, ", 1)
_ONE_STEP = """            flew, step_violation, min_sep2 = _ordinary_step(
                state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                violation_steps, worst_excursion, steps_flown,
            )
            if flew:
                step += 1
                _record_step(state, command, record, step, record_every)
                if step_violation:"""
if _ONE_STEP not in _source:
    raise SystemExit("kernel._advance_world changed: this experiment's substitution no longer applies")
_source = _source.replace(_ONE_STEP, """            flew, step_violation, min_sep2 = _ordinary_run(
                state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                violation_steps, worst_excursion, steps_flown, n_steps - step, stop_on_violation, lanes, q, index,
                record, record_every, step,
            )
            if flew:
                step += flew
                if step_violation:""")
_namespace = dict(vars(kernel))
_namespace["_ordinary_run"] = _ordinary_run
exec(_source, _namespace)  # noqa: S102 - the kernel's own loop, with the run of ordinary steps in place of one
_advance_world_persistent = njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)(
    _namespace["_advance_world_persistent"])


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _advance_world_with_lanes(state, waypoints, wind_x, wind_y, n_steps, params, grad, command, min_airspeed,
                              max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, record,
                              record_every, ordinary_steps):
    """``kernel._advance_world``'s signature, its lane buffers allocated per call (a few
    hundred ns against tens of µs), for the filter's prediction compiled on it."""
    n = state.shape[0]
    return _advance_world_persistent(np.empty((N_L, n)), np.empty((N_Q, n)), np.empty(n, dtype=np.int64), state,
                                     waypoints, wind_x, wind_y, n_steps, params, grad, command, min_airspeed,
                                     max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, record,
                                     record_every, ordinary_steps)


def recorded_checks(scenario: str, seeds: int):
    """The filter's checks of ``finetuned_ppo``'s proposals on seeds 0..seeds-1: states
    (C, N, N_STATE), planned waypoints (C, N, 2), wind estimates (C, 2), its parameters."""
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    cases = []
    screen = shield_prediction.PlanPredictor.screen

    def recording(self, state, proposal, time_s, period_s, memory, stall_progress_nm):
        cases.append((self.params, state.copy(), proposal.copy(), memory.wind_kt.copy()))
        return screen(self, state, proposal, time_s, period_s, memory, stall_progress_nm)

    shield_prediction.PlanPredictor.screen = recording
    try:
        shielded = SafetyFilter(make_policy("agents/models/finetuned_ppo.zip"))
        for seed in range(seeds):
            run_episode(shielded, make_scenario(scenario, seed=seed), seed=seed)
    finally:
        shield_prediction.PlanPredictor.screen = screen
    states = np.stack([c[1] for c in cases])
    planned = np.stack([c[2] for c in cases])
    not_flying = states[:, :, S_STATUS] != FLYING
    planned[not_flying] = states[not_flying][:, S_WP_X : S_WP_Y + 1]
    return states, planned, np.stack([c[3] for c in cases]), cases[0][0]


def fly_all(flight, extra, states, planned, winds, params, n_steps, n_record):
    """Every case flown ``n_steps`` by ``flight``: (seconds, (states, per-aircraft
    extremes, counts, LoS pairs, records, return values))."""
    n_cases, n = states.shape[:2]
    out = states.copy()
    grad, command = np.zeros((n, n, 2)), np.zeros((n, N_COMMAND))
    extremes = np.zeros((n_cases, 3, n))
    counts = np.zeros((n_cases, 2, n), dtype=np.int64)
    los = np.zeros((n_cases, n, n), dtype=np.uint8)
    records = np.zeros((n_cases, n_record, n, N_RECORD))
    returned = np.zeros((n_cases, 3))
    start = time.perf_counter()
    for c in range(n_cases):
        returned[c] = flight(*extra, out[c], planned[c], winds[c, 0], winds[c, 1], n_steps, params, grad, command,
                             extremes[c, 0], extremes[c, 1], counts[c, 0], extremes[c, 2], counts[c, 1], los[c],
                             records[c], 1, True)
    return time.perf_counter() - start, (out, extremes, counts, los, records, returned)


def prediction_on_this_flight() -> type:
    """``PlanPredictor`` of a copy of ``shield_prediction`` compiled against a copy of the
    kernel module whose ``_advance_world`` is ``_advance_world_with_lanes``."""
    kernel_copy = types.ModuleType("kernel_with_lanes")
    kernel_copy.__dict__.update(vars(kernel))
    kernel_copy._advance_world = _advance_world_with_lanes
    spec = importlib.util.spec_from_file_location("shield_prediction_with_lanes", shield_prediction.__file__)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.kernel = kernel_copy  # read when the compiled functions are first called, not before
    from numba.core.caching import NullCache

    for value in vars(module).values():
        if hasattr(value, "py_func") and hasattr(value, "_cache"):
            # numba's cache keys a function on its file and name, not on its globals: a cached
            # ``_first_safe`` compiled against the kernel would be loaded instead.
            value._cache = NullCache()
    return module.PlanPredictor


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=8, help="episodes whose checks are recorded (part 1)")
    parser.add_argument("--ab-seeds", type=int, default=30, help="episodes per filter and scenario (part 2; 0: skip)")
    parser.add_argument("--scenarios", default="converging-6,random-6,converging-4")
    args = parser.parse_args(argv)
    scenarios = [s for s in args.scenarios.split(",") if s]
    for scenario in scenarios:
        states, planned, winds, params = recorded_checks(scenario, args.seeds)
        n_cases, n = states.shape[:2]
        buffers = (np.zeros((N_L, n)), np.zeros((N_Q, n)), np.zeros(n, dtype=np.int64))
        free = params.copy()
        free[nf.P_STOP_ON_VIOLATION] = 0.0
        same = True
        for flight_params in (params, free):
            for n_record in (0, 121):
                _, want = fly_all(kernel._advance_world, (), states, planned, winds, flight_params, 120, n_record)
                _, got = fly_all(_advance_world_persistent, buffers, states, planned, winds, flight_params, 120,
                                 n_record)
                same &= all(np.array_equal(a.view(np.uint8), b.view(np.uint8)) for a, b in zip(want, got))
        per_check = {False: [], True: []}
        for round_ in range(15):
            for lanes in ((False, True) if round_ % 2 else (True, False)):
                seconds, _ = fly_all(_advance_world_persistent if lanes else kernel._advance_world,
                                     buffers if lanes else (), states, planned, winds, params, 120, 0)
                if round_:
                    per_check[lanes].append(seconds / n_cases * 1e6)
        ratios = np.array(per_check[False]) / np.array(per_check[True])
        q25, q50, q75 = np.percentile(ratios, [25, 50, 75])
        print(f"{scenario}: {n_cases} checks of 120 steps; same bits: {same}; per check: kernel "
              f"{np.median(per_check[False]):.1f} µs, lanes kept between steps {np.median(per_check[True]):.1f} µs; "
              f"kernel / lanes {q50:.2f} [{q25:.2f}-{q75:.2f}]", flush=True)
        if not same:
            return 1
    if args.ab_seeds:
        from _alternating import fly_alternately  # bench/experiments/ is on sys.path when run as a script

        from atc_nf_env.policy import make_policy
        from atc_nf_env.shield import SafetyFilter

        predictor = prediction_on_this_flight()

        class FilterWithLanes(SafetyFilter):
            def reset(self, scenario, config, seed=None):
                super().reset(scenario, config, seed)
                shipped = self._predictor
                self._predictor = predictor(shipped.params, shipped.period_steps, shipped.lookahead_periods,
                                            *shipped._homing)

        agent = make_policy("agents/models/finetuned_ppo.zip")
        filters = {"shipped": SafetyFilter(agent), "lanes": FilterWithLanes(agent)}
        print(f"finetuned_ppo inside the filter as shipped and with its prediction on this flight, seeds "
              f"0..{args.ab_seeds - 1}, alternating episode by episode in one process:")
        for scenario in scenarios:
            print(f"  {scenario}: {fly_alternately(filters, scenario, args.ab_seeds)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
