"""The aligned tables that ``atc-nf fly`` and ``atc-nf evaluate`` print, for people.

Figures are rounded to what they can tell (minutes to 0.1, miles to 1 or 0.1, knots to
1, milliseconds to 0.1); nothing prints as a Python dict or ``None``. The JSON summaries
(``fly_summary``, and the evaluator's own) go to files.

Units: minutes, nautical miles, knots, milliseconds.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import EpisodeResult
from atc_nf_env.kernel import R_AIRSPEED_MAX, R_AIRSPEED_MIN, R_FLEW, R_X, R_Y
from atc_nf_env.metrics import format_stream, peak_rss_mb, summarize
from atc_nf_env.shield import summarize_interventions


def aligned(rows: Sequence[Sequence[str]], right: Sequence[bool]) -> list[str]:
    """Rows of cells as lines, each column padded to its widest cell, right-aligned where
    ``right`` says so; columns two spaces apart."""
    widths = [max(len(row[c]) for row in rows) for c in range(len(rows[0]))]
    return [
        "  ".join(cell.rjust(w) if r else cell.ljust(w) for cell, w, r in zip(row, widths, right)).rstrip()
        for row in rows
    ]


def _range(low: float | None, high: float | None, digits: int = 0) -> str:
    if low is None or high is None or not (np.isfinite(low) and np.isfinite(high)):
        return "-"
    return f"{low:.{digits}f}–{high:.{digits}f}"


def _number(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def duration(seconds: float) -> str:
    """A duration with three significant figures at most, in s, ms or µs."""
    if seconds >= 1.0:
        return f"{seconds:.2f} s"
    if seconds >= 1e-3:
        return f"{1e3 * seconds:.1f} ms"
    return f"{1e6 * seconds:.0f} µs"


#: Most pair distances ``closest_approach_nm`` holds at once: a handful of arrays of this
#: many 8-byte values (tens of MB) whatever the number of aircraft and of records.
PAIR_BLOCK_ELEMENTS: int = 1 << 20


def closest_approach_nm(records: np.ndarray) -> np.ndarray:
    """Per aircraft, the closest distance (N,) nm to any other aircraft at the records
    (R, N, N_RECORD) both flew; NaN where no other aircraft flew beside it.

    The pairs are taken a block of records and of aircraft at a time, at most
    ``PAIR_BLOCK_ELEMENTS`` distances at once: memory O(N) per record, whatever R and N
    (time O(R·N²)); every distance is the one an all-pairs array would hold, bit for bit."""
    n_records, n = records.shape[:2]
    closest = np.full(n, np.inf)
    flew = records[:, :, R_FLEW] > 0
    x, y = records[:, :, R_X], records[:, :, R_Y]
    rows = max(1, min(n, PAIR_BLOCK_ELEMENTS // max(n, 1)))  # aircraft per block
    steps = max(1, PAIR_BLOCK_ELEMENTS // (rows * max(n, 1)))  # records per block
    for t0 in range(0, n_records, steps):
        t = slice(t0, t0 + steps)
        for i0 in range(0, n, rows):
            i = slice(i0, min(i0 + rows, n))
            distance = np.hypot(x[t, i, None] - x[t, None, :], y[t, i, None] - y[t, None, :])
            both = flew[t, i, None] & flew[t, None, :]
            own = np.arange(i.start, i.stop)
            both[:, own - i0, own] = False  # an aircraft is not its own neighbour
            nearest = np.where(both, distance, np.inf).min(axis=(0, 2), initial=np.inf)
            closest[i] = np.minimum(closest[i], nearest)
    return np.where(np.isfinite(closest), closest, np.nan)


def airspeed_range_kt(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per aircraft, the lowest and highest airspeed (N,) kt over the records (R, N,
    N_RECORD) it flew, each record's sub-steps included (``R_AIRSPEED_MIN``,
    ``R_AIRSPEED_MAX``); NaN where it flew none."""
    flew = records[:, :, R_FLEW] > 0
    low = np.where(flew, records[:, :, R_AIRSPEED_MIN], np.inf).min(axis=0, initial=np.inf)
    high = np.where(flew, records[:, :, R_AIRSPEED_MAX], -np.inf).max(axis=0, initial=-np.inf)
    flown = flew.any(axis=0)
    return np.where(flown, low, np.nan), np.where(flown, high, np.nan)


