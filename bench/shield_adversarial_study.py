"""The safety filter against adversarial proposers, per run.

The filter (``atc_nf_env.shield.SafetyFilter``) is meant to hold against any proposer,
including ones that never aim home: every aircraft home, no loss of separation (5 nm), no
integration step outside [366, 540] kt, within the evaluator's 4-h limit, and never an
exception. This study flies, inside the filter (its defaults, or the settings given), a
family of proposers that do not try to be safe or to get home:

- ``off-<angle>``: every aircraft's waypoint 100 nm out, ``angle`` degrees off the bearing
  to its destination (0: straight home; 180: straight away), turned left;
- ``oscillate-<angle>``: the same, turned alternately left and right at every decision;
- ``corner``: every aircraft aimed at the same far corner of the workspace (0.7 of its
  radius out on the diagonal);
- ``random``: waypoints drawn uniformly over a square twice the workspace's bounding
  square (inside and outside the workspace), seeded;
- ``garbage``: the ``random`` proposer with, at random, NaN, ±inf, ±1e100 nm waypoints;
- ``hold``: every waypoint on the aircraft itself (the NF's singular point);
- ``behind``: every waypoint 100 nm behind the aircraft (the NF answers with a reverse
  airspeed);
- ``chase``: every aircraft aimed 100 nm past the next one (a collision course);
- ``far``: every waypoint 1e4 nm out (outside the workspace) along the bearing + 90°.

For each proposer and scenario it flies seeds 0..SEEDS-1 (σ = 5.17 m/s, 4-h limit) and
prints per row: runs, runs with every aircraft home, runs with a loss of separation, runs
with any integration step outside [366, 540] kt, the worst airspeed excursion outside the
envelope (kt), the longest flight (min), aircraft handed over by the filter's progress
rule, and the seeds not home or not safe.

Run: python bench/shield_adversarial_study.py --scenarios converging-4,converging-6,random-4,random-6
     --seeds 4  (with --write, into the BENCHMARKS.md section named by --section;
     ``--filter key=value`` passes settings to ``SafetyFilter``, e.g.
     ``--filter progress_fraction=None`` for the filter without its progress rule)
"""

from __future__ import annotations

import argparse
import ast
import math
import sys
from pathlib import Path

import numpy as np

#: The families' names, in the table's order (``make_proposer`` builds each).
PROPOSERS = ("off-0", "off-30", "off-60", "off-80", "off-90", "off-120", "off-150", "off-180", "oscillate-60",
             "oscillate-120", "corner", "random", "garbage", "hold", "behind", "chase", "far")


class Adversary:
    """A proposer of the ``atc_nf_env.policy.Policy`` interface that ignores safety.

    ``waypoints(view, rng)`` gives the waypoints (N, 2) nm of one decision; ``rng`` is
    seeded by the episode's seed, so that a run repeats bit for bit."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.decision = 0
        self.rng = np.random.default_rng(0)
        self.workspace_radius_nm = 1500.0

    def reset(self, scenario, config, seed=None) -> None:
        self.decision = 0
        self.rng = np.random.default_rng([0 if seed is None else seed, 0xAD])
        self.workspace_radius_nm = float(scenario.workspace_radius_nm)

    def act(self, view) -> np.ndarray:
        waypoints = self.waypoints(view)
        self.decision += 1
        return waypoints

    def waypoints(self, view) -> np.ndarray:  # pragma: no cover - every family defines it
        raise NotImplementedError


class OffBearing(Adversary):
    """Each aircraft's waypoint ``distance_nm`` out, ``angle_deg`` off its bearing home,
    turned left (``alternate``: left and right at alternate decisions)."""

    def __init__(self, name: str, angle_deg: float, distance_nm: float = 100.0, alternate: bool = False) -> None:
        super().__init__(name)
        self.angle_rad, self.distance_nm, self.alternate = math.radians(angle_deg), distance_nm, alternate

    def waypoints(self, view) -> np.ndarray:
        to_dest = view.destinations - view.positions
        angle = self.angle_rad * (-1.0 if self.alternate and self.decision % 2 else 1.0)
        direction = np.arctan2(to_dest[:, 1], to_dest[:, 0]) + angle
        return view.positions + self.distance_nm * np.stack([np.cos(direction), np.sin(direction)], axis=1)


class Corner(Adversary):
    """Every aircraft aimed at the same point, ``fraction`` of the workspace's radius out on
    the diagonal."""

    def __init__(self, name: str, fraction: float = 0.7) -> None:
        super().__init__(name)
        self.fraction = fraction

    def waypoints(self, view) -> np.ndarray:
        corner = self.fraction * self.workspace_radius_nm / math.sqrt(2.0)
        return np.full((len(view.positions), 2), corner)


class RandomWaypoints(Adversary):
    """Waypoints uniform over a square of half-side ``spread`` × the workspace's radius
    (inside and outside the workspace); with ``garbage``, a quarter of them NaN, ±inf or
    ±1e100 nm."""

    def __init__(self, name: str, spread: float = 2.0, garbage: bool = False) -> None:
        super().__init__(name)
        self.spread, self.garbage = spread, garbage

    def waypoints(self, view) -> np.ndarray:
        n = len(view.positions)
        half = self.spread * self.workspace_radius_nm
        waypoints = self.rng.uniform(-half, half, size=(n, 2))
        if self.garbage:
            bad = self.rng.random((n, 2)) < 0.25
            values = np.array([np.nan, np.inf, -np.inf, 1e100, -1e100])
            waypoints[bad] = values[self.rng.integers(0, len(values), size=int(bad.sum()))]
        return waypoints


class Hold(Adversary):
    """Every waypoint on the aircraft itself: the NF's singular point."""

    def waypoints(self, view) -> np.ndarray:
        return view.positions.copy()


