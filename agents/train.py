"""``atc-nf train``: reinforcement learning with Stable-Baselines3, CleanRL style.

Two set-ups, one script:

* ``--mode shared`` (default): PPO with parameter sharing across aircraft. Every aircraft
  is an agent of the PettingZoo ``ParallelEnv``; SuperSuit turns ``num_envs`` copies of it
  into one SB3 vector env (``black_death_v3`` -> ``pettingzoo_env_to_vec_env_v1`` ->
  ``concat_vec_envs_v1``), in which each aircraft is one sub-env, so one policy network
  sees every aircraft's ego observation and acts for each. ``--vec native`` uses the
  package's own vector env instead (``make_sb3_vec_env(mode="shared")``: the same
  observations, actions and rewards, all worlds stepped in one kernel call; much faster).
* ``--mode centralized``: PPO or SAC (``--algo sac``) on the centralized env (one agent
  sees all aircraft and acts for all), through the native vector env
  (``make_sb3_vec_env(mode="centralized")``).

``--init-from MODEL.zip`` starts PPO from a saved PPO model (e.g. the policy cloned from
the MPC by ``atc-nf imitate``): weights copied, the actor optionally frozen for the first
``--value-warmup-updates`` updates so that the fresh critic learns the returns first.

Outputs in ``--out``: ``model.zip`` (the final model, with the metadata
``agents.policy.SB3AgentPolicy`` needs), ``checkpoints/``, ``tb/`` (tensorboard logs:
``tensorboard --logdir OUT/tb``), ``config.json`` (the configuration, the command, the
wall time). Seeds: ``--seed`` seeds torch, NumPy and the action sampling; the training
episodes' seeds start at ``--env-seed-offset + 1000 * seed`` (world b gets that + b at the
first reset, later episodes draw their seeds from the worlds' generators), far from the
evaluation seeds 0..N-1 of ``atc-nf evaluate``. Every training episode's seed lies in the
benchmark's train split (``atc_nf_env.benchmark``; a stream's: the offset counts from the
stream tasks' train split, 3 000 000 000): the first ones are checked, the envs draw the
later ones inside it (``atc_nf_env.envs.drawn_seed_split``).

Example (``agents/models/finetuned_ppo.md`` has the exact command of a shipped model):

    atc-nf train --mode shared --vec native --scenario converging-4 --total-timesteps 200000 --out out/train
    atc-nf evaluate --policy out/train/model.zip --scenario converging-4 --runs 100
"""

from __future__ import annotations

import json
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from agents._config import arg, config_dict, parse_config, progress_callback, write_json


