"""Encounter scenarios: the paper's converging encounters, seeded random ones, and
user-defined ones from a dict or a JSON file.

Coordinates are nm in a frame centred on the workspace, x east and y north; headings
are radians counter-clockwise from east (the x axis). In dicts and JSON files
headings are given in degrees, with the same convention.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import stat
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from atc_nf_env.units import AIRCRAFT_RADIUS_NM, AIRSPEED_NOMINAL_KT, SEPARATION_MIN_NM

#: Largest heading accepted, in degrees (dicts and JSON files) and radians (``Scenario``):
#: one turn either way. Any direction is within it; a larger value is a mistake (1e308
#: degrees once flew a 500-nm trip as 1,063 nm).
MAX_HEADING_DEG: float = 360.0
MAX_HEADING_RAD: float = math.radians(MAX_HEADING_DEG)

#: Radius of the paper's converging encounters, nm.
ENCOUNTER_RADIUS_NM: float = 250.0

#: Default radius of the workspace (the NF's boundary obstacle β0), nm. Much larger than
#: the encounters: the unobstructed NF airspeed scales with 1/β0, and a workspace six
#: times the encounter radius keeps it within a few percent across the flight region
#: (see ``atc_nf_env.calibration``).
WORKSPACE_RADIUS_NM: float = 1500.0


@dataclass(frozen=True, eq=False)
class Scenario:
    """Initial conditions of an encounter.

    Attributes:
        name: a label.
        start_xy: (n, 2) initial positions, nm.
        start_heading: (n,) initial headings, rad.
        dest_xy: (n, 2) destinations, nm.
        dest_heading: (n,) desired arrival headings θ_d at the destinations, rad.
        start_airspeed_kt: airspeed at t = 0, kt.
        workspace_radius_nm: radius of the circular workspace, nm.
    """

    name: str
    start_xy: np.ndarray
    start_heading: np.ndarray
    dest_xy: np.ndarray
    dest_heading: np.ndarray
    start_airspeed_kt: float = AIRSPEED_NOMINAL_KT
    workspace_radius_nm: float = WORKSPACE_RADIUS_NM
    metadata: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for name in ("start_xy", "start_heading", "dest_xy", "dest_heading"):
            object.__setattr__(self, name, np.array(getattr(self, name), dtype=np.float64))
        validate_scenario(self)

    @property
    def n_aircraft(self) -> int:
        return int(self.start_xy.shape[0])

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Scenario":
        """The reader of ``to_dict``'s dict (see ``scenario_from_dict`` for its keys)."""
        return scenario_from_dict(data)

    @classmethod
    def from_json(cls, path: str | Path) -> "Scenario":
        """A scenario from a JSON file holding ``to_dict``'s dict."""
        return scenario_from_json(path)

    def canonical_json(self) -> str:
        """What this scenario flies, as a canonical JSON text: the initial conditions at full
        precision (positions nm, headings rad, airspeed kt, workspace radius nm), without the
        ``name`` and ``metadata`` labels, which change nothing that flies. Equal texts fly
        the same encounter."""
        flown = {
            "start_xy": self.start_xy.tolist(),
            "start_heading": self.start_heading.tolist(),
            "dest_xy": self.dest_xy.tolist(),
            "dest_heading": self.dest_heading.tolist(),
            "start_airspeed_kt": float(self.start_airspeed_kt),
            "workspace_radius_nm": float(self.workspace_radius_nm),
        }
        # json writes each float as its shortest round-trip repr: equal texts, equal bits.
        return json.dumps(flown, sort_keys=True, separators=(",", ":"), allow_nan=False)

    def content_sha256(self) -> str:
        """SHA-256 (hex) of ``canonical_json``: identifies the encounter by what it flies, not
        by where it was read from."""
        return hashlib.sha256(self.canonical_json().encode()).hexdigest()

    def to_dict(self) -> dict[str, Any]:
        """The scenario as a JSON-ready dict (headings in degrees), read back by ``Scenario.from_dict``."""
        return {
            "name": self.name,
            "workspace_radius_nm": self.workspace_radius_nm,
            "start_airspeed_kt": self.start_airspeed_kt,
            "aircraft": [
                {
                    "start": [float(x) for x in self.start_xy[i]],
                    "heading_deg": math.degrees(float(self.start_heading[i])),
                    "destination": [float(x) for x in self.dest_xy[i]],
                    "arrival_heading_deg": math.degrees(float(self.dest_heading[i])),
                }
                for i in range(self.n_aircraft)
            ],
        }


