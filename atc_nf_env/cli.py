"""The ``atc-nf`` command line."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from atc_nf_env.config import PHYSICS_PRESETS, SimConfig
from atc_nf_env.episode import MAX_EPISODE_S, run_episode, warm_up
from atc_nf_env.evaluate import BACKENDS, Study, evaluate
from atc_nf_env.metrics import format_run, peak_rss_mb, summarize
from atc_nf_env.policy import available_policies, make_policy
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.shield import SafetyFilter, summarize_interventions
from atc_nf_env.units import WIND_SIGMA_MPS

def _non_negative_float(text: str) -> float:
    value = float(text)
    if not value >= 0:  # also rejects NaN
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number >= 0")
    return value


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be an integer >= 1")
    return value


def _add_mpc_options(parser: argparse.ArgumentParser) -> None:
    # No argparse defaults here: an option left out is not passed, and the MPC keeps its
    # own (the paper's, except --proposal), which the help text quotes.
    group = parser.add_argument_group("MCMC-MPC settings (policy mpc; defaults are the paper's except --proposal)")
    group.add_argument("--extractions", type=_positive_int, help="K, proposals per decision (default: 1000)")
    group.add_argument("--horizon", type=_positive_int, help="N, periods in the horizon (default: 4)")
    group.add_argument("--wind-model", choices=("none", "sampled", "estimated"),
                       help="the MPC's prediction wind (default: estimated)")
    group.add_argument("--constraint-check", choices=("every-step", "sampling-instants"),
                       help="where the MPC checks the envelope and separation (default: every-step)")
    group.add_argument("--acceptance", choices=("standard", "table-i"),
                       help="Metropolis-Hastings acceptance: standard, or as printed in Table I (default: standard)")
    group.add_argument("--cost-exponent", type=float, help="J, the chain's target is C^-J (default: 1)")
    group.add_argument("--proposal", choices=("homing", "paper"),
                       help="homing (starts the chain aimed home, recovers missed aircraft, searches wider "
                            "before a fallback) or paper (Table I as printed) (default: homing)")
    group.add_argument("--search", choices=("lazy", "exhaustive"),
                       help="lazy flies a candidate only as far as the chain needs; exhaustive flies all K over "
                            "the whole horizon and measures every decision's feasible fraction; both pick the "
                            "same waypoints (default: lazy)")


def _policy_kwargs(args: argparse.Namespace) -> dict:
    names = ("extractions", "horizon", "wind_model", "constraint_check", "acceptance", "cost_exponent", "proposal",
             "search")
    kwargs = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    if kwargs and args.policy != "mpc":
        raise ValueError(f"--{next(iter(kwargs)).replace('_', '-')} applies to --policy mpc only")
    return kwargs


def _add_episode_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--policy",
        default="mpc",
        help=f"the policy: {', '.join(available_policies())} (mpc: the paper's MCMC-MPC, the reference; nf: the "
        "NF alone, which strands aircraft under wind), or a trained agent's PATH.zip (agents/models/*.zip)",
    )
    parser.add_argument(
        "--scenario",
        default="converging-4",
        help="converging-N (the paper's encounter: 3, 4, 6), random-N, or a scenario .json file",
    )
    parser.add_argument(
        "--wind-sigma",
        type=_non_negative_float,
        default=WIND_SIGMA_MPS,
        help="standard deviation of each wind component, m/s",
    )
    parser.add_argument("--seed", type=int, default=0, help="seeds the wind and the policy")
    parser.add_argument(
        "--max-minutes",
        type=_non_negative_float,
        default=MAX_EPISODE_S / 60,
        help="time limit of an episode, min",
    )
    parser.add_argument("--physics", choices=tuple(PHYSICS_PRESETS), default="default",
                        help="NF settings: default, or paper-nf (proximity range 30/15 nm: the paper's "
                        "22 nm NF-alone separation; see REPRODUCTION.md)")
    parser.add_argument("--summary-json", type=Path, help="write the summary metrics to this JSON file")
    parser.add_argument("--shield", action="store_true",
                        help="fly the policy inside the safety filter (atc_nf_env.shield): each waypoint set is "
                        "predicted two periods ahead and replaced by the closest safe alternative, or the MPC's "
                        "decision, when unsafe; the summary counts its interventions")
    _add_mpc_options(parser)


def _check_output_file(path: Path | None, option: str) -> None:
    """Refuse, before anything flies, an output file that cannot be written: a folder that
    does not exist (rather than create folders silently), a directory, no write access."""
    if path is None:
        return
    if path.is_dir():
        raise ValueError(f"{option} {path} is a directory; give a file path")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: the folder {path.parent} does not exist; create it first")
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"{option} {path} is not writable")


def _check_output_folder(path: Path | None, option: str) -> None:
    """Create an output folder now, or refuse it, before anything flies."""
    if path is None:
        return
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option} {path} is a file; give a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"{option} {path}: cannot create the folder: {error.strerror}") from None
    if not os.access(path, os.W_OK):
        raise ValueError(f"{option} {path} is not writable")


def _fly(args: argparse.Namespace) -> int:
    _check_output_file(args.summary_json, "--summary-json")
    _check_output_folder(args.plots, "--plots")
    _check_output_file(args.animate, "--animate")
    scenario = make_scenario(args.scenario, seed=args.seed)
    policy = make_policy(args.policy, **_policy_kwargs(args))
    if args.shield:
        policy = SafetyFilter(policy)
    record_every = 1 if (args.plots or args.animate) else 0
    config = SimConfig.preset(args.physics)
    compile_s = warm_up(policy, scenario, seed=args.seed, wind_sigma_mps=args.wind_sigma,
                        config=config, record_every=record_every)
    result = run_episode(
        policy,
        scenario,
        seed=args.seed,
        wind_sigma_mps=args.wind_sigma,
        max_time_s=args.max_minutes * 60.0,
        record_every=record_every,
        config=config,
    )
    print(format_run(result.metrics))
    print(f"  times above are warm; the warm-up before them (numba compiling or loading its cache, the "
          f"policy's first decision) took {compile_s:.2f} s (compile_s)")
    info = policy.episode_info() if hasattr(policy, "episode_info") else {}
    if info:
        print("  policy: " + ", ".join(f"{key} {value}" for key, value in info.items()))
    if args.summary_json:
        summary = summarize([result.metrics], peak_rss_mb=peak_rss_mb(), compile_s=compile_s)
        summary["policy"] = args.policy
        if len(result.decision_s):
            summary["decision_s"].update(median=float(np.median(result.decision_s)),
                                         p99=float(np.percentile(result.decision_s, 99)),
                                         max=float(result.decision_s.max()))
        shield = summarize_interventions([info])
        if shield is not None:
            summary["shield"] = shield
        info = dict(info)
        if "fallbacks" in info:  # at the top level, as in evaluate's summary
            summary["fallbacks"] = info.pop("fallbacks")
        summary["policy_info"] = info
        summary["run"] = result.metrics.to_dict()
        args.summary_json.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"summary written to {args.summary_json}")
    label = Path(args.policy).stem if args.policy.lower().endswith(".zip") else args.policy
    label += "+shield" if args.shield else ""
    if args.plots:
        from atc_nf_env.plotting import write_episode_plots

        paths = write_episode_plots(result, args.plots, f"{scenario.name}_{label}", policy=label,
                                    wind_sigma_mps=args.wind_sigma)
        print("figures written: " + ", ".join(str(p) for p in paths))
    if args.animate:
        from atc_nf_env.rendering import save_animation

        from atc_nf_env.plotting import episode_title

        title = episode_title(result, "", label, args.wind_sigma).rstrip(": ")
        print(f"animation written to {save_animation(result, args.animate, scenario=scenario, title=title)}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    _check_output_file(args.out, "--out")
    _check_output_file(args.summary_json, "--summary-json")
    study = Study(
        policy=args.policy,
        scenario=args.scenario,
        wind_sigma_mps=args.wind_sigma,
        policy_kwargs=_policy_kwargs(args),
        max_time_s=args.max_minutes * 60.0,
        physics=args.physics,
        shield=args.shield,
    )
    summary = evaluate(
        study,
        args.runs,
        first_seed=args.seed,
        workers=args.workers,
        backend=args.backend,
        out=args.out,
        resume=args.resume,
        progress=not args.no_progress,
    )
    summary["policy"] = args.policy
    text = json.dumps(summary, indent=2)
    print(text)
    if args.summary_json:
        args.summary_json.write_text(text + "\n")
        print(f"summary written to {args.summary_json}", file=sys.stderr)
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from atc_nf_env.experiments import reproduce

    return reproduce.main(args.rest)


def _train(args: argparse.Namespace) -> int:
    from agents import train

    return train.main(args.rest)


def _imitate(args: argparse.Namespace) -> int:
    from agents import imitate

    return imitate.main(args.rest)


#: Subcommands whose script owns its options (and its --help).
_DELEGATED = {"reproduce": _reproduce, "train": _train, "imitate": _imitate}


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every real default; an option without one (None, or off) says nothing."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="atc-nf",
        description="Aircraft under decentralized dipolar navigation functions with hidden wind.",
        formatter_class=HelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True)
    fly = sub.add_parser("fly", help="fly one episode and print its metrics", formatter_class=HelpFormatter)
    _add_episode_options(fly)
    fly.add_argument("--plots", type=Path,
                     help="write trajectory and airspeed figures into this folder (created if missing)")
    fly.add_argument("--animate", type=Path, help="write a GIF animation of the episode to this file")
    fly.set_defaults(handler=_fly)

    ev = sub.add_parser("evaluate", help="a Monte Carlo study: many seeded episodes, in parallel, resumable",
                        formatter_class=HelpFormatter)
    _add_episode_options(ev)
    ev.add_argument("--runs", type=_positive_int, default=100, help="number of episodes (seeds SEED..SEED+RUNS-1)")
    ev.add_argument("--workers", type=_positive_int,
                    help="worker processes (default and most: the usable cores; never more than the runs left)")
    ev.add_argument("--backend", choices=BACKENDS, default="local", help="local processes or a Ray cluster")
    ev.add_argument("--out", type=Path, help="JSON-lines file receiving every finished run")
    ev.add_argument("--resume", action="store_true", help="finish the study in --out, skipping runs already there")
    ev.add_argument("--no-progress", action="store_true", help="no progress bar")
    ev.set_defaults(handler=_evaluate)

    rep = sub.add_parser("reproduce", help="the paper's figures and the reproduction table from fresh runs",
                         add_help=False)
    rep.set_defaults(handler=_reproduce)

    tr = sub.add_parser("train", help="train a Stable-Baselines3 agent (PPO parameter-shared, or PPO/SAC centralized)",
                        add_help=False)
    tr.set_defaults(handler=_train)
    im = sub.add_parser("imitate", help="imitate the MCMC-MPC: demonstrations, behaviour cloning, DAgger, "
                        "PPO fine-tuning", add_help=False)
    im.set_defaults(handler=_imitate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in _DELEGATED:
        # The experiment or training script owns its options (and its --help).
        args = argparse.Namespace(command=argv[0], handler=_DELEGATED[argv[0]], rest=argv[1:])
    else:
        args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except ValueError as error:
        print(f"atc-nf {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # an output that cannot be written (e.g. reproduce --figures)
        print(f"atc-nf {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
