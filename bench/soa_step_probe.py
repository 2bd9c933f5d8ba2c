"""A probe for the kernel's next layout, end to end: whole integration steps of worlds whose
aircraft have no neighbour in range, flown as structure of arrays, against the kernel.

``bench/layout_probe.py`` times the NF's proximity core alone. This probe flies the whole
law of the kernel's ordinary step (guards 1-5: the NF without neighbours, the commands
(5a)-(5b), the AB2/Euler move, the heading wrap, θ_nh and its rate) for B worlds of
converging-N over its first period, where every aircraft is far from every other (no
neighbour within the sensing radius, no refined step, no arrival: checked), with the loop
over worlds innermost and the branches of the law written as selects, so that LLVM can fly
several worlds per instruction; atan2 and sincos stay scalar calls in loops of their own
(no vector form is bit for bit the scalar one). The final states must equal the kernel's
bit for bit (checked). Reported: ns per aircraft-step on one thread, both timed alternately
in rounds, medians, and their ratio.

What vectorizes: the NF's loop (packed square root and division in the machine code), and
the loop of the commands and the move only as a ``prange`` loop. As a plain loop it reads
and writes a dozen fields of the state, and LLVM's loop vectorizer gives up on the runtime
checks that the fields do not overlap (its remark with llvmlite's
``-pass-remarks-missed=loop-vectorize``: "too many memory checks needed"); numba compiles
a ``prange`` loop's body into a kernel of its own whose arrays LLVM may take as distinct.
The probe runs on one thread: the gain is the vector lanes', not the threads'.

It is not a kernel: neighbours, the right-hand rule, sub-steps, arrivals, departures,
records and the envelope's bookkeeping are left out, and the kernel's entry checks and
``Trace`` are not paid. It measures what the layout gains on the arithmetic of an ordinary
step, which is most of what the MPC's candidates and the vector envs fly.

Run: python bench/soa_step_probe.py [--rounds 21] [--write]
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
from bench_kernel import Case
from numba import njit, prange

from atc_nf_env import kernel, nf
from atc_nf_env.nf import FAST_MATH_FLAGS
from atc_nf_env.units import DECISION_PERIOD_S, SECONDS_PER_HOUR

#: The state fields the probe flies, in the order of its (F, N, B) array.
FIELDS = (kernel.S_X, kernel.S_Y, kernel.S_HEADING, kernel.S_AIRSPEED, kernel.S_THETA_NH, kernel.S_WP_X,
          kernel.S_WP_Y, kernel.S_THETA_D, kernel.S_COS_D, kernel.S_SIN_D, kernel.S_FRESH, kernel.S_VX_PREV,
          kernel.S_VY_PREV, kernel.S_OMEGA_PREV, kernel.S_LAST_SUBSTEPS, kernel.S_TIME, kernel.S_PATH)
(X, Y, HEADING, AIRSPEED, THETA_NH, WP_X, WP_Y, THETA_D, COS_D, SIN_D, FRESH, VX_PREV, VY_PREV, OMEGA_PREV,
 LAST_SUB, TIME, PATH) = range(len(FIELDS))
_PI = math.pi
_TWO_PI = 2.0 * math.pi


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def _wrap(angle: float) -> float:
    """``kernel._wrap`` for |angle| < 3π (its first two cases, as a select); the kernel's
    third case, a floor, is for angles an ordinary step never makes (``fly`` counts them)."""
    near = angle - _TWO_PI if angle >= _PI else angle + _TWO_PI
    # & instead of a chained comparison: ``and`` short-circuits, a branch the vectorizer cannot take.
    return angle if (angle >= -_PI) & (angle < _PI) else near


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def own_gradient(x: float, y: float, wp_x: float, wp_y: float, ed_x: float, ed_y: float, g: float,
                 grad_gx: float, grad_gy: float, consts: tuple) -> tuple[float, float, float, float]:
    """∇_iΦ_i of ``nf.nf_along_direction`` for k = 2 from the aircraft's position, waypoint
    and θ_d's unit vector (nm), its G_i and ∇_iG_i (in units of L): (gx, gy, coef_g, the sign
    of the aircraft's side of the dipole axis), its arithmetic operation for operation."""
    inv_len, _, inv_k, beta0_max, _, _, _, _, eps_nh, a0, x_cut = consts
    xi = x * inv_len
    yi = y * inv_len
    dx = (x - wp_x) * inv_len
    dy = (y - wp_y) * inv_len
    gamma = dx * dx + dy * dy
    p_axis = ed_x * dx + ed_y * dy
    h_nh = eps_nh + p_axis * p_axis
    beta0 = beta0_max - (xi * xi + yi * yi)
    g_rel = g / x_cut
    f_in = a0 * (1.0 - 3.0 * g_rel * g_rel + 2.0 * g_rel * g_rel * g_rel)
    df_in = a0 * (-6.0 * g_rel + 6.0 * g_rel * g_rel) / x_cut
    f = f_in if g < x_cut else 0.0
    df = df_in if g < x_cut else 0.0
    a = gamma + f
    m = h_nh * g * beta0
    d = a * a + m
    d_root = math.sqrt(d)
    scale = 1.0 / (d_root * d)
    a_over_k = a * inv_k
    coef_g = scale * (m * df - a_over_k * h_nh * beta0)
    coef_gamma = scale * m
    coef_h = -scale * a_over_k * g * beta0
    coef_beta0 = -scale * a_over_k * h_nh * g
    gx = coef_gamma * 2.0 * dx + coef_h * 2.0 * p_axis * ed_x + coef_beta0 * (-2.0 * xi) + coef_g * grad_gx
    gy = coef_gamma * 2.0 * dy + coef_h * 2.0 * p_axis * ed_y + coef_beta0 * (-2.0 * yi) + coef_g * grad_gy
    sgn_along = 1.0 if ed_x * dx + ed_y * dy >= 0.0 else -1.0
    return gx, gy, coef_g, sgn_along


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def feedback(gx: float, gy: float, cos_h: float, sin_h: float, x: float, y: float, wp_x: float, wp_y: float,
             atan2_nh: float, theta_d: float, params: np.ndarray) -> tuple[float, float, float]:
    """The kernel's pass 1 after the NF: (−sgn(P_i) F_i kt, P_i floored, θ_nh rad), with θ_d
    where the gradient has no direction (guard 3)."""
    inv_len = 1.0 / params[nf.P_LENGTH]
    grad_floor = params[nf.P_GRAD_FLOOR]
    p_dir = cos_h * gx + sin_h * gy
    dx = (x - wp_x) * inv_len
    dy = (y - wp_y) * inv_len
    grad_norm2 = gx * gx + gy * gy
    f_speed = params[nf.P_K_U] * grad_norm2 + params[nf.P_K_Z] * (dx * dx + dy * dy)
    sgn_p = 1.0 if p_dir >= 0.0 else -1.0
    theta_nh = atan2_nh if grad_norm2 > grad_floor * grad_floor else theta_d
    return -sgn_p * f_speed, sgn_p * max(abs(p_dir), params[nf.P_P_FLOOR]), theta_nh


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def move(u: float, cos_h: float, sin_h: float, wind_x: float, wind_y: float, x0: float, y0: float,
         heading: float, theta_nh: float, theta_nh_before: float, fresh: float, last_sub: float, vx_prev: float,
         vy_prev: float, omega_prev: float, params: np.ndarray) -> tuple[float, float, float, float, float, float, bool]:
    """The kernel's heading law (5b) and move of an ordinary step (AB2, or Euler after a
    waypoint switch or a refined step), every branch a select: (x1, y1 nm, the wrapped
    heading rad, vx, vy kt, ω rad/s, whether an angle reached 3π, where ``_wrap`` is not the
    kernel's)."""
    dt = params[nf.P_DT]
    nm_per_kt_step = dt / SECONDS_PER_HOUR
    jump_raw = theta_nh - theta_nh_before
    error_raw = heading - theta_nh
    jump = _wrap(jump_raw)
    rate = jump * (max(last_sub, 1.0) * (1.0 / dt))
    theta_nh_rate = 0.0 if (fresh != 0.0) | (abs(jump) > 0.5 * _PI) else rate
    omega = -params[nf.P_K_THETA] * _wrap(error_raw) + theta_nh_rate
    vx = u * cos_h + wind_x
    vy = u * sin_h + wind_y
    ab2 = (fresh == 0.0) & (last_sub <= 1.0)
    x_ab2 = x0 + (1.5 * vx - 0.5 * vx_prev) * nm_per_kt_step
    y_ab2 = y0 + (1.5 * vy - 0.5 * vy_prev) * nm_per_kt_step
    h_ab2 = heading + (1.5 * omega - 0.5 * omega_prev) * dt
    x_euler = x0 + vx * nm_per_kt_step
    y_euler = y0 + vy * nm_per_kt_step
    h_euler = heading + omega * dt
    new_heading = h_ab2 if ab2 else h_euler
    far = max(abs(jump_raw), abs(error_raw), abs(new_heading)) >= 3.0 * _PI
    return (x_ab2 if ab2 else x_euler), (y_ab2 if ab2 else y_euler), _wrap(new_heading), vx, vy, omega, far


