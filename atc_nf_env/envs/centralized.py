"""The centralized Gymnasium environment ``atc_nf_env/Encounter-v0`` and the one-world
episode logic (``EncounterWorld``) that it shares with the PettingZoo env."""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from atc_nf_env.envs import EnvConfig, ScenarioSource, draw_episode_seed, episode_wind
from atc_nf_env.envs.actions import waypoints_for_state
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.envs.rewards import StepOutcome, step_outcome
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
    Trace,
)
from atc_nf_env.simulation import Simulation
from atc_nf_env.units import DECISION_PERIOD_S

#: Integration steps between recorded states when rendering (trails), at dt = 5 s: 30 s.
RENDER_RECORD_EVERY: int = 6


class EncounterWorld:
    """One world (B = 1) of an environment: a ``Simulation`` flown one decision period
    (T = 300 s) per step, with the episode's bookkeeping (seed, time limit, rewards).

    Used by the centralized Gymnasium env and the PettingZoo env; the vector env runs the
    same logic over B worlds in one kernel call (``atc_nf_env.envs.vector``).
    """

    def __init__(self, cfg: EnvConfig, where: str) -> None:
        self.cfg = cfg
        self.source = ScenarioSource(cfg.scenario)
        self.n_slots = self.source.slots(cfg.max_aircraft, where)
        self.obs_spec = ObservationSpec.for_config(cfg.config, cfg.n_neighbours, cfg.expose_wind)
        self.record_every = RENDER_RECORD_EVERY if cfg.render_mode is not None else 0
        self.sim: Simulation | None = None
        self.episode_seed: int = -1
        self.decisions = 0
        self.last_waypoints = np.zeros((self.n_aircraft, 2))

    # ----------------------------------------------------------------- episode

    @property
    def n_aircraft(self) -> int:
        return self.source.n_aircraft

    def reset(self, episode_seed: int) -> None:
        scenario = self.source.scenario(episode_seed)
        wind = episode_wind(episode_seed, self.cfg.wind_sigma)
        self.sim = Simulation(scenario, config=self.cfg.config, wind_kt=wind, record_every=self.record_every)
        self.episode_seed = int(episode_seed)
        self.decisions = 0
        self.last_waypoints = self.sim.state[0, :, [S_WP_X, S_WP_Y]].T.copy()
        self._refresh()

    def _refresh(self) -> None:
        """Observe the current state once (observations and nearest distances)."""
        assert self.sim is not None
        obs, nearest = self.obs_spec.observe_with_nearest(
            self.sim.state, np.array([self.time_fraction]), self.sim.wind_kt[None], self.n_slots
        )
        self._obs = obs[0]
        self._nearest = nearest[0, : self.n_aircraft]

    @property
    def started(self) -> bool:
        return self.sim is not None

    @property
    def flying(self) -> np.ndarray:
        """(n,) bool."""
        assert self.sim is not None
        return self.sim.status == FLYING

    @property
    def time_fraction(self) -> float:
        assert self.sim is not None
        return min(1.0, self.sim.time_s / (self.cfg.max_decisions * DECISION_PERIOD_S))

    @property
    def truncated(self) -> bool:
        """The time limit has been reached."""
        return self.decisions >= self.cfg.max_decisions

    @property
    def over(self) -> bool:
        """Every aircraft has arrived or left, or the time limit has been reached."""
        return self.sim is not None and (self.sim.done or self.truncated)

    def observe(self) -> np.ndarray:
        """(n_slots, obs_dim) float32 (a fresh array after every reset and step)."""
        return self._obs

    def global_state(self) -> np.ndarray:
        assert self.sim is not None
        return self.obs_spec.global_state(
            self.sim.state, np.array([self.time_fraction]), self.sim.wind_kt[None], self.n_slots
        )[0]

    def step(self, actions: np.ndarray) -> tuple[StepOutcome, Trace]:
        """Fly one decision period with clipped actions (n, 2) (rows of aircraft not flying
        are ignored)."""
        sim = self.sim
        assert sim is not None
        state = sim.state[0]
        flying_before = state[:, S_STATUS] == FLYING
        distance_before = np.hypot(state[:, S_DEST_X] - state[:, S_X], state[:, S_DEST_Y] - state[:, S_Y])
        waypoints = waypoints_for_state(
            actions[None], sim.state, self.cfg.action_mapping,
            sim.scenario.workspace_radius_nm, self.cfg.config.aircraft_radius_nm,
        )[0]
        self.last_waypoints = waypoints
        trace = sim.advance(waypoints, DECISION_PERIOD_S)
        self.decisions += 1
        state = sim.state[0]
        distance_after = np.hypot(state[:, S_DEST_X] - state[:, S_X], state[:, S_DEST_Y] - state[:, S_Y])
        self._refresh()
        outcome = step_outcome(
            flying_before[None],
            distance_before[None],
            distance_after[None],
            (state[:, S_STATUS] == ARRIVED)[None],
            (state[:, S_STATUS] == LEFT)[None],
            trace,
            self.cfg.reward_weights,
        )
        return outcome, trace

    # ----------------------------------------------------------------- infos

    def reset_info_arrays(self) -> dict[str, Any]:
        assert self.sim is not None
        state = self.sim.state[0]
        return {
            "airspeed_kt": state[:, S_AIRSPEED].copy(),
            "distance_to_go_nm": np.hypot(state[:, S_DEST_X] - state[:, S_X], state[:, S_DEST_Y] - state[:, S_Y]),
            "nearest_nm": self._nearest.copy(),
        }

    def step_info_arrays(self, outcome: StepOutcome, trace: Trace, clipped: np.ndarray) -> dict[str, Any]:
        """Per-aircraft (n,) arrays and world scalars describing the last step."""
        assert self.sim is not None
        state = self.sim.state[0]
        n = self.n_aircraft
        min_sep = float(trace.min_separation_nm[0])
        return {
            "airspeed_kt": state[:, S_AIRSPEED].copy(),
            "airspeed_min_kt": trace.min_airspeed_kt[0, :n].copy(),
            "airspeed_max_kt": trace.max_airspeed_kt[0, :n].copy(),
            "distance_to_go_nm": outcome.distance_to_go_nm[0],
            "min_separation_nm": np.inf if min_sep >= NO_PAIR_SEPARATION_NM else min_sep,
            "nearest_nm": self._nearest.copy(),
            "los_count": outcome.los_count[0],
            "envelope_violation": trace.violation_steps[0, :n] > 0,
            "envelope_violation_fraction": outcome.violation_fraction[0],
            "action_clipped": clipped & outcome.flew[0],
            "arrived": state[:, S_STATUS] == ARRIVED,
            "left_workspace": state[:, S_STATUS] == LEFT,
            "waypoint_nm": self.last_waypoints.copy(),
            "reward": outcome.rewards[0],
        }


