"""The environments: PettingZoo (``parallel_env``, ``env``, ``raw_env``), the centralized
Gymnasium env (``atc_nf_env/Encounter-v1``) and its native vector env.

Every environment takes the same keyword arguments, checked here (``EnvConfig``):

===================  ==================================================================
argument             meaning
===================  ==================================================================
scenario             "converging-N", "random-N" (a new encounter every reset, drawn
                     from the env's seed), a path to a .json file, a dict
                     (``Scenario.to_dict()``'s format) or a Scenario. Default
                     "converging-4".
wind_sigma           standard deviation of each wind component, m/s (default 5.17).
render_mode          None, "rgb_array" or "human".
max_aircraft         aircraft slots (default: the scenario's number); a scenario with
                     fewer aircraft is padded and masked.
n_neighbours         K nearest neighbours in each observation (default 4).
max_episode_minutes  time limit, min (default None: not given, 180 min for an
                     encounter, the stream's length for a traffic stream);
                     truncation after ceil(limit / 5 min) decisions. A value given
                     is always honoured, 180 included.
max_cycles           decision periods (5 min each) before truncation, PettingZoo's
                     name for an episode's length (default None: from
                     max_episode_minutes). Give one of the two, not both.
expose_wind          put the true wind in observations, state and info (default False).
action_mapping       ActionMapping or dict (default 100 ± 40 nm, ±90°).
reward_weights       RewardWeights or dict (see ``atc_nf_env.envs.rewards``).
config               SimConfig: NF gains and integrator (the calibrated defaults).
render_size_px       side of the rendered square frame, pixels (default 512).
===================  ==================================================================

Unknown keyword arguments raise TypeError (as Python does for a function), bad values
ValueError; both name what is allowed.

Seeds: ``reset(seed=s)`` flies episode seed s; a reset without a seed draws its episode
seed from the env's generator, always inside the benchmark's train split (0 … 999 999 999;
for a traffic stream the stream tasks' train split, 3 000 000 000 … 3 999 999 999), so
training never meets a validation or test seed (``drawn_seed_split``). Every env reports
the episode's seed in its info (``"episode_seed"``).

Units at the API: nm, kt, s (the wind's σ in m/s, as in the paper). One env step is
one decision period T = 300 s flown by the batched kernel.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from atc_nf_env.benchmark import SPLITS, STREAM_SPLITS, Split
from atc_nf_env.config import SimConfig, check_aircraft_count
from atc_nf_env.envs.actions import ActionMapping
from atc_nf_env.envs.rewards import RewardWeights
from atc_nf_env.episode import episode_wind_kt
from atc_nf_env.scenarios import Scenario, make_scenario
from atc_nf_env.simulation import check_wind_sigma
from atc_nf_env.units import DECISION_PERIOD_S, WIND_SIGMA_MPS

#: Default time limit, min: the 6-aircraft encounter's flights take ~70-90 min.
MAX_EPISODE_MINUTES: float = 180.0
RENDER_MODES: tuple[str, ...] = ("human", "rgb_array")
_RANDOM = re.compile(r"^random-(\d+)$")


@dataclass(frozen=True)
class EnvConfig:
    """The common keyword arguments of every environment (see the module docstring)."""

    scenario: Any = "converging-4"
    wind_sigma: float = WIND_SIGMA_MPS
    render_mode: str | None = None
    max_aircraft: int | None = None
    n_neighbours: int = 4
    #: The time limit, min: None (not given) becomes ``MAX_EPISODE_MINUTES`` at
    #: construction, so that it is always a number afterwards; ``time_limit_given`` keeps
    #: whether a limit was given (a stream lasts its length unless one was).
    max_episode_minutes: float | None = None
    max_cycles: int | None = None
    expose_wind: bool = False
    action_mapping: ActionMapping = field(default_factory=ActionMapping)
    reward_weights: RewardWeights = field(default_factory=RewardWeights)
    config: SimConfig = field(default_factory=SimConfig)
    render_size_px: int = 512
    #: Whether ``max_episode_minutes`` or ``max_cycles`` was given (not None).
    time_limit_given: bool = field(init=False, default=False)

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any], where: str) -> "EnvConfig":
        """Validate keyword arguments: TypeError for an unknown one, ValueError for a bad
        value, each naming what is allowed."""
        allowed = [f.name for f in fields(cls)]
        unknown = sorted(set(kwargs) - set(allowed))
        if unknown:
            # Python's own wording, which clients match to drop arguments an env does not
            # take (TorchRL's GymEnv retries without ``frameskip``).
            more = f" (and {unknown[1:]})" if len(unknown) > 1 else ""
            raise TypeError(
                f"{where}: got an unexpected keyword argument {unknown[0]!r}{more}; allowed: {allowed}"
            )
        if kwargs.get("max_cycles") is not None and kwargs.get("max_episode_minutes") is not None:
            raise ValueError(
                f"{where}: max_cycles = {kwargs['max_cycles']!r} and max_episode_minutes = "
                f"{kwargs['max_episode_minutes']!r} both set the episode's length; give one of them"
            )
        values = {key: value for key, value in kwargs.items() if not (key == "max_episode_minutes" and value is None)}
        values["action_mapping"] = ActionMapping.coerce(values.get("action_mapping"))
        values["reward_weights"] = RewardWeights.coerce(values.get("reward_weights"))
        config = values.get("config")
        if config is None:
            values["config"] = SimConfig()
        elif not isinstance(config, SimConfig):
            raise ValueError(f"{where}: config = {config!r}: must be a SimConfig (atc_nf_env.config)")
        return cls(**values)

    def __post_init__(self) -> None:
        try:
            check_wind_sigma(self.wind_sigma)
        except TypeError as error:  # the envs' settings are ValueErrors throughout
            raise ValueError(str(error)) from None
        if self.render_mode is not None and self.render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode = {self.render_mode!r}: allowed: None, {', '.join(map(repr, RENDER_MODES))}")
        if self.max_aircraft is not None and (
            isinstance(self.max_aircraft, bool) or not isinstance(self.max_aircraft, (int, np.integer)) or self.max_aircraft < 1
        ):
            raise ValueError(f"max_aircraft = {self.max_aircraft!r}: must be an integer >= 1 (or None)")
        if isinstance(self.n_neighbours, bool) or not isinstance(self.n_neighbours, (int, np.integer)) or self.n_neighbours < 0:
            raise ValueError(f"n_neighbours = {self.n_neighbours!r}: must be an integer >= 0")
        object.__setattr__(self, "time_limit_given", self.max_cycles is not None or self.max_episode_minutes is not None)
        if self.max_episode_minutes is None:
            object.__setattr__(self, "max_episode_minutes", MAX_EPISODE_MINUTES)
        minutes = self.max_episode_minutes
        if isinstance(minutes, bool) or not isinstance(minutes, (int, float)) or not (math.isfinite(minutes) and minutes > 0):
            raise ValueError(f"max_episode_minutes = {minutes!r}: must be a finite number > 0")
        cycles = self.max_cycles
        if cycles is not None and (isinstance(cycles, bool) or not isinstance(cycles, (int, np.integer)) or cycles < 1):
            raise ValueError(f"max_cycles = {cycles!r}: must be an integer >= 1 (decision periods of 5 min) or None")
        if not isinstance(self.expose_wind, (bool, np.bool_)):
            raise ValueError(f"expose_wind = {self.expose_wind!r}: must be True or False")
        size = self.render_size_px
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 64 <= size <= 4096:
            raise ValueError(f"render_size_px = {size!r}: must be an integer in [64, 4096]")

    @functools.cached_property
    def max_decisions(self) -> int:
        """Decisions before truncation: ``max_cycles``, else ceil(time limit / T)."""
        if self.max_cycles is not None:
            return int(self.max_cycles)
        return max(1, math.ceil(self.max_episode_minutes * 60.0 / DECISION_PERIOD_S - 1e-9))


class ScenarioSource:
    """Resolves the ``scenario`` argument: a fixed scenario, or ``random-N`` drawn per episode."""

    def __init__(self, spec: Any) -> None:
        self.spec = spec
        self.random_n: int | None = None
        if isinstance(spec, str) and _RANDOM.match(spec):
            self.random_n = int(_RANDOM.match(spec).group(1))  # type: ignore[union-attr]
        if not isinstance(spec, (str, Mapping, Scenario)):
            raise ValueError(
                f"scenario = {spec!r}: must be a name ('converging-3', 'converging-4', 'converging-6', "
                "'random-N'), a path to a .json file, a dict or a Scenario"
            )
        self.template: Scenario = make_scenario(spec, seed=0)

    @property
    def n_aircraft(self) -> int:
        return self.template.n_aircraft

    @property
    def workspace_radius_nm(self) -> float:
        return self.template.workspace_radius_nm

    def slots(self, max_aircraft: int | None, where: str) -> int:
        """Aircraft slots of a world: the scenario's aircraft, or ``max_aircraft`` to pad."""
        n = self.n_aircraft
        n_slots = n if max_aircraft is None else int(max_aircraft)
        if n_slots < n:
            raise ValueError(
                f"{where}: max_aircraft = {max_aircraft} is smaller than the scenario's {n} aircraft; "
                f"use max_aircraft >= {n} (or None)"
            )
        try:
            return check_aircraft_count(n_slots, "max_aircraft")
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None

    def scenario(self, episode_seed: int) -> Scenario:
        """The scenario of the episode with this seed (a new draw for random-N)."""
        if self.random_n is None:
            return self.template
        return make_scenario(self.spec, seed=episode_seed)


