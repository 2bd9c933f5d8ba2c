"""The benchmark's baseline table: standard learners trained with several seeds, scored on
the test split alone and inside the safety filter, next to the MPC and the NF alone.

    python -m agents.baselines_table --write          # train, score, write docs/baselines.md
    python -m agents.baselines_table --quick          # a tiny budget (the tests' plumbing)
    make baselines                                     # the first, in TorchRL's venv (.venv-torch)

What it does, per task of ``TASKS`` (``atc_nf_env.benchmark``'s converging-4 and random-6):

1. **Reference policies** (no training): the MCMC-MPC (``mpc``) and the NF alone (``nf``),
   each scored on the test split's first ``test_runs`` seeds; the NF also inside the filter.
2. **Training** of every learner with ``seeds`` training seeds, on the train split only:

   * ``ppo``: ``atc-nf train --mode shared --vec native`` (PPO, one policy shared by every
     aircraft) for ``ppo_frames`` frames (one frame = one aircraft's decision);
   * ``bc`` and ``dagger``: ``atc-nf imitate`` (behaviour cloning from ``demo_episodes`` MPC
     episodes, then ``dagger_iterations`` DAgger iterations of ``dagger_episodes`` learner
     episodes labelled by the MPC); one imitation run per seed gives both models (``bc`` is
     its first stage), its training seeds start at ``10 000 + 10⁶ · seed``;
   * ``ippo`` and ``mappo``: ``agents.marl_torchrl.train``, which needs TorchRL: run the
     table in TorchRL's venv (``make baselines`` builds ``.venv-torch`` and runs it there).
     A command that cannot run a row it is asked for fails before training anything,
     naming the missing library; ``--skip-unavailable`` leaves such rows out with a note
     instead, for plumbing checks only (``--write`` refuses it).

3. **Scoring**: every model on the test split's first ``test_runs`` seeds
   (``atc_nf_env.benchmark.score_card``), alone and inside ``atc_nf_env.shield.SafetyFilter``,
   each card with the MPC's runs on the same seeds for the flight-time ratio.
4. **The table**: per algorithm and task, the mean over training seeds of runs safe, runs
   home and the flight-time ratio to the MPC, with a 95 % Student-t interval over seeds
   (``t_interval``), alone and in the filter; the frame budget and the training wall time
   per seed. Learning curves (mean and 95 % band over seeds) go to
   ``docs/figures/baselines_<task>.png``.

Everything lands in ``--out`` (default ``out/baselines``): a training unit (one learner,
task and seed) is done when its ``done.json`` exists, and a study's runs are appended to a
resumable results file, so a killed command restarts where it stopped. The folder records
the build fingerprint (``atc_nf_env.build.fingerprint``) and the budget it was started with
in ``manifest.json``; a command on another build or budget refuses to use it
(``--restart`` empties it first).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import math
import shlex
import shutil
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

#: Tasks of the table (``atc_nf_env.benchmark.TASKS``).
TASKS: tuple[str, ...] = ("converging-4", "random-6")
#: The split every card is scored on.
SPLIT = "test"
#: Learners of this module, in table order; the TorchRL ones join when importable.
SB3_ALGORITHMS: tuple[str, ...] = ("ppo", "bc", "dagger")
#: Experiments towards agents safe without the filter (``--algorithms`` adds them):
#: ``ppo-margin`` is ``ppo`` with ``agents.train``'s envelope-margin penalty.
EXPERIMENTS: tuple[str, ...] = ("ppo-margin",)
PPO_MARGIN = {"envelope_margin_kt": 40.0, "envelope_margin_weight": 1.0}
TORCHRL_ALGORITHMS: tuple[str, ...] = ("ippo", "mappo")
TORCHRL_MODULE = "agents.marl_torchrl"
#: Reference policies (no training); the NF is also scored in the filter.
REFERENCES: tuple[str, ...] = ("mpc", "nf")
#: The section of the results page this command owns.
DOC = Path(__file__).resolve().parent.parent / "docs" / "baselines.md"
FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
SECTION = "baselines"
#: PPO's reward weights (those of the shipped ``scratch_ppo``): a period outside the
#: envelope and a loss of separation cost more than the defaults' 1 and 5.
PPO_REWARD_WEIGHTS = '{"envelope_violation": 20.0, "loss_of_separation": 50.0}'
#: First training episode seed of imitation seed s: IMITATION_FIRST_SEED + IMITATION_SEED_STRIDE · s
#: (the train split; each run's DAgger iterations stay below the next seed's block).
IMITATION_FIRST_SEED = 10_000
IMITATION_SEED_STRIDE = 1_000_000


@dataclass(frozen=True)
class Budget:
    """How much training and scoring one table costs. Frames: aircraft-decisions (one
    aircraft choosing one waypoint), the unit of the shared-parameter learners."""

    name: str
    seeds: int  # training seeds per learner and task
    test_runs: int  # test-split runs per model and per reference policy
    ppo_frames: int
    ppo_num_envs: int
    ppo_n_steps: int
    demo_episodes: int  # MPC episodes of behaviour cloning, per seed
    bc_epochs: int
    dagger_iterations: int
    dagger_episodes: int  # learner episodes per DAgger iteration, per seed
    dagger_epochs: int
    torchrl_frames: int
    expert_extractions: int = 1000  # the MPC's K in the demonstrations (the paper: 1000)
    mpc_workers: int = 2  # processes of the MPC's studies and of the demonstrations

    def describe(self) -> str:
        return (f"{self.seeds} training seeds per learner and task; PPO {self.ppo_frames:,} frames per seed "
                f"({self.ppo_num_envs} worlds × {self.ppo_n_steps} steps per rollout); BC from "
                f"{self.demo_episodes} MPC episodes (K = {self.expert_extractions}), {self.bc_epochs} epochs; DAgger "
                f"{self.dagger_iterations} × {self.dagger_episodes} learner episodes after BC, {self.dagger_epochs} "
                f"epochs each; IPPO/MAPPO {self.torchrl_frames:,} frames per seed (frames: aircraft decisions); "
                f"{self.test_runs} test-split runs "
                f"per model")


BUDGETS: dict[str, Budget] = {
    "default": Budget("default", seeds=3, test_runs=50, ppo_frames=300_000, ppo_num_envs=32, ppo_n_steps=32,
                      demo_episodes=24, bc_epochs=40, dagger_iterations=2, dagger_episodes=8, dagger_epochs=20,
                      torchrl_frames=300_000),
    "quick": Budget("quick", seeds=2, test_runs=1, ppo_frames=512, ppo_num_envs=2, ppo_n_steps=32,
                    demo_episodes=1, bc_epochs=2, dagger_iterations=1, dagger_episodes=1, dagger_epochs=1,
                    torchrl_frames=512, expert_extractions=50, mpc_workers=1),
}


# ------------------------------------------------------------------ statistics


def _betacf(a: float, b: float, x: float) -> float:
    """The continued fraction of the regularized incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 400):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def _betainc(a: float, b: float, x: float, y: float) -> float:
    """The regularized incomplete beta function I_x(a, b), x ∈ [0, 1], given y = 1 − x
    computed by the caller without cancellation."""
    if x <= 0.0:
        return 0.0
    if y <= 0.0:
        return 1.0
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log(y)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _betacf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _betacf(b, a, y) / b


