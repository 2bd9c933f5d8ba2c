"""A probe for the kernel's next layout in traffic: ordinary integration steps of worlds
whose aircraft do feel their neighbours, flown as structure of arrays, against the kernel.

``bench/soa_step_probe.py`` flies the ordinary step of aircraft far apart. Here the NF has
its neighbours: the proximity product G_i and its gradients with respect to every
neighbour (``nf.nf_along_direction``'s two passes), ∂Φ_i/∂t from the neighbours' feedback
airspeeds (the kernel's pass 2), and the 1/P_i term of (5a). The worlds are random-N
encounters flown by the NF alone to ``--start-min`` minutes, where aircraft cross; of them,
the probe keeps the worlds whose next period the kernel flies with no refined step (guard
8), no right-hand rule (guard 9) and no arrival or departure, which is what "ordinary"
means here. Every branch of the law is a select; atan2 and sincos are scalar loops; the
per-aircraft loops over worlds are ``prange`` loops (see ``soa_step_probe``). The final
states must equal the kernel's bit for bit (checked). Reported: ns per aircraft-step on one
thread, both timed alternately in rounds, medians, and their ratio, with the share of
aircraft-steps that had a neighbour within the sensing radius.

Run: python bench/soa_dense_probe.py [--rounds 21] [--write]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numba
import numpy as np
from _report import machine, publish  # bench/ is on sys.path when run as a script
from numba import njit, prange
from soa_step_probe import (
    AIRSPEED,
    COS_D,
    FRESH,
    HEADING,
    LAST_SUB,
    OMEGA_PREV,
    PATH,
    SIN_D,
    THETA_D,
    THETA_NH,
    TIME,
    VX_PREV,
    VY_PREV,
    WP_X,
    WP_Y,
    X,
    Y,
    feedback,
    move,
    own_gradient,
    to_fields,
)

from atc_nf_env import kernel, nf
from atc_nf_env.config import SimConfig
from atc_nf_env.nf import FAST_MATH_FLAGS
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state
from atc_nf_env.units import DECISION_PERIOD_S


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def _bump(sv: float, c_bar: float) -> tuple[float, float]:
    """``nf.proximity_bump`` as selects (both of its early returns computed, one kept)."""
    inv = 1.0 / (sv + c_bar)
    w = (1.0 + c_bar) * sv * inv
    dw = (1.0 + c_bar) * c_bar * inv * inv
    h = 1.0 if sv >= 1.0 else (0.0 if sv <= 0.0 else w * (2.0 - w))
    dh = 0.0 if sv >= 1.0 else (0.0 if sv <= 0.0 else 2.0 * (1.0 - w) * dw)
    return h, dh


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", parallel=True)
def fly(s: np.ndarray, wind: np.ndarray, params: np.ndarray, n_steps: int, per_aircraft: np.ndarray,
        pairs: np.ndarray) -> tuple[int, int]:
    """Fly ``s`` (F, N, B) for ``n_steps`` ordinary steps with neighbours; ``wind`` (2, B)
    kt; scratch ``per_aircraft`` (10, N, B) and ``pairs`` (2, N, N, B), the gradients of
    Φ_i with respect to each neighbour j. Returns (steps that were not ordinary: a
    saturated command, the watch or the right-hand rule, which the kernel flies otherwise;
    aircraft-steps with a neighbour in range)."""
    # k = 2 (the default) is assumed, as in ``own_gradient``.
    consts = nf.nf_constants(params)
    inv_len, _, _, _, contact2, inv_beta_s, c_bar, r_sense2, _, _, _ = consts
    u_cap, gain, substep_from = params[nf.P_U_CAP], params[nf.P_DPHI_DT_GAIN], params[nf.P_SUBSTEP_FROM]
    turn_angle, turn_from = params[nf.P_RIGHT_TURN], params[nf.P_RIGHT_TURN_FROM]
    dt = params[nf.P_DT]
    n, b_count = s.shape[1], s.shape[2]
    cos_h, sin_h, gix, giy, theta_nh_of, u_fb, p_of, near_of, arg_y, arg_x = (
        per_aircraft[0], per_aircraft[1], per_aircraft[2], per_aircraft[3], per_aircraft[4], per_aircraft[5],
        per_aircraft[6], per_aircraft[7], per_aircraft[8], per_aircraft[9])
    gjx_of, gjy_of = pairs[0], pairs[1]
    unusual = 0
    near_steps = 0
    for i in range(n):
        for b in range(b_count):
            cos_h[i, b] = math.cos(s[HEADING, i, b])
            sin_h[i, b] = math.sin(s[HEADING, i, b])
    for _ in range(n_steps):
        # Pass 1: every aircraft's NF, gradients and feedback command from the positions at
        # the step's start (nf.nf_along_direction's two passes over the neighbours).
        for i in range(n):
            for b in prange(b_count):
                xi = s[X, i, b] * inv_len
                yi = s[Y, i, b] * inv_len
                g = 1.0
                near = 0.0
                for j in range(n):
                    rx = xi - s[X, j, b] * inv_len
                    ry = yi - s[Y, j, b] * inv_len
                    dist2 = rx * rx + ry * ry
                    in_range = (j != i) & (dist2 < r_sense2)
                    h, dh = _bump((dist2 - contact2) * inv_beta_s, c_bar)
                    g = g * h if in_range else g
                    near += 1.0 if in_range else 0.0
                    # h_j and h'_j kept for the second pass, as the NF keeps them.
                    gjx_of[i, j, b] = h if in_range else 0.0
                    gjy_of[i, j, b] = dh if in_range else 0.0
                second = (near > 0.0) & (g > 0.0)
                grad_gx = 0.0
                grad_gy = 0.0
                for j in range(n):
                    h = gjx_of[i, j, b]
                    dh = gjy_of[i, j, b]
                    rx = xi - s[X, j, b] * inv_len
                    ry = yi - s[Y, j, b] * inv_len
                    use = second & (h != 0.0)
                    others = g / (h if h != 0.0 else 1.0)
                    ox = -2.0 * rx * inv_beta_s * dh * others
                    oy = -2.0 * ry * inv_beta_s * dh * others
                    ox = ox if use else 0.0
                    oy = oy if use else 0.0
                    gjx_of[i, j, b] = ox
                    gjy_of[i, j, b] = oy
                    grad_gx -= ox
                    grad_gy -= oy
                gx, gy, coef_g, sgn_along = own_gradient(s[X, i, b], s[Y, i, b], s[WP_X, i, b], s[WP_Y, i, b],
                                                         s[COS_D, i, b], s[SIN_D, i, b], g, grad_gx, grad_gy, consts)
                for j in range(n):
                    ox = gjx_of[i, j, b]
                    oy = gjy_of[i, j, b]
                    gjx_of[i, j, b] = ox * coef_g if near > 0.0 else ox
                    gjy_of[i, j, b] = oy * coef_g if near > 0.0 else oy
                gix[i, b] = gx
                giy[i, b] = gy
                near_of[i, b] = near
                arg_y[i, b] = sgn_along * gy
                arg_x[i, b] = sgn_along * gx
            for b in range(b_count):
                theta_nh_of[i, b] = math.atan2(arg_y[i, b], arg_x[i, b])
            for b in prange(b_count):
                u, p, theta_nh = feedback(gix[i, b], giy[i, b], cos_h[i, b], sin_h[i, b], s[X, i, b], s[Y, i, b],
                                          s[WP_X, i, b], s[WP_Y, i, b], theta_nh_of[i, b], s[THETA_D, i, b], params)
                u_fb[i, b] = u
                p_of[i, b] = p
                theta_nh_of[i, b] = theta_nh
        # Pass 2 and 3: ∂Φ_i/∂t from the neighbours' feedback airspeeds, the command, the move.
        for i in range(n):
            for b in prange(b_count):
                near = near_of[i, b]
                dphi_dt = 0.0
                for j in range(n):
                    along = gjx_of[i, j, b] * cos_h[j, b] + gjy_of[i, j, b] * sin_h[j, b]
                    term = u_fb[j, b] * along
                    dphi_dt += term if (near > 0.0) & (j != i) else 0.0
                dphi_dt *= gain
                p = p_of[i, b]
                turning = (turn_angle > 0.0) & (dphi_dt > 0.0) & (dphi_dt / abs(p) > turn_from)
                watched = dphi_dt > substep_from * abs(p)
                u_feedback = u_fb[i, b]
                u_law = u_feedback - (dphi_dt + abs(dphi_dt)) / (2.0 * p)
                u = u_law if dphi_dt > 0.0 else u_feedback
                saturated = not ((u > -u_cap) & (u < u_cap))
                unusual += 1 if turning | watched | saturated else 0
                near_steps += 1 if near > 0.0 else 0
                u = min(max(u, -u_cap), u_cap)
                theta_nh = theta_nh_of[i, b]
                x1, y1, heading, vx, vy, omega, far = move(
                    u, cos_h[i, b], sin_h[i, b], wind[0, b], wind[1, b], s[X, i, b], s[Y, i, b], s[HEADING, i, b],
                    theta_nh, s[THETA_NH, i, b], s[FRESH, i, b], s[LAST_SUB, i, b], s[VX_PREV, i, b],
                    s[VY_PREV, i, b], s[OMEGA_PREV, i, b], params,
                )
                unusual += 1 if far else 0
                # Positions and headings are written after every aircraft's pass 2: a later
                # aircraft's pass 2 reads the positions of the step's start.
                arg_x[i, b] = x1
                arg_y[i, b] = y1
                gix[i, b] = heading
                giy[i, b] = u
                s[VX_PREV, i, b] = vx
                s[VY_PREV, i, b] = vy
                s[OMEGA_PREV, i, b] = omega
                s[THETA_NH, i, b] = theta_nh
        for i in range(n):
            for b in prange(b_count):
                x0 = s[X, i, b]
                y0 = s[Y, i, b]
                x1 = arg_x[i, b]
                y1 = arg_y[i, b]
                s[X, i, b] = x1
                s[Y, i, b] = y1
                s[HEADING, i, b] = gix[i, b]
                s[AIRSPEED, i, b] = giy[i, b]
                s[LAST_SUB, i, b] = 1.0
                s[FRESH, i, b] = 0.0
                s[TIME, i, b] += dt
                s[PATH, i, b] += math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
            for b in range(b_count):
                cos_h[i, b] = math.cos(s[HEADING, i, b])
                sin_h[i, b] = math.sin(s[HEADING, i, b])
    return unusual, near_steps


def ordinary_worlds(scenario_name: str, n_worlds: int, start_min: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States (B', N, N_STATE) of random-N worlds (seeds 0..n_worlds-1) flown by the NF alone
    to ``start_min`` minutes, their waypoints and winds, keeping only the worlds whose next
    period the kernel flies with every step ordinary (no sub-steps, all aircraft flying)."""
    config = SimConfig()
    states, winds = [], []
    rng = np.random.default_rng(7)
    for seed in range(n_worlds):
        scenario = make_scenario(scenario_name, seed=seed)
        state = initial_state(scenario, 1)
        wind = rng.normal(0.0, 10.0, (1, 2))
        params = config.to_params(scenario.workspace_radius_nm)
        kernel.advance(state, state[:, :, kernel.S_WP_X: kernel.S_WP_Y + 1].copy(), wind, start_min * 60.0, params)
        states.append(state[0])
        winds.append(wind[0])
    state, wind = np.stack(states), np.stack(winds)
    waypoints = np.ascontiguousarray(state[:, :, kernel.S_WP_X: kernel.S_WP_Y + 1])
    params = config.to_params(make_scenario(scenario_name, seed=0).workspace_radius_nm)
    flown = state.copy()
    ordinary = (flown[:, :, kernel.S_STATUS] == kernel.FLYING).all(axis=1)
    for _ in range(kernel.steps_for(DECISION_PERIOD_S, config.dt_s)):
        kernel.advance(flown, waypoints, wind, config.dt_s, params)
        ordinary &= (flown[:, :, kernel.S_LAST_SUBSTEPS] <= 1.0).all(axis=1)
        ordinary &= (flown[:, :, kernel.S_STATUS] == kernel.FLYING).all(axis=1)
    return state[ordinary], waypoints[ordinary], wind[ordinary]