@dataclass
class Args:
    # --- what to train
    algo: str = arg("ppo", "ppo or sac (sac: --mode centralized only)")
    mode: str = arg("shared", "shared (one policy for every aircraft) or centralized (one agent for all)")
    vec: str = arg("supersuit", "shared mode's vectorization: supersuit (PettingZoo ParallelEnv) or native")
    scenario: str = arg("converging-4", "converging-N, random-N or a scenario .json")
    wind_sigma: float = arg(5.17, "standard deviation of each wind component, m/s")
    max_episode_minutes: float = arg(180.0, "episode time limit, min")
    n_neighbours: int = arg(4, "K nearest neighbours in each observation")
    max_aircraft: int = arg(0, "centralized: aircraft slots (0: the scenario's number)")
    reward_weights: str = arg("", 'JSON of RewardWeights fields, e.g. \'{"envelope_violation": 10}\'')
    envelope_margin_kt: float = arg(0.0, "experimental (--vec native, shared): penalize every aircraft whose airspeed "
                                         "came within this margin of the envelope's edges during the period (0: off)")
    envelope_margin_weight: float = arg(0.0, "weight of that penalty: weight × (margin − closest approach) / margin, "
                                             "capped at 2 × weight (beyond the edge by a margin or more)")
    num_envs: int = arg(16, "worlds (copies of the environment) stepped together")
    total_timesteps: int = arg(200_000, "environment steps (SB3 counts one per sub-env per step)")
    seed: int = arg(0, "seeds torch, NumPy and the action noise")
    env_seed_offset: int = arg(10_000, "training episode seeds start at this + 1000 * seed, inside the train split "
                                       "(a stream's: counted from its first seed, 3e9)")
    # --- algorithm
    learning_rate: float = arg(3e-4, "learning rate")
    net_arch: str = arg("64,64", "hidden layer sizes of the actor and of the critic")
    gamma: float = arg(0.99, "discount per 5-min decision")
    batch_size: int = arg(1024, "minibatch size")
    n_steps: int = arg(64, "PPO: steps per sub-env per rollout")
    n_epochs: int = arg(5, "PPO: epochs per rollout")
    gae_lambda: float = arg(0.95, "PPO: GAE lambda")
    clip_range: float = arg(0.2, "PPO: clip range")
    ent_coef: float = arg(0.0, "PPO: entropy coefficient")
    vf_coef: float = arg(0.5, "PPO: value loss coefficient")
    target_kl: float = arg(0.0, "PPO: stop an update's epochs past this KL (0: never)")
    log_std_init: float = arg(-0.5, "PPO: initial log std of the Gaussian policy")
    buffer_size: int = arg(200_000, "SAC: replay buffer size")
    learning_starts: int = arg(2_000, "SAC: steps before learning")
    gradient_steps: int = arg(1, "SAC: gradient steps per env step")
    # --- fine-tuning
    init_from: Path | None = arg(None, "start from this PPO model .zip (e.g. a cloned policy)")
    keep_log_std: bool = arg(True, "with --init-from: keep the model's log std (else set --log-std-init)")
    value_warmup_updates: int = arg(0, "with --init-from: PPO updates with the actor frozen, critic only")
    # --- bookkeeping
    out: Path = arg(Path("out/train"), "output folder (model.zip, checkpoints/, tb/, config.json)")
    checkpoint_every: int = arg(50_000, "save a checkpoint every this many timesteps (0: never)")
    max_wall_minutes: float = arg(0.0, "stop learning (and save the model) after this many minutes of wall time (0: never)")
    eval_runs: int = arg(0, "after training, evaluate on seeds 0..N-1 with atc-nf evaluate's evaluator "
                            "(prints runs safe and runs home out of N)")
    eval_every: int = arg(0, "every this many timesteps, fly --eval-every-runs runs on seeds 0..R-1 and print runs "
                             "safe and runs home (rows of OUT/evaluations.csv; 0: never)")
    eval_every_runs: int = arg(10, "runs of each periodic evaluation (--eval-every)")
    torch_threads: int = arg(2, "torch CPU threads")
    progress: bool = arg(True, "show a progress bar")
    verbose: int = arg(0, "SB3 verbosity")


# ------------------------------------------------------------------ 1. environments


def env_kwargs(args: Args) -> dict[str, Any]:
    kwargs: dict[str, Any] = {
        "scenario": args.scenario,
        "wind_sigma": args.wind_sigma,
        "max_episode_minutes": args.max_episode_minutes,
        "n_neighbours": args.n_neighbours,
    }
    if args.reward_weights:
        kwargs["reward_weights"] = json.loads(args.reward_weights)
    if args.mode == "centralized" and args.max_aircraft:
        kwargs["max_aircraft"] = args.max_aircraft
    return kwargs


def make_vec_env(args: Args) -> Any:
    """The SB3 vector env of the configuration, wrapped in ``VecMonitor``."""
    from stable_baselines3.common.vec_env import VecMonitor

    from atc_nf_env.envs.vector import make_sb3_vec_env, seedable_sb3_vec_env

    kwargs = env_kwargs(args)
    if args.mode == "centralized" or args.vec == "native":
        venv = make_sb3_vec_env(args.num_envs, mode=args.mode, **kwargs)
    else:
        import supersuit as ss

        import atc_nf_env

        parallel = ss.black_death_v3(atc_nf_env.parallel_env(**kwargs))  # arrived aircraft see zeros
        venv = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(parallel), args.num_envs, num_cpus=0,
                                     base_class="stable_baselines3")
        venv = seedable_sb3_vec_env(venv)  # PPO(seed=...) calls venv.seed(), which SuperSuit lacks
    if args.envelope_margin_kt > 0 and args.envelope_margin_weight > 0:
        venv = EnvelopeMarginPenalty(venv, args.envelope_margin_kt, args.envelope_margin_weight)
    # Parameter sharing: VecMonitor counts one episode per aircraft.
    return VecMonitor(venv)


