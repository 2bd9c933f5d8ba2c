"""``atc-nf imitate``: learn the MCMC-MPC's waypoints, then optionally improve on them.

Read top to bottom, as the script runs:

1. **Demonstrations.** The MPC (``baselines.MCMCMPC``, the paper's settings unless
   ``--expert-extractions``/``--expert-horizon`` say otherwise) flies training episodes
   (seeds from ``--first-seed`` = 10 000 up: never the evaluation seeds 0..N-1) inside
   ``run_episode``, wrapped in a recorder that stores, at every decision and for every
   flying aircraft, the aircraft's observation (the environments' own observation code:
   ``agents.policy.ego_observations``) and the MPC's waypoint as an action of the
   environments' action space (``waypoint_to_action``; the MPC's proposals, 100 ± 10 nm
   and ±90°, lie inside the default 100 ± 40 nm, ±90° mapping). Episodes run in parallel
   worker processes, one ``.npz`` per episode in ``OUT/demos/<stage>/<scenario>/``;
   files already there are skipped, so a killed collection resumes where it stopped.
2. **Behaviour cloning** into the actor of an SB3 ``ActorCriticPolicy`` (the policy of a
   PPO model, so that step 4 can fine-tune it): maximise the log-likelihood of the MPC's
   action under the policy's Gaussian (``--bc-loss nll``; ``mse`` fits the mean only),
   Adam on minibatches, a validation split by episode, the best epoch kept. Two choices
   make the MPC's labels learnable by a deterministic policy:

   * *Arrived aircraft only* (``--arrived-only``): in some MPC episodes an aircraft ends in
     a holding orbit near its destination (REPRODUCTION.md); those aircraft's samples are
     dropped from the MPC's own episodes.
   * *One chirality* (``--canonical-chirality``): the MPC resolves the symmetric
     converging encounters by a roundabout turning either way, chosen at random; the mean
     of both is flying straight into the conflict. The world is mirror-symmetric, so an
     episode whose traffic turned clockwise about the encounter centre (negative summed
     angular momentum of the flown path) is mirrored (every "left" and "sin" feature of
     the ego observation and the action's angle change sign) before training: the
     cloned policy learns one direction of roundabout and flies it consistently.

   ``--policy-arch deepsets`` clones into the permutation-invariant network of
   ``agents.deepsets`` instead of the MLP (with ``--n-neighbours`` slots; it flies any
   number of aircraft), and ``--wind-sigmas LO,HI`` draws each episode's wind sigma in
   that range, so that one model learns mixed traffic and wind.

3. **DAgger** (``--dagger-iterations``): the current policy flies new training episodes
   while the MPC labels every state the learner visits (its wind estimate follows the
   learner's flight: after each decision the MPC's prediction of the applied waypoints
   is recomputed for the learner's waypoints, so the drift it measures is the real one);
   the labels are added to the dataset and the policy is trained further on all of it.
4. **PPO fine-tuning** (``--finetune-steps``): ``atc-nf train`` with ``--init-from`` the
   last cloned model, parameter-shared PPO on the native vector env.

The ``imitation`` library would do 2 and 3, but it pins gymnasium 0.29 and SB3 2.2
(this project runs gymnasium 1.x and SB3 2.9), so both are written here with torch on
SB3's own policy objects.

Outputs in ``--out``: ``demos/``, ``bc.zip``, ``dagger-<k>.zip``, ``finetune/model.zip``,
``tb/`` (tensorboard: losses per epoch), ``log.json`` (dataset sizes, losses, wall times,
quick checks on validation seeds 5000.., which are neither training nor evaluation seeds).
With ``--resume`` (default), a stage whose model is already in ``--out`` is loaded instead
of trained again.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from agents._config import arg, config_dict, parse_config, write_json
from atc_nf_env.units import WIND_SIGMA_MPS

#: Seeds of the quick checks after each stage: neither training (10 000+) nor evaluation (0..N-1).
CHECK_SEED = 5_000
#: DAgger iteration k's episodes start at first_seed + k * DAGGER_SEED_STRIDE.
DAGGER_SEED_STRIDE = 100_000


@dataclass
class Args:
    # --- demonstrations
    out: Path = arg(Path("out/imitate"), "output folder")
    episodes: str = arg("converging-4:300,converging-6:60,random-4:120",
                        "MPC demonstration episodes per scenario, SCENARIO:COUNT,...")
    first_seed: int = arg(10_000, "first training episode seed (evaluation uses 0..N-1)")
    workers: int = arg(0, "worker processes for the episodes (0: all cores)")
    expert_extractions: int = arg(1000, "the MPC's K (the paper: 1000)")
    expert_horizon: int = arg(4, "the MPC's N (the paper: 4)")
    max_minutes: float = arg(150.0, "time limit of a collected episode, min")
    wind_sigmas: str = arg("", "LO,HI: each episode's wind sigma drawn uniformly in [LO, HI] m/s from its seed "
                               "(empty: the default 5.17 m/s)")
    # --- behaviour cloning
    net_arch: str = arg("64,64", "hidden layers of the actor (and of PPO's critic)")
    policy_arch: str = arg("mlp", "mlp (on the K nearest neighbours in order) or deepsets (agents.deepsets: a "
                                  "permutation-invariant set of neighbours, any N)")
    n_neighbours: int = arg(4, "K neighbour slots of the observation")
    deepsets_hidden: int = arg(64, "deepsets: width of the own and neighbour encoders")
    bc_loss: str = arg("nll", "nll (Gaussian log-likelihood) or mse (on the mean action)")
    bc_epochs: int = arg(40, "epochs of the first behaviour cloning")
    batch_size: int = arg(256, "minibatch size")
    learning_rate: float = arg(1e-3, "Adam learning rate")
    val_fraction: float = arg(0.1, "fraction of episodes held out for validation")
    canonical_chirality: bool = arg(True, "mirror clockwise episodes so that all turn one way")
    arrived_only: bool = arg(True, "drop samples of aircraft that never arrived, in the MPC's own episodes")
    log_std_init: float = arg(-1.0, "initial log std of the policy's Gaussian")
    # --- DAgger
    dagger_iterations: int = arg(0, "DAgger iterations (0: behaviour cloning only)")
    dagger_episodes: str = arg("converging-4:100,converging-6:30,random-4:60",
                               "learner episodes per DAgger iteration, SCENARIO:COUNT,...")
    dagger_epochs: int = arg(20, "epochs of training after each DAgger iteration")
    # --- PPO fine-tuning
    finetune_steps: int = arg(0, "PPO timesteps of fine-tuning from the cloned policy (0: none)")
    finetune_scenario: str = arg("converging-4", "scenario of the fine-tuning")
    finetune_num_envs: int = arg(32, "worlds of the fine-tuning's vector env")
    finetune_lr: float = arg(1e-4, "fine-tuning learning rate")
    finetune_clip_range: float = arg(0.1, "fine-tuning PPO clip range")
    finetune_gamma: float = arg(0.97, "fine-tuning discount per decision (< 1 rewards arriving sooner)")
    finetune_reward_weights: str = arg('{"envelope_violation": 20.0, "loss_of_separation": 50.0}',
                                       "fine-tuning RewardWeights (JSON)")
    finetune_value_warmup: int = arg(5, "fine-tuning updates with the actor frozen (critic warm-up)")
    # --- bookkeeping
    check_runs: int = arg(20, "after each stage, fly this many validation episodes per scenario (0: none)")
    seed: int = arg(0, "seeds torch, the validation split and the minibatches")
    resume: bool = arg(True, "reuse demonstrations and stage models already in --out")
    torch_threads: int = arg(2, "torch CPU threads")
    progress: bool = arg(True, "progress bars")


# ------------------------------------------------------------------ 1. demonstrations


def parse_episodes(text: str) -> list[tuple[str, int]]:
    """``"converging-4:300,random-4:100"`` -> [("converging-4", 300), ("random-4", 100)]."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        name, _, count = part.rpartition(":")
        if not name or not count.isdigit():
            raise ValueError(f"episodes {text!r}: write SCENARIO:COUNT,... e.g. converging-4:300")
        out.append((name, int(count)))
    return out


