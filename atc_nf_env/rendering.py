"""Rendering: one frame of the airspace as an H×W×3 uint8 array (matplotlib, no display
needed), a window for ``render_mode="human"``, and GIF animations of whole episodes.

A frame shows every aircraft with its heading (a triangle), its 5 nm separation
circle (another aircraft inside it is a loss of separation; drawn red while one is),
its current waypoint (a hollow circle, dotted line from the aircraft), its destination
(a cross), its trail, the wind (an arrow in the corner, with its speed in kt) and the
time. A traffic stream's frame shows the flights airborne (labelled with their flight
numbers and colours: a flight that enters appears at the sector's edge, one that
arrives or leaves is gone at the next decision), the sector's edge, and no empty slot. Coordinates in nm, x east, y north.

Entry points:
    ``render_simulation(sim, ...)``  one frame of a ``Simulation``;
    ``FrameRenderer.draw(snapshot)``  the drawing itself (reuses one figure);
    ``save_animation(source, path, ...)``  a GIF from frames, from an ``EpisodeResult``
        (``run_episode(..., record_every > 0)``) or by playing an env for one episode.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from atc_nf_env.kernel import FLYING, R_FLEW, R_HEADING, R_X, R_Y, S_DEST_X, S_DEST_Y, S_HEADING, S_STATUS, S_WP_X, S_WP_Y, S_X, S_Y
from atc_nf_env.units import SEPARATION_MIN_NM

#: Colour of aircraft i (cyclic), shared with the static figures (``plotting``); red is
#: kept for the conflict disks.
AIRCRAFT_COLORS = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f", "#d62728",
)


@dataclass
class Snapshot:
    """What one frame shows. Positions, waypoints, destinations in nm; headings in rad.

    Attributes:
        positions: (N, 2) aircraft positions.
        headings: (N,) headings (counter-clockwise from east).
        flying: (N,) bool; aircraft no longer flying are drawn faded, without circle.
        waypoints: (N, 2) current waypoints.
        destinations: (N, 2).
        trails: N arrays (T_i, 2) of past positions.
        wind_kt: (2,) wind (east, north), kt, or None to draw no arrow.
        time_s: simulated time, s.
        extent: (xmin, xmax, ymin, ymax) of the view, nm.
        title: a title line.
        separation_nm: radius of the separation circles, nm.
        labels: (N,) text next to each flying aircraft (default: its index).
        color_ids: (N,) colour index of each aircraft (default: its index), so that an
            aircraft keeps its colour while others come and go.
        sector_radius_nm: radius of a traffic stream's sector, drawn around the origin
            (None: none drawn).
        legend_aircraft: one legend entry per aircraft (off for streams: dozens).
    """

    positions: np.ndarray
    headings: np.ndarray
    flying: np.ndarray
    waypoints: np.ndarray
    destinations: np.ndarray
    trails: list[np.ndarray]
    wind_kt: np.ndarray | None
    time_s: float
    extent: tuple[float, float, float, float]
    title: str = ""
    separation_nm: float = SEPARATION_MIN_NM
    in_conflict: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    labels: Sequence[str] | None = None
    color_ids: np.ndarray | None = None
    sector_radius_nm: float | None = None
    legend_aircraft: bool = True

    def __post_init__(self) -> None:
        if self.in_conflict.shape != self.flying.shape:
            self.in_conflict = conflicts(self.positions, self.flying, self.separation_nm)


def conflicts(positions: np.ndarray, flying: np.ndarray, separation_nm: float = SEPARATION_MIN_NM) -> np.ndarray:
    """(N,) bool: flying aircraft closer than ``separation_nm`` to another flying one."""
    positions = np.asarray(positions, dtype=np.float64)
    diff = positions[:, None, :] - positions[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    both = flying[:, None] & flying[None, :]
    np.fill_diagonal(both, False)
    return (both & (dist < separation_nm)).any(axis=1)


def view_extent(points: np.ndarray, margin_nm: float = 40.0) -> tuple[float, float, float, float]:
    """A square view (xmin, xmax, ymin, ymax), nm, around ``points`` (K, 2) with a margin."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    low = points.min(axis=0)
    high = points.max(axis=0)
    centre = 0.5 * (low + high)
    half = 0.5 * float((high - low).max()) + margin_nm
    return (centre[0] - half, centre[0] + half, centre[1] - half, centre[1] + half)