class Mixed(Adversary):
    """Aircraft i proposes as ``parts[i % len(parts)]`` does; with probability
    ``garbage_rate`` a waypoint is replaced by NaN, ±inf or ±1e100 nm."""

    def __init__(self, name: str, parts: list[Adversary], garbage_rate: float = 0.0) -> None:
        super().__init__(name)
        self.parts, self.garbage_rate = parts, garbage_rate

    def reset(self, scenario, config, seed=None) -> None:
        super().reset(scenario, config, seed)
        for part in self.parts:
            part.reset(scenario, config, seed)

    def waypoints(self, view) -> np.ndarray:
        proposals = [part.act(view) for part in self.parts]
        n = len(view.positions)
        waypoints = np.array([proposals[i % len(self.parts)][i] for i in range(n)], dtype=np.float64)
        bad = self.rng.random((n, 2)) < self.garbage_rate
        values = np.array([np.nan, np.inf, -np.inf, 1e100, -1e100])
        waypoints[bad] = values[self.rng.integers(0, len(values), size=int(bad.sum()))]
        return waypoints


class Behind(Adversary):
    """Every waypoint ``distance_nm`` behind the aircraft, against its heading."""

    def __init__(self, name: str, distance_nm: float = 100.0) -> None:
        super().__init__(name)
        self.distance_nm = distance_nm

    def waypoints(self, view) -> np.ndarray:
        heading = view.headings
        return view.positions - self.distance_nm * np.stack([np.cos(heading), np.sin(heading)], axis=1)


class Chase(Adversary):
    """Aircraft i aimed ``distance_nm`` past aircraft i + 1 (mod N), along the line to it."""

    def __init__(self, name: str, distance_nm: float = 100.0) -> None:
        super().__init__(name)
        self.distance_nm = distance_nm

    def waypoints(self, view) -> np.ndarray:
        target = np.roll(view.positions, -1, axis=0)
        line = target - view.positions
        length = np.maximum(np.hypot(line[:, 0], line[:, 1]), 1e-9)
        return target + self.distance_nm * line / length[:, None]


def make_proposer(name: str) -> Adversary:
    """The adversarial proposer of ``PROPOSERS`` (or ``off-A``/``oscillate-A`` for any angle
    A in degrees) named ``name``."""
    family, _, argument = name.partition("-")
    if family == "off" and argument:
        return OffBearing(name, float(argument))
    if family == "oscillate" and argument:
        return OffBearing(name, float(argument), alternate=True)
    if name == "corner":
        return Corner(name)
    if name == "random":
        return RandomWaypoints(name)
    if name == "garbage":
        return RandomWaypoints(name, garbage=True)
    if name == "hold":
        return Hold(name)
    if name == "behind":
        return Behind(name)
    if name == "chase":
        return Chase(name)
    if name == "far":
        return OffBearing(name, 90.0, distance_nm=1e4)
    raise ValueError(f"proposer {name!r}: allowed: {', '.join(PROPOSERS)}, off-A or oscillate-A (A in degrees)")


