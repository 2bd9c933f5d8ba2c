"""A trained Stable-Baselines3 model as a policy of the ``atc_nf_env.policy.Policy`` interface.

``SB3AgentPolicy("agents/models/x.zip")`` flies any model that ``atc-nf train`` or
``atc-nf imitate`` saved, so the evaluator treats it exactly like the MPC and the NF
alone (``atc-nf evaluate --policy agents/models/x.zip``). At every decision it

1. builds the observation of every aircraft from the kernel state (``view.state``) with
   the environments' own code (``ObservationSpec.observe``, the same compiled function
   the PettingZoo, Gymnasium and vector envs call; the wind is never observed);
2. runs the policy network for the aircraft still flying, deterministically: one
   parameter-shared network applied to each aircraft's ego observation (``mode
   "shared"``), or one network over the concatenated observations of all aircraft slots
   (``mode "centralized"``);
3. maps the actions to waypoints with the environments' action mapping
   (``atc_nf_env.envs.actions.waypoints_for_state``, the function the envs call).

Decision latency. SB3's ``predict`` costs ~100 µs of Python and torch overhead per
call, more than the network itself. For the policies our scripts train (PPO's
``ActorCriticPolicy`` with an MLP or the deep-sets extractor of ``agents.deepsets``,
SAC's ``Actor``) the deterministic action is computed here in one compiled call
(``agents.compiled_forward``) from the weights of the SB3 policy: PPO's action is the
Gaussian's mean ``action_net(policy_net(features(obs)))`` clipped to [-1, 1] (what
``predict(deterministic=True)`` returns); SAC's is ``tanh(mu(latent_pi(obs)))``. It agrees
with ``predict`` to float32 rounding (~1e-6), not bit for bit: neither torch nor BLAS
fixes the order of a sum. ``tests/test_agents.py`` and ``tests/test_agents_any_n.py``
check it against SB3's ``predict``. Any other policy architecture falls back to
``predict`` (``fast=False`` forces it).

Model metadata. Our scripts save, inside the model's zip (SB3's ``include``), an
``atc_nf_meta`` dict: the algorithm, the mode, and the environment settings the model
was trained with (observation neighbours K, time limit, action mapping, number of slots
for centralized models), plus how it was trained. A zip without it is read as a
parameter-shared PPO model on the default environment settings.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from agents.compiled_forward import (
    CLIP,
    IDENTITY,
    RELU,
    SQUASH,
    TANH,
    deepsets_actions,
    mlp_actions,
    pack_layers,
    widest,
)
from atc_nf_env.config import SimConfig
from atc_nf_env.envs import EnvConfig
from atc_nf_env.envs.actions import ActionMapping, waypoints_for_state
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.kernel import N_STATE
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView
from atc_nf_env.units import DECISION_PERIOD_S

#: Key of the metadata saved inside a model's zip.
META_KEY = "atc_nf_meta"
ALGOS = ("ppo", "sac")
MODES = ("shared", "centralized")


def default_meta() -> dict[str, Any]:
    """Metadata assumed for a zip saved without ``atc_nf_meta``."""
    return {
        "algo": "ppo",
        "mode": "shared",
        "env": {
            "n_neighbours": EnvConfig().n_neighbours,
            "max_episode_minutes": EnvConfig().max_episode_minutes,
            "expose_wind": False,
            "action_mapping": ActionMapping().as_dict(),
            "max_aircraft": None,
        },
    }


def env_meta(cfg: EnvConfig, n_slots: int | None = None) -> dict[str, Any]:
    """The ``env`` part of the metadata for a model trained on environments built with ``cfg``."""
    return {
        "n_neighbours": int(cfg.n_neighbours),
        "max_episode_minutes": float(cfg.max_episode_minutes),
        "expose_wind": bool(cfg.expose_wind),
        "action_mapping": cfg.action_mapping.as_dict(),
        "max_aircraft": None if n_slots is None else int(n_slots),
    }


def read_meta(path: str | Path) -> dict[str, Any]:
    """The ``atc_nf_meta`` of a saved model (``default_meta()`` where it has none)."""
    return _meta_of(_saved_data(path))


#: What ``SB3AgentPolicy`` flies: SB3 policy classes by the algorithm that saves them.
POLICY_CLASSES = {"ppo": "ActorCriticPolicy", "sac": "SACPolicy"}
_ACCEPTED = ("a PPO model (ActorCriticPolicy) or a SAC model (SACPolicy) saved by `atc-nf train` or "
             "`atc-nf imitate` (shipped models: agents/models/*.zip)")


def _saved_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` entry of an SB3 zip (its class, spaces, settings and our metadata).

    Raises:
        ValueError: the file is not a zip, is cut off, or holds no SB3 ``data`` entry.
    """
    from stable_baselines3.common.save_util import load_from_zip_file

    try:
        data, _, _ = load_from_zip_file(str(path), device="cpu", load_data=True, print_system_info=False)
    except Exception as error:  # zipfile, json and pickle errors of a damaged or foreign file
        raise ValueError(f"{path}: not a Stable-Baselines3 model, or a damaged one ({type(error).__name__}: {error}); "
                         f"accepted: {_ACCEPTED}") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path}: a zip without a Stable-Baselines3 'data' entry (cut off, or another kind of "
                         f"zip); accepted: {_ACCEPTED}")
    return data