def EnvelopeMarginPenalty(venv: Any, margin_kt: float, weight: float) -> Any:  # noqa: N802 - a wrapper class's factory
    """The native shared vector env with a shaping term on the airspeed envelope's margin:
    an aircraft that flew during the period and whose extreme airspeeds came within
    ``margin_kt`` of [366, 540] kt loses weight × (margin − m) / margin, capped at
    2 × weight, where m = min(min airspeed − 366, 540 − max airspeed) over the period's
    integration steps. The env's own reward (and its envelope penalty) is unchanged; this
    is an experiment towards agents that stay in the envelope without the filter, not an
    env default. The extreme airspeeds come from the kernel's trace of each step, which
    the native vector env computes anyway (its ``worlds.step`` is wrapped to keep it)."""
    import numpy as np
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT

    class _Penalty(VecEnvWrapper):
        def __init__(self) -> None:
            super().__init__(venv)
            worlds = getattr(venv, "worlds", None)
            if worlds is None or getattr(venv, "mode", None) != "shared":
                raise ValueError("--envelope-margin-kt needs --mode shared --vec native (the package's vector env)")
            self.penalty: np.ndarray | None = None
            step = worlds.step

            def step_and_keep(actions: Any, active: Any = None) -> Any:
                outcome, trace = step(actions, active)
                closest = np.minimum(trace.min_airspeed_kt - AIRSPEED_MIN_KT, AIRSPEED_MAX_KT - trace.max_airspeed_kt)
                deficit = np.clip((margin_kt - closest) / margin_kt, 0.0, 2.0)
                self.penalty = np.where(outcome.flew, weight * deficit, 0.0).reshape(-1)
                return outcome, trace

            worlds.step = step_and_keep

        def reset(self) -> Any:
            return self.venv.reset()

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            if self.penalty is None or self.penalty.shape != rewards.shape:
                raise RuntimeError(f"envelope margin penalty: {None if self.penalty is None else self.penalty.shape} "
                                   f"per-aircraft terms for {rewards.shape} rewards (one per aircraft slot expected)")
            rewards = rewards - self.penalty.astype(rewards.dtype)
            self.penalty = None
            return obs, rewards, dones, infos

    return _Penalty()


def check_args(args: Args) -> None:
    if args.algo not in ("ppo", "sac"):
        raise ValueError(f"--algo {args.algo!r}: allowed: ppo, sac")
    if args.mode not in ("shared", "centralized"):
        raise ValueError(f"--mode {args.mode!r}: allowed: shared, centralized")
    if args.vec not in ("supersuit", "native"):
        raise ValueError(f"--vec {args.vec!r}: allowed: supersuit, native")
    if args.algo == "sac" and args.mode != "centralized":
        raise ValueError("--algo sac trains the centralized agent: add --mode centralized")
    if args.init_from is not None and args.algo != "ppo":
        raise ValueError("--init-from starts PPO from a PPO model: use --algo ppo")
    if args.init_from is not None and not Path(args.init_from).is_file():
        raise ValueError(f"--init-from {args.init_from}: no such file")
    if args.total_timesteps < 1 or args.num_envs < 1:
        raise ValueError("--total-timesteps and --num-envs must be >= 1")
    if args.eval_every < 0 or args.eval_every_runs < 1 or args.eval_runs < 0:
        raise ValueError("--eval-every and --eval-runs must be >= 0, --eval-every-runs >= 1")
    if not (args.envelope_margin_kt >= 0 and args.envelope_margin_weight >= 0):
        raise ValueError("--envelope-margin-kt and --envelope-margin-weight must be >= 0")
    if args.envelope_margin_kt > 0 and args.envelope_margin_weight > 0 and (args.mode, args.vec) != ("shared", "native"):
        raise ValueError("--envelope-margin-kt needs --mode shared --vec native (the package's vector env)")
    if not args.max_wall_minutes >= 0:
        raise ValueError(f"--max-wall-minutes {args.max_wall_minutes}: must be >= 0 (0: no limit)")
    first_training_seed(args)


