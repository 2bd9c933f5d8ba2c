"""The agents against the MCMC-MPC and the NF alone, with the Monte Carlo evaluator.

    python -m agents.benchmark --models agents/models/bc.zip,agents/models/dagger.zip --runs 200

For every scenario and policy this runs ``atc_nf_env.evaluate.evaluate`` (the evaluator of
``atc-nf evaluate``) on the seeds FIRST_SEED..FIRST_SEED+RUNS-1 (``--first-seed``, default 0;
the shipped tables use 0..RUNS-1: training used 10 000 and up, the imitation's quick
checks 5 000..; the benchmark suite's validation and test splits start at 10**9 and
2·10**9, ``atc_nf_env.benchmark``), keeps each study's runs in ``--out`` (JSON lines,
resumable: a rerun only flies what is missing), and writes the summaries (``--summary``)
and the markdown table (``--table``); ``agents/results/`` holds those behind the model zoo
table of ``agents/README.md`` (``python -m agents.zoo --write``).

``--shield`` adds, for every model, a study of the model inside the safety filter
(``atc_nf_env.shield.SafetyFilter``, ``atc-nf evaluate --shield``), labelled ``MODEL+shield``,
with the filter's interventions (decisions changed, aircraft changed, MPC fallbacks,
aircraft taken over by the progress rule and flown home) in
the table; the decision latency's mean and p99 are printed for every policy.

``--reuse-mpc DIR`` copies the MPC runs of the same seeds from an earlier study of the
same scenario (``atc-nf reproduce`` keeps its 1000-run studies of converging-4 and
converging-6 in ``out/reproduction``) instead of flying them again: the same study (policy,
settings, wind, time limit), the same seeds, hence the same runs; only the airspeed
series that the reproduction also recorded are dropped.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any, Sequence

from atc_nf_env.evaluate import STEP_TRACE_KEYS, Study, differing_header_keys, evaluate, read_results

SCENARIOS = "converging-4,converging-6,random-4"


def label_of(policy: str, shield: bool = False) -> str:
    return (Path(policy).stem if policy.endswith(".zip") else policy) + ("+shield" if shield else "")


def reuse_mpc_runs(study: Study, runs: int, source_dir: Path, target: Path, first_seed: int = 0) -> int:
    """Copy the MPC runs of seeds first_seed..first_seed+runs-1 of ``study`` from
    ``source_dir`` into ``target`` (a new results file); returns how many were copied."""
    if target.exists():
        return 0
    header = study.header()
    for path in sorted(source_dir.glob("*.jsonl")):
        old, records = read_results(path)
        if old is None:
            continue
        # Both ways: a shielded MPC study (its header has ``shield``) is another study.
        if differing_header_keys(old, header, ignore=("airspeed_every_s",)):
            continue
        chosen = sorted((r for r in records if first_seed <= r["seed"] < first_seed + runs), key=lambda r: r["seed"])
        if not chosen:
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with target.open("w") as handle:
            handle.write(json.dumps(header) + "\n")
            for record in chosen:
                record = {k: v for k, v in record.items() if k not in STEP_TRACE_KEYS}
                handle.write(json.dumps(record) + "\n")
        return len(chosen)
    return 0


def run(models: list[str], scenarios: list[str], runs: int, mpc_runs: int, out: Path, reuse_mpc: Path | None,
        workers: int | None, progress: bool, baselines: Sequence[str] = ("nf", "mpc"),
        shield: bool = False, first_seed: int = 0) -> dict[str, Any]:
    results: dict[str, Any] = {}
    plan = [(policy, False) for policy in [*baselines, *models]] + [(model, True) for model in models if shield]
    labels = [label_of(policy, shielded) for policy, shielded in plan]
    shared = sorted({label for label in labels if labels.count(label) > 1})
    if shared:
        # One label is one results file and one row: a second study would be refused on
        # resume, or (a model named mpc.zip) take the reference's row.
        raise ValueError(f"two studies would share the label {shared[0]!r} (its results file and table row): "
                         f"{', '.join(p for (p, s), l in zip(plan, labels) if l == shared[0])}; give each model "
                         "file a name of its own, and none a baseline's")
    for scenario in scenarios:
        results[scenario] = {}
        for policy, shielded in plan:
            n = mpc_runs if policy == "mpc" else runs
            study = Study(policy=policy, scenario=scenario, shield=shielded)
            label = label_of(policy, shielded)
            path = out / scenario / f"{label}.jsonl"
            if policy == "mpc" and reuse_mpc is not None:
                copied = reuse_mpc_runs(study, n, reuse_mpc, path, first_seed)
                if copied:
                    print(f"{scenario}: {copied} MPC runs copied from {reuse_mpc}", file=sys.stderr)
            print(f"{scenario}: {label} x {n}", file=sys.stderr)
            summary = evaluate(study, n, first_seed=first_seed, out=path, resume=path.exists(), workers=workers,
                               progress=progress)
            header = study.header()
            # What the cards and tables say about the runs: their settings and seeds.
            summary["study"] = {"wind_sigma_mps": header["wind_sigma_mps"], "max_time_s": header["max_time_s"],
                                "build": header["build"], "seeds": [first_seed, first_seed + n - 1]}
            # A shielded summary counts its breached runs itself (shield.runs_breached, ...).
            results[scenario][label] = summary
            p99 = summary["decision_s"].get("p99")
            print(f"{scenario}: {label} decision mean {_fmt_latency(summary['wall_s_per_decision'])} (over every "
                  f"decision), p99 {'n/a' if p99 is None else _fmt_latency(p99)}", file=sys.stderr)
    return results


def _fmt_latency(seconds: float) -> str:
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.1f} ms"
    return f"{seconds * 1e6:.0f} µs"


def _per_run(summary: dict[str, Any], key: str) -> str:
    value = summary.get(key)
    return "n/a" if value is None else str(value)


def _interventions(shield: dict[str, Any] | None) -> str:
    if not shield:
        return ""
    return (f"{shield['filtered']} of {shield['decisions']} ({100 * shield['filtered_fraction']:.1f} %) / "
            f"{shield['aircraft_changed']} / {shield.get('sampled_changes', 0)} / {shield['mpc_fallbacks']} / "
            f"{shield['stalled_aircraft']}")


def table(results: dict[str, Any]) -> str:
    """The markdown comparison table. Safety is counted per run (a run counts if any of
    its integration steps breached), next to the pooled share of steps; the success rate
    carries its Wilson 95 % interval."""
    lines = [
        "| scenario | policy | runs | success [95 % CI] | runs with LoS (LoS) | min separation (nm) | "
        "runs outside envelope | runs at airspeed cap | worst excursion (kt) | envelope held (% of steps) | "
        "mean flight time (min) | decision latency | MPC latency / agent's | decision p99 | "
        "shield: decisions changed / aircraft changed / settled by a sampled set / MPC fallbacks / "
        "aircraft taken over by the progress rule |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for scenario, by_policy in results.items():
        mpc = by_policy.get("mpc", {}).get("wall_s_per_decision")
        for label, s in by_policy.items():
            latency = s["wall_s_per_decision"]
            ratio = f"{mpc / latency:,.0f}×" if mpc and latency and label != "mpc" else "1×" if label == "mpc" else ""
            flight = s["flight_time_min"]["mean"]
            ci = s.get("success_rate_ci95")
            success = f"{100 * s['success_rate']:.1f} %" + (
                f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]" if ci else "")
            separation = s["min_separation_nm"]["min"]
            p99 = s["decision_s"].get("p99")
            worst = s.get("worst_envelope_excursion_kt", s.get("worst_excursion_kt"))
            lines.append(
                f"| {scenario} | {label} | {s['runs']} | {success} | {s['runs_with_los']} ({s['los_count']}) | "
                f"{'n/a' if separation is None else f'{separation:.2f}'} | "
                f"{_per_run(s, 'runs_with_envelope_violation')} | {_per_run(s, 'runs_at_airspeed_cap')} | "
                f"{'n/a' if worst is None else f'{worst:.0f}'} | "
                f"{100 * (1 - s['envelope_violation_fraction']):.2f} | "
                f"{'n/a' if flight is None else f'{flight:.1f}'} | {_fmt_latency(latency)} | {ratio} | "
                f"{_fmt_latency(p99) if p99 is not None else 'n/a'} | {_interventions(s.get('shield'))} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--models", default="", help="comma-separated model .zip files")
    parser.add_argument("--scenarios", default=SCENARIOS, help="comma-separated scenarios")
    parser.add_argument("--runs", type=int, default=200, help="runs per study (seeds FIRST_SEED..FIRST_SEED+RUNS-1)")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="the first seed of every study (e.g. a split of atc_nf_env.benchmark)")
    parser.add_argument("--mpc-runs", type=int, help="runs of the MPC's studies (default --runs)")
    parser.add_argument("--out", type=Path, default=Path("out/agents"), help="folder of the studies' runs")
    parser.add_argument("--reuse-mpc", type=Path, help="folder of earlier MPC studies to copy runs from")
    parser.add_argument("--summary", type=Path, default=Path("out/agents/summary.json"), help="summaries (JSON)")
    parser.add_argument("--table", type=Path, default=Path("out/agents/table.md"), help="the markdown table")
    parser.add_argument("--write-section", metavar="FILE#NAME",
                        help="also write the table, with the command that made it, into the marked section NAME "
                        "(<!-- begin NAME --> ... <!-- end NAME -->) of the Markdown FILE")
    parser.add_argument("--workers", type=int, help="worker processes (default: all cores)")
    parser.add_argument("--baselines", default="nf,mpc",
                        help="comma-separated reference policies flown before the models (empty: none)")
    parser.add_argument("--shield", action="store_true",
                        help="also evaluate every model inside the safety filter (rows MODEL+shield)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    section = None
    if args.write_section:
        path, _, name = args.write_section.partition("#")
        if not (path and name and Path(path).is_file()):
            parser.error(f"--write-section {args.write_section!r}: give FILE#NAME with an existing Markdown FILE")
        section = (Path(path), name)
    models = [m for m in args.models.split(",") if m]
    for model in models:
        if not Path(model).is_file():
            parser.error(f"--models: {model} does not exist")
    try:
        results = run(models, [s for s in args.scenarios.split(",") if s], args.runs, args.mpc_runs or args.runs,
                      args.out, args.reuse_mpc, args.workers, not args.no_progress,
                      [b for b in args.baselines.split(",") if b], args.shield, args.first_seed)
    except ValueError as error:
        print(f"agents.benchmark: error: {error}", file=sys.stderr)
        return 2
    args.summary.parent.mkdir(parents=True, exist_ok=True)
    args.summary.write_text(json.dumps(results, indent=2) + "\n")
    text = table(results)
    args.table.parent.mkdir(parents=True, exist_ok=True)
    args.table.write_text(text)
    print(text)
    if section is not None:
        from atc_nf_env.experiments.marked_sections import write_marked_section

        # Quoted so that the printed command runs as printed (an empty --baselines "" too).
        command = "python -m agents.benchmark " + shlex.join(argv if argv is not None else sys.argv[1:])
        write_marked_section(section[0], section[1], f"Generated by `{command}`:\n\n{text}")
        print(f"table written into {section[0]} (section {section[1]})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
