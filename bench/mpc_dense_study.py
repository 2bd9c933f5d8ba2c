"""The MCMC-MPC in dense traffic, per run: the joint sampler against conflict clusters.

Flies ``baselines.MCMCMPC`` on converging-N and random-N encounters of many aircraft
(σ = 5.17 m/s, the evaluator's 4-h limit) in these settings:

- ``auto``: the defaults (``joint`` on at most 6 aircraft, ``per-cluster`` on more and
  on streams: ``baselines.mcmc_mpc.MPCSettings.for_traffic``);
- ``joint``: every decision samples every aircraft's waypoint jointly (the paper's search);
- ``dense``: ``sampling="clusters"`` (when the chain's start breaks a constraint, the
  chain samples only the conflict cluster around the aircraft involved, the others keep
  their start) and the progress rule (``progress_fraction=0.5``, ``progress_periods=6``:
  an aircraft that closed less than half a direct flight's progress over 30 min is held
  on its recovery waypoint);
- ``per-cluster``: ``sampling="per-cluster"`` (each independent conflict cluster of the
  chain's start searched by a chain of its own) and the same progress rule; not in the
  default ``--settings``: above 6 aircraft and on streams its rows are ``auto``'s, bit for
  bit;
- ``per-cluster-70``: ``per-cluster`` with ``recovery_angle_rad`` 70° instead of 60° (the
  chain's start and the heading-relative share of the proposal turn up to 70° a period);
- ``per-cluster-approach-80``: ``per-cluster`` with ``approach_angle_rad`` 80°: within
  60 nm of home an aircraft turns up to 80° a period (60° elsewhere), against orbits near
  home.

Per row: runs; runs with every aircraft home; runs with a loss of separation; runs with
any integration step outside [366, 540] kt and the worst excursion; runs with a fallback
(a decision without a feasible candidate) and the fallbacks in all; runs in which an
aircraft flew more than 1.5× its direct distance, and the largest such ratio; the mean
and 99th-percentile decision time (warm), and the mean's ratio to the same setting's on
converging-4 measured in the same run; the seeds that failed any of these.

With ``--streams`` (e.g. ``stream-30,stream-60,stream-120``) it flies traffic streams too,
``--stream-runs`` runs each from ``--stream-first-seed``, into a table of their own: runs
with a flight that left the workspace, with a loss of separation, outside the envelope,
with a fallback; throughput, delay against the direct flight, the most airborne at once,
the decision times. ``--scenarios ''`` skips the encounters. With ``--shielded`` (e.g.
``agents/models/deepsets_mixed.zip,nf-leg``) the streams are flown by those proposers
inside the safety filter, whose MPC fallback flies each setting (section
"shielded-streams").

Run: python bench/mpc_dense_study.py --scenarios converging-12,converging-16,random-12,random-16 --runs 20
     (--write puts the table into BENCHMARKS.md; --workers W flies runs in W processes, which
     makes the decision times those of W processes sharing the machine)
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np

from baselines.mcmc_mpc import NAMED_SETTINGS

#: The settings compared, by name: ``baselines.mcmc_mpc.NAMED_SETTINGS`` ("auto", the
#: default, flies "joint" up to 6 aircraft and "per-cluster" above and on streams).
SETTINGS = {name: dict(settings) for name, settings in NAMED_SETTINGS.items()}
#: What ``--settings`` flies when left out: every named setting but "per-cluster", whose
#: rows above 6 aircraft are "auto"'s.
DEFAULT_SETTINGS = ("auto", "joint", "dense", "per-cluster-70", "per-cluster-approach-80")
#: How the tables describe "auto", whose settings are the defaults.
AUTO_DESCRIBED = "the defaults: joint up to 6 aircraft, per-cluster above"
#: A run fails the detour goal when an aircraft flies more than this times its direct distance.
DETOUR_LIMIT = 1.5
#: The reference of the decision-time ratio.
REFERENCE_SCENARIO = "converging-4"


def fly(setting: str, scenario_name: str, seed: int) -> dict:
    """One run: its per-run outcomes and decision times (s)."""
    from atc_nf_env.episode import run_episode, scenario_for_seed
    from baselines.mcmc_mpc import MCMCMPC

    policy = MCMCMPC(**SETTINGS[setting])
    scenario = scenario_for_seed(scenario_name, seed)
    result = run_episode(policy, scenario, seed=seed)
    metrics = result.metrics
    direct = np.hypot(*(scenario.dest_xy - scenario.start_xy).T)
    detour = float((np.asarray(metrics.path_length_nm) / direct).max())
    return {
        "seed": seed,
        "home": bool(all(metrics.arrived)),
        "los": metrics.los_count > 0,
        "excursion": float(metrics.worst_excursion_kt),
        "fallbacks": int(policy.episode_info()["fallbacks"]),
        "detour": detour,
        "decision_s": [float(t) for t in result.decision_s],
    }


def _fly_packed(job: tuple[str, str, int]) -> dict:
    return fly(*job)


def fly_all(packed: Callable[[tuple[str, str, int]], dict], jobs: list[tuple[str, str, int]], workers: int) -> list[dict]:
    """``packed`` over ``jobs``, in ``workers`` processes (in this one when 1), in order.
    Each worker flies on one numba thread, as the evaluator's do: W workers each on every
    core's thread made 16 workers on 16 cores 9× slower per decision."""
    if workers > 1:
        import multiprocessing as mp

        from atc_nf_env.evaluate import _worker_init

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_worker_init) as pool:
            return list(pool.map(packed, jobs))
    return [packed(job) for job in jobs]