def fly(proposer: str, scenario_name: str, seed: int, filter_settings: dict | None = None):
    """One shielded run of ``proposer`` on ``scenario_name`` with ``seed``: its
    ``RunMetrics`` and the filter's ``episode_info()``."""
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    shield = SafetyFilter(make_proposer(proposer), **(filter_settings or {}))
    metrics = run_episode(shield, make_scenario(scenario_name, seed=seed), seed=seed).metrics
    return metrics, shield.episode_info()


def study(proposer: str, scenario_name: str, seeds: int, filter_settings: dict | None = None) -> dict:
    """Per-run outcomes of ``proposer`` inside the filter on seeds 0..seeds-1."""
    home = los = outside = handed = 0
    worst = longest = 0.0
    bad_seeds = []
    for seed in range(seeds):
        metrics, info = fly(proposer, scenario_name, seed, filter_settings)
        home += metrics.success
        los += metrics.los_count > 0
        outside += metrics.worst_excursion_kt > 0
        worst = max(worst, metrics.worst_excursion_kt)
        handed += info["shield_stalled_aircraft"]
        longest = max(longest, max(metrics.flight_time_min))
        if not metrics.success or metrics.los_count or metrics.worst_excursion_kt > 0:
            bad_seeds.append(seed)
    return {"home": home, "los": los, "outside": outside, "worst": worst, "longest": longest, "handed": handed,
            "bad_seeds": bad_seeds}


def _settings(pairs: list[str]) -> dict:
    settings = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise ValueError(f"--filter {pair!r}: expected key=value")
        settings[key] = ast.literal_eval(value)
    return settings


def main(argv: list[str] | None = None) -> int:
    from _report import publish  # bench/ is on sys.path when run as a script

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--proposers", default=",".join(PROPOSERS))
    parser.add_argument("--scenarios", default="converging-4,converging-6,random-4,random-6")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--filter", action="append", default=[], metavar="KEY=VALUE",
                        help="a SafetyFilter setting (repeatable), e.g. progress_fraction=None")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    parser.add_argument("--section", default="shield-adversarial", help="name of the BENCHMARKS.md section to write")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    try:
        settings = _settings(args.filter)
        proposers = [p for p in args.proposers.split(",") if p]
        for proposer in proposers:
            make_proposer(proposer)
    except ValueError as error:
        parser.error(str(error))
    rows = [
        "| proposer | scenario | runs | every aircraft home | runs with LoS | runs outside envelope "
        "| worst excursion (kt) | longest flight (min) | aircraft handed over | seeds not home or not safe |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    totals = dict.fromkeys(("runs", "home", "los", "outside"), 0)
    for proposer in proposers:
        for scenario in [s for s in args.scenarios.split(",") if s]:
            r = study(proposer, scenario, args.seeds, settings)
            for key in ("home", "los", "outside"):
                totals[key] += r[key]
            totals["runs"] += args.seeds
            rows.append(
                f"| {proposer} | {scenario} | {args.seeds} | {r['home']} | {r['los']} | {r['outside']} "
                f"| {r['worst']:.0f} | {r['longest']:.1f} | {r['handed']} | {' '.join(map(str, r['bad_seeds'])) or '—'} |"
            )
            print(rows[-1], flush=True)
    rows.append(f"| **all** | | {totals['runs']} | {totals['home']} | {totals['los']} | {totals['outside']} | | | | |")
    command = (f"python bench/shield_adversarial_study.py --proposers {args.proposers} --scenarios {args.scenarios} "
               f"--seeds {args.seeds}" + "".join(f" --filter {pair}" for pair in args.filter)
               + ("" if args.section == "shield-adversarial" else f" --section {args.section}"))
    text = "\n".join([
        "## Safety filter: adversarial proposers",
        "",
        f"`{command}` — each proposer inside `atc_nf_env.shield.SafetyFilter` "
        f"({', '.join(f'{k}={v!r}' for k, v in settings.items()) or 'its defaults'}), seeds from 0, σ = 5.17 m/s, "
        "4-h limit; outcomes per run (outside the envelope: any integration step outside [366, 540] kt).",
        "",
        *rows,
    ])
    return publish(args.section, text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
