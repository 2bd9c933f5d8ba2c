"""How much of ``kernel.advance`` at B = 1 is the Python around its compiled call.

``bench/bench_kernel.py`` times one 5-min period of converging-N per ``advance`` call. At
B = 1 the call's Python (its quick checks, the ``Trace`` and its ten arrays, numba's
dispatch of 21 arguments) is a share of that time that no kernel work can remove. This
probe times, alternately and warm (medians over 31 rounds of the medians of 200 calls
each): ``advance``; its compiled ``_advance_checked`` alone on preallocated arrays; the
same compiled call flying no step (numba's dispatch of the arguments, the checks of their
values and the world's setup before its first step); and the two Python layers alone, ``_quick_steps`` (types, shapes, layouts
and the step count) and ``KernelScratch.trace`` (handing back a dropped trace).

Run: python bench/experiments/advance_overhead.py
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state

TRACE_FIELDS = ("min_airspeed_kt", "max_airspeed_kt", "violation_steps", "worst_excursion_kt", "steps_flown",
                "los_pairs", "min_separation_nm", "steps_done", "violated", "record")


def one_world(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, kernel.KernelScratch]:
    """The start state, waypoints, wind (no wind), parameters and a scratch of one world of
    converging-``n`` flying its first period (also ``trace_reuse_ab.py``'s)."""
    scenario = make_scenario(f"converging-{n}")
    start = initial_state(scenario, 1)
    return (start, start[:, :, kernel.S_WP_X : kernel.S_WP_Y + 1].copy(), np.zeros((1, 2)),
            SimConfig().to_params(scenario.workspace_radius_nm), kernel.KernelScratch())


def measure(n: int) -> None:
    """Print both times for converging-``n``."""
    start, waypoints, wind, params, scratch = one_world(n)
    trace = kernel.advance(start.copy(), waypoints, wind, 300.0, params, scratch=scratch)
    grad, command = scratch.get(1, n)
    buffers = [np.empty_like(getattr(trace, name)) for name in TRACE_FIELDS]
    steps = kernel.steps_for(300.0, float(params[kernel.nf.P_DT]))

    def through_advance() -> float:
        state = start.copy()
        t0 = time.perf_counter()
        kernel.advance(state, waypoints, wind, 300.0, params, scratch=scratch)
        return time.perf_counter() - t0

    def compiled(n_steps: int) -> Callable[[], float]:
        def call() -> float:
            state = start.copy()
            t0 = time.perf_counter()
            kernel._advance_checked(state, waypoints, wind, n_steps, params, grad, command, *buffers, 1,
                                    scratch.lanes, scratch.lane_temp, scratch.lane_world)
            return time.perf_counter() - t0
        return call

    def quick_steps() -> float:
        t0 = time.perf_counter()
        kernel._quick_steps(start, waypoints, wind, 300.0, params, 0)
        return time.perf_counter() - t0

    def trace_reuse() -> float:
        t0 = time.perf_counter()
        scratch.trace(1, n, 0)
        return time.perf_counter() - t0

    probes = {"advance": through_advance, "compiled": compiled(steps), "no step": compiled(0),
              "quick checks": quick_steps, "trace": trace_reuse}
    for probe in probes.values():
        for _ in range(200):
            probe()
    medians: dict[str, list[float]] = {name: [] for name in probes}
    for r in range(31):
        order = list(probes) if r % 2 == 0 else list(reversed(probes))
        for name in order:
            medians[name].append(float(np.median([probes[name]() for _ in range(200)])))
    us = {name: float(np.median(values)) * 1e6 for name, values in medians.items()}
    a, c = us["advance"], us["compiled"]
    print(f"converging-{n}, B = 1: advance {a:.1f} µs per period, its compiled call alone {c:.1f} µs; "
          f"the Python around it {a - c:.1f} µs ({(a - c) / a:.0%}); the compiled call flying no step "
          f"(dispatch, value checks, the world's setup) {us['no step']:.1f} µs; quick checks {us['quick checks']:.1f} µs; "
          f"trace handed back {us['trace']:.1f} µs")


def main() -> None:
    for n in (4, 6):
        measure(n)


if __name__ == "__main__":
    main()
