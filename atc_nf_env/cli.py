"""The ``atc-nf`` command line.

``fly``, ``evaluate`` and ``reproduce`` are the core's own subcommands; more come from the
``atc_nf_env.commands`` entry-point group (this project declares ``train`` and ``imitate``,
the agents' scripts, there), each loaded only when it runs. A subcommand whose extra is
not installed says which extra to install. Each subcommand's options are built, and the
simulator imported, only when that subcommand is asked for: ``atc-nf --help`` imports
neither numba nor torch.

What ``fly`` and ``evaluate`` print is for people (aligned tables, rounded); the JSON goes
to files (``--summary-json``, ``--out``).
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

#: Entry-point group of further subcommands: ``NAME = "module:main"``, where
#: ``main(argv)`` parses its own options (and its --help) and returns the exit status.
COMMAND_GROUP = "atc_nf_env.commands"

#: The core's subcommands and their one-line help.
CORE_COMMANDS = {
    "fly": "fly one episode and print a table per aircraft",
    "evaluate": "a Monte Carlo study: many seeded episodes, in parallel, resumable",
    "reproduce": "the paper's figures and the reproduction table from fresh runs (into out/ unless --write)",
    "benchmark": "score a policy on a task of the benchmark suite (a score card, safety first)",
    "dataset": "record a policy on a benchmark task as a local Minari dataset; needs the dataset extra",
}
#: One-line help of the subcommands this project declares in ``COMMAND_GROUP`` (any
#: other installed subcommand is listed with the module that provides it).
_PLUGIN_HELP = {
    "train": "train a Stable-Baselines3 agent (PPO parameter-shared, or PPO/SAC centralized); needs the rl extra",
    "imitate": "imitate the MCMC-MPC: demonstrations, behaviour cloning, DAgger, PPO fine-tuning; needs the rl extra",
}
#: Subcommands whose module owns its options (and its --help): ``module.main(argv)``.
_DELEGATED_CORE = {
    "reproduce": "atc_nf_env.experiments.reproduce",
    "benchmark": "atc_nf_env.benchmark",
    "dataset": "atc_nf_env.dataset",
}


def make_policy(spec: str, **settings: Any):
    """``atc_nf_env.policy.make_policy``, imported when first called (it loads the simulator)."""
    from atc_nf_env.policy import make_policy as make

    return make(spec, **settings)


# -- option types ------------------------------------------------------------------------
def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number >= 0") from None
    if not value >= 0 or math.isinf(value):  # also rejects NaN
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number >= 0")
    return value


def _positive_minutes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number of minutes > 0") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number of minutes > 0")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be an integer >= 1") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be an integer >= 1")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be an integer >= 0") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be an integer >= 0")
    return value


# -- options -----------------------------------------------------------------------------
def _add_mpc_options(parser: argparse.ArgumentParser) -> None:
    # No argparse defaults here: an option left out is not passed, and the MPC keeps its
    # own, which the help text quotes.
    group = parser.add_argument_group(
        "MCMC-MPC settings (of --policy mpc and, with --shield, of the safety filter's MPC fallback, over its "
        "defaults: the MPC's, and on traffic streams --sampling per-cluster --progress-fraction 0.5 "
        "--progress-periods 6; the defaults are the homing proposal's, see --proposal)")
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
                       help="homing (the chain starts aimed home, a mixture proposal, a time-flown cost term, "
                            "4/10-kt envelope margins, wider rounds before a fallback) or paper (Table I as "
                            "printed) (default: homing)")
    group.add_argument("--search", choices=("lazy", "exhaustive"),
                       help="lazy flies a candidate only as far as the chain needs; exhaustive flies all K over "
                            "the whole horizon and measures every decision's feasible fraction; both pick the "
                            "same waypoints (default: lazy)")
    group.add_argument("--sampling", choices=("auto", "joint", "clusters", "per-cluster"),
                       help="auto is joint on at most 6 aircraft and per-cluster with the progress rule (0.5 over 6 "
                            "periods, unless --progress-fraction is given) on more and on streams; joint samples "
                            "every aircraft's waypoint; clusters, when the chain's start breaks a constraint, samples "
                            "only the conflict cluster around the aircraft involved; per-cluster gives each "
                            "independent conflict cluster of the start a chain of its own (see docs/mpc.md) "
                            "(default: auto)")
    group.add_argument("--cluster-radius-nm", type=float,
                       help="clusters, per-cluster: aircraft within this distance of one involved join its cluster "
                            "(default: 30)")
    group.add_argument("--progress-fraction", type=float,
                       help="the progress rule: an aircraft closing less than this share of a direct flight's "
                            "progress over --progress-periods periods is held on its recovery waypoint "
                            "(default: off, or 0.5 where --sampling auto flies per-cluster)")
    group.add_argument("--progress-periods", type=_positive_int,
                       help="the progress rule's window (default: 3, or 6 where --sampling auto flies per-cluster)")
    group.add_argument("--recovery-angle-deg", type=float,
                       help="homing: the chain's start and the heading-relative share of the proposal turn at most "
                            "this far from the heading, degrees, in (0, 90) (default: 60; what 70 trades in dense "
                            "traffic: docs/mpc.md)")
    group.add_argument("--approach-angle-deg", type=float,
                       help="homing: within 60 nm of its destination an aircraft turns up to this far from its "
                            "heading instead, degrees, in (0, 90) (default: no difference near home; against orbits "
                            "near home: docs/mpc.md)")


def _mpc_settings(args: argparse.Namespace) -> dict:
    """The MCMC-MPC settings given on the command line (``MPCSettings`` fields)."""
    names = ("extractions", "horizon", "wind_model", "constraint_check", "acceptance", "cost_exponent", "proposal",
             "search", "sampling", "cluster_radius_nm", "progress_fraction", "progress_periods", "recovery_angle_deg",
             "approach_angle_deg")
    kwargs = {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
    if kwargs and args.policy != "mpc" and not getattr(args, "shield", False):
        raise ValueError(f"--{next(iter(kwargs)).replace('_', '-')} applies to --policy mpc, or with --shield to the "
                         "safety filter's MPC fallback")
    for name in ("recovery_angle", "approach_angle"):
        if f"{name}_deg" in kwargs:
            # The MPC's settings are in rad; the option is checked in its own unit, so the error names it.
            degrees = kwargs.pop(f"{name}_deg")
            if not (math.isfinite(degrees) and 0.0 < degrees < 90.0):
                raise ValueError(f"--{name.replace('_', '-')}-deg {degrees!r}: must be a number in (0, 90)")
            kwargs[f"{name}_rad"] = math.radians(degrees)
    return kwargs


def _policy_kwargs(args: argparse.Namespace) -> dict:
    """The policy's settings: the MPC's options, for --policy mpc."""
    settings = _mpc_settings(args)
    return settings if args.policy == "mpc" else {}


def _shield_kwargs(args: argparse.Namespace) -> dict:
    """The safety filter's settings (--shield): the MPC's options go to its MPC fallback,
    over the fallback's defaults (``SafetyFilter``'s ``mpc_settings``)."""
    settings = _mpc_settings(args)
    return {"mpc_settings": settings} if getattr(args, "shield", False) and settings else {}


def _add_episode_options(parser: argparse.ArgumentParser) -> None:
    from atc_nf_env.config import PHYSICS_PRESETS
    from atc_nf_env.episode import MAX_EPISODE_S
    from atc_nf_env.policy import available_policies
    from atc_nf_env.units import WIND_SIGMA_MPS

    parser.add_argument(
        "--policy",
        default="mpc",
        help=f"the policy: {', '.join(available_policies())} (mpc: the paper's MCMC-MPC, the reference; nf: the "
        "NF alone, which strands aircraft under wind; nf-leg: the NF alone aimed 130 nm ahead along the line "
        "home, the floor for traffic streams), or a trained agent's PATH.zip (agents/models/*.zip)",
    )
    parser.add_argument(
        "--scenario",
        default="converging-4",
        help="converging-N (the paper's encounter: 3, 4, 6), random-N, stream-R (R aircraft an hour entering for 120 min; stream-R-Dmin: D min), or a scenario .json file",
    )
    parser.add_argument(
        "--wind-sigma",
        type=_non_negative_float,
        default=WIND_SIGMA_MPS,
        help="standard deviation of each wind component, m/s",
    )
    parser.add_argument("--seed", type=_seed, default=0, help="seeds the wind and the policy")
    parser.add_argument(
        "--max-minutes",
        type=_positive_minutes,
        default=MAX_EPISODE_S / 60,
        help="time limit of an episode, min (a whole number of 5-s integration steps)",
    )
    parser.add_argument("--physics", choices=tuple(PHYSICS_PRESETS), default="default",
                        help="NF settings: default, or paper-nf (proximity range 30/15 nm: the paper's "
                        "22 nm NF-alone separation; see REPRODUCTION.md)")
    parser.add_argument("--summary-json", type=Path, help="write the summary metrics to this JSON file")
    parser.add_argument("--shield", action="store_true",
                        help="fly the policy inside the safety filter (atc_nf_env.shield): each waypoint set is "
                        "predicted two periods ahead and replaced by the closest safe alternative, or the MPC's "
                        "decision, when unsafe (on traffic streams the per-cluster MPC; the MPC settings below "
                        "apply to it); the summary counts its interventions and the runs that breached anyway")
    _add_mpc_options(parser)


def _add_fly_options(parser: argparse.ArgumentParser) -> None:
    _add_episode_options(parser)
    parser.add_argument("--plots", type=Path,
                        help="write trajectory and airspeed figures into this folder (created if missing)")
    parser.add_argument("--animate", type=Path,
                        help="write an animation of the episode to this file (.gif, .png: animated PNG, .webp)")


def _add_evaluate_options(parser: argparse.ArgumentParser) -> None:
    from atc_nf_env.evaluate import BACKENDS

    _add_episode_options(parser)
    parser.add_argument("--runs", type=_positive_int, default=100,
                        help="number of episodes (seeds SEED..SEED+RUNS-1)")
    parser.add_argument("--workers", type=_positive_int,
                        help="worker processes (default and most: the usable cores; never more than the runs left)")
    parser.add_argument("--backend", choices=BACKENDS, default="local", help="local processes or a Ray cluster")
    parser.add_argument("--out", type=Path, help="JSON-lines file receiving every finished run")
    parser.add_argument("--resume", action="store_true", help="finish the study in --out, skipping runs already there")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


# -- checks before anything flies --------------------------------------------------------
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


def _check_animation(path: Path | None) -> None:
    """Refuse, before anything flies, an animation file the writer cannot write."""
    if path is None:
        return
    from atc_nf_env.rendering import animation_formats

    formats = animation_formats()
    if path.suffix.lower() not in formats:
        allowed = ", ".join(f"{suffix} ({what})" for suffix, what in formats.items())
        raise ValueError(f"--animate {path}: cannot write {path.suffix or 'a file without extension'}; "
                         f"supported: {allowed}")
    _check_output_file(path, "--animate")


def _max_time_s(minutes: float, dt_s: float) -> float:
    """``--max-minutes`` as seconds, or a ValueError in minutes: the time limit is flown in
    whole integration steps of ``dt_s``."""
    from atc_nf_env.episode import MAX_TIME_LIMIT_S

    step_min = dt_s / 60.0
    steps = minutes / step_min
    if abs(steps - round(steps)) > 1e-9 * max(1.0, steps) or round(steps) < 1:
        below, above = max(math.floor(steps), 1) * step_min, max(math.ceil(steps), 1) * step_min
        nearest = f"{below:.4g} or {above:.4g}" if below != above else f"{above:.4g}"
        raise ValueError(
            f"--max-minutes {minutes:g}: the time limit is flown in whole integration steps of {dt_s:g} s "
            f"({step_min:.4g} min); give a multiple of {step_min:.4g} min, e.g. {nearest} (any whole number of "
            "minutes is one)"
        )
    if minutes * 60.0 > MAX_TIME_LIMIT_S * (1 + 1e-12):
        raise ValueError(f"--max-minutes {minutes:g}: longer than any flight; allowed up to {MAX_TIME_LIMIT_S / 60:g}"
                         " min (24 h)")
    return round(steps) * dt_s


# -- fly -----------------------------------------------------------------------------------
def _fly(args: argparse.Namespace) -> int:
    from atc_nf_env.config import SimConfig
    from atc_nf_env.tables import fly_summary, fly_table

    _check_output_file(args.summary_json, "--summary-json")
    _check_output_folder(args.plots, "--plots")
    _check_animation(args.animate)
    config = SimConfig.preset(args.physics)
    max_time_s = _max_time_s(args.max_minutes, config.dt_s)
    from atc_nf_env.episode import run_episode, warm_up
    from atc_nf_env.scenarios import make_scenario

    scenario = make_scenario(args.scenario, seed=args.seed)
    policy = make_policy(args.policy, **_policy_kwargs(args))
    if args.shield:
        from atc_nf_env.shield import SafetyFilter

        policy = SafetyFilter(policy, **_shield_kwargs(args))
        policy.fallback_for(scenario)  # a setting that does not go with the scenario's fallback, refused now
    # Every integration step recorded: the table's per-aircraft separation and airspeeds
    # come from the recording (one episode's, a few MB at most).
    record_every = 1
    compile_s = warm_up(policy, scenario, seed=args.seed, wind_sigma_mps=args.wind_sigma,
                        config=config, record_every=record_every)
    result = run_episode(policy, scenario, seed=args.seed, wind_sigma_mps=args.wind_sigma, max_time_s=max_time_s,
                         record_every=record_every, config=config)
    info = policy.episode_info() if hasattr(policy, "episode_info") else {}
    label = Path(args.policy).stem if args.policy.lower().endswith(".zip") else args.policy
    label += "+shield" if args.shield else ""
    settings = ", ".join(f"{key.replace('_', ' ')} {value}" for key, value in _mpc_settings(args).items())
    print(fly_table(result, f"{label} ({settings})" if settings else label, config, info, compile_s,
                    wind_sigma_mps=args.wind_sigma))
    if args.summary_json:
        summary = fly_summary(result, args.policy, info, compile_s)
        args.summary_json.write_text(_json(summary) + "\n")
        print(f"summary written to {args.summary_json}")
    if args.plots:
        from atc_nf_env.plotting import write_episode_plots

        paths = write_episode_plots(result, args.plots, f"{scenario.name}_{label}", policy=label,
                                    wind_sigma_mps=args.wind_sigma)
        print("figures written: " + ", ".join(str(p) for p in paths))
    if args.animate:
        from atc_nf_env.plotting import episode_title
        from atc_nf_env.rendering import save_animation

        title = episode_title(result, "", label, args.wind_sigma).rstrip(": ")
        print(f"animation written to {save_animation(result, args.animate, scenario=scenario, title=title)}")
    return 0


def _json(data: Any) -> str:
    import json

    return json.dumps(data, indent=2)


# -- evaluate ------------------------------------------------------------------------------
def _evaluate(args: argparse.Namespace) -> int:
    from atc_nf_env.config import SimConfig
    from atc_nf_env.evaluate import Study, evaluate, read_results
    from atc_nf_env.tables import evaluate_table

    _check_output_file(args.out, "--out")
    _check_output_file(args.summary_json, "--summary-json")
    max_time_s = _max_time_s(args.max_minutes, SimConfig.preset(args.physics).dt_s)
    study = Study(
        policy=args.policy,
        scenario=args.scenario,
        wind_sigma_mps=args.wind_sigma,
        policy_kwargs=_policy_kwargs(args),
        max_time_s=max_time_s,
        physics=args.physics,
        shield=args.shield,
        shield_kwargs=_shield_kwargs(args),
    )
    records: list[dict[str, Any]] = []
    summary = evaluate(
        study,
        args.runs,
        first_seed=args.seed,
        workers=args.workers,
        backend=args.backend,
        out=args.out,
        resume=args.resume,
        progress=not args.no_progress,
        on_run=records.append,
    )
    if args.out is not None:  # a resumed study: the runs of earlier invocations too
        seeds = range(args.seed, args.seed + args.runs)
        records = [r for r in read_results(args.out)[1] if r["seed"] in seeds]
    summary["policy"] = args.policy
    print(evaluate_table(summary, records, study, first_seed=args.seed))
    if args.summary_json:
        args.summary_json.write_text(_json(summary) + "\n")
        print(f"summary written to {args.summary_json}")
    return 0


# -- delegated subcommands -------------------------------------------------------------
def _run_delegated(command: str, rest: list[str]) -> int:
    import importlib

    return importlib.import_module(_DELEGATED_CORE[command]).main(rest)


class CommandUnavailable(Exception):
    """A subcommand that cannot run in this install (its extra is missing)."""


def _plugin_commands() -> dict[str, Any]:
    """The installed subcommands of ``COMMAND_GROUP``, by name, not loaded."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=COMMAND_GROUP) if ep.name not in CORE_COMMANDS}