def _shielded(proposer: str, setting: str):
    """``proposer`` (a registered policy, or a model file of ``agents``) inside the safety
    filter, whose MPC fallback flies ``setting``."""
    from atc_nf_env.policy import make_policy
    from atc_nf_env.shield import SafetyFilter

    if proposer.endswith(".zip"):
        from agents.policy import SB3AgentPolicy

        # Streams lie outside every shipped model's stated operating range (3-10 aircraft).
        inner = SB3AgentPolicy(Path(proposer), outside_range="ignore")
    else:
        inner = make_policy(proposer)
    # On a stream the filter's fallback flies its settings over STREAM_FALLBACK_MPC_SETTINGS:
    # a setting that does not name the progress rule ("joint", "auto") turns it off there.
    return SafetyFilter(inner, mpc_settings={"sampling": "auto", "progress_fraction": None, **SETTINGS[setting]})


def fly_stream(setting: str, stream_name: str, seed: int, proposer: str = "") -> dict:
    """One run of a traffic stream: its per-run outcomes, the stream's metrics and the
    decision times (s). ``proposer``: fly it inside the safety filter instead of the MPC
    alone (the MPC in ``setting`` is the filter's fallback)."""
    from atc_nf_env.episode import run_episode
    from baselines.mcmc_mpc import MCMCMPC

    policy = _shielded(proposer, setting) if proposer else MCMCMPC(**SETTINGS[setting])
    result = run_episode(policy, stream_name, seed=seed)
    metrics = result.metrics
    stream = metrics.stream
    info = policy.episode_info()
    return {
        "seed": seed,
        "home": bool(metrics.success),  # no flight left the workspace
        "los": metrics.los_count > 0,
        "excursion": float(metrics.worst_excursion_kt),
        # Shielded: the decisions the filter left to the MPC, then those it could not make safe.
        "fallbacks": int(info["shield_mpc_fallbacks"] if proposer else info["fallbacks"]),
        "unresolved": int(info.get("shield_unresolved", 0)),
        "throughput_per_hour": float(stream["throughput_per_hour"]),
        "delay_s": stream["delay_s"]["mean"],
        "max_airborne": int(stream["max_airborne"]),
        "completed": int(stream["flights_completed"]),
        "entered": int(stream["flights_entered"]),
        "decision_s": [float(t) for t in result.decision_s],
    }