def validate_scenario(scenario: Scenario, check_start_separation: bool = True, allow_empty: bool = False) -> None:
    """Raise ValueError, naming the field, the value and what is allowed, if the scenario is impossible.

    ``check_start_separation``: whether the starts must be 5 nm apart; ``allow_empty``:
    whether no aircraft at all is allowed (both for a stream, whose flights start at
    different times and may be none)."""
    n = scenario.start_xy.shape[0] if scenario.start_xy.ndim == 2 else -1
    if scenario.start_xy.ndim != 2 or scenario.start_xy.shape[1:] != (2,):
        raise ValueError(f"start_xy has shape {scenario.start_xy.shape}; expected (n, 2)")
    if n < (0 if allow_empty else 1):
        raise ValueError(f"number of aircraft n = {n}: must be >= 1")
    if not isinstance(scenario, StreamScenario):  # a stream's world holds max_airborne slots, checked there
        _check_aircraft_count(n)
    expected = {"start_heading": (n,), "dest_xy": (n, 2), "dest_heading": (n,)}
    for name, shape in expected.items():
        if getattr(scenario, name).shape != shape:
            raise ValueError(f"{name} has shape {getattr(scenario, name).shape}; expected {shape}")
    for name in ("start_xy", "start_heading", "dest_xy", "dest_heading"):
        if not np.isfinite(getattr(scenario, name)).all():
            raise ValueError(f"{name} contains NaN or inf: {getattr(scenario, name).tolist()}")
    for name in ("start_heading", "dest_heading"):
        headings = getattr(scenario, name)
        beyond = np.flatnonzero(np.abs(headings) > MAX_HEADING_RAD)
        if beyond.size:
            i = int(beyond[0])
            raise ValueError(
                f"{name}[{i}] = {headings[i]!r} rad: must be in [-2*pi, 2*pi] (one turn either way; a heading "
                "beyond is the same direction written with whole turns added)"
            )
    radius = scenario.workspace_radius_nm
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"workspace_radius_nm = {radius!r}: must be a finite number > 0")
    if not (math.isfinite(scenario.start_airspeed_kt) and scenario.start_airspeed_kt >= 0):
        raise ValueError(
            f"start_airspeed_kt = {scenario.start_airspeed_kt!r}: must be a finite number >= 0"
        )
    inner = radius - AIRCRAFT_RADIUS_NM
    for name in ("start_xy", "dest_xy"):
        dist = np.hypot(*getattr(scenario, name).T)
        outside = np.flatnonzero(dist >= inner)
        if outside.size:
            i = int(outside[0])
            raise ValueError(
                f"{name}[{i}] = {getattr(scenario, name)[i].tolist()} lies {dist[i]:.1f} nm from the "
                f"centre: must be within workspace_radius_nm - aircraft radius = {inner:.1f} nm"
            )
    if n > 1 and check_start_separation:
        from atc_nf_env.config import SimConfig

        distance, i, j = closest_pair(scenario.start_xy)
        if distance < SEPARATION_MIN_NM:
            raise ValueError(
                f"start_xy: aircraft {i} and {j} start {distance:.2f} nm apart, in conflict; "
                f"initial separations must be >= {SEPARATION_MIN_NM} nm"
            )
        physics = SimConfig()
        if distance < physics.sensing_radius_nm:
            warnings.warn(
                f"start_xy: aircraft {i} and {j} start {distance:.2f} nm apart, inside the NF's sensing radius "
                f"({physics.sensing_radius_nm:g} nm): their proximity function acts from the first step, and below "
                f"its barrier distance ({physics.barrier_nm:g} nm) it commands up to the "
                f"{physics.airspeed_cap_kt:g}-kt cap within a period, before any policy can separate them; expect "
                f"airspeeds outside [{physics.airspeed_min_kt:g}, {physics.airspeed_max_kt:g}] kt (starts at least "
                f"{physics.sensing_radius_nm:g} nm apart begin beyond its reach)",
                CloseStartWarning,
                stacklevel=2,
            )


class CloseStartWarning(UserWarning):
    """Two aircraft of a scenario start closer than the NF's sensing radius (default physics):
    legal (the separation minimum is 5 nm), but the proximity function acts from the first
    step and, closer than its barrier distance, commands airspeeds far outside the envelope
    before any policy can act (docs/environments.md)."""


#: Distance matrices of ``closest_pair`` are built this many elements at a time (8 MB of float64).
_PAIR_BLOCK_ELEMENTS: int = 2**20


