"""The paper's section IV from fresh runs: figures and the reproduction table.

- Figs. 3, 5, 7 and the wind failure: the NF alone (``nf_alone``);
- Figs. 4 and 9: per aircraft, the mean airspeed and the lowest and highest airspeed
  over every integration step of the MPC's Monte Carlo runs, minute by minute, with the
  envelope (the axis always spans every excursion);
- Figs. 6 and 8: trajectories of one MPC run (seed 0) for 4 and 6 aircraft;
- ``REPRODUCTION.md``: every claim of section IV with the paper's number and ours, for
  the project's MPC (the "homing" proposal, ``HEADLINE_CONTROLLER``) on the paper's
  encounters and on seeded random 4- and 6-aircraft encounters, and for Table I's own
  proposal (``--proposal paper``) on the paper's encounters. Every cell is computed from
  the runs; sections between ``<!-- begin NAME -->`` and ``<!-- end NAME -->`` markers
  that other scripts wrote into the report are kept as they are.

Everything is written under ``--out`` (``out/reproduction``: the runs, ``REPRODUCTION.md``,
``figures/``) unless ``--write`` is given: then the report replaces the tracked
``REPRODUCTION.md`` and the figures go to ``docs/figures/``.

The Monte Carlo studies go through the evaluator: their runs are kept in JSON-lines
files under the output folder, so an interrupted reproduction resumes where it stopped.
Runs flown by another build (``atc_nf_env.build.fingerprint``: a change to a source
that flies a run, or to NumPy/numba) are never reused: that study is flown again.

Run: atc-nf reproduce [--runs 1000] [--out out/reproduction] [--write]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from atc_nf_env import build
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import MAX_EPISODE_S, run_episode
from atc_nf_env.evaluate import Study, evaluate, read_results
from atc_nf_env.experiments import nf_alone
from atc_nf_env.experiments.marked_sections import marked_sections
from atc_nf_env.plotting import _pyplot, aircraft_color, plot_airspeed, plot_trajectories
from atc_nf_env.policy import make_policy
from atc_nf_env.scenarios import converging
from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT, AIRSPEED_NOMINAL_KT, WIND_SIGMA_MPS

#: Width of the airspeed bands' windows, s.
BAND_WINDOW_S = 60.0

#: The MPC studies: scenario -> the paper's figures for it (None where the paper has none).
MPC_STUDIES: dict[str, dict[str, Any] | None] = {
    "converging-4": {"arrive": "1000/1000", "time_min": "66", "compute_s": "200", "memory_mb": "110",
                     "separation_nm": "11.5 - 16", "band_figure": 4, "trajectory_figure": 6},
    "converging-6": {"arrive": "all", "time_min": "85", "compute_s": "1500", "memory_mb": "130",
                     "separation_nm": "-", "band_figure": 9, "trajectory_figure": 8},
    "random-4": None,
    "random-6": None,
}

#: Table I's own proposal, chain start and cost (``--proposal paper``), flown on the paper's
#: encounters beside the project's default controller.
PAPER_PROPOSAL_STUDIES = ("converging-4", "converging-6")

#: What the MPC rows fly, in words; each addition is checked against ``MPCSettings``'
#: defaults in tests/test_reproduction.py.
HEADLINE_CONTROLLER = (
    "The MPC rows fly this project's default controller, `MPCSettings()` with the `homing` proposal: Table I's "
    "sampler (K = 1000 extractions, horizon N = 4 periods of T = 5 min, distance N(100, 10) nm) with five "
    "additions: (1) the chain starts from every aircraft aimed at its destination 130 nm out (Table I leaves "
    "the start free); (2) a mixture proposal: a quarter of the angles are drawn within ±60° of the heading "
    "instead of within ±90° of the line home; (3) the cost (6) adds each aircraft's time flown in the horizon, "
    "as distance at 454 kt; (4) the prediction holds the airspeed 4 kt inside the envelope (10 kt at an "
    "episode's first decision); (5) up to 2 wider rounds of K candidates before a fallback. Also not the "
    "paper's, for every MPC row: the constraints are checked at every integration step (the paper: at the "
    "sampling instants), the chain's acceptance is the standard independence sampler's (Table I prints the "
    "proposal ratio the other way up), and the prediction's wind is estimated from the observed drift. "
    "The rows marked \"Table I's proposal\" fly `--proposal paper`: Table I's proposal, chain start (the first "
    "draw) and cost (6), without margins or wider rounds; acceptance, constraint check and wind model as above."
)


# -- airspeed bands ---------------------------------------------------------------------
def airspeed_bands(records: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(window start in minutes (T,), mean, min, max (T, N)) airspeed per aircraft across
    runs, kt: min and max are the extremes over every integration step flown in the
    window by any run; mean is the mean of the runs' window means. NaN where no run had
    that aircraft flying in that window."""
    bands = [r["airspeed_band_kt"] for r in records]
    n = len(bands[0])
    length = max(len(aircraft) for run in bands for aircraft in run)
    data = np.full((len(bands), length, n, 3), np.nan)
    for k, run in enumerate(bands):
        for i, windows in enumerate(run):
            for w, values in enumerate(windows):
                if values is not None:
                    data[k, w, i] = values
    minutes = np.arange(length) * BAND_WINDOW_S / 60.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows stay NaN
        return (minutes, np.nanmean(data[..., 1], 0), np.nanmin(data[..., 0], 0), np.nanmax(data[..., 2], 0))