class FrameRenderer:
    """Draws snapshots into one reused off-screen matplotlib figure (Agg canvas: no
    display, no pyplot state). Frames are ``size_px`` × ``size_px`` × 3 uint8."""

    def __init__(self, size_px: int = 512, dpi: int = 100) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.size_px = int(size_px)
        self.figure = Figure(figsize=(self.size_px / dpi, self.size_px / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.figure)
        self.axes = self.figure.add_axes((0.11, 0.08, 0.86, 0.84))
        self._view: tuple[Any, str] | None = None
        self._artists: list[Any] = []
        self._background: Any = None

    def _frame(self, extent: tuple[float, float, float, float], title: str, n_aircraft: int = 0,
               sector_radius_nm: float | None = None) -> None:
        """The static part (axes, ticks, grid, labels, legend, a stream's sector edge),
        drawn once per view and kept as a pixel background: redrawing the tick labels
        every frame would cost most of the drawing time."""
        if (extent, title, n_aircraft, sector_radius_nm) == self._view:
            return
        ax = self.axes
        for artist in self._artists:
            artist.remove()
        ax.clear()
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.25)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (nm)", fontsize=8)
        ax.set_ylabel("y (nm)", fontsize=8)
        ax.set_title(title, fontsize=9)
        if sector_radius_nm is not None:
            circle = np.linspace(0.0, 2.0 * np.pi, 361)
            ax.plot(sector_radius_nm * np.cos(circle), sector_radius_nm * np.sin(circle), color="0.6", lw=1,
                    ls="--")
        self._legend(n_aircraft)
        self._artists = []
        self._view = (extent, title, n_aircraft, sector_radius_nm)
        self.canvas.draw()
        self._background = self.canvas.copy_from_bbox(self.figure.bbox)

    def _legend(self, n_aircraft: int) -> None:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], color=AIRCRAFT_COLORS[i % len(AIRCRAFT_COLORS)], marker=">", lw=1.0, ms=5,
                          label=f"aircraft {i}") for i in range(n_aircraft)]
        handles += [
            Line2D([], [], color="k", marker="x", ls="none", ms=5, mew=1.5, label="destination"),
            Line2D([], [], color="k", marker="o", mfc="none", ls=":", lw=0.9, ms=5, label="waypoint"),
            Line2D([], [], color="k", marker="o", mfc="none", ls="none", ms=9, label="5 nm separation"),
            Line2D([], [], color="red", marker="o", alpha=0.5, ls="none", ms=9, label="in conflict"),
        ]
        self.axes.legend(handles=handles, loc="lower right", fontsize=6, ncol=2, framealpha=0.8)

    def draw(self, snap: Snapshot) -> np.ndarray:
        """The frame (size_px, size_px, 3) uint8 of ``snap``."""
        from matplotlib.patches import Circle, Polygon

        ax = self.axes
        self._frame(
            tuple(float(v) for v in snap.extent), snap.title,  # type: ignore[arg-type]
            len(snap.positions) if snap.legend_aircraft else 0, snap.sector_radius_nm,
        )
        for artist in self._artists:
            artist.remove()
        self.canvas.restore_region(self._background)
        added: list[Any] = []
        xmin, xmax, ymin, ymax = snap.extent
        span = max(xmax - xmin, ymax - ymin)
        size = 0.018 * span  # aircraft glyph, nm
        for i in range(len(snap.positions)):
            color_id = i if snap.color_ids is None else int(snap.color_ids[i])
            color = AIRCRAFT_COLORS[color_id % len(AIRCRAFT_COLORS)]
            trail = snap.trails[i] if i < len(snap.trails) else np.zeros((0, 2))
            if len(trail) > 1:
                added += ax.plot(trail[:, 0], trail[:, 1], color=color, lw=1.0, alpha=0.7)
            added += ax.plot(*snap.destinations[i], marker="x", color=color, ms=7, mew=2)
            x, y = snap.positions[i]
            if snap.flying[i]:
                wx, wy = snap.waypoints[i]
                added += ax.plot([x, wx], [y, wy], ls=":", color=color, lw=0.9)
                added += ax.plot(wx, wy, marker="o", mfc="none", color=color, ms=6)
                conflict = bool(snap.in_conflict[i])
                added.append(
                    ax.add_patch(
                        Circle(
                            (x, y),
                            snap.separation_nm,
                            fill=conflict,
                            alpha=0.35 if conflict else 0.9,
                            color="red" if conflict else color,
                            lw=1.0,
                        )
                    )
                )
            h = snap.headings[i]
            fx, fy = math.cos(h), math.sin(h)
            nx, ny = -fy, fx
            triangle = np.array(
                [
                    [x + size * fx, y + size * fy],
                    [x - 0.6 * size * fx + 0.55 * size * nx, y - 0.6 * size * fy + 0.55 * size * ny],
                    [x - 0.6 * size * fx - 0.55 * size * nx, y - 0.6 * size * fy - 0.55 * size * ny],
                ]
            )
            added.append(ax.add_patch(Polygon(triangle, closed=True, color=color, alpha=1.0 if snap.flying[i] else 0.3)))
            if snap.flying[i]:
                added.append(
                    ax.annotate(str(i) if snap.labels is None else snap.labels[i], (x, y), xytext=(5, 5),
                                textcoords="offset points", fontsize=8, color=color)
                )
        added.append(
            ax.text(
                0.02, 0.97, f"t = {snap.time_s / 60:.1f} min", transform=ax.transAxes, va="top", fontsize=9,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"},
            )
        )
        if snap.wind_kt is not None:
            speed = float(np.hypot(*snap.wind_kt))
            base = np.array([0.86, 0.88])
            # 20 kt of wind is 0.08 of the axes; at least a visible stub.
            vector = np.asarray(snap.wind_kt, dtype=float) / 20.0 * 0.08
            if speed > 0 and np.hypot(*vector) < 0.015:
                vector *= 0.015 / np.hypot(*vector)
            added.append(
                ax.annotate(
                    "", xy=tuple(base + vector), xytext=tuple(base), xycoords="axes fraction",
                    arrowprops={"arrowstyle": "->", "lw": 1.8, "color": "black"},
                )
            )
            added.append(
                ax.text(0.86, 0.97, f"wind {speed:.0f} kt", transform=ax.transAxes, ha="center", va="top", fontsize=8)
            )
        self._artists = added
        for artist in added:
            ax.draw_artist(artist)
        frame = np.asarray(self.canvas.buffer_rgba())[..., :3]
        return np.ascontiguousarray(frame, dtype=np.uint8).copy()

    def close(self) -> None:
        self.figure.clear()