# parallel=True for what numba does with a prange loop: it compiles the loop's body into a
# kernel of its own whose arrays LLVM may assume do not overlap, which lets the loop of the
# commands and the move vectorize (as a plain loop it does not: LLVM's remark "too many
# memory checks needed"). The probe runs it on one thread.
@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy", parallel=True)
def fly(s: np.ndarray, wind: np.ndarray, params: np.ndarray, n_steps: int, scratch: np.ndarray) -> int:
    """Fly ``s`` (F, N, B) for ``n_steps`` ordinary steps; ``wind`` (2, B) kt; ``scratch``
    (6, N, B): cos and sin of the heading, the gradient, θ_nh's atan2 arguments. Returns
    how many angles reached 3π, where this probe's wrap is not the kernel's (0 expected)."""
    unusual = 0
    consts = nf.nf_constants(params)
    u_cap, dt = params[nf.P_U_CAP], params[nf.P_DT]
    n, b_count = s.shape[1], s.shape[2]
    cos_h, sin_h, grad_x, grad_y, arg_y, arg_x = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[5]
    for i in range(n):
        for b in range(b_count):
            cos_h[i, b] = math.cos(s[HEADING, i, b])
            sin_h[i, b] = math.sin(s[HEADING, i, b])
    for _ in range(n_steps):
        for i in range(n):
            # The NF's gradient without neighbours (G_i = 1, ∇_iG_i = 0) and θ_nh's arguments.
            for b in range(b_count):
                gx, gy, _, sgn_along = own_gradient(s[X, i, b], s[Y, i, b], s[WP_X, i, b], s[WP_Y, i, b],
                                                    s[COS_D, i, b], s[SIN_D, i, b], 1.0, 0.0, 0.0, consts)
                grad_x[i, b] = gx
                grad_y[i, b] = gy
                arg_y[i, b] = sgn_along * gy
                arg_x[i, b] = sgn_along * gx
            for b in range(b_count):
                arg_y[i, b] = math.atan2(arg_y[i, b], arg_x[i, b])  # θ_nh where the gradient has a direction
            # The commands (5a)-(5b) and the move. Every load before any select: a load under a
            # condition would keep the branch.
            for b in prange(b_count):
                c = cos_h[i, b]
                sn = sin_h[i, b]
                x0 = s[X, i, b]
                y0 = s[Y, i, b]
                u, _, theta_nh = feedback(grad_x[i, b], grad_y[i, b], c, sn, x0, y0, s[WP_X, i, b], s[WP_Y, i, b],
                                          arg_y[i, b], s[THETA_D, i, b], params)
                u = min(max(u, -u_cap), u_cap)
                x1, y1, heading, vx, vy, omega, far = move(
                    u, c, sn, wind[0, b], wind[1, b], x0, y0, s[HEADING, i, b], theta_nh, s[THETA_NH, i, b],
                    s[FRESH, i, b], s[LAST_SUB, i, b], s[VX_PREV, i, b], s[VY_PREV, i, b], s[OMEGA_PREV, i, b], params,
                )
                unusual += 1 if far else 0
                s[VX_PREV, i, b] = vx
                s[VY_PREV, i, b] = vy
                s[OMEGA_PREV, i, b] = omega
                s[LAST_SUB, i, b] = 1.0
                s[X, i, b] = x1
                s[Y, i, b] = y1
                s[HEADING, i, b] = heading
                s[AIRSPEED, i, b] = u
                s[THETA_NH, i, b] = theta_nh
                s[FRESH, i, b] = 0.0
                s[TIME, i, b] += dt
                s[PATH, i, b] += math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
            for b in range(b_count):
                cos_h[i, b] = math.cos(s[HEADING, i, b])
                sin_h[i, b] = math.sin(s[HEADING, i, b])
    return unusual


