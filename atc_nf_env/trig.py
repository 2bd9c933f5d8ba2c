"""atan2 and sincos of the kernel as straight-line arithmetic of our own.

The law needs, per aircraft and integration step, the direction of the NF's gradient
(atan2) and the cosine and sine of the heading. libm's functions are calls the compiler
cannot vectorize, and a vector form of them (SVML, libmvec) rounds differently from the
scalar one, so a world flown in a SIMD lane would not fly the same bits as alone. These
polynomials are Cephes' (Stephen L. Moshier's Cephes Math Library: the rational atan of
atan.c, the minimax sin and cos of sin.c with its three-part reduction), written with
selects instead of branches, so that a loop into which they are inlined can be
vectorized. The kernel calls them, compiled on their own, from its general scalar path,
and inlines them (``poly_atan2_inlined``, ``poly_sincos_inlined``) into its lane step's
loops and its one-world runs of ordinary steps: the same Python under the same flags, so every path
computes the same bits (``tests/test_kernel_lanes.py``,
``tests/test_kernel_ordinary_step.py``). They also make the
kernel's trajectories independent of the host's libm, whose results differ between
builds and CPUs (glibc picks an FMA variant where the CPU has one).

Accuracy, against libm (tests/test_trig.py): within
2 ulps where the result exceeds 1e-8 in size, absolute error at most 4.4e-16. Signed
zeros are not told apart (the kernel's fast-math flags ignore them).

Angles in radians.
"""

from __future__ import annotations

import math

from numba import njit

from atc_nf_env.nf import FAST_MATH_FLAGS
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

# Cephes atan.c (double precision): atan(x) = x + x³ P(x²)/Q(x²) on |x| <= 0.66, with the
# arguments beyond reduced by π/4 and π/2.
_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
      -1.228866684490136173410e2, -6.485021904942025371773e1)
_Q = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964425e2)
_MOREBITS = 6.123233995736765886130e-17  # π/2 − the double nearest π/2
# Cephes sin.c: minimax polynomials on [0, π/4], the argument reduced by π/4 in three parts.
_SIN = (1.58962301576546568060e-10, -2.50507477628578072866e-8, 2.75573136213857245213e-6,
        -1.98412698295895385996e-4, 8.33333333332211858878e-3, -1.66666666666666307295e-1)
_COS = (-1.13585365213876817300e-11, 2.08757008419747316778e-9, -2.75573141792967388112e-7,
        2.48015872888517045348e-5, -1.38888888888730564116e-3, 4.16666666666665929218e-2)
_DP1, _DP2, _DP3 = 7.85398125648498535156e-1, 3.77489470793079817668e-8, 2.69515142907905952645e-15
_FOUR_OVER_PI = 1.27323954473516268615


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
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


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
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


#: Largest |angle| that ``sincos`` reduces itself (``poly_sincos``'s accuracy is measured
#: there); beyond, libm's. The kernel's headings are wrapped to [−π, π) at every step, and
#: its lane path takes no angle beyond 3π, so only a start state can reach that branch.
SINCOS_POLY_LIMIT = 1e6


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def sincos(angle: float) -> tuple[float, float]:
    """(sin, cos) of ``angle`` (rad): ``poly_sincos`` where |angle| <= ``SINCOS_POLY_LIMIT``,
    libm's beyond."""
    if abs(angle) <= SINCOS_POLY_LIMIT:
        return poly_sincos(angle)
    return math.sin(angle), math.cos(angle)


# The same two functions inlined at numba's level into their callers: the lane step's two
# loops over worlds, which LLVM then vectorizes (B = 1000 flew 1.29-1.30x as fast as with
# the functions called, at the same first compilation), and the one-world runs of ordinary
# steps (``kernel._ordinary_run``, compiled on its own). Not the general scalar path:
# inlined everywhere they lengthened the kernel's first compilation by about a third for no
# gain at B = 1.
# The same Python under the same flags: the same bits.
poly_atan2_inlined = njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")(
    poly_atan2.py_func)
poly_sincos_inlined = njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")(
    poly_sincos.py_func)
