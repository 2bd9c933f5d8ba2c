"""The native vector env: B worlds of ``atc_nf_env/Encounter-v1`` stepped in one kernel
call, and adapters for Stable-Baselines3.

- ``EncounterVectorEnv``: a Gymnasium ``VectorEnv`` (``gym.make_vec("atc_nf_env/Encounter-v1",
  num_envs=B)``), equal world for world to ``SyncVectorEnv`` over ``EncounterEnv``
  (same seeds, same observations, rewards and ends: the kernel is bit-identical across
  batch sizes), but one kernel call (numba, parallel over worlds) per step.
- ``SB3VecEnv`` (``make_sb3_vec_env``): the same B worlds as a Stable-Baselines3 ``VecEnv``
  (same-step autoreset, ``terminal_observation``, ``TimeLimit.truncated``), either
  ``mode="centralized"`` (one SB3 env per world: flat observation, (M, 2) action) or
  ``mode="shared"`` (one SB3 env per aircraft slot, B·M of them, ego observation and
  (2,) action, for a parameter-shared decentralized policy; an aircraft that has
  arrived or left, and a padding slot, sees zeros and gets reward 0 until its world
  ends, as SuperSuit's black death does; SB3's ``VecMonitor`` then counts one episode
  per slot).
- ``seedable_sb3_vec_env``: makes SuperSuit's ``concat_vec_envs_v1(...,
  base_class="stable_baselines3")`` output accept ``PPO(..., seed=...)``.

SB3 is imported only when an adapter is built (``SB3VecEnv`` is created on first access).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from atc_nf_env import kernel
from atc_nf_env.calibration import check_calibrated
from atc_nf_env.config import check_batch_size
from atc_nf_env.envs import EnvConfig, ScenarioSource, draw_episode_seed, episode_wind
from atc_nf_env.scenarios import check_seed
from atc_nf_env.envs.actions import waypoints_for_state
from atc_nf_env.envs.centralized import validate_step_actions
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.envs.rewards import StepOutcome, period_outcome, reward_weight_vector
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
    Trace,
)
from atc_nf_env.simulation import initial_state
from atc_nf_env.units import DECISION_PERIOD_S


class BatchWorlds:
    """B independent worlds of one environment configuration in one kernel state
    (B, M, N_STATE), advanced together by ``kernel.advance``. World ``b`` behaves exactly
    as an ``EncounterEnv`` reset with the same seeds."""

    def __init__(self, cfg: EnvConfig, num_envs: int, where: str) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"{where}: num_envs = {num_envs!r}: must be an integer >= 1")
        self.cfg = cfg
        self._reward_weights = reward_weight_vector(cfg.reward_weights)
        self.num_envs = int(num_envs)
        self.source = ScenarioSource(cfg.scenario)
        self.n_slots = self.source.slots(cfg.max_aircraft, where)
        try:
            check_batch_size(self.num_envs, self.n_slots, "num_envs")
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
        self.obs_spec = ObservationSpec.for_config(cfg.config, cfg.n_neighbours, cfg.expose_wind)
        check_calibrated(cfg.config, self.source.workspace_radius_nm)
        self.params = cfg.config.to_params(self.source.workspace_radius_nm)
        b, m = self.num_envs, self.n_slots
        self.state = kernel.new_state(b, m)
        self.wind_kt = np.zeros((b, 2))
        self.time_s = np.zeros(b)
        self.decisions = np.zeros(b, dtype=np.int64)
        self.episode_seeds = np.full(b, -1, dtype=np.int64)
        self.rngs: list[np.random.Generator | None] = [None] * b
        self.scratch = KernelScratch()
        self.started = False
        self.last_waypoints = np.zeros((b, m, 2))
        self._template = (
            initial_state(self.source.template, 1, m)[0] if self.source.random_n is None else None
        )
        self._limit_s = cfg.max_decisions * DECISION_PERIOD_S

    # ----------------------------------------------------------------- resets

    def reset_worlds(self, worlds: np.ndarray, seeds: list[int | None] | None = None) -> None:
        """Start a new episode in each world of ``worlds`` (indices); a seed reseeds that
        world's generator and is its episode seed, None draws one from the generator."""
        for k, b in enumerate(np.asarray(worlds, dtype=np.int64).tolist()):
            seed = None if seeds is None else seeds[k]
            if seed is not None:
                episode_seed = check_seed(seed, f"seed of world {b}")  # the project's one seed rule
                self.rngs[b], _ = seeding.np_random(episode_seed)
            else:
                if self.rngs[b] is None:
                    self.rngs[b], _ = seeding.np_random()
                episode_seed = draw_episode_seed(self.rngs[b])  # type: ignore[arg-type]
            if self._template is not None:
                self.state[b] = self._template
            else:
                self.state[b] = initial_state(self.source.scenario(episode_seed), 1, self.n_slots)[0]
            self.wind_kt[b] = episode_wind(episode_seed, self.cfg.wind_sigma)
            self.time_s[b] = 0.0
            self.decisions[b] = 0
            self.episode_seeds[b] = episode_seed
        self.started = True
        self._refresh()

    def _refresh(self) -> None:
        self._obs, self._nearest = self.obs_spec.observe_with_nearest(
            self.state, np.minimum(1.0, self.time_s / self._limit_s), self.wind_kt, self.n_slots
        )

    # ----------------------------------------------------------------- views

    @property
    def flying(self) -> np.ndarray:
        """(B, M) bool."""
        return self.state[:, :, S_STATUS] == FLYING

    @property
    def present(self) -> np.ndarray:
        return self.state[:, :, S_STATUS] != kernel.ABSENT

    @property
    def terminated(self) -> np.ndarray:
        """(B,) no aircraft flying."""
        return ~self.flying.any(axis=1)

    @property
    def truncated(self) -> np.ndarray:
        """(B,) time limit reached (whether or not terminated)."""
        return self.decisions >= self.cfg.max_decisions

    def observe(self) -> np.ndarray:
        """(B, M, D) float32 (a fresh array after every reset and step)."""
        return self._obs

    # ----------------------------------------------------------------- step

    def step(self, actions: np.ndarray, active: np.ndarray | None = None) -> tuple[StepOutcome, Trace]:
        """Fly one decision period in the ``active`` worlds (all by default) with clipped
        actions (B, M, 2); the others do not move and get zero outcomes."""
        state = self.state
        flying_before = state[:, :, S_STATUS] == FLYING
        if active is not None:
            flying_before &= active[:, None]
        distance_before = np.hypot(state[:, :, S_DEST_X] - state[:, :, S_X], state[:, :, S_DEST_Y] - state[:, :, S_Y])
        waypoints = waypoints_for_state(
            actions, state, self.cfg.action_mapping,
            self.source.workspace_radius_nm, self.cfg.config.aircraft_radius_nm,
        )
        if active is None or active.all():
            trace = kernel.advance(state, waypoints, self.wind_kt, DECISION_PERIOD_S, self.params, scratch=self.scratch)
            self.time_s += trace.steps_done * self.cfg.config.dt_s
            self.decisions += 1
        else:
            index = np.flatnonzero(active)
            sub = state[index]
            part = kernel.advance(sub, waypoints[index], self.wind_kt[index], DECISION_PERIOD_S, self.params, scratch=self.scratch)
            state[index] = sub
            trace = _expand_trace(part, index, self.num_envs, self.n_slots)
            self.time_s[index] += part.steps_done * self.cfg.config.dt_s
            self.decisions[index] += 1
        self.last_waypoints = waypoints
        self._refresh()
        outcome = period_outcome(state, flying_before, distance_before, trace, self._reward_weights)
        return outcome, trace

    def info_arrays(self, outcome: StepOutcome | None, trace: Trace | None, clipped: np.ndarray | None) -> dict[str, Any]:
        """Per-world info arrays, (B, M) per aircraft or (B,), with ``EncounterEnv``'s keys;
        the same keys, shapes and dtypes after a reset (outcome None), with neutral values."""
        state = self.state
        flying = self.flying
        present = self.present
        status = state[:, :, S_STATUS]
        airspeed = np.where(present, state[:, :, S_AIRSPEED], 0.0)
        info: dict[str, Any] = {
            "airspeed_kt": airspeed,
            "distance_to_go_nm": np.where(
                present, np.hypot(state[:, :, S_DEST_X] - state[:, :, S_X], state[:, :, S_DEST_Y] - state[:, :, S_Y]), 0.0
            ),
            "nearest_nm": self._nearest.copy(),
        }
        if outcome is not None and trace is not None and clipped is not None:
            min_sep = trace.min_separation_nm.astype(np.float64)
            info.update(
                {
                    "airspeed_min_kt": np.where(present, trace.min_airspeed_kt, 0.0),
                    "airspeed_max_kt": np.where(present, trace.max_airspeed_kt, 0.0),
                    "min_separation_nm": np.where(min_sep >= NO_PAIR_SEPARATION_NM, np.inf, min_sep),
                    "los_count": outcome.los_count,
                    "envelope_violation": trace.violation_steps > 0,
                    "envelope_violation_fraction": outcome.violation_fraction,
                    "action_clipped": clipped & outcome.flew,
                    "aircraft_reward": outcome.rewards,
                    "waypoint_nm": np.where(present[..., None], self.last_waypoints, 0.0),
                }
            )
        else:
            shape = flying.shape
            info.update(
                {
                    "airspeed_min_kt": airspeed.copy(),
                    "airspeed_max_kt": airspeed.copy(),
                    "min_separation_nm": np.where(flying, self._nearest, np.inf).min(axis=1),
                    "los_count": np.zeros(shape, dtype=np.int64),
                    "envelope_violation": np.zeros(shape, dtype=bool),
                    "envelope_violation_fraction": np.zeros(shape),
                    "action_clipped": np.zeros(shape, dtype=bool),
                    "aircraft_reward": np.zeros(shape),
                    "waypoint_nm": np.where(present[..., None], state[:, :, [S_WP_X, S_WP_Y]], 0.0),
                }
            )
        info["arrived"] = status == ARRIVED
        info["left_workspace"] = status == LEFT
        info["alive"] = flying
        info["present"] = present
        info["time_s"] = self.time_s.copy()
        info["episode_seed"] = self.episode_seeds.copy()
        if self.cfg.expose_wind:
            info["wind_kt"] = self.wind_kt.copy()
        return info


