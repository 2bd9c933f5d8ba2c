"""Metrics of one run and the summary of many (the ``--summary-json`` contract).

Per aircraft: flight time (min), path length (nm), arrival. Per run: minimum
separation (nm), loss-of-separation count (pairs of aircraft that came closer than
5 nm), envelope violation as the fraction of integration steps flown with airspeed
outside [366, 540] kt, and the worst excursion outside it (kt).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Iterable

import numpy as np

from atc_nf_env.kernel import ARRIVED, LEFT, NO_PAIR_SEPARATION_NM, S_PATH, S_STATUS, S_TIME, S_X, S_Y
from atc_nf_env.config import SimConfig
from atc_nf_env.simulation import Simulation

#: The default guard on the commanded airspeed, kt (``SimConfig.airspeed_cap_kt``).
AIRSPEED_CAP_KT: float = SimConfig().airspeed_cap_kt


@dataclass
class RunMetrics:
    """Outcome of one episode. Times in minutes, distances in nm, speeds in kt."""

    scenario: str
    seed: int | None
    n_aircraft: int
    wind_kt: list[float]
    arrived: list[bool]
    left_workspace: list[bool]
    flight_time_min: list[float]
    path_length_nm: list[float]
    success: bool
    min_separation_nm: float | None
    los_count: int
    envelope_violation_fraction: float
    worst_excursion_kt: float
    airspeed_min_kt: float | None  # None when no integration step was flown
    airspeed_max_kt: float | None
    steps_flown: int
    sim_time_min: float
    wall_s: float
    decisions: int
    decision_s_mean: float
    #: A traffic stream's metrics (``stream_run_metrics``); None for an encounter.
    stream: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def run_metrics(
    sim: Simulation,
    *,
    seed: int | None,
    wall_s: float,
    decision_s: Iterable[float],
) -> RunMetrics:
    """Metrics of a finished (or truncated) simulation. For a traffic stream the
    per-aircraft lists are over the flights that entered, in the order they were due,
    ``success`` means that none of them left the workspace (those still airborne at the
    end count as neither arrived nor failed), and ``stream`` holds the stream's metrics."""
    from atc_nf_env.streams import StreamSimulation

    if isinstance(sim, StreamSimulation):
        return _stream_run_metrics(sim, seed=seed, wall_s=wall_s, decision_s=decision_s)
    state = sim.state[0, : sim.n_aircraft]
    stats = sim.stats
    decision_list = list(decision_s)
    # An arrival needs a finite position and path: a NaN compares as "close" nowhere, but
    # it must never be counted as a success either.
    finite = np.isfinite(state[:, [S_X, S_Y, S_PATH, S_TIME]]).all(axis=1)
    arrived = (state[:, S_STATUS] == ARRIVED) & finite
    flown = int(stats.steps_flown.sum())
    min_sep = stats.min_separation_nm
    return RunMetrics(
        scenario=sim.scenario.name,
        seed=seed,
        n_aircraft=sim.n_aircraft,
        wind_kt=[float(w) for w in sim.wind_kt],
        arrived=[bool(a) for a in arrived],
        left_workspace=[bool(s == LEFT) for s in state[:, S_STATUS]],
        flight_time_min=[float(t) / 60.0 for t in state[:, S_TIME]],
        path_length_nm=[float(p) for p in state[:, S_PATH]],
        success=bool(arrived.all()),
        min_separation_nm=None if min_sep >= NO_PAIR_SEPARATION_NM else float(min_sep),
        los_count=int(np.triu(stats.los_pairs, 1).sum()),
        envelope_violation_fraction=float(stats.violation_steps.sum()) / flown if flown else 0.0,
        worst_excursion_kt=float(stats.worst_excursion_kt.max(initial=0.0)),
        airspeed_min_kt=float(stats.min_airspeed_kt.min()) if flown else None,
        airspeed_max_kt=float(stats.max_airspeed_kt.max()) if flown else None,
        steps_flown=flown,
        sim_time_min=sim.time_s / 60.0,
        wall_s=wall_s,
        decisions=len(decision_list),
        decision_s_mean=float(np.mean(decision_list)) if decision_list else 0.0,
    )


