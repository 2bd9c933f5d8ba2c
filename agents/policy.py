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

Loading without unpickling. SB3's own loader (``PPO.load``) unpickles every value of a
zip's ``data`` that SB3 stored with cloudpickle, so a hostile zip runs code when it is
opened. ``load_model`` and ``read_meta`` read ``data`` as plain JSON and never decode a
pickled value (``PickledValue`` keeps only the plain text SB3 writes beside it): the policy
class, its settings (``policy_kwargs``) and its spaces are rebuilt from plain fields, from
the classes this project flies and from the environments' own spaces, and the weights are
read from ``policy.pth`` with ``torch.load(weights_only=True)``. The shipped models load
bit for bit as ``PPO.load`` loads them (``tests/test_reliability_round4_model_files.py``).
"""

from __future__ import annotations

import io
import json
import math
import re
import warnings
import zipfile
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
    return _meta_of(_saved_data(path), path)


#: What ``SB3AgentPolicy`` flies: SB3 policy classes by the algorithm that saves them.
POLICY_CLASSES = {"ppo": "ActorCriticPolicy", "sac": "SACPolicy"}
_ACCEPTED = ("a PPO model (ActorCriticPolicy) or a SAC model (SACPolicy) saved by `atc-nf train` or "
             "`atc-nf imitate` (shipped models: agents/models/*.zip)")


#: Bounds on a model zip's entries once decompressed, bytes: a hostile zip must not inflate
#: into memory without limit (the shipped models' ``data`` is < 40 kB, ``policy.pth`` < 200 kB).
MAX_DATA_BYTES = 16 * 2**20
MAX_WEIGHTS_BYTES = 256 * 2**20
#: The entry of a model zip with the policy's weights: a state dict of tensors.
WEIGHTS_ENTRY = "policy.pth"
#: Bounds on the settings a zip states: observed neighbours K and aircraft slots.
MAX_NEIGHBOURS = 1024
MAX_SLOTS = 1024


@dataclass(frozen=True)
class PickledValue:
    """A value of a model zip's ``data`` that SB3 saved as a cloudpickle payload (a dict
    with a ``":serialized:"`` key). It is never unpickled: only the plain-text description
    SB3 writes beside the payload is kept (attribute name -> JSON value or its ``str``)."""

    description: dict[str, Any]


@dataclass
class LoadedModel:
    """What flying needs of a saved SB3 model: its policy network (CPU, evaluation mode)
    and the observation and action spaces it was built for. ``predict`` is SB3's
    ``BaseAlgorithm.predict``: the policy's ``predict``."""

    policy: Any
    observation_space: Any
    action_space: Any

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        """(actions, None) of ``observation``, as ``PPO.predict`` / ``SAC.predict`` give them."""
        return self.policy.predict(observation, deterministic=deterministic)


def _read_entry(archive: zipfile.ZipFile, name: str, limit: int) -> bytes | None:
    """The bytes of entry ``name`` (None if the zip has none), refused above ``limit``."""
    if name not in archive.namelist():
        return None
    size = archive.getinfo(name).file_size
    if size > limit:
        raise ValueError(f"its {name!r} entry holds {size} bytes; at most {limit} are read")
    with archive.open(name) as entry:
        content = entry.read(limit + 1)
    if len(content) > limit:
        raise ValueError(f"its {name!r} entry inflates past {limit} bytes")
    return content


def torch_load_error(error: Exception) -> str:
    """One line on why ``torch.load(weights_only=True)`` refused a file: the unpickler's
    reason (e.g. "Unsupported global: GLOBAL builtins.exec") rather than torch's advice to
    load it unrestricted, which would run the code a hostile file holds."""
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in str(error).splitlines()]
    reason = next((line for line in lines if "WeightsUnpickler error" in line), None)
    reason = (reason or next((line for line in lines if line), "")).split(". Please use")[0]
    return f"{type(error).__name__}: {reason:.200}"