class HumanViewer:
    """A pyplot window showing frames (``render_mode="human"``). Without a display
    (a non-interactive backend such as Agg) it draws nothing and stays silent."""

    def __init__(self, fps: float = 4.0) -> None:
        import matplotlib.pyplot as plt

        self.plt = plt
        self.fps = fps
        self.figure = None
        self.image = None

    def show(self, frame: np.ndarray) -> None:
        plt = self.plt
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if self.figure is None or not plt.fignum_exists(self.figure.number):
                self.figure = plt.figure("atc-nf-env", figsize=(frame.shape[1] / 100, frame.shape[0] / 100))
                ax = self.figure.add_axes((0, 0, 1, 1))
                ax.axis("off")
                self.image = ax.imshow(frame)
            else:
                self.image.set_data(frame)
            self.figure.canvas.draw_idle()
            plt.pause(1.0 / self.fps)

    def close(self) -> None:
        if self.figure is not None:
            self.plt.close(self.figure)
            self.figure = None


# ------------------------------------------------------------------------ snapshots


def snapshot_of_simulation(
    sim: Any, *, extent: tuple[float, float, float, float] | None = None, title: str | None = None,
    show_wind: bool = True,
) -> Snapshot:
    """The current state of a ``Simulation`` as a snapshot; trails from its recording
    (``record_every > 0``), else only the start and the current position. A traffic
    stream's (``StreamSimulation``): the flights in their slots only (``stream_snapshot``)."""
    from atc_nf_env.streams import StreamSimulation

    if isinstance(sim, StreamSimulation):
        return stream_snapshot(sim, extent=extent, title=title, show_wind=show_wind)
    state = sim.state[0]
    n = sim.n_aircraft
    positions = state[:n, S_X : S_Y + 1].copy()
    _, records = sim.recording()
    if len(records):
        trails = [records[:, i, R_X : R_Y + 1] for i in range(n)]
    else:
        trails = [np.stack([sim.scenario.start_xy[i], positions[i]]) for i in range(n)]
    if extent is None:
        extent = view_extent(np.concatenate([sim.scenario.start_xy, sim.scenario.dest_xy]))
    return Snapshot(
        positions=positions,
        headings=state[:n, S_HEADING].copy(),
        flying=state[:n, S_STATUS] == FLYING,
        waypoints=state[:n, S_WP_X : S_WP_Y + 1].copy(),
        destinations=state[:n, S_DEST_X : S_DEST_Y + 1].copy(),
        trails=trails,
        wind_kt=np.asarray(sim.wind_kt) if show_wind else None,
        time_s=float(sim.time_s),
        extent=extent,
        title=title if title is not None else sim.scenario.name,
        separation_nm=sim.config.separation_min_nm,
    )


