"""The PettingZoo environment: ``parallel_env(**kwargs)`` (ParallelEnv), ``env(**kwargs)``
(AEC, order-enforced) and ``raw_env`` (AEC, unwrapped)."""

from __future__ import annotations

import operator
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.env_logger import EnvLogger
from pettingzoo.utils import AgentSelector
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from atc_nf_env.envs import EnvConfig, draw_episode_seed
from atc_nf_env.envs.centralized import (
    AIRCRAFT_INFO_KEYS,
    EncounterWorld,
    all_finite,
    close_renderers,
    render_world,
)
from atc_nf_env.scenarios import check_seed

AGENT_PREFIX = "aircraft_"
_SCALAR_INFO_KEYS = tuple(key for key in AIRCRAFT_INFO_KEYS if key != "waypoint_nm")
_INFO_KEYS = (*_SCALAR_INFO_KEYS, "waypoint_nm", "min_separation_nm", "time_s", "episode_seed")
_REWARD_FIELD = _SCALAR_INFO_KEYS.index("aircraft_reward")
_ROW_INFO_KEYS = (*_SCALAR_INFO_KEYS, "waypoint_nm")
_INFO_TEMPLATE: dict[str, Any] = dict.fromkeys(_INFO_KEYS)


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
    then removed from ``agents``. Every agent of the step is truncated after
    ``max_cycles`` decisions, or ceil(``max_episode_minutes`` / 5) (default None: 180 min, 36
    steps, room for the 6-aircraft encounter's ~70-90 min flights); one that arrives or
    leaves on that very step is terminated and truncated, so the last step never mixes
    agents only terminated with agents only truncated (RLlib's AEC wrapper ends an
    episode only on all-terminated or all-truncated).
    Once no agent is left, ``step({})`` returns empty dicts (as PettingZoo's own
    conversion wrappers do; SuperSuit's ``black_death_v3`` relies on it), and a step with
    any action raises ValueError (call ``reset``).

    ## Arguments

    ``atc_nf_env.parallel_env(scenario="converging-4", wind_sigma=5.17, render_mode=None,
    max_aircraft=None, n_neighbours=4, max_episode_minutes=None, max_cycles=None,
    expose_wind=False, action_mapping=None, reward_weights=None, config=None,
    render_size_px=512)``: see ``atc_nf_env.envs``. Unknown arguments raise TypeError
    listing the allowed ones.

    ## Info

    Per agent, the same keys and types after ``reset`` and after every ``step`` (libraries
    such as TorchRL build their specs from the reset): ``airspeed_kt`` (last integration
    step), ``airspeed_min_kt``, ``airspeed_max_kt`` (over the step), ``distance_to_go_nm``,
    ``nearest_nm`` (this aircraft to the nearest one still flying, now), ``los_count``
    (int), ``envelope_violation`` (bool, this step), ``envelope_violation_fraction``,
    ``action_clipped``, ``arrived``, ``left_workspace`` (bools), ``aircraft_reward`` (the
    agent's reward, as in ``rewards``), ``waypoint_nm`` ((2,) float64), ``min_separation_nm``
    (smallest distance between any two aircraft during the step, inf with fewer than two
    flying), ``time_s``, ``episode_seed`` (int); ``wind_kt`` ((2,)) only with
    ``expose_wind=True``. At reset the values are neutral: nothing clipped, violated or
    lost, reward 0, the airspeed range and separation those of the initial state, the
    waypoint the destination.

    ## Version History

    * v1: the kernel's integration among neighbours changed (θ̇_nh at its true rate inside
      sub-steps, error control of steps with a pair within the sensing radius, guard 9's
      right-hand rule retuned; CHANGELOG): every trajectory with two aircraft within the
      12-nm sensing radius changed. ``atc_nf_env/Encounter-v0`` is retired; making it
      raises an error that names v1.
    * v0: initial version.
    """

    metadata = {
        "name": "atc_nf_env_v1",
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
        self._all_index = np.arange(n, dtype=np.int64)
        self._live_index = self._all_index
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
            seed = check_seed(seed)  # the project's one seed rule
            self._np_random, self._np_random_seed = seeding.np_random(seed)
            episode_seed = seed
        else:
            episode_seed = draw_episode_seed(self.np_random)
        self.world.reset(episode_seed)
        self.agents = self.possible_agents[:]
        self._live_index = self._all_index
        observations = dict(zip(self.agents, self.world.observe()))
        infos = dict(zip(self.agents, self._info_list(None)))
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def _info_list(self, index: list[int] | None, rows: list[tuple] | None = None) -> list[dict[str, Any]]:
        """Per-agent info dicts of the aircraft ``index`` (all when None) from the world's
        info records (the same keys at reset and at every step); ``rows`` are the
        records' ``tolist()`` when the caller has them."""
        world = self.world
        if rows is None:
            rows = world.info.tolist()  # every aircraft's scalars as Python objects, one call
        waypoints = list(world.last_waypoints)  # (2,) views of an array fresh every step
        if index is not None:
            rows = [rows[i] for i in index]
            waypoints = [waypoints[i] for i in index]
        # Copies of a dict that has every key already (in order) and the step's common
        # values: quicker than building each agent's dict key by key.
        step_info = _INFO_TEMPLATE.copy()
        step_info["min_separation_nm"] = world.min_separation_nm
        step_info["time_s"] = float(world.sim.time_s)  # type: ignore[union-attr]
        step_info["episode_seed"] = world.episode_seed
        infos = []
        for row, waypoint in zip(rows, waypoints):
            info = step_info.copy()
            info.update(zip(_ROW_INFO_KEYS, row + (waypoint,)))
            infos.append(info)
        if self.cfg.expose_wind:
            wind = world.sim.wind_kt  # type: ignore[union-attr]
            for info in infos:
                info["wind_kt"] = wind.copy()
        return infos

    def _stacked_actions(self, values: list[Any], live: list[str]) -> np.ndarray:
        """The live agents' actions (``values`` in the order of ``live``) as finite
        float64 (len(live), 2); ValueError naming the culprit and what is allowed."""
        try:
            stacked = np.array(values)
            # complex (its imaginary part would be dropped), objects, strings: the slow path
            ok = stacked.dtype.kind in "biuf" and stacked.shape == (len(live), 2)
            if ok:
                stacked = stacked.astype(np.float64, copy=False)
                ok = all_finite(stacked)
        except (TypeError, ValueError):
            ok = False
        if not ok:  # find the culprit and say what is wrong with it (or convert one by one)
            stacked = np.array([_agent_action(agent, value) for agent, value in zip(live, values)])
        return stacked

    def _advance(
        self, stacked: np.ndarray
    ) -> tuple[list[str], list[np.ndarray], list[float], list[bool], bool, list[dict[str, Any]]]:
        """Fly one period with the live agents' finite actions ``stacked`` (their order),
        update ``agents``, and return, per agent live at the start (in that order): the
        agents, observations, rewards, terminations, the truncation flag (the same for
        all) and infos."""
        world = self.world
        live = self.agents
        n = world.n_aircraft
        all_live = len(live) == n
        if all_live:
            raw = stacked
        else:
            raw = np.zeros((n, 2))
            raw[self._live_index] = stacked
        world.step(raw)  # clips to the box, and reports what it clipped in the infos
        observations = list(world.observe())  # (D,) views of an array fresh every step
        rows = world.info.tolist()  # every aircraft's scalars as Python objects, one call
        flying = world.flying.tolist()
        index = None if all_live else self._live_index.tolist()
        infos = self._info_list(index, rows)
        if index is not None:
            observations = [observations[i] for i in index]
            rows = [rows[i] for i in index]
            flying = [flying[i] for i in index]
        rewards = [row[_REWARD_FIELD] for row in rows]
        terminations = [not alive for alive in flying]
        truncate = world.truncated
        # At the time limit every agent of the step is truncated, also one that arrives or
        # leaves on that step (then terminated too): the last step never mixes agents that
        # are only terminated with agents that are only truncated, so wrappers that end
        # the episode on "all terminated or all truncated" (RLlib's) end it cleanly.
        if truncate:
            self.agents = []
        elif not all(flying):
            self.agents = [agent for agent, alive in zip(live, flying) if alive]
        if len(self.agents) != len(live):
            self._live_index = np.array([self._index[agent] for agent in self.agents], dtype=np.int64)
        return live, observations, rewards, terminations, truncate, infos

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:
        """Fly one decision period (300 s). ``actions`` maps every live agent to its action;
        entries for agents already done are ignored (None is fine)."""
        if not self.world.started:
            raise ValueError("parallel_env: step() before reset(); call reset() first")
        if not isinstance(actions, dict):
            raise ValueError(
                f"parallel_env: actions must be a dict {{agent: action}}, got {type(actions).__name__}; "
                f"agents alive: {self.agents}"
            )
        live = self.agents
        if len(actions) != len(live) or not live:
            unknown = [agent for agent in actions if agent not in self._index]
            if unknown:
                raise ValueError(
                    f"parallel_env: unknown agent(s) {unknown}; agents of this env: {self.possible_agents}"
                )
        if not live:
            if actions and any(value is not None for value in actions.values()):
                raise ValueError(
                    "parallel_env: the episode is over (every aircraft has arrived or left, or the time "
                    "limit passed); call reset() before step()"
                )
            return {}, {}, {}, {}, {}
        try:
            values = [actions[agent] for agent in live]
        except KeyError:
            unknown = [agent for agent in actions if agent not in self._index]
            if unknown:
                raise ValueError(
                    f"parallel_env: unknown agent(s) {unknown}; agents of this env: {self.possible_agents}"
                ) from None
            missing = [agent for agent in live if agent not in actions]
            raise ValueError(
                f"parallel_env: no action for live agent(s) {missing}; give one for each of {live}"
            ) from None
        live, observations, rewards, terminations, truncate, infos = self._advance(self._stacked_actions(values, live))
        if self.render_mode == "human":
            self.render()
        return (
            dict(zip(live, observations)),
            dict(zip(live, rewards)),
            dict(zip(live, terminations)),
            dict.fromkeys(live, truncate),
            dict(zip(live, infos)),
        )

    def state(self) -> np.ndarray:
        """The global state (``state_space``): every aircraft slot in the workspace frame
        (see ``atc_nf_env.envs.observations``)."""
        if not self.world.started:
            raise ValueError("parallel_env: state() before reset(); call reset() first")
        return self.world.global_state()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"``; draws into a window for
        "human" (nothing without a display); None (with a warning) without a render mode.
        ``mode`` (RLlib's wrappers pass it) must be None or the env's ``render_mode``."""
        return render_world(self, self.world, mode)

    def close(self) -> None:
        close_renderers(self)


def _agent_action(agent: str, value: Any) -> np.ndarray:
    try:
        if np.iscomplexobj(value):  # float64 would silently drop the imaginary part
            raise TypeError("complex numbers")
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


def parallel_env(**kwargs: Any) -> ParallelEnv:
    """The PettingZoo ParallelEnv (see ``ATCParallelEnv`` for spaces, rewards, arguments);
    of a traffic stream (``scenario="stream-R"``), ``StreamParallelEnv``, whose agents
    join and leave (``atc_nf_env.envs.streams``)."""
    from atc_nf_env.envs.streams import StreamParallelEnv, is_stream

    if is_stream(kwargs.get("scenario")):
        return StreamParallelEnv(**kwargs)
    return ATCParallelEnv(**kwargs)


class raw_env(parallel_to_aec_wrapper):
    """The AEC form without PettingZoo's order-enforcing wrapper: agents act in turn
    (``aircraft_0`` first) and the world flies one period when the last live agent has
    acted. Same keyword arguments as ``parallel_env``.

    It behaves as PettingZoo's ``parallel_to_aec_wrapper`` around ``parallel_env`` (the
    same agents, selections, rewards, cumulative rewards, terminations, truncations,
    infos and observations after every call), with less work per agent: the turn is a
    position in the live agents' list, the actions wait in a list, and the period's
    results are put in the dicts once, without the wrapper's copies."""

    env: ATCParallelEnv

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(ATCParallelEnv(**kwargs))
        self._order: list[str] = []
        self._turn = 0
        self._pending: list[Any] = []

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        self._observations, self.infos = self.env.reset(seed=seed, options=options)
        self._order = self.env.agents
        self._turn = 0
        self._pending = [None] * len(self._order)
        self.agents = self._order[:]
        self.agent_selection = self._order[0]
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.rewards = dict.fromkeys(self.agents, 0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0)
        self._skip_agent_selection = None

    def observe(self, agent: str) -> np.ndarray:
        return self._observations[agent]

    def last(self, observe: bool = True) -> tuple[np.ndarray | None, float, bool, bool, dict[str, Any]]:
        agent = self.agent_selection
        return (
            self._observations[agent] if observe else None,
            self._cumulative_rewards[agent],
            self.terminations[agent],
            self.truncations[agent],
            self.infos[agent],
        )

    def step(self, action: Any) -> None:
        """Store the selected agent's action (None for an agent that has ended), and fly
        the period when the last live agent has acted."""
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        turn = self._turn
        order = self._order
        self._pending[turn] = action
        if turn + 1 < len(order):
            if turn == 0:  # the cycle's first action: last period's rewards are spent
                self._clear_rewards()
            self._turn = turn + 1
            self.agent_selection = order[turn + 1]
            return
        par = self.env
        live, observations, rewards, terminations, truncate, infos = par._advance(
            par._stacked_actions(self._pending, order)  # one entry per agent of ``order``
        )
        self._observations = dict(zip(live, observations))
        self.rewards = dict(zip(live, rewards))
        self._cumulative_rewards = self.rewards.copy()
        self.terminations = dict(zip(live, terminations))
        self.truncations = dict.fromkeys(live, truncate)
        self.infos = dict(zip(live, infos))
        still = par.agents
        self._turn = 0
        if len(still) == len(live):  # nobody ended: no dead agent to step first
            self.agents = still[:]
            self.agent_selection = still[0]
            return
        ended = [agent for agent in live if agent not in still]
        self.agents = still + sorted(ended, key=str)
        if still:
            self._order = still
            self._pending = [None] * len(still)
            self.agent_selection = still[0]
        self._deads_step_first()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """See ``ATCParallelEnv.render``."""
        return self.env.render(mode)


def _forwarded(name: str) -> property:
    # A C-level look-up on the raw env. Before the first reset the raw env has none of
    # these attributes: the AttributeError sends Python to the wrapper's ``__getattr__``,
    # which raises PettingZoo's "... cannot be accessed before reset".
    return property(operator.attrgetter(f"env.{name}"), doc=f"The wrapped env's ``{name}`` (after reset).")


class _OrderEnforcingWrapper(wrappers.OrderEnforcingWrapper):
    """PettingZoo's wrapper, with ``render`` taking the mode that RLlib's wrapper passes,
    and what clients use at every agent step (``agents``, ``agent_selection``,
    ``terminations``, ..., ``last()``, ``observe()``, ``step()``) reached directly:
    PettingZoo's wrapper finds the attributes through ``__getattr__`` and the methods
    through its base class, which cost more than the env's own bookkeeping. The same
    errors before the first reset."""

    agents = _forwarded("agents")
    agent_selection = _forwarded("agent_selection")
    terminations = _forwarded("terminations")
    truncations = _forwarded("truncations")
    rewards = _forwarded("rewards")
    infos = _forwarded("infos")
    _cumulative_rewards = _forwarded("_cumulative_rewards")

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        super().reset(seed=seed, options=options)
        # From the first reset on, the wrapper's checks before ``last`` and ``observe``
        # always pass: the raw env's methods answer directly.
        self.last = self.env.last  # type: ignore[method-assign]
        self.observe = self.env.observe  # type: ignore[method-assign]

    def step(self, action: Any) -> None:
        if not self._has_reset:
            EnvLogger.error_step_before_reset()
        self._has_updated = True
        if self.env.agents:
            self.env.step(action)
        else:
            EnvLogger.warn_step_after_terminated_truncated()

    def last(self, observe: bool = True) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if not self._has_reset:
            raise AttributeError("agent_selection cannot be accessed before reset")
        return self.env.last(observe)

    def render(self, mode: str | None = None) -> np.ndarray | None:
        if not self._has_reset:
            EnvLogger.error_render_before_reset()
        return self.env.render(mode)


def env(**kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC form (``raw_env`` in PettingZoo's ``OrderEnforcingWrapper``); of a traffic
    stream, ``StreamAECEnv`` (PettingZoo's ``parallel_to_aec`` conversion of
    ``StreamParallelEnv``, which handles agents that join), in the same wrapper."""
    from atc_nf_env.envs.streams import StreamAECEnv, is_stream

    if is_stream(kwargs.get("scenario")):
        return wrappers.OrderEnforcingWrapper(StreamAECEnv(**kwargs))
    return _OrderEnforcingWrapper(raw_env(**kwargs))


__all__ = ["AGENT_PREFIX", "ATCParallelEnv", "env", "parallel_env", "raw_env"]
