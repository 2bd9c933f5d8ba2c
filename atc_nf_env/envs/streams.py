"""Environments of traffic streams (``scenario="stream-R"``): aircraft join and leave.

``parallel_env(scenario="stream-60")``, ``env(...)``, ``gym.make("atc_nf_env/Stream-v1",
scenario="stream-60")`` (``STREAM_ENV_ID``; stream-30 by default) and ``gym.make(ENV_ID,
scenario="stream-60")`` build the classes here; the other keyword arguments are the
common ones (``atc_nf_env.envs.EnvConfig``), with these differences:

- ``max_aircraft`` sets the aircraft slots, the most airborne at once (default: the
  stream's ``max_airborne``, ``scenarios.default_max_airborne``); an entry waits while
  every slot is taken.
- The episode ends at the stream's length (``stream-60``: 120 min; ``stream-60-90min``:
  90 min), or at ``max_episode_minutes`` / ``max_cycles`` if one is given (not None;
  any value, 180 included) and shorter: every aircraft still airborne is then truncated.
- ``render_mode`` "rgb_array" or "human" draws the flights airborne, labelled with
  their flight numbers, and the sector's edge (``atc_nf_env.rendering.stream_snapshot``).

PettingZoo: the agents are the flights, ``flight_0`` ... ``flight_{F-1}``, in the order
they are due; ``possible_agents`` holds the most flights a stream of that rate and length
schedules (``scenarios.max_stream_flights``), fixed per env. ``agents`` are the flights
airborne: a flight joins at the step after which it entered, and terminates when it
arrives or leaves (never to return); one that enters at the episode's last instant has
no period left to fly and never joins. Periods in which no aircraft is airborne are flown
inside ``reset``/``step`` (nothing moves but the clock), so ``agents`` is empty only at
the end of the episode, or from the reset on when no flight enters before the time limit
(then ``step({})`` returns empty dicts, and the AEC form's ``agent_iter`` yields nothing). Observations, actions and rewards per flight are the encounter
env's (``ATCParallelEnv``), the reward of a period counted from the flight's slot.

Gymnasium: ``StreamEnv``'s observation is a dict of ``aircraft`` Box(M, D) (the encounter
env's per-aircraft observation in each of the M slots, zeros where empty) and ``mask``
MultiBinary(M) (1: an aircraft is airborne in that slot); its action Box(-1, 1, (M, 2)),
rows of empty slots ignored; its reward the sum over the aircraft; it never terminates and is truncated at the
episode's end. ``info["slot_flight"]``
maps slots to flights (-1: empty), and ``info["stream"]`` holds the stream's metrics at
the episode's end.

Units: nm, kt, s.

Version History: v1 (the PettingZoo name ``atc_nf_stream_v1``, the Gymnasium ID
``atc_nf_env/Stream-v1``): the kernel's integration among neighbours of
``atc_nf_env/Encounter-v1``; v0: the stream envs before it, reached through
``atc_nf_env/Encounter-v0``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv
from pettingzoo.utils import AgentSelector
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from atc_nf_env.envs import RENDER_MODES, EnvConfig, draw_episode_seed, episode_wind
from atc_nf_env.envs.centralized import close_renderers, render_world
from atc_nf_env.envs.actions import waypoints_for_state
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.envs.rewards import RewardWeights
from atc_nf_env.kernel import ARRIVED, FLYING, LEFT, S_DEST_X, S_DEST_Y, S_STATUS, S_X, S_Y
from atc_nf_env.scenarios import StreamScenario, check_seed, make_scenario, max_stream_flights
from atc_nf_env.streams import StreamSimulation
from atc_nf_env.units import DECISION_PERIOD_S

AGENT_PREFIX = "flight_"


def is_stream(spec: Any) -> bool:
    """Whether the ``scenario`` argument names or is a traffic stream."""
    if isinstance(spec, StreamScenario):
        return True
    return isinstance(spec, str) and spec.startswith("stream-") and not spec.endswith(".json")


class StreamWorld:
    """One world of a stream for the environments: a ``StreamSimulation`` flown one
    decision period per step, with each period's rewards and ends per slot."""

    def __init__(self, cfg: EnvConfig, where: str) -> None:
        if not is_stream(cfg.scenario):
            raise ValueError(
                f"{where}: scenario = {cfg.scenario!r} is not a traffic stream; allowed: 'stream-R', "
                "'stream-R-Dmin' or a StreamScenario (an encounter: atc_nf_env/Encounter-v1, parallel_env)"
            )
        self.cfg = cfg
        self.spec = cfg.scenario
        template = cfg.scenario if isinstance(cfg.scenario, StreamScenario) else make_scenario(cfg.scenario, seed=0)
        assert isinstance(template, StreamScenario)
        self.template = template
        self.n_slots = int(template.max_airborne if cfg.max_aircraft is None else cfg.max_aircraft)
        if isinstance(cfg.scenario, StreamScenario):
            self.max_flights = template.n_flights
        else:
            self.max_flights = max_stream_flights(template.rate_per_hour, template.duration_s / 60.0)
        self.obs_spec = ObservationSpec.for_config(cfg.config, cfg.n_neighbours, cfg.expose_wind)
        # The stream's length, unless a time limit was given (an explicit 180 min too; the
        # encounters' default applies only to encounters).
        limit_s = cfg.max_decisions * DECISION_PERIOD_S if cfg.time_limit_given else template.duration_s
        self.limit_s = min(template.duration_s, limit_s)
        self.weights: RewardWeights = cfg.reward_weights
        self.sim: StreamSimulation | None = None
        self.episode_seed = -1
        self._period_steps = round(DECISION_PERIOD_S / cfg.config.dt_s)

    # ----------------------------------------------------------------- episode
    def scenario(self, episode_seed: int) -> StreamScenario:
        scenario = self.template if isinstance(self.spec, StreamScenario) else make_scenario(self.spec, episode_seed)
        assert isinstance(scenario, StreamScenario)
        if scenario.max_airborne != self.n_slots:
            scenario = dataclasses.replace(scenario, max_airborne=self.n_slots)
        return scenario

    def reset(self, episode_seed: int) -> None:
        self.episode_seed = int(episode_seed)
        wind = episode_wind(episode_seed, self.cfg.wind_sigma)
        self.wind = wind[None].copy()
        self.sim = StreamSimulation(self.scenario(episode_seed), config=self.cfg.config, wind_kt=wind)
        self._skip_empty()
        self.obs = self._observe()

    @property
    def time_s(self) -> float:
        assert self.sim is not None
        return self.sim.time_s

    @property
    def truncated(self) -> bool:
        return self.time_s >= self.limit_s - 1e-9

    @property
    def over(self) -> bool:
        """The episode's end: the stream's length (or a shorter limit) has passed, with
        aircraft possibly still airborne: a truncation, never a termination."""
        return self.truncated

    def _skip_empty(self) -> None:
        """Fly the periods in which no aircraft is airborne (only the clock moves)."""
        sim = self.sim
        assert sim is not None
        while sim.airborne == 0 and not self.over:
            seconds = min(DECISION_PERIOD_S, self.limit_s - sim.time_s)
            sim.advance(sim.state[0, :, S_X : S_Y + 1].copy(), seconds)

    def _observe(self) -> np.ndarray:
        assert self.sim is not None
        fraction = np.array([min(1.0, self.time_s / self.limit_s)])
        return self.obs_spec.observe(self.sim.state, fraction, self.wind, self.n_slots)[0]

    def slot_flight(self) -> np.ndarray:
        assert self.sim is not None
        return self.sim.slot_flight.copy()

    def global_state(self) -> np.ndarray:
        assert self.sim is not None
        fraction = np.array([min(1.0, self.time_s / self.limit_s)])
        return self.obs_spec.global_state(self.sim.state, fraction, self.wind, self.n_slots)[0]

    def step(self, actions: np.ndarray) -> dict[str, np.ndarray]:
        """Fly one period with actions (slots, 2) (clipped to [-1, 1]; empty slots' rows
        ignored). Returns per slot as flown (before the next entries): ``flight``,
        ``reward``, ``ended`` (arrived or left), ``arrived``, ``obs`` (observations as
        flown), then moves on to the next decision (entries, empty periods skipped)."""
        sim = self.sim
        assert sim is not None
        state = sim.state
        flight = sim.slot_flight.copy()
        flying = state[0, :, S_STATUS] == FLYING
        before = np.hypot(state[0, :, S_DEST_X] - state[0, :, S_X], state[0, :, S_DEST_Y] - state[0, :, S_Y])
        clipped = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        waypoints = waypoints_for_state(
            clipped[None], state, self.cfg.action_mapping, self.template.workspace_radius_nm,
            self.cfg.config.aircraft_radius_nm,
        )[0]
        seconds = min(DECISION_PERIOD_S, self.limit_s - sim.time_s)
        trace = sim.advance(waypoints, seconds, next_decision=False)
        after = np.hypot(state[0, :, S_DEST_X] - state[0, :, S_X], state[0, :, S_DEST_Y] - state[0, :, S_Y])
        status = state[0, :, S_STATUS]
        arrived = flying & (status == ARRIVED)
        left = flying & (status == LEFT)
        w = self.weights
        los = np.triu(trace.los_pairs[0], 1) | np.triu(trace.los_pairs[0], 1).T
        reward = (
            w.progress_per_100nm * (before - after) / 100.0
            - w.envelope_violation * trace.violation_steps[0] / self._period_steps
            - w.loss_of_separation * los.sum(axis=1)
            + w.arrival_bonus * arrived
            - w.left_workspace_penalty * left
        )
        outcome = {
            "flight": flight,
            "flew": flying,
            "reward": np.where(flying, reward, 0.0),
            "ended": arrived | left,
            "arrived": arrived,
            "obs": self._observe(),
        }
        sim.next_decision()
        self._skip_empty()
        self.obs = self._observe()
        return outcome