def _meta_of(data: dict[str, Any]) -> dict[str, Any]:
    meta = default_meta()
    saved = (data or {}).get(META_KEY)
    if isinstance(saved, dict):
        env = {**meta["env"], **saved.get("env", {})}
        meta = {**meta, **saved, "env": env}
    return meta


#: Models loaded in this process, by (resolved path, modification time, size): the evaluator
#: builds a policy per run, and loading a zip costs more than flying an episode.
_LOADED: dict[tuple[str, int, int], tuple[Any, dict[str, Any]]] = {}


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """(SB3 model on the CPU, metadata) of a zip saved by ``atc-nf train`` or ``atc-nf imitate``
    (cached per process until the file changes; do not modify the returned model).

    Raises:
        ValueError: the file does not exist or is not an SB3 model of a known algorithm.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file {str(path)!r} does not exist; give the path to a .zip saved by "
                         "`atc-nf train` or `atc-nf imitate` (shipped models: agents/models/*.zip)")
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _LOADED:
        _LOADED[key] = _load_model(path)
    return _LOADED[key]


def _load_model(path: Path) -> tuple[Any, dict[str, Any]]:
    try:
        data = _saved_data(path)
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError("trained agents need stable-baselines3: pip install 'atc-nf-env[rl]'") from error
    meta = _meta_of(data)
    algo = meta.get("algo", "ppo")
    if algo not in ALGOS:
        raise ValueError(f"{path}: algorithm {algo!r} in its metadata; allowed: {', '.join(ALGOS)}")
    if meta.get("mode") not in MODES:
        raise ValueError(f"{path}: mode {meta.get('mode')!r} in its metadata; allowed: {', '.join(MODES)}")
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.sac.policies import SACPolicy

    policy_class = data.get("policy_class")
    expected = {"ppo": ActorCriticPolicy, "sac": SACPolicy}[algo]
    if not isinstance(policy_class, type):
        raise ValueError(f"{path}: its policy class cannot be read ({policy_class!r:.80}); accepted: {_ACCEPTED}")
    if not issubclass(policy_class, expected):
        held = next((a for a, c in (("ppo", ActorCriticPolicy), ("sac", SACPolicy)) if issubclass(policy_class, c)),
                    None)
        what = (f"a {held.upper()} model ({policy_class.__name__})" if held
                else f"a model of another algorithm ({policy_class.__name__}: neither PPO nor SAC)")
        if isinstance(data.get(META_KEY), dict):
            why = f"its {META_KEY} says algorithm {algo!r}, but it holds {what}"
        else:
            why = (f"it holds {what} and no {META_KEY} (without it a zip is read as a parameter-shared PPO "
                   "model on the default environment settings)")
        raise ValueError(f"{path}: {why}; accepted: {_ACCEPTED}")
    from stable_baselines3 import PPO, SAC

    cls = PPO if algo == "ppo" else SAC
    try:
        model = cls.load(str(path), device="cpu")
    except Exception as error:  # a file that reads as SB3 but whose parts do not fit together
        raise ValueError(f"{path}: cannot be loaded as a {algo.upper()} model ({type(error).__name__}: {error}); "
                         f"accepted: {_ACCEPTED}") from None
    return model, meta


# ------------------------------------------------------------------ compiled forward pass


def _activation(module: Any) -> int:
    import torch.nn as nn

    if isinstance(module, nn.Tanh):
        return TANH
    if isinstance(module, nn.ReLU):
        return RELU
    raise TypeError(f"activation {type(module).__name__} has no compiled form here")


def _mlp_layers(sequential: Any) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """[(W^T, b, activation code)] of an nn.Sequential of Linear and activation modules."""
    import torch.nn as nn

    layers: list[tuple[np.ndarray, np.ndarray, int]] = []
    activated = True  # an activation needs a Linear layer before it that has none yet
    for module in sequential:
        if isinstance(module, nn.Linear):
            weight = np.ascontiguousarray(module.weight.detach().cpu().numpy().astype(np.float32).T)
            bias = module.bias.detach().cpu().numpy().astype(np.float32).copy()
            layers.append((weight, bias, IDENTITY))
            activated = False
        else:
            if activated:
                raise TypeError(f"unexpected module {type(module).__name__} in the policy network")
            weight, bias, _ = layers[-1]
            layers[-1] = (weight, bias, _activation(module))
            activated = True
    return layers


def compiled_forward(model: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """A function obs (B, D) -> deterministic actions (B, A) float32 in [-1, 1] that
    computes ``model.predict(obs, deterministic=True)`` in one compiled call
    (``agents.compiled_forward``; equal to float32 rounding), or None if the model's policy
    is not one of the architectures handled here."""
    from stable_baselines3.common.torch_layers import FlattenExtractor

    try:
        from stable_baselines3.common.policies import ActorCriticPolicy
        from stable_baselines3.sac.policies import SACPolicy

        policy = model.policy
        extractor: Any = None
        if isinstance(policy, ActorCriticPolicy):
            from agents.deepsets import NeighbourSetExtractor

            if isinstance(policy.features_extractor, NeighbourSetExtractor) and policy.share_features_extractor:
                extractor = policy.features_extractor
            elif not isinstance(policy.features_extractor, FlattenExtractor):
                return None
            if policy.squash_output:
                return None
            from stable_baselines3.common.distributions import DiagGaussianDistribution

            if not isinstance(policy.action_dist, DiagGaussianDistribution):
                return None
            head = _mlp_layers(policy.mlp_extractor.policy_net) + _mlp_layers([policy.action_net])
            output = CLIP
        elif isinstance(policy, SACPolicy):
            actor = policy.actor
            if not isinstance(actor.features_extractor, FlattenExtractor) or actor.use_sde:
                return None
            head = _mlp_layers(actor.latent_pi) + _mlp_layers([actor.mu])
            output = SQUASH
        else:
            return None
    except TypeError:
        return None
    low = model.action_space.low.reshape(-1).astype(np.float64)
    high = model.action_space.high.reshape(-1).astype(np.float64)
    if not (np.all(low == -1.0) and np.all(high == 1.0)):
        return None  # our envs' actions are all in [-1, 1]; anything else goes through predict
    head_weights, head_layout = pack_layers(head)
    n_actions = int(head_layout[-1, 1])
    obs_dim = int(np.prod(model.observation_space.shape))
    compute: Callable[[np.ndarray, np.ndarray], bool]
    if extractor is None:
        buf_a, buf_b = (np.zeros(widest(head_layout), dtype=np.float32) for _ in range(2))

        def compute(x: np.ndarray, out: np.ndarray) -> bool:
            return mlp_actions(x, head_weights, head_layout, output, buf_a, buf_b, out)
    else:
        from agents.deepsets import N_NEIGHBOUR, N_OWN

        own_weights, own_layout = pack_layers(_mlp_layers(extractor.own))
        phi_weights, phi_layout = pack_layers(_mlp_layers(extractor.phi))
        width = max(widest(own_layout), widest(phi_layout), widest(head_layout))
        buf_a, buf_b = (np.zeros(width, dtype=np.float32) for _ in range(2))
        features = np.zeros(3 * extractor.hidden, dtype=np.float32)
        n_slots = int(extractor.n_slots)

        def compute(x: np.ndarray, out: np.ndarray) -> bool:
            return deepsets_actions(x, N_OWN, n_slots, N_NEIGHBOUR, own_weights, own_layout,
                                    phi_weights, phi_layout, head_weights, head_layout, output, buf_a,
                                    buf_b, features, out)

    def forward(obs: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != obs_dim:
            raise ValueError(f"observations of shape {np.shape(obs)}; expected (B, {obs_dim})")
        out = np.empty((x.shape[0], n_actions), dtype=np.float32)
        if not compute(x, out):
            raise ValueError(_NOT_FINITE_OBSERVATIONS)
        return out

    # For SB3AgentPolicy.act's path with buffers of its own: compute(x (B, D) float32
    # C-contiguous, out (B, n_actions) float32) -> False if x holds a NaN or inf.
    forward.compute = compute  # type: ignore[attr-defined]
    return forward


_NOT_FINITE_OBSERVATIONS = "observations contain NaN or inf (after conversion to float32); all must be finite"


# ------------------------------------------------------------------ the policy


def ego_observations(spec: ObservationSpec, view: WorldView, time_limit_s: float,
                     n_slots: int | None = None) -> np.ndarray:
    """Observations (N or n_slots, D) float32 of the aircraft of ``view``, computed by the
    environments' own code (``ObservationSpec.observe``) with the time fraction of an
    env whose time limit is ``time_limit_s``; the wind is never part of them."""
    time_fraction = np.array([min(1.0, view.time_s / time_limit_s)])
    return spec.observe(view.state[None], time_fraction, np.zeros((1, 2)), n_slots)[0]


def time_limit_s(max_episode_minutes: float) -> float:
    """The env's time limit, s, as its observations normalize time: ceil(minutes / 5) periods."""
    return EnvConfig(max_episode_minutes=float(max_episode_minutes)).max_decisions * DECISION_PERIOD_S