def stream_extent(sector_radius_nm: float, margin_nm: float = 40.0) -> tuple[float, float, float, float]:
    """The view of a traffic stream: its sector (centred on the origin) with a margin, nm."""
    corner = np.array([[-sector_radius_nm, -sector_radius_nm], [sector_radius_nm, sector_radius_nm]])
    return view_extent(corner, margin_nm)


def stream_snapshot(
    sim: Any, *, extent: tuple[float, float, float, float] | None = None, title: str | None = None,
    show_wind: bool = True,
) -> Snapshot:
    """A ``StreamSimulation``'s current state: the flights in their slots (empty slots
    left out), labelled and coloured by flight number, trails from the recording of each
    flight's time in its slot (``record_every > 0``), else from its entry point."""
    stream = sim.stream
    slots = np.flatnonzero(sim.slot_flight >= 0)
    flights = sim.slot_flight[slots]
    state = sim.state[0, slots]
    positions = state[:, S_X : S_Y + 1].copy()
    times, records = sim.recording()
    if len(records):
        history_times, history = sim.slot_history()
        occupant = occupants_of_records(times, history_times, history)
        start = occupancy_start_rows(occupant)[-1]
        # A flight that entered at this instant has no record yet (the last record is the
        # state before the entries).
        trails = [np.concatenate([stream.start_xy[f][None],
                                  records[start[s]:, s, R_X : R_Y + 1] if occupant[-1, s] == f else np.zeros((0, 2)),
                                  positions[k][None]])
                  for k, (s, f) in enumerate(zip(slots, flights))]
    else:
        trails = [np.stack([stream.start_xy[f], positions[k]]) for k, f in enumerate(flights)]
    return Snapshot(
        positions=positions,
        headings=state[:, S_HEADING].copy(),
        flying=state[:, S_STATUS] == FLYING,
        waypoints=state[:, S_WP_X : S_WP_Y + 1].copy(),
        destinations=state[:, S_DEST_X : S_DEST_Y + 1].copy(),
        trails=trails,
        wind_kt=np.asarray(sim.wind_kt) if show_wind else None,
        time_s=float(sim.time_s),
        extent=extent if extent is not None else stream_extent(stream.sector_radius_nm),
        title=title if title is not None else stream.name,
        separation_nm=sim.config.separation_min_nm,
        labels=[str(int(f)) for f in flights],
        color_ids=flights.copy(),
        sector_radius_nm=float(stream.sector_radius_nm),
        legend_aircraft=False,
    )


