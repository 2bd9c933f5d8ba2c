"""``kernel.advance`` with its ``Trace`` reused and with new arrays, side by side in one process.

``KernelScratch.trace`` hands ``advance`` the arrays of an earlier trace that nothing refers
to any more instead of allocating ten new ones and a dataclass. This flies one 5-min period
of converging-N at B = 1 both ways (``kernel._REUSE_TRACES`` switched between rounds), in
alternating order over 31 rounds of 200 calls each, warm: medians over rounds, and the
median of the per-round ratios.

Run: python bench/experiments/trace_reuse_ab.py
"""

from __future__ import annotations

import time

import numpy as np
from advance_overhead import one_world  # bench/experiments/ is on sys.path when run as a script

from atc_nf_env import kernel


def measure(n: int, rounds: int = 31, calls: int = 200) -> str:
    start, waypoints, wind, params, scratch = one_world(n)

    def one_period() -> float:
        state = start.copy()
        t0 = time.perf_counter()
        kernel.advance(state, waypoints, wind, 300.0, params, scratch=scratch)
        return time.perf_counter() - t0

    seconds: dict[bool, list[float]] = {True: [], False: []}
    reuse = kernel._REUSE_TRACES
    try:
        for _ in range(calls):
            one_period()
        for r in range(rounds):
            for flag in ((True, False) if r % 2 else (False, True)):
                kernel._REUSE_TRACES = flag
                seconds[flag].append(float(np.median([one_period() for _ in range(calls)])))
    finally:
        kernel._REUSE_TRACES = reuse
    new, reused = (np.median(seconds[flag]) * 1e6 for flag in (False, True))
    ratio = np.median(np.array(seconds[True]) / np.array(seconds[False]))
    return (f"converging-{n}, B = 1: new arrays {new:.1f} µs per period, reused trace {reused:.1f} µs; "
            f"reused / new per round {ratio:.3f}")


if __name__ == "__main__":
    for n in (4, 6):
        print(measure(n), flush=True)