def _agent_name(flight: int) -> str:
    return f"{AGENT_PREFIX}{flight}"


class StreamParallelEnv(ParallelEnv):
    """The PettingZoo parallel env of a traffic stream (see the module docstring)."""

    metadata = {"name": "atc_nf_stream_v1", "render_modes": list(RENDER_MODES), "is_parallelizable": True,
                "render_fps": 4}

    def __init__(self, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "parallel_env")
        self.world = StreamWorld(cfg, "parallel_env")
        self.render_mode = cfg.render_mode
        self._renderer: Any = None
        self._viewer: Any = None
        self.possible_agents = [_agent_name(k) for k in range(self.world.max_flights)]
        self.agents: list[str] = []
        space = self.world.obs_spec.space()
        self.observation_spaces = dict.fromkeys(self.possible_agents, space)
        action = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_spaces = dict.fromkeys(self.possible_agents, action)
        self.state_space = self.world.obs_spec.state_space(self.world.n_slots)
        self._np_random: np.random.Generator | None = None

    def observation_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        self._check_agent(agent)
        return self.action_spaces[agent]

    def _check_agent(self, agent: Any) -> None:
        if agent not in self.observation_spaces:
            raise ValueError(
                f"unknown agent {agent!r}; agents of this env: {AGENT_PREFIX}0 ... {AGENT_PREFIX}{self.world.max_flights - 1}"
            )

    def _live(self) -> dict[str, int]:
        """Airborne flights' names -> their slots."""
        slots = self.world.slot_flight()
        return {_agent_name(int(f)): int(s) for s, f in enumerate(slots) if f >= 0}

    def _info(self, slot: int) -> dict[str, Any]:
        return {"slot": slot, "time_s": self.world.time_s, "episode_seed": self.world.episode_seed}

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._np_random, _ = seeding.np_random(check_seed(seed))
            episode_seed = check_seed(seed)
        else:
            if self._np_random is None:
                self._np_random, _ = seeding.np_random(None)
            episode_seed = draw_episode_seed(self._np_random, stream=True)
        self.world.reset(episode_seed)
        live = self._live()
        self.agents = sorted(live, key=lambda a: int(a[len(AGENT_PREFIX):]))
        obs = {agent: self.world.obs[live[agent]] for agent in self.agents}
        if self.render_mode == "human":
            self.render()
        return obs, {agent: self._info(live[agent]) for agent in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self.world.sim is None:
            raise RuntimeError("call reset() before step()")
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict of agent -> action, got {type(actions).__name__}")
        if not self.agents:  # the episode is over, or no flight entered in its window
            if any(value is not None for value in actions.values()):
                raise ValueError(
                    "parallel_env: the episode is over (its time has passed, or no flight entered in it); "
                    "call reset() before step()"
                )
            return {}, {}, {}, {}, {}
        live = self._live()
        unknown = sorted(set(actions) - set(live), key=str)
        if unknown:
            raise ValueError(f"parallel_env: action(s) for agent(s) not airborne {unknown}; agents airborne: {self.agents}")
        missing = sorted(set(live) - set(actions))
        if missing:
            raise ValueError(f"parallel_env: no action for live agent(s) {missing}")
        table = np.zeros((self.world.n_slots, 2))
        for agent, value in actions.items():
            action = np.asarray(value, dtype=np.float64)
            if action.shape != (2,) or not np.isfinite(action).all():
                raise ValueError(f"action of {agent} = {value!r}: must be 2 finite numbers in [-1, 1]")
            table[live[agent]] = action
        outcome = self.world.step(table)
        truncated = self.world.truncated
        obs, rewards, terminations, truncations, infos = {}, {}, {}, {}, {}
        for agent, slot in live.items():
            ended = bool(outcome["ended"][slot])
            obs[agent] = outcome["obs"][slot]
            rewards[agent] = float(outcome["reward"][slot])
            terminations[agent] = ended
            truncations[agent] = truncated and not ended
            infos[agent] = self._info(slot) | {"arrived": bool(outcome["arrived"][slot])}
        now = self._live()
        for agent, slot in now.items():
            if agent in live:
                obs[agent] = self.world.obs[slot]  # after the skipped periods, if any
                continue
            if truncated:  # entered at the episode's last instant: no period left to fly
                continue
            obs[agent] = self.world.obs[slot]
            rewards[agent] = 0.0
            terminations[agent] = False
            truncations[agent] = truncated
            infos[agent] = self._info(slot)
        self.agents = [] if truncated else [
            a for a in sorted(now, key=lambda a: int(a[len(AGENT_PREFIX):])) if not terminations[a]
        ]
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        return self.world.global_state()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"`` (see
        ``ATCParallelEnv.render``): the flights airborne and the sector's edge."""
        return render_world(self, self.world, mode)

    def close(self) -> None:
        close_renderers(self)

    def stream_metrics(self) -> dict[str, Any]:
        """The stream's metrics so far (``StreamSimulation.stream_metrics``)."""
        assert self.world.sim is not None
        return self.world.sim.stream_metrics()


