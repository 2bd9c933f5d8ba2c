"""Model cards generated from what is saved with each model and from benchmark runs.

    python -m agents.cards --summaries agents/results/summary.json,agents/results/deepsets_summary.json

writes ``agents/models/NAME.md`` for every ``agents/models/*.zip`` (``--models`` to choose).
Nothing in a card is typed by hand: each section comes from

* the model's zip: ``atc_nf_meta`` (environment settings, training command, dataset,
  operating range and, for models saved since provenance was recorded, the build
  fingerprint, git commit, library versions and simulation settings at training time) and
  SB3's ``system_info.txt`` (library versions at save time);
* git, for models saved before provenance was recorded: the commit that added the file,
  and whether the MPC of that commit had its ``homing`` proposal;
* the benchmark summaries (``python -m agents.benchmark --summary ...``): per scenario,
  success with its Wilson 95 % interval and per-run safety on the held-out seeds.

``provenance()`` is what ``agents.train.save_model`` stores with every model it saves, and
``operating_range(meta)`` is the range of numbers of aircraft and wind sigmas a model
claims (``SB3AgentPolicy`` warns once, or refuses, outside it).
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import subprocess
import sys
import zipfile
from importlib import metadata
from pathlib import Path
from typing import Any, Sequence

from atc_nf_env.metrics import wilson_interval

#: Libraries whose versions a card states.
LIBRARIES = ("numpy", "numba", "torch", "stable-baselines3", "gymnasium", "pettingzoo")
#: Simulation settings (``SimConfig`` fields) a trained model depends on.
SIM_SETTINGS = ("sensing_radius_nm", "barrier_nm", "dt_s", "arrival_tolerance_nm", "airspeed_min_kt",
                "airspeed_max_kt", "separation_min_nm", "airspeed_cap_kt", "substep_s")
REPO_ROOT = Path(__file__).resolve().parent.parent


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def provenance() -> dict[str, Any]:
    """The code and settings a model is being trained with: build fingerprint, git commit
    (``dirty`` when tracked files differ from it), library versions, ``SimConfig``."""
    from atc_nf_env import build
    from atc_nf_env.config import SimConfig

    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"build": build.fingerprint(), "git_commit": commit, "git_dirty": bool(status) if commit else None,
            "libraries": library_versions(), "sim_config": SimConfig().as_dict()}


def _parse_command(command: str) -> tuple[str, list[str]]:
    """("train" or "imitate", its flags) of a stored ``atc-nf ...`` command."""
    command = command.split("  [stage", 1)[0]
    tokens = shlex.split(command)
    if len(tokens) < 2 or tokens[0] != "atc-nf" or tokens[1] not in ("train", "imitate"):
        raise ValueError(f"not an atc-nf train/imitate command: {command!r}")
    return tokens[1], tokens[2:]


def operating_range(meta: dict[str, Any]) -> dict[str, list[float]] | None:
    """{"n_aircraft": [min, max], "wind_sigma_mps": [min, max]} the model was trained on:
    saved in its metadata, or (models saved before it was) derived from the training
    command stored there; None if neither says."""
    if isinstance(meta.get("operating_range"), dict):
        return meta["operating_range"]
    command = (meta.get("training") or {}).get("command")
    if not command:
        return None
    from agents._config import parse_config
    from atc_nf_env.scenarios import make_scenario

    script, flags = _parse_command(command)
    if script == "imitate":
        from agents import imitate

        return imitate.operating_range(parse_config(imitate.Args, flags, prog="", description=""))
    from agents import train

    args = parse_config(train.Args, flags, prog="", description="")
    n = make_scenario(args.scenario, seed=0).n_aircraft
    return {"n_aircraft": [n, n], "wind_sigma_mps": [args.wind_sigma, args.wind_sigma]}


def _system_info(path: Path) -> dict[str, str]:
    with zipfile.ZipFile(path) as archive:
        if "system_info.txt" not in archive.namelist():
            return {}
        text = archive.read("system_info.txt").decode()
    info = {}
    for line in text.splitlines():
        key, _, value = line.lstrip("- ").partition(":")
        if value:
            info[key.strip()] = value.strip().split(" #")[0]
    return info


def _results_for(label: str, summaries: list[tuple[Path, dict[str, Any]]]) -> list[tuple[Path, str, dict, dict | None]]:
    def mpc_of(scenario: str, runs: int) -> dict | None:
        """The MPC's study of the same scenario and seeds, from any of the summaries."""
        for _, results in summaries:
            mpc = results.get(scenario, {}).get("mpc")
            if mpc and mpc["runs"] == runs:
                return mpc
        return None

    rows = []
    for path, results in summaries:
        for scenario, by_policy in results.items():
            if label in by_policy:
                rows.append((path, scenario, by_policy[label], mpc_of(scenario, by_policy[label]["runs"])))
    return rows


