"""The shipped agents off their training conditions: wind σ × number of aircraft, per run.

Flies every shipped model (``agents/models/*.zip``) on random-N encounters for N in
``--aircraft`` (3…8, 12, 16 by default) under wind σ in ``--sigmas`` (0, 5.17 and 15 m/s),
``--runs`` runs per cell from ``--first-seed`` (seeds no development run flew), alone and
inside the safety filter (``atc_nf_env.shield.SafetyFilter``, its defaults). A model is
flown outside the range its card states too (that is the point of the grid); such cells
are marked ``*``.

Per cell: runs safe (no loss of separation and no integration step outside [366, 540] kt)
and runs with every aircraft home, alone and in the filter. One table (``--write``: into
BENCHMARKS.md, section ``generalization-grid``) and one figure (``--figure``: the share
of runs safe per cell, alone and in the filter, one column per model).

Run: python bench/generalization_grid.py --runs 10 --workers 2 --write --figure docs/figures/generalization_grid.png
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MODELS = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "agents" / "models").glob("*.zip"))
SIGMAS_MPS = (0.0, 5.17, 15.0)
AIRCRAFT = (3, 4, 5, 6, 7, 8, 12, 16)
MODES = ("alone", "filter")


def fly_cell(model: str, n_aircraft: int, sigma_mps: float, seeds: range) -> dict:
    """One cell: per mode, runs safe and runs home over ``seeds``; whether the cell lies
    inside the model's stated operating range."""
    from agents.policy import SB3AgentPolicy
    from atc_nf_env.episode import run_episode
    from atc_nf_env.shield import SafetyFilter

    agent = SB3AgentPolicy(ROOT / model, outside_range="ignore")
    rng = agent.operating_range
    inside = rng is None or (rng["n_aircraft"][0] <= n_aircraft <= rng["n_aircraft"][1]
                             and rng["wind_sigma_mps"][0] - 1e-9 <= sigma_mps <= rng["wind_sigma_mps"][1] + 1e-9)
    cell = {"inside": inside}
    for mode in MODES:
        safe = home = 0
        for seed in seeds:
            policy = agent if mode == "alone" else SafetyFilter(agent)
            m = run_episode(policy, f"random-{n_aircraft}", seed=seed, wind_sigma_mps=sigma_mps).metrics
            safe += m.los_count == 0 and m.worst_excursion_kt == 0.0
            home += bool(all(m.arrived))
        cell[mode] = (safe, home)
    return cell


def _fly_packed(job: tuple) -> tuple:
    return job, fly_cell(*job)


def figure(cells: dict, models: list[str], sigmas: list[float], aircraft: list[int], runs: int, path: Path) -> None:
    """Share of runs safe per (N, σ), alone (top row) and in the filter (bottom), a column per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(models), figsize=(2.3 * len(models) + 1.2, 6.4), squeeze=False,
                             sharex=True, sharey=True)
    for col, model in enumerate(models):
        for row, mode in enumerate(MODES):
            ax = axes[row, col]
            share = np.array([[cells[(model, n, s)][mode][0] / runs for s in sigmas] for n in aircraft])
            image = ax.imshow(share, vmin=0.0, vmax=1.0, cmap="RdYlGn", aspect="auto", origin="lower")
            for i, n in enumerate(aircraft):
                for j, s in enumerate(sigmas):
                    mark = "" if cells[(model, n, s)]["inside"] else "*"
                    ax.text(j, i, f"{cells[(model, n, s)][mode][0]}{mark}", ha="center", va="center", fontsize=7)
            ax.set_xticks(range(len(sigmas)), [f"{s:g}" for s in sigmas])
            ax.set_yticks(range(len(aircraft)), [str(n) for n in aircraft])
            if row == 0:
                ax.set_title(Path(model).stem, fontsize=9)
            if row == 1:
                ax.set_xlabel("wind σ (m/s)")
            if col == 0:
                ax.set_ylabel(f"{mode}: aircraft")
    fig.colorbar(image, ax=axes, shrink=0.6, label=f"share of {runs} runs safe")
    fig.suptitle("Runs safe on random-N (* outside the model's stated range)", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    from _report import publish  # bench/ is on sys.path when run as a script

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=",".join(MODELS))
    parser.add_argument("--sigmas", default=",".join(f"{s:g}" for s in SIGMAS_MPS), help="wind σ values, m/s")
    parser.add_argument("--aircraft", default=",".join(map(str, AIRCRAFT)), help="numbers of aircraft")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1_200_000)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    parser.add_argument("--figure", type=Path, help="write the figure (PNG) here")
    args = parser.parse_args(argv)
    try:
        models = [m for m in args.models.split(",") if m]
        sigmas = [float(s) for s in args.sigmas.split(",") if s]
        aircraft = [int(n) for n in args.aircraft.split(",") if n]
    except ValueError as error:
        parser.error(f"--sigmas and --aircraft take numbers separated by commas: {error}")
    missing = [m for m in models if not (ROOT / m).is_file()]
    if missing:
        parser.error(f"--models: no such model file: {', '.join(missing)}")
    if args.runs < 1 or args.workers < 1 or args.first_seed < 0 or any(n < 2 for n in aircraft) or any(
            not 0.0 <= s <= 50.0 for s in sigmas):
        parser.error("--runs and --workers >= 1, --first-seed >= 0, aircraft >= 2, sigmas in [0, 50] m/s")
    seeds = range(args.first_seed, args.first_seed + args.runs)
    jobs = [(model, n, s, seeds) for model in models for n in aircraft for s in sigmas]
    cells: dict = {}
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            for job, cell in pool.map(_fly_packed, jobs):
                cells[job[:3]] = cell
    else:
        for job in jobs:
            cells[job[:3]] = fly_cell(*job)
    header = "| model | aircraft | " + " | ".join(f"σ {s:g}: alone safe / home | σ {s:g}: filter safe / home"
                                                  for s in sigmas) + " |"
    rows = [header, "|---|---:|" + "---:|" * (2 * len(sigmas))]
    for model in models:
        for n in aircraft:
            parts = []
            for s in sigmas:
                cell = cells[(model, n, s)]
                mark = "" if cell["inside"] else "*"
                parts += [f"{cell['alone'][0]} / {cell['alone'][1]}{mark}", f"{cell['filter'][0]} / {cell['filter'][1]}{mark}"]
            rows.append(f"| {Path(model).stem} | {n} | " + " | ".join(parts) + " |")
    command = (f"python bench/generalization_grid.py --sigmas {args.sigmas} --aircraft {args.aircraft} --runs {args.runs} "
               f"--first-seed {args.first_seed}" + ("" if args.models == ",".join(MODELS) else f" --models {args.models}")
               + (f" --figure {args.figure}" if args.figure else ""))
    text = "\n".join([
        "## Agents off their training conditions",
        "",
        f"`{command}` — every shipped model on random-N, seeds {seeds.start}–{seeds.stop - 1} per cell, alone and in "
        "the safety filter (its defaults): runs safe (no LoS, no integration step outside [366, 540] kt) / runs with "
        f"every aircraft home, of {args.runs}. `*`: outside the range the model's card states."
        + (f" Figure: `{args.figure}`." if args.figure else ""),
        "",
        *rows,
    ])
    if args.figure:
        figure(cells, models, sigmas, aircraft, args.runs, args.figure)
    return publish("generalization-grid", text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