class RecordingExpert:
    """A policy for ``run_episode`` that records (observation, MPC action) per flying aircraft.

    Without a learner the MPC flies (demonstrations); with one, the learner flies and the
    MPC only labels (DAgger), its wind estimate kept consistent with the learner's flight.
    """

    name = "recording-mpc"

    def __init__(self, expert: Any, obs_spec_kwargs: dict[str, Any], learner: Any = None) -> None:
        from agents.policy import time_limit_s
        from atc_nf_env.envs.actions import ActionMapping

        self.expert = expert
        self.learner = learner
        self.n_neighbours = int(obs_spec_kwargs["n_neighbours"])
        self.time_limit_s = time_limit_s(obs_spec_kwargs["max_episode_minutes"])
        self.mapping = ActionMapping.coerce(obs_spec_kwargs.get("action_mapping"))

    def reset(self, scenario: Any, config: Any, seed: int | None = None) -> None:
        from atc_nf_env import kernel
        from atc_nf_env.envs.observations import ObservationSpec

        self.expert.reset(scenario, config, seed)
        if self.learner is not None:
            self.learner.reset(scenario, config, seed)
        self.spec = ObservationSpec.for_config(config, self.n_neighbours, False)
        self.params = config.to_params(scenario.workspace_radius_nm)  # no stop on violation
        self.scratch = kernel.KernelScratch()
        self.obs: list[np.ndarray] = []
        self.labels: list[np.ndarray] = []
        self.learner_actions: list[np.ndarray] = []
        self.aircraft: list[np.ndarray] = []
        self.decision: list[np.ndarray] = []
        self.positions: list[np.ndarray] = []
        self.flying: list[np.ndarray] = []

    def act(self, view: Any) -> np.ndarray:
        from agents.policy import ego_observations
        from atc_nf_env.envs.actions import waypoint_to_action

        expert_wp = self.expert.act(view)
        flying = view.flying
        index = np.flatnonzero(flying)
        obs = ego_observations(self.spec, view, self.time_limit_s)
        labels = waypoint_to_action(expert_wp, view.positions, view.destinations, self.mapping)
        self.obs.append(obs[index])
        self.labels.append(labels[index])
        self.aircraft.append(index)
        self.decision.append(np.full(index.size, len(self.positions)))
        self.positions.append(view.positions.copy())
        self.flying.append(flying.copy())
        if self.learner is None:
            self.learner_actions.append(labels[index])
            return expert_wp
        waypoints = self.learner.act(view)
        self.learner_actions.append(waypoint_to_action(waypoints, view.positions, view.destinations,
                                                       self.mapping)[index])
        self._shadow_prediction(view, waypoints)
        return waypoints

    def _shadow_prediction(self, view: Any, waypoints: np.ndarray) -> None:
        """Tell the MPC where the learner's waypoints (not its own) should put the aircraft
        under its wind estimate, so that its next drift measurement is the real one
        (``MCMCMPC._update_wind_estimate`` compares the next positions with this)."""
        from atc_nf_env import kernel
        from atc_nf_env.kernel import S_X, S_Y

        mpc = self.expert
        state = view.state[None].copy()
        kernel.advance(state, waypoints[None], mpc._wind_estimate_kt[None].copy(), mpc.settings.period_s,
                       self.params, scratch=self.scratch)
        mpc._predicted_positions = state[0, :, S_X : S_Y + 1].copy()
        mpc._predicted_time_s = view.time_s + mpc.settings.period_s

    def arrays(self) -> dict[str, np.ndarray]:
        dim = self.spec.dim
        cat = (lambda items, shape: np.concatenate(items) if items else np.zeros(shape))
        return {
            "obs": cat(self.obs, (0, dim)).astype(np.float32),
            "act": cat(self.labels, (0, 2)).astype(np.float32),
            "learner_act": cat(self.learner_actions, (0, 2)).astype(np.float32),
            "aircraft": cat(self.aircraft, (0,)).astype(np.int64),
            "decision": cat(self.decision, (0,)).astype(np.int64),
            "positions": np.array(self.positions),
            "flying": np.array(self.flying),
        }


