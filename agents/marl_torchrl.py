"""IPPO and MAPPO with TorchRL on the batched env, and the trained policy as a waypoint policy.

    from agents.marl_torchrl import train
    out = train("mappo", "converging-4", seed=0, frames=100_000, out=Path("runs/mappo-c4-s0"))

    python -m agents.marl_torchrl --algorithm mappo --task converging-4 --seed 0 --frames 100000 --out DIR
    atc-nf benchmark --policy DIR/policy.pt --task converging-4 --split test --runs 50

Training (needs torchrl and tensordict, ``examples/requirements-torch.txt``):

- the env is ``atc_nf_env.integrations.torchrl.AtcNfBatchedEnv``: ``num_envs`` worlds of the
  task's scenario under its wind, stepped in one kernel call; every episode has a seed
  of the train split: training seed s takes the consecutive seeds from
  ``s * 1_000_000`` on, one per episode in the order the worlds reset;
- one policy shared by every aircraft (``MultiAgentMLP(share_params=True,
  centralized=False)``): ego observation -> the loc and scale of a TanhNormal over the
  2-D action; the deterministic action is tanh(loc);
- the critic, also shared by every aircraft: IPPO's sees the aircraft's ego observation,
  MAPPO's the ego observation joined to the global state (``"state"``, every aircraft
  slot: the agent-specific global state of Yu et al., "The Surprising Effectiveness of
  PPO in Cooperative Multi-Agent Games", NeurIPS 2022);
- GAE per aircraft: an aircraft's trajectory ends (terminated) when it arrives or leaves,
  a world's time limit truncates (bootstrapped); ``ClipPPOLoss`` averaged over the
  aircraft that were flying when they acted (the others' zero observations and
  zero rewards are padding, not data).

A *frame* is one decision period (5 min) of one world: TorchRL's count of env steps
over the batch. One frame is M aircraft decisions (M = 4 on converging-4).

Output folder: ``policy.pt`` (the actor's weights and what the loader needs),
``curve.csv`` (per evaluation point: frames, wall s, mean training return per aircraft,
the validation runs' share safe and share home), ``meta.json`` (algorithm, task, seed,
frames, hyperparameters, versions, wall time).

Scoring: ``TorchRLPolicy(path)`` flies ``policy.pt`` as an ``atc_nf_env.policy.Policy``
(needs only torch); the ``pt`` entry of the ``atc_nf_env.policy_files`` group makes
``--policy DIR/policy.pt`` work wherever a policy file does (``atc-nf benchmark``,
``evaluate``, ``fly``).
"""

from __future__ import annotations

import os
import sys

# The kernel's worker threads (numba, OpenMP) and torch's share libgomp; with its default
# wait policy the idle kernel threads spin on the two cores that torch's updates need, and
# training runs ~3x slower. Effective only when this module loads before torch and numba's
# OpenMP layer (``python -m agents.marl_torchrl`` does; import this module first otherwise).
_OMP_PASSIVE = "torch" not in sys.modules or os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE"
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import csv
import json
import math
import platform
import time
import warnings
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from agents.compiled_forward import IDENTITY, SQUASH, TANH, mlp_actions, pack_layers, widest
from agents.policy import OperatingRangeCheck, checked_outside_range, torch_load_error
from atc_nf_env.benchmark import SPLITS, get_task
from atc_nf_env.config import SimConfig
from atc_nf_env.envs import EnvConfig
from atc_nf_env.envs.actions import ActionMapping, waypoints_for_state
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.kernel import ARRIVED, N_STATE, S_STATUS
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView
from atc_nf_env.units import DECISION_PERIOD_S

ALGORITHMS = ("ippo", "mappo")
#: The ``format`` field of a saved policy file.
POLICY_FORMAT = "atc-nf-torchrl-policy/1"
GROUP = "aircraft"
#: Each training seed owns this many consecutive train-split seeds, one per episode.
SEEDS_PER_RUN = 1_000_000


