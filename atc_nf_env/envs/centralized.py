"""The centralized Gymnasium environment ``atc_nf_env/Encounter-v1`` and the one-world
episode logic (``EncounterWorld``) that it shares with the PettingZoo env."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numba import njit

from atc_nf_env import kernel
from atc_nf_env.envs import EnvConfig, ScenarioSource, draw_episode_seed, episode_wind
from atc_nf_env.envs.actions import WORKSPACE_MARGIN_NM, _waypoints_from_state, nonfinite_actions
from atc_nf_env.envs.observations import ObservationSpec, _observe
from atc_nf_env.envs.rewards import aircraft_reward, reward_weight_vector
from atc_nf_env.kernel import (
    ARRIVED,
    FLYING,
    LEFT,
    NO_PAIR_SEPARATION_NM,
    S_AIRSPEED,
    S_DEST_X,
    S_DEST_Y,
    S_STATUS,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
    KernelScratch,
)
from atc_nf_env.nf import P_DT
from atc_nf_env.scenarios import check_seed
from atc_nf_env.simulation import Simulation
from atc_nf_env.units import DECISION_PERIOD_S
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: CPU time of the compiled period's first compilation on an idle core, s (its first step
#: says so when numba's cache does not hold it: ``kernel.compile_notice``).
FIRST_PERIOD_COMPILE_S = 16

#: Integration steps between recorded states when rendering (trails), at dt = 5 s: 30 s.
RENDER_RECORD_EVERY: int = 6


#: Per-aircraft info keys of every env, in order (the same at reset and at every step).
AIRCRAFT_INFO_KEYS: tuple[str, ...] = (
    "airspeed_kt",
    "airspeed_min_kt",
    "airspeed_max_kt",
    "distance_to_go_nm",
    "nearest_nm",
    "los_count",
    "envelope_violation",
    "envelope_violation_fraction",
    "action_clipped",
    "arrived",
    "left_workspace",
    "aircraft_reward",
    "waypoint_nm",
)
#: The scalar per-aircraft infos as one record per aircraft: ``tolist()`` gives each
#: aircraft's values as Python floats, ints and bools in one call.
INFO_RECORD = np.dtype(
    [
        ("airspeed_kt", "f8"),
        ("airspeed_min_kt", "f8"),
        ("airspeed_max_kt", "f8"),
        ("distance_to_go_nm", "f8"),
        ("nearest_nm", "f8"),
        ("los_count", "i8"),
        ("envelope_violation", "?"),
        ("envelope_violation_fraction", "f8"),
        ("action_clipped", "?"),
        ("arrived", "?"),
        ("left_workspace", "?"),
        ("aircraft_reward", "f8"),
    ]
)
assert INFO_RECORD.names == AIRCRAFT_INFO_KEYS[:-1]


@njit(cache=True, error_model="numpy")
def _world_after_period(
    state: np.ndarray,
    actions: np.ndarray,
    flying_before: np.ndarray,
    distance_before: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    weights: np.ndarray,
    obs_args: np.ndarray,
    wind: np.ndarray,
    n_neighbours: int,
    expose_wind: bool,
    scales: np.ndarray,
    obs: np.ndarray,
    nearest: np.ndarray,
    info: np.ndarray,
    distance_after: np.ndarray,
    flying_after: np.ndarray,
) -> None:
    """Everything a single-world env reports after ``kernel.advance`` flew one period, in
    one call: the rewards (``rewards.aircraft_reward``) and per-aircraft infos, the observations and nearest distances.
    state (1, n, N_STATE); the trace's arrays as ``advance`` returned them (1, n) and
    (1, n, n); actions and per-aircraft arrays (n,); obs (1, n_slots, D); nearest
    (1, n_slots)."""
    _observe(state, obs_args, wind, n_neighbours, expose_wind, scales, obs, nearest)
    n = flying_before.shape[0]
    for i in range(n):
        x = state[0, i, S_X]
        y = state[0, i, S_Y]
        after = math.hypot(state[0, i, S_DEST_X] - x, state[0, i, S_DEST_Y] - y)
        distance_after[i] = after
        flew = flying_before[i]
        status = state[0, i, S_STATUS]
        flying_after[i] = status == FLYING
        arrived = status == ARRIVED
        left = status == LEFT
        share = violation_steps[0, i] / max(steps_flown[0, i], 1)
        count = 0
        for j in range(n):
            count += los_pairs[0, i, j]
        gain = (distance_before[i] - after) * (1.0 if flew else 0.0)
        record = info[i]
        record["airspeed_kt"] = state[0, i, S_AIRSPEED]
        record["airspeed_min_kt"] = min_airspeed[0, i]
        record["airspeed_max_kt"] = max_airspeed[0, i]
        record["distance_to_go_nm"] = after
        record["nearest_nm"] = nearest[0, i]
        record["los_count"] = count
        record["envelope_violation"] = violation_steps[0, i] > 0
        record["envelope_violation_fraction"] = share
        record["action_clipped"] = flew and (
            actions[i, 0] < -1.0 or actions[i, 0] > 1.0 or actions[i, 1] < -1.0 or actions[i, 1] > 1.0
        )
        record["arrived"] = arrived
        record["left_workspace"] = left
        record["aircraft_reward"] = aircraft_reward(weights, gain, share, count, flew and arrived, flew and left)


@njit(cache=True, error_model="numpy")
def _fly_world_period(
    actions: np.ndarray,
    state: np.ndarray,
    distance_nm: float,
    span_nm: float,
    angle_span_rad: float,
    limit_nm: float,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    flying_before: np.ndarray,
    distance_before: np.ndarray,
    weights: np.ndarray,
    obs_args: np.ndarray,
    n_neighbours: int,
    expose_wind: bool,
    scales: np.ndarray,
    nearest: np.ndarray,
    distance_after: np.ndarray,
    flying_after: np.ndarray,
    waypoints: np.ndarray,
    obs: np.ndarray,
    info: np.ndarray,
    time_s: float,
    limit_s: float,
) -> int:
    """One decision period of a single-world env in one compiled call: the actions (n, 2)
    mapped to ``waypoints`` (1, n, 2) nm, the flight (``kernel.advance``'s compiled part,
    the same code, so the same bits as ``advance`` and ``run_episode``), the episode's
    time fraction after it into ``obs_args[0]`` (``time_s`` at the start of the period
    and the time limit ``limit_s``, s) and ``_world_after_period``. Returns ``advance``'s outcome code; on anything but a finished
    flight nothing after the flight is written (the caller raises as ``advance`` does).

    Why one call: every call of a compiled function from Python pays about 0.2 µs per
    argument to type and unpack it, and ``advance``'s Python checks and ``Trace`` cost
    more; three calls and that glue took about a fifth of a converging-4 env step."""
    _waypoints_from_state(actions.reshape((1, actions.shape[0], 2)), state, distance_nm, span_nm, angle_span_rad,
                          limit_nm, waypoints)
    # ``kernel.advance``'s checks and one-world flight, inlined here: the kernel's entries
    # are chosen in Python, and this whole period is one compiled call.
    if not (kernel._all_finite(params) and kernel._all_finite(state) and kernel._all_finite(waypoints)
            and kernel._all_finite(wind)):
        return kernel._BAD_INPUT
    for index in kernel._POSITIVE_INDEX:
        if not params[index] > 0.0:
            return kernel._BAD_INPUT
    kernel._advance_one(
        0, state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed, max_airspeed,
        violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done, violated, record, 1,
    )
    outcome = kernel._DONE if kernel._all_finite(state) else kernel._NON_FINITE_RESULT
    if outcome == kernel._DONE:
        obs_args[0] = min(1.0, (time_s + steps_done[0] * params[P_DT]) / limit_s)
        _world_after_period(
            state, actions, flying_before, distance_before, min_airspeed, max_airspeed, violation_steps, steps_flown,
            los_pairs, weights, obs_args, wind, n_neighbours, expose_wind, scales, obs, nearest, info,
            distance_after, flying_after,
        )
    return outcome


@njit(cache=True)
def all_finite(values: np.ndarray) -> bool:
    """Whether every value of a float64 array is finite (one compiled pass: numpy's
    ``isfinite(...).all()`` costs several times more on the envs' few actions)."""
    for value in values.flat:
        if not math.isfinite(value):
            return False
    return True


class EncounterWorld:
    """One world (B = 1) of an environment: a ``Simulation`` flown one decision period
    (T = 300 s) per step, with the episode's bookkeeping (seed, time limit, rewards).

    Used by the centralized Gymnasium env and the PettingZoo env; the vector env runs the
    same logic over B worlds in one kernel call (``atc_nf_env.envs.vector``). Without a
    render mode the world flies a period in one compiled call (``_fly_world_period``:
    the action mapping, the kernel's one-world flight and the step's observations,
    rewards and infos; ``Simulation.stats`` is then not kept: the infos carry the same
    figures step by step).
    """

    def __init__(self, cfg: EnvConfig, where: str) -> None:
        self.cfg = cfg
        self.source = ScenarioSource(cfg.scenario)
        self.n_aircraft: int = self.source.n_aircraft
        self.n_slots = self.source.slots(cfg.max_aircraft, where)
        self.obs_spec = ObservationSpec.for_config(cfg.config, cfg.n_neighbours, cfg.expose_wind)
        self.record_every = RENDER_RECORD_EVERY if cfg.render_mode is not None else 0
        self.sim: Simulation | None = None
        self.episode_seed: int = -1
        self.decisions = 0
        self.max_decisions = cfg.max_decisions
        self._limit_s = self.max_decisions * DECISION_PERIOD_S
        self._reward_weights = reward_weight_vector(cfg.reward_weights)
        self._scratch = KernelScratch()
        self._dt_s = float(cfg.config.dt_s)
        self._period_steps = kernel.steps_for(DECISION_PERIOD_S, self._dt_s)
        # The compiled period's buffers, kept for the world's life: the kernel's scratch and
        # a trace of its own (read by ``_world_after_period`` within the same call).
        self._grad, self._command, self._aircraft_lanes = self._scratch.get(1, self.source.n_aircraft)
        self._trace = KernelScratch().trace(1, self.source.n_aircraft, 0)
        mapping = cfg.action_mapping
        self._mapping = (
            float(mapping.distance_nm),
            float(mapping.distance_span_nm),
            math.radians(mapping.angle_span_deg),
            self.source.workspace_radius_nm - cfg.config.aircraft_radius_nm - WORKSPACE_MARGIN_NM,
        )
        self._obs_dim = self.obs_spec.dim
        self._scales = self.obs_spec._scales
        n = self.n_aircraft
        self.last_waypoints = np.zeros((n, 2))
        self.min_separation_nm = np.inf
        self.info = np.zeros(n, dtype=INFO_RECORD)
        self._time_fraction = np.zeros(1)  # the observations' argument, refilled every step
        self._n_neighbours = int(cfg.n_neighbours)
        self._expose_wind = bool(cfg.expose_wind)
        self._nearest_buffer = np.empty((1, self.n_slots))  # read by the compiled step only
        self._start: SimpleNamespace | None = None
        self._compile_checked = False  # whether the compile notice was considered for this world
        self.flying = np.zeros(n, dtype=np.bool_)

    # ----------------------------------------------------------------- episode

    def reset(self, episode_seed: int) -> None:
        wind = episode_wind(episode_seed, self.cfg.wind_sigma)
        start = self._start
        if start is None or self.source.random_n is not None or self.record_every:
            scenario = self.source.scenario(episode_seed)
            self.sim = Simulation(scenario, config=self.cfg.config, wind_kt=wind, record_every=self.record_every)
            start = self._start = self._start_of_episode(self.sim.state)
        else:
            # The same scenario, no recording: the world's Simulation starts again from the
            # same initial state (what a new one would hold, minus its construction).
            sim = self.sim
            assert sim is not None
            sim.state[:] = start.state
            sim.time_s = 0.0
            sim.wind_kt = wind
        self._wind = wind[None].copy()
        self.episode_seed = int(episode_seed)
        self.decisions = 0
        self._time_fraction[0] = 0.0
        # Fresh copies of what is handed out or updated in place later.
        self.last_waypoints = start.waypoints.copy()
        self.flying = start.flying.copy()
        self._flying_spare = np.empty_like(self.flying)
        self._distance = start.distance.copy()
        self._distance_spare = np.empty_like(self._distance)
        if self.cfg.expose_wind:  # the observations carry the episode's wind
            obs, _ = self.obs_spec.observe_with_nearest(start.state, self._time_fraction, self._wind, self.n_slots)
            self._obs = obs[0]
        else:
            self._obs = start.obs.copy()
        self.info = start.info.copy()
        self.min_separation_nm = start.min_separation_nm

    def _start_of_episode(self, state: np.ndarray) -> SimpleNamespace:
        """What a reset reports about the initial ``state`` (kept while the scenario stays):
        the state, waypoints, flying mask, distances to go, observations (without the
        wind) and the neutral infos: nothing clipped, violated or lost, reward 0, the
        airspeed range and the separation those of the initial state."""
        n = self.n_aircraft
        status = state[0, :, S_STATUS]
        flying = status == FLYING
        distance = np.hypot(state[0, :, S_DEST_X] - state[0, :, S_X], state[0, :, S_DEST_Y] - state[0, :, S_Y])
        obs, nearest = self.obs_spec.observe_with_nearest(state, np.zeros(1), np.zeros((1, 2)), self.n_slots)
        nearest_nm = nearest[0, :n]
        info = np.zeros(n, dtype=INFO_RECORD)
        airspeed = state[0, :, S_AIRSPEED]
        info["airspeed_kt"] = airspeed
        info["airspeed_min_kt"] = airspeed
        info["airspeed_max_kt"] = airspeed
        info["distance_to_go_nm"] = distance
        info["nearest_nm"] = nearest_nm
        info["arrived"] = status == ARRIVED
        info["left_workspace"] = status == LEFT
        nearest_flying = nearest_nm[flying]
        return SimpleNamespace(
            state=state.copy(),
            waypoints=state[0, :, [S_WP_X, S_WP_Y]].T.copy(),
            flying=flying,
            distance=distance,
            obs=obs[0],
            info=info,
            min_separation_nm=float(nearest_flying.min()) if nearest_flying.size else np.inf,
        )

    @property
    def started(self) -> bool:
        return self.sim is not None

    @property
    def time_fraction(self) -> float:
        assert self.sim is not None
        return min(1.0, self.sim.time_s / self._limit_s)

    @property
    def truncated(self) -> bool:
        """The time limit has been reached."""
        return self.decisions >= self.max_decisions

    @property
    def done(self) -> bool:
        """Every aircraft has arrived or left."""
        return not self.flying.any()

    @property
    def over(self) -> bool:
        """Every aircraft has arrived or left, or the time limit has been reached."""
        return self.sim is not None and (self.done or self.truncated)

    def observe(self) -> np.ndarray:
        """(n_slots, obs_dim) float32 (a fresh array after every reset and step)."""
        return self._obs

    def global_state(self) -> np.ndarray:
        assert self.sim is not None
        return self.obs_spec.global_state(
            self.sim.state, np.array([self.time_fraction]), self._wind, self.n_slots
        )[0]

    def step(self, actions: np.ndarray) -> None:
        """Fly one decision period with finite actions (n, 2) float64 (clipped to [-1, 1]
        here; rows of aircraft not flying are ignored). Afterwards ``rewards`` (n,),
        ``info`` (n,) ``INFO_RECORD``, ``min_separation_nm``, ``last_waypoints``,
        ``flying`` and the observations describe the step. The observations, ``info`` and
        ``last_waypoints`` are fresh arrays every step (the envs hand out views of them);
        ``flying`` and the distances to go alternate between two buffers of the world's
        own (read them, or copy them, before the next step).

        Raises:
            ValueError: the flight's inputs hold a NaN or inf (as ``kernel.advance``).
            FloatingPointError: the flight produced a NaN or inf (as ``kernel.advance``).
        """
        sim = self.sim
        assert sim is not None
        state = sim.state
        n = self.n_aircraft
        waypoints = np.empty((1, n, 2))
        if self.record_every:
            distance_nm, span_nm, angle_span_rad, limit_nm = self._mapping
            _waypoints_from_state(actions.reshape(1, n, 2), state, distance_nm, span_nm, angle_span_rad, limit_nm,
                                  waypoints)
            trace = sim.advance(waypoints[0], DECISION_PERIOD_S)
            self._time_fraction[0] = min(1.0, sim.time_s / self._limit_s)
            self._after_period(actions, waypoints, trace)
            return
        trace = self._trace
        obs = np.empty((1, self.n_slots, self._obs_dim), dtype=np.float32)
        info = np.empty(n, dtype=INFO_RECORD)
        distance, self._distance_spare = self._distance_spare, self._distance
        flying, self._flying_spare = self._flying_spare, self.flying
        arguments = (
            actions, state, *self._mapping, self._wind, self._period_steps, sim.params, self._grad, self._command,
            self._aircraft_lanes,
            trace.min_airspeed_kt, trace.max_airspeed_kt, trace.violation_steps, trace.worst_excursion_kt,
            trace.steps_flown, trace.los_pairs, trace.min_separation_nm, trace.steps_done, trace.violated,
            trace.record, self._flying_spare,
            self._distance_spare, self._reward_weights, self._time_fraction, self._n_neighbours, self._expose_wind,
            self._scales, self._nearest_buffer, distance, flying, waypoints, obs, info, sim.time_s, self._limit_s,
        )
        if not self._compile_checked:  # the kernel's one-world path compiled into this period's call
            kernel.compile_notice(_fly_world_period, arguments, FIRST_PERIOD_COMPILE_S)
            self._compile_checked = True
        outcome = _fly_world_period(*arguments)
        if outcome != kernel._DONE:
            # Put the buffers back as they were, then raise as ``advance`` would.
            self._distance_spare, self._flying_spare = distance, flying
            if outcome == kernel._NON_FINITE_RESULT:
                kernel._check_finite_result(state)
            kernel._check_inputs(state, waypoints, self._wind, DECISION_PERIOD_S, sim.params, 0)
            raise AssertionError(f"the compiled period returned {outcome}, and the Python checks found nothing")
        sim.time_s += trace.steps_done.item() * self._dt_s
        self.decisions += 1
        self.last_waypoints = waypoints[0]
        self._obs = obs[0]
        self.info = info
        self._distance = distance
        self.flying = flying
        self._note_separation(trace)

    def _after_period(self, actions: np.ndarray, waypoints: np.ndarray, trace: kernel.Trace) -> None:
        """``step``'s bookkeeping after a recorded flight (``Simulation.advance``, for the
        renderer's trails)."""
        n = self.n_aircraft
        self.decisions += 1
        self.last_waypoints = waypoints[0]
        obs = np.empty((1, self.n_slots, self._obs_dim), dtype=np.float32)
        info = np.empty(n, dtype=INFO_RECORD)
        distance, self._distance_spare = self._distance_spare, self._distance
        flying, self._flying_spare = self._flying_spare, self.flying
        _world_after_period(
            self.sim.state, actions, self._flying_spare, self._distance_spare,  # type: ignore[union-attr]
            trace.min_airspeed_kt, trace.max_airspeed_kt, trace.violation_steps, trace.steps_flown,
            trace.los_pairs, self._reward_weights, self._time_fraction, self._wind,
            self._n_neighbours, self._expose_wind, self._scales, obs, self._nearest_buffer, info, distance, flying,
        )
        self._obs = obs[0]
        self.info = info
        self._distance = distance
        self.flying = flying
        self._note_separation(trace)

    def _note_separation(self, trace: kernel.Trace) -> None:
        min_sep = trace.min_separation_nm.item()
        self.min_separation_nm = np.inf if min_sep >= NO_PAIR_SEPARATION_NM else min_sep

    @property
    def rewards(self) -> np.ndarray:
        """(n,) each aircraft's reward for the last step (0 after a reset)."""
        return self.info["aircraft_reward"]

    # ----------------------------------------------------------------- infos

    def info_arrays(self) -> tuple[dict[str, np.ndarray], float]:
        """Per-aircraft arrays (n,) (``waypoint_nm`` (n, 2)) keyed by ``AIRCRAFT_INFO_KEYS``,
        and the smallest separation, nm, describing the last step; after a reset the same
        keys, shapes and dtypes with neutral values (nothing clipped, violated or lost; the
        airspeed range and the separation those of the initial state; reward 0)."""
        arrays = {key: self.info[key] for key in INFO_RECORD.names}
        arrays["waypoint_nm"] = self.last_waypoints
        return arrays, self.min_separation_nm


def validate_step_actions(action: Any, shape: tuple[int, ...], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Float64 actions of the expected shape, clipped, and the clipped mask (shape[:-1]).

    Raises:
        ValueError: wrong shape, not numbers, NaN or inf; the message says what is allowed.
    """
    try:
        if np.iscomplexobj(action):  # float64 would silently drop the imaginary part
            raise TypeError("complex numbers")
        array = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"{where}: action {action!r} is not an array of numbers ({error}); expected shape {shape} in [-1, 1]"
        ) from None
    if array.shape != shape:
        raise ValueError(
            f"{where}: action has shape {array.shape}; expected {shape} (per aircraft: "
            "[distance, angle] in [-1, 1])"
        )
    bad = nonfinite_actions(array)
    if bad is not None:
        raise ValueError(
            f"{where}: action contains NaN or inf: {bad}; allowed: finite numbers in [-1, 1] "
            "(values outside are clipped)"
        )
    clipped = np.clip(array, -1.0, 1.0)
    return clipped, (clipped != array).any(axis=-1)


class EncounterEnv(gym.Env[np.ndarray, np.ndarray]):
    """## Description

    The paper's air-traffic encounter as one centralized agent: ``n`` aircraft fly under
    their decentralized dipolar navigation functions (NF) with a hidden constant wind,
    and every T = 5 min the agent chooses each aircraft's intermediate waypoint (Roussos,
    Chaloulos, Kyriakopoulos, Lygeros, CDC 2008). One ``step`` flies one 300 s decision
    period through the batched kernel (Adams-Bashforth 2, dt = 5 s). Units: nm, kt, s.

    ## Action Space

    ``Box(-1, 1, (M, 2), float32)`` with M = ``max_aircraft`` slots: per aircraft
    [distance, angle], mapped to a waypoint at ``100 + 40·a[0]`` nm and ``90°·a[1]``
    off the bearing to its destination (``ActionMapping``; ``atc_nf_env.envs.actions``
    converts to and from absolute waypoints). Values outside [-1, 1] are clipped and
    ``info["action_clipped"]`` says which; rows of padding slots and of aircraft no
    longer flying are ignored.

    ## Observation Space

    ``Box((M · D,), float32)``: the M aircraft's ego-centric observations
    (``atc_nf_env.envs.observations``; D = 8 + 5 K, + 2 with ``expose_wind``)
    concatenated in slot order. Slot ``i``'s entry 0 is 1 while aircraft ``i`` flies;
    padding slots are zeros.

    ## Rewards

    The sum over aircraft of the per-aircraft reward (``atc_nf_env.envs.rewards``):
    progress (1 per 100 nm of distance to go flown off), minus 1 × the fraction of
    integration steps outside the airspeed envelope [366, 540] kt, minus 5 per loss of
    separation (< 5 nm) involving the aircraft, plus 5 on arrival. Weights via
    ``reward_weights``.

    ## Starting State

    The scenario's aircraft at their starts (the paper's encounter: evenly spaced on a
    250 nm circle, heading for the centre, bound for the opposite point), first waypoint
    at the destination, and a wind drawn per episode (each component N(0, σ²), σ = 5.17
    m/s): ``reset(seed=s)`` flies episode seed ``s`` (the same wind, and for ``random-N``
    the same encounter, as ``run_episode(..., seed=s)`` and ``atc-nf fly --seed s``);
    later resets draw episode seeds from the env's generator.

    ## Episode End

    Terminated when every aircraft has arrived (within Δ =
    ``SimConfig.arrival_tolerance_nm`` of its destination, checked at every integration
    step) or left the workspace. Truncated after ``max_cycles`` decisions, or
    ceil(``max_episode_minutes`` / 5) (default None: 180 min, 36 steps). Stepping after the end raises ValueError
    (call ``reset``).

    ## Arguments

    ``gym.make("atc_nf_env/Encounter-v1", scenario="converging-4", wind_sigma=5.17,
    render_mode=None, max_aircraft=None, n_neighbours=4, max_episode_minutes=None,
    max_cycles=None, expose_wind=False, action_mapping=None, reward_weights=None,
    config=None, render_size_px=512)``; see ``atc_nf_env.envs`` for each. Unknown
    arguments raise TypeError listing the allowed ones. ``gym.make_vec(..., num_envs=B)`` builds the
    native vector env (B worlds in one kernel call).

    ## Info

    The same keys, shapes and dtypes after ``reset`` and after every ``step`` (neutral
    values at reset: nothing clipped or violated, reward 0, the airspeed range and the
    separation those of the initial state). Per-aircraft arrays (M,): ``airspeed_kt``
    (last integration step), ``airspeed_min_kt``, ``airspeed_max_kt`` (over the step),
    ``distance_to_go_nm``, ``nearest_nm`` (to the nearest aircraft still flying),
    ``los_count``, ``envelope_violation``, ``envelope_violation_fraction``,
    ``action_clipped``, ``arrived``, ``left_workspace``, ``aircraft_reward`` (each
    aircraft's share of the reward), ``waypoint_nm`` (M, 2), ``alive``, ``present``;
    scalars ``min_separation_nm`` (over every pair during the step; inf with fewer than
    two aircraft flying), ``time_s``, ``episode_seed``, and ``wind_kt`` only with
    ``expose_wind=True``. No key shadows a standard one (``reward``, ``terminated``, ...).

    ## Version History

    * v1: the kernel's integration among neighbours changed (θ̇_nh at its true rate inside
      sub-steps, error control of steps with a pair within the sensing radius, guard 9's
      right-hand rule retuned; CHANGELOG): every trajectory with two aircraft within the
      12-nm sensing radius changed. ``atc_nf_env/Encounter-v0`` is retired; making it
      raises an error that names v1.
    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    def __new__(cls, **kwargs: Any) -> Any:
        # A traffic stream's env has other spaces (slot masks): ``StreamEnv``.
        from atc_nf_env.envs.streams import StreamEnv, is_stream

        if cls is EncounterEnv and is_stream(kwargs.get("scenario")):
            return StreamEnv(**kwargs)
        return super().__new__(cls)

    def __init__(self, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "atc_nf_env/Encounter-v1")
        self.cfg = cfg
        self.world = EncounterWorld(cfg, "atc_nf_env/Encounter-v1")
        self.render_mode = cfg.render_mode
        m = self.world.n_slots
        self.n_slots = m
        self.action_space = spaces.Box(-1.0, 1.0, shape=(m, 2), dtype=np.float32)
        self.observation_space = self.world.obs_spec.flat_space(m)
        self._renderer: Any = None
        self._viewer: Any = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode: a given ``seed`` flies episode seed ``seed``; None draws the next
        episode seed from the env's generator. ``options`` is not used.

        Returns:
            The observation, ``Box((M · D,), float32)``, and the info dict (Info in
            the class docstring, with its neutral values).
        """
        seed = None if seed is None else check_seed(seed)  # the project's one seed rule
        super().reset(seed=seed)
        episode_seed = seed if seed is not None else draw_episode_seed(self.np_random)
        self.world.reset(episode_seed)
        if self.render_mode == "human":
            self.render()
        return self.world.observe().reshape(-1), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Fly one decision period (300 s) with ``action``: (M, 2) finite numbers, clipped to
        [-1, 1]; rows of padding slots and of aircraft no longer flying are ignored.

        Returns:
            ``(observation, reward, terminated, truncated, info)``: the reward summed over the
            aircraft; terminated once every aircraft has arrived or left; truncated at the
            time limit (Episode End in the class docstring).

        Raises:
            ValueError: before ``reset``, after the episode's end, or for an action of
                another shape or with a value that is not finite.
        """
        world = self.world
        if not world.started:
            raise ValueError("atc_nf_env/Encounter-v1: step() before reset(); call reset() first")
        if world.over:
            raise ValueError(
                "atc_nf_env/Encounter-v1: the episode is over (every aircraft has arrived or left, or the "
                "time limit passed); call reset() before step()"
            )
        try:
            array = np.asarray(action)
            ok = array.dtype.kind in "biuf" and array.shape == (self.n_slots, 2)
            if ok:
                array = np.ascontiguousarray(array, dtype=np.float64)
                ok = all_finite(array)
        except (TypeError, ValueError):
            ok = False
        if not ok:  # say what is wrong with it, or convert it (an object array of numbers)
            validate_step_actions(action, (self.n_slots, 2), "atc_nf_env/Encounter-v1")
            array = np.ascontiguousarray(action, dtype=np.float64)
        world.step(array[: world.n_aircraft])
        terminated = world.done
        truncated = (not terminated) and world.truncated
        if self.render_mode == "human":
            self.render()
        return world.observe().reshape(-1), float(world.rewards.sum()), terminated, truncated, self._info()

    def _info(self) -> dict[str, Any]:
        world = self.world
        arrays, min_separation = world.info_arrays()
        m, n = self.n_slots, world.n_aircraft
        info: dict[str, Any]
        if m == n:
            info = dict(arrays)
            alive = world.flying.copy()
            present = np.ones(m, dtype=bool)
        else:
            info = {}
            for key, value in arrays.items():
                padded = np.full((m, *value.shape[1:]), np.inf if key == "nearest_nm" else 0, dtype=value.dtype)
                padded[:n] = value
                info[key] = padded
            alive = np.zeros(m, dtype=bool)
            alive[:n] = world.flying
            present = np.zeros(m, dtype=bool)
            present[:n] = True
        info["min_separation_nm"] = min_separation
        info["alive"] = alive
        info["present"] = present
        info["time_s"] = float(world.sim.time_s)  # type: ignore[union-attr]
        info["episode_seed"] = world.episode_seed
        if self.cfg.expose_wind:
            info["wind_kt"] = world.sim.wind_kt.copy()  # type: ignore[union-attr]
        return info

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"``; draws into a window for
        "human" (nothing without a display); None (with a warning) without a render mode.
        ``mode`` (passed by some wrappers, e.g. RLlib's) must be None or the env's
        ``render_mode``."""
        return render_world(self, self.world, mode)

    def close(self) -> None:
        close_renderers(self)
        super().close()


def render_world(owner: Any, world: EncounterWorld, mode: str | None = None) -> np.ndarray | None:
    """Render ``world`` for ``owner`` (an env with render_mode, _renderer and _viewer).
    ``mode``, when given, must be the owner's render mode (it is fixed at construction)."""
    if mode is not None and mode != owner.render_mode:
        raise ValueError(
            f"render(mode={mode!r}) on an env made with render_mode={owner.render_mode!r}: the render mode is "
            f"set when the env is made; make it with render_mode={mode!r}, or call render() without a mode"
        )
    if owner.render_mode is None:
        gym.logger.warn(
            "You are calling render method without specifying any render mode. "
            "Make the env with render_mode='rgb_array' or 'human'."
        )
        return None
    if world.sim is None:
        raise ValueError("render() before reset(); call reset() first")
    from atc_nf_env.rendering import FrameRenderer, snapshot_of_simulation

    if owner._renderer is None:
        owner._renderer = FrameRenderer(world.cfg.render_size_px)
    title = f"{world.sim.scenario.name}  seed {world.episode_seed}"
    frame = owner._renderer.draw(snapshot_of_simulation(world.sim, title=title))
    if owner.render_mode == "human":
        from atc_nf_env.rendering import HumanViewer

        if owner._viewer is None:
            owner._viewer = HumanViewer(fps=owner.metadata.get("render_fps", 4))
        owner._viewer.show(frame)
        return None
    return frame


def close_renderers(owner: Any) -> None:
    if getattr(owner, "_renderer", None) is not None:
        owner._renderer.close()
        owner._renderer = None
    if getattr(owner, "_viewer", None) is not None:
        owner._viewer.close()
        owner._viewer = None


__all__ = ["EncounterEnv", "EncounterWorld", "validate_step_actions"]
