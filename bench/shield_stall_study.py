"""The safety filter's progress rule, off and on, per run.

An aircraft that the wrapped policy holds, circles or flies away from home (the safety
checks let that pass) keeps a run from bringing every aircraft home. The filter's progress
rule (on by default: ``progress_fraction=0.5``, ``progress_periods=3``) takes from the
policy an aircraft that closed less than half of a direct flight's progress at 454 kt over
the last 3 periods (or, that close to home, did not arrive) and flies it by its homing
waypoint until it arrives. For each model and scenario this flies seeds 0..SEEDS-1
(σ = 5.17 m/s, the evaluator's 4-h limit) inside the filter with the rule off
(``progress_fraction=None``) and on (the defaults), and
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


def study(model: str, scenario_name: str, seeds: int, rule: bool) -> dict:
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    shield = SafetyFilter(make_policy(model)) if rule else SafetyFilter(make_policy(model), progress_fraction=None)
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
        "| scenario | model | progress rule | runs | every aircraft home | runs with LoS | runs outside envelope "
        "| aircraft handed over | longest flight (min) | seeds not home | seeds handed over |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for scenario in [s for s in args.scenarios.split(",") if s]:
        for model in [m for m in args.models.split(",") if m]:
            for rule in (False, True):
                r = study(model, scenario, args.seeds, rule)
                rows.append(
                    f"| {scenario} | {Path(model).stem} | {'on' if rule else 'off'} | {args.seeds} | {r['home']} "
                    f"| {r['los']} | {r['outside']} | {r['handed']} | {r['longest']:.1f} "
                    f"| {' '.join(map(str, r['failed'])) or '—'} | {' '.join(map(str, r['handed_seeds'])) or '—'} |"
                )
                print(rows[-1], flush=True)
    text = "\n".join([
        "## Safety filter: the progress rule" + ("" if args.section == "shield-stall" else f" ({args.scenarios})"),
        "",
        f"`python bench/shield_stall_study.py --models {args.models} --scenarios {args.scenarios} --seeds "
        f"{args.seeds}" + ("" if args.section == "shield-stall" else f" --section {args.section}") + "` — each model "
        "inside `atc_nf_env.shield.SafetyFilter` with the progress rule off (`progress_fraction=None`) and on (the "
        "default: an aircraft that closed less than half of a direct flight's progress over the last 3 periods, or "
        "did not arrive from that close, flies its homing waypoint until it arrives), held-out seeds from 0, "
        "σ = 5.17 m/s, 4-h limit; safety per run.",
        "",
        *rows,
    ])
    return publish(args.section, text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
