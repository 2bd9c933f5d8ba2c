"""One world's ordinary step with its aircraft in SIMD lanes, against the kernel's
``_ordinary_step``, side by side: the same bits, and how much faster?

A one-world flight (an env step, the safety filter's check and alternatives) flies most of
its steps by ``kernel._ordinary_step``, one aircraft after another. This experiment
copies each aircraft's fields into lanes (field-major, one lane per aircraft, padded with
idle lanes to ``PAD``), flies the lane step's select-only arithmetic over the lanes (the
kernel's lane path does the same over worlds), checks the pairs as ``_ordinary_step``
does and writes the step back; ``_advance_world`` is copied with that step in place of
``_ordinary_step``. The cases are the filter's checks of ``finetuned_ppo``'s proposals on
seeds 0..7 (two periods, 120 steps each); both flights run in alternating order over 15
rounds, the first dropped. Printed: the quartiles of the per-round ratio scalar / lanes,
the medians per flight, and whether every state, outcome array and return value is the
same bit for bit.

Not adopted: the copies in and out at every step and the pair loops leave little of what
the lanes save at 4 to 6 aircraft (see the README, "Safety filter"). The kernel now keeps
the aircraft in lanes from one ordinary step to the next (``kernel._ordinary_run``;
``ordinary_run_ab.py``), and no longer has the one-step form this script replaces: it runs
on the kernel of commit 9a8b1ef or earlier (``git checkout 9a8b1ef -- atc_nf_env``).

Run: python bench/experiments/one_world_aircraft_lanes.py [PAD] [scenario,...]
     (PAD 0: no padding, lanes = aircraft; default 8)
"""
import inspect
import math
import sys
import time

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
    N_COMMAND,
    N_LANE_TEMP,
    N_RECORD,
    N_STATE,
    P_DELTA,
    P_DT,
    P_K_THETA,
    P_LENGTH,
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
    T_ARG_X,
    T_COS,
    T_GX,
    T_GY,
    T_HEADING1,
    T_OMEGA,
    T_SIN,
    T_STEP_NM,
    T_THETA,
    T_U,
    T_VX,
    T_VY,
    T_X1,
    T_Y1,
    _flown_airspeed,
    _lane_feedback,
    _lane_move,
)
from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _ordinary_step_lanes(state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                         violation_steps, worst_excursion, steps_flown, lanes, temp):
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
    exit2 = exit_radius * exit_radius
    length = params[P_LENGTH]
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
    count = lanes.shape[1]
    for i in range(n):
        lanes[S_X, i] = state[i, S_X]
        lanes[S_Y, i] = state[i, S_Y]
        lanes[S_WP_X, i] = state[i, S_WP_X]
        lanes[S_WP_Y, i] = state[i, S_WP_Y]
        lanes[S_COS_D, i] = state[i, S_COS_D]
        lanes[S_SIN_D, i] = state[i, S_SIN_D]
        lanes[S_HEADING, i] = state[i, S_HEADING]
        lanes[S_THETA_D, i] = state[i, S_THETA_D]
        lanes[S_THETA_NH, i] = state[i, S_THETA_NH]
        lanes[S_FRESH, i] = state[i, S_FRESH]
        lanes[S_LAST_SUBSTEPS, i] = state[i, S_LAST_SUBSTEPS]
        lanes[S_VX_PREV, i] = state[i, S_VX_PREV]
        lanes[S_VY_PREV, i] = state[i, S_VY_PREV]
        lanes[S_OMEGA_PREV, i] = state[i, S_OMEGA_PREV]
        lanes[S_DEST_X, i] = state[i, S_DEST_X]
        lanes[S_DEST_Y, i] = state[i, S_DEST_Y]
        lanes[S_STATUS, i] = 1.0 if state[i, S_STATUS] == FLYING else 0.0
    for i in range(count):
        use = lanes[S_STATUS, i] != 0.0
        xb = lanes[S_X, i]; yb = lanes[S_Y, i]; wp_xb = lanes[S_WP_X, i]; wp_yb = lanes[S_WP_Y, i]
        cos_db = lanes[S_COS_D, i]; sin_db = lanes[S_SIN_D, i]
        gx, gy, _, sgn_along = nf.own_gradient_alone(
            xb if use else 0.0, yb if use else 0.0, wp_xb if use else length, wp_yb if use else 0.0,
            cos_db if use else 1.0, sin_db if use else 0.0, nf_consts,
        )
        temp[T_GX, i] = gx
        temp[T_GY, i] = gy
        temp[T_ARG_X, i] = sgn_along * gx
        temp[T_THETA, i] = sgn_along * gy
    for i in range(count):
        temp[T_THETA, i] = trig.poly_atan2_inlined(temp[T_THETA, i], temp[T_ARG_X, i])
    for i in range(count):
        temp[T_SIN, i], temp[T_COS, i] = trig.poly_sincos_inlined(lanes[S_HEADING, i])
    for i in range(count):
        c = temp[T_COS, i]
        sn = temp[T_SIN, i]
        x0 = lanes[S_X, i]
        y0 = lanes[S_Y, i]
        u, theta_nh = _lane_feedback(temp[T_GX, i], temp[T_GY, i], c, sn, (x0 - lanes[S_WP_X, i]) * inv_len,
                                     (y0 - lanes[S_WP_Y, i]) * inv_len, temp[T_THETA, i], lanes[S_THETA_D, i], params)
        saturated = not ((-u_cap < u) & (u < u_cap))
        x1, y1, heading1, vx, vy, omega, far = _lane_move(
            u, c, sn, wind_x, wind_y, x0, y0, lanes[S_HEADING, i], theta_nh, lanes[S_THETA_NH, i],
            lanes[S_FRESH, i], lanes[S_LAST_SUBSTEPS, i], lanes[S_VX_PREV, i], lanes[S_VY_PREV, i],
            lanes[S_OMEGA_PREV, i], dt, inv_dt, k_theta)
        step_nm = math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
        ex = x1 - lanes[S_DEST_X, i]
        ey = y1 - lanes[S_DEST_Y, i]
        reach = delta + step_nm
        unusual = saturated | far | (ex * ex + ey * ey <= reach * reach) | (x1 * x1 + y1 * y1 >= exit2)
        temp[T_ARG_X, i] = 1.0 if unusual else 0.0
        temp[T_X1, i] = x1
        temp[T_Y1, i] = y1
        temp[T_HEADING1, i] = heading1
        temp[T_VX, i] = vx
        temp[T_VY, i] = vy
        temp[T_OMEGA, i] = omega
        temp[T_U, i] = u
        temp[T_THETA, i] = theta_nh
        temp[T_STEP_NM, i] = step_nm
    for i in range(n):
        if state[i, S_STATUS] == FLYING and temp[T_ARG_X, i] != 0.0:
            return False, False, min_sep2
    new_min_sep2 = min_sep2
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        for j in range(i + 1, n):
            if state[j, S_STATUS] != FLYING:
                continue
            sx = temp[T_X1, i] - temp[T_X1, j]
            sy = temp[T_Y1, i] - temp[T_Y1, j]
            sep2 = sx * sx + sy * sy
            if sep2 < sep_min * sep_min:
                return False, False, min_sep2
            new_min_sep2 = min(new_min_sep2, sep2)
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    step_violation = False
    for i in range(n):
        command[i, C_VIOLATED] = 0.0
        if state[i, S_STATUS] != FLYING:
            command[i, C_FLEW] = 0.0
            continue
        u = temp[T_U, i]
        command[i, C_X1] = temp[T_X1, i]
        command[i, C_Y1] = temp[T_Y1, i]
        command[i, C_HEADING1] = temp[T_HEADING1, i]
        command[i, C_VX] = temp[T_VX, i]
        command[i, C_VY] = temp[T_VY, i]
        command[i, C_OMEGA] = temp[T_OMEGA, i]
        command[i, C_U] = u
        command[i, C_THETA_NH] = temp[T_THETA, i]
        command[i, C_STEP_NM] = temp[T_STEP_NM, i]
        state[i, S_VX_PREV] = temp[T_VX, i]
        state[i, S_VY_PREV] = temp[T_VY, i]
        state[i, S_OMEGA_PREV] = temp[T_OMEGA, i]
        state[i, S_LAST_SUBSTEPS] = 1.0
        state[i, S_X] = temp[T_X1, i]
        state[i, S_Y] = temp[T_Y1, i]
        state[i, S_HEADING] = temp[T_HEADING1, i]
        state[i, S_AIRSPEED] = u
        state[i, S_THETA_NH] = temp[T_THETA, i]
        state[i, S_FRESH] = 0.0
        state[i, S_TIME] += dt
        state[i, S_PATH] += temp[T_STEP_NM, i]
        command[i, C_FLEW] = 1.0
        command[i, C_STEP_MIN] = u
        command[i, C_STEP_MAX] = u
        min_airspeed[i], max_airspeed[i], worst_excursion[i], excursion = _flown_airspeed(
            u, steps_flown[i] == 0, min_airspeed[i], max_airspeed[i], worst_excursion[i], u_min, u_max)
        if excursion > 0.0:
            step_violation = True
            violation_steps[i] += 1
            command[i, C_VIOLATED] = 1.0
        steps_flown[i] += 1
    return True, step_violation, new_min_sep2