def occupants_of_records(times_s: np.ndarray, history_times_s: np.ndarray, history: np.ndarray) -> np.ndarray:
    """(R, N) the flight in each slot at each record (-1: empty), from a stream's
    ``slot_history``: a record at a decision instant is the state before its exits and
    entries, so it belongs to the slots of the decision before."""
    if len(history_times_s) == 0:
        raise ValueError("the stream's slot history is empty")
    # 1 µs below each record's time: its own decision instant counts as later.
    k = np.searchsorted(np.asarray(history_times_s), np.asarray(times_s) - 1e-6, side="left") - 1
    return np.asarray(history)[np.clip(k, 0, len(history_times_s) - 1)]


def occupancy_start_rows(occupant: np.ndarray) -> np.ndarray:
    """(R, N) for each record and slot, the first record of the slot's current occupant."""
    rows = np.arange(occupant.shape[0])[:, None]
    changed = np.vstack([np.ones((1, occupant.shape[1]), dtype=bool), occupant[1:] != occupant[:-1]])
    return np.maximum.accumulate(np.where(changed, rows, 0), axis=0)


def render_simulation(sim: Any, size_px: int = 512, renderer: FrameRenderer | None = None, **kwargs: Any) -> np.ndarray:
    """One frame (size_px, size_px, 3) uint8 of a ``Simulation``'s current state."""
    renderer = renderer or FrameRenderer(size_px)
    return renderer.draw(snapshot_of_simulation(sim, **kwargs))


def snapshots_of_recording(
    times_s: np.ndarray,
    records: np.ndarray,
    destinations: np.ndarray,
    *,
    decision_times_s: np.ndarray | None = None,
    waypoints: np.ndarray | None = None,
    wind_kt: np.ndarray | None = None,
    frame_every_s: float = 60.0,
    title: str = "",
    separation_nm: float = SEPARATION_MIN_NM,
) -> list[Snapshot]:
    """Snapshots every ``frame_every_s`` of simulated time from a recording.

    Args:
        times_s: (R,) times of the records, s.
        records: (R, N, N_RECORD) recorded states (``atc_nf_env.kernel.R_*``).
        destinations: (N, 2), nm.
        decision_times_s, waypoints: (D,) and (D, N, 2): the waypoint in force at time
            t is the last one decided at or before t (none drawn if omitted).
        wind_kt: (2,) wind, kt.
        frame_every_s: simulated seconds between frames.
    """
    times_s = np.asarray(times_s, dtype=np.float64)
    rows = _frame_rows(times_s, records, frame_every_s)
    n = records.shape[1]
    extent = view_extent(np.concatenate([records[0, :, R_X : R_Y + 1], destinations]))
    snaps = []
    for r in rows:
        flying = records[r, :, R_FLEW] > 0
        wp = _waypoints_at(decision_times_s, waypoints, times_s[r], destinations)
        snaps.append(
            Snapshot(
                positions=records[r, :, R_X : R_Y + 1].copy(),
                headings=records[r, :, R_HEADING].copy(),
                flying=flying,
                waypoints=wp,
                destinations=np.asarray(destinations, dtype=np.float64),
                trails=[records[: r + 1, i, R_X : R_Y + 1] for i in range(n)],
                wind_kt=None if wind_kt is None else np.asarray(wind_kt, dtype=np.float64),
                time_s=float(times_s[r]),
                extent=extent,
                title=title,
                separation_nm=separation_nm,
            )
        )
    return snaps


def _frame_rows(times_s: np.ndarray, records: np.ndarray, frame_every_s: float) -> np.ndarray:
    """The records drawn: the first at or after every ``frame_every_s``, and the last."""
    if records.shape[0] == 0:
        raise ValueError("the recording is empty: run the episode with record_every > 0")
    targets = np.arange(0.0, times_s[-1] + 1e-9, max(frame_every_s, 1e-9))
    return np.unique(np.append(np.searchsorted(times_s, targets - 1e-9).clip(0, len(times_s) - 1), len(times_s) - 1))