#: What each of a stream's metrics means (``RunMetrics.stream``; times in s).
STREAM_METRIC_NOTES: dict[str, str] = {
    "throughput_per_hour": "flights that arrived per hour of the episode",
    "delay_s": "over arrived flights: flight time minus the direct flight's (straight line at 454 kt, no wind)",
    "entry_delay_s": "over entered flights: entry time minus due time (entries happen at decision instants)",
    "entries_held": "flights that could not enter at the first decision instant they were due at (slot or clearance)",
    "los_per_flight_hour": "pairs of flights that lost separation per hour flown by all flights",
    "max_airborne": "most aircraft airborne at once (at decision instants)",
}


def _stream_run_metrics(sim: Any, *, seed: int | None, wall_s: float, decision_s: Iterable[float]) -> RunMetrics:
    from atc_nf_env.streams import AIRBORNE, DONE_ARRIVED, DONE_LEFT

    stream = sim.stream_metrics()  # also copies the airborne flights' times and paths
    log = sim.flights
    entered = np.flatnonzero(np.isfinite(log.entered_s))
    arrived = log.state[entered] == DONE_ARRIVED
    flown = int(log.steps_flown.sum())
    stats = sim.stats
    min_sep = stats.min_separation_nm
    decision_list = list(decision_s)
    flew = log.steps_flown > 0
    return RunMetrics(
        scenario=sim.scenario.name,
        seed=seed,
        n_aircraft=int(entered.size),
        wind_kt=[float(w) for w in sim.wind_kt],
        arrived=[bool(a) for a in arrived],
        left_workspace=[bool(s == DONE_LEFT) for s in log.state[entered]],
        flight_time_min=[float(t) / 60.0 for t in log.flight_time_s[entered]],
        path_length_nm=[float(p) for p in log.path_nm[entered]],
        success=not bool((log.state == DONE_LEFT).any()),
        min_separation_nm=None if min_sep >= NO_PAIR_SEPARATION_NM else float(min_sep),
        los_count=len(log.los_pairs),
        envelope_violation_fraction=float(log.violation_steps.sum()) / flown if flown else 0.0,
        worst_excursion_kt=float(log.worst_excursion_kt.max(initial=0.0)),
        airspeed_min_kt=float(log.min_airspeed_kt[flew].min()) if flew.any() else None,
        airspeed_max_kt=float(log.max_airspeed_kt[flew].max()) if flew.any() else None,
        steps_flown=flown,
        sim_time_min=sim.time_s / 60.0,
        wall_s=wall_s,
        decisions=len(decision_list),
        decision_s_mean=float(np.mean(decision_list)) if decision_list else 0.0,
        stream=stream | {"airborne_flights": int((log.state == AIRBORNE).sum())},
    )


def summarize_streams(runs: list[RunMetrics]) -> dict[str, Any] | None:
    """The stream block of a summary (None when no run is a stream): totals and means over
    runs, the delays' mean over all flights and max over runs, LoS per flight hour pooled."""
    streams = [r.stream for r in runs if r.stream]
    return pool_stream_metrics(streams) if streams else None


def pool_stream_metrics(streams: list[dict[str, Any]]) -> dict[str, Any]:
    """The stream blocks of several runs (``RunMetrics.stream``, or the ``stream`` of the
    evaluator's records) pooled: totals and means over runs, the delays' mean over all
    flights and max over runs, LoS per flight hour pooled."""
    if not streams:
        raise ValueError("pool_stream_metrics needs at least one run's stream metrics")
    hours = sum(s["flight_hours"] for s in streams)
    los = sum(s["los_count"] for s in streams)

    def pooled(key: str, count_key: str) -> dict[str, float | None]:
        weighted = [(s[key]["mean"], s[count_key]) for s in streams if s[key]["mean"] is not None]
        total = sum(n for _, n in weighted)
        maxima = [s[key]["max"] for s in streams if s[key]["max"] is not None]
        return {
            "mean": sum(m * n for m, n in weighted) / total if total else None,
            "max": max(maxima) if maxima else None,
        }

    return {
        "runs": len(streams),
        "flights_entered": int(sum(s["flights_entered"] for s in streams)),
        "flights_completed": int(sum(s["flights_completed"] for s in streams)),
        "flights_left_workspace": int(sum(s["flights_left_workspace"] for s in streams)),
        "entries_held": int(sum(s["entries_held"] for s in streams)),
        "throughput_per_hour": _stats([s["throughput_per_hour"] for s in streams]),
        "delay_s": pooled("delay_s", "flights_completed"),
        "entry_delay_s": pooled("entry_delay_s", "flights_entered"),
        "flight_hours": hours,
        "los_count": int(los),
        "los_per_flight_hour": los / hours if hours > 0 else 0.0,
        "max_airborne": int(max(s["max_airborne"] for s in streams)),
        "notes": STREAM_METRIC_NOTES,
    }


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"min": None, "mean": None, "max": None}
    return {"min": float(min(values)), "mean": float(np.mean(values)), "max": float(max(values))}