# _advance_world with the lane ordinary step
_src = inspect.getsource(kernel._advance_world.py_func)
_src = _src[_src.index("def _advance_world"):]
_src = _src.replace("def _advance_world(", "def _advance_world_lanes(lanes, temp, ", 1)
_src = _src.replace("""_ordinary_step(
                state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                violation_steps, worst_excursion, steps_flown,
            )""", """_ordinary_step_lanes(
                state, command, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed, max_airspeed,
                violation_steps, worst_excursion, steps_flown, lanes, temp,
            )""")
if "_ordinary_step_lanes(" not in _src:
    raise SystemExit("this kernel flies runs of ordinary steps, not the one-step form this experiment replaces: "
                     "run it on the kernel of commit 9a8b1ef or earlier (see its docstring)")
ns = dict(vars(kernel)); ns["_ordinary_step_lanes"] = _ordinary_step_lanes
exec(_src, ns)  # noqa: S102 - the kernel's own loop, with the lane step in place of its ordinary step
_advance_world_lanes = njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)(ns["_advance_world_lanes"])

@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def fly_many(states, wps, winds, n_steps, params, use_lanes, lanes, temp, out, grad, command, per, cnt, los, rec, outcome):
    for c in range(states.shape[0]):
        state = out[c]
        n = state.shape[0]
        for i in range(n):
            for f in range(N_STATE):
                state[i, f] = states[c, i, f]
        if use_lanes:
            r = _advance_world_lanes(lanes, temp, state, wps[c], winds[c, 0], winds[c, 1], n_steps, params, grad, command,
                                     per[c, 0], per[c, 1], cnt[c, 0], per[c, 2], cnt[c, 1], los[c], rec, 1, True)
        else:
            r = kernel._advance_world(state, wps[c], winds[c, 0], winds[c, 1], n_steps, params, grad, command,
                                      per[c, 0], per[c, 1], cnt[c, 0], per[c, 2], cnt[c, 1], los[c], rec, 1, True)
        outcome[c, 0] = r[0]; outcome[c, 1] = r[1]; outcome[c, 2] = r[2]