def _waypoints_at(decision_times_s: np.ndarray | None, waypoints: np.ndarray | None, time_s: float,
                  default: np.ndarray) -> np.ndarray:
    """The waypoints in force at ``time_s``: the last decided at or before it (``default``
    without decisions)."""
    if waypoints is None or decision_times_s is None or not len(waypoints):
        return np.asarray(default, dtype=np.float64)
    k = max(0, int(np.searchsorted(decision_times_s, time_s, side="right")) - 1)
    return np.asarray(waypoints[k], dtype=np.float64)


def snapshots_of_stream_recording(
    times_s: np.ndarray,
    records: np.ndarray,
    stream: Any,
    slot_flight_times_s: np.ndarray,
    slot_flight: np.ndarray,
    *,
    decision_times_s: np.ndarray | None = None,
    waypoints: np.ndarray | None = None,
    wind_kt: np.ndarray | None = None,
    frame_every_s: float = 60.0,
    title: str = "",
    separation_nm: float = SEPARATION_MIN_NM,
) -> list[Snapshot]:
    """Snapshots every ``frame_every_s`` of a traffic stream's recording: in each, the
    flights then in their slots (``stream_snapshot``'s drawing), each trail from the
    flight's entry point.

    Args:
        times_s, records: (R,) s and (R, N, N_RECORD) over the N slots.
        stream: the ``StreamScenario`` flown (entry points and destinations per flight).
        slot_flight_times_s, slot_flight: (K,) s and (K, N), the slots' occupants
            (``EpisodeResult.slot_flight``, ``StreamSimulation.slot_history``).
        decision_times_s, waypoints, wind_kt, frame_every_s: as ``snapshots_of_recording``.
    """
    times_s = np.asarray(times_s, dtype=np.float64)
    rows = _frame_rows(times_s, records, frame_every_s)
    if slot_flight.shape[1:] != records.shape[1:2]:
        raise ValueError(f"slot_flight has shape {slot_flight.shape}; the records have {records.shape[1]} slots")
    occupant = occupants_of_records(times_s, slot_flight_times_s, slot_flight)
    if occupant.max(initial=-1) >= stream.n_flights:
        raise ValueError(f"the slots hold flight {int(occupant.max())}; the stream {stream.name!r} has "
                         f"{stream.n_flights} flights: give the StreamScenario that was flown")
    start = occupancy_start_rows(occupant)
    extent = stream_extent(stream.sector_radius_nm)
    snaps = []
    for r in rows:
        slots = np.flatnonzero(occupant[r] >= 0)
        flights = occupant[r, slots]
        destinations = np.zeros((records.shape[1], 2))
        destinations[slots] = stream.dest_xy[flights]
        wp = _waypoints_at(decision_times_s, waypoints, times_s[r], destinations)
        snaps.append(
            Snapshot(
                positions=records[r, slots, R_X : R_Y + 1].copy(),
                headings=records[r, slots, R_HEADING].copy(),
                flying=records[r, slots, R_FLEW] > 0,
                waypoints=wp[slots],
                destinations=destinations[slots],
                trails=[np.concatenate([stream.start_xy[f][None], records[start[r, s] : r + 1, s, R_X : R_Y + 1]])
                        for s, f in zip(slots, flights)],
                wind_kt=None if wind_kt is None else np.asarray(wind_kt, dtype=np.float64),
                time_s=float(times_s[r]),
                extent=extent,
                title=title,
                separation_nm=separation_nm,
                labels=[str(int(f)) for f in flights],
                color_ids=flights.copy(),
                sector_radius_nm=float(stream.sector_radius_nm),
                legend_aircraft=False,
            )
        )
    return snaps


# ------------------------------------------------------------------------ animation


