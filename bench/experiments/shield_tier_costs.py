"""Where a shielded decision's prediction time goes, by kind of call: the check of the
proposal and each tier of alternatives (single-aircraft, all-aircraft, sampled).

The safety filter calls ``PlanPredictor.first_safe`` once to check the proposal and, if
that fails, once per tier until one finds a safe set (``atc_nf_env.shield``). This script
flies a shipped model inside the filter on seeds 0..SEEDS-1 of each scenario (one untimed
warm-up episode first) and wraps ``first_safe`` to time every call and read, from the
predictor's ``survived``, how many candidates each call flew, for how many integration
steps, and how many of them breached only in the look-ahead period (the second period,
every aircraft re-aimed home). A call's tier is told by its size: 1 candidate (the
check), 6 (the all-aircraft tier: four turns and two homing distances), 64 (the sampled
tier), a multiple of 10 (the single-aircraft tier: ten variants per suspect).

Run: python bench/experiments/shield_tier_costs.py [--model agents/models/finetuned_ppo.zip]
     [--scenarios converging-6,random-6] [--seeds 100]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def kind_of(n_candidates: int) -> str:
    if n_candidates == 1:
        return "check"
    if n_candidates == 6:
        return "all-aircraft"
    if n_candidates == 64:
        return "sampled"
    return "single-aircraft"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="agents/models/finetuned_ppo.zip")
    parser.add_argument("--scenarios", default="converging-6,random-6")
    parser.add_argument("--seeds", type=int, default=100)
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    from atc_nf_env import shield_prediction
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    calls: list[tuple[str, float, int, int, int, int]] = []
    first_safe = shield_prediction.PlanPredictor.first_safe

    def timed(self, state, candidates, wind_kt, **kwargs):
        t0 = time.perf_counter()
        index = first_safe(self, state, candidates, wind_kt, **kwargs)
        elapsed = time.perf_counter() - t0
        survived = self.survived[: candidates.shape[0]]
        flown = survived[survived >= 0]
        lookahead = int(((flown >= self.period_steps) & (flown < self.full_steps)).sum())
        calls.append((kind_of(candidates.shape[0]), elapsed, int(index >= 0), len(flown),
                      int(flown.sum() + (flown < self.full_steps).sum()), lookahead))
        return index

    shield_prediction.PlanPredictor.first_safe = timed
    print(f"{args.model} inside the safety filter, seeds 0..{args.seeds - 1}, sigma = 5.17 m/s")
    print("| scenario | call | calls | found a safe set | candidates flown per call | steps per candidate flown "
          "| candidates flown that breached only in the look-ahead period | mean time per call | per decision |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for scenario in [s for s in args.scenarios.split(",") if s]:
        shielded = SafetyFilter(make_policy(args.model))
        run_episode(shielded, make_scenario(scenario, seed=10**6), seed=10**6)  # warm-up, not counted
        calls.clear()
        decisions = 0
        for seed in range(args.seeds):
            decisions += len(run_episode(shielded, make_scenario(scenario, seed=seed), seed=seed).decision_s)
        for kind in ("check", "single-aircraft", "all-aircraft", "sampled"):
            rows = [c for c in calls if c[0] == kind]
            if not rows:
                continue
            elapsed = np.array([r[1] for r in rows])
            flown = sum(r[3] for r in rows)
            print(f"| {scenario} | {kind} | {len(rows)} | {sum(r[2] for r in rows)} | {flown / len(rows):.1f} "
                  f"| {sum(r[4] for r in rows) / max(flown, 1):.0f} | {sum(r[5] for r in rows) / max(flown, 1):.0%} "
                  f"| {elapsed.mean() * 1e6:.0f} µs | {elapsed.sum() / decisions * 1e6:.0f} µs |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
