"""The NF alone as a floor: aimed at the destination (``nf``, ``baselines.NFDirect``) and
one leg ahead along the line home (``nf-leg``, ``baselines.NFLeg``), on encounters and on
traffic streams, under the paper's hidden wind.

Encounters: converging-4/6 and random-4/6, seeds 0..RUNS-1, each policy and two
variants of ``NFLeg`` (no turn limit, ``max_turn_rad = π``; aiming at the destination
itself within a leg, ``final_approach = "destination"``). Streams: stream-30/60/120
(2 h), seeds 0..STREAMS-1, ``nf`` and ``nf-leg``, and on the streams named by
``--shield`` both inside the safety filter too (slow on dense streams: the filter falls
back on the MPC). Every study is ``atc_nf_env.evaluate`` with one worker; reported per study:
runs with a loss of separation, runs with an integration step outside [366, 540] kt,
runs home (encounters: every aircraft arrived; streams: no flight left the workspace),
the share of steps outside the envelope, and for streams the throughput (flights
arrived per hour of the 2 h), the mean delay against the direct flight (over the
flights that arrived), LoS per flight hour and the most aircraft airborne at once.

Run: python bench/nf_floor_study.py [--runs 50] [--streams 3] [--shield stream-30,stream-60] [--write]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from _report import machine, publish  # bench/ is on sys.path when run as a script

ENCOUNTERS = ("converging-4", "converging-6", "random-4", "random-6")
STREAMS = ("stream-30", "stream-60", "stream-120")
#: (label, registered policy, settings) flown on the encounters.
ENCOUNTER_POLICIES = (
    ("nf", "nf", {}),
    ("nf-leg", "nf-leg", {}),
    ("nf-leg, max_turn_rad = π", "nf-leg", {"max_turn_rad": math.pi}),
    ('nf-leg, final_approach = "destination"', "nf-leg", {"final_approach": "destination"}),
)


def study(policy: str, settings: dict, scenario: str, runs: int, shield: bool) -> tuple[dict, float]:
    from atc_nf_env.evaluate import Study, evaluate

    start = time.perf_counter()
    summary = evaluate(Study(policy=policy, scenario=scenario, policy_kwargs=dict(settings), shield=shield), runs,
                       first_seed=0, workers=1, progress=False)
    return summary, time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=50, help="seeds per encounter (default 50)")
    parser.add_argument("--streams", type=int, default=3, help="seeds per stream (default 3)")
    parser.add_argument("--shield", default="", help="comma-separated streams also flown inside the safety filter "
                        f"(of {', '.join(STREAMS)}; default none)")
    parser.add_argument("--write", action="store_true", help="write the section into BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.streams < 1:
        parser.error("--runs and --streams must be >= 1")
    shielded = [name for name in args.shield.split(",") if name]
    if any(name not in STREAMS for name in shielded):
        parser.error(f"--shield {args.shield}: allowed: {', '.join(STREAMS)}, comma-separated")

    from atc_nf_env.policy import register_policy
    from baselines import NFLeg

    # In this process (one worker): the name resolves whether or not the package's entry
    # points were reinstalled since nf-leg was added.
    register_policy("nf-leg", NFLeg)

    encounter_rows = []
    for scenario in ENCOUNTERS:
        for label, policy, settings in ENCOUNTER_POLICIES:
            summary, wall = study(policy, settings, scenario, args.runs, False)
            encounter_rows.append(
                f"| {scenario} | {label} | {summary['runs']} | {summary['runs_with_los']} | "
                f"{summary['runs_with_envelope_violation']} | {round(summary['success_rate'] * summary['runs'])} | "
                f"{100 * summary['envelope_violation_fraction']:.2f} | {wall:.1f} |")
            print(encounter_rows[-1], file=sys.stderr)
    stream_rows = []
    for scenario in STREAMS:
        for policy in ("nf", "nf-leg"):
            for shield in (False, True) if scenario in shielded else (False,):
                summary, wall = study(policy, {}, scenario, args.streams, shield)
                s = summary["stream"]
                delay = s["delay_s"]["mean"]
                stream_rows.append(
                    f"| {scenario} | {policy}{' (shielded)' if shield else ''} | {summary['runs']} | "
                    f"{summary['runs_with_los']} | {summary['runs_with_envelope_violation']} | "
                    f"{round(summary['success_rate'] * summary['runs'])} | "
                    f"{100 * summary['envelope_violation_fraction']:.2f} | {s['throughput_per_hour']['mean']:.1f} | "
                    f"{'n/a' if delay is None else format(delay, '.0f')} | {s['los_per_flight_hour']:.3f} | "
                    f"{s['max_airborne']} | {wall:.1f} |")
                print(stream_rows[-1], file=sys.stderr)

    options = [f"--runs {args.runs}" if args.runs != 50 else "", f"--streams {args.streams}" if args.streams != 3 else "",
               f"--shield {','.join(shielded)}" if shielded else ""]
    command = " ".join(["python bench/nf_floor_study.py", *filter(None, options)])
    text = "\n".join([
        "## The NF alone as a floor: aimed at the destination, or a leg ahead",
        "",
        f"`{command}` ({machine()}). The NF alone aimed at the destination (`nf`, `NFDirect`) and "
        "130 nm ahead along the line home, turned at most 60° from the heading (`nf-leg`, `NFLeg`), under the "
        "paper's wind (σ 5.17 m/s), seeds from 0, one worker. Outside: runs with an integration step outside "
        "[366, 540] kt; home: runs where every aircraft arrived (streams: no flight left the workspace); "
        "% outside: the share of all aircraft-steps outside the envelope.",
        "",
        "| scenario | policy | runs | runs with LoS | runs outside | runs home | % steps outside | wall s |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
        *encounter_rows,
        "",
        "Traffic streams (2 h): throughput, flights arrived per hour of the 2 h (the sector starts empty); "
        "delay, the mean over the flights that arrived of flight time minus the direct flight's (straight line "
        "at 454 kt), s; LoS per flight hour, pooled; max airborne, the most at once over the runs.",
        "",
        "| stream | policy | runs | runs with LoS | runs outside | runs home | % steps outside | throughput /h | "
        "delay s | LoS per flight hour | max airborne | wall s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *stream_rows,
    ]) + "\n"
    return publish("nf-floor", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