def animation_formats() -> dict[str, str]:
    """The animation files ``save_animation`` can write here, by suffix: what Pillow
    writes as an animation (GIF, animated PNG, and WebP where Pillow has it). No video
    format: Pillow encodes none."""
    from PIL import features

    formats = {".gif": "GIF", ".png": "animated PNG"}
    if features.check("webp"):
        formats[".webp"] = "animated WebP"
    return formats


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 8.0, loop: int = 0) -> Path:
    """Write frames (H, W, 3) uint8 as an animation (Pillow): a GIF, or the format of
    ``path``'s suffix among ``animation_formats()``; returns the path."""
    from PIL import Image

    path = Path(path)
    formats = animation_formats()
    if path.suffix.lower() not in formats:
        allowed = ", ".join(f"{suffix} ({what})" for suffix, what in formats.items())
        raise ValueError(f"{path}: cannot write {path.suffix or 'a file without extension'}; supported: {allowed}")
    frames = list(frames)
    if not frames:
        raise ValueError("no frames to write: the animation needs at least one frame")
    for index, frame in enumerate(frames):
        array = np.asarray(frame)
        if array.ndim != 3 or array.shape[2] != 3 or array.dtype != np.uint8:
            raise ValueError(
                f"frame {index} has shape {array.shape} and dtype {array.dtype}; expected (H, W, 3) uint8"
            )
        if array.shape != np.asarray(frames[0]).shape:
            raise ValueError(f"frame {index} has shape {array.shape}; all frames must match frame 0's {frames[0].shape}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps = {fps!r}: must be a number > 0")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        images = [Image.fromarray(np.asarray(f)).convert("P", palette=Image.Palette.ADAPTIVE) for f in frames]
    else:  # full colour: APNG and WebP need no palette
        images = [Image.fromarray(np.asarray(f)) for f in frames]
    images[0].save(
        path, save_all=True, append_images=images[1:], duration=int(round(1000.0 / fps)), loop=loop, optimize=False
    )
    return path


def _frames_from_env(env: Any, policy: Callable[[Any], Any] | None, seed: int | None, max_steps: int) -> list[np.ndarray]:
    """Play one episode of an env (PettingZoo parallel or Gymnasium, render_mode
    "rgb_array") and collect a frame after the reset and after every step."""
    base = getattr(env, "unwrapped", env)
    if getattr(base, "render_mode", None) != "rgb_array":
        raise ValueError(
            f"save_animation needs an env made with render_mode='rgb_array' (this one has "
            f"{getattr(base, 'render_mode', None)!r})"
        )
    frames = []
    if hasattr(env, "possible_agents"):  # PettingZoo ParallelEnv
        obs, _ = env.reset(seed=seed)
        frames.append(env.render())
        for _ in range(max_steps):
            if not env.agents:
                break
            if policy is None:
                actions = {agent: np.zeros(2, dtype=np.float32) for agent in env.agents}
            else:
                actions = policy(obs)
            obs, *_ = env.step(actions)
            frames.append(env.render())
    else:  # Gymnasium Env
        obs, _ = env.reset(seed=seed)
        frames.append(env.render())
        for _ in range(max_steps):
            action = np.zeros(env.action_space.shape, dtype=np.float32) if policy is None else policy(obs)
            obs, _, terminated, truncated, _ = env.step(action)
            frames.append(env.render())
            if terminated or truncated:
                break
    return frames