def collect_episode(task: dict[str, Any]) -> dict[str, Any]:
    """Fly one episode of ``task`` and save its samples to ``task["path"]`` (atomically)."""
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario
    from baselines import MCMCMPC

    start = time.perf_counter()
    learner = None
    if task.get("learner"):
        from agents.policy import SB3AgentPolicy

        learner = SB3AgentPolicy(task["learner"])
    expert = MCMCMPC(extractions=task["extractions"], horizon=task["horizon"])
    recorder = RecordingExpert(expert, task["env"], learner)
    scenario = make_scenario(task["scenario"], seed=task["seed"])
    result = run_episode(recorder, scenario, seed=task["seed"], max_time_s=task["max_minutes"] * 60.0,
                         wind_sigma_mps=task.get("wind_sigma", WIND_SIGMA_MPS))
    m = result.metrics
    arrays = recorder.arrays()
    info = expert.episode_info()
    path = Path(task["path"])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez_compressed(
        tmp, **arrays, arrived=np.array(m.arrived), success=m.success, los_count=m.los_count,
        envelope_violation_fraction=m.envelope_violation_fraction,
        flight_time_min=np.array(m.flight_time_min), expert_acted=learner is None, seed=task["seed"],
        scenario=task["scenario"], fallbacks=info["fallbacks"], wall_s=time.perf_counter() - start,
        wind_sigma_mps=task.get("wind_sigma", WIND_SIGMA_MPS),
    )
    os.replace(tmp, path)
    return {"path": str(path), "samples": int(arrays["obs"].shape[0]), "success": bool(m.success),
            "los": int(m.los_count), "violation": float(m.envelope_violation_fraction)}


