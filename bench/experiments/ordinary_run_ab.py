"""The kernel's runs of ordinary steps (``kernel._ordinary_run``: one world's flying
aircraft kept in lanes from one ordinary step to the next) against the one-step form they
replaced (``_ordinary_step``, which read and wrote the state's rows at every step): the
same bits, and how much faster, per check and inside the safety filter?

A one-world flight (an env step, the safety filter's check and its alternatives) flies most
of its steps as ordinary steps: no neighbour within the sensing radius, no guard acting, no
arrival or departure within reach. Until this build the kernel flew each such step by
``_ordinary_step``, one aircraft after another (``one_world_aircraft_lanes.py`` moved that
step's arithmetic into lanes but copied the state in and out at every step, and gained
nothing). ``_ordinary_run`` keeps the flying aircraft in lanes for as many consecutive
ordinary steps as come, and writes the state back once. This script holds the one-step
form (copied from the kernel before) and compiles ``kernel._advance_world`` with it in
place of the run.

Part 1: the safety filter's checks of ``finetuned_ppo``'s proposals on seeds 0..SEEDS-1
(recorded in situ), each flown 120 steps both ways, with the envelope stop on and off and
with and without a record of every step: states, outcome arrays, records and return values
compared bit for bit; then both timed in alternating order over 15 rounds, the first
dropped (medians per check; quartiles of the per-round ratio).

Part 2: the filter as shipped against the filter with its prediction compiled on the
one-step form (a copy of ``shield_prediction`` bound to a copy of the kernel module),
around one agent, episode by episode in alternating order in one process
(``_alternating.fly_alternately``: it stops if they ever apply different waypoints).

Run: python bench/experiments/ordinary_run_ab.py [--seeds 8] [--ab-seeds 30]
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
    C_HEADING1,
    C_OMEGA,
    C_STEP_MAX,
    C_STEP_MIN,
    C_STEP_NM,
    C_THETA_NH,
    C_U,
    C_VIOLATED,
    C_VX,
    C_VY,
    C_X1,
    C_Y1,
    FLYING,
    N_AIRCRAFT_LANE,
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
)
from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _ordinary_step(
    state: np.ndarray,
    command: np.ndarray,
    wind_x: float,
    wind_y: float,
    params: np.ndarray,
    nf_consts: tuple,
    min_sep2: float,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
) -> tuple[bool, bool, float]:
    """The kernel's one-step form of an ordinary step, as it was before ``_ordinary_run``
    (its docstring there gives its contract)."""
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
    # No two flying aircraft within the sensing radius, in the NF's own arithmetic (its test
    # is symmetric in the pair: q_j − q_i is exactly −(q_i − q_j)).
    any_flying = False
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        any_flying = True
        xi = state[i, S_X] * inv_len
        yi = state[i, S_Y] * inv_len
        for j in range(i + 1, n):
            if state[j, S_STATUS] != FLYING:
                continue
            rx = xi - state[j, S_X] * inv_len
            ry = yi - state[j, S_Y] * inv_len
            if rx * rx + ry * ry < r_sense2:
                return False, False, min_sep2
    if not any_flying:
        return False, False, min_sep2
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        x0 = state[i, S_X]
        y0 = state[i, S_Y]
        wp_x = state[i, S_WP_X]
        wp_y = state[i, S_WP_Y]
        heading = state[i, S_HEADING]
        gx, gy, _, sgn_along = nf.own_gradient_alone(x0, y0, wp_x, wp_y, state[i, S_COS_D], state[i, S_SIN_D],
                                                     nf_consts)
        atan2_nh = trig.poly_atan2_inlined(sgn_along * gy, sgn_along * gx)
        sin_h, cos_h = trig.poly_sincos_inlined(heading)
        u, theta_nh = _lane_feedback(gx, gy, cos_h, sin_h, (x0 - wp_x) * inv_len, (y0 - wp_y) * inv_len, atan2_nh,
                                     state[i, S_THETA_D], params)
        if not -u_cap < u < u_cap:
            return False, False, min_sep2
        x1, y1, heading1, vx, vy, omega, far = _lane_move(
            u, cos_h, sin_h, wind_x, wind_y, x0, y0, heading, theta_nh, state[i, S_THETA_NH], state[i, S_FRESH],
            state[i, S_LAST_SUBSTEPS], state[i, S_VX_PREV], state[i, S_VY_PREV], state[i, S_OMEGA_PREV], dt, inv_dt,
            k_theta,
        )
        step_nm = math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
        ex = x1 - state[i, S_DEST_X]
        ey = y1 - state[i, S_DEST_Y]
        reach = delta + step_nm
        if far or ex * ex + ey * ey <= reach * reach or x1 * x1 + y1 * y1 >= exit_radius * exit_radius:
            return False, False, min_sep2
        command[i, C_X1] = x1
        command[i, C_Y1] = y1
        command[i, C_HEADING1] = heading1
        command[i, C_VX] = vx
        command[i, C_VY] = vy
        command[i, C_OMEGA] = omega
        command[i, C_U] = u
        command[i, C_THETA_NH] = theta_nh
        command[i, C_STEP_NM] = step_nm
    new_min_sep2 = min_sep2
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        for j in range(i + 1, n):
            if state[j, S_STATUS] != FLYING:
                continue
            sx = command[i, C_X1] - command[j, C_X1]
            sy = command[i, C_Y1] - command[j, C_Y1]
            sep2 = sx * sx + sy * sy
            if sep2 < sep_min * sep_min:
                return False, False, min_sep2
            new_min_sep2 = min(new_min_sep2, sep2)
    # Ordinary: the step as ``_advance_world`` writes it.
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    step_violation = False
    for i in range(n):
        command[i, C_VIOLATED] = 0.0
        if state[i, S_STATUS] != FLYING:
            command[i, C_FLEW] = 0.0
            continue
        u = command[i, C_U]
        state[i, S_VX_PREV] = command[i, C_VX]
        state[i, S_VY_PREV] = command[i, C_VY]
        state[i, S_OMEGA_PREV] = command[i, C_OMEGA]
        state[i, S_LAST_SUBSTEPS] = 1.0
        state[i, S_X] = command[i, C_X1]
        state[i, S_Y] = command[i, C_Y1]
        state[i, S_HEADING] = command[i, C_HEADING1]
        state[i, S_AIRSPEED] = u
        state[i, S_THETA_NH] = command[i, C_THETA_NH]
        state[i, S_FRESH] = 0.0
        state[i, S_TIME] += dt
        state[i, S_PATH] += command[i, C_STEP_NM]
        command[i, C_FLEW] = 1.0
        command[i, C_STEP_MIN] = u
        command[i, C_STEP_MAX] = u
        min_airspeed[i], max_airspeed[i], worst_excursion[i], excursion = _flown_airspeed(
            u, steps_flown[i] == 0, min_airspeed[i], max_airspeed[i], worst_excursion[i], u_min, u_max
        )
        if excursion > 0.0:
            step_violation = True
            violation_steps[i] += 1
            command[i, C_VIOLATED] = 1.0
        steps_flown[i] += 1
    return True, step_violation, new_min_sep2


# ``kernel._advance_world`` with the one-step form in place of its runs (same signature).
_source = inspect.getsource(kernel._advance_world.py_func)
_source = _source[_source.index("def _advance_world"):].replace("def _advance_world(", "def _advance_world_one_step(", 1)
_RUN = """            flew, step_violation, min_sep2, abandoned = _ordinary_run(
                state, command, aircraft_lanes, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed,
                max_airspeed, violation_steps, worst_excursion, steps_flown, n_steps - step, stop_on_violation,
                record, record_every, step,
            )
            step += flew
            if step_violation:
                violated = True
                if stop_on_violation:
                    break
            if not abandoned:
                continue  # every step asked for was ordinary
            # The step the run abandoned is flown below.
