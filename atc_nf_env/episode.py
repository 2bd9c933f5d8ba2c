"""Fly one episode of a scenario with a policy: a decision every period, the NF between."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.metrics import RunMetrics, run_metrics
from atc_nf_env.policy import Policy
from atc_nf_env.scenarios import Scenario, StreamScenario, check_seed, make_scenario
from atc_nf_env.simulation import sample_wind_kt
from atc_nf_env.streams import make_simulation
from atc_nf_env.units import DECISION_PERIOD_S, WIND_SIGMA_MPS

#: Default time limit of an episode, s: room for the 6-aircraft NF roundabout.
MAX_EPISODE_S: float = 4 * 3600.0
#: Longest time limit accepted, s: no aircraft stays airborne a day, and a longer limit
#: would let an NF holding orbit fly (and a study run) for ever.
MAX_TIME_LIMIT_S: float = 24 * 3600.0


class LayoutSeedWarning(UserWarning):
    """A random encounter drawn with one seed is flown with another: its layout is the one
    of the seed it was drawn with, so a loop over seeds would fly one layout in many winds."""


def scenario_for_seed(scenario: Scenario | str | Mapping[str, Any], seed: int | None) -> Scenario:
    """The ``Scenario`` that a run with ``seed`` flies: a name or dict is resolved with
    ``make_scenario(scenario, seed=seed)`` (a ``random-N`` name is drawn with the run's
    seed, as the evaluator does); a ``Scenario`` is flown as it is, with a
    ``LayoutSeedWarning`` when it is a random encounter drawn with another seed."""
    if not isinstance(scenario, Scenario):
        return make_scenario(scenario, seed=0 if seed is None else seed)
    drawn_with = scenario.metadata.get("seed") if isinstance(scenario.metadata, dict) else None
    if drawn_with is not None and seed is not None and drawn_with != seed:
        warnings.warn(
            f"{scenario.name!r} was drawn with seed {drawn_with} and is flown with seed {seed}: the layout is seed "
            f"{drawn_with}'s, only the wind is seed {seed}'s. Pass the name ({scenario.name!r}) to draw each run's "
            "layout with its seed, as the evaluator does.",
            LayoutSeedWarning,
            stacklevel=3,
        )
    return scenario


@dataclass
class EpisodeResult:
    """A finished episode: its metrics and, when recorded, its trajectory.

    ``times_s`` (R,) and ``records`` (R, N, N_RECORD) hold the state every
    ``record_every`` integration steps (fields ``atc_nf_env.kernel.R_*``).
    """

    metrics: RunMetrics
    times_s: np.ndarray
    records: np.ndarray
    waypoints: np.ndarray  # (decisions, N, 2) nm
    decision_times_s: np.ndarray
    #: (decisions,) wall time of each decision (the policy's ``act``), s.
    decision_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: A traffic stream's slots, (K,) s and (K, N): ``StreamSimulation.slot_history``;
    #: None for an encounter.
    slot_flight_times_s: np.ndarray | None = None
    slot_flight: np.ndarray | None = None


def episode_wind_kt(seed: int | None, wind_sigma_mps: float) -> np.ndarray:
    """The hidden wind of the episode with this seed (kt): a stream of its own, so that
    a policy's randomness never changes the wind of a seed."""
    seed = 0 if seed is None else check_seed(seed)
    rng = np.random.default_rng([seed, 0x57494E44])
    return sample_wind_kt(rng, wind_sigma_mps)


def warm_up(
    policy: Policy,
    scenario: Scenario,
    *,
    seed: int | None = 0,
    wind_sigma_mps: float = WIND_SIGMA_MPS,
    config: SimConfig | None = None,
    record_every: int = 0,
) -> float:
    """Fly one decision period of ``scenario`` untimed, so that numba has compiled (or
    loaded from its cache) the kernel and the policy has made its first decision before
    anything is timed; returns the seconds it took (the ``compile_s`` of reports).

    The policy is reset by the next ``run_episode``, so the warm-up changes no result.
    """
    start = time.perf_counter()
    run_episode(
        policy,
        scenario,
        seed=seed,
        wind_sigma_mps=wind_sigma_mps,
        config=config,
        max_time_s=DECISION_PERIOD_S,
        record_every=record_every,
    )
    return time.perf_counter() - start