def wilson_interval(successes: int, trials: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for the default z).

    Unlike the normal approximation it stays inside [0, 1] and is not empty at 0 or
    ``trials`` successes: 300 of 300 gives [0.9874, 1].
    """
    if not isinstance(trials, int) or trials < 1 or not 0 <= successes <= trials:
        raise ValueError(f"wilson_interval: need 0 <= successes <= trials and trials >= 1, got {successes}/{trials}")
    p = successes / trials
    denominator = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    # Exact at the ends: the Wilson bound is 1 (or 0) there, up to rounding.
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return low, high


#: What the timing fields of a summary mean, written into it so that a reader need not guess.
TIMING_NOTE = (
    "wall_s_per_run and decision_s are warm (numba compiled, policy loaded); compile_s is the "
    "warm-up apart: numba compiling or loading its cache and the policy's first call, "
    "the longest over the worker processes"
)


def summarize(
    runs: list[RunMetrics],
    peak_rss_mb: float | None = None,
    *,
    compile_s: float | None = None,
    airspeed_cap_kt: float = AIRSPEED_CAP_KT,
) -> dict[str, Any]:
    """The summary of DESIGN.md's contract over runs.

    ``flight_time_min`` is over arrived aircraft; ``envelope_violation_fraction`` pools
    the integration steps of all runs. Safety is also counted per run:
    ``runs_with_envelope_violation`` (any integration step outside [366, 540] kt),
    ``runs_at_airspeed_cap`` (the commanded airspeed reached ±``airspeed_cap_kt``),
    ``runs_with_los``, ``worst_envelope_excursion_kt`` (the largest over runs) and
    ``min_separation_nm`` {min, mean, max} over runs. ``success_rate_ci95`` is the
    Wilson score interval of the success rate. ``compile_s`` (s) is the warm-up kept out
    of the timings (see ``TIMING_NOTE``); None when unknown.
    """
    if not runs:
        raise ValueError("summarize needs at least one run")
    separations = [r.min_separation_nm for r in runs if r.min_separation_nm is not None]
    flight_times = [t for r in runs for t, a in zip(r.flight_time_min, r.arrived) if a]
    steps = sum(r.steps_flown for r in runs)
    violations = sum(r.envelope_violation_fraction * r.steps_flown for r in runs)
    decision_times = [r.decision_s_mean for r in runs if r.decisions]
    speeds_min = [r.airspeed_min_kt for r in runs if r.airspeed_min_kt is not None]
    speeds_max = [r.airspeed_max_kt for r in runs if r.airspeed_max_kt is not None]
    successes = sum(bool(r.success) for r in runs)
    worst = float(max(r.worst_excursion_kt for r in runs))
    return {
        "scenario": runs[0].scenario,
        "runs": len(runs),
        "success_rate": successes / len(runs),
        "success_rate_ci95": list(wilson_interval(successes, len(runs))),
        "success_rate_ci95_method": "Wilson score",
        "arrived_fraction": float(np.mean([a for r in runs for a in r.arrived])),
        "los_count": int(sum(r.los_count for r in runs)),
        "runs_with_los": int(sum(r.los_count > 0 for r in runs)),
        "min_separation_nm": _stats(separations),
        "airspeed_kt": {
            "min": min(speeds_min) if speeds_min else None,
            "max": max(speeds_max) if speeds_max else None,
        },
        "envelope_violation_fraction": violations / steps if steps else 0.0,
        "runs_with_envelope_violation": int(sum(r.envelope_violation_fraction > 0 for r in runs)),
        "runs_at_airspeed_cap": int(sum(_reached_cap(r, airspeed_cap_kt) for r in runs)),
        "worst_envelope_excursion_kt": worst,
        "worst_excursion_kt": worst,  # the same, under its earlier name
        "flight_time_min": {
            "mean": float(np.mean(flight_times)) if flight_times else None,
            "max": float(max(flight_times)) if flight_times else None,
        },
        "wall_s_per_run": {
            "mean": float(np.mean([r.wall_s for r in runs])),
            "median": float(np.median([r.wall_s for r in runs])),
        },
        "decision_s": {"mean": float(np.mean(decision_times)) if decision_times else 0.0},
        "compile_s": compile_s,
        "timing_note": TIMING_NOTE,
        "peak_rss_mb": peak_rss_mb,
    } | ({"stream": stream} if (stream := summarize_streams(runs)) is not None else {})


def _reached_cap(run: RunMetrics, airspeed_cap_kt: float) -> bool:
    # The kernel clips the commanded airspeed to exactly ±cap, so equality is the test.
    extremes = [abs(v) for v in (run.airspeed_min_kt, run.airspeed_max_kt) if v is not None]
    return bool(extremes) and max(extremes) >= airspeed_cap_kt


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def format_run(metrics: RunMetrics) -> str:
    """A short human-readable report of one run."""
    lines = [
        f"scenario {metrics.scenario}  seed {metrics.seed}  wind ({metrics.wind_kt[0]:+.1f}, "
        f"{metrics.wind_kt[1]:+.1f}) kt",
        f"  arrived {sum(metrics.arrived)}/{metrics.n_aircraft}"
        + (f"  left workspace {sum(metrics.left_workspace)}" if any(metrics.left_workspace) else ""),
        "  min separation "
        + ("n/a" if metrics.min_separation_nm is None else f"{metrics.min_separation_nm:.2f} nm")
        + f"  losses of separation {metrics.los_count}",
        "  airspeed: no step flown"
        if metrics.airspeed_min_kt is None or metrics.airspeed_max_kt is None
        else f"  airspeed {metrics.airspeed_min_kt:.0f}..{metrics.airspeed_max_kt:.0f} kt  "
        f"outside [366, 540] kt on {100 * metrics.envelope_violation_fraction:.1f} % of steps "
        f"(worst by {metrics.worst_excursion_kt:.0f} kt)",
        "  flight time "
        + ", ".join(f"{t:.1f}" if a else f"({t:.1f})" for t, a in zip(metrics.flight_time_min, metrics.arrived))
        + " min  (in parentheses: not arrived)",
        "  path length " + ", ".join(f"{p:.0f}" for p in metrics.path_length_nm) + " nm",
        f"  simulated {metrics.sim_time_min:.1f} min in {metrics.wall_s:.2f} s wall, "
        f"{metrics.decisions} decisions of {metrics.decision_s_mean * 1e3:.2f} ms",
    ]
    if metrics.stream:
        lines[1:1] = [format_stream(metrics.stream)]
        lines = [line for line in lines if not line.startswith(("  flight time", "  path length"))]
    return "\n".join(lines)


def _seconds(block: dict[str, Any]) -> str:
    if block["mean"] is None:
        return "n/a"
    return f"mean {block['mean']:.0f} s, max {block['max']:.0f} s"


def format_stream(stream: dict[str, Any]) -> str:
    """A stream's metrics in a few lines."""
    return "\n".join([
        f"  stream: {stream['flights_entered']} of {stream['flights_due']} due flights entered "
        f"({stream['entries_held']} held), {stream['flights_completed']} completed, "
        f"{stream['airborne_at_end']} airborne at the end, max airborne {stream['max_airborne']} "
        f"of {stream['max_airborne_slots']} slots",
        f"  throughput {stream['throughput_per_hour']:.1f} flights/h  delay vs direct {_seconds(stream['delay_s'])}"
        f"  entry delay {_seconds(stream['entry_delay_s'])}",
        f"  LoS {stream['los_count']} in {stream['flight_hours']:.1f} flight hours "
        f"({stream['los_per_flight_hour']:.3f} per flight hour)",
    ])
