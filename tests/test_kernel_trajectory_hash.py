"""``bench/kernel_trajectory_hash.py``, the before/after check of kernel changes, is only
useful if it repeats: the same flight twice gives the same hash, another flight another."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from kernel_trajectory_hash import MIX, workload_hash


def test_hash_repeats_and_tells_flights_apart() -> None:
    specs = list(MIX) * 4
    first = workload_hash(specs, 6, False, 2, seed=11, periods=6)
    assert workload_hash(specs, 6, False, 2, seed=11, periods=6) == first
    assert workload_hash(specs, 6, False, 2, seed=12, periods=6) != first
    assert workload_hash(specs, 6, True, 2, seed=11, periods=6) != first