def closest_pair(points: np.ndarray) -> tuple[float, int, int]:
    """(distance nm, i, j) of the closest two of ``points`` (n, 2) nm, n >= 2, i < j: the
    first in row-major order of the full ``np.hypot`` distance matrix, as ``np.argmin``
    would give it, computed a block of rows at a time against the columns after each row,
    so that memory stays O(n) (60 000 aircraft: 8-MB blocks, not a 54-GiB matrix)."""
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    rows = max(1, _PAIR_BLOCK_ELEMENTS // n)
    best, best_i, best_j = math.inf, 0, 1
    for first in range(0, n - 1, rows):
        block = points[first : first + rows]
        diff = block[:, None, :] - points[None, first:, :]
        squared = diff[..., 0] ** 2 + diff[..., 1] ** 2
        squared[np.tril_indices(block.shape[0], 0, squared.shape[1])] = np.inf  # j <= i
        least = squared.min()
        if not least <= best * best * (1.0 + 1e-9):
            continue
        # The exact distances (hypot, as the full matrix) of the entries that may be the least.
        near = np.flatnonzero(squared.ravel() <= least * (1.0 + 1e-9))
        i, j = np.divmod(near, squared.shape[1])
        exact = np.hypot(diff[i, j, 0], diff[i, j, 1])
        k = int(np.argmin(exact))  # the first of the least, in row-major order
        if exact[k] < best:
            best, best_i, best_j = float(exact[k]), first + int(i[k]), first + int(j[k])
    return best, best_i, best_j


def _check_aircraft_count(n: int, name: str = "number of aircraft n") -> int:
    """``atc_nf_env.config.check_aircraft_count``: at most ``MAX_AIRCRAFT`` in one world,
    refused before anything of that size is allocated."""
    from atc_nf_env.config import check_aircraft_count

    return check_aircraft_count(n, name)


def converging(n: int, radius_nm: float = ENCOUNTER_RADIUS_NM, **kwargs: Any) -> Scenario:
    """The paper's encounter: n aircraft evenly spaced on a circle, all heading for the
    centre, each bound for the diametrically opposite point (section IV-A)."""
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"number of aircraft n = {n!r}: must be an integer >= 1")
    _check_aircraft_count(int(n))
    if not (math.isfinite(radius_nm) and radius_nm > 0):
        raise ValueError(f"radius_nm = {radius_nm!r}: must be a finite number > 0")
    angles = 2.0 * np.pi * np.arange(n) / n
    start = radius_nm * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    heading = np.mod(angles + np.pi + np.pi, 2 * np.pi) - np.pi
    return Scenario(
        name=f"converging-{n}",
        start_xy=start,
        start_heading=heading,
        dest_xy=-start,
        dest_heading=heading,
        **kwargs,
    )


#: Layouts ``random_encounter`` draws independently before it builds one spaced (below).
RANDOM_DRAWS: int = 10_000


def _gap_angle(radius_nm: float, separation_nm: float) -> float:
    """Angle (rad) between two points of a circle of ``radius_nm`` whose chord is
    ``separation_nm``, plus a margin of rounding."""
    return 2.0 * math.asin(min(1.0, separation_nm / (2.0 * radius_nm))) * (1.0 + 1e-9)


def max_random_aircraft(radius_nm: float = ENCOUNTER_RADIUS_NM, min_separation_nm: float = 20.0) -> int:
    """The most aircraft that ``random_encounter`` can place on a circle of ``radius_nm``
    with starts (and destinations) ``min_separation_nm`` apart: whole gaps of the chord's
    angle in one turn."""
    return max(1, int(2.0 * math.pi / _gap_angle(radius_nm, min_separation_nm)))


def _spaced_angles(rng: np.random.Generator, n: int, gap: float, deviation: float) -> tuple[np.ndarray, np.ndarray]:
    """(start, destination) angles (rad) of ``n`` aircraft, starts at least ``gap + 2 e``
    apart, each destination opposite its start turned by a common δ0 in ±(deviation − e)
    plus its own u in ±e: destinations are then at least ``gap`` apart too (moving each point
    by at most e changes a circular distance by at most 2 e) and every δ0 + u is within
    ±deviation. The starts are uniform among those so spaced (uniform spare arc split by a
    Dirichlet draw, a uniform rotation, aircraft in random order)."""
    spare = 2.0 * math.pi - n * gap
    e = min(deviation, spare / (2.0 * n)) / 2.0
    gaps = gap + 2.0 * e + rng.dirichlet(np.ones(n)) * (spare - 2.0 * n * e)
    angles = rng.uniform(-np.pi, np.pi) + np.concatenate(([0.0], np.cumsum(gaps)[:-1]))
    start_angles = rng.permutation(np.mod(angles + np.pi, 2.0 * np.pi) - np.pi)
    turn = rng.uniform(-(deviation - e), deviation - e) + rng.uniform(-e, e, n)
    return start_angles, start_angles + np.pi + turn


