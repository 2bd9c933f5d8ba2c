"""The kernel's first compilation: import, then the first ``advance`` of one world and of 32
worlds (the scalar path and the lane path), timed. Run it with an empty numba cache so that it compiles
rather than loads, e.g.

    NUMBA_CACHE_DIR=$(mktemp -d) python bench/experiments/kernel_compile_time.py
"""

from __future__ import annotations

import time

import numpy as np


def main() -> int:
    t0 = time.perf_counter()
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.simulation import initial_state

    scenario = make_scenario("converging-4")
    params = SimConfig().to_params(scenario.workspace_radius_nm)
    t1 = time.perf_counter()
    for n_worlds in (1, 32):
        state = initial_state(scenario, n_worlds)
        waypoints = state[:, :, kernel.S_WP_X : kernel.S_WP_Y + 1].copy()
        kernel.advance(state, waypoints, np.zeros((n_worlds, 2)), 300.0, params)
    t2 = time.perf_counter()
    print(f"import {t1 - t0:.1f} s; first advance of 1 world and of 32 worlds: {t2 - t1:.1f} s "
          f"(lane path: {'yes' if hasattr(kernel, '_advance_lanes') else 'no'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