def _worker_init() -> None:
    import numba

    numba.set_num_threads(1)  # parallelism is across episodes
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass


def collect(tasks: list[dict[str, Any]], workers: int, progress: bool, label: str) -> dict[str, Any]:
    """Run the tasks whose file is missing, in parallel; a summary of what was run."""
    todo = [t for t in tasks if not Path(t["path"]).exists()]
    start = time.perf_counter()
    results: list[dict[str, Any]] = []
    if todo:
        workers = min(workers or os.cpu_count() or 1, len(todo))
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), unit="episode", desc=label,
                       dynamic_ncols=True)
        if workers == 1:
            stream: Any = map(collect_episode, todo)
            pool = None
        else:
            import multiprocessing as mp

            pool = mp.get_context("spawn").Pool(workers, initializer=_worker_init)
            stream = pool.imap_unordered(collect_episode, todo)
        try:
            for result in stream:
                results.append(result)
                if bar is not None:
                    bar.update(1)
        finally:
            if pool is not None:
                pool.close()
                pool.join()
            if bar is not None:
                bar.close()
    return {"episodes": len(tasks), "collected_now": len(results), "wall_s": round(time.perf_counter() - start, 1),
            "success_rate_now": float(np.mean([r["success"] for r in results])) if results else None}


def make_tasks(args: Args, stage: str, episodes: str, first_seed: int, learner: Path | None,
               env: dict[str, Any]) -> list[dict[str, Any]]:
    folder = args.out / "demos" / stage
    expert = {"extractions": args.expert_extractions, "horizon": args.expert_horizon, "max_minutes": args.max_minutes,
              "env": env, "learner": None if learner is None else str(learner)}
    sigma_range = wind_sigma_range(args.wind_sigmas)
    if args.wind_sigmas:
        expert["wind_sigmas"] = list(sigma_range)
    _check_folder(folder, expert)
    tasks = []
    for k, (scenario, count) in enumerate(parse_episodes(episodes)):
        base = first_seed + k * 10_000  # distinct seed blocks per scenario
        for j in range(count):
            seed = base + j
            task = {**expert, "scenario": scenario, "seed": seed, "path": str(folder / scenario / f"seed_{seed}.npz")}
            if args.wind_sigmas:
                task["wind_sigma"] = episode_wind_sigma(seed, sigma_range)
            tasks.append(task)
    return tasks


def wind_sigma_range(text: str) -> tuple[float, float]:
    """``"0,10"`` -> (0.0, 10.0); empty -> the default sigma twice."""
    if not text.strip():
        return (WIND_SIGMA_MPS, WIND_SIGMA_MPS)
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--wind-sigmas {text!r}: write LO,HI in m/s, e.g. 0,10") from None
    if not (0.0 <= low <= high and np.isfinite(high)):
        raise ValueError(f"--wind-sigmas {text!r}: need 0 <= LO <= HI, finite")
    return (low, high)


def episode_wind_sigma(seed: int, sigma_range: tuple[float, float]) -> float:
    """The wind sigma of training episode ``seed``, m/s: uniform in the range, drawn from
    a generator of its own (the episode's wind direction still comes from ``seed``)."""
    low, high = sigma_range
    return float(np.random.default_rng([seed, 7]).uniform(low, high))


def operating_range(args: Args) -> dict[str, list[float]]:
    """The numbers of aircraft and the wind sigmas the training episodes covered."""
    from atc_nf_env.scenarios import make_scenario

    counts = [make_scenario(name, seed=0).n_aircraft for name, _ in parse_episodes(args.episodes)]
    low, high = wind_sigma_range(args.wind_sigmas)
    return {"n_aircraft": [min(counts), max(counts)], "wind_sigma_mps": [low, high]}