def random_encounter(
    n: int,
    seed: int,
    radius_nm: float = ENCOUNTER_RADIUS_NM,
    min_separation_nm: float = 20.0,
    max_deviation_deg: float = 45.0,
    **kwargs: Any,
) -> Scenario:
    """A seeded random crossing encounter.

    Each aircraft starts on the circle of ``radius_nm`` at a uniformly random angle a,
    heading for its destination on the same circle at angle a + π + δ, with δ uniform in
    ± ``max_deviation_deg``; starts and destinations are at least ``min_separation_nm``
    apart. Every seed gives a layout: layouts are drawn independently until one is so
    spread, and when ``RANDOM_DRAWS`` draws give none (crowded circles: random-18 needs
    more for a few seeds in ten) one is built spaced from the same seeded stream
    (``_spaced_angles``: its starts are uniform among spaced ones, its turns share a common
    part). Raises ValueError, naming n and the limit, when n aircraft cannot be that far
    apart on the circle (``max_random_aircraft``: 78 at the defaults).
    """
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"number of aircraft n = {n!r}: must be an integer >= 1")
    if not (math.isfinite(radius_nm) and radius_nm > 0):
        raise ValueError(f"radius_nm = {radius_nm!r}: must be a finite number > 0")
    if not (math.isfinite(min_separation_nm) and min_separation_nm >= SEPARATION_MIN_NM):
        raise ValueError(
            f"min_separation_nm = {min_separation_nm!r}: must be >= {SEPARATION_MIN_NM} nm"
        )
    rng = np.random.default_rng(_check_seed(seed))
    max_n = max_random_aircraft(radius_nm, min_separation_nm)
    if n > max_n:
        raise ValueError(
            f"n = {n} aircraft cannot start {min_separation_nm} nm apart on a circle of "
            f"{radius_nm} nm; at most {max_n}"
        )

    def spread(angles: np.ndarray) -> bool:
        pts = radius_nm * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        diff = pts[:, None] - pts[None]
        sep = np.hypot(diff[..., 0], diff[..., 1]) + np.diag(np.full(n, np.inf))
        return bool(sep.min() >= min_separation_nm) if n > 1 else True

    if not (math.isfinite(max_deviation_deg) and 0 <= max_deviation_deg <= 90):
        raise ValueError(f"max_deviation_deg = {max_deviation_deg!r}: must be a number of degrees in [0, 90]")
    deviation = math.radians(max_deviation_deg)
    for _ in range(RANDOM_DRAWS):
        start_angles = rng.uniform(-np.pi, np.pi, n)
        dest_angles = start_angles + np.pi + rng.uniform(-deviation, deviation, n)
        if spread(start_angles) and spread(dest_angles):
            break
    else:
        # Crowded circles: a layout built spaced, from the same stream of this seed.
        start_angles, dest_angles = _spaced_angles(rng, n, _gap_angle(radius_nm, min_separation_nm), deviation)
        if not (spread(start_angles) and spread(dest_angles)):  # pragma: no cover - the construction guarantees it
            raise RuntimeError(f"random_encounter({n}, seed={seed}): the spaced layout is not spread")
    start = radius_nm * np.stack([np.cos(start_angles), np.sin(start_angles)], axis=1)
    dest = radius_nm * np.stack([np.cos(dest_angles), np.sin(dest_angles)], axis=1)
    heading = np.arctan2(dest[:, 1] - start[:, 1], dest[:, 0] - start[:, 0])
    return Scenario(
        name=f"random-{n}",
        start_xy=start,
        start_heading=heading,
        dest_xy=dest,
        dest_heading=heading,
        metadata={"seed": seed},
        **kwargs,
    )


#: Default length of a stream episode, min.
STREAM_DURATION_MIN: float = 120.0
#: Largest arrival rate of a stream, aircraft per hour (one every 6 s).
MAX_STREAM_RATE_PER_H: float = 600.0
#: Longest stream, min (a day, as any episode's time limit).
MAX_STREAM_DURATION_MIN: float = 24 * 60.0
#: Default clearance an entering aircraft needs from every aircraft already in, nm: it
#: enters only where nothing flies within this distance, and waits otherwise. Four
#: separation minima: an aircraft closer than that is a conflict within two minutes.
STREAM_ENTRY_CLEARANCE_NM: float = 20.0