def per_aircraft(result: EpisodeResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per aircraft, from a recording of every integration step: the closest distance to
    any other aircraft (N,) nm at the ends of the steps both flew (NaN where no other
    aircraft flew beside it, ``closest_approach_nm``), and the lowest and highest airspeed
    (N,) kt over the steps it flew, sub-steps included (NaN where none,
    ``airspeed_range_kt``). The kernel's run-wide minimum separation also looks between a
    refined step's sub-steps, so it can be a little lower than the least of these."""
    records = result.records
    if records.ndim != 3 or records.shape[0] == 0:
        nothing = np.full(records.shape[1] if records.ndim == 3 else result.metrics.n_aircraft, np.nan)
        return nothing, nothing.copy(), nothing.copy()
    return (closest_approach_nm(records), *airspeed_range_kt(records))


def _policy_line(info: dict[str, Any]) -> str | None:
    """The policy's diagnostics in words (the MCMC-MPC's, the safety filter's), or None."""
    parts = []
    if "fallbacks" in info and "decisions" in info:
        text = f"MPC: {info['decisions']} decisions, {info['fallbacks']} without a feasible candidate (fallbacks)"
        if info.get("wider_searches"):
            text += f", {info['wider_searches']} needing a wider search"
        if info.get("start_kept") is not None and info["decisions"]:
            text += f"; the chain's start applied unmoved in {info['start_kept']}"
        parts.append(text)
    if "shield_decisions" in info:
        changed = info["shield_filtered"]
        text = f"safety filter: {info['shield_decisions']} decisions, {changed} changed for safety"
        if changed:
            kinds = [(info.get("shield_single_changes", 0), "one aircraft"),
                     (info.get("shield_joint_changes", 0), "all aircraft"),
                     (info.get("shield_sampled_changes", 0), "sampled"),
                     (info.get("shield_mpc_fallbacks", 0), "fallback policy")]
            text += " (" + ", ".join(f"{count} {what}" for count, what in kinds if count) + ")"
        if info.get("shield_unresolved"):
            text += f", {info['shield_unresolved']} applied although predicted unsafe"
        if info.get("shield_stalled_aircraft"):
            text += f", {info['shield_stalled_aircraft']} aircraft taken over by the progress rule"
        parts.append(text)
    return "; ".join(parts) if parts else None


def fly_table(
    result: EpisodeResult,
    policy: str,
    config: SimConfig,
    info: dict[str, Any],
    compile_s: float,
    *,
    wind_sigma_mps: float,
) -> str:
    """One episode: a line on what flew, a row per aircraft (home, flight time, path,
    closest approach, airspeed range) and the run's totals."""
    m = result.metrics
    head = (f"{policy} on {m.scenario}, seed {m.seed}, wind ({m.wind_kt[0]:+.1f}, {m.wind_kt[1]:+.1f}) kt "
            f"(σ {wind_sigma_mps:g} m/s)")
    if m.stream:
        # A stream: its flights share slots, so there is no row per aircraft; its metrics instead.
        lines = [head, format_stream(m.stream).replace("  ", "", 1),
                 f"min separation {_number(m.min_separation_nm)} nm, airspeed "
                 f"{_range(m.airspeed_min_kt, m.airspeed_max_kt)} kt, steps outside "
                 f"[{config.airspeed_min_kt:.0f}, {config.airspeed_max_kt:.0f}] kt: "
                 f"{round(m.envelope_violation_fraction * m.steps_flown)} of {m.steps_flown}"
                 + (f" (worst by {m.worst_excursion_kt:.0f} kt)" if m.envelope_violation_fraction else "")]
        decisions = result.decision_s
        timing = f"flew {m.sim_time_min:.1f} simulated min in {m.wall_s:.2f} s"
        if len(decisions):
            timing += (f"; {len(decisions)} decisions, {duration(float(np.median(decisions)))} median, "
                       f"{duration(float(decisions.max()))} max")
        lines.append(timing)
        policy_line = _policy_line(info)
        if policy_line:
            lines.append(policy_line)
        return "\n".join(lines)
    closest, low, high = per_aircraft(result)
    rows = [["aircraft", "home", "flight min", "path nm", "closest nm", "airspeed kt"]]
    for i in range(m.n_aircraft):
        home = "yes" if m.arrived[i] else ("left" if m.left_workspace[i] else "no")
        rows.append([str(i), home, _number(m.flight_time_min[i]), _number(m.path_length_nm[i], 0),
                     _number(float(closest[i])), _range(float(low[i]), float(high[i]))])
    arrived = sum(m.arrived)
    times = [t for t, a in zip(m.flight_time_min, m.arrived) if a]
    # The run's row: only what aggregates without a legend (a count, a least, a range).
    rows.append(["all", f"{arrived}/{m.n_aircraft}", "", "", _number(m.min_separation_nm),
                 _range(m.airspeed_min_kt, m.airspeed_max_kt)])
    lines = [head, *aligned(rows, [False, False, True, True, True, True])]
    if times:
        lines.append(f"mean flight time of the {len(times)} aircraft home: {np.mean(times):.1f} min")
    envelope = f"[{config.airspeed_min_kt:.0f}, {config.airspeed_max_kt:.0f}] kt"
    outside = round(m.envelope_violation_fraction * m.steps_flown)
    safety = (f"losses of separation (< {config.separation_min_nm:g} nm): {m.los_count}; "
              f"steps outside {envelope}: {outside} of {m.steps_flown}")
    if outside:
        safety += f" (worst by {m.worst_excursion_kt:.0f} kt)"
    lines.append(safety)
    if arrived < m.n_aircraft:
        lines.append("home: no = still flying at the time limit; left = left the workspace. flight min of an "
                     "aircraft not home is its time flown.")
    decisions = result.decision_s
    timing = f"flew {m.sim_time_min:.1f} simulated min in {m.wall_s:.2f} s"
    if len(decisions):
        timing += (f"; {len(decisions)} decisions, {duration(float(np.median(decisions)))} median, "
                   f"{duration(float(decisions.max()))} max")
    timing += f"; warm-up before it (compiling or loading the simulator, the policy's first call) {compile_s:.1f} s"
    lines.append(timing)
    policy_line = _policy_line(info)
    if policy_line:
        lines.append(policy_line)
    return "\n".join(lines)


def fly_summary(result: EpisodeResult, policy: str, info: dict[str, Any], compile_s: float) -> dict[str, Any]:
    """The JSON summary of one episode (``fly --summary-json``): the evaluator's summary
    of one run, its decision latencies, the filter's counts and the run's metrics."""
    summary = summarize([result.metrics], peak_rss_mb=peak_rss_mb(), compile_s=compile_s)
    summary["policy"] = policy
    if len(result.decision_s):
        summary["decision_s"].update(median=float(np.median(result.decision_s)),
                                     p99=float(np.percentile(result.decision_s, 99)),
                                     max=float(result.decision_s.max()))
    shield = summarize_interventions([info])
    if shield is not None:
        summary["shield"] = shield
    info = dict(info)
    if "fallbacks" in info:  # at the top level, as in evaluate's summary
        summary["fallbacks"] = info.pop("fallbacks")
    summary["policy_info"] = info
    summary["run"] = result.metrics.to_dict()
    return summary


def run_is_safe(record: dict[str, Any]) -> bool:
    """A run without a loss of separation and without an integration step outside the
    airspeed envelope."""
    return record["los_count"] == 0 and record["envelope_violation_fraction"] == 0


def evaluate_table(summary: dict[str, Any], records: list[dict[str, Any]], study: Any, *, first_seed: int) -> str:
    """A study: one aligned line per figure (runs, home, safe runs, flight time, minimum
    separation, airspeed range, decision time, the policy's counts)."""
    config = SimConfig.preset(study.physics)
    runs = summary["runs"]
    envelope = f"[{config.airspeed_min_kt:.0f}, {config.airspeed_max_kt:.0f}] kt"
    settings = "".join(f", {key.replace('_', ' ')} {value}" for key, value in study.policy_kwargs.items())
    head = (f"{study.policy}{'+shield' if study.shield else ''}{f' ({settings[2:]})' if settings else ''} on "
            f"{study.scenario}, wind σ "
            f"{study.wind_sigma_mps:g} m/s, seeds {first_seed}–{first_seed + runs - 1}")
    success = round(summary["success_rate"] * runs)
    ci = summary.get("success_rate_ci95")
    home = f"{success}/{runs}" + (f" (95 % interval {100 * ci[0]:.1f}–{100 * ci[1]:.1f} %)" if ci else "")
    safe = sum(run_is_safe(r) for r in records)
    flight = summary["flight_time_min"]
    separation = summary["min_separation_nm"]
    speed = summary["airspeed_kt"]
    decision = summary["decision_s"]
    decision_text = f"{duration(decision['mean'])} mean"
    if decision.get("p99") is not None:
        decision_text += f", {duration(decision['p99'])} p99"
    rows = [
        ["runs", str(runs)],
        ["every aircraft home", home],
        ["safe runs", f"{safe}/{len(records)} (no loss of separation, no step outside {envelope})"],
        ["flight time (arrived)", "no aircraft home" if flight["mean"] is None else
         f"{flight['mean']:.1f} min mean, {flight['max']:.1f} min max"],
        ["min separation", "no two aircraft flew together" if separation["min"] is None else
         f"{separation['min']:.1f} nm lowest run, {separation['mean']:.1f} nm mean"],
        ["airspeed range", f"{_range(speed['min'], speed['max'])} kt"],
        ["decision time", decision_text],
    ]
    stream = summary.get("stream")
    if stream is not None:
        # A stream's run is a success when no aircraft left the workspace (``metrics.run_metrics``).
        rows[1] = ["no aircraft lost", home]
        delay, entry = stream["delay_s"], stream["entry_delay_s"]
        rows += [
            ["flights", f"{stream['flights_completed']} completed of {stream['flights_entered']} entered "
                        f"({stream['entries_held']} entries held)"],
            ["throughput", f"{stream['throughput_per_hour']['mean']:.1f} flights/h mean"],
            ["delay vs direct", "none completed" if delay["mean"] is None else
             f"{delay['mean']:.0f} s mean, {delay['max']:.0f} s max"],
            ["entry delay", "none entered" if entry["mean"] is None else
             f"{entry['mean']:.0f} s mean, {entry['max']:.0f} s max"],
            ["LoS per flight hour", f"{stream['los_per_flight_hour']:.3f} ({stream['los_count']} in "
                                    f"{stream['flight_hours']:.0f} h)"],
            ["max airborne", str(stream["max_airborne"])],
        ]
    if "fallbacks" in summary:
        rows.append(["fallbacks", f"{summary['fallbacks']} of {summary['decisions']} decisions"])
    kept = [r.get("policy_info", {}).get("start_kept") for r in records]
    if records and all(k is not None for k in kept):
        decisions = sum(r["decisions"] for r in records)
        rows.append(["chain start kept", f"{sum(kept)} of {decisions} decisions applied the chain's start unmoved"])
    shield = summary.get("shield")
    if shield is not None:
        rows.append(["safety filter", f"{shield['filtered']} of {shield['decisions']} decisions changed, "
                                      f"{shield['mpc_fallbacks']} by the fallback policy"])
    return "\n".join([head, *("  " + line for line in aligned(rows, [False, False]))])


__all__ = ["airspeed_range_kt", "aligned", "closest_approach_nm", "duration", "evaluate_table", "fly_summary",
           "fly_table", "per_aircraft", "run_is_safe"]
