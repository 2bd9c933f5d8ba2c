"""Figures of an episode: trajectories (paper Figs. 5-8) and airspeed over time (Figs. 3, 4, 9)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from atc_nf_env.episode import EpisodeResult
from atc_nf_env.kernel import R_AIRSPEED, R_FLEW, R_X, R_Y
from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT, AIRSPEED_NOMINAL_KT


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_trajectories(result: EpisodeResult, path: str | Path, title: str | None = None) -> None:
    """Ground tracks of every aircraft, with starts, destinations and 5 nm disks at the
    moment of minimum separation is not known here, so at the start."""
    plt = _pyplot()
    records = result.records
    if records.shape[0] == 0:
        raise ValueError("the episode was run without recording (record_every = 0)")
    scenario_starts = records[0, :, R_X : R_Y + 1]
    fig, ax = plt.subplots(figsize=(6.2, 6.2))
    for i in range(records.shape[1]):
        flew = records[:, i, R_FLEW] > 0
        line = ax.plot(records[flew, i, R_X], records[flew, i, R_Y], lw=1.4, label=f"aircraft {i}")[0]
        ax.plot(*scenario_starts[i], "o", color=line.get_color(), ms=5)
        last = np.flatnonzero(flew)[-1]
        ax.plot(records[last, i, R_X], records[last, i, R_Y], "s", color=line.get_color(), ms=5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (nm)")
    ax.set_ylabel("y (nm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title or f"{result.metrics.scenario}: trajectories (o start, ■ end)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_airspeed(result: EpisodeResult, path: str | Path, title: str | None = None) -> None:
    """Airspeed of every aircraft over time, with the envelope [366, 540] kt."""
    plt = _pyplot()
    records = result.records
    if records.shape[0] == 0:
        raise ValueError("the episode was run without recording (record_every = 0)")
    minutes = result.times_s / 60.0
    fig, ax = plt.subplots(figsize=(8, 4.2))
    for i in range(records.shape[1]):
        flew = records[:, i, R_FLEW] > 0
        ax.plot(minutes[flew], records[flew, i, R_AIRSPEED], lw=1.2, label=f"aircraft {i}")
    ax.axhline(AIRSPEED_MIN_KT, color="k", ls="--", lw=1)
    ax.axhline(AIRSPEED_MAX_KT, color="k", ls="--", lw=1, label="envelope")
    ax.axhline(AIRSPEED_NOMINAL_KT, color="g", ls=":", lw=1, label="nominal")
    top = max(AIRSPEED_MAX_KT * 1.3, float(np.percentile(records[..., R_AIRSPEED], 99)) * 1.05)
    ax.set_ylim(min(0.0, float(records[..., R_AIRSPEED].min())) - 20, top)
    ax.set_xlabel("time (min)")
    ax.set_ylabel("airspeed (kt)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    ax.set_title(title or f"{result.metrics.scenario}: airspeed")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_episode_plots(result: EpisodeResult, directory: str | Path, prefix: str) -> list[Path]:
    """Trajectories and airspeed figures of an episode into ``directory``; returns the paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = [directory / f"{prefix}_trajectories.png", directory / f"{prefix}_airspeed.png"]
    plot_trajectories(result, paths[0])
    plot_airspeed(result, paths[1])
    return paths