def save_animation(
    source: Any,
    path: str | Path,
    *,
    fps: float = 8.0,
    scenario: Any = None,
    frame_every_s: float = 60.0,
    size_px: int = 512,
    policy: Callable[[Any], Any] | None = None,
    seed: int | None = None,
    max_steps: int = 1000,
    title: str | None = None,
) -> Path:
    """Write a GIF animation of a whole episode; returns the path written.

    ``source`` is one of:

    - a sequence of frames (H, W, 3) uint8 (e.g. collected from ``env.render()``);
    - an ``atc_nf_env.episode.EpisodeResult`` from ``run_episode(..., record_every=k)``
      with k > 0 (``scenario`` required: the Scenario that was flown, for the
      destinations); a frame every ``frame_every_s`` of simulated time, the waypoints
      in force and the wind from the result (a traffic stream's: its StreamScenario, the
      flights in their slots as ``EpisodeResult.slot_flight`` says);
    - an environment made with ``render_mode="rgb_array"`` (``atc_nf_env.parallel_env``
      or ``gym.make("atc_nf_env/Encounter-v1")``): one episode is played from
      ``reset(seed=seed)`` with ``policy`` (obs -> actions, as the env takes them;
      default: every action (0, 0), a waypoint 100 nm ahead on the line to the
      destination) and a frame is taken after the reset and after every step.

    Args:
        source: frames, an EpisodeResult or an env (see above).
        path: the file to write, .gif or another of ``animation_formats()`` (folders are
            created).
        fps: frames per second of the GIF.
        scenario: the Scenario (or its name) flown, for an EpisodeResult.
        frame_every_s: simulated seconds between frames, for an EpisodeResult.
        size_px: frame side, pixels, for an EpisodeResult.
        policy, seed, max_steps: for an env.
        title: title of the frames drawn from an EpisodeResult (default: scenario name).

    Raises:
        ValueError: on a source of another kind, empty frames, an EpisodeResult
            without recording or without ``scenario``, or a suffix the writer does not
            know (checked before any frame is drawn).
    """
    from atc_nf_env.episode import EpisodeResult

    formats = animation_formats()
    if Path(path).suffix.lower() not in formats:
        allowed = ", ".join(f"{suffix} ({what})" for suffix, what in formats.items())
        raise ValueError(f"{path}: cannot write {Path(path).suffix or 'a file without extension'}; supported: {allowed}")
    if isinstance(source, EpisodeResult):
        if scenario is None:
            raise ValueError("save_animation(EpisodeResult, ...) needs scenario= (the Scenario that was flown)")
        if isinstance(scenario, str):
            from atc_nf_env.scenarios import make_scenario

            scenario = make_scenario(scenario, seed=source.metrics.seed)
        if source.records.shape[0] == 0:
            raise ValueError("the EpisodeResult has no recording: run run_episode(..., record_every=1) (or > 0)")
        from atc_nf_env.scenarios import StreamScenario

        common = {
            "decision_times_s": source.decision_times_s,
            "waypoints": source.waypoints,
            "wind_kt": np.asarray(source.metrics.wind_kt),
            "frame_every_s": frame_every_s,
            "title": title if title is not None else f"{scenario.name}  seed {source.metrics.seed}",
        }
        is_stream = source.slot_flight is not None
        if is_stream != isinstance(scenario, StreamScenario):
            flown = "a traffic stream" if is_stream else "an encounter"
            raise ValueError(f"save_animation: the EpisodeResult is of {flown}, scenario {scenario.name!r} is not: "
                             "give the scenario that was flown")
        if is_stream:
            snaps = snapshots_of_stream_recording(
                source.times_s, source.records, scenario, source.slot_flight_times_s, source.slot_flight, **common
            )
        else:
            if scenario.n_aircraft != source.records.shape[1]:
                raise ValueError(f"save_animation: scenario {scenario.name!r} has {scenario.n_aircraft} aircraft, "
                                 f"the EpisodeResult {source.records.shape[1]}: give the scenario that was flown")
            snaps = snapshots_of_recording(source.times_s, source.records, scenario.dest_xy, **common)
        renderer = FrameRenderer(size_px)
        frames = [renderer.draw(s) for s in snaps]
        renderer.close()
    elif hasattr(source, "reset") and hasattr(source, "step"):
        frames = _frames_from_env(source, policy, seed, max_steps)
    elif isinstance(source, (list, tuple)) or (isinstance(source, np.ndarray) and source.ndim == 4):
        frames = list(source)
    else:
        raise ValueError(
            f"save_animation: source of type {type(source).__name__} not understood; give a list of "
            "(H, W, 3) uint8 frames, an EpisodeResult (run_episode(..., record_every>0)) or an env "
            "made with render_mode='rgb_array'"
        )
    return write_gif(frames, path, fps=fps)


__all__ = [
    "FrameRenderer",
    "animation_formats",
    "HumanViewer",
    "Snapshot",
    "conflicts",
    "render_simulation",
    "save_animation",
    "snapshot_of_simulation",
    "snapshots_of_recording",
    "snapshots_of_stream_recording",
    "stream_extent",
    "stream_snapshot",
    "view_extent",
    "write_gif",
]