def _fly_stream_packed(job: tuple) -> dict:
    return fly_stream(*job)


def stream_study(setting: str, stream_name: str, seeds: range, workers: int, proposer: str = "") -> dict:
    """Per-run outcomes of ``setting`` on the traffic stream ``stream_name`` over ``seeds``
    (of ``proposer`` inside the safety filter, when given)."""
    runs = fly_all(_fly_stream_packed, [(setting, stream_name, seed, proposer) for seed in seeds], workers)
    decisions = np.concatenate([r["decision_s"] for r in runs])
    delays = [r["delay_s"] for r in runs if r["delay_s"] is not None]
    return {
        "runs": len(runs),
        "left": sum(not r["home"] for r in runs),
        "los": sum(r["los"] for r in runs),
        "outside": sum(r["excursion"] > 0 for r in runs),
        "worst": max(r["excursion"] for r in runs),
        "fallback_runs": sum(r["fallbacks"] > 0 for r in runs),
        "fallbacks": sum(r["fallbacks"] for r in runs),
        "unresolved": sum(r["unresolved"] for r in runs),
        "decisions": int(decisions.size),
        "throughput": float(np.mean([r["throughput_per_hour"] for r in runs])),
        "delay_s": float(np.mean(delays)) if delays else None,
        "max_airborne": max(r["max_airborne"] for r in runs),
        "completed": sum(r["completed"] for r in runs),
        "entered": sum(r["entered"] for r in runs),
        "decision_mean_ms": 1e3 * float(decisions.mean()),
        "decision_p99_ms": 1e3 * float(np.percentile(decisions, 99)),
        # Shielded, a decision left to the MPC is no failure; one it could not make safe is.
        "failed": [r["seed"] for r in runs if not r["home"] or r["los"] or r["excursion"] > 0
                   or (r["unresolved"] if proposer else r["fallbacks"])],
    }


