"""How far trajectories move between the frozen kernel and the current one.

The kernel's performance work may change results by rounding (e.g. a direction taken
from a gradient's components instead of from the cosine and sine of its atan2). This
flies the same episodes twice in one process, once with the package's kernel and once
with ``atc_nf_env.kernel.advance`` replaced by the frozen copy under
``bench/frozen_kernel`` (every caller, the MPC's candidates included, goes through
``kernel.advance``), and prints the largest position difference between the two
recorded trajectories, and whether the outcome (arrivals, safety) changed. For scale,
each episode is flown a third time by the frozen kernel from a start moved by one unit
in the last place (the first aircraft's heading, ~4e-16 rad): how far a rounding-sized
change carries that flight.

Run: python bench/kernel_drift.py
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from contextlib import contextmanager
from typing import Iterator

import numpy as np
from frozen_kernel import kernel as frozen  # bench/ is on sys.path when run as a script

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import EpisodeResult, run_episode
from atc_nf_env.kernel import R_FLEW, R_X, R_Y
from atc_nf_env.policy import make_policy
from atc_nf_env.scenarios import make_scenario

EPISODES = (("mpc", "converging-4", 0), ("nf", "converging-4", 0), ("nf", "converging-6", 0))


FROZEN_CALLS = [0]


@contextmanager
def frozen_kernel() -> Iterator[None]:
    """``kernel.advance`` replaced by the frozen copy's (same state layout and Trace fields)."""
    current = kernel.advance

    def advance(state, waypoints, wind_kt, seconds, params, *, record_every=0, scratch=None):
        FROZEN_CALLS[0] += 1
        return frozen.advance(state, waypoints, wind_kt, seconds, np.ascontiguousarray(params[: frozen.nf.N_PARAMS]),
                              record_every=record_every)

    kernel.advance = advance
    try:
        yield
    finally:
        kernel.advance = current


def fly(policy: str, scenario: str, seed: int, nudge: bool = False) -> EpisodeResult:
    encounter = make_scenario(scenario, seed=seed)
    if nudge:
        heading = np.array(encounter.start_heading, dtype=float)
        heading[0] = np.nextafter(heading[0], np.inf)
        encounter = dataclasses.replace(encounter, start_heading=heading)
    return run_episode(make_policy(policy), encounter, seed=seed, config=SimConfig(), record_every=1)


def compare(a: EpisodeResult, b: EpisodeResult) -> tuple[float, int]:
    """(largest position difference over the steps both flew, nm; steps compared)."""
    rows = min(len(a.records), len(b.records))
    ra, rb = a.records[:rows], b.records[:rows]
    both = (ra[..., R_FLEW] > 0) & (rb[..., R_FLEW] > 0)
    diff = np.hypot(ra[..., R_X] - rb[..., R_X], ra[..., R_Y] - rb[..., R_Y])
    return float(diff[both].max()) if both.any() else 0.0, rows


def outcome(result: EpisodeResult) -> str:
    m = result.metrics
    return (f"success {m.success}, arrived {sum(m.arrived)}/{m.n_aircraft}, LoS {m.los_count}, "
            f"min separation {m.min_separation_nm:.4f} nm, envelope violations {m.envelope_violation_fraction:.3g}, "
            f"flight times {[round(t, 3) for t in m.flight_time_min]} min")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.parse_args(argv)
    for policy, scenario, seed in EPISODES:
        current = fly(policy, scenario, seed)
        calls = FROZEN_CALLS[0]
        with frozen_kernel():
            old = fly(policy, scenario, seed)
            nudged = fly(policy, scenario, seed, nudge=True)
        if FROZEN_CALLS[0] == calls:
            raise RuntimeError("the frozen kernel was not called: the comparison would compare a kernel with itself")
        drift, rows = compare(current, old)
        sensitivity, _ = compare(nudged, old)
        print(f"{policy} {scenario} seed {seed}: max position difference {drift:.3g} nm over {rows} records; "
              f"records {len(old.records)} (frozen) vs {len(current.records)} (current); frozen kernel from a start "
              f"one ulp away: {sensitivity:.3g} nm")
        print(f"  frozen : {outcome(old)}")
        print(f"  current: {outcome(current)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