def first_training_seed(args: Args) -> int:
    """World 0's episode seed at the first reset (world b gets this + b): ``--env-seed-offset
    + 1000 * --seed`` from the train split's first seed. ValueError unless every world's
    first seed lies in the train split, where the envs draw the later episodes' seeds:
    training never flies a validation or test seed."""
    from atc_nf_env.envs import drawn_seed_split
    from atc_nf_env.envs.streams import is_stream

    split = drawn_seed_split(is_stream(args.scenario))
    offset = args.env_seed_offset + 1000 * args.seed
    if offset < 0 or offset + args.num_envs > split.size:
        raise ValueError(
            f"--env-seed-offset {args.env_seed_offset} with --seed {args.seed} and --num-envs {args.num_envs}: the first "
            f"episodes' seeds {split.first + offset}..{split.first + offset + args.num_envs - 1} leave the train split "
            f"{split.first}..{split.first + split.size - 1}; need 0 <= offset + 1000 * seed <= {split.size - args.num_envs}"
        )
    return split.first + offset


def net_arch_of(text: str) -> list[int]:
    sizes = [int(s) for s in text.split(",") if s.strip()]
    if not sizes or min(sizes) < 1:
        raise ValueError(f"--net-arch {text!r}: give hidden layer sizes, e.g. 64,64")
    return sizes


# ------------------------------------------------------------------ 2. model


def make_model(args: Args, venv: Any) -> Any:
    """A fresh PPO/SAC model, or PPO started from ``--init-from``."""
    import torch

    from stable_baselines3 import PPO, SAC

    arch = net_arch_of(args.net_arch)
    tb = str(args.out / "tb")
    if args.algo == "sac":
        return SAC("MlpPolicy", venv, learning_rate=args.learning_rate, buffer_size=args.buffer_size,
                   learning_starts=args.learning_starts, batch_size=args.batch_size, gamma=args.gamma,
                   gradient_steps=args.gradient_steps, policy_kwargs={"net_arch": arch}, seed=args.seed,
                   tensorboard_log=tb, device="cpu", verbose=args.verbose)
    policy_kwargs: dict[str, Any] = {"net_arch": {"pi": arch, "vf": arch}, "log_std_init": args.log_std_init}
    source = None
    if args.init_from is not None:
        from agents.policy import load_model

        source = load_model(args.init_from)[0]  # never unpickles: SB3's PPO.load would run a hostile zip's code
        policy_kwargs = {"net_arch": source.policy.net_arch, "activation_fn": source.policy.activation_fn,
                         "log_std_init": args.log_std_init}
    model = PPO("MlpPolicy", venv, learning_rate=args.learning_rate, n_steps=args.n_steps,
                batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma, gae_lambda=args.gae_lambda,
                clip_range=args.clip_range, ent_coef=args.ent_coef, vf_coef=args.vf_coef,
                target_kl=args.target_kl or None, policy_kwargs=policy_kwargs, seed=args.seed,
                tensorboard_log=tb, device="cpu", verbose=args.verbose)
    if source is not None:
        if source.observation_space.shape != model.observation_space.shape:
            raise ValueError(f"--init-from {args.init_from}: its observations have shape "
                             f"{source.observation_space.shape}, this env's {model.observation_space.shape}")
        state = source.policy.state_dict()
        if not args.keep_log_std:
            state["log_std"] = torch.full_like(state["log_std"], args.log_std_init)
        model.policy.load_state_dict(state)
    return model


def model_meta(args: Args, venv: Any, command: str) -> dict[str, Any]:
    """What ``SB3AgentPolicy`` needs to fly the model, and how it was trained."""
    from agents.policy import env_meta
    from atc_nf_env.envs import EnvConfig, ScenarioSource

    cfg = EnvConfig.from_kwargs(env_kwargs(args), "atc-nf train")
    slots = venv.action_space.shape[0] if args.mode == "centralized" else None
    n = ScenarioSource(args.scenario).n_aircraft
    operating = {"n_aircraft": [n, n], "wind_sigma_mps": [args.wind_sigma, args.wind_sigma]}
    return {"algo": args.algo, "mode": args.mode, "env": env_meta(cfg, slots), "operating_range": operating,
            "training": {"script": "atc-nf train", "command": command, "scenario": args.scenario,
                         "seed": args.seed, "total_timesteps": args.total_timesteps,
                         "init_from": None if args.init_from is None else str(args.init_from)}}


def save_model(model: Any, path: Path, meta: dict[str, Any]) -> Path:
    """Save with the metadata (``agents.policy.META_KEY``) inside the zip."""
    from agents.cards import provenance
    from agents.policy import META_KEY

    meta = {**meta, "provenance": provenance()}
    setattr(model, META_KEY, meta)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(path), include=[META_KEY])
    return path


# ------------------------------------------------------------------ 3. callbacks

