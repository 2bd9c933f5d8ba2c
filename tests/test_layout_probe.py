"""The premise of ``bench/layout_probe.py``: the NF's proximity term flown as structure of
arrays without branches gives the kernel's per-world, branching arithmetic bit for bit."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from atc_nf_env.config import SimConfig
from atc_nf_env.nf import nf_constants

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from layout_probe import per_world, structure_of_arrays

CONSTS = nf_constants(SimConfig().to_params(250.0))


@settings(max_examples=60, deadline=None)
@given(
    # Positions within a few sensing radii of each other: neighbours out of range, inside the
    # barrier and overlapping (s <= 0) all occur.
    pos=st.integers(1, 40).flatmap(lambda b: st.integers(2, 6).flatmap(
        lambda n: hnp.arrays(np.float64, (b, n, 2), elements=st.floats(-30.0, 30.0)))),
    waypoint=st.tuples(st.floats(-200.0, 200.0), st.floats(-200.0, 200.0)),
)
def test_the_branch_free_layout_gives_the_kernels_numbers_bit_for_bit(pos, waypoint) -> None:
    n_worlds = pos.shape[0]
    wp = np.tile(np.array(waypoint), (n_worlds, 1))
    first, second = np.empty(n_worlds), np.empty(n_worlds)
    per_world(pos, wp, CONSTS, first)
    x, y = np.ascontiguousarray(pos[:, :, 0].T), np.ascontiguousarray(pos[:, :, 1].T)
    structure_of_arrays(x, y, np.ascontiguousarray(wp[:, 0]), np.ascontiguousarray(wp[:, 1]), CONSTS,
                        np.empty(n_worlds), second)
    assert np.isfinite(first).all()  # the workspace is far wider than these positions: real numbers
    assert np.array_equal(first, second)