def measure(scenario_name: str, n_worlds: int, start_min: float, rounds: int) -> dict[str, float]:
    """Both flights checked equal on the ordinary worlds, then timed on one thread."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return _measure(scenario_name, n_worlds, start_min, rounds)
    finally:
        numba.set_num_threads(threads)


def _measure(scenario_name: str, n_worlds: int, start_min: float, rounds: int) -> dict[str, float]:
    config = SimConfig()
    state, waypoints, wind = ordinary_worlds(scenario_name, n_worlds, start_min)
    params = config.to_params(make_scenario(scenario_name, seed=0).workspace_radius_nm)
    n_steps = kernel.steps_for(DECISION_PERIOD_S, config.dt_s)
    b, n = state.shape[0], state.shape[1]
    if b == 0:
        raise RuntimeError("no world flies an ordinary period from there: choose another start")
    flown = state.copy()
    kernel.advance(flown, waypoints, wind, DECISION_PERIOD_S, params)
    wind_t = np.ascontiguousarray(wind.T)
    per_aircraft, pairs = np.empty((10, n, b)), np.empty((2, n, n, b))
    probe = to_fields(state)
    unusual, near_steps = fly(probe, wind_t, params, n_steps, per_aircraft, pairs)
    if unusual:
        raise RuntimeError(f"{unusual} steps of the probe were not ordinary where the kernel's were")
    if not np.array_equal(probe, to_fields(flown)):
        bad = int((probe != to_fields(flown)).sum())
        raise RuntimeError(f"the probe's flight differs from the kernel's in {bad} values: it would time other arithmetic")
    times: dict[str, list[float]] = {"kernel": [], "probe": []}
    steps = b * n * n_steps
    scratch = kernel.KernelScratch()
    for r in range(rounds):
        for name in (("kernel", "probe") if r % 2 == 0 else ("probe", "kernel")):
            if name == "kernel":
                again = state.copy()
                t0 = time.perf_counter()
                kernel.advance(again, waypoints, wind, DECISION_PERIOD_S, params, scratch=scratch)
            else:
                fields = to_fields(state)
                t0 = time.perf_counter()
                fly(fields, wind_t, params, n_steps, per_aircraft, pairs)
            times[name].append((time.perf_counter() - t0) / steps * 1e9)
    k, p = statistics.median(times["kernel"]), statistics.median(times["probe"])
    return {"kernel": k, "probe": p, "ratio": k / p, "worlds": b, "near": near_steps / steps}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=21)
    parser.add_argument("--worlds", type=int, default=2000, help="random-N seeds flown (default 2000)")
    parser.add_argument("--start-min", type=float, default=30.0, help="minutes flown before the probed period")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.worlds < 1 or not 0.0 < args.start_min <= 120.0:
        parser.error("--rounds and --worlds must be >= 1, --start-min in (0, 120]")
    rows = ["| scenario | ordinary worlds | aircraft-steps with a neighbour in range | kernel (ns per aircraft-step) "
            "| structure of arrays (ns) | ratio |", "|---|---:|---:|---:|---:|---:|"]
    ratios = []
    for scenario in ("random-4", "random-6"):
        r = measure(scenario, args.worlds, args.start_min, args.rounds)
        ratios.append(r["ratio"])
        rows.append(f"| {scenario} | {r['worlds']} of {args.worlds} | {r['near']:.1%} | {r['kernel']:.1f} | "
                    f"{r['probe']:.1f} | {r['ratio']:.2f}× |")
        print(rows[-1], flush=True)
    text = "\n".join([
        "## A probe for the kernel's layout: ordinary steps in traffic",
        "",
        f"`python bench/soa_dense_probe.py --rounds {args.rounds} --worlds {args.worlds} --start-min "
        f"{args.start_min:g}` — {machine()}, numba {numba.__version__}, one thread. Seeds 0..{args.worlds - 1} of "
        f"random-N flown by the NF alone for {args.start_min:g} min, then the next period of the worlds the "
        "kernel flies with every step ordinary (no sub-step, no right-hand rule, no arrival), by "
        "`kernel.advance` and in structure of arrays with the NF's neighbour terms, ∂Φ_i/∂t and every branch "
        "as a select; the final states are the kernel's bit for bit (checked before timing). ns per "
        "aircraft-step, medians over rounds timed alternately:",
        "",
        *rows,
        "",
        f"Here the layout flew {min(ratios):.2f}–{max(ratios):.2f}× as fast as the kernel. Written without "
        "branches, it evaluates the proximity bump (two divisions) for every pair of every world at every "
        "step, where the kernel's per-world loop skips the pairs beyond the sensing radius: nearly all of "
        "them in this traffic. The aircraft-steps without a neighbour, which `soa_step_probe.py` flies "
        "faster than the kernel, pay for the pairs here. A kernel in this layout would have to skip the pairs of a "
        "block of worlds together where none of the block is in range.",
    ])
    return publish("soa-dense-probe", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
