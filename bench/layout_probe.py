"""A probe for the kernel's lane layout: the NF's proximity term over many worlds, per world
with branches (as the kernel flies it) against structure of arrays without branches.

For aircraft 0 of each of B worlds of N aircraft (positions from a converging-N start
perturbed at random, so that neighbours fall inside and outside the sensing radius), both
versions compute G_0 = Π_j h(s_0j) with the kernel's own bump (``nf.proximity_bump``'s
arithmetic) and a scale of the NF's form D^(−1/k−1) with k = 2 (a square root and a division;
f_i simplified to a0 (1 − G_0), and the gradients with respect to the neighbours left out):

- per world: one world after another, the neighbour loop skipping a neighbour out of range
  and the bump branching on s, as ``nf.nf_along_direction`` does;
- structure of arrays: one array per coordinate and aircraft, the loop over worlds
  innermost, every bump computed and the in-range one selected, so that LLVM can fly
  several worlds in the lanes of one SIMD register.

Both are compiled with the kernel's fast-math flags and must give the same numbers bit for
bit (checked); reported: ns per aircraft-evaluation on one thread (medians over rounds
timed alternately), their ratio, and the packed square roots and divisions in the second's
machine code (its vectorization). This is the NF's core alone, not the kernel. It is the
probe that led to the kernel's lane path (``kernel._advance_lanes``), which flies a world's
ordinary steps in this layout; it stays as a measure of the layout alone.

Run: python bench/layout_probe.py [--rounds 31] [--write]
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
from numba import njit

from atc_nf_env.config import SimConfig
from atc_nf_env.nf import FAST_MATH_FLAGS, nf_constants
from atc_nf_env.scenarios import converging


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy")  # not cached: inspect_asm needs the compilation
def per_world(pos: np.ndarray, wp: np.ndarray, consts: tuple, out: np.ndarray) -> None:
    """pos (B, N, 2) nm, wp (B, 2) nm; out (B,): the scale D^(−3/2) of aircraft 0, k = 2."""
    inv_len, _, _, beta0_max, contact2, inv_beta_s, c_bar, r_sense2, eps_nh, a0, _ = consts
    for b in range(pos.shape[0]):
        xi = pos[b, 0, 0] * inv_len
        yi = pos[b, 0, 1] * inv_len
        dx = (pos[b, 0, 0] - wp[b, 0]) * inv_len
        dy = (pos[b, 0, 1] - wp[b, 1]) * inv_len
        g = 1.0
        for j in range(1, pos.shape[1]):
            rx = xi - pos[b, j, 0] * inv_len
            ry = yi - pos[b, j, 1] * inv_len
            dist2 = rx * rx + ry * ry
            if dist2 >= r_sense2:
                continue
            s = (dist2 - contact2) * inv_beta_s
            if s >= 1.0:
                h = 1.0
            elif s <= 0.0:
                h = 0.0
            else:
                w = (1.0 + c_bar) * s / (s + c_bar)
                h = w * (2.0 - w)
            g *= h
        a = dx * dx + dy * dy + a0 * (1.0 - g)
        d = a * a + (eps_nh + dx * dx) * g * (beta0_max - (xi * xi + yi * yi))
        out[b] = 1.0 / (math.sqrt(d) * d)


@njit(fastmath=FAST_MATH_FLAGS, error_model="numpy")  # not cached: inspect_asm needs the compilation
def structure_of_arrays(x: np.ndarray, y: np.ndarray, wx: np.ndarray, wy: np.ndarray, consts: tuple,
                        g: np.ndarray, out: np.ndarray) -> None:
    """x, y (N, B) nm; wx, wy (B,) nm; g (B,) scratch; out (B,): as ``per_world``."""
    inv_len, _, _, beta0_max, contact2, inv_beta_s, c_bar, r_sense2, eps_nh, a0, _ = consts
    n_worlds = x.shape[1]
    for b in range(n_worlds):
        g[b] = 1.0
    for j in range(1, x.shape[0]):
        for b in range(n_worlds):
            rx = x[0, b] * inv_len - x[j, b] * inv_len
            ry = y[0, b] * inv_len - y[j, b] * inv_len
            dist2 = rx * rx + ry * ry
            s = (dist2 - contact2) * inv_beta_s
            w = (1.0 + c_bar) * s / (s + c_bar)
            inside = w * (2.0 - w)
            h = 1.0 if s >= 1.0 else (0.0 if s <= 0.0 else inside)
            g[b] *= 1.0 if dist2 >= r_sense2 else h
    for b in range(n_worlds):
        xi = x[0, b] * inv_len
        yi = y[0, b] * inv_len
        dx = (x[0, b] - wx[b]) * inv_len
        dy = (y[0, b] - wy[b]) * inv_len
        a = dx * dx + dy * dy + a0 * (1.0 - g[b])
        d = a * a + (eps_nh + dx * dx) * g[b] * (beta0_max - (xi * xi + yi * yi))
        out[b] = 1.0 / (math.sqrt(d) * d)


def measure(n_worlds: int, n_aircraft: int, pull: float, rounds: int) -> dict[str, float]:
    scenario = converging(n_aircraft)
    consts = nf_constants(SimConfig().to_params(scenario.workspace_radius_nm))
    rng = np.random.default_rng(0)
    # Starts pulled toward the centre by a random share of up to ``pull`` and jittered by up
    # to 15 nm: the smaller ``pull``, the more neighbours inside the 12-nm sensing radius.
    share = rng.uniform(0.0, pull, (n_worlds, 1, 1))
    pos = scenario.start_xy[None] * share + rng.uniform(-15.0, 15.0, (n_worlds, n_aircraft, 2))
    wp = np.repeat(scenario.dest_xy[:1], n_worlds, axis=0)
    x, y = np.ascontiguousarray(pos[:, :, 0].T), np.ascontiguousarray(pos[:, :, 1].T)
    wx, wy = np.ascontiguousarray(wp[:, 0]), np.ascontiguousarray(wp[:, 1])
    first, second, g = np.empty(n_worlds), np.empty(n_worlds), np.empty(n_worlds)
    calls = max(1, 200_000 // n_worlds)
    times: dict[str, list[float]] = {"per_world": [], "soa": []}
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        per_world(pos, wp, consts, first)
        structure_of_arrays(x, y, wx, wy, consts, g, second)
        if not np.array_equal(first, second):
            raise RuntimeError("the two layouts disagree: the probe would compare different arithmetic")
        for r in range(rounds):
            for name in (("per_world", "soa") if r % 2 == 0 else ("soa", "per_world")):
                t0 = time.perf_counter()
                for _ in range(calls):
                    if name == "per_world":
                        per_world(pos, wp, consts, first)
                    else:
                        structure_of_arrays(x, y, wx, wy, consts, g, second)
                times[name].append((time.perf_counter() - t0) / (calls * n_worlds) * 1e9)
    finally:
        numba.set_num_threads(threads)
    near = float(((np.hypot(*(pos[:, 1:] - pos[:, :1]).transpose(2, 0, 1)) < SimConfig().sensing_radius_nm)
                  .any(axis=1)).mean())
    per, soa = statistics.median(times["per_world"]), statistics.median(times["soa"])
    return {"per_world": per, "soa": soa, "ratio": per / soa, "near": near}


def vector_instructions() -> dict[str, int]:
    """Packed square roots and divisions in the compiled ``structure_of_arrays``."""
    asm = "".join(structure_of_arrays.inspect_asm().values())
    if not asm:
        raise RuntimeError("no machine code to inspect: the probe cannot say whether the loop vectorized")
    return {op: asm.count(op) for op in ("vsqrtpd", "vdivpd")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=31)
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    rows = [
        "| B | N | worlds with a neighbour in range | per world, branches (ns) | structure of arrays (ns) | ratio |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    ratios = []
    for n_worlds in (1000, 10_000):
        for n_aircraft in (4, 6):
            for pull in (1.0, 0.05):
                r = measure(n_worlds, n_aircraft, pull, args.rounds)
                ratios.append(r["ratio"])
                rows.append(f"| {n_worlds} | {n_aircraft} | {r['near']:.0%} | {r['per_world']:.2f} | "
                            f"{r['soa']:.2f} | {r['ratio']:.1f}× |")
                print(rows[-1], flush=True)
    ops = vector_instructions()
    text = "\n".join([
        "## A probe for the kernel's layout",
        "",
        f"`python bench/layout_probe.py --rounds {args.rounds}` — {machine()}, numba {numba.__version__}, one "
        "thread. The NF's proximity term and scale for aircraft 0 of B worlds of N aircraft (converging-N "
        "starts pulled in and jittered at random), flown per world with branches as the kernel does, and as "
        "structure of arrays with the loop over worlds innermost and no branches; both give the same numbers "
        "bit for bit (checked before timing). ns per aircraft-evaluation, medians over rounds timed "
        "alternately:",
        "",
        *rows,
        "",
        f"The second's machine code holds {ops['vsqrtpd']} packed square root(s) and {ops['vdivpd']} packed "
        "division(s)" + (": LLVM flies several worlds per instruction there" if min(ops.values()) > 0 else
                         ": LLVM did not vectorize all of it") + ". This is the NF's core alone: "
        f"this part of a kernel step ran {min(ratios):.1f}–{max(ratios):.1f}× faster in this layout with the "
        "same numbers (the more neighbours in range, the more the branches cost). The kernel's lane path "
        "(\"Kernel throughput\") flies a world's ordinary steps, those with no pair in range and no guard "
        "acting, in this layout; its other steps branch per world on the scalar path. One call per B worlds: "
        "the call's own cost is spread over B.",
    ])
    return publish("layout-probe", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