#: What SB3AgentPolicy does outside its model's operating range.
OUTSIDE_RANGE = ("warn", "refuse", "ignore")
#: Models that have warned in this process (one warning per model).
_WARNED_OUTSIDE: set[str] = set()


class OutsideOperatingRangeWarning(UserWarning):
    """A model flies traffic or wind outside the range it was trained on."""


@dataclass
class _DecisionBuffers:
    """``SB3AgentPolicy.act``'s arrays, kept between decisions of one scenario: the state's
    shape (N, N_STATE) they fit, the time fraction (1,), a zero wind (1, 2), observations
    (1, N, D) float32, nearest distances (1, N), actions (N, 2) float32 and as float64
    (1, N, 2)."""

    shape: tuple[int, int]
    time_fraction: np.ndarray
    no_wind: np.ndarray
    obs: np.ndarray
    nearest: np.ndarray
    actions32: np.ndarray
    actions64: np.ndarray


class SB3AgentPolicy:
    """A model saved by ``atc-nf train`` / ``atc-nf imitate`` as a waypoint policy.

    Args:
        path: the model's .zip.
        fast: use the compiled forward pass where the architecture allows (see the module
            docstring); False always calls SB3's ``predict(deterministic=True)``.
        outside_range: "warn" (once per model and process), "refuse" (ValueError) or
            "ignore", when an episode's number of aircraft or wind sigma lies outside the
            model's operating range (``agents.cards.operating_range``: saved with the
            model, or derived from its training command).

    Units: waypoints in nm, like every policy of ``atc_nf_env.policy``.
    """

    def __init__(self, path: str | Path, fast: bool = True, outside_range: str = "warn") -> None:
        if outside_range not in OUTSIDE_RANGE:
            raise ValueError(f"outside_range = {outside_range!r}: allowed: {', '.join(OUTSIDE_RANGE)}")
        self.path = Path(path)
        self.outside_range = outside_range
        self.model, self.meta = load_model(self.path)
        from agents.cards import operating_range

        self.operating_range = operating_range(self.meta)
        self.name = self.path.stem
        env = self.meta["env"]
        if env.get("expose_wind"):
            raise ValueError(
                f"{self.path}: the model was trained with expose_wind=True, but a policy never sees the wind; "
                "train with expose_wind=False"
            )
        self.mode: str = self.meta["mode"]
        self.mapping = ActionMapping.coerce(env.get("action_mapping"))
        self.n_neighbours = int(env.get("n_neighbours", 4))
        self.time_limit_s = time_limit_s(env.get("max_episode_minutes"))
        obs_dim = int(np.prod(self.model.observation_space.shape))
        per_aircraft = ObservationSpec(n_neighbours=self.n_neighbours).dim
        if self.mode == "shared":
            if obs_dim != per_aircraft or self.model.action_space.shape != (2,):
                raise ValueError(
                    f"{self.path}: observation size {obs_dim} and action shape {self.model.action_space.shape} do "
                    f"not fit a parameter-shared model with K = {self.n_neighbours} neighbours ({per_aircraft}, (2,))"
                )
            self.n_slots: int | None = None
        else:
            slots = self.model.action_space.shape[0]
            if obs_dim != slots * per_aircraft:
                raise ValueError(f"{self.path}: observation size {obs_dim} is not {slots} slots x {per_aircraft}")
            self.n_slots = int(slots)
        self._forward = compiled_forward(self.model) if fast else None
        self._spec: ObservationSpec | None = None
        self._buffers: _DecisionBuffers | None = None
        self._warm = False

    def check_operating_conditions(self, n_aircraft: int, wind_sigma_mps: float | None) -> None:
        """Warn once per model and process (``outside_range="warn"``), or raise ValueError
        (``"refuse"``), when ``n_aircraft`` or the wind's sigma (m/s; None: a fixed wind,
        not checked) lies outside the range the model was trained on (its card's
        operating range). ``run_episode`` calls this before ``reset``."""
        rng = self.operating_range
        if rng is None or self.outside_range == "ignore":
            return
        problems = []
        n_lo, n_hi = rng["n_aircraft"]
        if not n_lo <= n_aircraft <= n_hi:
            problems.append(f"{n_aircraft} aircraft (trained on {n_lo:g}..{n_hi:g})")
        s_lo, s_hi = rng["wind_sigma_mps"]
        if wind_sigma_mps is not None and not s_lo - 1e-9 <= wind_sigma_mps <= s_hi + 1e-9:
            problems.append(f"wind sigma {wind_sigma_mps:g} m/s (trained on {s_lo:g}..{s_hi:g})")
        if not problems:
            return
        message = (f"{self.path.name} flies outside its operating range: {' and '.join(problems)}; its card "
                   f"({self.path.with_suffix('.md').name}) gives no result there that it was trained for")
        if self.outside_range == "refuse":
            raise ValueError(message + "; pass outside_range='warn' or 'ignore' to fly it anyway")
        key = str(self.path.resolve())
        if key not in _WARNED_OUTSIDE:
            _WARNED_OUTSIDE.add(key)
            warnings.warn(message, OutsideOperatingRangeWarning, stacklevel=3)

    # -- Policy interface -------------------------------------------------------------
    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Prepare the observation code for ``scenario`` flown with ``config`` (the policy is
        deterministic: ``seed`` is unused)."""
        if self.n_slots is not None and scenario.n_aircraft > self.n_slots:
            raise ValueError(
                f"{self.path}: a centralized model with {self.n_slots} aircraft slots cannot fly "
                f"{scenario.name!r} ({scenario.n_aircraft} aircraft)"
            )
        self._spec = ObservationSpec.for_config(config, self.n_neighbours, False)
        self._workspace_radius_nm = float(scenario.workspace_radius_nm)
        self._aircraft_radius_nm = float(config.aircraft_radius_nm)
        self._buffers = None
        if self.mode == "shared" and self._forward is not None:
            n, dim = scenario.n_aircraft, self._spec.dim
            self._buffers = _DecisionBuffers(
                shape=(n, N_STATE), time_fraction=np.zeros(1), no_wind=np.zeros((1, 2)),
                obs=np.zeros((1, n, dim), dtype=np.float32), nearest=np.zeros((1, n)),
                actions32=np.zeros((n, 2), dtype=np.float32), actions64=np.zeros((1, n, 2)),
            )
        if not self._warm:  # load the compiled functions now, not inside the first timed act()
            from atc_nf_env.simulation import initial_state

            state = initial_state(scenario)[0]
            self.act(WorldView(time_s=0.0, state=state, scenario=scenario))
            self._warm = True

    def observe(self, view: WorldView) -> np.ndarray:
        """Observations (N or slots, D) float32 of every aircraft, as the envs compute them."""
        if self._spec is None:
            raise RuntimeError("call reset(scenario, config, seed) before act()")
        return ego_observations(self._spec, view, self.time_limit_s, self.n_slots)

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (B, 2) or (B, slots, 2) in [-1, 1] for observations (B, D)."""
        if self._forward is not None:
            return self._forward(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        return np.asarray(action, dtype=np.float64)

    def act(self, view: WorldView) -> np.ndarray:
        """Waypoints (N, 2), nm: each flying aircraft's action mapped with the env's mapping;
        aircraft no longer flying keep their waypoint."""
        state = view.state
        buffers = self._buffers
        if (buffers is not None and type(state) is np.ndarray and state.dtype == np.float64
                and state.shape == buffers.shape and state.flags.c_contiguous):
            # The same compiled observation, forward pass and mapping as below, on buffers
            # kept between decisions: the Python around them was a third of a decision.
            world = state[None]
            buffers.time_fraction[0] = min(1.0, view.time_s / self.time_limit_s)
            self._spec.observe_into(world, buffers.time_fraction, buffers.no_wind, buffers.obs, buffers.nearest)
            if not self._forward.compute(buffers.obs[0], buffers.actions32):
                raise ValueError(_NOT_FINITE_OBSERVATIONS)
            buffers.actions64[0] = buffers.actions32
            return waypoints_for_state(buffers.actions64, world, self.mapping, self._workspace_radius_nm,
                                       self._aircraft_radius_nm)[0]
        obs = self.observe(view)
        n = state.shape[0]
        if self.mode == "shared":
            # One batch for all rows: cheaper than selecting the flying ones, and the rows of
            # aircraft no longer flying are ignored by waypoints_for_state.
            actions = self.actions(obs)[None]
        else:
            actions = self.actions(obs.reshape(1, -1)).reshape(1, self.n_slots, 2)[:, :n]
        return waypoints_for_state(actions, state[None], self.mapping, self._workspace_radius_nm,
                                   self._aircraft_radius_nm)[0]


def is_model_path(spec: str) -> bool:
    """Whether a ``--policy`` value names a model file rather than a built-in policy."""
    return isinstance(spec, str) and spec.lower().endswith(".zip")


__all__ = ["META_KEY", "OutsideOperatingRangeWarning", "SB3AgentPolicy", "default_meta", "env_meta", "is_model_path", "load_model", "compiled_forward",
           "read_meta"]