def student_t_cdf(t: float, df: int) -> float:
    """P(T ≤ t) for Student's t with ``df`` degrees of freedom."""
    tail = 0.5 * _betainc(df / 2.0, 0.5, df / (df + t * t), t * t / (df + t * t))
    return 1.0 - tail if t >= 0 else tail


def student_t_quantile(p: float, df: int) -> float:
    """The ``p`` quantile of Student's t with ``df`` ≥ 1 degrees of freedom (bisection on
    the CDF to 1e-12; no SciPy in the project's dependencies)."""
    if isinstance(df, bool) or not isinstance(df, int) or df < 1:
        raise ValueError(f"df = {df!r}: must be an integer >= 1")
    if not 0.0 < p < 1.0:
        raise ValueError(f"p = {p!r}: must lie in (0, 1)")
    low, high = -1.0, 1.0
    while student_t_cdf(low, df) > p:
        low *= 2.0
    while student_t_cdf(high, df) < p:
        high *= 2.0
    while high - low > 1e-12 * max(1.0, abs(high)):
        mid = 0.5 * (low + high)
        if student_t_cdf(mid, df) < p:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def t_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float | None, float | None]:
    """(mean, low, high): the mean of ``values`` (one per training seed) and its Student-t
    interval mean ± t_{(1+confidence)/2, n−1} · s / √n, with s the sample standard deviation
    (n − 1 in the denominator). One value: no interval (None, None)."""
    values = [float(v) for v in values]
    if not values:
        raise ValueError("t_interval needs at least one value")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"t_interval: values must be finite, got {values}")
    n = len(values)
    mean = sum(values) / n
    if n == 1:
        return mean, None, None
    s = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))
    half = student_t_quantile(0.5 + confidence / 2.0, n - 1) * s / math.sqrt(n)
    return mean, mean - half, mean + half


# ------------------------------------------------------------------ the output folder


def _build() -> str:
    from atc_nf_env.build import fingerprint

    return fingerprint()