@dataclass(frozen=True, eq=False)
class StreamScenario(Scenario):
    """Traffic entering a circular sector over time: the flights of one episode.

    ``start_xy``, ``start_heading``, ``dest_xy`` and ``dest_heading`` hold every flight of
    the episode (entry point on the sector's edge, destination across it), in the order
    they are due; ``entry_time_s`` (s) says when each is due. A flight enters at the first
    decision instant at or after its time at which a slot is free and no aircraft flies
    within ``entry_clearance_nm`` of its entry point (``atc_nf_env.streams``).

    The world holds ``max_airborne`` aircraft slots (the kernel state's fixed size): an
    aircraft that has not entered, or has arrived, leaves its slot empty (ABSENT) and out
    of every interaction. ``n_aircraft`` is that slot count; ``n_flights`` the flights.
    Its attributes beyond ``Scenario``'s are these.

    Attributes:
        entry_time_s: (M,) times the flights are due, s, non-decreasing, in [0, duration_s).
        duration_s: length of the episode, s.
        max_airborne: aircraft slots, >= 1.
        rate_per_hour: the mean arrival rate the schedule was drawn with, aircraft/h.
        sector_radius_nm: radius of the sector the flights cross, nm.
        entry_clearance_nm: clearance an entering aircraft needs, nm.
    """

    entry_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    duration_s: float = STREAM_DURATION_MIN * 60.0
    max_airborne: int = 1
    rate_per_hour: float = 0.0
    sector_radius_nm: float = ENCOUNTER_RADIUS_NM
    entry_clearance_nm: float = STREAM_ENTRY_CLEARANCE_NM

    def __post_init__(self) -> None:
        for name in ("start_xy", "start_heading", "dest_xy", "dest_heading", "entry_time_s"):
            object.__setattr__(self, name, np.array(getattr(self, name), dtype=np.float64))
        validate_scenario(self, check_start_separation=False, allow_empty=True)
        times = self.entry_time_s
        if times.shape != (self.n_flights,):
            raise ValueError(f"entry_time_s has shape {times.shape}; expected ({self.n_flights},)")
        duration = self.duration_s
        if not (math.isfinite(duration) and 0 < duration <= MAX_STREAM_DURATION_MIN * 60.0):
            raise ValueError(
                f"duration_s = {duration!r}: must be a number of seconds in (0, {MAX_STREAM_DURATION_MIN * 60:g}]"
            )
        if not (np.isfinite(times).all() and (times >= 0).all() and (times < duration).all()):
            raise ValueError(f"entry_time_s must be finite and in [0, duration_s = {duration:g}) s")
        if (np.diff(times) < 0).any():
            raise ValueError("entry_time_s must be non-decreasing (flights in the order they are due)")
        if isinstance(self.max_airborne, bool) or not isinstance(self.max_airborne, (int, np.integer)) \
                or self.max_airborne < 1:
            raise ValueError(f"max_airborne = {self.max_airborne!r}: must be an integer >= 1")
        _check_aircraft_count(int(self.max_airborne), "max_airborne")
        if not (math.isfinite(self.entry_clearance_nm) and self.entry_clearance_nm >= SEPARATION_MIN_NM):
            raise ValueError(
                f"entry_clearance_nm = {self.entry_clearance_nm!r}: must be a number of nm >= {SEPARATION_MIN_NM}"
            )

    @property
    def n_aircraft(self) -> int:
        """Aircraft slots of the world (``max_airborne``): the kernel state's size."""
        return int(self.max_airborne)

    @property
    def n_flights(self) -> int:
        """Flights of the episode (airborne or not)."""
        return int(self.start_xy.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """Not for a stream: the dict format holds an encounter (all aircraft at t = 0).
        A stream is named by ``stream-R`` and a seed, or built with ``stream_scenario``."""
        raise ValueError(
            f"{self.name!r} is a traffic stream: the scenario dict holds encounters only; name the stream "
            "('stream-R' with a seed) or build it with atc_nf_env.scenarios.stream_scenario"
        )

    def canonical_json(self) -> str:
        """``Scenario.canonical_json`` plus the schedule, the length and the slots."""
        flown = json.loads(super().canonical_json())
        flown.update(
            entry_time_s=self.entry_time_s.tolist(),
            duration_s=float(self.duration_s),
            max_airborne=int(self.max_airborne),
            entry_clearance_nm=float(self.entry_clearance_nm),
        )
        return json.dumps(flown, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _check_stream_numbers(rate_per_hour: Any, duration_min: Any) -> tuple[float, float]:
    """The rate (aircraft/h) and length (min) as floats, or a ValueError naming the allowed range."""
    if not _is_number(rate_per_hour) or not (
        math.isfinite(float(rate_per_hour)) and 0 < float(rate_per_hour) <= MAX_STREAM_RATE_PER_H
    ):
        raise ValueError(
            f"rate_per_hour = {_shown(rate_per_hour)}: must be a number of aircraft per hour in "
            f"(0, {MAX_STREAM_RATE_PER_H:g}]"
        )
    if not _is_number(duration_min) or not (
        math.isfinite(float(duration_min)) and 0 < float(duration_min) <= MAX_STREAM_DURATION_MIN
    ):
        raise ValueError(
            f"duration_min = {_shown(duration_min)}: must be a number of minutes in (0, {MAX_STREAM_DURATION_MIN:g}]"
        )
    return float(rate_per_hour), float(duration_min)


def default_max_airborne(rate_per_hour: float, sector_radius_nm: float = ENCOUNTER_RADIUS_NM) -> int:
    """Slots of a stream: the mean number airborne in steady state (rate × the time to
    cross the sector's diameter at the nominal airspeed) plus four standard deviations of
    a Poisson count and four, so that a full sector makes an entry wait only rarely."""
    airborne = rate_per_hour * 2.0 * sector_radius_nm / AIRSPEED_NOMINAL_KT
    return int(math.ceil(airborne + 4.0 * math.sqrt(airborne) + 4.0))


def max_stream_flights(rate_per_hour: float, duration_min: float) -> int:
    """The most flights a stream schedules: the Poisson mean over the episode plus six
    standard deviations and six (a bound the count passes with probability < 1e-9; a
    schedule that would pass it is cut there, and says so in its metadata)."""
    mean = rate_per_hour * duration_min / 60.0
    return int(math.ceil(mean + 6.0 * math.sqrt(mean) + 6.0))


def stream_scenario(
    rate_per_hour: float,
    seed: int,
    duration_min: float = STREAM_DURATION_MIN,
    *,
    sector_radius_nm: float = ENCOUNTER_RADIUS_NM,
    max_deviation_deg: float = 45.0,
    max_airborne: int | None = None,
    entry_clearance_nm: float = STREAM_ENTRY_CLEARANCE_NM,
    **kwargs: Any,
) -> StreamScenario:
    """A seeded traffic stream: Poisson arrivals at ``rate_per_hour`` over ``duration_min``.

    Each flight enters at a uniformly random point of the sector's edge (a circle of
    ``sector_radius_nm`` around the workspace centre) and is bound for the point across
    it, turned by δ uniform in ± ``max_deviation_deg`` (as ``random_encounter``), heading
    along the line between them. Its due time is the previous one's plus an exponential
    gap of mean 1/rate. ``max_airborne`` (default ``default_max_airborne``) bounds the
    aircraft airborne at once; at most ``max_stream_flights`` flights are scheduled.

    Raises ValueError, naming the allowed range, on a rate outside (0, 600] aircraft/h, a
    length outside (0, 1440] min, or a bad seed, radius, deviation or slot count.
    """
    rate, duration = _check_stream_numbers(rate_per_hour, duration_min)
    seed = _check_seed(seed)
    if not (math.isfinite(sector_radius_nm) and 0 < sector_radius_nm):
        raise ValueError(f"sector_radius_nm = {sector_radius_nm!r}: must be a finite number of nm > 0")
    if not (math.isfinite(max_deviation_deg) and 0 <= max_deviation_deg <= 90):
        raise ValueError(f"max_deviation_deg = {max_deviation_deg!r}: must be a number of degrees in [0, 90]")
    slots = default_max_airborne(rate, sector_radius_nm) if max_airborne is None else max_airborne
    rng = np.random.default_rng([seed, 0x5354524D])  # a stream of its own, apart from the wind's
    bound = max_stream_flights(rate, duration)
    gaps = rng.exponential(3600.0 / rate, size=bound + 1)
    due = np.cumsum(gaps)
    count = int(np.searchsorted(due, duration * 60.0, side="left"))
    cut = count > bound
    count = min(count, bound)
    times = due[:count]
    angles = rng.uniform(-np.pi, np.pi, size=bound)[:count]
    turns = rng.uniform(-1.0, 1.0, size=bound)[:count] * math.radians(max_deviation_deg)
    start = sector_radius_nm * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    dest_angles = angles + np.pi + turns
    dest = sector_radius_nm * np.stack([np.cos(dest_angles), np.sin(dest_angles)], axis=1)
    heading = np.arctan2(dest[:, 1] - start[:, 1], dest[:, 0] - start[:, 0])
    name = f"stream-{rate:g}" if duration == STREAM_DURATION_MIN else f"stream-{rate:g}-{duration:g}min"
    return StreamScenario(
        name=name,
        start_xy=start,
        start_heading=heading,
        dest_xy=dest,
        dest_heading=heading,
        entry_time_s=times,
        duration_s=duration * 60.0,
        max_airborne=slots,
        rate_per_hour=rate,
        sector_radius_nm=sector_radius_nm,
        entry_clearance_nm=entry_clearance_nm,
        metadata={"seed": seed, "schedule_cut": cut},
        **kwargs,
    )


def _is_number(value: Any) -> bool:
    """A real number: Python's or numpy's (np.float32, np.int64 …), never a bool."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


#: Largest seed anywhere in the project: episode seeds are kept as int64 (env infos).
MAX_SEED: int = 2**63 - 1


def check_seed(seed: Any, name: str = "seed") -> int:
    """The one seed rule of the project (scenarios, episodes, every environment, the
    evaluator): an integer (Python or numpy, not a bool) in [0, 2**63 - 1], as
    Gymnasium's ``np_random`` asks for a non-negative integer. Returns it as an int;
    raises ValueError naming ``name`` otherwise."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise ValueError(f"{name} = {seed!r}: must be an integer in [0, 2**63 - 1] (or None where allowed)")
    return int(seed)


_check_seed = check_seed


def _shown(value: Any, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters: an error message quotes what it refuses,
    not a megabyte of it."""
    try:
        text = repr(value)
    except RecursionError:
        text = f"a {type(value).__name__} nested too deeply to show"
    except ValueError:  # an int too long to print (Python limits int-to-str conversions)
        text = f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _as_float(value: Any, where: str, allowed: str) -> float:
    """``value`` (a number) as a float, or ValueError naming ``where`` when it has no float
    (an integer beyond 1.8e308)."""
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{where} = {_shown(value)}: too large for a float; must be {allowed}") from None


_ALLOWED_KEYS = {"name", "aircraft", "workspace_radius_nm", "start_airspeed_kt"}
_ALLOWED_AIRCRAFT_KEYS = {"start", "destination", "heading_deg", "arrival_heading_deg"}


def scenario_from_dict(data: Mapping[str, Any]) -> Scenario:
    """A scenario from a dict such as ``Scenario.to_dict()`` writes.

    Keys: ``aircraft`` (a list of {"start": [x, y], "destination": [x, y], optional
    "heading_deg", optional "arrival_heading_deg"}; headings default to the bearing
    from start to destination), optional ``name``, ``workspace_radius_nm``,
    ``start_airspeed_kt``.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"a scenario must be a dict, got {type(data).__name__}")
    unknown = set(data) - _ALLOWED_KEYS
    if unknown:
        raise ValueError(f"unknown scenario keys {sorted(unknown)}; allowed: {sorted(_ALLOWED_KEYS)}")
    aircraft = data.get("aircraft")
    if not isinstance(aircraft, list) or len(aircraft) < 1:
        raise ValueError(
            f"aircraft = {aircraft!r}: must be a non-empty list of "
            '{"start": [x, y], "destination": [x, y]} (n >= 1)'
        )
    _check_aircraft_count(len(aircraft), "len(aircraft)")
    starts, dests, headings, arrivals = [], [], [], []
    for index, entry in enumerate(aircraft):
        if not isinstance(entry, Mapping):
            raise ValueError(f"aircraft[{index}] = {entry!r}: must be a dict")
        unknown = set(entry) - _ALLOWED_AIRCRAFT_KEYS
        if unknown:
            raise ValueError(
                f"aircraft[{index}]: unknown keys {sorted(unknown)}; allowed: {sorted(_ALLOWED_AIRCRAFT_KEYS)}"
            )
        for key in ("start", "destination"):
            value = entry.get(key)
            if not isinstance(value, (list, tuple)) or len(value) != 2 or not all(_is_number(v) for v in value):
                raise ValueError(f"aircraft[{index}].{key} = {_shown(value)}: must be [x, y] in nm")
        start = np.array([_as_float(v, f"aircraft[{index}].start", "[x, y] in nm") for v in entry["start"]])
        dest = np.array([_as_float(v, f"aircraft[{index}].destination", "[x, y] in nm")
                         for v in entry["destination"]])
        bearing = math.atan2(dest[1] - start[1], dest[0] - start[0])
        turns = {}
        for key in ("heading_deg", "arrival_heading_deg"):
            if key not in entry:
                turns[key] = bearing
                continue
            allowed = f"a finite number of degrees in [-{MAX_HEADING_DEG:g}, {MAX_HEADING_DEG:g}]"
            if not _is_number(entry[key]):
                raise ValueError(f"aircraft[{index}].{key} = {_shown(entry[key])}: must be {allowed}")
            degrees = _as_float(entry[key], f"aircraft[{index}].{key}", allowed)
            # NaN and inf go on to validate_scenario, which names the array holding them.
            if math.isfinite(degrees) and abs(degrees) > MAX_HEADING_DEG:
                raise ValueError(f"aircraft[{index}].{key} = {degrees!r}: must be {allowed}")
            turns[key] = math.radians(degrees)
        starts.append(start)
        dests.append(dest)
        headings.append(turns["heading_deg"])
        arrivals.append(turns["arrival_heading_deg"])
    kwargs: dict[str, Any] = {}
    for key in ("workspace_radius_nm", "start_airspeed_kt"):
        if key in data:
            if not _is_number(data[key]):
                raise ValueError(f"{key} = {_shown(data[key])}: must be a number")
            kwargs[key] = _as_float(data[key], key, "a finite number")
    return Scenario(
        name=str(data.get("name", "custom")),
        start_xy=np.array(starts),
        start_heading=np.array(headings),
        dest_xy=np.array(dests),
        dest_heading=np.array(arrivals),
        **kwargs,
    )


def scenario_from_json(path: str | Path) -> Scenario:
    """A scenario from a JSON file holding ``scenario_from_dict``'s dict."""
    path = Path(path)
    where = f"scenario file {str(path)!r}"
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ValueError(f"{where} does not exist") from None
    except OSError as error:
        raise ValueError(f"{where} cannot be read: {error.strerror}") from None
    if not stat.S_ISREG(mode):
        # A FIFO would block for ever, /dev/zero would fill the memory.
        raise ValueError(f"{where} is not a regular file (a directory, device or pipe); give a .json file")
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except OSError as error:
        raise ValueError(f"{where} cannot be read: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"{where} is not UTF-8 text (byte {error.start}); a scenario is a UTF-8 JSON file") from None
    except json.JSONDecodeError as error:
        raise ValueError(f"{where} is not valid JSON: {error}") from None
    except RecursionError:
        raise ValueError(f"{where}: JSON nested too deeply; a scenario is a dict of a list of dicts") from None
    except ValueError as error:  # e.g. an integer of more digits than Python converts
        raise ValueError(f"{where} cannot be read as JSON: {error}") from None
    try:
        return scenario_from_dict(data)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None


_NAME_PATTERN = re.compile(r"^(converging|random)-(\d+)$")
#: ``stream-R`` or ``stream-R-Dmin``: R aircraft an hour for D minutes (default 120).
_STREAM_PATTERN = re.compile(r"^stream-([^-]*)(?:-(.*)min)?$")


def draws_per_seed(spec: Any) -> bool:
    """Whether ``make_scenario(spec, seed)`` gives each seed its own layout (a ``random-N``
    or ``stream-R`` name) rather than one encounter whatever the seed."""
    if not isinstance(spec, str):
        return False
    return (bool(_NAME_PATTERN.match(spec)) and spec.startswith("random-")) or bool(_STREAM_PATTERN.match(spec))


def _parse_stream_name(spec: str, seed: int) -> StreamScenario:
    """``stream-R`` / ``stream-R-Dmin`` drawn with ``seed``; ValueError naming the ranges."""
    match = _STREAM_PATTERN.match(spec)
    assert match is not None
    numbers = []
    for text, what in ((match.group(1), "rate R"), (match.group(2), "length D")):
        if text is None:
            numbers.append(STREAM_DURATION_MIN)
            continue
        try:
            numbers.append(float(text))
        except ValueError:
            raise ValueError(
                f"scenario {spec!r}: the {what} is not a number; write 'stream-R' (R aircraft per hour in "
                f"(0, {MAX_STREAM_RATE_PER_H:g}], {STREAM_DURATION_MIN:g} min) or 'stream-R-Dmin' (D minutes in "
                f"(0, {MAX_STREAM_DURATION_MIN:g}]), e.g. stream-60 or stream-60-90min"
            ) from None
    try:
        return stream_scenario(numbers[0], seed=seed, duration_min=numbers[1])
    except ValueError as error:
        raise ValueError(f"scenario {spec!r}: {error}") from None


def make_scenario(spec: str | Scenario | Mapping[str, Any], seed: int | None = None) -> Scenario:
    """Resolve a scenario: a Scenario, a dict, a path to a ``.json`` file, or a name.

    Names: ``converging-N`` (the paper's encounter with N aircraft; the paper uses 3, 4
    and 6), ``random-N`` (a random encounter of N aircraft drawn with ``seed``) and
    ``stream-R`` / ``stream-R-Dmin`` (traffic entering at R aircraft an hour for D minutes,
    default 120, drawn with ``seed``: ``stream_scenario``).
    """
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    if not isinstance(spec, str):
        raise ValueError(f"scenario = {spec!r}: must be a name, a .json path, a dict or a Scenario")
    if spec.endswith(".json"):
        return scenario_from_json(spec)
    if _STREAM_PATTERN.match(spec):
        return _parse_stream_name(spec, 0 if seed is None else seed)
    match = _NAME_PATTERN.match(spec)
    if not match:
        raise ValueError(
            f"unknown scenario {spec!r}; allowed: 'converging-N' (e.g. converging-3, "
            "converging-4, converging-6), 'random-N', 'stream-R' or 'stream-R-Dmin' (e.g. stream-60, "
            "stream-60-90min), or a path to a .json file"
        )
    kind, n = match.group(1), int(match.group(2))
    if n < 1:
        raise ValueError(f"scenario {spec!r}: the number of aircraft must be >= 1")
    if kind == "converging":
        return converging(n)
    return random_encounter(n, seed=0 if seed is None else seed)