def _check_folder(folder: Path, expert: dict[str, Any]) -> None:
    """Demonstrations of one stage share their expert settings: refuse to mix."""
    folder.mkdir(parents=True, exist_ok=True)
    record = folder / "expert.json"
    settings = {k: v for k, v in expert.items() if k != "learner"}
    if record.exists():
        old = json.loads(record.read_text())
        if {k: old.get(k) for k in settings} != json.loads(json.dumps(settings)):
            raise ValueError(f"{folder} holds demonstrations with other settings ({old}); choose another --out")
    record.write_text(json.dumps({**settings, "learner": expert["learner"]}, indent=2) + "\n")


# ------------------------------------------------------------------ 2. dataset


def mirror_signs(n_neighbours: int) -> np.ndarray:
    """Signs (D,) that mirror an ego observation (y -> -y in the world): every ego-frame
    "left" component and the bearing's sine change sign."""
    from atc_nf_env.envs.observations import ObservationSpec

    labels = ObservationSpec(n_neighbours=n_neighbours).labels()
    flips = ("dest_sin", "wp_left", "_left", "_vel_left", "wind_left")
    return np.array([-1.0 if name.endswith(flips) else 1.0 for name in labels], dtype=np.float32)


def chirality(positions: np.ndarray, flying: np.ndarray) -> float:
    """Summed angular momentum of the flown path about the encounter centre (0, 0), nm²:
    positive when the traffic turned counter-clockwise."""
    if len(positions) < 2:
        return 0.0
    p, dp = positions[:-1], positions[1:] - positions[:-1]
    cross = p[..., 0] * dp[..., 1] - p[..., 1] * dp[..., 0]
    return float((cross * flying[:-1]).sum())


@dataclass
class Dataset:
    obs: np.ndarray
    act: np.ndarray
    episode: np.ndarray  # (S,) episode index, for the validation split
    episodes: int
    mirrored: int
    dropped: int


def load_dataset(folders: list[Path], canonical_chirality: bool, arrived_only: bool, n_neighbours: int) -> Dataset:
    """Every episode file under ``folders``, canonicalized and filtered (module docstring)."""
    signs = mirror_signs(n_neighbours)
    obs, act, episode = [], [], []
    mirrored = dropped = count = 0
    for folder in folders:
        for path in sorted(folder.glob("*/seed_*.npz")):
            if path.name.endswith(".tmp.npz"):
                continue
            with np.load(path) as data:
                o, a = data["obs"], data["act"]
                keep = np.ones(len(o), dtype=bool)
                if arrived_only and bool(data["expert_acted"]):
                    keep = data["arrived"][data["aircraft"]]
                dropped += int((~keep).sum())
                o, a = o[keep], a[keep].copy()
                if canonical_chirality and chirality(data["positions"], data["flying"]) < 0:
                    o = o * signs
                    a[:, 1] = -a[:, 1]
                    mirrored += 1
            obs.append(o)
            act.append(a)
            episode.append(np.full(len(o), count))
            count += 1
    if not count:
        raise ValueError(f"no demonstrations in {[str(f) for f in folders]}")
    return Dataset(np.concatenate(obs).astype(np.float32), np.concatenate(act).astype(np.float32),
                   np.concatenate(episode), count, mirrored, dropped)


# ------------------------------------------------------------------ 3. behaviour cloning


def new_model(net_arch: list[int], log_std_init: float, seed: int, n_neighbours: int = 4, policy_arch: str = "mlp",
              deepsets_hidden: int = 64) -> Any:
    """A PPO model whose ``ActorCriticPolicy`` receives the cloned actor (its env only gives
    the spaces: one aircraft's observation and action)."""
    from stable_baselines3 import PPO

    from atc_nf_env.envs.vector import make_sb3_vec_env

    venv = make_sb3_vec_env(1, mode="shared", scenario="converging-4", n_neighbours=n_neighbours)
    if policy_arch == "deepsets":
        from agents.deepsets import policy_kwargs

        kwargs = policy_kwargs(deepsets_hidden, net_arch, log_std_init)
    elif policy_arch == "mlp":
        kwargs = {"net_arch": {"pi": net_arch, "vf": net_arch}, "log_std_init": log_std_init}
    else:
        raise ValueError(f"--policy-arch {policy_arch!r}: allowed: mlp, deepsets")
    return PPO("MlpPolicy", venv, policy_kwargs=kwargs, seed=seed, device="cpu")


def actor_parameters(policy: Any) -> list[Any]:
    """The parameters behaviour cloning trains: the features extractor (when it has
    weights, as the deep-sets one does), the actor's MLP, its output layer, the log std."""
    return [*policy.pi_features_extractor.parameters(), *policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(),
            policy.log_std]


