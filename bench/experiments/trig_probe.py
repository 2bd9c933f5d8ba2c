"""A probe for the kernel's libm floor: atan2 and sincos as our own polynomials (Cephes'
rational atan and minimax sin/cos with Cody-Waite reduction), against libm, compiled
alike.

On one thread the lane path of bench/experiments/kernel_lane_path.patch spends 55 % of an
aircraft-step in libm's atan2 and sincos: scalar calls, since libm has no vector form that
gives the scalar bits. Functions of our own, written as straight-line arithmetic with
selects, would vectorize in the lane step and give the same bits on the scalar path, but
they round differently from libm, so adopting them moves every trajectory (a new build and
a full regeneration). This probe measures what that would buy and what it would cost in
accuracy, before anyone does it:

- accuracy: the largest error in ulps of the double result against libm over random
  arguments (headings in [-3π, 3π], gradient components of any sign and scale);
- speed: ns per call in a loop over 4096 arguments, for libm and for ours, alternately
  over rounds (medians); ours in a loop LLVM can vectorize, libm's as the kernel calls it;
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

from atc_nf_env.nf import FAST_MATH_FLAGS

# Cephes atan.c (double precision): atan(x) = x + x³ P(x²)/Q(x²) on |x| <= 0.66, with the
# arguments beyond reduced by π/4 and π/2.
_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
      -1.228866684490136173410e2, -6.485021904942025371773e1)
_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964425e2)
_T3P8 = 2.41421356237309504880  # tan(3π/8)
_MOREBITS = 6.123233995736765886130e-17  # π/2 − the double nearest π/2
# Cephes sin.c: minimax polynomials on [0, π/4], the argument reduced by π/4 in three parts.
_SIN = (1.58962301576546568060e-10, -2.50507477628578072866e-8, 2.75573136213857245213e-6,
        -1.98412698295895385996e-4, 8.33333333332211858878e-3, -1.66666666666666307295e-1)
_COS = (-1.13585365213876817300e-11, 2.08757008419747316778e-9, -2.75573141792967388112e-7,
        2.48015872888517045348e-5, -1.38888888888730564116e-3, 4.16666666666665929218e-2)
_DP1, _DP2, _DP3 = 7.85398125648498535156e-1, 3.77489470793079817668e-8, 2.69515142907905952645e-15
_FOUR_OVER_PI = 1.27323954473516268615


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def poly_atan2(y: float, x: float) -> float:
    """atan2(y, x) in (−π, π], our polynomial (selects, no libm call). Signed zeros are not
    told apart (the kernel's flags ignore them): y = −0 is taken as +0 (π on the negative x
    axis, where libm gives −π), and atan2(±0, −0) is 0 (libm: ±π)."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    small = min(ax, ay)
    t = small / big if big > 0.0 else 0.0  # in [0, 1]
    # Cephes' reduction on [0, 1]: beyond 0.66 by π/4 ((t − 1)/(t + 1)); t never exceeds tan(3π/8).
    upper = t > 0.66
    u = (t - 1.0) / (t + 1.0) if upper else t
    z = u * u
    p = (((_P[0] * z + _P[1]) * z + _P[2]) * z + _P[3]) * z + _P[4]
    q = ((((z + _Q[0]) * z + _Q[1]) * z + _Q[2]) * z + _Q[3]) * z + _Q[4]
    a = u * (z * p / q) + u
    a = (a + 0.5 * _MOREBITS) + 0.25 * math.pi if upper else a
    a = (0.5 * math.pi - a) + _MOREBITS if ay > ax else a  # swapped: atan(1/t) = π/2 − atan(t)
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def poly_sincos(angle: float) -> tuple[float, float]:
    """(sin, cos) of an angle of moderate size (|angle| < 1e6 rad), our polynomials."""
    sign = -1.0 if angle < 0.0 else 1.0
    x = abs(angle)
    j = math.floor(x * _FOUR_OVER_PI)
    j = j + 1.0 if j % 2.0 != 0.0 else j  # to the even octant boundary
    octant = j % 8.0
    r = ((x - j * _DP1) - j * _DP2) - j * _DP3
    z = r * r
    s = r + r * z * (((((_SIN[0] * z + _SIN[1]) * z + _SIN[2]) * z + _SIN[3]) * z + _SIN[4]) * z + _SIN[5])
    c = 1.0 - 0.5 * z + z * z * (((((_COS[0] * z + _COS[1]) * z + _COS[2]) * z + _COS[3]) * z + _COS[4]) * z
                                 + _COS[5])
    swap = octant == 2.0 or octant == 6.0
    sin_v = c if swap else s
    cos_v = s if swap else c
    sin_v = -sin_v if octant >= 4.0 else sin_v
    cos_v = -cos_v if (octant == 2.0 or octant == 4.0) else cos_v
    return sign * sin_v, cos_v


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