def validate_step_actions(action: Any, shape: tuple[int, ...], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Float64 actions of the expected shape, clipped, and the clipped mask (shape[:-1]).

    Raises:
        ValueError: wrong shape, not numbers, NaN or inf; the message says what is allowed.
    """
    try:
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
    if not np.isfinite(array).all():
        raise ValueError(
            f"{where}: action contains NaN or inf: {array.tolist()}; allowed: finite numbers in [-1, 1] "
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
    step) or left the workspace. Truncated after ceil(``max_episode_minutes`` / 5)
    decisions (default 180 min: 36 steps). Stepping after the end raises ValueError
    (call ``reset``).

    ## Arguments

    ``gym.make("atc_nf_env/Encounter-v0", scenario="converging-4", wind_sigma=5.17,
    render_mode=None, max_aircraft=None, n_neighbours=4, max_episode_minutes=180,
    expose_wind=False, action_mapping=None, reward_weights=None, config=None,
    render_size_px=512)``; see ``atc_nf_env.envs`` for each. Unknown arguments raise
    ValueError listing the allowed ones. ``gym.make_vec(..., num_envs=B)`` builds the
    native vector env (B worlds in one kernel call).

    ## Info

    Per-aircraft arrays (M,): ``airspeed_kt`` (last integration step), ``airspeed_min_kt``,
    ``airspeed_max_kt`` (over the step), ``distance_to_go_nm``, ``nearest_nm``
    (to the nearest aircraft still flying), ``los_count``, ``envelope_violation``,
    ``envelope_violation_fraction``, ``action_clipped``, ``arrived``, ``left_workspace``,
    ``alive``, ``present``, ``waypoint_nm`` (M, 2), ``reward``; scalars
    ``min_separation_nm`` (over every pair during the step; inf with fewer than two
    aircraft flying), ``time_s``, ``episode_seed``, and ``wind_kt`` only with
    ``expose_wind=True``.

    ## Version History

    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 4}

    def __init__(self, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "atc_nf_env/Encounter-v0")
        self.cfg = cfg
        self.world = EncounterWorld(cfg, "atc_nf_env/Encounter-v0")
        self.render_mode = cfg.render_mode
        m = self.world.n_slots
        self.n_slots = m
        self.action_space = spaces.Box(-1.0, 1.0, shape=(m, 2), dtype=np.float32)
        self.observation_space = self.world.obs_spec.flat_space(m)
        self._renderer: Any = None
        self._viewer: Any = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        episode_seed = int(seed) if seed is not None else draw_episode_seed(self.np_random)
        self.world.reset(episode_seed)
        info = self._pad_info(self.world.reset_info_arrays())
        info.update(self._world_info())
        if self.render_mode == "human":
            self.render()
        return self.world.observe().reshape(-1), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        world = self.world
        if not world.started:
            raise ValueError("atc_nf_env/Encounter-v0: step() before reset(); call reset() first")
        if world.over:
            raise ValueError(
                "atc_nf_env/Encounter-v0: the episode is over (every aircraft has arrived or left, or the "
                "time limit passed); call reset() before step()"
            )
        clipped_actions, clipped = validate_step_actions(action, (self.n_slots, 2), "atc_nf_env/Encounter-v0")
        n = world.n_aircraft
        outcome, trace = world.step(clipped_actions[:n])
        info = self._pad_info(world.step_info_arrays(outcome, trace, clipped[:n]))
        info.update(self._world_info())
        terminated = bool(world.sim.done)  # type: ignore[union-attr]
        truncated = (not terminated) and world.truncated
        if self.render_mode == "human":
            self.render()
        return world.observe().reshape(-1), float(outcome.rewards.sum()), terminated, truncated, info

    def _pad_info(self, arrays: dict[str, Any]) -> dict[str, Any]:
        m, n = self.n_slots, self.world.n_aircraft
        info: dict[str, Any] = {}
        for key, value in arrays.items():
            if isinstance(value, np.ndarray) and value.shape[:1] == (n,):
                padded = np.zeros((m, *value.shape[1:]), dtype=value.dtype)
                if key == "nearest_nm":
                    padded[:] = np.inf
                padded[:n] = value
                info[key] = padded
            else:
                info[key] = value
        return info

    def _world_info(self) -> dict[str, Any]:
        world = self.world
        alive = np.zeros(self.n_slots, dtype=bool)
        alive[: world.n_aircraft] = world.flying
        present = np.zeros(self.n_slots, dtype=bool)
        present[: world.n_aircraft] = True
        info: dict[str, Any] = {
            "alive": alive,
            "present": present,
            "time_s": float(world.sim.time_s),  # type: ignore[union-attr]
            "episode_seed": world.episode_seed,
        }
        if self.cfg.expose_wind:
            info["wind_kt"] = world.sim.wind_kt.copy()  # type: ignore[union-attr]
        return info

    def render(self) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"``; draws into a window for
        "human" (nothing without a display); None (with a warning) without a render mode."""
        return render_world(self, self.world)

    def close(self) -> None:
        close_renderers(self)
        super().close()


def render_world(owner: Any, world: EncounterWorld) -> np.ndarray | None:
    """Render ``world`` for ``owner`` (an env with render_mode, _renderer and _viewer)."""
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