def _extra_providing(module: str | None) -> str | None:
    """The extra of the installed atc-nf-env whose requirements hold ``module`` (by its
    top-level name), or None."""
    from importlib.metadata import PackageNotFoundError, requires

    if not module:
        return None
    try:
        requirements = requires("atc-nf-env") or []
    except PackageNotFoundError:
        return None

    def normal(name: str) -> str:
        return re.sub(r"[-_.]+", "-", name).lower()

    wanted = normal(module.split(".")[0])
    for requirement in requirements:
        name = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", requirement)
        extra = re.search(r"extra\s*==\s*[\"']([^\"']+)[\"']", requirement)
        if name and extra and normal(name.group(1)) == wanted:
            return extra.group(1)
    return None


def _run_plugin(name: str, entry_point: Any, rest: list[str]) -> int:
    try:
        command: Callable[[list[str]], int] = entry_point.load()
        return command(rest)
    except ModuleNotFoundError as error:
        extra = _extra_providing(error.name)
        if extra is None:
            raise
        raise CommandUnavailable(
            f"`atc-nf {name}` needs the {extra} extra: pip install 'atc-nf-env[{extra}]' "
            f"(this install has no {error.name!r})"
        ) from None


# -- the parser ----------------------------------------------------------------------------
class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every real default; an option without one (None, or off) says nothing."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