def stream_section(settings: list[str], streams: list[str], seeds: range, workers: int,
                   proposers: list[str] | None = None) -> str:
    """The streams' table: the MPC alone in each setting, or (``proposers``) each proposer
    inside the safety filter with the MPC in each setting as its fallback."""
    shielded = proposers is not None
    rows = [
        "| setting | " + ("proposer | " if shielded else "") + "stream | runs | runs with a flight that left "
        "| runs with LoS | runs outside envelope (worst kt) "
        + ("| runs left to the MPC (decisions left of all; unresolved) " if shielded else
           "| runs with a fallback (fallbacks of decisions) ")
        + "| flights completed / entered | throughput /h | delay s | max airborne | decision mean / p99 (ms) "
        "| seeds failing any |",
        "|---|" + ("---|" if shielded else "") + "---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for setting in settings:
        for proposer in proposers or [""]:
            for stream in streams:
                r = stream_study(setting, stream, seeds, workers, proposer)
                failed = " ".join(map(str, r["failed"][:4])) + (" …" if len(r["failed"]) > 4 else "")
                delay = "–" if r["delay_s"] is None else f"{r['delay_s']:.0f}"
                left_to_mpc = (f"{r['fallback_runs']} ({r['fallbacks']} of {r['decisions']}; {r['unresolved']})"
                               if shielded else f"{r['fallback_runs']} ({r['fallbacks']} of {r['decisions']})")
                rows.append(
                    f"| {setting} | " + (f"{Path(proposer).stem} | " if shielded else "")
                    + f"{stream} | {r['runs']} | {r['left']} | {r['los']} | {r['outside']} ({r['worst']:.0f}) "
                    f"| {left_to_mpc} | {r['completed']} / {r['entered']} "
                    f"| {r['throughput']:.1f} | {delay} | {r['max_airborne']} "
                    f"| {r['decision_mean_ms']:.0f} / {r['decision_p99_ms']:.0f} | {failed or '—'} |"
                )
                print(rows[-1], flush=True)
    return "\n".join(rows)


def study(setting: str, scenario_name: str, seeds: range, workers: int) -> dict:
    """Per-run outcomes of ``setting`` on ``scenario_name`` over ``seeds``."""
    runs = fly_all(_fly_packed, [(setting, scenario_name, seed) for seed in seeds], workers)
    decisions = np.concatenate([r["decision_s"] for r in runs])
    failed = [r["seed"] for r in runs
              if not r["home"] or r["los"] or r["excursion"] > 0 or r["fallbacks"] or r["detour"] > DETOUR_LIMIT]
    return {
        "runs": len(runs),
        "home": sum(r["home"] for r in runs),
        "los": sum(r["los"] for r in runs),
        "outside": sum(r["excursion"] > 0 for r in runs),
        "worst": max(r["excursion"] for r in runs),
        "fallback_runs": sum(r["fallbacks"] > 0 for r in runs),
        "fallbacks": sum(r["fallbacks"] for r in runs),
        "detour_runs": sum(r["detour"] > DETOUR_LIMIT for r in runs),
        "detour_max": max(r["detour"] for r in runs),
        "decision_mean_ms": 1e3 * float(decisions.mean()),
        "decision_p99_ms": 1e3 * float(np.percentile(decisions, 99)),
        "failed": failed,
    }


def main(argv: list[str] | None = None) -> int:
    from _report import machine, publish  # bench/ is on sys.path when run as a script

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settings", default=",".join(DEFAULT_SETTINGS),
                        help=f"of {', '.join(SETTINGS)} (default: {','.join(DEFAULT_SETTINGS)})")
    parser.add_argument("--scenarios", default="converging-12,converging-16,random-12,random-16")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1_100_000,
                        help="seeds first-seed .. first-seed + runs - 1 (default: seeds no development run used)")
    parser.add_argument("--streams", default="", help="traffic streams to fly too, e.g. stream-30,stream-60")
    parser.add_argument("--stream-runs", type=int, default=3)
    parser.add_argument("--stream-first-seed", type=int, default=3_100_000_000,
                        help="seeds of the streams (default: in the stream tasks' training range, never flown)")
    parser.add_argument("--shielded", default="",
                        help="with --streams: fly these proposers (registered policies, or model files such as "
                             "agents/models/deepsets_mixed.zip) inside the safety filter instead of the MPC alone, the "
                             "MPC in each setting as the filter's fallback (BENCHMARKS section shielded-streams)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--section", default="mpc-dense",
                        help="BENCHMARKS.md section of the encounters' table (another name keeps the default's)")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    settings = [s for s in args.settings.split(",") if s]
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        parser.error(f"--settings {','.join(unknown)}: allowed: {', '.join(SETTINGS)}")
    if args.runs < 1 or args.workers < 1 or args.first_seed < 0 or args.stream_runs < 1 or args.stream_first_seed < 0:
        parser.error("--runs, --stream-runs and --workers must be >= 1, --first-seed and --stream-first-seed >= 0")
    seeds = range(args.first_seed, args.first_seed + args.runs)
    scenarios = [s for s in args.scenarios.split(",") if s]
    streams = [s for s in args.streams.split(",") if s]
    status = 0
    if scenarios:
        status = encounter_table(args, settings, scenarios, seeds)
    if streams:
        stream_seeds = range(args.stream_first_seed, args.stream_first_seed + args.stream_runs)
        proposers = [p for p in args.shielded.split(",") if p]
        rows = stream_section(settings, streams, stream_seeds, args.workers, proposers or None)
        command = (f"python bench/mpc_dense_study.py --settings {','.join(settings)} --scenarios '' --streams "
                   f"{args.streams} --stream-runs {args.stream_runs} --stream-first-seed {args.stream_first_seed} "
                   + (f"--shielded {args.shielded} " if proposers else "") + f"--workers {args.workers}")
        what = ("each proposer inside the safety filter (`atc_nf_env.shield.SafetyFilter`, its defaults), whose "
                "fallback is `baselines.MCMCMPC` in the setting named; a decision left to the MPC is one no "
                "alternative of the filter made safe, unresolved: one the MPC's choice did not make safe either"
                if proposers else "`baselines.MCMCMPC` in the settings above; a fallback: a decision without a "
                "feasible candidate")
        text = "\n".join([
            "## Shielded policies on traffic streams" if proposers else "## MCMC-MPC on traffic streams",
            "",
            f"`{command}` ({machine()}) — {what}; seeds {stream_seeds.start}–"
            f"{stream_seeds.stop - 1}, σ = 5.17 m/s, 2 h of traffic each; outcomes per run (a flight that left: "
            "it left the workspace instead of arriving; outside the envelope: any integration step outside "
            "[366, 540] kt). Throughput: flights arrived per "
            "hour (the sector starts empty), the mean over runs; delay: flight time minus the direct flight's "
            "(straight line at 454 kt), s, over the flights that arrived. Decision times warm, in this run.",
            "",
            rows,
        ])
        status = publish("shielded-streams" if proposers else "mpc-streams", text, args.write) or status
    return status