def _study_sigma(summary: dict[str, Any]) -> float:
    study = summary.get("study")
    if study:
        return float(study["wind_sigma_mps"])
    from atc_nf_env.evaluate import Study

    return Study(policy="nf", scenario="converging-4").wind_sigma_mps  # what the benchmark flew


def _n_of(scenario: str) -> int:
    from atc_nf_env.scenarios import make_scenario

    return make_scenario(scenario, seed=0).n_aircraft


def _latency(seconds: float | None) -> str:
    if not seconds:
        return "n/a"
    return f"{seconds * 1e3:.1f} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.0f} µs"


def card(path: Path, summaries: list[tuple[Path, dict[str, Any]]]) -> str:
    """The markdown card of the model at ``path``."""
    from agents.policy import read_meta, time_limit_s
    from atc_nf_env import build
    from atc_nf_env.config import SimConfig
    from atc_nf_env.envs.observations import ObservationSpec

    meta = read_meta(path)
    label = path.stem
    training = meta.get("training", {})
    prov = meta.get("provenance")
    env = meta["env"]
    k = int(env["n_neighbours"])
    arch = training.get("policy_arch", "mlp")
    lines = [f"# {label}", ""]
    kind = {"atc-nf imitate": f"imitation of the MCMC-MPC (stage {training.get('stage')})",
            "atc-nf train": "reinforcement learning (PPO)" + (
                f", started from {training['init_from']}" if training.get("init_from") else ", from scratch")}
    lines += [f"{kind.get(training.get('script'), training.get('script'))}; {meta['algo'].upper()} "
              f"{meta['mode']} policy, "
              + ("permutation-invariant deep-sets network over the neighbour set (`agents.deepsets`)"
                 if arch == "deepsets" else "MLP on the ego observation with its neighbours in nearest-first order")
              + f"; {path.stat().st_size / 1e6:.2f} MB.", ""]

    lines += ["## Code version", ""]
    if prov:
        dirty = " (with uncommitted changes to tracked files)" if prov.get("git_dirty") else ""
        lines.append(f"- Trained at git commit `{prov.get('git_commit')}`{dirty}, build fingerprint "
                     f"`{prov['build']}` (`atc_nf_env.build.fingerprint()`).")
    else:
        added = _git("log", "--diff-filter=A", "--format=%h %ad", "--date=short", "--", str(path.relative_to(REPO_ROOT)))
        added = (added or "").splitlines()[-1:] or ["unknown"]
        lines.append(f"- Not recorded at training (saved before provenance was). The file was added to the "
                     f"repository in commit `{added[0]}`; it was trained on the code of that commit's parent or "
                     "earlier.")
        if added[0] != "unknown":
            mpc_then = _git("show", f"{added[0].split()[0]}:baselines/mcmc_mpc.py") or ""
            if training.get("script") == "atc-nf imitate" or training.get("init_from"):
                lines.append("- Its demonstrations came from the MCMC-MPC of that commit, whose proposal was "
                             + ("the `homing` one." if '"homing"' in mpc_then else
                                "Table I's (the `homing` proposal, today's default, did not exist yet)."))
    lines.append(f"- This card was generated by build `{build.fingerprint()}`.")
    lines.append("")

    lines += ["## Libraries", ""]
    if prov:
        lines.append("At training: " + ", ".join(f"{k_} {v}" for k_, v in prov["libraries"].items()) + ".")
    info = _system_info(path)
    if info:
        lines.append("Saved by (SB3's `system_info.txt`): " + ", ".join(f"{k_} {v}" for k_, v in info.items()
                                                                            if k_ not in ("OS", "GPU Enabled")) + ".")
    lines.append("")

    lines += ["## Simulation settings the model depends on", ""]
    config = prov["sim_config"] if prov else SimConfig().as_dict()
    source = "recorded at training"
    physics = ["atc_nf_env/kernel.py", "atc_nf_env/nf.py", "atc_nf_env/config.py"]
    if prov and prov.get("git_commit"):
        changed = _git("diff", "--name-only", prov["git_commit"], "HEAD", "--", *physics)
        if changed:
            source += "; " + ", ".join(f"`{c}`" for c in changed.split()) + " changed since that commit"
    if not prov:
        source = "not recorded at training; shown: today's `SimConfig()` defaults"
        added = (_git("log", "--diff-filter=A", "--format=%h", "--", str(path.relative_to(REPO_ROOT))) or "").split()
        if added:
            changed = _git("diff", "--name-only", added[-1], "HEAD", "--", *physics)
            if changed is not None:
                source += ("; " + ", ".join(f"`{c}`" for c in changed.split()) + " changed since the commit that "
                           "added the model") if changed else "; the physics sources have not changed since"
    limit = time_limit_s(env["max_episode_minutes"])
    mapping = env["action_mapping"]
    lines += [
        f"- Physics ({source}): proximity range (G_i's sensing radius / barrier) "
        f"{config['sensing_radius_nm']:g} / {config['barrier_nm']:g} nm, integration step dt = {config['dt_s']:g} s, "
        f"arrival tolerance {config['arrival_tolerance_nm']:g} nm, envelope [{config['airspeed_min_kt']:g}, "
        f"{config['airspeed_max_kt']:g}] kt, separation {config['separation_min_nm']:g} nm, airspeed guard "
        f"±{config['airspeed_cap_kt']:g} kt.",
        f"- Time feature: elapsed time / {limit:g} s (the time limit of {env['max_episode_minutes']:g} min in whole "
        "5-min decisions), capped at 1.",
        f"- Action: [distance, angle] in [-1, 1]² → waypoint at {mapping['distance_nm']:g} ± "
        f"{mapping['distance_span_nm']:g} nm, ±{mapping['angle_span_deg']:g}° from the bearing home.",
        f"- Observation ({ObservationSpec(n_neighbours=k).dim} values, K = {k} neighbour slots, no wind): "
        + ", ".join(f"`{name}`" for name in ObservationSpec(n_neighbours=k).labels()) + ".",
        "",
    ]

    lines += ["## Training", ""]
    lines.append(f"- Command: `{training.get('command')}`")
    for key in ("dataset", "total_timesteps", "timesteps_done", "wall_s", "bc_wall_s"):
        if key in training:
            lines.append(f"- {key.replace('_', ' ')}: {json.dumps(training[key])}")
    if "expert" in training:
        lines.append(f"- Expert: {json.dumps(training['expert'])}")
    lines.append("")

    rng = operating_range(meta)
    lines += ["## Operating range", ""]
    if rng:
        n_lo, n_hi = rng["n_aircraft"]
        s_lo, s_hi = rng["wind_sigma_mps"]
        span = (lambda lo, hi: f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}")
        lines.append(f"Trained on {span(n_lo, n_hi)} aircraft and wind σ {span(s_lo, s_hi)} m/s"
                     + ("" if "operating_range" in meta else " (derived from the training command in its metadata)")
                     + ". `SB3AgentPolicy` warns once per model and process when it flies outside that range "
                     "(`outside_range=\"refuse\"` raises instead, `\"ignore\"` says nothing).")
    else:
        lines.append("Not recorded.")
    lines.append("")

    rows = _results_for(label, summaries)
    lines += ["## Results on held-out seeds", ""]
    if not rows:
        lines += ["No benchmark summary holds this model yet.", ""]
    else:
        lines += ["Seeds 0..runs−1 (training used 10 000 and up). Success: every aircraft arrives, with the Wilson "
                  "95 % interval. Safety per run: runs with any loss of separation (5 nm), runs with any "
                  "integration step outside the envelope, runs at the airspeed guard.", "",
                  "| scenario | σ (m/s) | in range | runs | success [95 % CI] | runs with LoS | min sep. (nm) | "
                  "runs outside envelope | runs at cap | worst excursion (kt) | mean flight (min) | MPC's mean flight "
                  "(min) | decision | summary |",
                  "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
        for source_path, scenario, s, mpc in rows:
            sigma = _study_sigma(s)
            n = _n_of(scenario)
            inside = "n/a" if not rng else ("yes" if rng["n_aircraft"][0] <= n <= rng["n_aircraft"][1]
                                             and rng["wind_sigma_mps"][0] - 1e-9 <= sigma <= rng["wind_sigma_mps"][1] + 1e-9
                                             else "**no**")
            successes = round(s["success_rate"] * s["runs"])
            low, high = wilson_interval(successes, s["runs"])
            flight = s["flight_time_min"]["mean"]
            mpc_flight = mpc["flight_time_min"]["mean"] if mpc else None
            sep = s["min_separation_nm"]["min"]
            worst = s.get("worst_envelope_excursion_kt")
            lines.append(
                f"| {scenario} | {sigma:g} | {inside} | {s['runs']} | {100 * s['success_rate']:.1f} % "
                f"[{100 * low:.1f}, {100 * high:.1f}] | {s['runs_with_los']} | "
                f"{'n/a' if sep is None else f'{sep:.2f}'} | {s['runs_with_envelope_violation']} | "
                f"{s['runs_at_airspeed_cap']} | {'n/a' if worst is None else f'{worst:.0f}'} | "
                f"{'n/a' if flight is None else f'{flight:.1f}'} | "
                f"{'n/a' if mpc_flight is None else f'{mpc_flight:.1f}'} | {_latency(s.get('wall_s_per_decision'))} | "
                f"`{source_path.as_posix()}` |")
        lines.append("")

    lines += ["## Intended use", "",
              "Research on learned conflict resolution in this simulator: a fast stand-in for the MCMC-MPC "
              "(`baselines.MCMCMPC`, the reference policy) in studies, and a starting point for training. Not "
              "for operational air-traffic control. Inside its operating range only; the MPC, which checks "
              "20 min of predicted flight at every decision, stays the reference for safety.", ""]

    lines += ["## Known failures (from the results above)", ""]
    failures = []
    for source_path, scenario, s, _ in rows:
        parts = []
        if s["success_rate"] < 1:
            parts.append(f"{s['runs'] - round(s['success_rate'] * s['runs'])} of {s['runs']} run(s) with an aircraft "
                         "not home")
        if s["runs_with_los"]:
            parts.append(f"{s['runs_with_los']} run(s) with a loss of separation (closest {s['min_separation_nm']['min']:.2f} nm)")
        if s["runs_with_envelope_violation"]:
            parts.append(f"{s['runs_with_envelope_violation']} run(s) outside the envelope (worst "
                         f"{s.get('worst_envelope_excursion_kt', 0):.0f} kt), {s['runs_at_airspeed_cap']} at the guard")
        if parts:
            failures.append(f"- {scenario} (σ {_study_sigma(s):g} m/s): " + "; ".join(parts) + ".")
    failures = failures or ["- None in the runs above (which bounds the failure rate only as the intervals say)."]
    lines += failures
    lines.append("")
    lines.append("Generated by `python -m agents.cards` from the model's metadata and the summaries named above; "
                 "edits by hand are overwritten.")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", default="", help="comma-separated .zip files (default: agents/models/*.zip)")
    parser.add_argument("--summaries", default="agents/results/summary.json",
                        help="comma-separated summary JSON files of python -m agents.benchmark")
    args = parser.parse_args(argv)
    models = [Path(m) for m in args.models.split(",") if m] or sorted((REPO_ROOT / "agents" / "models").glob("*.zip"))
    summaries = []
    for name in args.summaries.split(","):
        if not name:
            continue
        path = Path(name)
        if not path.is_file():
            parser.error(f"--summaries: {path} does not exist")
        summaries.append((path, json.loads(path.read_text())))
    for model in models:
        if not model.is_file():
            parser.error(f"--models: {model} does not exist")
        target = model.with_suffix(".md")
        target.write_text(card(model.resolve(), summaries))
        print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