CURVE_HEADER = "timesteps,wall_s,episodes,mean_return,mean_length,success_rate"
EVALUATIONS_HEADER = "timesteps,runs,runs_safe,runs_home,runs_with_los,runs_outside_envelope"


def _mean(values: list[Any]) -> float | None:
    return float(sum(values) / len(values)) if values else None



def make_callbacks(args: Args, meta: dict[str, Any]) -> list[Any]:
    from stable_baselines3.common.callbacks import BaseCallback

    class Checkpoints(BaseCallback):
        """Save the model (with its metadata) every ``checkpoint_every`` timesteps."""

        def _on_training_start(self) -> None:
            self.next_save = args.checkpoint_every

        def _on_step(self) -> bool:
            if args.checkpoint_every and self.model.num_timesteps >= self.next_save:
                save_model(self.model, args.out / "checkpoints" / f"model_{self.model.num_timesteps}.zip", meta)
                self.next_save += args.checkpoint_every
            return True

    class ValueWarmup(BaseCallback):
        """Freeze the actor (policy net, action net, log std) for the first N updates."""

        def _on_training_start(self) -> None:
            self.updates = 0

        def _actor_params(self) -> list[Any]:
            policy = self.model.policy
            return [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(), policy.log_std]

        def _on_rollout_end(self) -> None:
            frozen = self.updates < args.value_warmup_updates
            for p in self._actor_params():
                p.requires_grad_(not frozen)
            if frozen:
                for p in self._actor_params():
                    p.grad = None
            self.logger.record("train/actor_frozen", float(frozen))
            self.updates += 1

        def _on_step(self) -> bool:
            return True

    class LearningCurve(BaseCallback):
        """One row of ``OUT/curve.csv`` per rollout: timesteps, wall time, and the mean
        return, length (decisions) and success of the last 100 episodes (with parameter
        sharing one episode is one aircraft slot); stops learning past --max-wall-minutes."""

        def _on_training_start(self) -> None:
            self.start = time.perf_counter()
            self.path = args.out / "curve.csv"
            self.path.write_text(CURVE_HEADER + "\n")
            self.stop = False

        def _on_rollout_end(self) -> None:
            episodes = list(self.model.ep_info_buffer)
            successes = list(self.model.ep_success_buffer)
            wall = time.perf_counter() - self.start
            row = [self.model.num_timesteps, round(wall), len(episodes),
                   _mean([e["r"] for e in episodes]), _mean([e["l"] for e in episodes]), _mean(successes)]
            with self.path.open("a") as file:
                file.write(",".join("" if v is None else (f"{v:.4f}" if isinstance(v, float) else str(v)) for v in row) + "\n")
            self.stop = bool(args.max_wall_minutes) and wall >= 60.0 * args.max_wall_minutes

        def _on_step(self) -> bool:
            return not self.stop

    class PeriodicEvaluation(BaseCallback):
        """Every ``eval_every`` timesteps: save the model, fly it on seeds 0..R-1 and append
        per-run safety to ``OUT/evaluations.csv`` (timesteps, runs, runs safe, runs home,
        runs with LoS, runs outside the envelope)."""

        def _on_training_start(self) -> None:
            self.next_eval = args.eval_every
            self.path = args.out / "evaluations.csv"
            self.path.write_text(EVALUATIONS_HEADER + "\n")

        def _on_step(self) -> bool:
            if self.model.num_timesteps >= self.next_eval:
                model_path = save_model(self.model, args.out / "eval_model.zip", meta)
                report = safety_report(str(model_path), args.scenario, args.eval_every_runs, args.wind_sigma,
                                       label=f"evaluation at {self.model.num_timesteps} timesteps")["per_run"]
                with self.path.open("a") as file:
                    file.write(",".join(str(v) for v in (self.model.num_timesteps, report["runs"], report["runs_safe"],
                                                         report["runs_home"], report["runs_with_los"],
                                                         report["runs_outside_envelope"])) + "\n")
                for key in ("runs_safe", "runs_home"):
                    self.logger.record(f"eval/{key}", report[key])
                self.next_eval += args.eval_every
            return True

    callbacks = [progress_callback(args.total_timesteps, args.progress), Checkpoints(), LearningCurve()]
    if args.eval_every:
        callbacks.append(PeriodicEvaluation())
    if args.value_warmup_updates and args.algo == "ppo":
        callbacks.append(ValueWarmup())
    return callbacks