def bc_losses(policy: Any, obs: Any, act: Any, loss: str) -> tuple[Any, Any]:
    """(training loss, MSE of the deterministic action) of a batch, torch tensors."""
    import torch

    dist = policy.get_distribution(obs)
    mean = dist.distribution.mean
    mse = ((torch.clamp(mean, -1.0, 1.0) - act) ** 2).sum(dim=1).mean()
    if loss == "nll":
        return -dist.log_prob(act).mean(), mse
    return ((mean - act) ** 2).sum(dim=1).mean(), mse


def behaviour_cloning(model: Any, data: Dataset, *, epochs: int, batch_size: int, learning_rate: float,
                      val_fraction: float, loss: str, seed: int, writer: Any = None, tag: str = "bc",
                      progress: bool = False) -> dict[str, Any]:
    """Fit the actor of ``model.policy`` to (obs, act) in place; the epoch with the lowest
    validation loss is kept. Returns the history."""
    import torch

    if loss not in ("nll", "mse"):
        raise ValueError(f"bc loss {loss!r}: allowed: nll, mse")
    if len(data.obs) < 2:
        raise ValueError(
            f"behaviour cloning needs at least 2 samples, the dataset has {len(data.obs)} ({data.dropped} dropped "
            "because their aircraft never arrived): collect more or longer episodes (--episodes, --max-minutes) "
            "or keep every sample (--no-arrived-only)"
        )
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    val_episodes = rng.random(data.episodes) < val_fraction if data.episodes > 1 else np.zeros(1, bool)
    is_val = val_episodes[data.episode]
    if not is_val.any() or is_val.all():  # tiny datasets: hold out samples instead
        is_val = rng.random(len(data.obs)) < max(val_fraction, 1.0 / len(data.obs))
        if is_val.all():
            is_val[0] = False
    policy = model.policy
    policy.set_training_mode(True)
    obs = torch.as_tensor(data.obs)
    act = torch.as_tensor(data.act)
    train_idx, val_idx = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    optimizer = torch.optim.Adam(actor_parameters(policy), lr=learning_rate)

    def validation() -> tuple[float, float]:
        with torch.no_grad():
            v_loss, v_mse = bc_losses(policy, obs[val_idx], act[val_idx], loss)
        return float(v_loss), float(v_mse)

    history: dict[str, Any] = {"samples": int(len(data.obs)), "train": int(len(train_idx)),
                               "validation": int(len(val_idx)), "epochs": []}
    best_loss, _ = validation()
    history["initial_validation_loss"] = best_loss
    best_state = {k: v.clone() for k, v in policy.state_dict().items()}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=epochs, unit="epoch", desc=tag, dynamic_ncols=True)
    for epoch in range(epochs):
        order = rng.permutation(train_idx)
        total, batches = 0.0, 0
        for start in range(0, len(order), batch_size):
            batch = order[start : start + batch_size]
            train_loss, _ = bc_losses(policy, obs[batch], act[batch], loss)
            optimizer.zero_grad()
            train_loss.backward()
            torch.nn.utils.clip_grad_norm_(actor_parameters(policy), 1.0)
            optimizer.step()
            total += float(train_loss.detach())
            batches += 1
        v_loss, v_mse = validation()
        row = {"epoch": epoch, "train_loss": total / max(batches, 1), "val_loss": v_loss, "val_mse": v_mse,
               "log_std": policy.log_std.detach().numpy().round(3).tolist()}
        history["epochs"].append(row)
        if writer is not None:
            for key in ("train_loss", "val_loss", "val_mse"):
                writer.add_scalar(f"{tag}/{key}", row[key], epoch)
        if v_loss < best_loss:
            best_loss = v_loss
            best_state = {k: v.clone() for k, v in policy.state_dict().items()}
        if bar is not None:
            bar.set_postfix(val_loss=f"{v_loss:.3f}", val_mse=f"{v_mse:.4f}")
            bar.update(1)
    if bar is not None:
        bar.close()
    policy.load_state_dict(best_state)
    policy.set_training_mode(False)
    history["best_validation_loss"] = best_loss
    return history


# ------------------------------------------------------------------ 4. checks, saving


