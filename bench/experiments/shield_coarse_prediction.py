"""The safety filter with its prediction flown at a coarser integration step, against the
default, side by side.

The filter predicts a proposal over two periods with the kernel at the flight's own step
(5 s). At B = 1 that one-world prediction is most of a shielded decision's time. This
experiment subclasses ``SafetyFilter`` so that its ``PlanPredictor`` flies at ``--dt`` s
(optionally with the separation minimum raised by ``--sep-margin`` nm, for what the coarser
sampling of the separation may miss), and flies a shipped model inside both filters on
seeds 0..SEEDS-1 of each scenario, alternating the order per seed. It prints per filter the
mean decision time, and safety per run: runs home, runs with a loss of separation, runs
with a step outside the envelope, the lowest separation, the mean flight time and the
decisions changed.

Not adopted (README, "Safety filter"): a coarser prediction is a different model of the
flight than the one the filter checks against, and would need the 1000-seed safety runs of
its own.

Run: python bench/experiments/shield_coarse_prediction.py [--model agents/models/finetuned_ppo.zip]
     [--seeds 40] [--scenarios converging-6,random-6] [--dt 10] [--sep-margin 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.episode import run_episode
from atc_nf_env.policy import make_policy
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.shield import SafetyFilter
from atc_nf_env.shield_prediction import PlanPredictor


def coarse_filter(dt_s: float, sep_margin_nm: float) -> type[SafetyFilter]:
    """A ``SafetyFilter`` whose prediction flies at ``dt_s`` with the separation minimum
    raised by ``sep_margin_nm``."""

    class CoarseFilter(SafetyFilter):
        def reset(self, scenario, config, seed=None):
            super().reset(scenario, config, seed)
            coarse = dataclasses.replace(self._config, dt_s=dt_s,
                                         separation_min_nm=config.separation_min_nm + sep_margin_nm)
            self._params = coarse.to_params(scenario.workspace_radius_nm, stop_on_violation=True)
            self._period_steps = kernel.steps_for(self.period_s, dt_s)
            self._predictor = PlanPredictor(self._params, self._period_steps, self.lookahead_periods,
                                            self.home_distance_nm, self.recovery_angle_rad, self._waypoint_limit_nm)

    return CoarseFilter


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="agents/models/finetuned_ppo.zip")
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--scenarios", default="converging-6,random-6")
    parser.add_argument("--dt", type=float, default=10.0)
    parser.add_argument("--sep-margin", type=float, default=0.0)
    args = parser.parse_args(argv)
    if args.seeds < 1 or not args.dt > 0 or args.sep_margin < 0:
        parser.error("--seeds must be >= 1, --dt > 0 and --sep-margin >= 0")
    variants = {"default": SafetyFilter, f"dt {args.dt:g} s, margin {args.sep_margin:g} nm":
                coarse_filter(args.dt, args.sep_margin)}
    for scenario in [s for s in args.scenarios.split(",") if s]:
        filters = {name: cls(make_policy(args.model)) for name, cls in variants.items()}
        for shielded in filters.values():
            run_episode(shielded, make_scenario(scenario, seed=10**6), seed=10**6)  # warm-up
        rows: dict[str, list[tuple]] = {name: [] for name in filters}
        for seed in range(args.seeds):
            order = list(filters.items())
            for name, shielded in order if seed % 2 else order[::-1]:
                result = run_episode(shielded, make_scenario(scenario, seed=seed), seed=seed)
                m = result.metrics
                arrived = [t for t, a in zip(m.flight_time_min, m.arrived) if a]
                rows[name].append((float(np.mean(result.decision_s)), m.success, m.los_count > 0,
                                   m.envelope_violation_fraction > 0, m.min_separation_nm,
                                   float(np.mean(arrived)) if arrived else float("nan"),
                                   shielded.episode_info()["shield_filtered"]))
        for name, runs in rows.items():
            a = np.array(runs, dtype=float)
            print(f"{scenario}, {name}: mean decision {a[:, 0].mean() * 1e6:.0f} µs; home {a[:, 1].sum():.0f}/{len(a)}, "
                  f"runs with LoS {a[:, 2].sum():.0f}, runs outside the envelope {a[:, 3].sum():.0f}, lowest separation "
                  f"{a[:, 4].min():.2f} nm, mean flight {np.nanmean(a[:, 5]):.2f} min, decisions changed {a[:, 6].sum():.0f}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
