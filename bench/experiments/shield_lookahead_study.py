"""The safety filter with one period of look-ahead against its default two, side by side:
what the second period buys in safety, and what it costs in time.

The filter predicts a proposal over the coming period and, by default, one more period in
which every aircraft is re-aimed home (``SafetyFilter(lookahead_periods=2)``). The second
period is about half of the check every decision pays, so it is the first thing to drop
for speed. This script flies shipped models inside both filters on the same seeds of each
scenario (alternating which goes first per seed) and prints, per filter, safety per run:
runs home, runs with a loss of separation, runs with an integration step outside the
[366, 540] kt envelope, the worst excursion outside it (kt); the decisions changed and the
mean decision (µs, warm: one untimed episode first).

Run: python bench/experiments/shield_lookahead_study.py [--models agents/models/finetuned_ppo.zip]
     [--scenarios random-4,random-6,converging-6] [--seeds 100] [--first-seed 1000]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", default="agents/models/finetuned_ppo.zip")
    parser.add_argument("--scenarios", default="random-4,random-6,converging-6")
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=1000)
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.first_seed < 0:
        parser.error("--seeds must be >= 1 and --first-seed >= 0")
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(f"seeds {seeds.start}..{seeds.stop - 1}, sigma = 5.17 m/s")
    print("| model | scenario | look-ahead (periods) | runs | home | runs with LoS | runs outside the envelope "
          "| worst excursion (kt) | decisions changed | mean decision |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for model in [m for m in args.models.split(",") if m]:
        for scenario in [s for s in args.scenarios.split(",") if s]:
            filters = {periods: SafetyFilter(make_policy(model), lookahead_periods=periods) for periods in (1, 2)}
            for shielded in filters.values():
                run_episode(shielded, make_scenario(scenario, seed=10**6), seed=10**6)  # warm-up, untimed
            rows: dict[int, list[tuple[float, ...]]] = {periods: [] for periods in filters}
            for k, seed in enumerate(seeds):
                order = list(filters.items())
                for periods, shielded in order if k % 2 else order[::-1]:
                    result = run_episode(shielded, make_scenario(scenario, seed=seed), seed=seed)
                    m = result.metrics
                    rows[periods].append((m.success, m.los_count > 0, m.envelope_violation_fraction > 0,
                                          m.worst_excursion_kt, shielded.episode_info()["shield_filtered"],
                                          float(np.sum(result.decision_s)), len(result.decision_s)))
            for periods, runs in rows.items():
                a = np.array(runs, dtype=float)
                print(f"| {model.rsplit('/', 1)[-1].removesuffix('.zip')} | {scenario} | {periods} | {len(a)} "
                      f"| {a[:, 0].sum():.0f} | {a[:, 1].sum():.0f} | {a[:, 2].sum():.0f} | {a[:, 3].max():.1f} "
                      f"| {a[:, 4].sum():.0f} | {a[:, 5].sum() / a[:, 6].sum() * 1e6:.0f} µs |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
