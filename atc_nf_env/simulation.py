"""One world stepped through the kernel, with the statistics metrics need.

``Simulation`` is the single-world (B = 1) face of the batched kernel that the
environments and the episode runner use; ``initial_state`` builds kernel states for
any batch size (the MPC's candidates start from copies of a world's state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.calibration import check_calibrated
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import (
    ABSENT,
    ARRIVED,
    FLYING,
    S_AIRSPEED,
    S_COS_D,
    S_SIN_D,
    S_DEST_HEADING,
    S_DEST_X,
    S_DEST_Y,
    S_HEADING,
    S_STATUS,
    S_THETA_D,
    S_THETA_NH,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
    S_FRESH,
    Trace,
)
from atc_nf_env.scenarios import Scenario, StreamScenario
from atc_nf_env.units import KT_PER_MPS, WIND_SIGMA_MPS


def initial_state(scenario: Scenario, n_worlds: int = 1, n_slots: int | None = None) -> np.ndarray:
    """Kernel state (n_worlds, n_slots, N_STATE) at t = 0; slots beyond the scenario's
    aircraft are ABSENT. Each aircraft's first waypoint is its destination. A traffic
    stream (``StreamScenario``) starts with every slot ABSENT: its flights enter later
    (``atc_nf_env.streams``)."""
    if isinstance(scenario, StreamScenario):
        return kernel.new_state(n_worlds, scenario.n_aircraft if n_slots is None else n_slots)
    n = scenario.n_aircraft
    n_slots = n if n_slots is None else n_slots
    if n_slots < n:
        raise ValueError(f"n_slots = {n_slots}: must be >= the scenario's {n} aircraft")
    state = kernel.new_state(n_worlds, n_slots)
    state[:, :n, S_X] = scenario.start_xy[:, 0]
    state[:, :n, S_Y] = scenario.start_xy[:, 1]
    state[:, :n, S_HEADING] = scenario.start_heading
    state[:, :n, S_THETA_NH] = scenario.start_heading
    state[:, :n, S_AIRSPEED] = scenario.start_airspeed_kt
    state[:, :n, S_DEST_X] = scenario.dest_xy[:, 0]
    state[:, :n, S_DEST_Y] = scenario.dest_xy[:, 1]
    state[:, :n, S_DEST_HEADING] = scenario.dest_heading
    state[:, :n, S_WP_X] = scenario.dest_xy[:, 0]
    state[:, :n, S_WP_Y] = scenario.dest_xy[:, 1]
    state[:, :n, S_THETA_D] = scenario.dest_heading
    state[:, :n, S_COS_D] = np.cos(scenario.dest_heading)
    state[:, :n, S_SIN_D] = np.sin(scenario.dest_heading)
    state[:, :n, S_FRESH] = 1.0
    state[:, :n, S_STATUS] = FLYING
    return state


#: Largest σ of the wind accepted, m/s: four times the NF's airspeed cap (772 m/s). Far
#: beyond any wind an aircraft makes headway in, and far below where a sample overflows.
WIND_SIGMA_MAX_MPS: float = 3000.0


def check_wind_sigma(sigma_mps: float) -> float:
    """``sigma_mps`` as a float, or a ValueError/TypeError naming ``wind_sigma``."""
    if isinstance(sigma_mps, bool) or not isinstance(sigma_mps, (int, float, np.integer, np.floating)):
        raise TypeError(f"wind_sigma = {sigma_mps!r}: must be a number of m/s")
    if not (math.isfinite(sigma_mps) and 0 <= sigma_mps <= WIND_SIGMA_MAX_MPS):
        raise ValueError(
            f"wind_sigma = {sigma_mps!r} m/s: must be a finite number in [0, {WIND_SIGMA_MAX_MPS:g}] m/s"
        )
    return float(sigma_mps) + 0.0  # -0.0 becomes 0.0 (numpy refuses a scale of -0.0)


def sample_wind_kt(rng: np.random.Generator, sigma_mps: float = WIND_SIGMA_MPS) -> np.ndarray:
    """A constant wind for one episode: each component N(0, σ²) (paper IV-A), returned in kt."""
    return rng.normal(0.0, check_wind_sigma(sigma_mps), size=2) * KT_PER_MPS


@dataclass(frozen=True)
class WorldView:
    """What a policy sees at a decision: the state of every aircraft, not the wind.

    ``state`` is a copy (N, N_STATE) in the kernel's layout (``atc_nf_env.kernel.S_*``).
    """

    time_s: float
    state: np.ndarray
    scenario: Scenario

    @property
    def positions(self) -> np.ndarray:
        """(N, 2) positions, nm."""
        return self.state[:, S_X : S_Y + 1]

    @property
    def headings(self) -> np.ndarray:
        """(N,) headings, rad."""
        return self.state[:, S_HEADING]

    @property
    def airspeeds(self) -> np.ndarray:
        """(N,) airspeeds of the last integration step, kt."""
        return self.state[:, S_AIRSPEED]

    @property
    def destinations(self) -> np.ndarray:
        """(N, 2) destinations, nm."""
        return self.state[:, S_DEST_X : S_DEST_Y + 1]

    @property
    def waypoints(self) -> np.ndarray:
        """(N, 2) current waypoints, nm."""
        return self.state[:, S_WP_X : S_WP_Y + 1]

    @property
    def flying(self) -> np.ndarray:
        """(N,) bool: still in the airspace."""
        return self.state[:, S_STATUS] == FLYING


@dataclass
class RunStats:
    """Statistics of one world accumulated over kernel calls (integration-step resolution)."""

    n_aircraft: int
    steps_flown: np.ndarray = field(init=False)
    violation_steps: np.ndarray = field(init=False)
    worst_excursion_kt: np.ndarray = field(init=False)
    min_airspeed_kt: np.ndarray = field(init=False)
    max_airspeed_kt: np.ndarray = field(init=False)
    los_pairs: np.ndarray = field(init=False)
    min_separation_nm: float = kernel.NO_PAIR_SEPARATION_NM

    def __post_init__(self) -> None:
        n = self.n_aircraft
        self.steps_flown = np.zeros(n, dtype=np.int64)
        self.violation_steps = np.zeros(n, dtype=np.int64)
        self.worst_excursion_kt = np.zeros(n)
        self.min_airspeed_kt = np.full(n, np.inf)
        self.max_airspeed_kt = np.full(n, -np.inf)
        self.los_pairs = np.zeros((n, n), dtype=bool)

    def add(self, trace: Trace, world: int = 0) -> None:
        n = self.n_aircraft
        flew = trace.steps_flown[world, :n] > 0
        self.steps_flown += trace.steps_flown[world, :n]
        self.violation_steps += trace.violation_steps[world, :n]
        self.worst_excursion_kt = np.maximum(self.worst_excursion_kt, trace.worst_excursion_kt[world, :n])
        self.min_airspeed_kt = np.where(
            flew, np.minimum(self.min_airspeed_kt, trace.min_airspeed_kt[world, :n]), self.min_airspeed_kt
        )
        self.max_airspeed_kt = np.where(
            flew, np.maximum(self.max_airspeed_kt, trace.max_airspeed_kt[world, :n]), self.max_airspeed_kt
        )
        self.los_pairs |= trace.los_pairs[world, :n, :n].astype(bool)
        self.min_separation_nm = min(self.min_separation_nm, float(trace.min_separation_nm[world]))


class Simulation:
    """One world of a scenario under a constant wind, advanced through the kernel.

    Args:
        scenario: the encounter.
        config: NF gains and integrator settings (the calibrated defaults if None).
        wind_kt: constant wind (east, north), kt. Hidden from policies.
        record_every: keep the state every this many integration steps for plots
            (0: keep nothing).
    """

    def __init__(
        self,
        scenario: Scenario,
        config: SimConfig | None = None,
        wind_kt: np.ndarray | tuple[float, float] = (0.0, 0.0),
        record_every: int = 0,
    ) -> None:
        self.scenario = scenario
        self.config = config or SimConfig()
        try:
            if np.iscomplexobj(wind_kt):
                raise TypeError("complex")
            wind = np.asarray(wind_kt, dtype=np.float64)
        except (TypeError, ValueError):
            wind = np.full(1, np.nan)  # refused just below, naming wind_kt
        if wind.shape != (2,) or not np.isfinite(wind).all():
            raise ValueError(f"wind_kt = {wind_kt!r}: must be two finite numbers (east, north) in kt")
        self.wind_kt = wind
        check_calibrated(self.config, scenario.workspace_radius_nm)
        self.params = self.config.to_params(scenario.workspace_radius_nm)
        self.record_every = record_every
        self.state = initial_state(scenario)
        self.time_s = 0.0
        self.stats = RunStats(scenario.n_aircraft)
        self.records: list[np.ndarray] = []
        self.record_times_s: list[np.ndarray] = []
        self._scratch = kernel.KernelScratch()

    @property
    def n_aircraft(self) -> int:
        return self.scenario.n_aircraft

    @property
    def status(self) -> np.ndarray:
        """(N,) status codes (kernel.FLYING, ARRIVED, LEFT)."""
        return self.state[0, :, S_STATUS]

    @property
    def done(self) -> bool:
        """Every aircraft has arrived or left."""
        return not bool((self.status == FLYING).any())

    def view(self) -> WorldView:
        return WorldView(time_s=self.time_s, state=self.state[0].copy(), scenario=self.scenario)

    def advance(self, waypoints: np.ndarray, seconds: float) -> Trace:
        """Fly ``seconds`` toward ``waypoints`` (N, 2) nm; returns the kernel's trace."""
        if np.iscomplexobj(waypoints):
            raise ValueError("waypoints are complex; expected real numbers (N, 2) in nm")
        waypoints = np.asarray(waypoints, dtype=np.float64)
        if waypoints.shape != (self.n_aircraft, 2):
            raise ValueError(
                f"waypoints has shape {waypoints.shape}; expected ({self.n_aircraft}, 2) in nm"
            )
        if not np.isfinite(waypoints).all():
            raise ValueError(f"waypoints contain NaN or inf: {waypoints.tolist()}; all must be finite")
        radius = np.hypot(waypoints[:, 0], waypoints[:, 1])
        limit = self.scenario.workspace_radius_nm - self.config.aircraft_radius_nm
        flying = self.status == FLYING
        outside = np.flatnonzero(flying & (radius >= limit))
        if outside.size:
            i = int(outside[0])
            raise ValueError(
                f"waypoint of aircraft {i} = {waypoints[i].tolist()} lies {radius[i]:.1f} nm from the "
                f"centre: must be within the workspace ({limit:.1f} nm)"
            )
        trace = kernel.advance(
            self.state,
            waypoints[None],
            self.wind_kt[None],
            seconds,
            self.params,
            record_every=self.record_every,
            scratch=self._scratch,
        )
        self.stats.add(trace)
        if self.record_every:
            steps = int(trace.steps_done[0])
            rows = steps // self.record_every + 1
            # The first row repeats the previous call's last one; keep it only once.
            start = 0 if not self.records else 1
            self.records.append(trace.record[0, start:rows])
            self.record_times_s.append(
                self.time_s + self.config.dt_s * self.record_every * np.arange(start, rows)
            )
        self.time_s += float(trace.steps_done[0]) * self.config.dt_s
        return trace

    def recording(self) -> tuple[np.ndarray, np.ndarray]:
        """(times (R,) s, records (R, N, N_RECORD)) kept so far."""
        if not self.records:
            return np.zeros(0), np.zeros((0, self.n_aircraft, kernel.N_RECORD))
        return np.concatenate(self.record_times_s), np.concatenate(self.records)


__all__ = [
    "ARRIVED",
    "ABSENT",
    "FLYING",
    "RunStats",
    "Simulation",
    "WorldView",
    "initial_state",
    "check_wind_sigma",
    "sample_wind_kt",
]