@dataclass
class PPOConfig:
    """Hyperparameters of IPPO and MAPPO (the same for both; only the critic's input differs).

    Attributes:
        num_envs: worlds stepped together (B).
        steps_per_batch: decision periods per world in one collected batch (T); a batch
            is B·T frames.
        epochs: passes of PPO over each batch.
        minibatch_frames: frames per minibatch (of whole worlds' time steps).
        lr: Adam's learning rate.
        gamma, lmbda: discount and GAE's λ (per decision period of 5 min).
        clip_epsilon: PPO's ratio clip.
        entropy_coef: weight of the entropy bonus.
        max_grad_norm: gradient clipping.
        hidden: units per hidden layer (two tanh layers, actor and critic).
        eval_every_batches: batches between evaluation points (and one at the end).
        eval_runs: validation-split runs per evaluation point (deterministic policy).
    """

    num_envs: int = 32
    steps_per_batch: int = 32
    epochs: int = 4
    minibatch_frames: int = 256
    lr: float = 3e-4
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 1e-3
    max_grad_norm: float = 1.0
    hidden: int = 64
    eval_every_batches: int = 10
    eval_runs: int = 32

    @property
    def frames_per_batch(self) -> int:
        return self.num_envs * self.steps_per_batch

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"PPOConfig.{f.name} = {value!r}: must be a finite number > 0")
        if self.minibatch_frames > self.frames_per_batch:
            raise ValueError(f"PPOConfig.minibatch_frames = {self.minibatch_frames}: must be <= num_envs x "
                             f"steps_per_batch = {self.frames_per_batch}")


# ----------------------------------------------------------------------------- training


