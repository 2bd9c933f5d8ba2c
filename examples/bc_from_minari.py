"""Behaviour cloning from an offline Minari dataset written by ``atc-nf dataset``.

    atc-nf dataset --policy mpc --task converging-4 --episodes 24 --dataset-id atc-nf/converging-4/mpc-v0
    python examples/bc_from_minari.py --dataset-id atc-nf/converging-4/mpc-v0 --out out/bc_offline.zip
    atc-nf benchmark --policy out/bc_offline.zip --task converging-4 --split validation --runs 50

The dataset's episodes are the centralized env's (every aircraft slot at once); they are
turned into per-aircraft (observation, action) pairs with
``atc_nf_env.dataset.aircraft_transitions`` and cloned into the parameter-shared MLP actor
of ``atc-nf imitate`` (``agents.imitate``: the same model, loss, optimizer, validation
split by episode and best-epoch selection), so the model file flies wherever a shipped
model does (``--policy FILE``, the safety filter, ``atc-nf benchmark``).

What ``atc-nf imitate`` does on the fly and this script cannot: mirror clockwise
episodes (``--canonical-chirality`` needs the flown positions, which the dataset's
ego-centric observations do not hold) and DAgger (it needs the MPC to label the
learner's own flights). Samples of aircraft that never arrived are dropped, as ``atc-nf
imitate`` does (``--keep-unarrived`` keeps them); a step whose waypoint the action
mapping could not express (``infos["policy_waypoint_clipped"]``) is never a label.

Needs torch, Stable-Baselines3 and Minari (``pip install '.[rl,dataset]'``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np


def cloning_dataset(dataset: Any, *, arrived_only: bool = True) -> Any:
    """The per-aircraft (observation, action) pairs of a Minari ``dataset`` as
    ``agents.imitate.Dataset``: every step of every aircraft flying at it, in episode,
    step and slot order; ``episode`` indexes the dataset's episodes for the validation
    split. With ``arrived_only`` the samples of aircraft that had not arrived at their
    episode's end are dropped (counted in ``dropped``).

    The observation's ``time`` feature is elapsed time over the recorded env's time
    limit (the task's, 240 min); it is rescaled to the limit of the env the model is
    flown with (``EnvConfig``'s default), as ``atc-nf imitate``'s samples are."""
    from agents.imitate import Dataset
    from atc_nf_env.dataset import aircraft_transitions
    from atc_nf_env.envs import EnvConfig
    from atc_nf_env.envs.observations import ObservationSpec

    recorded = dataset.spec.env_spec.kwargs
    spec = ObservationSpec(n_neighbours=int(recorded.get("n_neighbours", EnvConfig().n_neighbours)))
    time_column = spec.labels().index("time")
    time_scale = float(recorded["max_episode_minutes"]) / EnvConfig().max_episode_minutes

    arrived = {}
    clipped = {}
    for episode in dataset.iterate_episodes():
        arrived[int(episode.id)] = np.asarray(episode.infos["arrived"])[-1].astype(bool)
        # infos row k + 1 belongs to the action of step k (row 0 is the reset's).
        clipped[int(episode.id)] = np.asarray(episode.infos["policy_waypoint_clipped"])[1:].astype(bool)
    obs, act, index = [], [], []
    dropped = 0
    order = {episode: k for k, episode in enumerate(sorted(arrived))}
    for t in aircraft_transitions(dataset):
        episode, aircraft = t["episode"], t["aircraft"]
        if clipped[episode][t["step"], aircraft] or (arrived_only and not arrived[episode][aircraft]):
            dropped += 1
            continue
        obs.append(t["observation"])
        act.append(t["action"])
        index.append(order[episode])
    if not obs:
        raise ValueError(f"the dataset holds no usable samples ({dropped} dropped: their aircraft never arrived "
                         "or their waypoint was clipped)")
    observations = np.asarray(obs, dtype=np.float32)
    observations[:, time_column] *= np.float32(time_scale)
    return Dataset(observations, np.asarray(act, dtype=np.float32), np.asarray(index), len(order), 0, dropped)


def clone(dataset: Any, out: Path, *, seed: int = 0, epochs: int = 40, net_arch: str = "64,64",
          arrived_only: bool = True, torch_threads: int = 1) -> dict[str, Any]:
    """Behaviour cloning of ``dataset`` (a ``MinariDataset``) into the model file ``out``
    with ``agents.imitate``'s defaults; returns the training history."""
    import torch

    from agents import imitate
    from agents.train import net_arch_of

    torch.set_num_threads(max(1, torch_threads))
    data = cloning_dataset(dataset, arrived_only=arrived_only)
    args = imitate.Args(out=out.parent, bc_epochs=epochs, net_arch=net_arch, seed=seed, arrived_only=arrived_only,
                        canonical_chirality=False, episodes=_episodes_text(dataset), progress=False)
    model = imitate.new_model(net_arch_of(net_arch), args.log_std_init, seed, args.n_neighbours)
    width = model.observation_space.shape[0]
    if data.obs.shape[1] != width:
        raise ValueError(f"the dataset's per-aircraft observation has {data.obs.shape[1]} features, the model "
                         f"{width} ({args.n_neighbours} neighbours): record the dataset with the env's defaults")
    history = imitate.behaviour_cloning(model, data, epochs=epochs, batch_size=args.batch_size,
                                        learning_rate=args.learning_rate, val_fraction=args.val_fraction,
                                        loss=args.bc_loss, seed=seed)
    command = (f"python examples/bc_from_minari.py --dataset-id {dataset.spec.dataset_id} --out {out} --seed {seed} "
               f"--epochs {epochs}" + ("" if arrived_only else " --keep-unarrived"))
    summary = {"episodes": data.episodes, "samples": int(len(data.obs)), "dropped": data.dropped,
               "minari_dataset": dataset.spec.dataset_id}
    imitate.save_stage(model, out, args, command, "bc-offline", {"dataset": summary})
    return {**history, "dataset": summary}


def _episodes_text(dataset: Any) -> str:
    """``SCENARIO:COUNT`` of the env the dataset recorded, for the model card's operating
    range."""
    env_spec = dataset.spec.env_spec
    scenario = None if env_spec is None else env_spec.kwargs.get("scenario")
    if not isinstance(scenario, str):
        raise ValueError(f"dataset {dataset.spec.dataset_id!r} names no scenario in its env spec: record it with "
                         "atc-nf dataset")
    return f"{scenario}:{dataset.spec.total_episodes}"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset-id", required=True, help="a local Minari dataset, e.g. atc-nf/converging-4/mpc-v0")
    parser.add_argument("--out", type=Path, required=True, help="the model file to write (.zip)")
    parser.add_argument("--seed", type=int, default=0, help="seeds torch, the validation split and the minibatches")
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--net-arch", default="64,64")
    parser.add_argument("--keep-unarrived", action="store_true", help="keep the samples of aircraft that never arrived")
    args = parser.parse_args(argv)
    import minari

    try:
        dataset = minari.load_dataset(args.dataset_id)
        history = clone(dataset, args.out, seed=args.seed, epochs=args.epochs, net_arch=args.net_arch,
                        arrived_only=not args.keep_unarrived)
    except (ValueError, FileNotFoundError) as error:
        print(f"bc_from_minari: {error}", file=sys.stderr)
        return 2
    print(f"behaviour cloning from {args.dataset_id}: {history['dataset']}, validation loss "
          f"{history['initial_validation_loss']:.3f} -> {history['best_validation_loss']:.3f}; model written to "
          f"{args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