_OPTIONS = {"fly": _add_fly_options, "evaluate": _add_evaluate_options}
_HANDLERS = {"fly": _fly, "evaluate": _evaluate}


def build_parser(command: str | None = None, plugins: dict[str, Any] | None = None) -> argparse.ArgumentParser:
    """The ``atc-nf`` parser. Only ``command``'s options are built (all the core's when
    ``command`` is None): building them imports the simulator, which ``atc-nf --help``
    does not need."""
    parser = argparse.ArgumentParser(
        prog="atc-nf",
        description="Aircraft under decentralized dipolar navigation functions with hidden wind.",
        formatter_class=HelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, text in CORE_COMMANDS.items():
        delegated = name in _DELEGATED_CORE
        child = sub.add_parser(name, help=text, description=text, formatter_class=HelpFormatter,
                               add_help=not delegated)
        if not delegated and command in (None, name):
            _OPTIONS[name](child)
            child.set_defaults(handler=_HANDLERS[name])
    for name, entry_point in sorted((_plugin_commands() if plugins is None else plugins).items()):
        module = entry_point.value.split(":")[0]
        sub.add_parser(name, help=_PLUGIN_HELP.get(name, f"from {module}; `atc-nf {name} --help` for its options"),
                       add_help=False)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv else None
    try:
        if command in _DELEGATED_CORE:
            # The module owns its options (and its --help).
            return _run_delegated(command, argv[1:])
        plugins = _plugin_commands()
        if command in plugins:
            return _run_plugin(command, plugins[command], argv[1:])
        if command in _PLUGIN_HELP:
            raise CommandUnavailable(
                f"`atc-nf {command}` is not installed: this install of atc-nf-env declares no {COMMAND_GROUP!r} "
                f"entry point {command!r}; reinstall it (pip install -e . in its checkout)"
            )
        parser = build_parser(command if command in _OPTIONS else "", plugins)
        args = parser.parse_args(argv)
        return args.handler(args)
    except CommandUnavailable as error:
        print(f"atc-nf: error: {error}", file=sys.stderr)
        return 2
    except ValueError as error:
        print(f"atc-nf {command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # an output that cannot be written (e.g. reproduce --figures)
        print(f"atc-nf {command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C is the user's own stop, not a failure to debug: one line, and the status a
        # shell gives a command that SIGINT ended.
        kept = _KEPT_ON_INTERRUPT.get(command or "")
        print(f"atc-nf {command}: interrupted (Ctrl-C){'; ' + kept if kept else ''}", file=sys.stderr)
        return INTERRUPTED_STATUS


#: The exit status after Ctrl-C: 128 + SIGINT, as a shell reports a command it interrupted.
INTERRUPTED_STATUS = 130
#: What an interrupted subcommand kept, said on its one line.
_KEPT_ON_INTERRUPT = {
    "evaluate": "the runs finished so far are in --out, if given; the same command with --resume finishes the study",
    "benchmark": "the runs finished so far are in --results-dir, if given; the same command resumes from there",
}


if __name__ == "__main__":
    sys.exit(main())
