"""The safety filter's stall rule, off and on, per run.

An aircraft that the wrapped policy holds, circles or flies away from home (the filter
only guards safety, so it lets that pass) keeps a run from bringing every aircraft home.
The filter's stall rule (on by default: ``stall_progress_nm=0.0``, ``stall_periods=4``)
hands an aircraft that came no closer to its destination over the last 4 periods to the
MCMC-MPC's decision until it arrives. For each model and scenario this flies seeds
0..SEEDS-1 (σ = 5.17 m/s, the evaluator's 4-h limit) inside the filter with the rule off
(``stall_progress_nm=None``) and on (the defaults), and
prints per run: runs with every aircraft home, runs with LoS, runs with any integration
step outside [366, 540] kt, aircraft handed over, the longest flight, and the seeds that
failed or were handed over.

Run: python bench/shield_stall_study.py --models agents/models/deepsets_mixed.zip
     --scenarios random-7,random-8 --seeds 100  (writes BENCHMARKS.md with --write, into
     the section named by --section)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _report import publish  # bench/ is on sys.path when run as a script


def study(model: str, scenario_name: str, seeds: int, stall: bool) -> dict:
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    shield = SafetyFilter(make_policy(model)) if stall else SafetyFilter(make_policy(model), progress_fraction=None)
    home = los = outside = handed = 0
    longest = 0.0
    failed, handed_seeds = [], []
    for seed in range(seeds):
        metrics = run_episode(shield, make_scenario(scenario_name, seed=seed), seed=seed).metrics
        info = shield.episode_info()
        home += metrics.success
        los += metrics.los_count > 0
        outside += metrics.worst_excursion_kt > 0
        handed += info["shield_stalled_aircraft"]
        longest = max(longest, max(metrics.flight_time_min))
        if not metrics.success:
            failed.append(seed)
        if info["shield_stalled_aircraft"]:
            handed_seeds.append(seed)
    return {"home": home, "los": los, "outside": outside, "handed": handed, "longest": longest,
            "failed": failed, "handed_seeds": handed_seeds}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="agents/models/deepsets_mixed.zip")
    parser.add_argument("--scenarios", default="random-7,random-8")
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    parser.add_argument("--section", default="shield-stall", help="name of the BENCHMARKS.md section to write")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    rows = [
        "| scenario | model | stall rule | runs | every aircraft home | runs with LoS | runs outside envelope "
        "| aircraft handed to the MPC | longest flight (min) | seeds not home | seeds handed over |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for scenario in [s for s in args.scenarios.split(",") if s]:
        for model in [m for m in args.models.split(",") if m]:
            for stall in (False, True):
                r = study(model, scenario, args.seeds, stall)
                rows.append(
                    f"| {scenario} | {Path(model).stem} | {'on' if stall else 'off'} | {args.seeds} | {r['home']} "
                    f"| {r['los']} | {r['outside']} | {r['handed']} | {r['longest']:.1f} "
                    f"| {' '.join(map(str, r['failed'])) or '—'} | {' '.join(map(str, r['handed_seeds'])) or '—'} |"
                )
                print(rows[-1], flush=True)
    text = "\n".join([
        "## Safety filter: the stall rule" + ("" if args.section == "shield-stall" else f" ({args.scenarios})"),
        "",
        f"`python bench/shield_stall_study.py --models {args.models} --scenarios {args.scenarios} --seeds "
        f"{args.seeds}" + ("" if args.section == "shield-stall" else f" --section {args.section}") + "` — each model "
        "inside `atc_nf_env.shield.SafetyFilter` with the stall rule off (`stall_progress_nm=None`) and on (the "
        "default: an aircraft no closer to home than 4 periods ago is flown by the MCMC-MPC's decision until it "
        "arrives), held-out seeds from 0, σ = 5.17 m/s, 4-h limit; safety per run.",
        "",
        *rows,
    ])
    return publish(args.section, text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