def _check_args(algorithm: str, task: str, seed: int, frames: int) -> None:
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm = {algorithm!r}: allowed: {', '.join(ALGORITHMS)}")
    if get_task(task).is_stream:
        from atc_nf_env.benchmark import TASKS

        encounters = [name for name, t in TASKS.items() if not t.is_stream]
        raise ValueError(f"task = {task!r} is a traffic stream: the batched TorchRL env flies encounters; "
                         f"allowed: {', '.join(encounters)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < SPLITS["train"].size // SEEDS_PER_RUN:
        raise ValueError(f"seed = {seed!r}: must be an integer in [0, {SPLITS['train'].size // SEEDS_PER_RUN})")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames = {frames!r}: must be an integer >= 1 (decision periods summed over worlds)")


def _networks(algorithm: str, n_slots: int, obs_dim: int, state_dim: int, hidden: int,
              action_spec: Any) -> tuple[Any, Any]:
    """(actor, critic) TensorDict modules over the group ``aircraft``."""
    import torch
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torch import nn
    from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal

    actor_net = nn.Sequential(
        MultiAgentMLP(obs_dim, 4, n_slots, centralized=False, share_params=True, depth=2, num_cells=hidden,
                      activation_class=nn.Tanh),
        NormalParamExtractor(),
    )
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "loc"), (GROUP, "scale")]),
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        spec=action_spec,
        return_log_prob=True,
        log_prob_key=(GROUP, "action_log_prob"),
    )
    if algorithm == "ippo":
        critic = TensorDictModule(
            MultiAgentMLP(obs_dim, 1, n_slots, centralized=False, share_params=True, depth=2, num_cells=hidden,
                          activation_class=nn.Tanh),
            in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")],
        )
    else:
        class EgoAndState(nn.Module):
            """Each aircraft's ego observation joined to the global state, through one shared MLP."""

            def __init__(self) -> None:
                super().__init__()
                self.mlp = MultiAgentMLP(obs_dim + state_dim, 1, n_slots, centralized=False, share_params=True,
                                         depth=2, num_cells=hidden, activation_class=nn.Tanh)

            def forward(self, obs: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
                shared = state.unsqueeze(-2).expand(*obs.shape[:-1], state.shape[-1])
                return self.mlp(torch.cat([obs, shared], dim=-1))

        critic = TensorDictModule(EgoAndState(), in_keys=[(GROUP, "observation"), "state"],
                                  out_keys=[(GROUP, "state_value")])
    return actor, critic


def _actor_layers(actor: Any) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """The shared actor MLP's layers [(weight (out, in), bias (out,), activation)], the last
    one cut to the loc half of its outputs (what the deterministic action uses)."""
    from torch import nn

    mlp = actor.module[0].module[0]  # ProbabilisticActor -> TensorDictModule -> Sequential -> MultiAgentMLP
    params = mlp.params.flatten_keys(".")
    layers: list[tuple[np.ndarray, np.ndarray, str]] = []
    for name, module in mlp._empty_net.named_children():
        if isinstance(module, nn.Linear):
            layers.append((params[f"{name}.weight"].detach().cpu().numpy().astype(np.float32),
                           params[f"{name}.bias"].detach().cpu().numpy().astype(np.float32), "identity"))
        elif isinstance(module, nn.Tanh):
            weight, bias, _ = layers[-1]
            layers[-1] = (weight, bias, "tanh")
        else:
            raise TypeError(f"unexpected module {type(module).__name__} in the actor")
    weight, bias, activation = layers[-1]
    half = weight.shape[0] // 2
    layers[-1] = (weight[:half].copy(), bias[:half].copy(), activation)
    return layers


@dataclass
class _Evaluation:
    runs: int
    safe: int
    home: int
    mean_return: float


def _evaluate(actor: Any, env_kwargs: dict[str, Any], seeds: Sequence[int]) -> _Evaluation:
    """Fly the deterministic policy on ``seeds`` (one world each) to each world's end."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    env = AtcNfBatchedEnv(len(seeds), **env_kwargs)
    td = env.reset_with_seeds(seeds)
    b = env.num_envs
    ended = np.zeros(b, dtype=bool)
    unsafe = np.zeros(b, dtype=bool)
    returns = np.zeros(b)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.cfg.max_decisions):
            td = env.step(actor(td))
            nxt = td["next"]
            live = ~ended
            unsafe |= live & ((nxt[GROUP, "los_count"] > 0).any(-1) | nxt[GROUP, "envelope_violation"].any(-1)).numpy()
            returns += np.where(live, nxt[GROUP, "reward"].squeeze(-1).mean(-1).numpy(), 0.0)
            ended |= nxt["done"].squeeze(-1).numpy()
            if ended.all():
                break
            td = step_mdp(td)
    status = env.worlds.state[:, :, S_STATUS]
    present = env.worlds.present
    home = ((status == ARRIVED) | ~present).all(axis=1)
    return _Evaluation(runs=b, safe=int((~unsafe).sum()), home=int(home.sum()), mean_return=float(returns.mean()))


def _versions() -> dict[str, str]:
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for name in ("torch", "torchrl", "tensordict", "numpy", "numba", "atc-nf-env"):
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "not installed"
    return out


def train(algorithm: str, task: str, seed: int, frames: int, out: Path, config: PPOConfig | None = None,
          progress: bool = True) -> Path:
    """Train IPPO or MAPPO on ``task`` for ``frames`` frames (decision periods summed over the
    worlds; rounded up to whole batches) and write ``policy.pt``, ``curve.csv`` and
    ``meta.json`` into ``out``. Returns the path of ``policy.pt``.

    Same ``seed`` and config, same weights: torch's and the env's generators are seeded,
    and training runs in one thread (``torch.set_num_threads(1)``); a different torch
    build may still round differently.
    """
    _check_args(algorithm, task, seed, frames)
    config = config or PPOConfig()
    if not _OMP_PASSIVE:
        warnings.warn("torch was imported before agents.marl_torchrl without OMP_WAIT_POLICY=PASSIVE: the kernel's "
                      "idle OpenMP threads may spin and slow training ~3x; set OMP_WAIT_POLICY=PASSIVE in the "
                      "environment or import agents.marl_torchrl first", RuntimeWarning, stacklevel=2)
    import torch
    from torch import nn
    from torchrl.collectors import Collector
    from torchrl.envs import RewardSum, TransformedEnv
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    task_ = get_task(task)
    env_kwargs = {"scenario": task_.scenario, "wind_sigma": task_.wind_sigma_mps}
    first_seed = SPLITS["train"].first + seed * SEEDS_PER_RUN
    train_seeds = iter(range(first_seed, first_seed + SEEDS_PER_RUN))
    base = AtcNfBatchedEnv(config.num_envs, episode_seeds=train_seeds, **env_kwargs)
    env = TransformedEnv(base, RewardSum(in_keys=[(GROUP, "reward")], out_keys=[(GROUP, "episode_reward")]))
    m = base.n_slots
    actor, critic = _networks(algorithm, m, base.observation_dim, base.state_dim, config.hidden,
                              base.full_action_spec)
    n_batches = max(1, math.ceil(frames / config.frames_per_batch))
    collector = Collector(env, actor, frames_per_batch=config.frames_per_batch,
                          total_frames=n_batches * config.frames_per_batch, auto_register_policy_transforms=False)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=config.clip_epsilon, entropy_coeff=config.entropy_coef,
                       normalize_advantage=False, reduction="none")
    loss.set_keys(reward=(GROUP, "reward"), action=(GROUP, "action"), sample_log_prob=(GROUP, "action_log_prob"),
                  value=(GROUP, "state_value"), done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.lmbda)
    optimizer = torch.optim.Adam(loss.parameters(), lr=config.lr)
    val = SPLITS["validation"]
    eval_seeds = list(val.seeds(config.eval_runs))
    rows: list[dict[str, Any]] = []
    recent_returns: list[float] = []
    frames_done = 0
    start = time.perf_counter()
    generator = torch.Generator().manual_seed(seed)

    def evaluation_point(batch_index: int) -> None:
        result = _evaluate(actor, env_kwargs, eval_seeds)
        row = {
            "batch": batch_index, "frames": frames_done, "wall_s": round(time.perf_counter() - start, 2),
            "train_return_mean": float(np.mean(recent_returns)) if recent_returns else float("nan"),
            "eval_runs": result.runs, "eval_safe_share": result.safe / result.runs,
            "eval_home_share": result.home / result.runs, "eval_return_mean": result.mean_return,
        }
        rows.append(row)
        recent_returns.clear()
        if progress:
            print(f"{algorithm} {task} seed {seed}: frames {frames_done:>8}  wall {row['wall_s']:>7.1f} s  "
                  f"train return {row['train_return_mean']:7.3f}  validation: safe {result.safe}/{result.runs}  "
                  f"home {result.home}/{result.runs}  return {result.mean_return:7.3f}", flush=True)

    evaluation_point(0)
    for batch_index, batch in enumerate(collector, start=1):
        frames_done += batch.numel()
        nxt = batch["next"]
        flying_next = nxt[GROUP, "mask"].unsqueeze(-1)
        shape = nxt[GROUP, "reward"].shape
        # An aircraft's own trajectory ends when it stops flying; the world's time limit
        # truncates every aircraft still flying.
        nxt.set((GROUP, "terminated"), nxt["terminated"].unsqueeze(-1).expand(shape) | ~flying_next)
        nxt.set((GROUP, "done"), nxt["done"].unsqueeze(-1).expand(shape) | ~flying_next)
        ended = nxt["done"].squeeze(-1)
        if ended.any():
            recent_returns.extend(nxt[GROUP, "episode_reward"][ended].squeeze(-1).mean(-1).tolist())
        with torch.no_grad():
            loss.value_estimator(batch, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        flat = batch.reshape(-1)
        steps = flat.shape[0]
        per_minibatch = max(1, config.minibatch_frames)
        for _ in range(config.epochs):
            order = torch.randperm(steps, generator=generator)
            for first in range(0, steps, per_minibatch):
                sample = flat[order[first:first + per_minibatch]]
                valid = sample[GROUP, "mask"].float()  # aircraft flying when they acted
                weight = valid / valid.sum().clamp_min(1.0)
                terms = loss(sample)
                total = sum((terms[key].reshape(valid.shape) * weight).sum()
                            for key in ("loss_objective", "loss_critic", "loss_entropy"))
                optimizer.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), config.max_grad_norm)
                optimizer.step()
        collector.update_policy_weights_()
        if batch_index % config.eval_every_batches == 0 or batch_index == n_batches:
            evaluation_point(batch_index)
    collector.shutdown()
    wall_s = time.perf_counter() - start
    torch.set_num_threads(threads)

    layers = _actor_layers(actor)
    policy_path = out / "policy.pt"
    cfg = base.cfg
    torch.save({
        "format": POLICY_FORMAT,
        "algorithm": algorithm,
        "task": task,
        "seed": seed,
        "frames": frames_done,
        "layers": [{"weight": torch.from_numpy(w), "bias": torch.from_numpy(b), "activation": a}
                   for w, b, a in layers],
        "output": "tanh",
        "env": {"n_neighbours": int(cfg.n_neighbours), "max_episode_minutes": float(cfg.max_episode_minutes),
                "action_mapping": cfg.action_mapping.as_dict(), "observation_dim": base.observation_dim},
        "actor_state_dict": actor.state_dict(),
    }, policy_path)
    _check_saved_policy(policy_path, actor, base)
    with open(out / "curve.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    meta = {
        "algorithm": algorithm,
        "task": task,
        "scenario": task_.scenario,
        "wind_sigma_mps": task_.wind_sigma_mps,
        "seed": seed,
        "frames_asked": frames,
        "frames": frames_done,
        "frame": "one decision period (5 min) of one world; aircraft decisions = frames x aircraft",
        "aircraft_slots": m,
        "train_seeds": f"train split, one per episode from {first_seed} on "
                       f"({first_seed}..{first_seed + base.episodes_started - 1})",
        "eval_seeds": f"validation split {eval_seeds[0]}..{eval_seeds[-1]}",
        "wall_s": round(wall_s, 2),
        "frames_per_s": round(frames_done / wall_s, 1),
        "torch_threads": 1,
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
        "ppo": asdict(config),
        "final": rows[-1],
        "versions": _versions(),
    }
    (out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
    return policy_path


def _check_saved_policy(path: Path, actor: Any, env: Any) -> None:
    """The saved layers must give the actor's deterministic action (to float32 rounding)."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = actor(td)[GROUP, "action"].numpy().reshape(-1, 2)
    obs = td[GROUP, "observation"].numpy().reshape(-1, env.observation_dim)
    got = TorchRLPolicy(path).actions(obs)
    if not np.allclose(got, expected, atol=1e-5):
        raise RuntimeError(f"{path}: the saved policy's actions differ from the actor's by "
                           f"{np.abs(got - expected).max():.3g}")


# ----------------------------------------------------------------------------- the policy


_ACTIVATIONS = {"identity": IDENTITY, "tanh": TANH}
#: The output squashing a saved policy may name (its deterministic action is tanh(loc)).
_OUTPUTS = ("tanh",)
#: The most layers, and units per layer, a saved policy may have.
MAX_LAYERS = 64
MAX_UNITS = 4096


def _required(path: Path, mapping: dict[str, Any], key: str, where: str = "") -> Any:
    if key not in mapping:
        raise ValueError(f"{path}: the policy file lacks {where}{key!r}; a policy.pt written by "
                         f"agents.marl_torchrl.train has format, algorithm, task, layers, output and env")
    return mapping[key]


def _checked_layers(path: Path, saved: dict[str, Any]) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The actor's layers [(W^T (in, out) float32, b (out,) float32, activation code)] of a
    policy file, each checked: 2-D weights and 1-D biases of finite floats, widths that
    chain from one layer to the next and end in the 2 action values, a known activation.

    Raises:
        ValueError: naming the file and the layer and field that is missing or wrong.
    """
    import torch

    layers = _required(path, saved, "layers")
    if not isinstance(layers, list) or not 1 <= len(layers) <= MAX_LAYERS:
        raise ValueError(f"{path}: its 'layers' = {type(layers).__name__} of length {_length(layers)}: must be a "
                         f"list of 1 to {MAX_LAYERS} layers")
    checked = []
    for index, layer in enumerate(layers):
        where = f"layers[{index}]"
        if not isinstance(layer, dict):
            raise ValueError(f"{path}: its {where} is a {type(layer).__name__}: must be a dict with weight, bias "
                             "and activation")
        weight, bias, activation = (_required(path, layer, key, f"{where}.") for key in ("weight", "bias",
                                                                                          "activation"))
        if not (isinstance(weight, torch.Tensor) and weight.ndim == 2 and weight.is_floating_point()
                and 1 <= min(weight.shape) and max(weight.shape) <= MAX_UNITS):
            raise ValueError(f"{path}: its {where}.weight = {_describe(weight)}: must be a 2-D float tensor "
                             f"(out, in) of 1 to {MAX_UNITS} units each")
        if not (isinstance(bias, torch.Tensor) and bias.ndim == 1 and bias.is_floating_point()
                and bias.shape[0] == weight.shape[0]):
            raise ValueError(f"{path}: its {where}.bias = {_describe(bias)}: must be a 1-D float tensor of "
                             f"{weight.shape[0]} values (the weight's rows)")
        if not (bool(torch.isfinite(weight).all()) and bool(torch.isfinite(bias).all())):
            raise ValueError(f"{path}: its {where} holds NaN or inf; every weight must be finite")
        if not isinstance(activation, str) or activation not in _ACTIVATIONS:
            raise ValueError(f"{path}: its {where}.activation = {activation!r:.40}: allowed: "
                             f"{', '.join(_ACTIVATIONS)}")
        if checked and weight.shape[1] != checked[-1][0].shape[1]:
            raise ValueError(f"{path}: its {where}.weight takes {weight.shape[1]} inputs, but layers[{index - 1}] "
                             f"gives {checked[-1][0].shape[1]}")
        checked.append((weight.detach().to(torch.float32).numpy().T.copy(),
                        bias.detach().to(torch.float32).numpy().copy(), _ACTIVATIONS[activation]))
    if checked[-1][0].shape[1] != 2:
        raise ValueError(f"{path}: its last layer gives {checked[-1][0].shape[1]} values; the action has 2")
    return checked


def _length(value: Any) -> str:
    return str(len(value)) if isinstance(value, (list, tuple, dict, str)) else "-"


def _describe(value: Any) -> str:
    import torch

    if isinstance(value, torch.Tensor):
        return f"a {value.dtype} tensor of shape {tuple(value.shape)}"
    return f"{value!r:.40}"


class TorchRLPolicy(OperatingRangeCheck):
    """A ``policy.pt`` written by ``train`` as an ``atc_nf_env.policy.Policy``: every flying
    aircraft's ego observation (the envs' own code) through the shared actor, its
    deterministic action tanh(loc) mapped to a waypoint with the envs' action mapping.
    Needs only torch (to read the file, ``weights_only=True``: tensors and plain values,
    nothing unpickled); the forward pass is the compiled MLP of ``agents.compiled_forward``.
    Units: waypoints in nm.

    Args:
        path: the ``policy.pt``.
        outside_range: "warn" (once per model and process), "refuse" (ValueError) or
            "ignore", when an episode's number of aircraft or wind sigma is not its training
            task's (as ``agents.policy.SB3AgentPolicy``).

    Raises:
        ValueError: the file is missing, is not a policy written by ``train``, or lacks
            (or holds a wrong) field, named in the message.
    """

    def __init__(self, path: str | Path, outside_range: str = "warn") -> None:
        import torch

        self.outside_range = checked_outside_range(outside_range)
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"policy file {str(self.path)!r} does not exist; give the policy.pt that "
                             "agents.marl_torchrl.train wrote")
        try:
            saved = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as error:  # a damaged file, another kind of .pt, or one that needs unpickling
            raise ValueError(f"{self.path}: not a policy written by agents.marl_torchrl.train "
                             f"({torch_load_error(error)})") from None
        if not isinstance(saved, dict) or saved.get("format") != POLICY_FORMAT:
            raise ValueError(f"{self.path}: not a policy written by agents.marl_torchrl.train (no format "
                             f"{POLICY_FORMAT!r})")
        self.meta = {key: value for key, value in saved.items() if key not in ("layers", "actor_state_dict")}
        algorithm = _required(self.path, saved, "algorithm")
        if algorithm not in ALGORITHMS:
            raise ValueError(f"{self.path}: its algorithm = {algorithm!r:.40}: allowed: {', '.join(ALGORITHMS)}")
        self.name = f"{algorithm}-{self.path.parent.name or self.path.stem}"
        output = _required(self.path, saved, "output")
        if output not in _OUTPUTS:
            raise ValueError(f"{self.path}: its output = {output!r:.40}: allowed: {', '.join(_OUTPUTS)}")
        task_name = _required(self.path, saved, "task")
        try:
            task = get_task(task_name)
        except ValueError as error:
            raise ValueError(f"{self.path}: its {error}") from None
        env = _required(self.path, saved, "env")
        if not isinstance(env, dict):
            raise ValueError(f"{self.path}: its env = {env!r:.40}: must be a dict with n_neighbours, "
                             "max_episode_minutes and action_mapping")
        n_neighbours, minutes, mapping = (_required(self.path, env, key, "env.")
                                          for key in ("n_neighbours", "max_episode_minutes", "action_mapping"))
        if isinstance(n_neighbours, bool) or not isinstance(n_neighbours, int) or not 0 <= n_neighbours <= MAX_UNITS:
            raise ValueError(f"{self.path}: its env.n_neighbours = {n_neighbours!r:.40}: must be an integer in "
                             f"[0, {MAX_UNITS}]")
        try:
            self.mapping = ActionMapping.coerce(mapping)
            limit = EnvConfig(max_episode_minutes=minutes)
        except Exception as error:  # the settings' own checks, on values of any type the file holds
            raise ValueError(f"{self.path}: its env: {type(error).__name__}: {error}") from None
        self.n_neighbours = n_neighbours
        self.time_limit_s = limit.max_decisions * DECISION_PERIOD_S
        layers = _checked_layers(self.path, saved)
        self.obs_dim = int(layers[0][0].shape[0])
        if self.obs_dim != ObservationSpec(n_neighbours=self.n_neighbours).dim:
            raise ValueError(f"{self.path}: input size {self.obs_dim} does not fit K = {self.n_neighbours} neighbours")
        from atc_nf_env.scenarios import make_scenario

        n_aircraft = make_scenario(task.scenario, seed=0).n_aircraft
        self.operating_range = {"n_aircraft": [n_aircraft, n_aircraft],
                                "wind_sigma_mps": [task.wind_sigma_mps, task.wind_sigma_mps]}
        self.range_source = f"it was trained on task {task_name!r} alone"
        self._weights, self._layout = pack_layers(layers)
        width = widest(self._layout)
        self._buf_a, self._buf_b = np.zeros(width, np.float32), np.zeros(width, np.float32)
        self._spec: ObservationSpec | None = None

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (B, 2) float32 in [-1, 1] of ego observations (B, D)."""
        x = np.ascontiguousarray(obs, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.obs_dim:
            raise ValueError(f"observations of shape {np.shape(obs)}; expected (B, {self.obs_dim})")
        out = np.empty((x.shape[0], 2), dtype=np.float32)
        if not mlp_actions(x, self._weights, self._layout, SQUASH, self._buf_a, self._buf_b, out):
            raise ValueError("observations contain NaN or inf; all must be finite")
        return out

    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Prepare for ``scenario`` flown with ``config`` (deterministic: ``seed`` is unused)."""
        self._spec = ObservationSpec.for_config(config, self.n_neighbours, False)
        self._workspace_radius_nm = float(scenario.workspace_radius_nm)
        self._aircraft_radius_nm = float(config.aircraft_radius_nm)

    def act(self, view: WorldView) -> np.ndarray:
        """Waypoints (N, 2), nm; aircraft no longer flying are ignored by the runner."""
        if self._spec is None:
            raise RuntimeError("call reset(scenario, config, seed) before act()")
        state = view.state
        if state.ndim != 2 or state.shape[1] != N_STATE:
            raise ValueError(f"state of shape {state.shape}; expected (N, {N_STATE})")
        time_fraction = np.array([min(1.0, view.time_s / self.time_limit_s)])
        obs = self._spec.observe(state[None], time_fraction, np.zeros((1, 2)))[0]
        actions = self.actions(obs).astype(np.float64)[None]
        return waypoints_for_state(actions, state[None], self.mapping, self._workspace_radius_nm,
                                   self._aircraft_radius_nm)[0]


def score(policy_path: str | Path, task: str, split: str = "test", runs: int = 50, shield: bool = False,
          reference: bool = False) -> dict[str, Any]:
    """The benchmark's score card of a ``policy.pt`` (``atc_nf_env.benchmark.score_card``),
    flown in this process; works before the ``pt`` policy-file entry point is installed."""
    from atc_nf_env import policy as policy_registry
    from atc_nf_env.benchmark import score_card

    spec = str(policy_path)
    if "pt" not in policy_registry.policy_file_suffixes():
        policy_registry.register_policy(spec, lambda: TorchRLPolicy(spec))
    return score_card(spec, task, split, runs, shield=shield, reference=reference, workers=1)


# ----------------------------------------------------------------------------- command line


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m agents.marl_torchrl", description=__doc__.splitlines()[0])
    parser.add_argument("--algorithm", required=True, choices=ALGORITHMS)
    parser.add_argument("--task", default="converging-4")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=100_000,
                        help="decision periods summed over worlds (default 100000)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--num-envs", type=int, default=PPOConfig.num_envs)
    parser.add_argument("--eval-every", type=int, default=PPOConfig.eval_every_batches, help="batches")
    parser.add_argument("--eval-runs", type=int, default=PPOConfig.eval_runs)
    parser.add_argument("--score-runs", type=int, default=0,
                        help="after training, score the policy on this many test-split runs (0: none)")
    args = parser.parse_args(argv)
    try:
        config = PPOConfig(num_envs=args.num_envs, eval_every_batches=args.eval_every, eval_runs=args.eval_runs)
        path = train(args.algorithm, args.task, args.seed, args.frames, args.out, config)
    except ValueError as error:
        print(f"agents.marl_torchrl: {error}", file=sys.stderr)
        return 2
    print(f"wrote {path}, {args.out / 'curve.csv'}, {args.out / 'meta.json'}")
    if args.score_runs:
        from atc_nf_env.benchmark import format_card

        card = score(path, args.task, "test", args.score_runs)
        (args.out / "card-test.json").write_text(json.dumps(card, indent=2) + "\n")
        print(format_card(card))
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["ALGORITHMS", "POLICY_FORMAT", "PPOConfig", "TorchRLPolicy", "main", "score", "train"]
