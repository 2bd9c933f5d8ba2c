"""Two policies flown on the same seeds, episode by episode in alternating order, in one
process: the machine's load then moves both alike, and their decision times compare
(``shield_screen_ab.py``, ``agent_buffers_ab.py``)."""

from __future__ import annotations

from typing import Any

import numpy as np


def fly_alternately(policies: dict[str, Any], scenario_name: str, seeds: int) -> str:
    """Fly the two ``policies`` (label -> policy; the first is the baseline) on seeds
    0..seeds-1 of ``scenario_name`` after an untimed warm-up episode each, stopping if they
    ever apply different waypoints. Returns a line: each one's mean and median decision
    (µs) and the median, over seeds, of each seed's mean decision second / first, with its
    quartiles."""
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario

    first, second = policies
    for policy in policies.values():  # loads and compiles, not timed
        run_episode(policy, make_scenario(scenario_name, seed=10**6), seed=10**6)
    times: dict[str, list[float]] = {first: [], second: []}
    per_seed: dict[str, list[float]] = {first: [], second: []}
    for seed in range(seeds):
        flown = {}
        for label in ((first, second) if seed % 2 else (second, first)):
            result = run_episode(policies[label], make_scenario(scenario_name, seed=seed), seed=seed)
            flown[label] = result.waypoints
            times[label] += list(result.decision_s)
            per_seed[label].append(float(np.mean(result.decision_s)))
        if not np.array_equal(flown[first], flown[second]):
            raise SystemExit(f"{scenario_name} seed {seed}: {first} and {second} applied different waypoints")
    a, b = (np.array(times[label]) * 1e6 for label in (first, second))
    q25, q50, q75 = np.percentile(np.array(per_seed[second]) / np.array(per_seed[first]), [25, 50, 75])
    return (f"{first} mean {a.mean():.1f} µs, median {np.median(a):.1f} µs; {second} mean {b.mean():.1f} µs, "
            f"median {np.median(b):.1f} µs; {second}/{first} per seed {q50:.3f} [{q25:.3f}-{q75:.3f}]")