"""
if _RUN not in _source:
    raise SystemExit("kernel._advance_world changed: this experiment's substitution no longer applies")
_source = _source.replace(_RUN, """            flew, step_violation, min_sep2 = _ordinary_step(
                state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                violation_steps, worst_excursion, steps_flown,
            )
            if flew:
                step += 1
                _record_step(state, command, record, step, record_every)
                if step_violation:
                    violated = True
                    if stop_on_violation:
                        break
                continue
""")
_namespace = dict(vars(kernel))
_namespace["_ordinary_step"] = _ordinary_step
exec(_source, _namespace)  # noqa: S102 - the kernel's own loop, with the one-step form in place of the runs
_advance_world_one_step = njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)(
    _namespace["_advance_world_one_step"])


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


def fly_all(flight, states, planned, winds, params, n_steps, n_record):
    """Every case flown ``n_steps`` by ``flight``: (seconds, (states, per-aircraft
    extremes, counts, LoS pairs, records, return values))."""
    n_cases, n = states.shape[:2]
    out = states.copy()
    grad, command, lanes = np.zeros((n, n, 2)), np.zeros((n, N_COMMAND)), np.zeros((N_AIRCRAFT_LANE, n))
    extremes = np.zeros((n_cases, 3, n))
    counts = np.zeros((n_cases, 2, n), dtype=np.int64)
    los = np.zeros((n_cases, n, n), dtype=np.uint8)
    records = np.zeros((n_cases, n_record, n, N_RECORD))
    returned = np.zeros((n_cases, 3))
    start = time.perf_counter()
    for c in range(n_cases):
        returned[c] = flight(out[c], planned[c], winds[c, 0], winds[c, 1], n_steps, params, grad, command, lanes,
                             extremes[c, 0], extremes[c, 1], counts[c, 0], extremes[c, 2], counts[c, 1], los[c],
                             records[c], 1, True)
    return time.perf_counter() - start, (out, extremes, counts, los, records, returned)


def prediction_on_one_step_form() -> type:
    """``PlanPredictor`` of a copy of ``shield_prediction`` compiled against a copy of the
    kernel module whose ``_advance_world`` flies the one-step form."""
    from numba.core.caching import NullCache

    kernel_copy = types.ModuleType("kernel_one_step")
    kernel_copy.__dict__.update(vars(kernel))
    kernel_copy._advance_world = _advance_world_one_step
    spec = importlib.util.spec_from_file_location("shield_prediction_one_step", shield_prediction.__file__)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.kernel = kernel_copy  # read when the compiled functions are first called, not before
    for value in vars(module).values():
        if hasattr(value, "py_func") and hasattr(value, "_cache"):
            # numba's cache keys a function on its file and name, not on its globals: the
            # package's cached ``_first_safe`` would be loaded instead.
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
        n_cases = states.shape[0]
        free = params.copy()
        free[nf.P_STOP_ON_VIOLATION] = 0.0
        same = True
        for flight_params in (params, free):
            for n_record in (0, 121):
                _, want = fly_all(_advance_world_one_step, states, planned, winds, flight_params, 120, n_record)
                _, got = fly_all(kernel._advance_world, states, planned, winds, flight_params, 120, n_record)
                same &= all(np.array_equal(a.view(np.uint8), b.view(np.uint8)) for a, b in zip(want, got))
        per_check = {False: [], True: []}
        for round_ in range(15):
            for runs in ((False, True) if round_ % 2 else (True, False)):
                seconds, _ = fly_all(kernel._advance_world if runs else _advance_world_one_step, states, planned,
                                     winds, params, 120, 0)
                if round_:
                    per_check[runs].append(seconds / n_cases * 1e6)
        ratios = np.array(per_check[False]) / np.array(per_check[True])
        q25, q50, q75 = np.percentile(ratios, [25, 50, 75])
        print(f"{scenario}: {n_cases} checks of 120 steps; same bits: {same}; per check: one-step form "
              f"{np.median(per_check[False]):.1f} µs, the kernel's runs {np.median(per_check[True]):.1f} µs; "
              f"one-step / runs {q50:.2f} [{q25:.2f}-{q75:.2f}]", flush=True)
        if not same:
            return 1
    if args.ab_seeds:
        from _alternating import fly_alternately  # bench/experiments/ is on sys.path when run as a script

        from atc_nf_env.policy import make_policy
        from atc_nf_env.shield import SafetyFilter

        predictor = prediction_on_one_step_form()

        class OneStepFilter(SafetyFilter):
            def reset(self, scenario, config, seed=None):
                super().reset(scenario, config, seed)
                shipped = self._predictor
                self._predictor = predictor(shipped.params, shipped.period_steps, shipped.lookahead_periods,
                                            *shipped._homing)

        agent = make_policy("agents/models/finetuned_ppo.zip")
        filters = {"one-step": OneStepFilter(agent), "runs": SafetyFilter(agent)}
        print(f"finetuned_ppo inside the filter with its prediction on the one-step form and as shipped (runs), "
              f"seeds 0..{args.ab_seeds - 1}, alternating episode by episode in one process:")
        for scenario in scenarios:
            print(f"  {scenario}: {fly_alternately(filters, scenario, args.ab_seeds)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