def whole_steps(name: str, seconds: float, dt_s: float) -> int:
    """``seconds`` as a whole number >= 1 of integration steps of ``dt_s``, or a ValueError
    saying which durations are allowed (checked before anything flies)."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} = {seconds!r}: must be a number of seconds")
    seconds = float(seconds)
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"{name} = {seconds!r}: must be a finite number of seconds > 0")
    steps = round(seconds / dt_s)
    if steps < 1 or abs(steps * dt_s - seconds) > 1e-9 * max(1.0, seconds):
        raise ValueError(
            f"{name} = {seconds!r} s is not a whole number of integration steps of {dt_s:g} s; "
            f"allowed: a multiple of {dt_s:g} s (e.g. {max(steps, 1) * dt_s:g})"
        )
    if steps * dt_s > MAX_TIME_LIMIT_S:
        raise ValueError(
            f"{name} = {seconds!r} s: longer than any flight ({MAX_TIME_LIMIT_S:g} s = 24 h); allowed: a multiple "
            f"of {dt_s:g} s up to {MAX_TIME_LIMIT_S:g} s"
        )
    return steps


def run_episode(
    policy: Policy,
    scenario: Scenario | str | Mapping[str, Any],
    *,
    seed: int | None = 0,
    wind_sigma_mps: float = WIND_SIGMA_MPS,
    wind_kt: np.ndarray | None = None,
    config: SimConfig | None = None,
    period_s: float = DECISION_PERIOD_S,
    max_time_s: float = MAX_EPISODE_S,
    record_every: int = 0,
) -> EpisodeResult:
    """Fly ``scenario`` with ``policy`` until every aircraft has arrived or left, or
    ``max_time_s`` has passed; a traffic stream (``stream-R``) until its length has passed
    (or ``max_time_s``, if shorter), its aircraft entering and leaving meanwhile.

    Args:
        policy: any object of the ``Policy`` interface.
        scenario: the encounter: a ``Scenario``, or anything ``make_scenario`` resolves (a
            name such as ``"random-6"`` or ``"stream-60"``, a dict, a .json path), resolved
            with ``seed``: a ``random-N`` or ``stream-R`` name is drawn with this run's
            seed, as the evaluator does. A
            ``Scenario`` is flown as given; one drawn by ``random_encounter`` with another
            seed than ``seed`` flies with a ``LayoutSeedWarning`` (its layout is the seed
            it was drawn with, only the wind follows ``seed``).
        seed: seeds the wind (unless ``wind_kt`` is given), the policy and, for a
            ``random-N`` name, the layout.
        wind_sigma_mps: standard deviation of each wind component, m/s.
        wind_kt: a fixed wind (east, north) in kt instead of a sampled one.
        config: NF gains and integrator settings.
        period_s: decision period T, s (a whole number of integration steps).
        max_time_s: time limit, s (a whole number of integration steps).
        record_every: keep the state every this many integration steps (0: none).

    Raises:
        ValueError: on a period or time limit that is not a whole number >= 1 of
            integration steps (refused before anything flies), or any other bad setting.
    """
    config = config or SimConfig()
    scenario = scenario_for_seed(scenario, seed)
    period_steps = whole_steps("period_s", period_s, config.dt_s)
    limit_steps = whole_steps("max_time_s", max_time_s, config.dt_s)
    wind = episode_wind_kt(seed, wind_sigma_mps) if wind_kt is None else wind_kt  # Simulation checks it
    stream = isinstance(scenario, StreamScenario)
    if stream:
        # A stream ends at its length (flights still airborne then are counted as such).
        limit_steps = min(limit_steps, whole_steps("the stream's duration_s", scenario.duration_s, config.dt_s))
    sim = make_simulation(scenario, config=config, wind_kt=wind, record_every=record_every)
    # A policy with a stated operating range (trained agents) checks the traffic and the
    # wind's sigma here: reset() sees the scenario but not the sigma.
    check_conditions = getattr(policy, "check_operating_conditions", None)
    if check_conditions is not None:
        check_conditions(scenario.n_aircraft, wind_sigma_mps if wind_kt is None else None)
    policy.reset(scenario, config, seed)
    decision_s: list[float] = []
    waypoints: list[np.ndarray] = []
    decision_times: list[float] = []
    steps_done = 0  # counted in whole steps: a float clock could stall short of the limit
    start = time.perf_counter()
    while not sim.done and steps_done < limit_steps:
        view = sim.view()
        if stream and not view.flying.any():
            # An empty sector: nothing to decide until the next flight enters.
            steps = min(period_steps, limit_steps - steps_done)
            sim.advance(view.waypoints, steps * config.dt_s)
            steps_done += steps
            continue
        t0 = time.perf_counter()
        action = policy.act(view)
        if np.iscomplexobj(action):
            raise ValueError(f"{type(policy).__name__}.act returned complex waypoints; expected real (N, 2) nm")
        action = np.asarray(action, dtype=np.float64)
        decision_s.append(time.perf_counter() - t0)
        waypoints.append(action.copy())
        decision_times.append(sim.time_s)
        steps = min(period_steps, limit_steps - steps_done)
        sim.advance(action, steps * config.dt_s)
        steps_done += steps
    wall = time.perf_counter() - start
    times, records = sim.recording()
    metrics = run_metrics(sim, seed=seed, wall_s=wall, decision_s=decision_s)
    slot_times, slot_flight = sim.slot_history() if stream else (None, None)  # type: ignore[attr-defined]
    return EpisodeResult(
        metrics=metrics,
        times_s=times,
        records=records,
        waypoints=np.array(waypoints),
        decision_times_s=np.array(decision_times),
        decision_s=np.array(decision_s),
        slot_flight_times_s=slot_times,
        slot_flight=slot_flight,
    )
