"""The kernel's own atan2 and sincos (``atc_nf_env.trig``: Cephes' rational atan and
minimax sin/cos with a three-part reduction) against libm, compiled alike.

Before the kernel adopted them, its lane path spent 55 % of an aircraft-step on one thread
in libm's atan2 and sincos: scalar calls, since libm has no vector form that gives the
scalar bits. Ours are straight-line arithmetic with selects: they vectorize in the lane
step and give the same bits on the scalar path. This probe measured what that would buy
and what it would cost in accuracy, before the kernel took them, and still does:

- accuracy: the largest error in ulps of the double result against libm over random
  arguments (headings in [-3π, 3π], gradient components of any sign and scale);
- speed: ns per call in a loop over 4096 arguments, for libm and for ours, alternately
  over rounds (medians); ours inlined at numba's level in a loop LLVM can vectorize, libm's
  as the kernel called it;
  and both in a chain where each argument depends on the last result, which cannot be
  vectorized (one aircraft's steps on the scalar path).

Run: python bench/experiments/trig_probe.py [--rounds 21]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np
from numba import njit

from atc_nf_env import trig
from atc_nf_env.nf import FAST_MATH_FLAGS

# The kernel's functions inlined at numba's level, as LLVM needs them to vectorize a loop of
# them (the kernel itself calls them without this inlining, for its compile time).
poly_atan2 = njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")(trig.poly_atan2.py_func)
poly_sincos = njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")(trig.poly_sincos.py_func)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def libm_loop(y: np.ndarray, x: np.ndarray, h: np.ndarray, out: np.ndarray) -> None:
    for k in range(y.shape[0]):
        out[k] = math.atan2(y[k], x[k]) + math.cos(h[k]) + math.sin(h[k])


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def poly_loop(y: np.ndarray, x: np.ndarray, h: np.ndarray, out: np.ndarray) -> None:
    for k in range(y.shape[0]):
        s, c = poly_sincos(h[k])
        out[k] = poly_atan2(y[k], x[k]) + c + s


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def libm_chain(y: np.ndarray, x: np.ndarray, h: np.ndarray) -> float:
    """Each call's argument depends on the last result, as along one aircraft's steps (no
    vectorization: the scalar path's case)."""
    carry = 0.0
    for k in range(y.shape[0]):
        carry = 1e-3 * (math.atan2(y[k] + carry, x[k]) + math.cos(h[k] + carry) + math.sin(h[k] + carry))
    return carry


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def poly_chain(y: np.ndarray, x: np.ndarray, h: np.ndarray) -> float:
    carry = 0.0
    for k in range(y.shape[0]):
        s, c = poly_sincos(h[k] + carry)
        carry = 1e-3 * (poly_atan2(y[k] + carry, x[k]) + c + s)
    return carry


@njit(cache=True, error_model="numpy")
def errors(y: np.ndarray, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Ours against libm, for atan2, sin and cos: the largest error in ulps where the result
    exceeds 1e-8 in size, and the largest absolute error anywhere, (3, 2)."""
    worst = np.zeros((3, 2))
    for k in range(y.shape[0]):
        s, c = poly_sincos(h[k])
        pairs = ((poly_atan2(y[k], x[k]), math.atan2(y[k], x[k])), (s, math.sin(h[k])), (c, math.cos(h[k])))
        for m in range(3):
            ours, ref = pairs[m]
            if abs(ref) > 1e-8:
                worst[m, 0] = max(worst[m, 0], abs(ours - ref) / abs(np.spacing(ref)))
            worst[m, 1] = max(worst[m, 1], abs(ours - ref))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=21)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    n = 1_000_000
    scale = 10.0 ** rng.uniform(-6, 3, n)
    y, x = rng.normal(size=n) * scale, rng.normal(size=n) * scale
    h = rng.uniform(-3 * math.pi, 3 * math.pi, n)
    # Near the special points too: axes, the diagonal, the octant boundaries.
    edge = np.concatenate([np.arange(-12, 13) * (math.pi / 4) + d for d in (0.0, 1e-12, -1e-12)])
    worst = np.maximum(errors(y, x, h), errors(np.sin(edge), np.cos(edge), edge))
    print(f"against libm ({n:,} random arguments and {edge.size} near octant boundaries): largest error "
          + ", ".join(f"{name} {worst[m, 0]:.1f} ulps (absolute {worst[m, 1]:.1e})"
                      for m, name in enumerate(("atan2", "sin", "cos")))
          + "; ulps where the result exceeds 1e-8")
    m = 4096
    out = np.empty(m)
    times: dict[str, list[float]] = {"libm": [], "ours": []}
    for r in range(args.rounds):
        for name, loop in (("libm", libm_loop), ("ours", poly_loop))[:: 1 if r % 2 else -1]:
            loop(y[:m], x[:m], h[:m], out)
            t0 = time.perf_counter()
            for _ in range(50):
                loop(y[:m], x[:m], h[:m], out)
            times[name].append((time.perf_counter() - t0) / (50 * m) * 1e9)
    libm, ours = statistics.median(times["libm"]), statistics.median(times["ours"])
    print(f"atan2 + sincos per argument, one thread, medians of {args.rounds} rounds: libm {libm:.1f} ns, "
          f"ours {ours:.1f} ns ({libm / ours:.2f}x), in a loop LLVM vectorizes")
    chain: dict[str, list[float]] = {"libm": [], "ours": []}
    for r in range(args.rounds):
        for name, loop in (("libm", libm_chain), ("ours", poly_chain))[:: 1 if r % 2 else -1]:
            loop(y[:m], x[:m], h[:m])
            t0 = time.perf_counter()
            for _ in range(50):
                loop(y[:m], x[:m], h[:m])
            chain[name].append((time.perf_counter() - t0) / (50 * m) * 1e9)
    libm, ours = statistics.median(chain["libm"]), statistics.median(chain["ours"])
    print(f"the same, each argument depending on the last result (the scalar path's case): libm {libm:.1f} ns, "
          f"ours {ours:.1f} ns ({libm / ours:.2f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