def encounter_table(args: argparse.Namespace, settings: list[str], scenarios: list[str], seeds: range) -> int:
    from _report import machine, publish

    rows = [
        "| setting | scenario | runs | every aircraft home | runs with LoS | runs outside envelope (worst kt) "
        f"| runs with a fallback (fallbacks) | runs with a path > {DETOUR_LIMIT}× direct (largest) "
        f"| decision mean / p99 (ms) | mean ÷ {REFERENCE_SCENARIO}'s | seeds failing any |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for setting in settings:
        reference = study(setting, REFERENCE_SCENARIO, seeds, args.workers)
        for scenario in [REFERENCE_SCENARIO] + scenarios:
            r = reference if scenario == REFERENCE_SCENARIO else study(setting, scenario, seeds, args.workers)
            failed = " ".join(map(str, r["failed"][:8])) + (" …" if len(r["failed"]) > 8 else "")
            rows.append(
                f"| {setting} | {scenario} | {r['runs']} | {r['home']} | {r['los']} | {r['outside']} ({r['worst']:.0f}) "
                f"| {r['fallback_runs']} ({r['fallbacks']}) | {r['detour_runs']} ({r['detour_max']:.2f}) "
                f"| {r['decision_mean_ms']:.1f} / {r['decision_p99_ms']:.0f} "
                f"| {r['decision_mean_ms'] / reference['decision_mean_ms']:.1f} | {failed or '—'} |"
            )
            print(rows[-1], flush=True)
    command = (f"python bench/mpc_dense_study.py --settings {','.join(settings)} --scenarios {args.scenarios} "
               f"--runs {args.runs} --first-seed {args.first_seed} --workers {args.workers}"
               + ("" if args.section == "mpc-dense" else f" --section {args.section}"))
    title = "MCMC-MPC in dense traffic" + ("" if args.section == "mpc-dense" else
                                           f": {', '.join(settings)}, {args.runs} runs")
    described = "; ".join(f"{name}: {', '.join(f'{k}={v!r}' for k, v in SETTINGS[name].items()) or AUTO_DESCRIBED}"
                          for name in settings)
    text = "\n".join([
        f"## {title}",
        "",
        f"`{command}` ({machine()}) — `baselines.MCMCMPC` ({described}), seeds "
        f"{seeds.start}–{seeds.stop - 1}, σ = 5.17 m/s, "
        "4-h limit; outcomes per run (outside the envelope: any integration step outside [366, 540] kt; a "
        "fallback: a decision without a feasible candidate). Decision times warm, in this run.",
        "",
        *rows,
    ])
    return publish(args.section, text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