def quick_check(path: Path, scenarios: list[str], runs: int) -> dict[str, Any]:
    """The evaluator on validation seeds CHECK_SEED.. (neither training nor evaluation
    seeds), counted per run: runs safe, runs home (``agents.train.safety_report``)."""
    from agents.train import safety_report

    out = {}
    for scenario in scenarios:
        s = safety_report(str(path), scenario, runs, WIND_SIGMA_MPS, first_seed=CHECK_SEED, label=f"  check {path.name}")
        out[scenario] = {"success_rate": s["success_rate"], "los_count": s["los_count"],
                         "envelope_violation_fraction": round(s["envelope_violation_fraction"], 5),
                         "flight_time_min_mean": s["flight_time_min"]["mean"], **s["per_run"]}
    return out


def save_stage(model: Any, path: Path, args: Args, command: str, stage: str, extra: dict[str, Any]) -> Path:
    from agents.policy import env_meta
    from agents.train import save_model
    from atc_nf_env.envs import EnvConfig

    meta = {"algo": "ppo", "mode": "shared", "env": env_meta(EnvConfig(n_neighbours=args.n_neighbours)),
            "operating_range": operating_range(args),
            "training": {"script": "atc-nf imitate", "command": command, "stage": stage, "seed": args.seed,
                         "policy_arch": args.policy_arch, **extra}}
    return save_model(model, path, meta)


# ------------------------------------------------------------------ main


def _check_expert(args: Args) -> None:
    """Refuse the expert's settings before any demonstration starts."""
    from atc_nf_env.config import SimConfig
    from atc_nf_env.episode import whole_steps
    from baselines import MCMCMPC

    try:
        MCMCMPC(extractions=args.expert_extractions, horizon=args.expert_horizon)
    except (TypeError, ValueError) as error:
        raise ValueError(f"--expert-extractions/--expert-horizon: {error}") from None
    whole_steps("--max-minutes (in s)", args.max_minutes * 60.0, SimConfig().dt_s)
    parse_episodes(args.episodes)