def open_folder(out: Path, budget: Budget, restart: bool) -> dict[str, Any]:
    """Create or reopen ``out``; refuse one started by another build or budget."""
    manifest_path = out / "manifest.json"
    build = _build()
    wanted = {"build": build, "budget": dataclasses.asdict(budget), "split": SPLIT}
    if restart and out.exists():
        shutil.rmtree(out)
    if manifest_path.exists():
        old = json.loads(manifest_path.read_text())
        if old.get("build") != build:
            raise ValueError(
                f"{out} holds results of build {old.get('build')}, this code is build {build}: results of two builds "
                "are never mixed; start again with --restart (empties the folder) or give another --out")
        if old.get("budget") != wanted["budget"] or old.get("split") != SPLIT:
            raise ValueError(f"{out} was started with the budget {old.get('budget', {}).get('name')!r} "
                             f"({old.get('budget')}); use that budget, --restart, or another --out")
        return old
    out.mkdir(parents=True, exist_ok=True)
    manifest = {**wanted, "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())}
    _write_json(manifest_path, manifest)
    return manifest


def _write_json(path: Path, data: Any) -> None:
    """Write atomically: a killed command leaves the old file or the new one, never half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


def _read_done(path: Path, build: str) -> dict[str, Any] | None:
    if not path.exists():
        return None
    done = json.loads(path.read_text())
    if done.get("build") != build:
        raise ValueError(f"{path} was written by build {done.get('build')}, this code is build {build}: "
                         "results of two builds are never mixed; start again with --restart")
    return done


# ------------------------------------------------------------------ training units


def torchrl_trainer() -> tuple[Any, str | None]:
    """(the module ``agents.marl_torchrl``, None) or (None, why it cannot be used)."""
    try:
        module = importlib.import_module(TORCHRL_MODULE)
    except ImportError as error:
        return None, f"{TORCHRL_MODULE} is not importable here ({error})"
    if not callable(getattr(module, "train", None)):
        return None, f"{TORCHRL_MODULE} has no train(algorithm, task, seed, frames, out)"
    if not _torchrl_installed():
        return None, "torchrl is not installed in this environment (examples/requirements-torch.txt)"
    return module, None


#: Where the rows that need TorchRL run: the venv ``make baselines`` builds.
TORCHRL_VENV_HINT = ("run the table in TorchRL's venv: `make baselines` (builds .venv-torch from "
                     "examples/requirements-torch.txt), or .venv-torch/bin/python -m agents.baselines_table ...")


class RowNotRun(RuntimeError):
    """A row of the table cannot be run here (a library missing, no model trained)."""


def unavailable_rows(algorithms: Sequence[str], skip_unavailable: bool = False) -> dict[str, str]:
    """The learners of ``algorithms`` that cannot run here, each with why: empty, or (with
    ``skip_unavailable``) the rows to leave out with a note. RowNotRun otherwise."""
    wanted = [a for a in algorithms if a in TORCHRL_ALGORITHMS]
    if not wanted:
        return {}
    module, why_not = torchrl_trainer()
    if module is not None:
        return {}
    if not skip_unavailable:
        raise RowNotRun(f"the rows {', '.join(wanted)} need TorchRL, and here {why_not}; {TORCHRL_VENV_HINT}")
    return {a: str(why_not) for a in wanted}


def _torchrl_installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("torchrl") is not None and importlib.util.find_spec("tensordict") is not None


def _curve_csv(path: Path, x_key: str, y_key: str) -> dict[str, list[float]] | None:
    import csv

    if not path.exists():
        return None
    with path.open() as handle:
        rows = [row for row in csv.DictReader(handle) if row.get(x_key) and row.get(y_key)]
    if not rows:
        return None
    return {"x": [float(r[x_key]) for r in rows], "y": [float(r[y_key]) for r in rows]}


def train_ppo(task: str, seed: int, budget: Budget, folder: Path, algorithm: str = "ppo",
              extra: dict[str, float] | None = None) -> dict[str, Any]:
    """Shared-parameter PPO (``agents.train``) on the task's scenario, train-split seeds;
    ``extra``: more ``agents.train.Args`` fields (the experiments' options)."""
    from agents import train as rl
    from atc_nf_env.benchmark import get_task

    from atc_nf_env.scenarios import make_scenario

    scenario = get_task(task).scenario
    # One minibatch at most per rollout (num_envs worlds × aircraft × n_steps frames).
    batch = min(1024, budget.ppo_num_envs * budget.ppo_n_steps * make_scenario(scenario, seed=0).n_aircraft)
    args = rl.Args(mode="shared", vec="native", scenario=scenario, total_timesteps=budget.ppo_frames, seed=seed,
                   num_envs=budget.ppo_num_envs, n_steps=budget.ppo_n_steps, batch_size=batch, gamma=0.97,
                   reward_weights=PPO_REWARD_WEIGHTS, out=folder / "run", checkpoint_every=0, torch_threads=1,
                   progress=False, **(extra or {}))
    command = (f"atc-nf train --mode shared --vec native --scenario {scenario} --total-timesteps {budget.ppo_frames} "
               f"--seed {seed} --num-envs {budget.ppo_num_envs} --n-steps {budget.ppo_n_steps} --batch-size {batch} "
               f"--gamma 0.97 --reward-weights {shlex.quote(PPO_REWARD_WEIGHTS)} --torch-threads 1 "
               f"--checkpoint-every 0 --out {args.out}"
               + "".join(f" --{key.replace('_', '-')} {value:g}" for key, value in (extra or {}).items()))
    record = rl.train(args, command=command)
    model = folder / f"{algorithm}-s{seed}.zip"
    shutil.copyfile(record["model"], model)
    return {algorithm: {"model": str(model), "frames": record["timesteps"], "frames_unit": "frames",
                    "wall_s": record["wall_s"], "command": command,
                    "curve": _curve_csv(folder / "run" / "curve.csv", "timesteps", "mean_return"),
                    "curve_axes": ["frames", "mean return per aircraft episode (training)"]}}


def _epoch_losses(stage: dict[str, Any]) -> list[float]:
    return [float(e["val_loss"]) for e in stage.get("history", {}).get("epochs", [])]


def train_imitation(task: str, seed: int, budget: Budget, folder: Path) -> dict[str, Any]:
    """BC then DAgger from the MPC (``agents.imitate``): one run, two models."""
    from agents import imitate
    from atc_nf_env.benchmark import get_task

    scenario = get_task(task).scenario
    first_seed = IMITATION_FIRST_SEED + IMITATION_SEED_STRIDE * seed
    args = imitate.Args(out=folder / "run", episodes=f"{scenario}:{budget.demo_episodes}", first_seed=first_seed,
                        workers=budget.mpc_workers, expert_extractions=budget.expert_extractions,
                        bc_epochs=budget.bc_epochs, dagger_iterations=budget.dagger_iterations,
                        dagger_episodes=f"{scenario}:{budget.dagger_episodes}", dagger_epochs=budget.dagger_epochs,
                        check_runs=0, seed=seed, torch_threads=1, progress=False)
    command = (f"atc-nf imitate --episodes {scenario}:{budget.demo_episodes} --first-seed {first_seed} "
               f"--expert-extractions {budget.expert_extractions} --bc-epochs {budget.bc_epochs} "
               f"--dagger-iterations {budget.dagger_iterations} --dagger-episodes {scenario}:{budget.dagger_episodes} "
               f"--dagger-epochs {budget.dagger_epochs} --check-runs 0 --seed {seed} --workers {budget.mpc_workers} "
               f"--out {args.out}")
    log = imitate.run(args, command)
    stages = log["stages"]
    demos = stages["demonstrations"]
    bc = stages["bc"]
    bc_wall = float(demos.get("wall_s", 0.0)) + float(bc.get("wall_s", 0.0))
    bc_model = folder / f"bc-s{seed}.zip"
    shutil.copyfile(args.out / "bc.zip", bc_model)
    bc_losses = _epoch_losses(bc)
    out = {"bc": {"model": str(bc_model), "frames": bc["dataset"]["samples"],
                  "frames_unit": "MPC-labelled aircraft-decisions", "episodes": bc["dataset"]["episodes"],
                  "wall_s": round(bc_wall, 3), "command": command,
                  "curve": {"x": list(range(1, len(bc_losses) + 1)), "y": bc_losses} if bc_losses else None,
                  "curve_axes": ["epoch", "validation loss (Gaussian NLL of the MPC's action)"]}}
    last = f"dagger-{budget.dagger_iterations}"
    if budget.dagger_iterations and last in stages:
        losses = bc_losses + [v for k in range(1, budget.dagger_iterations + 1)
                              for v in _epoch_losses(stages[f"dagger-{k}"])]
        dagger_model = folder / f"dagger-s{seed}.zip"
        shutil.copyfile(args.out / f"{last}.zip", dagger_model)
        out["dagger"] = {"model": str(dagger_model), "frames": stages[last]["dataset"]["samples"],
                         "frames_unit": "MPC-labelled aircraft-decisions", "episodes": stages[last]["dataset"]["episodes"],
                         "wall_s": log["wall_s"], "command": command,
                         "curve": {"x": list(range(1, len(losses) + 1)), "y": losses} if losses else None,
                         "curve_axes": ["epoch (BC, then each DAgger iteration)", "validation loss"]}
    return out


def train_torchrl(algorithm: str, task: str, seed: int, budget: Budget, folder: Path) -> dict[str, Any]:
    """IPPO or MAPPO with ``agents.marl_torchrl.train(algorithm, task, seed, frames, out)``.

    That trainer counts a frame as one decision period of one world (N aircraft
    decisions): it gets ``torchrl_frames / N`` of them, the same number of aircraft
    decisions as PPO's ``ppo_frames`` when both budgets are equal."""
    from atc_nf_env.benchmark import get_task
    from atc_nf_env.scenarios import make_scenario

    module, why = torchrl_trainer()
    if module is None:
        raise RuntimeError(why)
    n_aircraft = make_scenario(get_task(task).scenario, seed=0).n_aircraft
    periods = -(-budget.torchrl_frames // n_aircraft)
    start = time.perf_counter()
    trained = Path(module.train(algorithm, task, seed, periods, folder / "run"))
    wall = time.perf_counter() - start
    # Every seed's file has the same name (policy.pt): a copy named by algorithm and seed.
    model = folder / f"{algorithm}-s{seed}{trained.suffix}"
    shutil.copyfile(trained, model)
    meta_path = folder / "run" / "meta.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    done_periods = int(meta.get("frames", periods))
    curve = torchrl_curve(folder / "run" / "curve.csv", meta, n_aircraft)
    return {algorithm: {"model": str(model), "frames": done_periods * n_aircraft, "frames_unit": "frames",
                        "wall_s": round(float(meta.get("wall_s", wall)), 3),
                        "command": f"{TORCHRL_MODULE}.train({algorithm!r}, {task!r}, {seed}, {periods}, "
                                   f"{str(folder / 'run')!r})",
                        "curve": curve, "curve_axes": ["frames", "mean return per aircraft (training)"]}}


def torchrl_curve(path: Path, meta: dict[str, Any], n_aircraft: int) -> dict[str, list[float]] | None:
    """The learning curve of a TorchRL run against aircraft decisions (the table's frames).

    ``agents.marl_torchrl`` writes one row per evaluation point with ``batch`` (collected
    batches so far) and ``frames`` (world periods so far) and the mean training return. The
    x axis is ``frames`` × aircraft, or, for a curve without ``frames``, ``batch`` × the
    batch's world periods (``num_envs × steps_per_batch`` of the run's ``meta["ppo"]``) ×
    aircraft. None when the run wrote no curve.

    Raises:
        ValueError: a curve with neither column, or with only ``batch`` and a meta that
            lacks the batch's size.
    """
    import csv

    if not path.exists():
        return None
    with path.open() as handle:
        columns = next(csv.reader(handle), [])
    y_key = next((c for c in columns if "return" in c), None)
    if y_key is None:
        raise ValueError(f"{path}: no column of training returns (columns: {columns})")
    if "frames" in columns:
        curve, periods_per_x = _curve_csv(path, "frames", y_key), 1
    elif "batch" in columns:
        ppo = meta.get("ppo") or {}
        if not all(isinstance(ppo.get(k), int) and ppo[k] >= 1 for k in ("num_envs", "steps_per_batch")):
            raise ValueError(f"{path}: a curve by batch, and the run's meta.json gives no num_envs and "
                             f"steps_per_batch (its ppo block: {ppo}) to count a batch's frames")
        curve, periods_per_x = _curve_csv(path, "batch", y_key), ppo["num_envs"] * ppo["steps_per_batch"]
    else:
        raise ValueError(f"{path}: no frames or batch column to plot against (columns: {columns})")
    if curve is not None:
        curve["x"] = [x * periods_per_x * n_aircraft for x in curve["x"]]  # world periods -> aircraft decisions
    return curve


def flyable(model: str) -> str:
    """What ``score_card`` flies for a model file: the path of a ``.zip`` (SB3's loader),
    or for another format (TorchRL's ``policy.pt``) a name registered in this process
    (``atc_nf_env.policy.register_policy``; the studies run in this process) that carries
    the file's hash, so that a retrained model never resumes another's runs."""
    from atc_nf_env.evaluate import file_sha256
    from atc_nf_env.policy import make_policy, policy_file_suffixes, register_policy

    path = Path(model)
    if path.suffix == ".zip":
        return model
    name = f"{path.stem}-{file_sha256(path)[:12]}"
    if path.suffix.lstrip(".") in policy_file_suffixes():
        register_policy(name, lambda: make_policy(model))
    else:
        module, why = torchrl_trainer()
        loader = getattr(module, "TorchRLPolicy", None)
        if loader is None:
            raise ValueError(f"{model}: no installed loader for {path.suffix} files ({why or TORCHRL_MODULE + ' has no TorchRLPolicy'})")
        register_policy(name, lambda: loader(model))
    return name


@dataclass(frozen=True)
class Unit:
    """One training run: a trainer on one task with one seed; it yields one or more models."""

    trainer: str  # "ppo", "imitation", "ippo", "mappo"
    task: str
    seed: int

    @property
    def algorithms(self) -> tuple[str, ...]:
        return ("bc", "dagger") if self.trainer == "imitation" else (self.trainer,)

    def folder(self, out: Path) -> Path:
        return out / "train" / self.task / self.trainer / f"seed{self.seed}"


#: The trainers, by unit.trainer: f(task, seed, budget, folder) -> {algorithm: record}.
TRAINERS: dict[str, Callable[..., dict[str, Any]]] = {
    "ppo": train_ppo,
    "imitation": train_imitation,
    "ppo-margin": lambda task, seed, budget, folder: train_ppo(task, seed, budget, folder, "ppo-margin", PPO_MARGIN),
    "ippo": lambda task, seed, budget, folder: train_torchrl("ippo", task, seed, budget, folder),
    "mappo": lambda task, seed, budget, folder: train_torchrl("mappo", task, seed, budget, folder),
}


def plan(tasks: Sequence[str], algorithms: Sequence[str], seeds: int) -> list[Unit]:
    trainers: list[str] = []
    for algorithm in algorithms:
        trainer = "imitation" if algorithm in ("bc", "dagger") else algorithm
        if trainer not in trainers:
            trainers.append(trainer)
    return [Unit(trainer, task, seed) for task in tasks for trainer in trainers for seed in range(seeds)]


def run_unit(unit: Unit, budget: Budget, out: Path, build: str) -> dict[str, Any]:
    """Train the unit unless its ``done.json`` (same build) is there; returns it."""
    folder = unit.folder(out)
    done_path = folder / "done.json"
    done = _read_done(done_path, build)
    if done is not None:
        return done
    if folder.exists():  # an interrupted run: its partial models are not trusted ...
        for entry in folder.iterdir():
            if entry.name == "run" and unit.trainer == "imitation":
                # ... but imitation's demonstrations are (one file per episode, written
                # atomically): ``atc-nf imitate`` reuses them and retrains its stages.
                for item in entry.iterdir():
                    if item.name != "demos":
                        shutil.rmtree(item) if item.is_dir() else item.unlink()
            else:
                shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    print(f"baselines: training {unit.trainer} on {unit.task}, seed {unit.seed}", file=sys.stderr, flush=True)
    start = time.perf_counter()
    models = TRAINERS[unit.trainer](unit.task, unit.seed, budget, folder)
    done = {"build": build, "trainer": unit.trainer, "task": unit.task, "seed": unit.seed, "models": models,
            "unit_wall_s": round(time.perf_counter() - start, 3)}
    _write_json(done_path, done)
    return done


# ------------------------------------------------------------------ scoring


def score(policy: str, label: str, task: str, shield: bool, budget: Budget, out: Path, build: str,
          workers: int) -> dict[str, Any]:
    """The test-split card of ``policy`` (cached in ``out/cards``; runs resumable)."""
    from atc_nf_env.benchmark import score_card

    path = out / "cards" / task / f"{label}{'+shield' if shield else ''}.json"
    card = _read_done(path, build)
    if card is not None:
        return card
    print(f"baselines: scoring {label}{' in the filter' if shield else ''} on {task} ({budget.test_runs} {SPLIT} runs)",
          file=sys.stderr, flush=True)
    start = time.perf_counter()
    card = score_card(policy, task, SPLIT, budget.test_runs, shield=shield, reference=True,
                      results_dir=out / "results", workers=workers, progress=False)
    card = {**card, "build": build, "label": label, "scoring_wall_s": round(time.perf_counter() - start, 1)}
    _write_json(path, card)
    return card


# ------------------------------------------------------------------ the table


@dataclass
class Row:
    task: str
    algorithm: str
    seeds: list[int]
    budget: str
    wall_s: list[float]
    alone: list[dict[str, Any]]
    shielded: list[dict[str, Any]]
    note: str = ""


def _stat(cards: list[dict[str, Any]], key: str) -> dict[str, Any] | None:
    values = [c[key] for c in cards if c.get(key) is not None]
    if not values or len(values) < len(cards):
        return None if not values else {"values": values, "partial": True, **_interval_dict(values)}
    return {"values": values, **_interval_dict(values)}


def _interval_dict(values: list[float]) -> dict[str, Any]:
    mean, low, high = t_interval(values)
    return {"mean": mean, "ci95": None if low is None else [low, high]}


def row_summary(row: Row) -> dict[str, Any]:
    out: dict[str, Any] = {"task": row.task, "algorithm": row.algorithm, "seeds": row.seeds, "budget": row.budget,
                           "wall_s_per_seed": row.wall_s, "note": row.note}
    for name, cards in (("alone", row.alone), ("shielded", row.shielded)):
        if cards:
            out[name] = {"runs_per_seed": cards[0]["runs"], "runs_safe": _stat(cards, "runs_safe"),
                         "runs_home": _stat(cards, "runs_home"),
                         "flight_time_ratio_to_mpc": _stat(cards, "flight_time_ratio_to_mpc"),
                         "runs_with_los": [c["runs_with_los"] for c in cards],
                         "runs_outside_envelope": [c["runs_outside_envelope"] for c in cards]}
    return out


def _count_cell(stat: dict[str, Any] | None, runs: int) -> str:
    if stat is None:
        return "–"
    values = stat["values"]
    if len(values) == 1:
        return f"{values[0]:g}/{runs}"
    low, high = stat["ci95"]
    # Clipped to what a count can be: the interval of a mean of counts in [0, runs].
    return (f"{stat['mean']:.1f} [{max(0.0, low):.1f}, {min(float(runs), high):.1f}]/{runs} "
            f"({', '.join(f'{v:g}' for v in values)})")


def _ratio_cell(stat: dict[str, Any] | None) -> str:
    if stat is None:
        return "–"
    values = stat["values"]
    if len(values) == 1:
        return f"{values[0]:.3f}"
    low, high = stat["ci95"]
    return f"{stat['mean']:.3f} [{low:.3f}, {high:.3f}]" + (" (some seeds none home)" if stat.get("partial") else "")


def _wall_cell(walls: list[float]) -> str:
    if not walls:
        return "–"
    return f"{sum(walls) / len(walls):.0f}"


def markdown_table(summaries: list[dict[str, Any]]) -> str:
    header = ("task", "algorithm", "seeds", "training budget per seed", "training wall s per seed (mean)",
              "runs safe alone", "runs home alone", "flight time / MPC alone", "runs safe in the filter",
              "runs home in the filter", "flight time / MPC in the filter")
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * 3 + "---:|" * (len(header) - 3)]
    for s in summaries:
        alone, shielded = s.get("alone"), s.get("shielded")
        if s["note"] and not alone:
            lines.append(f"| {s['task']} | {s['algorithm']} | – | – | – | {s['note']} |" + " |" * 5)
            continue
        cells = [s["task"], s["algorithm"], str(len(s["seeds"])) if s["seeds"] else "–", s["budget"],
                 _wall_cell(s["wall_s_per_seed"])]
        for part in (alone, shielded):
            if part is None:
                cells += ["not flown"] * 3
            else:
                cells += [_count_cell(part["runs_safe"], part["runs_per_seed"]),
                          _count_cell(part["runs_home"], part["runs_per_seed"]),
                          _ratio_cell(part["flight_time_ratio_to_mpc"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _budget_text(record: dict[str, Any]) -> str:
    if record["frames_unit"] == "frames":
        return f"{record['frames']:,} frames"
    return f"{record.get('episodes', '?')} episodes, {record['frames']:,} MPC-labelled decisions"


# ------------------------------------------------------------------ figures


def plot_curves(task: str, curves: dict[str, list[dict[str, Any]]], axes_labels: dict[str, list[str]],
                path: Path) -> Path | None:
    """One panel per algorithm: the mean over seeds and its 95 % t band (seeds whose curve
    is shorter are dropped past their end)."""
    panels = [(a, c) for a, c in curves.items() if c]
    if not panels:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter

    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.3), constrained_layout=True, squeeze=False)
    for ax, (algorithm, seed_curves) in zip(axes[0], panels):
        length = min(len(c["x"]) for c in seed_curves)
        x = seed_curves[0]["x"][:length]
        means, lows, highs, xs = [], [], [], []
        for i in range(length):
            ys = [c["y"][i] for c in seed_curves]
            if not all(math.isfinite(y) for y in ys):
                continue  # a point some seed has no value at (TorchRL's return before its first episode ends)
            mean, low, high = t_interval(ys)
            xs.append(x[i])
            means.append(mean)
            lows.append(mean if low is None else low)
            highs.append(mean if high is None else high)
        ax.plot(xs, means, lw=1.4, label=f"mean of {len(seed_curves)} seeds")
        ax.fill_between(xs, lows, highs, alpha=0.25, label="95 % t interval over seeds")
        ax.set_title(f"{algorithm} on {task}")
        if axes_labels[algorithm][0] == "frames":
            ax.xaxis.set_major_formatter(EngFormatter())  # 300k, not 300000 run into its neighbours
        ax.set_xlabel(textwrap.fill(axes_labels[algorithm][0], 40))
        ax.set_ylabel(textwrap.fill(axes_labels[algorithm][1], 32))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ the command


def build_table(budget: Budget, out: Path, tasks: Sequence[str], algorithms: Sequence[str],
                figures: Path, workers: int | None = None, skip_unavailable: bool = False) -> dict[str, Any]:
    """Train what is missing, score what is missing, aggregate; returns the table's record.

    Raises:
        RowNotRun: before any training, when a row needs TorchRL and it is missing (unless
            ``skip_unavailable``: then that row only says why); after training, when a
            learner trained no model.
    """
    started = time.perf_counter()
    skipped = unavailable_rows(algorithms, skip_unavailable)
    runnable = [a for a in algorithms if a not in skipped]
    manifest = open_folder(out, budget, restart=False)
    build = manifest["build"]
    model_workers = 1  # a learned model flies in microseconds: worker processes would only add start-up
    mpc_workers = workers or budget.mpc_workers
    summaries: list[dict[str, Any]] = []
    figure_paths: dict[str, str] = {}
    units = plan(tasks, runnable, budget.seeds)
    done_by_unit = {}
    for unit in units:
        done_by_unit[unit] = run_unit(unit, budget, out, build)
    for task in tasks:
        for reference in REFERENCES:
            alone = [score(reference, reference, task, False, budget, out, build,
                           mpc_workers if reference == "mpc" else model_workers)]
            shielded = [] if reference == "mpc" else [score(reference, reference, task, True, budget, out, build,
                                                            model_workers)]
            summaries.append(row_summary(Row(task, reference, [], "none (no training)", [], alone, shielded)))
        curves: dict[str, list[dict[str, Any]]] = {}
        axes_labels: dict[str, list[str]] = {}
        for algorithm in algorithms:
            if algorithm in skipped:
                summaries.append(row_summary(Row(task, algorithm, [], "–", [], [], [],
                                                 note=f"left out (--skip-unavailable): {skipped[algorithm]}")))
                continue
            records = [done["models"][algorithm] for unit, done in done_by_unit.items()
                       if unit.task == task and algorithm in unit.algorithms and algorithm in done["models"]]
            seeds = [unit.seed for unit, done in done_by_unit.items()
                     if unit.task == task and algorithm in unit.algorithms and algorithm in done["models"]]
            if not records:
                raise RowNotRun(f"{algorithm} on {task}: no training seed produced a model "
                                f"(see {out / 'train' / task})")
            alone = [score(flyable(r["model"]), Path(r["model"]).stem, task, False, budget, out, build,
                           model_workers) for r in records]
            shielded = [score(flyable(r["model"]), Path(r["model"]).stem, task, True, budget, out, build,
                              model_workers) for r in records]
            summaries.append(row_summary(Row(task, algorithm, seeds, _budget_text(records[0]),
                                             [r["wall_s"] for r in records], alone, shielded)))
            curves[algorithm] = [r["curve"] for r in records if r.get("curve")]
            axes_labels[algorithm] = records[0]["curve_axes"]
        figure = plot_curves(task, curves, axes_labels, figures / f"baselines_{task}.png")
        if figure is not None:
            figure_paths[task] = str(figure)
    # What this table cost: every unit's training and every card's scoring, as recorded
    # when each was made (a resumed command adds up the pieces of every attempt).
    cards = list((out / "cards").rglob("*.json"))
    training_s = sum(float(d.get("unit_wall_s", 0.0)) for d in done_by_unit.values())
    scoring_s = sum(float(json.loads(p.read_text()).get("scoring_wall_s", 0.0)) for p in cards)
    import os
    import platform

    record = {"build": build, "budget": dataclasses.asdict(budget), "split": SPLIT, "tasks": list(tasks),
              "machine": f"{platform.machine()}, {os.cpu_count()} cores",
              "algorithms": list(algorithms), "rows": summaries, "figures": figure_paths,
              "training_wall_s": round(training_s, 1), "scoring_wall_s": round(scoring_s, 1),
              "this_command_wall_s": round(time.perf_counter() - started, 1)}
    _write_json(out / "table.json", record)
    return record


def section_text(record: dict[str, Any], command: str, figures_rel: str) -> str:
    budget = Budget(**record["budget"])
    lines = [f"Generated by `{command}` on build `{record['build']}` "
             f"(budget `{budget.name}`: {budget.describe()}).", "",
             f"Training took {record['training_wall_s'] / 60:.1f} min and scoring "
             f"{record['scoring_wall_s'] / 60:.1f} min of wall time in all (as recorded when each piece ran, on "
             f"{record.get('machine', 'an unrecorded machine')}).", "",
             markdown_table(record["rows"])]
    for task, path in record["figures"].items():
        lines += [f"![Learning curves on {task}]({figures_rel}/{Path(path).name})", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m agents.baselines_table", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="the tiny budget of the tests (not a result)")
    parser.add_argument("--out", type=Path, default=None,
                        help="intermediate results (default out/baselines, with --quick out/baselines-quick)")
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated benchmark tasks")
    parser.add_argument("--algorithms", default=",".join(SB3_ALGORITHMS + TORCHRL_ALGORITHMS),
                        help=f"comma-separated learners (experiments: {', '.join(EXPERIMENTS)})")
    parser.add_argument("--restart", action="store_true", help="empty --out first (results of another build or budget)")
    parser.add_argument("--workers", type=int, default=None, help="processes of the MPC's studies (default: the budget's)")
    parser.add_argument("--write", action="store_true", help="write the table into --doc and the curves into --figures")
    parser.add_argument("--skip-unavailable", action="store_true",
                        help="leave out, with a note, the rows whose library (TorchRL) is missing, instead of failing; "
                             "a plumbing check, never a result: --write refuses it")
    parser.add_argument("--doc", type=Path, default=DOC, help="the results page whose baselines section --write replaces")
    parser.add_argument("--figures", type=Path, default=None,
                        help="folder of the learning-curve figures (default: docs/figures with --write, else OUT/figures)")
    args = parser.parse_args(argv)
    from atc_nf_env.benchmark import get_task

    budget = BUDGETS["quick" if args.quick else "default"]
    out = args.out or Path("out/baselines-quick" if args.quick else "out/baselines")
    tasks = [t for t in args.tasks.split(",") if t]
    algorithms = [a for a in args.algorithms.split(",") if a]
    try:
        for task in tasks:
            get_task(task)
        known = SB3_ALGORITHMS + TORCHRL_ALGORITHMS + EXPERIMENTS
        for algorithm in algorithms:
            if algorithm not in known:
                raise ValueError(f"--algorithms: {algorithm!r} unknown; allowed: {', '.join(known)}")
        if not tasks or not algorithms:
            raise ValueError("--tasks and --algorithms need at least one name each")
        if args.write and args.skip_unavailable:
            raise ValueError("--write with --skip-unavailable: a written table has every row it names; drop "
                             "--skip-unavailable (or --write), or name fewer --algorithms")
        unavailable_rows(algorithms, args.skip_unavailable)  # before --restart empties anything
        if args.restart:
            open_folder(out, budget, restart=True)
        figures = args.figures or (FIGURES if args.write else out / "figures")
        record = build_table(budget, out, tasks, algorithms, figures, args.workers, args.skip_unavailable)
    except (ValueError, RowNotRun) as error:
        print(f"baselines_table: error: {error}", file=sys.stderr)
        return 2
    command = "python -m agents.baselines_table " + shlex.join(list(argv) if argv is not None else sys.argv[1:])
    try:
        figures_rel = Path(figures).resolve().relative_to(args.doc.resolve().parent).as_posix()
    except ValueError:
        figures_rel = Path(figures).resolve().as_posix()
    text = section_text(record, command, figures_rel)
    print(text)
    if args.write:
        from atc_nf_env.experiments.marked_sections import write_marked_section

        write_marked_section(args.doc, SECTION, text, header="# Baselines\n")
        print(f"table written into {args.doc} (section {SECTION})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