class StreamEnv(gym.Env):
    """The centralized Gymnasium env of a traffic stream (see the module docstring)."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 4}

    def __init__(self, **kwargs: Any) -> None:
        cfg = EnvConfig.from_kwargs(kwargs, "StreamEnv")
        self.world = StreamWorld(cfg, "StreamEnv")
        self.render_mode = cfg.render_mode
        self._renderer: Any = None
        self._viewer: Any = None
        m = self.world.n_slots
        box = self.world.obs_spec.space()
        self.observation_space = spaces.Dict({
            "aircraft": spaces.Box(
                np.repeat(box.low[None], m, axis=0), np.repeat(box.high[None], m, axis=0), dtype=np.float32
            ),
            "mask": spaces.MultiBinary(m),
        })
        self.action_space = spaces.Box(-1.0, 1.0, shape=(m, 2), dtype=np.float32)

    def _observation(self) -> dict[str, np.ndarray]:
        mask = (self.world.slot_flight() >= 0).astype(np.int8)
        return {"aircraft": np.where(mask[:, None] > 0, self.world.obs, 0.0).astype(np.float32), "mask": mask}

    def _info(self) -> dict[str, Any]:
        info = {"slot_flight": self.world.slot_flight(), "time_s": self.world.time_s,
                "episode_seed": self.world.episode_seed}
        if self.world.over:
            assert self.world.sim is not None
            info["stream"] = self.world.sim.stream_metrics()
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start an episode of the stream: a given ``seed`` flies episode seed ``seed``; None
        draws the next episode seed from the env's generator. ``options`` is not used.

        Returns:
            The observation (``aircraft`` (M, D) float32, ``mask`` (M,): the slots airborne)
            and the info dict (``slot_flight``, ``time_s``, ``episode_seed``).
        """
        if seed is not None:
            check_seed(seed)
        super().reset(seed=seed)
        episode_seed = check_seed(seed) if seed is not None else draw_episode_seed(self.np_random, stream=True)
        self.world.reset(episode_seed)
        if self.render_mode == "human":
            self.render()
        return self._observation(), self._info()

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        """Fly one decision period (300 s) with ``action``: (M, 2) finite numbers, one row
        per slot (rows of empty slots are ignored).

        Returns:
            ``(observation, reward, terminated, truncated, info)``: the reward summed over the
            airborne aircraft; terminated is always False (a stream has no end state);
            truncated at the episode's end, when ``info["stream"]`` holds the stream's metrics.
        """
        if self.world.sim is None:
            raise RuntimeError("call reset() before step()")
        array = np.asarray(action, dtype=np.float64)
        if array.shape != self.action_space.shape or not np.isfinite(array).all():
            raise ValueError(
                f"action has shape {array.shape}: must be {self.action_space.shape} finite numbers in [-1, 1] "
                "(one row per slot; rows of empty slots are ignored)"
            )
        outcome = self.world.step(array)
        reward = float(outcome["reward"].sum())
        if self.render_mode == "human":
            self.render()
        return self._observation(), reward, False, self.world.truncated, self._info()

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """An (H, W, 3) uint8 frame for ``render_mode="rgb_array"``: the flights airborne
        and the sector's edge; a window for "human"."""
        return render_world(self, self.world, mode)

    def close(self) -> None:
        close_renderers(self)


class StreamAECEnv(parallel_to_aec_wrapper):
    """The AEC form of a traffic stream: PettingZoo's ``parallel_to_aec`` conversion of
    ``StreamParallelEnv`` (agents that join take their turns from the next cycle on), which
    also takes an episode in which no flight enters before the time limit: no agent from
    the reset on, ``agent_selection`` None, ``agent_iter`` yields nothing (PettingZoo's
    conversion divides by the number of agents there)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(StreamParallelEnv(**kwargs))

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        # PettingZoo's reset, less its checks of infos (the parallel env gives one per
        # agent) and with an empty agent list allowed.
        self._observations, self.infos = self.env.reset(seed=seed, options=options)
        self.agents = self.env.agents[:]
        self._live_agents = self.agents[:]
        self._actions = dict.fromkeys(self.agents)
        self._agent_selector = AgentSelector(self._live_agents)
        self.agent_selection = self._agent_selector.reset() if self.agents else None
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.rewards = dict.fromkeys(self.agents, 0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0)
        self.new_agents = []
        self.new_values = {}


__all__ = ["AGENT_PREFIX", "StreamAECEnv", "StreamEnv", "StreamParallelEnv", "StreamWorld", "is_stream"]