def band_axis_limits(low: np.ndarray, high: np.ndarray) -> tuple[float, float]:
    """y-limits that hold the envelope and every value of the bands, with a margin."""
    lowest = min(AIRSPEED_MIN_KT, float(np.nanmin(low, initial=AIRSPEED_MIN_KT)))
    highest = max(AIRSPEED_MAX_KT, float(np.nanmax(high, initial=AIRSPEED_MAX_KT)))
    margin = max(40.0, 0.05 * (highest - lowest))
    return lowest - margin, highest + margin


def plot_airspeed_bands(records: list[dict[str, Any]], path: Path, title: str) -> None:
    """One panel per aircraft: min-max band and mean over runs, the envelope, and a mark
    at every window whose extreme lies outside the envelope."""
    plt = _pyplot()
    minutes, mean, low, high = airspeed_bands(records)
    n = mean.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(8, 1.7 * n + 0.8), sharex=True)
    bottom, top = band_axis_limits(low, high)
    for i, ax in enumerate(np.atleast_1d(axes)):
        color = aircraft_color(i)
        ax.fill_between(minutes, low[:, i], high[:, i], alpha=0.3, color=color, step="post",
                        label="min-max over runs")
        ax.plot(minutes, mean[:, i], lw=1.2, color=color, drawstyle="steps-post", label="mean over runs")
        ax.axhline(AIRSPEED_MIN_KT, color="k", ls="--", lw=0.8)
        ax.axhline(AIRSPEED_MAX_KT, color="k", ls="--", lw=0.8, label="envelope")
        ax.axhline(AIRSPEED_NOMINAL_KT, color="g", ls=":", lw=0.8)
        with np.errstate(invalid="ignore"):
            below = low[:, i] < AIRSPEED_MIN_KT
            above = high[:, i] > AIRSPEED_MAX_KT
        if below.any() or above.any():
            ax.plot(minutes[below], low[below, i], "rv", ms=4)
            ax.plot(minutes[above], high[above, i], "r^", ms=4, label="outside the envelope")
            worst_low, worst_high = np.nanmin(low[:, i]), np.nanmax(high[:, i])
            ax.text(0.01, 0.06, f"lowest {worst_low:.0f} kt, highest {worst_high:.0f} kt", color="r",
                    transform=ax.transAxes, fontsize=7)
        ax.set_ylim(bottom, top)
        ax.set_ylabel(f"ac {i} (kt)")
    first = np.atleast_1d(axes)[0]
    first.set_title(title, fontsize=9)
    first.legend(fontsize=6, loc="upper right", ncol=4)
    np.atleast_1d(axes)[-1].set_xlabel("time (min)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# -- studies ----------------------------------------------------------------------------
def mpc_study_of(scenario: str, proposal: str = "homing") -> Study:
    """The MPC's study of ``scenario`` with the ``proposal`` of ``MPCSettings`` ("homing",
    the default, or "paper")."""
    kwargs = {} if proposal == "homing" else {"proposal": proposal}
    return Study(policy="mpc", scenario=scenario, wind_sigma_mps=WIND_SIGMA_MPS, airspeed_every_s=BAND_WINDOW_S,
                 policy_kwargs=kwargs)


def fly_study(study: Study, runs: int, path: Path, workers: int | None, progress: bool) -> tuple[dict, list, int]:
    """(summary, records of seeds 0..runs-1, how many of them were reused from ``path``).

    Runs already in ``path`` are reused only if the same build flew the same study;
    otherwise the file is replaced and the study flown again, and the reason printed."""
    header, old = read_results(path)
    expected = study.header()
    if header is not None and header != expected:
        if header.get("build") != expected["build"]:
            why = f"flown by build {header.get('build')}, this build is {expected['build']}"
        else:
            changed = sorted(k for k in expected if header.get(k) != expected[k])
            why = f"a different study (differs in {', '.join(changed)})"
        print(f"{path}: {len(old)} runs {why}: not reused, flying the study again", file=sys.stderr)
        path.unlink()
        old = []
    reused = sum(1 for r in old if r["seed"] < runs)
    summary = evaluate(study, runs, workers=workers, out=path, resume=path.exists(), progress=progress)
    _, records = read_results(path)
    records = sorted((r for r in records if r["seed"] < runs), key=lambda r: r["seed"])
    return summary, records, reused


def run_safety(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-run outcomes of a study, from its run records (everything the report says)."""
    config = SimConfig()
    runs = len(records)
    missed = [(r, i) for r in records for i, a in enumerate(r["arrived"]) if not a]
    holding = [(r, i) for r, i in missed if not r["left_workspace"][i]]
    left = [(r, i) for r, i in missed if r["left_workspace"][i]]
    short = [r["distance_short_nm"][i] for r, i in holding]
    breached = [r for r in records if r["envelope_violation_fraction"] > 0]
    after_fallback = [r for r in breached if set(r["excursion_decisions"]) & set(r["fallback_decisions"])]
    without_fallback = [r for r in breached if set(r["excursion_decisions"]) - set(r["fallback_decisions"])]
    steps = sum(r["steps_flown"] for r in records)
    outside_steps = sum(round(r["envelope_violation_fraction"] * r["steps_flown"]) for r in records)
    mean_airspeed = (
        sum(r["airspeed_mean_kt"] * r["steps_flown"] for r in records if r["airspeed_mean_kt"] is not None) / steps
        if steps else None
    )
    all_home_times = [t for r in records if r["success"] for t in r["flight_time_min"]]
    kept = [(r.get("policy_info") or {}).get("start_kept") for r in records]
    return {
        "runs": runs,
        "runs_all_home": sum(r["success"] for r in records),
        "aircraft_not_home": len(missed),
        "runs_not_home": len({r["seed"] for r, _ in missed}),
        "aircraft_at_time_limit": len(holding),
        "aircraft_left_workspace": len(left),
        "distance_short_nm": {
            "median": float(np.median(short)) if short else None,
            "min": float(min(short)) if short else None,
            "max": float(max(short)) if short else None,
        },
        "runs_with_los": sum(r["los_count"] > 0 for r in records),
        "los_pairs": sum(r["los_count"] for r in records),
        "runs_outside_envelope": len(breached),
        "runs_outside_envelope_after_a_fallback": len(after_fallback),
        "runs_outside_envelope_without_a_fallback": len(without_fallback),
        "steps": steps,
        "steps_outside_envelope": outside_steps,
        "worst_excursion_kt": max((r["worst_excursion_kt"] for r in records), default=0.0),
        "airspeed_min_kt": min((r["airspeed_min_kt"] for r in records if r["airspeed_min_kt"] is not None),
                               default=None),
        "airspeed_max_kt": max((r["airspeed_max_kt"] for r in records if r["airspeed_max_kt"] is not None),
                               default=None),
        "mean_airspeed_kt": mean_airspeed,
        "runs_with_a_fallback": sum(bool(r["fallback_decisions"]) for r in records),
        "fallbacks": sum(len(r["fallback_decisions"]) for r in records),
        "decisions": sum(r["decisions"] for r in records),
        # Decisions that applied the chain's start without an accepted move (None: runs
        # recorded before the MPC counted them).
        "decisions_start_kept": sum(kept) if records and None not in kept else None,
        "flight_time_all_home_min": float(np.mean(all_home_times)) if all_home_times else None,
        "time_limit_min": MAX_EPISODE_S / 60.0,
        "envelope_kt": [config.airspeed_min_kt, config.airspeed_max_kt],
    }


# -- the report -------------------------------------------------------------------------
def _fmt(value: float | None, digits: int = 1) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _interval(summary: dict[str, Any]) -> str:
    ci = summary.get("success_rate_ci95")
    return f" (95 % interval {100 * ci[0]:.1f} - {100 * ci[1]:.1f} %)" if ci else ""


def arrival_note(s: dict[str, Any]) -> str:
    if s["aircraft_not_home"] == 0:
        return ""
    parts = []
    if s["aircraft_at_time_limit"]:
        d = s["distance_short_nm"]
        parts.append(
            f"{_count(s['aircraft_at_time_limit'], 'aircraft', 'aircraft')} still flying at the "
            f"{s['time_limit_min']:.0f}-min time limit, a median {_fmt(d['median'])} nm "
            f"({_fmt(d['min'])} - {_fmt(d['max'])}) from the destination"
        )
    if s["aircraft_left_workspace"]:
        parts.append(f"{_count(s['aircraft_left_workspace'], 'aircraft', 'aircraft')} left the workspace")
    return f"{_count(s['aircraft_not_home'], 'aircraft', 'aircraft')} not home in {_count(s['runs_not_home'], 'run')}: " + "; ".join(parts)


def envelope_note(s: dict[str, Any]) -> str:
    if s["runs_outside_envelope"] == 0:
        return "checked at every integration step"
    return (
        f"{_count(s['steps_outside_envelope'], 'step')} of {s['steps']} outside; in "
        f"{_count(s['runs_outside_envelope_after_a_fallback'], 'run')} a step outside falls in the period of a "
        f"fallback decision, in {_count(s['runs_outside_envelope_without_a_fallback'], 'run')} in the period of a "
        "decision whose predicted flight was feasible (note 2)"
    )


def start_kept_cell(s: dict[str, Any]) -> str:
    """The decisions that applied the chain's start without an accepted move, of all."""
    kept, decisions = s.get("decisions_start_kept"), s["decisions"]
    if kept is None:
        return "n/a"
    return f"{kept} of {decisions} ({100 * kept / decisions:.0f} %)" if decisions else "0 of 0"


def mpc_rows(
    scenario: str, summary: dict[str, Any], s: dict[str, Any], proposal: str = "homing"
) -> list[tuple[str, str, str, str]]:
    """The table's rows of one MPC study (``proposal``: "homing", the default controller,
    or "paper", Table I's proposal)."""
    paper = MPC_STUDIES.get(scenario) or {}
    runs = s["runs"]
    low, high = s["envelope_kt"]
    label = f"{scenario}, MPC under wind" if proposal == "homing" else \
        f"{scenario}, MPC with Table I's proposal (`--proposal paper`) under wind"
    sep = summary["min_separation_nm"]
    rows = [
        (f"{label}: runs where every aircraft arrives", paper.get("arrive", "-"),
         f"{s['runs_all_home']}/{runs}" + _interval(summary), arrival_note(s)),
        (f"{label}: runs with a loss of separation (< 5 nm)", "0" if paper else "-", f"{s['runs_with_los']}/{runs}",
         f"{s['los_pairs']} pairs" if s["los_pairs"] else ""),
        (f"{label}: minimum separation over runs (nm)", paper.get("separation_nm", "-"),
         f"{_fmt(sep['min'])} - {_fmt(sep['max'])} (mean {_fmt(sep['mean'])})", ""),
        (f"{label}: runs with an integration step outside [{low:.0f}, {high:.0f}] kt",
         "0" if paper else "-", f"{s['runs_outside_envelope']}/{runs}", envelope_note(s)),
        (f"{label}: airspeed range over every step of every run (kt)",
         f"inside [{low:.0f}, {high:.0f}]" if paper else "-",
         f"{_fmt(s['airspeed_min_kt'], 0)} .. {_fmt(s['airspeed_max_kt'], 0)}",
         f"worst excursion {s['worst_excursion_kt']:.0f} kt" if s["worst_excursion_kt"] > 0 else ""),
        (f"{label}: decisions without any feasible candidate (fallbacks)", "-",
         f"{s['fallbacks']} of {s['decisions']}",
         f"in {_count(s['runs_with_a_fallback'], 'run')}" if s["fallbacks"] else ""),
        (f"{label}: decisions that apply the chain's start without an accepted move", "-", start_kept_cell(s),
         "the start: every aircraft aimed home" if proposal == "homing" else "the start: the first random draw"),
        (f"{label}: mean airspeed over every step (kt)", "near 454" if paper else "-",
         _fmt(s["mean_airspeed_kt"], 0), ""),
        (f"{label}: flight time of the arrived aircraft (min)", paper.get("time_min", "-"),
         f"mean {_fmt(summary['flight_time_min']['mean'])}, max {_fmt(summary['flight_time_min']['max'])}",
         "" if s["runs_all_home"] == runs else
         f"mean {_fmt(s['flight_time_all_home_min'])} over the runs where every aircraft arrived"),
        (f"{label}: compute time per run (s)",
         f"{paper['compute_s']} (dual-core Pentium 3.2 GHz)" if paper else "-",
         f"{_fmt(summary['wall_s_per_run']['mean'], 2)} (one core, {platform.machine()})", "note 3"),
        (f"{label}: peak memory (MB)", paper.get("memory_mb", "-"), _fmt(summary["peak_rss_mb"], 0),
         "resident set of a worker process, Python and numba included"),
    ]
    return rows


def nf_rows(nf4: dict[str, Any], nf6: dict[str, Any], nfw: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    rows = []
    for n, nf in ((4, nf4), (6, nf6)):
        low, high = nf["airspeed_kt"]
        rows += [
            (f"converging-{n}, NF alone, no wind: aircraft that arrive; losses of separation", "all; 0",
             f"{nf['arrived']}/{n}; {nf['los_count']}", ""),
            (f"converging-{n}, NF alone, no wind: minimum separation (nm)", "22" if n == 4 else "-",
             _fmt(nf["min_separation_nm"]), "note 1"),
            (f"converging-{n}, NF alone, no wind: airspeed range (kt); steps outside the envelope", "-",
             f"{_fmt(low, 0)} .. {_fmt(high, 0)}; {100 * nf['envelope_violation_fraction']:.1f} %",
             "the NF alone has no envelope"),
        ]
    rows += [
        ("converging-4, NF alone: airspeed decays toward zero on the approach", "yes",
         ", ".join(f"{v:.0f}" for v in nf4["airspeed_at_arrival_kt"]) + " kt on the last step", ""),
        ("converging-6, NF alone, no wind: roundabout radius (nm)", "about 190", _fmt(nf6["roundabout_radius_nm"]),
         "closest approach to the centre, mean over aircraft; note 1"),
        (f"converging-4, NF alone, wind σ = {nfw['wind_sigma_mps']} m/s: runs with an aircraft that never arrives",
         "some", f"{nfw['runs_with_an_aircraft_that_never_arrives']}/{nfw['runs']}",
         f"{nfw['aircraft_never_arriving']} aircraft, a median {_fmt(nfw['stall_distance_nm']['median'])} nm short"
         if nfw["aircraft_never_arriving"] else ""),
        (f"converging-4, NF alone, wind σ = {nfw['wind_sigma_mps']} m/s: runs with a loss of separation", "-",
         f"{nfw['runs_with_a_loss_of_separation']}/{nfw['runs']}", ""),
    ]
    return rows


def summary_paragraph(results: dict[str, Any]) -> str:
    """The report's summary: every figure from the table."""
    parts = []
    for scenario in MPC_STUDIES:
        s = results["safety"][scenario]
        parts.append(_study_sentence(scenario, s))
    paper_parts = [_study_sentence(scenario, s) for scenario, s in results.get("paper_safety", {}).items()]
    nf4, nf6 = results["nf4"], results["nf6"]
    text = f"The MPC (homing proposal) under wind (σ = {WIND_SIGMA_MPS} m/s): " + "; ".join(parts) + ". "
    if paper_parts:
        text += "With Table I's proposal (`--proposal paper`): " + "; ".join(paper_parts) + ". "
    return text + (
        f"The NF alone without wind keeps a minimum separation of {_fmt(nf4['min_separation_nm'])} nm with 4 "
        f"aircraft (paper 22) and {_fmt(nf6['min_separation_nm'])} nm with 6 ({nf6['los_count']} pairs losing "
        f"separation), and circles at {_fmt(nf6['roundabout_radius_nm'])} nm (paper about 190)."
    )


def _study_sentence(scenario: str, s: dict[str, Any]) -> str:
    """One study's outcome in a sentence (of the summary)."""
    runs = s["runs"]
    text = (
        f"{scenario}: every aircraft home in {s['runs_all_home']}/{runs} runs, a loss of separation in "
        f"{s['runs_with_los']}, a step outside the envelope in {s['runs_outside_envelope']}"
    )
    if s["runs_outside_envelope"]:
        text += f" (worst excursion {s['worst_excursion_kt']:.0f} kt)"
    text += f", {_count(s['fallbacks'], 'fallback')}"
    return text


def write_report(path: Path, results: dict[str, Any]) -> None:
    """Write the table; blocks that other scripts wrote between markers in the old report
    are kept, after the generated part."""
    config = SimConfig()
    rows = []
    for scenario in MPC_STUDIES:
        rows += mpc_rows(scenario, results["mpc"][scenario], results["safety"][scenario])
    for scenario in results.get("paper_safety", {}):
        rows += mpc_rows(scenario, results["paper_mpc"][scenario], results["paper_safety"][scenario], "paper")
    rows += nf_rows(results["nf4"], results["nf6"], results["nf_wind"])
    reused = {k: v for k, v in results["reused"].items() if v}
    reuse_text = (
        "Runs reused from earlier invocations of the same build: "
        + ", ".join(f"{k} {v}" for k, v in reused.items()) + "."
        if reused else "No run was reused: every run was flown by this invocation."
    )
    lines = [
        "# Reproduction of the paper's section IV",
        "",
        f"Generated by `{results['command']}`: the MPC studies fly seeds 0..R-1, "
        + ", ".join(f"R = {n} for {k}" for k, n in results["runs"].items())
        + "".join(f", R = {n} for {k} with Table I's proposal" for k, n in results.get("paper_runs", {}).items())
        + " (converging-N is the paper's encounter, "
        f"random-N a seeded random crossing encounter per seed) under a hidden wind of σ = {WIND_SIGMA_MPS} m/s "
        f"per component; integration step "
        f"{config.dt_s:g} s, arrival within {config.arrival_tolerance_nm:g} nm, time limit "
        f"{MAX_EPISODE_S / 60:.0f} min. The NF-alone rows fly seed 0 without wind, and "
        f"{results['nf_wind']['runs']} seeds under wind. Every run was flown by build "
        f"`{results['build']}` (`atc_nf_env.build.fingerprint()`: a hash of the sources that fly a run and of the "
        f"Python, NumPy and numba versions). {reuse_text} Figures are in `{results['figures']}/`.",
        "",
        "## The controller",
        "",
        HEADLINE_CONTROLLER,
        "",
        "## In short",
        "",
        results["summary"],
        "",
        "## The table",
        "",
        "| claim | paper | ours | note |",
        "|---|---|---|---|",
        *[f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows],
        "",
        "Notes.",
        "",
        f"1. Proximity function. Our G_i senses neighbours within {config.sensing_radius_nm:g} nm and concentrates",
        f"   its repulsion inside {config.barrier_nm:g} nm (`SimConfig`); the paper's NF interacts over",
        "   the whole encounter. Airspeed goes with ‖∇Φ‖², so the range of G_i sets both the NF",
        "   alone's separation and roundabout and how far the repulsion moves the airspeed.",
        "2. Prediction. The MPC never sees the wind: it predicts with its own estimate, corrected",
        "   from the observed drift after every period, so the real flight of a decision whose",
        "   predicted flight was feasible can still leave the envelope. A fallback decision is one",
        "   where no candidate's predicted flight was feasible.",
        "3. Compute time. One run is one process on one core, mean over runs; the studies ran",
        "   two workers on the 2 cores of a machine that other work shared. `BENCHMARKS.md` has",
        "   episode times measured alone. The paper's figures are for a 2008 machine and an",
        "   implementation we do not know.",
        "",
    ]
    text = "\n".join(lines)
    if path.exists():
        for block in marked_sections(path.read_text()).values():
            text += "\n" + block + "\n"
    path.write_text(text)


def main(argv: list[str] | None = None) -> int:
    from atc_nf_env.cli import HelpFormatter

    parser = argparse.ArgumentParser(
        prog="atc-nf reproduce", formatter_class=HelpFormatter,
        description="Reproduce the paper's section IV: figures and table, into --out unless --write.")
    parser.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs per MPC study")
    parser.add_argument("--random-runs", type=int,
                        help="Monte Carlo runs of the random-4 and random-6 MPC studies (default: --runs)")
    parser.add_argument("--paper-runs", type=int,
                        help="Monte Carlo runs of the studies with Table I's proposal (default: --runs)")
    parser.add_argument("--nf-wind-runs", type=int, default=100, help="runs of the NF alone under wind")
    parser.add_argument("--out", type=Path, default=Path("out/reproduction"),
                        help="folder for the runs (JSON lines) and, without --write, the report and figures")
    parser.add_argument("--write", action="store_true",
                        help="write the report into REPRODUCTION.md and the figures into docs/figures/ (the "
                        "tracked files) instead of into --out")
    parser.add_argument("--report", type=Path,
                        help="the report's file (default: OUT/REPRODUCTION.md, or REPRODUCTION.md with --write)")
    parser.add_argument("--figures", type=Path,
                        help="folder for the figures (default: OUT/figures, or docs/figures with --write)")
    parser.add_argument("--workers", type=int, help="worker processes (default: all cores)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    for option, value in (("--runs", args.runs), ("--random-runs", args.random_runs),
                          ("--paper-runs", args.paper_runs), ("--nf-wind-runs", args.nf_wind_runs),
                          ("--workers", args.workers)):
        if value is not None and value < 1:
            parser.error(f"{option} {value}: must be >= 1")
    figures = args.figures or (Path("docs/figures") if args.write else args.out / "figures")
    report = args.report or (Path("REPRODUCTION.md") if args.write else args.out / "REPRODUCTION.md")
    figures.mkdir(parents=True, exist_ok=True)
    args.out.mkdir(parents=True, exist_ok=True)
    report.parent.mkdir(parents=True, exist_ok=True)
    runs = {k: args.runs if k.startswith("converging") or args.random_runs is None else args.random_runs
            for k in MPC_STUDIES}
    paper_runs = {k: args.runs if args.paper_runs is None else args.paper_runs for k in PAPER_PROPOSAL_STUDIES}
    command = f"atc-nf reproduce --runs {args.runs}" + (
        f" --random-runs {args.random_runs}" if args.random_runs is not None else "") + (
        f" --paper-runs {args.paper_runs}" if args.paper_runs is not None else "") + (
        f" --nf-wind-runs {args.nf_wind_runs}" if args.nf_wind_runs != 100 else "") + (
        " --write" if args.write else "")
    results: dict[str, Any] = {"runs": runs, "paper_runs": paper_runs, "command": command, "figures": str(figures),
                               "build": build.fingerprint(), "mpc": {}, "safety": {}, "paper_mpc": {},
                               "paper_safety": {}, "reused": {}}
    results["nf4"], _ = nf_alone.windless(4, figures)
    results["nf6"], _ = nf_alone.windless(6, figures)
    results["nf_wind"] = nf_alone.windy(args.nf_wind_runs, figures)
    for scenario, paper in MPC_STUDIES.items():
        path = args.out / f"mpc_{scenario.replace('-', '')}.jsonl"
        summary, records, reused = fly_study(mpc_study_of(scenario), runs[scenario], path, args.workers,
                                             not args.no_progress)
        results["mpc"][scenario] = summary
        results["safety"][scenario] = run_safety(records)
        results["reused"][scenario] = reused
        if paper is None:
            continue
        n = records[0]["n_aircraft"]
        plot_airspeed_bands(
            records, figures / f"mpc_converging{n}_airspeed_bands.png",
            f"MPC, {n} aircraft, {len(records)} runs: mean and min-max airspeed over every 5-s step, "
            f"per minute (paper Fig. {paper['band_figure']})",
        )
        example = run_episode(make_policy("mpc"), converging(n), seed=0, wind_sigma_mps=WIND_SIGMA_MPS,
                              record_every=1)
        plot_trajectories(example, figures / f"mpc_converging{n}_trajectories.png",
                          title=f"MPC, {n} aircraft, seed 0 (paper Fig. {paper['trajectory_figure']})")
        plot_airspeed(example, figures / f"mpc_converging{n}_airspeed.png",
                      title=f"MPC, {n} aircraft, seed 0: airspeed")
    for scenario in PAPER_PROPOSAL_STUDIES:
        path = args.out / f"mpc_paper_{scenario.replace('-', '')}.jsonl"
        summary, records, reused = fly_study(mpc_study_of(scenario, "paper"), paper_runs[scenario], path,
                                             args.workers, not args.no_progress)
        results["paper_mpc"][scenario] = summary
        results["paper_safety"][scenario] = run_safety(records)
        results["reused"][f"{scenario} (Table I's proposal)"] = reused
    results["summary"] = summary_paragraph(results)
    (args.out / "reproduction.json").write_text(json.dumps(results, indent=2) + "\n")
    write_report(report, results)
    print(report.read_text())
    print(f"report written to {report}, figures to {figures}/" + (
        "" if args.write else " (give --write to update REPRODUCTION.md and docs/figures/)"), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
