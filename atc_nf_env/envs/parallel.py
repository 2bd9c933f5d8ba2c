"""The PettingZoo environment: ``parallel_env(**kwargs)`` (ParallelEnv), ``env(**kwargs)``
(AEC, order-enforced) and ``raw_env`` (AEC, unwrapped)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from atc_nf_env.envs import EnvConfig, draw_episode_seed
from atc_nf_env.envs.centralized import EncounterWorld, close_renderers, render_world, validate_step_actions

AGENT_PREFIX = "aircraft_"


class ATCParallelEnv(ParallelEnv):
    """## Description

    The paper's air-traffic encounter as a multi-agent environment: every aircraft is an
    agent (``aircraft_0``, ``aircraft_1``, ...) flying under its decentralized dipolar
    navigation function (NF) with a hidden constant wind, and every T = 5 min each agent
    chooses its own intermediate waypoint (Roussos, Chaloulos, Kyriakopoulos, Lygeros,
    CDC 2008). One ``step`` flies one 300 s decision period through the batched kernel
    (Adams-Bashforth 2, dt = 5 s). Units: nm, kt, s.

    ## Action Space

    Per agent ``Box(-1, 1, (2,), float32)``: [distance, angle], mapped to a waypoint at
    ``100 + 40·a[0]`` nm and ``90°·a[1]`` off the bearing to the aircraft's destination
    (configurable with ``action_mapping``; ``atc_nf_env.envs.actions.action_to_waypoint``
    and ``waypoint_to_action`` convert). Values outside [-1, 1] are clipped and
    ``infos[agent]["action_clipped"]`` is True; NaN/inf, a wrong shape, an unknown agent
    or a missing live agent raise ValueError.

    ## Observation Space

    Per agent ``Box((D,), float32)``, D = 8 + 5 K (+ 2 with ``expose_wind``): ego-centric
    (frame of the aircraft's heading), normalized: its airspeed, distance and bearing to
    its destination, its current waypoint, the time, then the K (default 4) nearest
    aircraft still flying (relative position and velocity, padded with zeros and a mask
    bit). See ``atc_nf_env.envs.observations`` for the table. ``state()`` returns the
    global state (``state_space``), padded to ``max_aircraft`` slots.

    ## Rewards

    Per agent and step: progress (1 per 100 nm of distance to go flown off), minus 1 × the
    fraction of its integration steps outside the airspeed envelope [366, 540] kt, minus
    5 per other aircraft that came within 5 nm, plus 5 on arrival (``reward_weights``).

    ## Starting State

    The scenario's aircraft at their starts, first waypoint at the destination, a wind
    drawn per episode (each component N(0, σ²), σ = 5.17 m/s). ``reset(seed=s)`` flies
    episode seed ``s``: the same wind (and, for ``random-N``, the same encounter) as
    ``run_episode(..., seed=s)``; later resets draw seeds from the env's generator.

    ## Episode End

    An agent terminates when it arrives (within Δ = ``SimConfig.arrival_tolerance_nm`` of
    its destination, checked at every integration step) or leaves the workspace, and is
    then removed from ``agents``. All remaining agents are truncated after ceil(``max_episode_minutes`` / 5) decisions
    (default 180 min: 36 steps, room for the 6-aircraft encounter's ~70-90 min flights).
    Once no agent is left, ``step({})`` returns empty dicts (as PettingZoo's own
    conversion wrappers do; SuperSuit's ``black_death_v3`` relies on it), and a step with
    any action raises ValueError (call ``reset``).

    ## Arguments

    ``atc_nf_env.parallel_env(scenario="converging-4", wind_sigma=5.17, render_mode=None,
    max_aircraft=None, n_neighbours=4, max_episode_minutes=180, expose_wind=False,
    action_mapping=None, reward_weights=None, config=None, render_size_px=512)``: see
    ``atc_nf_env.envs``. Unknown arguments raise ValueError listing the allowed ones.

    ## Info

    Per agent after a step: ``airspeed_kt`` (last integration step), ``airspeed_min_kt``,
    ``airspeed_max_kt`` (over the step), ``distance_to_go_nm``, ``min_separation_nm``
    (smallest distance between any two aircraft during the step, inf with fewer than two
    flying), ``nearest_nm`` (this aircraft to the nearest one still flying, now),
    ``los_count``, ``envelope_violation`` (bool, this step), ``envelope_violation_fraction``,
    ``action_clipped``, ``arrived``, ``left_workspace``, ``waypoint_nm`` (2,), ``time_s``,
    ``episode_seed``; ``wind_kt`` only with ``expose_wind=True``. After a reset:
    ``airspeed_kt``, ``distance_to_go_nm``, ``nearest_nm``, ``time_s``, ``episode_seed``.

    ## Version History

    * v0: initial version.
    """

    metadata = {
        "name": "atc_nf_env_v0",
        "render_modes": ["human", "rgb_array"],
        "is_parallelizable": True,
        "render_fps": 4,
    }

    def __init__(self, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "parallel_env")
        self.cfg = cfg
        self.world = EncounterWorld(cfg, "parallel_env")
        self.render_mode = cfg.render_mode
        n = self.world.n_aircraft
        self.possible_agents: list[str] = [f"{AGENT_PREFIX}{i}" for i in range(n)]
        self.agents: list[str] = []
        self._index = {agent: i for i, agent in enumerate(self.possible_agents)}
        # One space object per agent, returned every time (PettingZoo seeds them per agent).
        self.observation_spaces = {agent: self.world.obs_spec.space() for agent in self.possible_agents}
        self.action_spaces = {
            agent: spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32) for agent in self.possible_agents
        }
        self.state_space = self.world.obs_spec.state_space(self.world.n_slots)
        self._np_random: np.random.Generator | None = None
        self._np_random_seed: int | None = None
        self._renderer: Any = None
        self._viewer: Any = None

    # ---------------------------------------------------------------- spaces

    def _check_agent(self, agent: Any) -> int:
        index = self._index.get(agent) if isinstance(agent, str) else None
        if index is None:
            raise ValueError(f"unknown agent {agent!r}; agents of this env: {self.possible_agents}")
        return index

    def observation_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self.action_spaces[agent]

    @property
    def np_random(self) -> np.random.Generator:
        """The env's generator (seeded by ``reset(seed=...)``); draws the episode seeds."""
        if self._np_random is None:
            self._np_random, self._np_random_seed = seeding.np_random()
        return self._np_random

    # ---------------------------------------------------------------- episode

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode; ``seed`` is its episode seed (wind, random encounter).
        ``options`` is accepted and ignored."""
        if seed is not None:
            self._np_random, self._np_random_seed = seeding.np_random(seed)
            episode_seed = int(seed)
        else:
            episode_seed = draw_episode_seed(self.np_random)
        self.world.reset(episode_seed)
        self.agents = self.possible_agents[:]
        obs = self.world.observe()
        arrays = self.world.reset_info_arrays()
        common = self._common_info()
        observations = {agent: obs[i] for i, agent in enumerate(self.agents)}
        infos = {
            agent: {key: float(value[i]) for key, value in arrays.items()} | common
            for i, agent in enumerate(self.agents)
        }
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def _common_info(self) -> dict[str, Any]:
        world = self.world
        info: dict[str, Any] = {"time_s": float(world.sim.time_s), "episode_seed": world.episode_seed}  # type: ignore[union-attr]
        if self.cfg.expose_wind:
            info["wind_kt"] = world.sim.wind_kt.copy()  # type: ignore[union-attr]
        return info

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:
        """Fly one decision period (300 s). ``actions`` maps every live agent to its action;
        entries for agents already done are ignored (None is fine)."""
        world = self.world
        if not world.started:
            raise ValueError("parallel_env: step() before reset(); call reset() first")
        if not isinstance(actions, dict):
            raise ValueError(
                f"parallel_env: actions must be a dict {{agent: action}}, got {type(actions).__name__}; "
                f"agents alive: {self.agents}"
            )
        unknown = [agent for agent in actions if agent not in self._index]
        if unknown:
            raise ValueError(f"parallel_env: unknown agent(s) {unknown}; agents of this env: {self.possible_agents}")
        if not self.agents:
            if actions and any(value is not None for value in actions.values()):
                raise ValueError(
                    "parallel_env: the episode is over (every aircraft has arrived or left, or the time "
                    "limit passed); call reset() before step()"
                )
            return {}, {}, {}, {}, {}
        missing = [agent for agent in self.agents if agent not in actions]
        if missing:
            raise ValueError(f"parallel_env: no action for live agent(s) {missing}; give one for each of {self.agents}")
        n = world.n_aircraft
        live = self.agents
        index = [self._index[agent] for agent in live]
        raw = np.zeros((n, 2))
        try:
            stacked = np.asarray([actions[agent] for agent in live], dtype=np.float64)
            ok = stacked.shape == (len(live), 2) and bool(np.isfinite(stacked).all())
        except (TypeError, ValueError):
            ok = False
        if ok:
            raw[index] = stacked
        if not ok:  # find the culprit and say what is wrong with it
            for agent in live:
                _agent_action(agent, actions[agent])
        clipped_actions, clipped = validate_step_actions(raw, (n, 2), "parallel_env")
        outcome, trace = world.step(clipped_actions)
        arrays = world.step_info_arrays(outcome, trace, clipped)
        obs = world.observe()
        flying = world.flying.tolist()
        truncate = world.truncated
        common = self._common_info()
        rewards_list = outcome.rewards[0].tolist()
        waypoints = arrays.pop("waypoint_nm")
        min_separation = arrays.pop("min_separation_nm")
        columns = {key: value.tolist() for key, value in arrays.items()}
        observations: dict[str, np.ndarray] = {}
        rewards: dict[str, float] = {}
        terminations: dict[str, bool] = {}
        truncations: dict[str, bool] = {}
        infos: dict[str, dict[str, Any]] = {}
        for agent, i in zip(live, index):
            observations[agent] = obs[i]
            rewards[agent] = rewards_list[i]
            terminations[agent] = not flying[i]
            truncations[agent] = flying[i] and truncate
            info = {key: column[i] for key, column in columns.items()}
            info["min_separation_nm"] = min_separation
            info["waypoint_nm"] = waypoints[i]
            info.update(common)
            infos[agent] = info
        self.agents = [agent for agent in live if not (terminations[agent] or truncations[agent])]
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global state (``state_space``): every aircraft slot in the workspace frame
        (see ``atc_nf_env.envs.observations``)."""
        if not self.world.started:
            raise ValueError("parallel_env: state() before reset(); call reset() first")
        return self.world.global_state()

    def render(self) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"``; draws into a window for
        "human" (nothing without a display); None (with a warning) without a render mode."""
        return render_world(self, self.world)

    def close(self) -> None:
        close_renderers(self)


def _agent_action(agent: str, value: Any) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"parallel_env: action for {agent} = {value!r} is not a pair of numbers; expected shape (2,) in [-1, 1]"
        ) from None
    if array.shape != (2,):
        raise ValueError(
            f"parallel_env: action for {agent} has shape {array.shape}; expected (2,): [distance, angle] in [-1, 1]"
        )
    if not np.isfinite(array).all():
        raise ValueError(
            f"parallel_env: action for {agent} contains NaN or inf: {array.tolist()}; allowed: finite numbers "
            "in [-1, 1] (values outside are clipped)"
        )
    return array


def parallel_env(**kwargs: Any) -> ATCParallelEnv:
    """The PettingZoo ParallelEnv (see ``ATCParallelEnv`` for spaces, rewards, arguments)."""
    return ATCParallelEnv(**kwargs)


class raw_env(parallel_to_aec_wrapper):
    """The AEC form without PettingZoo's order-enforcing wrapper: agents act in turn
    (``aircraft_0`` first) and the world flies one period when the last live agent has
    acted. Same keyword arguments as ``parallel_env``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(ATCParallelEnv(**kwargs))


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form (``raw_env`` in PettingZoo's ``OrderEnforcingWrapper``)."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))


__all__ = ["AGENT_PREFIX", "ATCParallelEnv", "env", "parallel_env", "raw_env"]
