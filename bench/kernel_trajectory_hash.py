"""A fingerprint of what the kernel flies: run it before and after a change to the kernel
that must not change a trajectory, and compare the hashes.

Six workloads through ``kernel.advance``, each a batch of mixed encounters (random-4/5/6,
converging-4/6, padded to one slot count with ABSENT aircraft where fewer fly) under
per-world winds (σ = 10 kt per component), flown period after period (5 min each, up to
40) until every aircraft has arrived or left; every other period each aircraft is sent to
a waypoint offset from its destination (σ = 30 nm), so that waypoint switches, the guards
and neighbours in range all occur. The workloads cover one world, a small batch, 300
worlds with and without ``stop_on_violation``, and 200 worlds with recording every 1 or 2
steps. Each hash is SHA-256 over the state after every period and every array of each
``Trace`` (16 hex digits printed per workload).

Equal hashes before and after a change mean the change flew the same numbers bit for bit
on this machine; it says nothing about speed (``bench/bench_kernel.py``).

Run: python bench/kernel_trajectory_hash.py
"""

from __future__ import annotations

import hashlib
import sys
import time

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state

#: The encounters of a batch, in the order its worlds cycle through them.
MIX = ("random-4", "random-6", "converging-4", "converging-6", "random-5")


def workload_hash(specs: list[str], n_slots: int, stop_on_violation: bool, record_every: int, seed: int,
                  periods: int = 40) -> str:
    """16 hex digits of SHA-256 over the flight of the worlds ``specs`` (see the module docstring)."""
    rng = np.random.default_rng(seed)
    scenarios = [make_scenario(spec, seed=seed * 1000 + b) for b, spec in enumerate(specs)]
    state = np.stack([initial_state(scenario, 1, n_slots)[0] for scenario in scenarios])
    radius = max(scenario.workspace_radius_nm for scenario in scenarios)
    params = SimConfig().to_params(radius, stop_on_violation=stop_on_violation)
    wind_kt = rng.normal(0.0, 10.0, (len(scenarios), 2))
    digest = hashlib.sha256()
    for period in range(periods):
        waypoints = state[:, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy()
        if period % 2 == 1:
            waypoints += rng.normal(0.0, 30.0, waypoints.shape)
        trace = kernel.advance(state, waypoints, wind_kt, 300.0, params, record_every=record_every)
        for array in (state, trace.min_airspeed_kt, trace.max_airspeed_kt, trace.violation_steps,
                      trace.worst_excursion_kt, trace.steps_flown, trace.los_pairs, trace.min_separation_nm,
                      trace.steps_done, trace.violated, trace.record):
            digest.update(np.ascontiguousarray(array).tobytes())
        if (state[:, :, kernel.S_STATUS] != kernel.FLYING).all():
            break
    return digest.hexdigest()[:16]


def hashes() -> list[str]:
    """The six workloads' hashes, in the module docstring's order."""
    mixed = [MIX[b % len(MIX)] for b in range(300)]
    return [
        workload_hash(mixed[:1], 6, False, 0, 1),
        workload_hash(mixed[:7], 6, False, 3, 2),
        workload_hash(mixed, 6, False, 0, 3),
        workload_hash(mixed, 6, True, 0, 4),
        workload_hash(["converging-4"] * 200, 4, False, 1, 5),
        workload_hash(["random-4"] * 200, 4, True, 2, 6),
    ]


def main() -> int:
    start = time.perf_counter()
    print(" ".join(hashes()), f"({time.perf_counter() - start:.1f} s, compilation included)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