def main():
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter
    cases = []
    screen = shield_prediction.PlanPredictor.screen
    def tscreen(self, state, proposal, time_s, period_s, memory, stall):
        cases.append((self, state.copy(), proposal.copy(), memory.wind_kt.copy()))
        return screen(self, state, proposal, time_s, period_s, memory, stall)
    shield_prediction.PlanPredictor.screen = tscreen
    pad = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    for scen in sys.argv[2].split(",") if len(sys.argv) > 2 else ["converging-6", "random-6", "converging-4"]:
        cases.clear()
        f = SafetyFilter(make_policy("agents/models/finetuned_ppo.zip"))
        for s in range(8):
            run_episode(f, make_scenario(scen, seed=s), seed=s)
        pred = cases[0][0]
        params = pred.params
        states = np.stack([c[1] for c in cases]); wps = np.stack([c[2] for c in cases]); winds = np.stack([c[3] for c in cases])
        # proposals for non flying: current waypoints
        nfly = states[:, :, S_STATUS] != FLYING
        wps[nfly] = states[nfly][:, S_WP_X:S_WP_Y + 1]
        C, n = states.shape[:2]
        count = max(pad * math.ceil(n / pad), n) if pad else n
        lanes = np.zeros((N_STATE, count)); temp = np.zeros((N_LANE_TEMP, count))
        for b in range(count):
            lanes[:, b] = states[0, 0]; lanes[S_STATUS, b] = 0.0
        results = {}  # the last round's flights: states, outcome arrays, return values
        per_flight = {False: [], True: []}  # µs per flight, by round (the first dropped)
        for rnd in range(15):
            for use in ((False, True) if rnd % 2 else (True, False)):
                out = np.zeros_like(states); grad = np.zeros((n, n, 2)); command = np.zeros((n, N_COMMAND))
                per = np.zeros((C, 3, n)); cnt = np.zeros((C, 2, n), dtype=np.int64); los = np.zeros((C, n, n), dtype=np.uint8)
                rec = np.zeros((0, n, N_RECORD)); outcome = np.zeros((C, 3))
                t0 = time.perf_counter()
                fly_many(states, wps, winds, 120, params, use, lanes, temp, out, grad, command, per, cnt, los, rec, outcome)
                elapsed = time.perf_counter() - t0
                results[use] = (out, per, cnt, outcome)
                if rnd > 0:
                    per_flight[use].append(elapsed / C * 1e6)
        ratios = np.array(per_flight[False]) / np.array(per_flight[True])
        print("ratio quartiles", np.percentile(ratios, [25, 50, 75]).round(3))
        same = all(np.array_equal(a.view(np.uint8), b.view(np.uint8)) for a, b in zip(results[False], results[True]))
        scalar, lanes_us = np.median(per_flight[False]), np.median(per_flight[True])
        print(f"{scen} pad={pad} count={count}: cases {C}, per 120-step flight: scalar {scalar:.1f} µs, lanes "
              f"{lanes_us:.1f} µs, ratio {scalar / lanes_us:.2f}; same bits: {same}")

if __name__ == "__main__":
    main()