def _saved_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` entry of an SB3 zip (its class, spaces, settings and our metadata), read
    as plain JSON: every value SB3 pickled is a ``PickledValue``, never unpickled.

    Raises:
        ValueError: the file is not a zip, is cut off, or holds no SB3 ``data`` entry.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            content = _read_entry(archive, "data", MAX_DATA_BYTES)
        data = None if content is None else json.loads(content.decode("utf-8"))
    except Exception as error:  # zipfile, UTF-8 and JSON errors of a damaged or foreign file
        raise ValueError(f"{path}: not a Stable-Baselines3 model, or a damaged one ({type(error).__name__}: {error}); "
                         f"accepted: {_ACCEPTED}") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path}: a zip without a Stable-Baselines3 'data' entry (cut off, or another kind of "
                         f"zip); accepted: {_ACCEPTED}")
    return {key: PickledValue({k: v for k, v in value.items() if k != ":serialized:"})
            if isinstance(value, dict) and ":serialized:" in value else value for key, value in data.items()}


def _meta_of(data: dict[str, Any], path: str | Path) -> dict[str, Any]:
    meta = default_meta()
    saved = data.get(META_KEY)
    if isinstance(saved, PickledValue):
        raise ValueError(f"{path}: its {META_KEY} is a pickled object, which is never unpickled here; "
                         f"`atc-nf train` and `atc-nf imitate` save it as plain JSON")
    if isinstance(saved, dict):
        env = saved.get("env", {})
        if not isinstance(env, dict):
            raise ValueError(f"{path}: its {META_KEY}['env'] = {env!r:.80}: must be a dict of the environment "
                             f"settings ({', '.join(meta['env'])})")
        meta = {**meta, **saved, "env": {**meta["env"], **env}}
    return meta


#: The SB3 policy classes flown here, by their module and name, and the algorithm saving each.
_POLICY_ALGOS = {"stable_baselines3.common.policies.ActorCriticPolicy": "ppo",
                 "stable_baselines3.sac.policies.SACPolicy": "sac"}


def _class_name(value: Any) -> str | None:
    """``module.Name`` of a class SB3 pickled, from the plain description beside the
    payload (its ``__module__`` and the name in its ``__init__``'s text); None if unreadable."""
    if not isinstance(value, PickledValue):
        return None
    module, init = value.description.get("__module__"), value.description.get("__init__")
    found = re.fullmatch(r"<function (\w+)\.__init__ at 0x[0-9a-fA-F]+>", init) if isinstance(init, str) else None
    return f"{module}.{found.group(1)}" if isinstance(module, str) and found else None


def _classes() -> dict[str, dict[str, Any]]:
    """The classes a policy's settings may name ("activation": ``activation_fn``,
    "extractor": ``features_extractor_class``), by the text SB3 writes for each."""
    from stable_baselines3.common.torch_layers import FlattenExtractor
    from torch import nn

    from agents.deepsets import NeighbourSetExtractor

    def by_text(classes: list[type]) -> dict[str, type]:
        return {f"<class '{cls.__module__}.{cls.__qualname__}'>": cls for cls in classes}

    return {"activation": by_text([nn.Tanh, nn.ReLU, nn.ELU, nn.LeakyReLU, nn.SiLU, nn.GELU]),
            "extractor": by_text([FlattenExtractor, NeighbourSetExtractor])}


#: Settings of each policy class a zip may hold (``policy_kwargs``), and the kind of each.
_SETTINGS: dict[str, dict[str, str]] = {
    "ppo": {"net_arch": "arch", "activation_fn": "activation", "ortho_init": "bool", "log_std_init": "number",
            "full_std": "bool", "use_expln": "bool", "squash_output": "bool", "features_extractor_class":
            "extractor", "features_extractor_kwargs": "dict", "share_features_extractor": "bool",
            "normalize_images": "bool"},
    "sac": {"net_arch": "arch", "activation_fn": "activation", "use_sde": "bool", "log_std_init": "number",
            "use_expln": "bool", "clip_mean": "number", "features_extractor_class": "extractor",
            "features_extractor_kwargs": "dict", "normalize_images": "bool", "n_critics": "count",
            "share_features_extractor": "bool"},
}
#: Settings that only shape training (the optimizer): not needed to fly, so not read.
_TRAINING_ONLY = ("optimizer_class", "optimizer_kwargs", "device")


def _widths(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(w, int) and not isinstance(w, bool) and w >= 1 for w in value)


def _policy_settings(path: Path, value: Any, algo: str) -> dict[str, Any]:
    """The ``policy_kwargs`` of a zip, rebuilt from plain values and the classes of ``_classes``.

    Raises:
        ValueError: a setting is unknown, of the wrong kind, or names a class not flown here.
    """
    if isinstance(value, PickledValue):
        if value.description.get(":type:") != "<class 'dict'>":
            raise ValueError(f"{path}: its policy_kwargs is not a dict ({value.description.get(':type:')!r:.80})")
        value = {k: v for k, v in value.description.items() if k != ":type:"}
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise ValueError(f"{path}: its policy_kwargs = {value!r:.80}: must be a dict")
    allowed = _SETTINGS[algo]
    classes = _classes()
    settings: dict[str, Any] = {}
    for key, item in value.items():
        if key in _TRAINING_ONLY:
            continue
        kind = allowed.get(key)
        if kind is None:
            raise ValueError(f"{path}: its policy_kwargs has the setting {key!r}, unknown here; allowed: "
                             f"{', '.join(allowed)}")
        if kind in classes:
            cls = classes[kind].get(item) if isinstance(item, str) else None
            if cls is None:
                raise ValueError(f"{path}: its policy_kwargs[{key!r}] = {item!r:.120}; allowed: "
                                 f"{', '.join(classes[kind])}")
            settings[key] = cls
            continue
        good = {"bool": isinstance(item, bool),
                "number": isinstance(item, (int, float)) and not isinstance(item, bool) and math.isfinite(item),
                "count": isinstance(item, int) and not isinstance(item, bool) and 1 <= item <= 16,
                "dict": isinstance(item, dict),
                "arch": _widths(item) or (isinstance(item, dict) and bool(item)
                                          and all(k in ("pi", "vf", "qf") and _widths(v) for k, v in item.items()))}
        if not good[kind]:
            what = {"bool": "true or false", "number": "a finite number", "count": "an integer in [1, 16]",
                    "dict": "a dict", "arch": "a list of layer widths (integers >= 1) or a dict of such lists "
                    "under 'pi', 'vf', 'qf'"}[kind]
            raise ValueError(f"{path}: its policy_kwargs[{key!r}] = {item!r:.80}: must be {what}")
        settings[key] = item
    return settings



#: Models loaded in this process, by (resolved path, modification time, size): the evaluator
#: builds a policy per run, and loading a zip costs more than flying an episode.
_LOADED: dict[tuple[str, int, int], tuple[LoadedModel, dict[str, Any]]] = {}


def load_model(path: str | Path) -> tuple[LoadedModel, dict[str, Any]]:
    """(SB3 policy on the CPU with its spaces, metadata) of a zip saved by ``atc-nf train`` or ``atc-nf imitate``
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


def _least_parameters(settings: dict[str, Any], algo: str, obs_dim: int, act_dim: int) -> int:
    """A lower bound on the number of parameters of the policy that ``settings`` describe:
    the weights of the linear layers of its actor and of one critic (SB3's policies hold
    at least these; biases, log std and SAC's other critics come on top)."""
    from agents.deepsets import NeighbourSetExtractor

    features, extractor = obs_dim, 0
    hidden = (settings.get("features_extractor_kwargs") or {}).get("hidden", 64)
    if settings.get("features_extractor_class") is NeighbourSetExtractor and isinstance(hidden, int):
        features, extractor = 3 * hidden, 2 * hidden * hidden
    arch = settings.get("net_arch", [256, 256] if algo == "sac" else [64, 64])
    actor = arch.get("pi", []) if isinstance(arch, dict) else arch
    critic = arch.get("qf" if algo == "sac" else "vf", []) if isinstance(arch, dict) else arch
    critic_input = features + act_dim if algo == "sac" else features

    def weights(dims: list[int]) -> int:
        return sum(a * b for a, b in zip(dims, dims[1:]))

    return extractor + weights([features, *actor, act_dim]) + weights([critic_input, *critic, 1])


def _weights(path: Path) -> dict[str, Any]:
    """The policy's state dict from the zip's ``policy.pth``, read with
    ``torch.load(weights_only=True)``: tensors and plain containers only, never a pickled object.

    Raises:
        ValueError: no such entry, one that needs unpickling, or tensors that are not finite.
    """
    import torch

    try:
        with zipfile.ZipFile(path) as archive:
            content = _read_entry(archive, WEIGHTS_ENTRY, MAX_WEIGHTS_BYTES)
        if content is None:
            raise ValueError(f"no {WEIGHTS_ENTRY!r} entry")
        state = torch.load(io.BytesIO(content), map_location="cpu", weights_only=True)
    except Exception as error:  # torch's UnpicklingError for anything but tensors, and damaged files
        raise ValueError(f"{path}: its weights cannot be read as plain tensors ({torch_load_error(error)}); a "
                         f"{WEIGHTS_ENTRY} that needs unpickling is refused; accepted: {_ACCEPTED}") from None
    if (not isinstance(state, dict) or not state
            or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items())):
        raise ValueError(f"{path}: its {WEIGHTS_ENTRY} is not a state dict of named tensors")
    for name, tensor in state.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{path}: its {WEIGHTS_ENTRY} holds NaN or inf in {name!r}; every weight must be finite")
    return state


def _box_shape(path: Path, data: dict[str, Any], key: str) -> tuple[int, ...]:
    """The shape a zip states for its ``observation_space`` or ``action_space`` (a float32 Box)."""
    value = data.get(key)
    described = value.description if isinstance(value, PickledValue) else {}
    shape = described.get("_shape")
    if (described.get(":type:") != "<class 'gymnasium.spaces.box.Box'>" or described.get("dtype") != "float32"
            or not isinstance(shape, list) or not shape
            or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in shape)):
        raise ValueError(f"{path}: its {key} is not a float32 gymnasium Box of a known shape "
                         f"({str(described or value):.120}); accepted: {_ACCEPTED}")
    return tuple(shape)


def _spaces(path: Path, data: dict[str, Any], meta: dict[str, Any]) -> tuple[Any, Any]:
    """(observation, action) spaces: the Boxes our envs give a model of ``meta``'s mode and
    K, of the shapes the zip states (the bounds of a Box do not change a policy's actions).

    Raises:
        ValueError: the shapes do not fit the model's mode and K, or K or the slots are out of bounds.
    """
    from gymnasium import spaces

    env = meta["env"]
    k = env.get("n_neighbours", 4)
    if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= MAX_NEIGHBOURS:
        raise ValueError(f"{path}: its {META_KEY}['env']['n_neighbours'] = {k!r:.40}: must be an integer in "
                         f"[0, {MAX_NEIGHBOURS}]")
    spec = ObservationSpec(n_neighbours=k, expose_wind=bool(env.get("expose_wind")))
    obs_shape, act_shape = _box_shape(path, data, "observation_space"), _box_shape(path, data, "action_space")
    if meta["mode"] == "shared":
        slots, expected = None, ((spec.dim,), (2,))
    else:
        slots = act_shape[0]
        if not 1 <= slots <= MAX_SLOTS:
            raise ValueError(f"{path}: a centralized model with {slots} aircraft slots; at most {MAX_SLOTS}")
        expected = ((slots * spec.dim,), (slots, 2))
    if (obs_shape, act_shape) != expected:
        raise ValueError(f"{path}: observations of shape {obs_shape} and actions of shape {act_shape} do not fit a "
                         f"{meta['mode']} model with K = {k} neighbours ({expected[0]}, {expected[1]})")
    observation = spec.space() if slots is None else spec.flat_space(slots)
    return observation, spaces.Box(-1.0, 1.0, shape=act_shape, dtype=np.float32)


def _load_model(path: Path) -> tuple[LoadedModel, dict[str, Any]]:
    try:
        from stable_baselines3.common.policies import ActorCriticPolicy
        from stable_baselines3.sac.policies import SACPolicy
    except ImportError as error:  # pragma: no cover - depends on the install
        raise ImportError("trained agents need stable-baselines3: pip install 'atc-nf-env[rl]'") from error
    data = _saved_data(path)
    meta = _meta_of(data, path)
    algo = meta.get("algo", "ppo")
    if algo not in ALGOS:
        raise ValueError(f"{path}: algorithm {algo!r} in its metadata; allowed: {', '.join(ALGOS)}")
    if meta.get("mode") not in MODES:
        raise ValueError(f"{path}: mode {meta.get('mode')!r} in its metadata; allowed: {', '.join(MODES)}")
    held = _class_name(data.get("policy_class"))
    if held is None:
        raise ValueError(f"{path}: its policy class cannot be read ({data.get('policy_class')!r:.80}); "
                         f"accepted: {_ACCEPTED}")
    held_algo = _POLICY_ALGOS.get(held)
    if held_algo != algo:
        name = held.rsplit(".", 1)[-1]
        what = (f"a {held_algo.upper()} model ({name})" if held_algo
                else f"a model of another algorithm ({name}: neither PPO nor SAC)")
        if isinstance(data.get(META_KEY), dict):
            why = f"its {META_KEY} says algorithm {algo!r}, but it holds {what}"
        else:
            why = (f"it holds {what} and no {META_KEY} (without it a zip is read as a parameter-shared PPO "
                   "model on the default environment settings)")
        raise ValueError(f"{path}: {why}; accepted: {_ACCEPTED}")
    observation_space, action_space = _spaces(path, data, meta)
    settings = _policy_settings(path, data.get("policy_kwargs"), algo)
    if algo == "ppo":  # PPO passes its own use_sde to the policy; SAC keeps it in policy_kwargs
        use_sde = data.get("use_sde", False)
        if not isinstance(use_sde, bool):
            raise ValueError(f"{path}: its use_sde = {use_sde!r:.40}: must be true or false")
        settings["use_sde"] = use_sde
    state = _weights(path)
    held_parameters = sum(int(tensor.numel()) for tensor in state.values())
    least = _least_parameters(settings, algo, int(np.prod(observation_space.shape)), int(np.prod(action_space.shape)))
    if least > held_parameters:  # checked before building: the settings could ask for any size
        raise ValueError(f"{path}: its policy_kwargs describe a policy of at least {least} parameters, but its "
                         f"{WEIGHTS_ENTRY} holds {held_parameters}")
    policy_class = ActorCriticPolicy if algo == "ppo" else SACPolicy
    try:
        # The learning rate only sets the optimizer's, and flying never steps it.
        policy = policy_class(observation_space, action_space, lambda _progress: 0.0, **settings)
        policy.load_state_dict(state)  # strict: every tensor present, none extra, same shapes
    except Exception as error:  # settings and weights that do not fit together
        first_line = (str(error).strip().splitlines() or [""])[0]
        raise ValueError(f"{path}: cannot be loaded as a {algo.upper()} model ({type(error).__name__}: "
                         f"{first_line:.300}); accepted: {_ACCEPTED}") from None
    policy.set_training_mode(False)
    return LoadedModel(policy, observation_space, action_space), meta


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


def checked_outside_range(outside_range: str) -> str:
    """``outside_range`` if it is one of ``OUTSIDE_RANGE`` (ValueError otherwise)."""
    if outside_range not in OUTSIDE_RANGE:
        raise ValueError(f"outside_range = {outside_range!r}: allowed: {', '.join(OUTSIDE_RANGE)}")
    return outside_range


class OperatingRangeCheck:
    """``check_operating_conditions`` of a model file flown as a policy, whatever its format
    (``.zip``, ``.pt``): the subclass sets ``path``, ``outside_range`` (``OUTSIDE_RANGE``),
    ``operating_range`` ({"n_aircraft": [min, max], "wind_sigma_mps": [min, max]} or None)
    and ``range_source`` (where the range was read, for the message)."""

    path: Path
    outside_range: str
    operating_range: dict[str, list[float]] | None
    range_source: str

    def check_operating_conditions(self, n_aircraft: int, wind_sigma_mps: float | None) -> None:
        """Warn once per model and process (``outside_range="warn"``), or raise ValueError
        (``"refuse"``), when ``n_aircraft`` or the wind's sigma (m/s; None: a fixed wind,
        not checked) lies outside the range the model was trained on. ``run_episode``
        calls this before ``reset``."""
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
        message = f"{self.path.name} flies outside its operating range: {' and '.join(problems)}; {self.range_source}"
        if self.outside_range == "refuse":
            raise ValueError(message + "; pass outside_range='warn' or 'ignore' to fly it anyway")
        key = str(self.path.resolve())
        if key not in _WARNED_OUTSIDE:
            _WARNED_OUTSIDE.add(key)
            warnings.warn(message, OutsideOperatingRangeWarning, stacklevel=3)


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


class SB3AgentPolicy(OperatingRangeCheck):
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
        self.outside_range = checked_outside_range(outside_range)
        self.path = Path(path)
        self.model, self.meta = load_model(self.path)
        from agents.cards import operating_range

        self.operating_range = operating_range(self.meta)
        self.range_source = (f"its card ({self.path.with_suffix('.md').name}) gives no result there that it was "
                             "trained for")
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


__all__ = ["META_KEY", "LoadedModel", "OperatingRangeCheck", "OutsideOperatingRangeWarning", "PickledValue", "SB3AgentPolicy",
           "checked_outside_range", "default_meta", "env_meta", "is_model_path", "load_model", "compiled_forward",
           "read_meta"]