def to_fields(state: np.ndarray) -> np.ndarray:
    """Kernel state (B, N, N_STATE) -> the probe's (F, N, B)."""
    return np.ascontiguousarray(state[:, :, list(FIELDS)].transpose(2, 1, 0))


def measure(n_worlds: int, n_aircraft: int, rounds: int) -> dict[str, float]:
    """Both flights checked equal, then timed on one thread (numba's thread count restored)."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return _measure(n_worlds, n_aircraft, rounds)
    finally:
        numba.set_num_threads(threads)


def _measure(n_worlds: int, n_aircraft: int, rounds: int) -> dict[str, float]:
    case = Case(kernel, n_worlds, n_aircraft)
    n_steps = case.n_steps
    flown = case.start.copy()
    trace = kernel.advance(flown, case.waypoints, case.wind, DECISION_PERIOD_S, case.params)
    if not (trace.min_separation_nm.min() > 2 * case.params[nf.P_R_SENSE]
            and (flown[:, :, kernel.S_LAST_SUBSTEPS] <= 1).all() and (flown[:, :, kernel.S_STATUS] == 0).all()):
        raise RuntimeError("a neighbour came in range, a step was refined or an aircraft arrived: not an ordinary flight")
    wind = np.ascontiguousarray(case.wind.T)
    scratch = np.empty((6, n_aircraft, n_worlds))
    probe = to_fields(case.start)
    if fly(probe, wind, case.params, n_steps, scratch):
        raise RuntimeError("an angle reached 3π: the probe's wrap would differ from the kernel's")
    if not np.array_equal(probe, to_fields(flown)):
        bad = int((probe != to_fields(flown)).sum())
        raise RuntimeError(f"the probe's flight differs from the kernel's in {bad} values: it would time other arithmetic")
    times: dict[str, list[float]] = {"kernel": [], "probe": []}
    steps = n_worlds * n_aircraft * n_steps
    for r in range(rounds):
        for name in (("kernel", "probe") if r % 2 == 0 else ("probe", "kernel")):
            if name == "kernel":
                state = case.start.copy()
                t0 = time.perf_counter()
                kernel.advance(state, case.waypoints, case.wind, DECISION_PERIOD_S, case.params, scratch=case.scratch)
            else:
                fields = to_fields(case.start)
                t0 = time.perf_counter()
                fly(fields, wind, case.params, n_steps, scratch)
            times[name].append((time.perf_counter() - t0) / steps * 1e9)
    k, p = statistics.median(times["kernel"]), statistics.median(times["probe"])
    return {"kernel": k, "probe": p, "ratio": k / p}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=21)
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    rows = ["| B | N | kernel (ns per aircraft-step) | structure of arrays (ns) | ratio |", "|---:|---:|---:|---:|---:|"]
    ratios = []
    for n_worlds in (1000, 10_000):
        for n_aircraft in (4, 6):
            r = measure(n_worlds, n_aircraft, args.rounds)
            ratios.append(r["ratio"])
            rows.append(f"| {n_worlds} | {n_aircraft} | {r['kernel']:.1f} | {r['probe']:.1f} | {r['ratio']:.2f}× |")
            print(rows[-1], flush=True)
    asm = "".join(fly.inspect_asm().values())
    asm_ops = {op: asm.count(op) for op in ("vsqrtpd", "vdivpd")}
    text = "\n".join([
        "## A probe for the kernel's layout: an ordinary step end to end",
        "",
        f"`python bench/soa_step_probe.py --rounds {args.rounds}` — {machine()}, numba {numba.__version__}, one "
        "thread. B worlds of converging-N over their first period (no neighbour in range, no refined step, no "
        "arrival: checked), flown by `kernel.advance` and by the law of an ordinary step written as structure "
        "of arrays with the loop over worlds innermost and selects for branches (atan2 and sincos in scalar "
        "loops of their own); the final states are the kernel's bit for bit (checked before timing). ns per "
        "aircraft-step, medians over rounds timed alternately:",
        "",
        *rows,
        "",
        f"The layout flew the same steps {min(ratios):.2f}–{max(ratios):.2f}× as fast as the kernel "
        f"({asm_ops['vsqrtpd']} packed square root(s), {asm_ops['vdivpd']} packed division(s) in its machine "
        "code). Its loop of the commands and the move vectorizes only as a `prange` loop, which numba "
        "compiles into a kernel whose arrays LLVM may take as distinct (one thread here: the gain is the "
        "vector lanes'). The probe "
        "leaves out what the kernel also does on every step (the neighbour loop, the envelope's and the "
        "separation's bookkeeping, the arrival and departure tests, the right-hand rule's and the watch's "
        "tests) and its entry checks and `Trace`; those are what a kernel in this layout would add back. "
        + ("On ordinary steps without neighbours the layout reaches the issue's 2×; whether a kernel in it keeps "
           "that depends on what the kernel adds back (the neighbours: `bench/soa_dense_probe.py`)."
           if min(ratios) >= 2.0 else
           "On this evidence the layout does not by itself double the kernel's rate: atan2 and sincos stay "
           "scalar in both, and bound it."),
    ])
    return publish("soa-step-probe", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