def run(args: Args, command: str) -> dict[str, Any]:
    import torch
    from torch.utils.tensorboard import SummaryWriter

    from agents.train import net_arch_of
    from atc_nf_env.envs import EnvConfig
    from agents.policy import env_meta

    if args.bc_loss not in ("nll", "mse"):
        raise ValueError(f"--bc-loss {args.bc_loss!r}: allowed: nll, mse")
    _check_expert(args)
    wind_sigma_range(args.wind_sigmas)
    if args.policy_arch not in ("mlp", "deepsets"):
        raise ValueError(f"--policy-arch {args.policy_arch!r}: allowed: mlp, deepsets")
    torch.set_num_threads(max(1, args.torch_threads))
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "log.json"
    log: dict[str, Any] = {"config": config_dict(args), "command": command, "stages": {}}
    # A resumed run keeps what the earlier runs recorded about the stages it reuses.
    previous = json.loads(log_path.read_text()).get("stages", {}) if args.resume and log_path.exists() else {}
    writer = SummaryWriter(str(args.out / "tb"))
    env = env_meta(EnvConfig(n_neighbours=args.n_neighbours))
    scenarios = [name for name, _ in parse_episodes(args.episodes)]
    arch = net_arch_of(args.net_arch)
    started = time.perf_counter()

    def stage_done(name: str, path: Path, record: dict[str, Any]) -> None:
        if record.get("reused"):
            record = {**previous.get(name, {}), "reused": True}
        if args.check_runs:
            record["check"] = quick_check(path, scenarios, args.check_runs)
        record["elapsed_s"] = round(time.perf_counter() - started, 1)
        log["stages"][name] = record
        write_json(log_path, log)

    # 1. Demonstrations from the MPC, in parallel, one file per episode (resumable).
    tasks = make_tasks(args, "expert", args.episodes, args.first_seed, None, env)
    if not args.resume:
        for t in tasks:
            Path(t["path"]).unlink(missing_ok=True)
    log["stages"]["demonstrations"] = collect(tasks, args.workers, args.progress, "MPC demonstrations")
    if not log["stages"]["demonstrations"]["collected_now"] and "demonstrations" in previous:
        log["stages"]["demonstrations"]["first_collection"] = previous["demonstrations"].get(
            "first_collection", previous["demonstrations"])
    folders = [args.out / "demos" / "expert"]

    # 2. Behaviour cloning.
    path = args.out / "bc.zip"
    if args.resume and path.exists():
        from stable_baselines3 import PPO

        model = PPO.load(str(path), device="cpu")
        stage_done("bc", path, {"reused": True})
    else:
        t0 = time.perf_counter()
        data = load_dataset(folders, args.canonical_chirality, args.arrived_only, env["n_neighbours"])
        model = new_model(arch, args.log_std_init, args.seed, args.n_neighbours, args.policy_arch, args.deepsets_hidden)
        history = behaviour_cloning(model, data, epochs=args.bc_epochs, batch_size=args.batch_size,
                                    learning_rate=args.learning_rate, val_fraction=args.val_fraction,
                                    loss=args.bc_loss, seed=args.seed, writer=writer, tag="bc",
                                    progress=args.progress)
        wall = time.perf_counter() - t0
        dataset = {"episodes": data.episodes, "samples": int(len(data.obs)), "mirrored": data.mirrored,
                   "dropped": data.dropped}
        save_stage(model, path, args, command, "bc", {"dataset": dataset, "bc_wall_s": round(wall, 1)})
        print(f"behaviour cloning: {dataset}, validation loss {history['initial_validation_loss']:.3f} -> "
              f"{history['best_validation_loss']:.3f}; model written to {path}")
        stage_done("bc", path, {"dataset": dataset, "history": history, "wall_s": round(wall, 1)})

    # 3. DAgger: the learner flies, the MPC labels, aggregate, train further.
    for k in range(1, args.dagger_iterations + 1):
        learner = path
        path = args.out / f"dagger-{k}.zip"
        stage = f"dagger-{k}"
        tasks = make_tasks(args, stage, args.dagger_episodes, args.first_seed + k * DAGGER_SEED_STRIDE, learner, env)
        if args.resume and path.exists():
            from stable_baselines3 import PPO

            model = PPO.load(str(path), device="cpu")
            folders.append(args.out / "demos" / stage)
            stage_done(stage, path, {"reused": True})
            continue
        t0 = time.perf_counter()
        collected = collect(tasks, args.workers, args.progress, f"DAgger {k}: learner flies, MPC labels")
        folders.append(args.out / "demos" / stage)
        data = load_dataset(folders, args.canonical_chirality, args.arrived_only, env["n_neighbours"])
        history = behaviour_cloning(model, data, epochs=args.dagger_epochs, batch_size=args.batch_size,
                                    learning_rate=args.learning_rate, val_fraction=args.val_fraction,
                                    loss=args.bc_loss, seed=args.seed + k, writer=writer, tag=stage,
                                    progress=args.progress)
        wall = time.perf_counter() - t0
        dataset = {"episodes": data.episodes, "samples": int(len(data.obs)), "mirrored": data.mirrored,
                   "dropped": data.dropped}
        save_stage(model, path, args, command, stage, {"dataset": dataset, "wall_s": round(wall, 1)})
        print(f"{stage}: learner success {collected['success_rate_now']}, dataset {dataset}; model written to {path}")
        stage_done(stage, path, {"collection": collected, "dataset": dataset, "history": history,
                                 "wall_s": round(wall, 1)})

    # 4. Optional PPO fine-tuning from the cloned policy.
    if args.finetune_steps:
        from agents import train as rl

        from atc_nf_env.scenarios import make_scenario

        rollout = 32 * args.finetune_num_envs * make_scenario(args.finetune_scenario, seed=0).n_aircraft
        ft = rl.Args(mode="shared", vec="native", scenario=args.finetune_scenario, num_envs=args.finetune_num_envs,
                     total_timesteps=args.finetune_steps, seed=args.seed, learning_rate=args.finetune_lr,
                     clip_range=args.finetune_clip_range, gamma=args.finetune_gamma,
                     reward_weights=args.finetune_reward_weights, init_from=path,
                     value_warmup_updates=args.finetune_value_warmup, n_steps=32, batch_size=min(1024, rollout), n_epochs=5,
                     out=args.out / "finetune", checkpoint_every=max(args.finetune_steps // 4, 1),
                     torch_threads=args.torch_threads, progress=args.progress)
        final = args.out / "finetune" / "model.zip"
        if args.resume and final.exists():
            stage_done("finetune", final, {"reused": True})
        else:
            record = rl.train(ft, command=f"{command}  [stage finetune: atc-nf train with --init-from {path}]")
            stage_done("finetune", final, record)
    writer.close()
    log["wall_s"] = round(time.perf_counter() - started, 1)
    write_json(log_path, log)
    print(f"log written to {log_path}")
    return log


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_config(Args, argv, prog="atc-nf imitate", description=__doc__.split("\n\n")[0])
    command = "atc-nf imitate " + " ".join(shlex.quote(a) for a in (sys.argv[2:] if argv is None else argv))
    try:
        run(args, command)
    except ValueError as error:
        print(f"atc-nf imitate: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
