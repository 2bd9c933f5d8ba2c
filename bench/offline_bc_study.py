"""Behaviour cloning from a Minari dataset against behaviour cloning on the fly, per seed.

For each training seed s (0 … ``--seeds`` - 1), on the same MPC demonstration episodes
(converging-4, ``--episodes`` training seeds from the baseline table's first imitation
seed of s, the MPC at K = 1000):

- **on the fly**: ``atc-nf imitate`` (``agents.imitate``) flies the MPC, records what
  each aircraft saw and the MPC's waypoint, and clones it (no DAgger, no mirroring of
  clockwise episodes: the dataset cannot mirror, see ``examples/bc_from_minari.py``);
- **offline**: ``atc-nf dataset`` records the same seeds as a Minari dataset (through
  ``atc_nf_env/Encounter-v1``), and ``examples/bc_from_minari.py`` clones it, with the
  same model, loss, epochs and torch seed.

Both models are scored on the test split of converging-4 (``--runs`` runs), alone and in
the safety filter, with their flight time against the MPC's on the same seeds. The table
says, per seed, how many samples each had and how far apart the two sources'
observations and actions are (the env flies the float32 action's waypoint, the evaluator
the MPC's own waypoint: the flights may part).

Run: python bench/offline_bc_study.py --seeds 3 --episodes 24 --runs 50 --write
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TASK = "converging-4"


def train_pair(seed: int, episodes: int, work: Path, workers: int) -> dict[str, Any]:
    """Both BC models of one seed; their files and what they learned from."""
    import minari

    from agents import imitate
    from agents.baselines_table import IMITATION_FIRST_SEED, IMITATION_SEED_STRIDE
    from atc_nf_env.benchmark import get_task
    from atc_nf_env.dataset import record_dataset

    sys.path.insert(0, str(ROOT / "examples"))
    from bc_from_minari import clone, cloning_dataset

    scenario = get_task(TASK).scenario
    first_seed = IMITATION_FIRST_SEED + IMITATION_SEED_STRIDE * seed
    models = work / "models"
    models.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    args = imitate.Args(out=work / f"on-the-fly-s{seed}", episodes=f"{scenario}:{episodes}", first_seed=first_seed,
                        workers=workers, expert_extractions=1000, bc_epochs=40, dagger_iterations=0,
                        canonical_chirality=False, arrived_only=True, check_runs=0, seed=seed, torch_threads=1,
                        progress=False, resume=False)
    log = imitate.run(args, f"atc-nf imitate --episodes {scenario}:{episodes} --first-seed {first_seed} "
                            f"--no-canonical-chirality --check-runs 0 --seed {seed}")
    on_the_fly = models / f"on-the-fly-s{seed}.zip"
    shutil.copyfile(args.out / "bc.zip", on_the_fly)
    on_the_fly_s = time.perf_counter() - start

    start = time.perf_counter()
    dataset_id = f"atc-nf/{TASK}/mpc-s{seed}-v0"
    if dataset_id in minari.list_local_datasets():
        minari.delete_dataset(dataset_id)
    dataset = record_dataset("mpc", TASK, episodes, dataset_id, first_seed=first_seed)
    offline = models / f"offline-s{seed}.zip"
    history = clone(dataset, offline, seed=seed)
    offline_s = time.perf_counter() - start

    fly = imitate.load_dataset([args.out / "demos" / "expert"], False, True, args.n_neighbours)
    off = cloning_dataset(dataset)
    same_shape = fly.obs.shape == off.obs.shape
    return {
        "seed": seed, "first_seed": first_seed,
        "on_the_fly": {"model": str(on_the_fly), "samples": int(len(fly.obs)), "wall_s": on_the_fly_s,
                       "validation_loss": log["stages"]["bc"]["history"]["best_validation_loss"]},
        "offline": {"model": str(offline), "samples": int(len(off.obs)), "wall_s": offline_s,
                    "validation_loss": history["best_validation_loss"]},
        "max_obs_difference": float(np.abs(fly.obs - off.obs).max()) if same_shape else None,
        "max_action_difference": float(np.abs(fly.act - off.act).max()) if same_shape else None,
    }


def cards(model: str, runs: int, work: Path, workers: int) -> dict[str, Any]:
    from atc_nf_env.benchmark import score_card

    return {mode: score_card(model, TASK, "test", runs, shield=mode == "filter", reference=True,
                             results_dir=work / "results", workers=workers)
            for mode in ("alone", "filter")}


def _difference(value: float | None) -> str:
    return "flights parted (sample counts differ)" if value is None else f"{value:.2g}"


def table(pairs: list[dict[str, Any]], scored: dict[str, dict[str, Any]], args: argparse.Namespace) -> str:
    from _report import machine

    lines = [
        "## Behaviour cloning from a Minari dataset",
        "",
        f"`python bench/offline_bc_study.py --seeds {args.seeds} --episodes {args.episodes} --runs {args.runs}` "
        f"({machine()}). Per training seed, BC on {args.episodes} MPC episodes of {TASK} (K = 1000, training seeds "
        "from the baseline table's imitation seeds): *on the fly* (`atc-nf imitate`, without mirroring) and "
        "*offline* (`atc-nf dataset` then `examples/bc_from_minari.py`), same model, epochs and torch seed. "
        f"Scored on the first {args.runs} seeds of {TASK}'s test split: runs safe (no LoS, no step outside "
        "[366, 540] kt) and runs home, alone and in the safety filter; flight time as a ratio to the MPC's on "
        "the same seeds. Δ: the largest difference between the two sources' observations (actions) over "
        "all samples.",
        "",
        "| seed | BC | samples | best validation loss | safe alone | home alone | flight time / MPC alone "
        "| safe in filter | home in filter | flight time / MPC in filter | Δ observations (actions) |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for pair in pairs:
        for source in ("on_the_fly", "offline"):
            entry = pair[source]
            card = scored[entry["model"]]
            cells = []
            for mode in ("alone", "filter"):
                c = card[mode]
                ratio = c.get("flight_time_ratio_to_mpc")
                cells += [f"{c['runs_safe']}/{c['runs']}", f"{c['runs_home']}/{c['runs']}",
                          "–" if ratio is None else f"{ratio:.3f}"]
            diff = (f"{_difference(pair['max_obs_difference'])} ({_difference(pair['max_action_difference'])})"
                    if source == "offline" else "")
            lines.append(f"| {pair['seed']} | {source.replace('_', ' ')} | {entry['samples']:,} | "
                         f"{entry['validation_loss']:.3f} | " + " | ".join(cells) + f" | {diff} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from _report import publish  # bench/ is on sys.path when run as a script

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="training seeds (0 … SEEDS - 1)")
    parser.add_argument("--episodes", type=int, default=24, help="MPC demonstration episodes per seed")
    parser.add_argument("--runs", type=int, default=50, help="test-split runs per model and mode")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--write", action="store_true", help="put the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    for name in ("seeds", "episodes", "runs", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1")
    with tempfile.TemporaryDirectory(prefix="offline-bc-") as folder:
        work = Path(folder)
        # The study's datasets live in a Minari folder of their own, never the user's.
        os.environ["MINARI_DATASETS_PATH"] = str(work / "minari")
        pairs = [train_pair(seed, args.episodes, work, args.workers) for seed in range(args.seeds)]
        scored = {pair[source]["model"]: cards(pair[source]["model"], args.runs, work, args.workers)
                  for pair in pairs for source in ("on_the_fly", "offline")}
        text = table(pairs, scored, args)
    return publish("offline-bc", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