# ------------------------------------------------------------------ 4. train


def train(args: Args, command: str | None = None) -> dict[str, Any]:
    """Train, save ``OUT/model.zip`` and ``OUT/config.json``; returns the config record."""
    import numba
    import torch

    check_args(args)
    torch.set_num_threads(max(1, args.torch_threads))
    numba.set_num_threads(min(numba.config.NUMBA_NUM_THREADS, max(1, args.torch_threads)))
    command = command or "atc-nf train " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    args.out.mkdir(parents=True, exist_ok=True)

    venv = make_vec_env(args)
    model = make_model(args, venv)
    # Training episodes draw seeds far from the evaluation seeds 0..N-1 (model init seeded
    # the env with --seed; this replaces it before the first reset).
    venv.seed(first_training_seed(args))
    meta = model_meta(args, venv, command)

    start = time.perf_counter()
    model.learn(total_timesteps=args.total_timesteps, callback=make_callbacks(args, meta),
                tb_log_name=f"{args.algo}_{args.mode}", progress_bar=False)
    wall = time.perf_counter() - start
    meta["training"]["wall_s"] = round(wall, 3)
    meta["training"]["timesteps_done"] = int(model.num_timesteps)
    path = save_model(model, args.out / "model.zip", meta)
    venv.close()

    record = {"config": config_dict(args), "command": command, "wall_s": round(wall, 3), "model": str(path),
              "timesteps": int(model.num_timesteps)}
    if args.eval_runs:
        record["evaluation"] = evaluate_model(path, args.scenario, args.eval_runs, args.wind_sigma)
    write_json(args.out / "config.json", record)
    print(f"model written to {path} ({wall:.0f} s, {model.num_timesteps} timesteps)")
    return record


def safety_report(policy: str, scenario: str, runs: int, wind_sigma: float, first_seed: int = 0,
                  label: str = "evaluation") -> dict[str, Any]:
    """Fly ``policy`` on seeds first_seed..first_seed+runs-1 and count per run: runs safe
    (no loss of separation and no integration step outside the envelope,
    ``atc_nf_env.benchmark.run_is_safe``), runs home (every aircraft arrived), runs with a
    loss of separation, runs outside the envelope; prints one line and returns the
    evaluator's summary with those counts added (``per_run``)."""
    from atc_nf_env.benchmark import run_is_safe
    from atc_nf_env.evaluate import Study, evaluate

    records: list[dict[str, Any]] = []
    summary = evaluate(Study(policy=policy, scenario=scenario, wind_sigma_mps=wind_sigma), runs,
                       first_seed=first_seed, workers=1, progress=False, on_run=records.append)
    per_run = {
        "runs": len(records),
        "runs_safe": sum(run_is_safe(r) for r in records),
        "runs_home": sum(bool(r["success"]) for r in records),
        "runs_with_los": sum(int(r["los_count"]) > 0 for r in records),
        "runs_outside_envelope": sum(float(r["envelope_violation_fraction"]) > 0 for r in records),
        "seeds": [first_seed, first_seed + runs - 1],
    }
    print(f"{label} on {scenario}, seeds {first_seed}..{first_seed + runs - 1}: "
          f"{per_run['runs_safe']}/{per_run['runs']} runs safe (with LoS {per_run['runs_with_los']}, outside the "
          f"envelope {per_run['runs_outside_envelope']}), {per_run['runs_home']}/{per_run['runs']} runs home",
          flush=True)
    return {**summary, "per_run": per_run}


def evaluate_model(path: Path, scenario: str, runs: int, wind_sigma: float) -> dict[str, Any]:
    """The evaluator's summary of the model on the held-out seeds 0..runs-1, with the
    per-run safety counts (``safety_report``)."""
    summary = safety_report(str(path), scenario, runs, wind_sigma, label="final evaluation")
    keys = ("runs", "success_rate", "los_count", "envelope_violation_fraction", "flight_time_min", "decision_s")
    print(json.dumps({k: summary.get(k) for k in keys}))
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_config(Args, argv, prog="atc-nf train", description=__doc__.split("\n\n")[0])
    command = "atc-nf train " + " ".join(shlex.quote(a) for a in (sys.argv[2:] if argv is None else argv))
    try:
        train(args, command)
    except ValueError as error:
        print(f"atc-nf train: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
