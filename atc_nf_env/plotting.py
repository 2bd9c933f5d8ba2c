"""Figures of an episode: trajectories (paper Figs. 5-8) and airspeed over time (Figs. 3, 4, 9).

Aircraft keep the same colours here and in the animations (``rendering.AIRCRAFT_COLORS``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import EpisodeResult
from atc_nf_env.kernel import R_AIRSPEED, R_AIRSPEED_MAX, R_AIRSPEED_MIN, R_FLEW, R_X, R_Y
from atc_nf_env.rendering import AIRCRAFT_COLORS
from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT, AIRSPEED_NOMINAL_KT, DECISION_PERIOD_S

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Caption of an airspeed figure whose policy moves the waypoints every period.
SAWTOOTH_NOTE = (
    "The sawtooth: every {period:g} min the policy sets new waypoints about 100 nm ahead; the NF "
    "airspeed then falls\nas the aircraft closes on its waypoint (airspeed grows with ‖∇Φ‖² and the "
    "distance²) and jumps back at the next decision."
)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def aircraft_color(i: int) -> str:
    """The colour of aircraft ``i`` in every figure and animation."""
    return AIRCRAFT_COLORS[i % len(AIRCRAFT_COLORS)]


def episode_title(result: EpisodeResult, what: str, policy: str | None = None,
                  wind_sigma_mps: float | None = None) -> str:
    """'<policy> on <scenario>, seed S, wind (east, north) kt [σ m/s]: <what>'."""
    m = result.metrics
    wind = f"wind ({m.wind_kt[0]:+.1f}, {m.wind_kt[1]:+.1f}) kt"
    if wind_sigma_mps is not None:
        wind += f" (σ {wind_sigma_mps:g} m/s)"
    head = f"{policy} on {m.scenario}" if policy else m.scenario
    return f"{head}, seed {m.seed}, {wind}: {what}"


def plot_trajectories(result: EpisodeResult, path: str | Path, title: str | None = None, *,
                      policy: str | None = None, wind_sigma_mps: float | None = None) -> None:
    """Ground tracks of every aircraft: hollow circles at the starts, filled squares where
    each track ends (drawn on top: in converging encounters an aircraft ends where
    another started)."""
    plt = _pyplot()
    records = result.records
    if records.shape[0] == 0:
        raise ValueError("the episode was run without recording (record_every = 0)")
    starts = records[0, :, R_X : R_Y + 1]
    fig, ax = plt.subplots(figsize=(6.4, 6.6))
    for i in range(records.shape[1]):
        color = aircraft_color(i)
        flew = records[:, i, R_FLEW] > 0
        ax.plot(records[flew, i, R_X], records[flew, i, R_Y], lw=1.4, color=color, label=f"aircraft {i}")
        ax.plot(*starts[i], "o", mfc="none", mec=color, mew=1.6, ms=11, zorder=3)
        last = np.flatnonzero(flew)[-1] if flew.any() else 0
        ax.plot(records[last, i, R_X], records[last, i, R_Y], "s", color=color, ms=5, zorder=4)
    ax.plot([], [], "o", mfc="none", mec="k", ms=9, label="start")
    ax.plot([], [], "s", color="k", ms=5, label="end of track")
    _finish_map(plt, fig, ax, path, title or episode_title(result, "trajectories", policy, wind_sigma_mps))


def _finish_map(plt, fig, ax, path: str | Path, title: str) -> None:
    """A plan view's axes (nm, equal scales), legend and title, saved to ``path`` and closed."""
    ax.set_aspect("equal")
    ax.set_xlabel("x (nm)")
    ax.set_ylabel("y (nm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: A jump of a slot's position between two records larger than this (nm) is one flight
#: leaving the slot and the next entering it: the track is cut there.
STREAM_TRACK_JUMP_NM: float = 30.0


def plot_stream_trajectories(result: EpisodeResult, path: str | Path, title: str | None = None, *,
                             policy: str | None = None, wind_sigma_mps: float | None = None,
                             sector_radius_nm: float | None = None) -> None:
    """Ground tracks of a traffic stream's flights (a slot's track cut where one flight
    left it and the next entered), a dot where each track ends, and the sector's edge."""
    plt = _pyplot()
    records = result.records
    if records.shape[0] == 0:
        raise ValueError("the episode was run without recording (record_every = 0)")
    fig, ax = plt.subplots(figsize=(6.4, 6.6))
    if sector_radius_nm:
        circle = np.linspace(0.0, 2.0 * np.pi, 361)
        ax.plot(sector_radius_nm * np.cos(circle), sector_radius_nm * np.sin(circle), color="0.6", lw=1, ls="--",
                label="sector edge")
    for i in range(records.shape[1]):
        flew = records[:, i, R_FLEW] > 0
        xy = records[:, i, R_X : R_Y + 1].copy()
        jump = np.r_[False, np.hypot(*np.diff(xy, axis=0).T) > STREAM_TRACK_JUMP_NM]
        segment = np.cumsum(jump | np.r_[False, flew[1:] & ~flew[:-1]])
        for k in np.unique(segment[flew]):
            rows = flew & (segment == k)
            ax.plot(xy[rows, 0], xy[rows, 1], lw=0.9, color=aircraft_color(int(k) * 7 + i), alpha=0.85)
            last = np.flatnonzero(rows)[-1]
            ax.plot(*xy[last], ".", color="k", ms=3, zorder=3)
    ax.plot([], [], ".", color="k", ms=5, label="end of track (arrival or end of episode)")
    _finish_map(plt, fig, ax, path, title or episode_title(result, "trajectories", policy, wind_sigma_mps))


def _moves_waypoints(result: EpisodeResult) -> bool:
    waypoints = result.waypoints
    return len(waypoints) > 1 and bool(np.any(np.abs(np.diff(waypoints, axis=0)) > 1e-6))


#: An aircraft's lowest or highest airspeed reached within a step is marked where it lies
#: more than this beyond its line (kt): the band alone can be too thin to see.
EXTREME_MARK_KT: float = 10.0


def airspeed_figure(result: EpisodeResult, title: str | None = None, *, policy: str | None = None,
                    wind_sigma_mps: float | None = None, caption: str | None = None) -> Figure:
    """The airspeed figure (``plot_airspeed``) as an open matplotlib ``Figure``; the
    caller saves and closes it. Each aircraft's line, band and markers carry the gid
    ``"aircraft i"``."""
    from atc_nf_env.tables import airspeed_range_kt

    plt = _pyplot()
    records = result.records
    if records.shape[0] == 0:
        raise ValueError("the episode was run without recording (record_every = 0)")
    minutes = result.times_s / 60.0
    if caption is None and _moves_waypoints(result):
        caption = SAWTOOTH_NOTE.format(period=DECISION_PERIOD_S / 60.0)
    fig, ax = plt.subplots(figsize=(8, 4.6 if caption else 4.2))
    lowest, highest = airspeed_range_kt(records)
    beyond_the_line = False
    for i in range(records.shape[1]):
        flew = records[:, i, R_FLEW] > 0
        if not flew.any():
            continue
        color, gid, t = aircraft_color(i), f"aircraft {i}", minutes[flew]
        line = records[flew, i, R_AIRSPEED]
        ax.plot(t, line, lw=1.2, color=color, gid=gid,
                label=None if result.metrics.stream else gid)  # a stream's slots: no legend each
        # The band's edges are drawn so that a one-step excursion (a sub-step spike) shows.
        ax.fill_between(t, records[flew, i, R_AIRSPEED_MIN], records[flew, i, R_AIRSPEED_MAX], color=color,
                        alpha=0.3, lw=0.5, gid=gid)
        for extreme, drawn, marker in ((lowest[i], line.min(), "v"), (highest[i], line.max(), "^")):
            if abs(extreme - drawn) > EXTREME_MARK_KT:  # reached within a step only: marked where
                beyond_the_line = True
                at = t[np.flatnonzero(records[flew, i, R_AIRSPEED_MIN if marker == "v" else R_AIRSPEED_MAX]
                                      == extreme)[0]]
                ax.plot([at], [extreme], marker, color=color, ms=5, mec="k", mew=0.5, gid=gid, zorder=4)
    if beyond_the_line:
        ax.fill_between([], [], [], color="0.5", alpha=0.3, label="range within a step (sub-steps)")
        ax.plot([], [], "v", color="0.5", mec="k", mew=0.5, ms=5, label="extreme reached within a step")
    ax.axhline(AIRSPEED_MIN_KT, color="k", ls="--", lw=1)
    ax.axhline(AIRSPEED_MAX_KT, color="k", ls="--", lw=1,
               label=f"envelope {AIRSPEED_MIN_KT:g}–{AIRSPEED_MAX_KT:g} kt")
    ax.axhline(AIRSPEED_NOMINAL_KT, color="0.45", ls="-.", lw=1, label=f"nominal {AIRSPEED_NOMINAL_KT:g} kt")
    flown = np.isfinite(lowest)
    low = min(AIRSPEED_MIN_KT - 60.0, float(lowest[flown].min(initial=np.inf)))
    high = max(AIRSPEED_MAX_KT + 60.0, float(highest[flown].max(initial=-np.inf)))
    cap = SimConfig().airspeed_cap_kt
    if max(-low, high) >= cap:
        for sign in (1, -1):
            ax.axhline(sign * cap, color="r", ls=":", lw=1, label=f"±{cap:g} kt guard (law saturated)" if sign > 0
                       else None)
    m = result.metrics
    if flown.any() and m.airspeed_min_kt is not None and (m.airspeed_min_kt < lowest[flown].min()
                                                          or m.airspeed_max_kt > highest[flown].max()):
        # A recording sparser than every step: the run's range lies partly between records.
        ax.text(0.01, 0.02, f"between the records the airspeed reached {m.airspeed_min_kt:.0f}–"
                f"{m.airspeed_max_kt:.0f} kt (not drawn)", transform=ax.transAxes, fontsize=7.5)
    margin = 0.04 * (high - low)
    ax.set_ylim(low - margin, high + margin)
    ax.set_xlabel("time (min)")
    ax.set_ylabel("airspeed (kt)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    ax.set_title(title or episode_title(result, "airspeed", policy, wind_sigma_mps), fontsize=9)
    if caption:
        fig.text(0.01, 0.01, caption, fontsize=7.5, va="bottom", ha="left")
        fig.tight_layout(rect=(0, 0.09, 1, 1))
    else:
        fig.tight_layout()
    return fig


def plot_airspeed(result: EpisodeResult, path: str | Path, title: str | None = None, *,
                  policy: str | None = None, wind_sigma_mps: float | None = None,
                  caption: str | None = None) -> None:
    """Airspeed of every aircraft over time (kt against minutes) into ``path``: a line
    through the airspeed at the end of each recorded integration step, a band around it
    from the lowest to the highest airspeed within that step (a step refined at the law's
    singularity, kernel guard 8, can reach far beyond its ends), and a marker where an
    aircraft's extreme lies within a step only (more than ``EXTREME_MARK_KT`` beyond the
    line); the envelope [366, 540] kt and, when the
    data reach it, the ±cap guard of the law. The axis spans every value drawn, the
    bands' included: from a recording of every step (``atc-nf fly``) each aircraft's
    extremes are those of the ``fly`` table. A sparser recording leaves the steps between
    records undrawn; when the run's range reaches beyond the records a note under the
    lines says so. ``caption`` (default: the sawtooth note when the policy moved the
    waypoints) is printed under the axes."""
    fig = airspeed_figure(result, title, policy=policy, wind_sigma_mps=wind_sigma_mps, caption=caption)
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)


def write_episode_plots(result: EpisodeResult, directory: str | Path, prefix: str, *,
                        policy: str | None = None, wind_sigma_mps: float | None = None) -> list[Path]:
    """Trajectories and airspeed figures of an episode into ``directory`` (created if
    missing), titled with the policy, scenario, seed and wind; returns the paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = [directory / f"{prefix}_trajectories.png", directory / f"{prefix}_airspeed.png"]
    if result.metrics.stream:
        plot_stream_trajectories(result, paths[0], policy=policy, wind_sigma_mps=wind_sigma_mps,
                                 sector_radius_nm=result.metrics.stream.get("sector_radius_nm"))
    else:
        plot_trajectories(result, paths[0], policy=policy, wind_sigma_mps=wind_sigma_mps)
    plot_airspeed(result, paths[1], policy=policy, wind_sigma_mps=wind_sigma_mps)
    return paths