def _expand_trace(part: Trace, index: np.ndarray, n_worlds: int, n: int) -> Trace:
    """A Trace of ``n_worlds`` worlds holding ``part`` at ``index`` and zeros elsewhere."""

    def full(array: np.ndarray, fill: float = 0) -> np.ndarray:
        out = np.full((n_worlds, *array.shape[1:]), fill, dtype=array.dtype)
        out[index] = array
        return out

    return Trace(
        min_airspeed_kt=full(part.min_airspeed_kt),
        max_airspeed_kt=full(part.max_airspeed_kt),
        violation_steps=full(part.violation_steps),
        worst_excursion_kt=full(part.worst_excursion_kt),
        steps_flown=full(part.steps_flown),
        los_pairs=full(part.los_pairs),
        min_separation_nm=full(part.min_separation_nm, NO_PAIR_SEPARATION_NM),
        steps_done=full(part.steps_done),
        violated=full(part.violated),
        record=np.zeros((n_worlds, 0, n, kernel.N_RECORD)),
    )


def _with_masks(info: dict[str, Any], mask: np.ndarray) -> dict[str, Any]:
    """Gymnasium's vector info convention: every key ``k`` with a ``_k`` (B,) bool mask."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        out[key] = value
        out[f"_{key}"] = mask.copy()
    return out


class EncounterVectorEnv(VectorEnv):
    """B worlds of ``atc_nf_env/Encounter-v1`` (see ``EncounterEnv`` for the spaces,
    rewards, episode ends and arguments) stepped in one kernel call.

    ``gym.make_vec("atc_nf_env/Encounter-v1", num_envs=B, **kwargs)`` builds it. Seeds:
    ``reset(seed=s)`` gives world b the episode seed s + b (as ``SyncVectorEnv`` does),
    so world b equals ``EncounterEnv`` reset with seed s + b, autoresets included.

    Args:
        num_envs: B, the number of worlds.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (Gymnasium's default: the step after
            an episode's end resets that world and returns its first observation with
            reward 0), ``SAME_STEP`` (reset at once; the last observation and info in
            ``info["final_obs"]`` and ``info["final_info"]``) or ``DISABLED`` (reset with
            ``reset(options={"reset_mask": mask})``; stepping an ended world raises
            ValueError). A string ("NextStep", "SameStep", "Disabled") is accepted.
        **kwargs: the environment's arguments (``atc_nf_env.envs``); ``render_mode`` must
            be None (render single envs instead).

    Info: the keys of ``EncounterEnv``'s info as arrays (B, M) or (B,), each with its
    ``_key`` mask.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __new__(cls, num_envs: int = 1, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                **kwargs: Any) -> Any:
        # A traffic stream: Gymnasium's SyncVectorEnv over ``StreamEnv`` (its dict
        # observations with slot masks, batched); each world is stepped in its own call.
        from atc_nf_env.envs.streams import StreamEnv, is_stream

        if cls is EncounterVectorEnv and is_stream(kwargs.get("scenario")):
            if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
                raise ValueError(f"atc_nf_env/Encounter-v1 (vector): num_envs = {num_envs!r}: must be an integer >= 1")
            from gymnasium.vector import SyncVectorEnv

            return SyncVectorEnv([lambda: StreamEnv(**kwargs)] * int(num_envs), autoreset_mode=autoreset_mode)
        return super().__new__(cls)

    def __init__(self, num_envs: int = 1, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "atc_nf_env/Encounter-v1 (vector)")
        if cfg.render_mode is not None:
            raise ValueError(
                f"atc_nf_env/Encounter-v1 (vector): render_mode = {cfg.render_mode!r}: the vector env does not "
                "render; allowed: None (render a single env from gym.make instead)"
            )
        try:
            mode = AutoresetMode(autoreset_mode) if isinstance(autoreset_mode, str) else autoreset_mode
        except ValueError:
            mode = None
        if not isinstance(mode, AutoresetMode):
            raise ValueError(
                f"autoreset_mode = {autoreset_mode!r}: allowed: {[m.value for m in AutoresetMode]} "
                "(or gymnasium.vector.AutoresetMode members)"
            )
        self.cfg = cfg
        self.worlds = BatchWorlds(cfg, num_envs, "atc_nf_env/Encounter-v1 (vector)")
        self.num_envs = self.worlds.num_envs
        self.autoreset_mode = mode
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.render_mode = None
        m = self.worlds.n_slots
        self.n_slots = m
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(m, 2), dtype=np.float32)
        self.single_observation_space = self.worlds.obs_spec.flat_space(m)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every world (or those of ``options["reset_mask"]``). ``seed``: an int s
        (world b gets s + b) or a list of B seeds/None."""
        b = self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            check_seed(seed)
            check_seed(int(seed) + b - 1, f"seed + num_envs - 1 (world {b - 1}'s seed)")
            super().reset(seed=int(seed))
            seeds: list[int | None] = [int(seed) + k for k in range(b)]
        elif seed is None:
            seeds = [None] * b
        elif isinstance(seed, (list, tuple)) and len(seed) == b:
            seeds = list(seed)
        else:
            if not isinstance(seed, (list, tuple)):
                check_seed(seed)  # the one rule's message (a bool, a float, a string …)
            raise ValueError(f"seed = {seed!r}: must be None, an int, or a list of {b} ints/None")
        mask = np.ones(b, dtype=bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (b,):
                raise ValueError(f"options['reset_mask'] has shape {mask.shape}; expected ({b},) bool")
        worlds = np.flatnonzero(mask)
        if not self.worlds.started and not mask.all():
            raise ValueError("the first reset must reset every world (no reset_mask, or an all-True one)")
        self.worlds.reset_worlds(worlds, [seeds[k] for k in worlds])
        self._autoreset[worlds] = False
        obs = self.worlds.observe().reshape(b, -1)
        return obs, _with_masks(self.worlds.info_arrays(None, None, None), mask)

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        worlds = self.worlds
        b, m = self.num_envs, self.n_slots
        if not worlds.started:
            raise ValueError("atc_nf_env/Encounter-v1 (vector): step() before reset(); call reset() first")
        clipped_actions, clipped = validate_step_actions(actions, (b, m, 2), "atc_nf_env/Encounter-v1 (vector)")
        ended = worlds.terminated | worlds.truncated
        if self.autoreset_mode == AutoresetMode.DISABLED and ended.any():
            raise ValueError(
                f"atc_nf_env/Encounter-v1 (vector): world(s) {np.flatnonzero(ended).tolist()} are over; reset them "
                "with reset(options={'reset_mask': mask}) before step() (autoreset_mode is DISABLED)"
            )
        reset_now = self._autoreset.copy() if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.zeros(b, dtype=bool)
        active = ~reset_now
        outcome, trace = worlds.step(clipped_actions, None if active.all() else active)
        rewards = outcome.rewards.sum(axis=1)
        terminated = worlds.terminated & active
        truncated = worlds.truncated & ~terminated & active
        info = _with_masks(worlds.info_arrays(outcome, trace, clipped), active)
        obs = worlds.observe().reshape(b, -1)
        if reset_now.any():
            index = np.flatnonzero(reset_now)
            worlds.reset_worlds(index)
            obs[index] = worlds.observe()[index].reshape(len(index), -1)
            rewards[index] = 0.0
            fresh = worlds.info_arrays(None, None, None)
            for key, value in fresh.items():
                info[key][index] = value[index]
                info[f"_{key}"][index] = True
        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            index = np.flatnonzero(done)
            final_obs = np.full(b, None, dtype=object)
            for k in index:
                final_obs[k] = obs[k].copy()
            info["final_obs"] = final_obs
            info["_final_obs"] = done.copy()
            info["final_info"] = {key: (value.copy() if isinstance(value, np.ndarray) else value) for key, value in info.items() if key not in ("final_obs", "_final_obs")}
            info["_final_info"] = done.copy()
            worlds.reset_worlds(index)
            obs[index] = worlds.observe()[index].reshape(len(index), -1)
            fresh = worlds.info_arrays(None, None, None)
            for key, value in fresh.items():
                info[key][index] = value[index]
        self._autoreset = done if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.zeros(b, dtype=bool)
        return obs, rewards, terminated, truncated, info

    def __repr__(self) -> str:
        return f"EncounterVectorEnv(num_envs={self.num_envs}, scenario={self.cfg.scenario!r})"


# --------------------------------------------------------------------------- SB3


def make_sb3_vec_env(num_envs: int = 8, mode: str = "centralized", **kwargs: Any) -> Any:
    """A Stable-Baselines3 ``VecEnv`` over ``num_envs`` worlds stepped in one kernel call.

    Args:
        num_envs: B, the number of worlds.
        mode: "centralized" (B SB3 envs: flat observation, (M, 2) action, summed reward)
            or "shared" (B·M SB3 envs, one per aircraft slot: ego observation, (2,)
            action, per-aircraft reward; for a parameter-shared policy).
        **kwargs: the environment's arguments (``atc_nf_env.envs``).

    ``PPO(..., seed=s)`` seeds it: world b gets episode seed s + b at the first reset.
    """
    return _sb3_adapter_class()(num_envs=num_envs, mode=mode, **kwargs)


_SB3_CLASSES: dict[str, type] = {}


def _sb3_adapter_class() -> type:
    if "adapter" in _SB3_CLASSES:
        return _SB3_CLASSES["adapter"]
    try:
        from stable_baselines3.common.vec_env.base_vec_env import VecEnv as SB3BaseVecEnv
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError(
            "the SB3 adapter needs stable-baselines3: pip install 'atc-nf-env[rl]'"
        ) from error

    class SB3VecEnv(SB3BaseVecEnv):
        """B worlds as a Stable-Baselines3 VecEnv (see ``make_sb3_vec_env``)."""

        def __init__(self, num_envs: int = 8, mode: str = "centralized", **kwargs: Any) -> None:
            if mode not in ("centralized", "shared"):
                raise ValueError(f"mode = {mode!r}: allowed: 'centralized', 'shared'")
            cfg = EnvConfig.from_kwargs(kwargs, "SB3VecEnv")
            if cfg.render_mode is not None:
                raise ValueError(f"SB3VecEnv: render_mode = {cfg.render_mode!r}: allowed: None")
            self.cfg = cfg
            self.mode = mode
            self.worlds = BatchWorlds(cfg, num_envs, "SB3VecEnv")
            self.render_mode = None
            self.n_worlds = self.worlds.num_envs
            m = self.worlds.n_slots
            if mode == "centralized":
                n_envs = self.n_worlds
                obs_space = self.worlds.obs_spec.flat_space(m)
                act_space = spaces.Box(-1.0, 1.0, shape=(m, 2), dtype=np.float32)
            else:
                n_envs = self.n_worlds * m
                obs_space = self.worlds.obs_spec.space()
                act_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
            self._actions: np.ndarray | None = None
            self._base_seed: int | None = None
            super().__init__(n_envs, obs_space, act_space)

        # SB3's seeding: seed() is applied at the next reset().
        def seed(self, seed: int | None = None) -> list[int | None]:
            self._base_seed = None if seed is None else int(seed)
            return [None if seed is None else int(seed) + k for k in range(self.n_worlds)]

        def _obs(self, obs: np.ndarray) -> np.ndarray:
            if self.mode == "centralized":
                return obs.reshape(self.n_worlds, -1)
            live = self.worlds.flying.reshape(-1)
            flat = obs.reshape(self.num_envs, -1)
            flat[~live] = 0.0  # black death: finished aircraft and padding see zeros
            return flat

        def reset(self) -> np.ndarray:
            seeds = (
                [self._base_seed + k for k in range(self.n_worlds)] if self._base_seed is not None else None
            )
            self._base_seed = None
            self.worlds.reset_worlds(np.arange(self.n_worlds), seeds)
            self.reset_infos = [{} for _ in range(self.num_envs)]
            return self._obs(self.worlds.observe())

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
            worlds = self.worlds
            if not worlds.started or self._actions is None:
                raise ValueError("SB3VecEnv: step before reset(); call reset() first")
            b, m = self.n_worlds, worlds.n_slots
            shape = (b, m, 2) if self.mode == "centralized" else (b * m, 2)
            clipped_actions, _ = validate_step_actions(self._actions, shape, "SB3VecEnv")
            outcome, _ = worlds.step(clipped_actions.reshape(b, m, 2))
            terminated = worlds.terminated
            truncated = worlds.truncated & ~terminated
            done = terminated | truncated
            obs = self._obs(worlds.observe())
            if self.mode == "centralized":
                rewards = outcome.rewards.sum(axis=1).astype(np.float32)
                dones = done.copy()
                infos: list[dict[str, Any]] = [{} for _ in range(b)]
                owners = np.arange(b)
            else:
                rewards = outcome.rewards.reshape(-1).astype(np.float32)
                dones = np.repeat(done, m)
                infos = [{} for _ in range(b * m)]
                owners = np.repeat(np.arange(b), m)
            if done.any():
                ended = np.flatnonzero(dones)
                # SB3's convention (ep_success_buffer, rollout/success_rate): the world's
                # aircraft all arrived (centralized), this slot's aircraft arrived (shared;
                # a padding slot counts as arrived).
                home = worlds.state[:, :, S_STATUS] != FLYING
                home &= worlds.state[:, :, S_STATUS] != LEFT
                for k in ended:
                    infos[k]["terminal_observation"] = obs[k].copy()
                    infos[k]["TimeLimit.truncated"] = bool(truncated[owners[k]])
                    infos[k]["episode_seed"] = int(worlds.episode_seeds[owners[k]])
                    infos[k]["is_success"] = bool(home[k].all() if self.mode == "centralized" else home[owners[k], k % m])
                index = np.flatnonzero(done)
                worlds.reset_worlds(index)
                fresh = self._obs(worlds.observe())
                obs[ended] = fresh[ended]
            self._actions = None
            return obs, rewards, dones, infos

        def close(self) -> None:
            pass

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            return [getattr(self, attr_name) for _ in self._get_indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            setattr(self, attr_name, value)

        def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
            method = getattr(self, method_name)
            return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False for _ in self._get_indices(indices)]

        def get_images(self) -> list[None]:
            return [None for _ in range(self.num_envs)]

    _SB3_CLASSES["adapter"] = SB3VecEnv
    return SB3VecEnv


def seedable_sb3_vec_env(venv: Any) -> Any:
    """Wrap SuperSuit's ``concat_vec_envs_v1(..., base_class="stable_baselines3")`` so that
    ``PPO(..., seed=s)`` works: SB3 calls ``venv.seed(s)``, which SuperSuit's
    ``ConcatVecEnv`` lacks (AttributeError); here the seed is kept and passed to the next
    ``reset`` (sub-env k gets s + k, i.e. the k-th copy of the PettingZoo env is reset
    with seed s + k)."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class SeedableVecEnv(VecEnvWrapper):
        def __init__(self, venv: Any) -> None:
            super().__init__(venv)
            self._pending_seed: int | None = None

        def seed(self, seed: int | None = None) -> list[int | None]:
            self._pending_seed = None if seed is None else int(seed)
            return [None if seed is None else int(seed) + k for k in range(self.num_envs)]

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            if attr_name == "render_mode":  # SuperSuit's wrapper keeps it, not its sub-envs
                return [getattr(self.venv, "render_mode", None) for _ in self._get_indices(indices)]
            return self.venv.get_attr(attr_name, indices)

        def reset(self) -> np.ndarray:
            seed, self._pending_seed = self._pending_seed, None
            inner = getattr(self.venv, "venv", None)
            if seed is not None and inner is not None:
                observations, infos = inner.reset(seed=seed)
                self.venv.reset_infos = infos
                self.reset_infos = infos
                return observations
            return self.venv.reset()

        def step_wait(self) -> Any:
            return self.venv.step_wait()

    return SeedableVecEnv(venv)


def __getattr__(name: str) -> Any:
    if name == "SB3VecEnv":
        return _sb3_adapter_class()
    raise AttributeError(f"module 'atc_nf_env.envs.vector' has no attribute {name!r}")


__all__ = ["BatchWorlds", "EncounterVectorEnv", "SB3VecEnv", "make_sb3_vec_env", "seedable_sb3_vec_env"]