def drawn_seed_split(stream: bool = False) -> Split:
    """The seeds a reset without a seed draws from: the benchmark's train split
    (``atc_nf_env.benchmark.SPLITS``), or the stream tasks' train split
    (``STREAM_SPLITS``) for a traffic stream, so that no training loop built on the envs
    meets a validation or test seed unless it asks for one by name."""
    return STREAM_SPLITS["train"] if stream else SPLITS["train"]


def draw_episode_seed(rng: np.random.Generator, *, stream: bool = False) -> int:
    """An episode seed drawn from an env's np_random (for resets without a seed):
    uniform over ``drawn_seed_split(stream)``."""
    split = drawn_seed_split(stream)
    return split.first + int(rng.integers(0, split.size))


def episode_wind(episode_seed: int, wind_sigma_mps: float) -> np.ndarray:
    """The hidden wind of an episode, kt: ``atc_nf_env.episode.episode_wind_kt``, so that
    ``reset(seed=s)`` meets the same wind as ``run_episode(..., seed=s)`` and the CLI."""
    return episode_wind_kt(episode_seed, wind_sigma_mps)


_LAZY = {
    "ATCParallelEnv": "atc_nf_env.envs.parallel",
    "parallel_env": "atc_nf_env.envs.parallel",
    "env": "atc_nf_env.envs.parallel",
    "raw_env": "atc_nf_env.envs.parallel",
    "EncounterEnv": "atc_nf_env.envs.centralized",
    "EncounterVectorEnv": "atc_nf_env.envs.vector",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'atc_nf_env.envs' has no attribute {name!r}")


__all__ = [
    "ActionMapping",
    "EnvConfig",
    "MAX_EPISODE_MINUTES",
    "RewardWeights",
    "ScenarioSource",
    *_LAZY,
]
