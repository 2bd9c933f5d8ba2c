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


def validate_scenario(scenario: Scenario) -> None:
    """Raise ValueError, naming the field, the value and what is allowed, if the scenario is impossible."""
    n = scenario.start_xy.shape[0] if scenario.start_xy.ndim == 2 else -1
    if scenario.start_xy.ndim != 2 or scenario.start_xy.shape[1:] != (2,):
        raise ValueError(f"start_xy has shape {scenario.start_xy.shape}; expected (n, 2)")
    if n < 1:
        raise ValueError(f"number of aircraft n = {n}: must be >= 1")
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
    if n > 1:
        diff = scenario.start_xy[:, None, :] - scenario.start_xy[None, :, :]
        sep = np.hypot(diff[..., 0], diff[..., 1]) + np.diag(np.full(n, np.inf))
        i, j = np.unravel_index(int(np.argmin(sep)), sep.shape)
        if sep[i, j] < SEPARATION_MIN_NM:
            raise ValueError(
                f"start_xy: aircraft {i} and {j} start {sep[i, j]:.2f} nm apart, in conflict; "
                f"initial separations must be >= {SEPARATION_MIN_NM} nm"
            )


def converging(n: int, radius_nm: float = ENCOUNTER_RADIUS_NM, **kwargs: Any) -> Scenario:
    """The paper's encounter: n aircraft evenly spaced on a circle, all heading for the
    centre, each bound for the diametrically opposite point (section IV-A)."""
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"number of aircraft n = {n!r}: must be an integer >= 1")
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
    ±``max_deviation_deg``; starts and destinations are at least ``min_separation_nm``
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


def draws_per_seed(spec: Any) -> bool:
    """Whether ``make_scenario(spec, seed)`` gives each seed its own layout (a ``random-N``
    name) rather than one encounter whatever the seed."""
    return isinstance(spec, str) and bool(_NAME_PATTERN.match(spec)) and spec.startswith("random-")


def make_scenario(spec: str | Scenario | Mapping[str, Any], seed: int | None = None) -> Scenario:
    """Resolve a scenario: a Scenario, a dict, a path to a ``.json`` file, or a name.

    Names: ``converging-N`` (the paper's encounter with N aircraft; the paper uses 3, 4
    and 6) and ``random-N`` (a random encounter of N aircraft drawn with ``seed``).
    """
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, Mapping):
        return scenario_from_dict(spec)
    if not isinstance(spec, str):
        raise ValueError(f"scenario = {spec!r}: must be a name, a .json path, a dict or a Scenario")
    if spec.endswith(".json"):
        return scenario_from_json(spec)
    match = _NAME_PATTERN.match(spec)
    if not match:
        raise ValueError(
            f"unknown scenario {spec!r}; allowed: 'converging-N' (e.g. converging-3, "
            "converging-4, converging-6), 'random-N', or a path to a .json file"
        )
    kind, n = match.group(1), int(match.group(2))
    if n < 1:
        raise ValueError(f"scenario {spec!r}: the number of aircraft must be >= 1")
    if kind == "converging":
        return converging(n)
    return random_encounter(n, seed=0 if seed is None else seed)
