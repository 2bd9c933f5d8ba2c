"""The premise of ``bench/experiments/trig_probe.py``: its polynomial atan2 and sincos are
within 2 ulps of libm (where the result is not tiny) over the kernel's range of angles."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench" / "experiments"))
from trig_probe import poly_atan2, poly_sincos

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


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
    assert close(poly_atan2(y, x), math.atan2(y, x))


@settings(max_examples=400, deadline=None)
@given(st.floats(min_value=-3 * math.pi, max_value=3 * math.pi, allow_nan=False))
def test_sincos_within_two_ulps(angle: float) -> None:
    s, c = poly_sincos(angle)
    assert close(s, math.sin(angle)) and close(c, math.cos(angle))


def test_the_axes_and_quadrants() -> None:
    for y, x in ((0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (0.0, 0.0)):
        assert close(poly_atan2(y, x), math.atan2(y, x)), (y, x)
    assert poly_sincos(0.0) == (0.0, 1.0)
