"""The ``atc-nf`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from atc_nf_env.episode import MAX_EPISODE_S, run_episode
from atc_nf_env.metrics import format_run, peak_rss_mb, summarize
from atc_nf_env.policy import Policy
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.units import WIND_SIGMA_MPS

POLICIES = ("nf",)


def make_policy(name: str) -> Policy:
    """A policy by its command-line name."""
    if name == "nf":
        from baselines import NFDirect

        return NFDirect()
    raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(POLICIES)}")


def _non_negative_float(text: str) -> float:
    value = float(text)
    if not value >= 0:  # also rejects NaN
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number >= 0")
    return value


def _add_episode_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--policy", default="nf", help=f"the policy: {', '.join(POLICIES)}")
    parser.add_argument(
        "--scenario",
        default="converging-4",
        help="converging-N (the paper's encounter: 3, 4, 6), random-N, or a scenario .json file",
    )
    parser.add_argument(
        "--wind-sigma",
        type=_non_negative_float,
        default=WIND_SIGMA_MPS,
        help=f"standard deviation of each wind component, m/s (default {WIND_SIGMA_MPS})",
    )
    parser.add_argument("--seed", type=int, default=0, help="seeds the wind and the policy")
    parser.add_argument(
        "--max-minutes",
        type=_non_negative_float,
        default=MAX_EPISODE_S / 60,
        help="time limit of an episode, min",
    )
    parser.add_argument("--summary-json", type=Path, help="write the summary metrics to this JSON file")


def _fly(args: argparse.Namespace) -> int:
    scenario = make_scenario(args.scenario, seed=args.seed)
    policy = make_policy(args.policy)
    result = run_episode(
        policy,
        scenario,
        seed=args.seed,
        wind_sigma_mps=args.wind_sigma,
        max_time_s=args.max_minutes * 60.0,
        record_every=1 if args.plots else 0,
    )
    print(format_run(result.metrics))
    if args.summary_json:
        summary = summarize([result.metrics], peak_rss_mb=peak_rss_mb())
        summary["policy"] = args.policy
        summary["run"] = result.metrics.to_dict()
        args.summary_json.parent.mkdir(parents=True, exist_ok=True)
        args.summary_json.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"summary written to {args.summary_json}")
    if args.plots:
        from atc_nf_env.plotting import write_episode_plots

        paths = write_episode_plots(result, args.plots, f"{scenario.name}_{args.policy}")
        print("figures written: " + ", ".join(str(p) for p in paths))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="atc-nf",
        description="Aircraft under decentralized dipolar navigation functions with hidden wind.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    fly = sub.add_parser("fly", help="fly one episode and print its metrics")
    _add_episode_options(fly)
    fly.add_argument("--plots", type=Path, help="write trajectory and airspeed figures into this folder")
    fly.set_defaults(handler=_fly)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except ValueError as error:
        print(f"atc-nf {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
