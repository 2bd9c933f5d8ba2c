"""The kernel's own atan2 and sincos (``atc_nf_env.trig``): within 2 ulps of libm where the
result is not tiny, over the angles and gradients the kernel meets and far beyond."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from atc_nf_env import trig

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
tiny_to_huge = st.floats(min_value=1e-300, max_value=1e300, allow_nan=False, allow_infinity=False)


def close(ours: float, ref: float) -> bool:
    if abs(ref) > 1e-8:
        return abs(ours - ref) <= 2 * abs(np.spacing(ref))
    return abs(ours - ref) <= 1e-15


@settings(max_examples=400, deadline=None)
@given(finite, finite)
def test_atan2_within_two_ulps(y: float, x: float) -> None:
    # Signed zeros are not told apart (the kernel compiles without them, and asks atan2 only
    # for a gradient above its floor): where y is ±0, libm answers by the zero's sign (±π
    # on the negative x axis), ours as for +0 (test_the_axes_and_quadrants).
    assume(y != 0.0)
    assert close(trig.poly_atan2(y, x), math.atan2(y, x))


@settings(max_examples=200, deadline=None)
@given(tiny_to_huge, tiny_to_huge, st.sampled_from((1.0, -1.0)), st.sampled_from((1.0, -1.0)))
def test_atan2_at_any_scale(ay: float, ax: float, sy: float, sx: float) -> None:
    # Gradients of any size: the ratio of the two components is what matters.
    y, x = sy * ay, sx * ax
    assert close(trig.poly_atan2(y, x), math.atan2(y, x))


@settings(max_examples=400, deadline=None)
@given(st.floats(min_value=-3 * math.pi, max_value=3 * math.pi, allow_nan=False))
def test_sincos_within_two_ulps_where_the_kernel_flies(angle: float) -> None:
    s, c = trig.poly_sincos(angle)
    assert close(s, math.sin(angle)) and close(c, math.cos(angle))


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-1e12, max_value=1e12, allow_nan=False))
def test_sincos_within_two_ulps_of_any_start_heading(angle: float) -> None:
    # ``sincos`` reduces up to SINCOS_POLY_LIMIT itself and hands larger angles to libm.
    s, c = trig.sincos(angle)
    assert close(s, math.sin(angle)) and close(c, math.cos(angle))
    if abs(angle) > trig.SINCOS_POLY_LIMIT:
        assert (s, c) == (math.sin(angle), math.cos(angle))


def test_the_axes_and_quadrants() -> None:
    for y, x in ((0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (0.0, 0.0)):
        assert close(trig.poly_atan2(y, x), math.atan2(y, x)), (y, x)
    assert trig.poly_sincos(0.0) == (0.0, 1.0)
    for k in range(-12, 13):
        s, c = trig.poly_sincos(k * math.pi / 4)
        assert close(s, math.sin(k * math.pi / 4)) and close(c, math.cos(k * math.pi / 4)), k
