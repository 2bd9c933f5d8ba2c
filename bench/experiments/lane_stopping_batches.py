"""The kernel's lane path against its scalar batch on candidate sets that stop at once, side
by side.

B = 1000 copies of one mid-encounter state (converging-6 at 25 min, random-16 and random-6
at 20 min, seed 3, flown there by the NF alone without wind), each aimed at waypoints
scattered 20 nm (σ) about the destinations, flown for one period with
``stop_on_violation`` (nearly all stop at their first step, as an MPC's infeasible
candidates do), by ``kernel._advance_lanes`` and ``kernel._advance_batch`` alternately in 7
rounds; both end in the same state (checked). Prints the medians and their ratio.

Run: python bench/experiments/lane_stopping_batches.py
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from atc_nf_env import kernel as K
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state


def main() -> int:
    if not hasattr(K, "_advance_lanes"):
        print("this kernel has no lane path (kernel._advance_lanes)")
        return 1
    for spec, t_min in (("converging-6", 25), ("random-16", 20), ("random-6", 20)):
        scenario = make_scenario(spec, seed=3)
        st0 = initial_state(scenario, 1)
        wp = st0[:, :, K.S_DEST_X : K.S_DEST_Y + 1].copy()
        free_params = SimConfig().to_params(scenario.workspace_radius_nm)
        for _ in range(t_min // 5):
            K.advance(st0, wp, np.zeros((1, 2)), 300.0, free_params)
        b_count, n = 1000, scenario.n_aircraft
        start = np.repeat(st0, b_count, axis=0)
        waypoints = np.repeat(wp, b_count, axis=0) + np.random.default_rng(0).normal(0, 20, (b_count, n, 2))
        wind = np.zeros((b_count, 2))
        params = SimConfig().to_params(scenario.workspace_radius_nm, stop_on_violation=True)
        scratch = K.KernelScratch()
        grad, command = scratch.get(b_count, n)
        times: dict[str, list[float]] = {"batch": [], "lanes": []}
        finals = {}
        for _ in range(7):
            for name in ("batch", "lanes"):
                state = start.copy()
                steps = np.zeros(b_count, np.int64)
                args = [state, waypoints, wind, 60, params, grad, command, np.empty((b_count, n)), np.empty((b_count, n)),
                        np.zeros((b_count, n), np.int64), np.empty((b_count, n)), np.zeros((b_count, n), np.int64),
                        np.zeros((b_count, n, n), np.uint8), np.empty(b_count), steps, np.zeros(b_count, np.bool_),
                        np.zeros((b_count, 0, n, K.N_RECORD)), 1]
                if name == "lanes":
                    args += [scratch.lanes, scratch.lane_temp, scratch.lane_world]
                t0 = time.perf_counter()
                (K._advance_lanes if name == "lanes" else K._advance_batch)(*args)
                times[name].append(time.perf_counter() - t0)
                finals[name] = state
        assert np.array_equal(finals["lanes"], finals["batch"])
        batch, lanes = statistics.median(times["batch"]), statistics.median(times["lanes"])
        print(f"{spec} at {t_min} min: steps done {steps.mean():.1f} on average; scalar batch {batch * 1e3:.1f} ms, "
              f"lane path {lanes * 1e3:.1f} ms; lane path speed / scalar {batch / lanes:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
