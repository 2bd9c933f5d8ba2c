"""Traffic streams: a world whose aircraft enter and leave during the episode.

A ``StreamScenario`` (``atc_nf_env.scenarios.stream_scenario``) schedules flights over
time; ``StreamSimulation`` flies them through the same kernel as every encounter, in a
state of fixed size: ``max_airborne`` aircraft slots. What it relies on in the kernel:
only FLYING aircraft are integrated, are obstacles in each other's navigation function
and enter the separation checks; ABSENT, ARRIVED and LEFT slots are frozen and ignored.
So a slot is ABSENT until a flight enters it, is set FLYING at the entry, and is emptied
(ABSENT again) at the first decision instant after its flight arrived or left.

Entries happen at decision instants only (every ``advance`` ends at one), so every policy
sees an aircraft before it flies a step, and no aircraft enters behind a plan made
without it. A flight due at time t enters at the first decision instant >= t at which a
slot is free and no aircraft flies within ``entry_clearance_nm`` (20 nm by default) of its
entry point: it is never placed in a loss of separation. Its entry delay (s) is the time
from due to entry; a flight that had to wait beyond the first instant it was due at is
counted as held.

Units: nm, kt, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import (
    ABSENT,
    ARRIVED,
    FLYING,
    LEFT,
    S_AIRSPEED,
    S_COS_D,
    S_DEST_HEADING,
    S_DEST_X,
    S_DEST_Y,
    S_FRESH,
    S_HEADING,
    S_PATH,
    S_SIN_D,
    S_STATUS,
    S_THETA_D,
    S_THETA_NH,
    S_TIME,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
    Trace,
)
from atc_nf_env.scenarios import StreamScenario
from atc_nf_env.simulation import Simulation
from atc_nf_env.units import AIRSPEED_NOMINAL_KT, SECONDS_PER_HOUR

#: Flight states (``StreamSimulation.flight_state``).
WAITING, AIRBORNE, DONE_ARRIVED, DONE_LEFT = 0, 1, 2, 3


@dataclass
class FlightLog:
    """What happened to each flight of a stream (arrays over the M flights)."""

    n_flights: int
    state: np.ndarray = field(init=False)  # WAITING, AIRBORNE, DONE_ARRIVED, DONE_LEFT
    slot: np.ndarray = field(init=False)  # slot while airborne, -1 otherwise
    entered_s: np.ndarray = field(init=False)  # entry time, s (NaN: not entered)
    held: np.ndarray = field(init=False)  # waited beyond the first decision instant it was due at
    flight_time_s: np.ndarray = field(init=False)  # time flown, s
    path_nm: np.ndarray = field(init=False)  # ground path flown, nm
    steps_flown: np.ndarray = field(init=False)
    violation_steps: np.ndarray = field(init=False)
    worst_excursion_kt: np.ndarray = field(init=False)
    min_airspeed_kt: np.ndarray = field(init=False)
    max_airspeed_kt: np.ndarray = field(init=False)
    #: Pairs of flights (i < j) that came closer than the separation minimum.
    los_pairs: set[tuple[int, int]] = field(default_factory=set)

    def __post_init__(self) -> None:
        m = self.n_flights
        self.state = np.full(m, WAITING, dtype=np.int64)
        self.slot = np.full(m, -1, dtype=np.int64)
        self.entered_s = np.full(m, np.nan)
        self.held = np.zeros(m, dtype=bool)
        self.flight_time_s = np.zeros(m)
        self.path_nm = np.zeros(m)
        self.steps_flown = np.zeros(m, dtype=np.int64)
        self.violation_steps = np.zeros(m, dtype=np.int64)
        self.worst_excursion_kt = np.zeros(m)
        self.min_airspeed_kt = np.full(m, np.inf)
        self.max_airspeed_kt = np.full(m, -np.inf)


class StreamSimulation(Simulation):
    """One world of a traffic stream under a constant wind, advanced through the kernel.

    The state has ``scenario.max_airborne`` slots; ``slot_flight`` maps each slot to the
    flight in it (-1: empty), ``flights`` logs every flight. Arguments as ``Simulation``.
    """

    def __init__(
        self,
        scenario: StreamScenario,
        config: SimConfig | None = None,
        wind_kt: np.ndarray | tuple[float, float] = (0.0, 0.0),
        record_every: int = 0,
    ) -> None:
        if not isinstance(scenario, StreamScenario):
            raise TypeError(f"StreamSimulation needs a StreamScenario, got {type(scenario).__name__}")
        super().__init__(scenario, config=config, wind_kt=wind_kt, record_every=record_every)
        self.stream = scenario
        self.slot_flight = np.full(scenario.n_aircraft, -1, dtype=np.int64)
        self.flights = FlightLog(scenario.n_flights)
        self.max_airborne_seen = 0
        #: ``slot_flight`` after each decision instant's exits and entries, and its time
        #: (``slot_history``): which flight each recorded slot holds, for the animations.
        self._history_times_s: list[float] = []
        self._history: list[np.ndarray] = []
        self._admit()
        self._keep_history()

    @property
    def done(self) -> bool:
        """The stream's length has passed (a stream's episode always lasts its length, so
        that its throughput is counted over the same hours whatever the traffic did)."""
        return self.time_s >= self.stream.duration_s - 1e-9

    @property
    def airborne(self) -> int:
        """Aircraft flying now."""
        return int((self.status == FLYING).sum())

    def advance(self, waypoints: np.ndarray, seconds: float, next_decision: bool = True) -> Trace:
        """Fly ``seconds`` toward ``waypoints`` (slots, 2) nm; then, unless
        ``next_decision`` is False (the caller calls ``next_decision`` itself after reading
        the slots as flown), retire the flights that arrived or left and admit those due.
        The clock moves by ``seconds`` even when no aircraft flies (the kernel stops early
        then)."""
        start_s = self.time_s
        steps = kernel.steps_for(float(seconds), self.config.dt_s)
        occupant = self.slot_flight.copy()
        trace = super().advance(waypoints, seconds)
        self.time_s = start_s + steps * self.config.dt_s
        self._log_trace(trace, occupant)
        if next_decision:
            self.next_decision()
        return trace

    def next_decision(self) -> None:
        """Empty the slots of the flights that arrived or left, then let in those due."""
        self._retire()
        self._admit()
        self._keep_history()

    def _keep_history(self) -> None:
        self._history_times_s.append(self.time_s)
        self._history.append(self.slot_flight.copy())

    def slot_history(self) -> tuple[np.ndarray, np.ndarray]:
        """(times (K,) s, slot_flight (K, N)): row k is the flight in each slot (-1:
        empty) from decision instant ``times[k]`` on (after its exits and entries) until
        the next; a state recorded at a decision instant itself is the one before them."""
        return np.array(self._history_times_s), np.array(self._history, dtype=np.int64).reshape(-1, self.n_aircraft)

    # -- bookkeeping ----------------------------------------------------------------
    def _log_trace(self, trace: Trace, occupant: np.ndarray) -> None:
        log = self.flights
        for slot in np.flatnonzero(occupant >= 0):
            f = occupant[slot]
            flown = int(trace.steps_flown[0, slot])
            if flown == 0:
                continue
            log.steps_flown[f] += flown
            log.violation_steps[f] += int(trace.violation_steps[0, slot])
            log.worst_excursion_kt[f] = max(log.worst_excursion_kt[f], float(trace.worst_excursion_kt[0, slot]))
            log.min_airspeed_kt[f] = min(log.min_airspeed_kt[f], float(trace.min_airspeed_kt[0, slot]))
            log.max_airspeed_kt[f] = max(log.max_airspeed_kt[f], float(trace.max_airspeed_kt[0, slot]))
        close = np.argwhere(np.triu(trace.los_pairs[0], 1) != 0)
        for a, b in close:
            fa, fb = int(occupant[a]), int(occupant[b])
            if fa >= 0 and fb >= 0:
                log.los_pairs.add((min(fa, fb), max(fa, fb)))

    def _retire(self) -> None:
        """Empty the slots whose flight arrived or left; log its flight."""
        state = self.state[0]
        for slot in np.flatnonzero(self.slot_flight >= 0):
            status = state[slot, S_STATUS]
            if status == FLYING:
                continue
            f = int(self.slot_flight[slot])
            self._copy_flight(slot, f)
            self.flights.state[f] = DONE_ARRIVED if status == ARRIVED else DONE_LEFT
            self.flights.slot[f] = -1
            self.slot_flight[slot] = -1
            state[slot, :] = 0.0
            state[slot, S_STATUS] = ABSENT

    def _copy_flight(self, slot: int, f: int) -> None:
        self.flights.flight_time_s[f] = self.state[0, slot, S_TIME]
        self.flights.path_nm[f] = self.state[0, slot, S_PATH]

    def sync_airborne(self) -> None:
        """Copy the flight time and path of the flights still airborne into ``flights``."""
        for slot in np.flatnonzero(self.slot_flight >= 0):
            self._copy_flight(slot, int(self.slot_flight[slot]))

    def _admit(self) -> None:
        """Let in the flights due by now, in the order they are due, where a slot is free
        and the entry point is clear."""
        stream = self.stream
        if self.time_s >= stream.duration_s - 1e-9:
            return
        log = self.flights
        now = self.time_s + 1e-9
        due_now = int(np.searchsorted(stream.entry_time_s, now, side="right"))
        state = self.state[0]
        clearance2 = stream.entry_clearance_nm**2
        for f in range(due_now):
            if log.state[f] != WAITING:
                continue
            free = np.flatnonzero(state[:, S_STATUS] != FLYING)
            entry = stream.start_xy[f]
            flying = state[:, S_STATUS] == FLYING
            gaps2 = ((state[flying, S_X] - entry[0]) ** 2 + (state[flying, S_Y] - entry[1]) ** 2)
            if free.size == 0 or (gaps2.size and gaps2.min() < clearance2):
                log.held[f] = True  # waits for the next decision instant
                continue
            self._place(int(free[0]), f)
        self.max_airborne_seen = max(self.max_airborne_seen, self.airborne)

    def _place(self, slot: int, f: int) -> None:
        """Put flight ``f`` into the empty ``slot``: at its entry point, heading along the
        line to its destination at the scenario's start airspeed, first waypoint its
        destination (the same fields as ``simulation.initial_state``)."""
        s = self.stream
        row = self.state[0, slot]
        row[:] = 0.0
        row[S_X], row[S_Y] = s.start_xy[f]
        row[S_HEADING] = s.start_heading[f]
        row[S_THETA_NH] = s.start_heading[f]
        row[S_AIRSPEED] = s.start_airspeed_kt
        row[S_DEST_X], row[S_DEST_Y] = s.dest_xy[f]
        row[S_DEST_HEADING] = s.dest_heading[f]
        row[S_WP_X], row[S_WP_Y] = s.dest_xy[f]
        row[S_THETA_D] = s.dest_heading[f]
        row[S_COS_D] = math.cos(s.dest_heading[f])
        row[S_SIN_D] = math.sin(s.dest_heading[f])
        row[S_FRESH] = 1.0
        row[S_STATUS] = FLYING
        self.slot_flight[slot] = f
        self.flights.state[f] = AIRBORNE
        self.flights.slot[f] = slot
        self.flights.entered_s[f] = self.time_s

    # -- metrics --------------------------------------------------------------------
    def stream_metrics(self) -> dict[str, Any]:
        """The stream's metrics so far (see ``atc_nf_env.metrics.STREAM_METRIC_NOTES``)."""
        self.sync_airborne()
        s = self.stream
        log = self.flights
        hours = self.time_s / SECONDS_PER_HOUR
        entered = np.isfinite(log.entered_s)
        arrived = log.state == DONE_ARRIVED
        direct_s = np.hypot(*(s.dest_xy - s.start_xy).T) / AIRSPEED_NOMINAL_KT * SECONDS_PER_HOUR
        delay = (log.flight_time_s - direct_s)[arrived]
        entry_delay = (log.entered_s - s.entry_time_s)[entered]
        due = s.entry_time_s <= self.time_s + 1e-9
        flight_hours = float(log.flight_time_s[entered].sum()) / SECONDS_PER_HOUR
        los = len(log.los_pairs)
        return {
            "rate_per_hour": s.rate_per_hour,
            "sector_radius_nm": s.sector_radius_nm,
            "duration_min": s.duration_s / 60.0,
            "max_airborne_slots": int(s.max_airborne),
            "flights_scheduled": int(s.n_flights),
            "flights_due": int(due.sum()),
            "flights_entered": int(entered.sum()),
            "flights_completed": int(arrived.sum()),
            "flights_left_workspace": int((log.state == DONE_LEFT).sum()),
            "airborne_at_end": int((log.state == AIRBORNE).sum()),
            "waiting_at_end": int((due & (log.state == WAITING)).sum()),
            "entries_held": int(log.held.sum()),
            "throughput_per_hour": float(arrived.sum()) / hours if hours > 0 else 0.0,
            "delay_s": _mean_max(delay),
            "entry_delay_s": _mean_max(entry_delay),
            "flight_hours": flight_hours,
            "los_count": los,
            "los_per_flight_hour": los / flight_hours if flight_hours > 0 else 0.0,
            "max_airborne": int(self.max_airborne_seen),
        }


def _mean_max(values: np.ndarray) -> dict[str, float | None]:
    if values.size == 0:
        return {"mean": None, "max": None}
    return {"mean": float(values.mean()), "max": float(values.max())}


def make_simulation(scenario: Any, **kwargs: Any) -> Simulation:
    """A ``StreamSimulation`` for a stream, a ``Simulation`` for any other scenario."""
    if isinstance(scenario, StreamScenario):
        return StreamSimulation(scenario, **kwargs)
    return Simulation(scenario, **kwargs)


__all__ = ["FlightLog", "StreamSimulation", "make_simulation", "WAITING", "AIRBORNE", "DONE_ARRIVED", "DONE_LEFT",
           "LEFT"]
