"""Offline datasets in Minari's format: a policy flying a benchmark task, recorded
through the centralized environment ``atc_nf_env/Encounter-v1``.

    atc-nf dataset --policy mpc --task converging-4 --episodes 100 --dataset-id atc-nf/converging-4/mpc-v0

    import minari
    data = minari.load_dataset("atc-nf/converging-4/mpc-v0")
    for transition in aircraft_transitions(data):    # one aircraft's step at a time
        ...

Minari records Gymnasium environments (not PettingZoo ones), so the episodes are the
centralized env's: the observation is every aircraft slot's ego-centric observation,
flattened (M·D,); the action (M, 2) in [-1, 1]; the reward the sum over aircraft. The
infos carry the per-aircraft figures (``aircraft_reward``, ``alive``, ``arrived``,
``los_count``, ``envelope_violation`` among them) and the run's safety so far
(``run_safe``: no loss of separation and no step outside [366, 540] kt yet;
``run_los_count``), so an episode's last info says whether the run was safe, and
``policy_waypoint_clipped``: the action mapping could not express the policy's waypoint
(the NF alone aims at destinations far beyond its range; the MPC's waypoints lie within
it), so the env flew the nearest waypoint it could and the recorded flight is not the
policy's own. ``aircraft_transitions`` turns an episode back into per-aircraft transitions, the
form parameter-shared agents learn from.

Episodes take the task's training seeds from ``first_seed`` (default 0): datasets are
for training; never record the validation or test split you score on. A policy acts on
the world as the evaluator shows it (``WorldView``); its waypoints are recorded as the
env's actions (``waypoint_to_action``: clipped to [-1, 1] where the waypoint lies beyond
the action mapping's range, exactly what the env would fly).

The episodes are written with ``minari.create_dataset_from_buffers`` (Minari's
``DataCollector`` would need JAX only to append steps). Datasets are written where Minari keeps them (``MINARI_DATASETS_PATH``, default
``~/.minari/datasets``). Needs the ``dataset`` extra (``pip install 'atc-nf-env[dataset]'``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from atc_nf_env.benchmark import SPLITS, SUITE_VERSION, TASKS, get_task

#: Minari's storage format for the datasets written here (Arrow: no HDF5 library needed).
DATA_FORMAT = "arrow"
#: A policy's waypoint farther than this from the one its recorded action flies, nm, is
#: flagged in ``infos["policy_waypoint_clipped"]`` (the float32 action alone moves it by
#: well under 1e-3 nm).
CLIP_TOLERANCE_NM = 0.01


def _import_minari() -> Any:
    try:
        import minari
    except ImportError:
        raise ImportError(
            "atc-nf datasets need Minari: pip install 'atc-nf-env[dataset]' (minari[arrow])"
        ) from None
    return minari


def _stack_infos(infos: list[dict[str, Any]], clipped: list[np.ndarray]) -> dict[str, np.ndarray]:
    """The episode's infos, key by key, stacked over its T + 1 observations, with the run's
    safety so far: ``run_los_count`` (losses of separation since the start) and
    ``run_safe`` (no loss of separation and no step outside the envelope yet; at the
    last step they are the run's), and ``policy_waypoint_clipped`` (M,) (the step's
    action could not express the policy's waypoint; False at reset)."""
    # Scalars as (1,) per step: Minari 0.5's Arrow storage cannot read back 0-d info rows.
    stacked = {key: np.stack([np.atleast_1d(info[key]) for info in infos]) for key in infos[0]}
    los = np.cumsum(stacked["los_count"].sum(axis=1))
    outside = np.cumsum(stacked["envelope_violation"].any(axis=1)) > 0
    stacked["run_los_count"] = los.astype(np.int64)[:, None]
    stacked["run_safe"] = ((los == 0) & ~outside)[:, None]
    stacked["policy_waypoint_clipped"] = np.stack(clipped)
    return stacked


#: Where a dataset is written before it is complete: a hidden folder of Minari's store
#: (Minari lists no hidden folder), renamed into place at the end.
PARTIAL_PREFIX = ".atc-nf-partial-"
#: The id grammar, for messages: Minari's own (``minari.dataset.minari_dataset.parse_dataset_id``).
DATASET_ID_FORM = ("[namespace/]name-vN, e.g. atc-nf/converging-4/mpc-v0 (letters, digits, '-' and '_'; "
                   "namespaces separated by single '/'; N a version number)")


def dataset_path(dataset_id: Any) -> Path:
    """The folder the dataset ``dataset_id`` has in Minari's store (``MINARI_DATASETS_PATH``,
    default ``~/.minari/datasets``), after checking the id: Minari's grammar
    ``[namespace/]name-vN`` with a version, written as Minari writes it back, and a folder
    inside the store (no ``..``, no absolute path, no link out of it). ValueError otherwise,
    before anything flies."""
    minari = _import_minari()  # noqa: F841 - the extra's message when Minari is missing
    from minari.dataset.minari_dataset import gen_dataset_id, parse_dataset_id
    from minari.storage import get_dataset_path

    shown = repr(dataset_id) if not isinstance(dataset_id, str) or len(dataset_id) <= 80 else repr(dataset_id[:79] + "…")
    if not isinstance(dataset_id, str):
        raise ValueError(f"dataset id {shown}: must be a string of the form {DATASET_ID_FORM}")
    try:
        namespace, name, version = parse_dataset_id(dataset_id)
    except (ValueError, TypeError):  # TypeError: Minari's parser on an id without a version
        raise ValueError(f"dataset id {shown}: must be of the form {DATASET_ID_FORM}") from None
    if "//" in dataset_id or gen_dataset_id(namespace, name, version) != dataset_id:
        raise ValueError(f"dataset id {shown}: must be of the form {DATASET_ID_FORM}, written as Minari writes it "
                         f"back ({gen_dataset_id(namespace, name, version)!r})")
    store = Path(get_dataset_path()).resolve()
    target = (store / dataset_id).resolve()
    if store not in target.parents:
        raise ValueError(f"dataset id {shown}: its folder {target} lies outside Minari's store {store}")
    return target


def _remove_stale_partials(store: Path) -> None:
    """Delete the partial datasets that processes no longer running left in ``store``
    (killed mid-write); a running process's own is left alone."""
    for folder in store.glob(PARTIAL_PREFIX + "*"):
        try:
            pid = int(folder.name[len(PARTIAL_PREFIX):].split("-")[0])
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except (ValueError, PermissionError, OSError):
            continue


def _check_target_free(target: Path, dataset_id: str) -> None:
    """ValueError if the dataset's folder is taken: by a complete dataset (Minari never
    overwrites one) or by anything else (a partial one an older version left)."""
    if not os.path.lexists(target):
        return
    try:
        complete = json.loads((target / "data" / "metadata.json").read_text())["dataset_id"] == dataset_id
    except (OSError, ValueError, KeyError, TypeError):
        complete = False
    if complete:
        raise ValueError(f"dataset {dataset_id!r} already exists locally; delete it first "
                         f"(minari.delete_dataset({dataset_id!r})) or choose another id")
    raise ValueError(f"dataset {dataset_id!r}: its folder {target} holds no complete dataset (an interrupted write "
                     f"of an older version?); delete the folder (minari.delete_dataset({dataset_id!r})) and run again")


@contextlib.contextmanager
def _minari_store(path: Path) -> Iterator[None]:
    """Minari's store is ``path`` inside the block (Minari reads ``MINARI_DATASETS_PATH`` at each call)."""
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if before is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


def record_dataset(policy: str, task: str, episodes: int, dataset_id: str, *, first_seed: int = 0,
                   policy_kwargs: dict[str, Any] | None = None, progress: bool = False) -> Any:
    """Fly ``policy`` on ``episodes`` training seeds of ``task`` (``first_seed`` …) and
    write them as the local Minari dataset ``dataset_id``; returns the ``MinariDataset``.

    ValueError when the id is not Minari's ``[namespace/]name-vN`` or its folder would lie
    outside Minari's store (``dataset_path``), the task, the count or the seeds are out of
    range, or a dataset of that id already exists (Minari never overwrites one: delete it
    with ``minari.delete_dataset(id)`` first); all before anything flies. The dataset is
    written to a hidden folder of the store and renamed into place once complete, so a run
    killed or stopped by a full disk leaves no dataset behind (and the next run deletes
    what it left).
    """
    import gymnasium as gym

    import atc_nf_env
    from atc_nf_env.envs.actions import action_to_waypoint, waypoint_to_action
    from atc_nf_env.policy import make_policy

    minari = _import_minari()
    from minari.data_collector import EpisodeBuffer

    target = dataset_path(dataset_id)
    task_ = get_task(task)
    if task_.is_stream:
        raise ValueError(f"task = {task!r}: datasets record encounter tasks only "
                         f"({', '.join(name for name, t in TASKS.items() if not t.is_stream)})")
    train = SPLITS["train"]
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes = {episodes!r}: must be an integer >= 1")
    if isinstance(first_seed, bool) or not isinstance(first_seed, (int, np.integer)) or not (
            train.first <= first_seed and first_seed + episodes <= train.first + train.size):
        raise ValueError(f"first_seed = {first_seed!r}, episodes = {episodes}: datasets take training seeds, "
                         f"{train.first} … {train.first + train.size - 1}")
    _check_target_free(target, dataset_id)
    actor = make_policy(policy, **dict(policy_kwargs or {}))
    env = gym.make(atc_nf_env.ENV_ID, scenario=task_.scenario, wind_sigma=task_.wind_sigma_mps,
                   max_episode_minutes=task_.max_time_s / 60.0)
    unwrapped = env.unwrapped
    world, mapping, slots = unwrapped.world, unwrapped.cfg.action_mapping, unwrapped.n_slots
    buffers = []
    for index, seed in enumerate(range(int(first_seed), int(first_seed) + episodes)):
        observation, info = env.reset(seed=seed)
        actor.reset(world.sim.scenario, world.cfg.config, seed)
        observations, infos = [observation], [info]
        actions, rewards, terminations, truncations = [], [], [], []
        clipped = [np.zeros(slots, dtype=bool)]
        done = False
        while not done:
            view = world.sim.view()
            n = view.state.shape[0]
            waypoints = actor.act(view)
            action = np.zeros((slots, 2), dtype=np.float32)
            action[:n] = waypoint_to_action(waypoints, view.positions, view.destinations, mapping)
            # Where the action mapping cannot reach the policy's waypoint, the env flies the
            # nearest one it can: the dataset says so per aircraft and step.
            reached = action_to_waypoint(action[:n], view.positions, view.destinations, mapping)
            step_clipped = np.zeros(slots, dtype=bool)
            step_clipped[:n] = view.flying & (np.hypot(*(reached - waypoints).T) > CLIP_TOLERANCE_NM)
            clipped.append(step_clipped)
            observation, reward, terminated, truncated, info = env.step(action)
            for items, item in ((observations, observation), (infos, info), (actions, action),
                                (rewards, reward), (terminations, terminated), (truncations, truncated)):
                items.append(item)
            done = terminated or truncated
        buffers.append(EpisodeBuffer(id=index, seed=seed, observations=np.stack(observations),
                                     actions=np.stack(actions), rewards=rewards, terminations=terminations,
                                     truncations=truncations, infos=_stack_infos(infos, clipped)))
        if progress:
            print(f"episode {index + 1}/{episodes} (seed {seed})", file=sys.stderr, flush=True)
    from minari.namespace import create_namespace, list_local_namespaces
    from minari.storage import get_dataset_path

    store = Path(get_dataset_path()).resolve()
    _remove_stale_partials(store)
    partial = Path(tempfile.mkdtemp(prefix=f"{PARTIAL_PREFIX}{os.getpid()}-", dir=store))
    try:
        with _minari_store(partial):
            _write_buffers(minari, buffers, env, dataset_id, policy, task_, first_seed, episodes)
        _check_target_free(target, dataset_id)  # another process may have written it meanwhile
        namespace = target.parent.relative_to(store).as_posix()
        if namespace != "." and namespace not in list_local_namespaces():
            create_namespace(namespace)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.rename(partial / dataset_id, target)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return minari.load_dataset(dataset_id)


def _write_buffers(minari: Any, buffers: list[Any], env: Any, dataset_id: str, policy: str, task_: Any,
                   first_seed: int, episodes: int) -> Any:
    """``minari.create_dataset_from_buffers`` with this module's metadata, in Minari's
    current store."""
    with warnings.catch_warnings():
        # Minari asks for a code permalink and an author e-mail: a local dataset has neither.
        warnings.filterwarnings("ignore", message=r"`(code_permalink|author_email)` is set to None")
        return minari.create_dataset_from_buffers(
            dataset_id=dataset_id,
            buffer=buffers,
            env=env,
            eval_env=env.spec,
            algorithm_name=f"atc-nf policy {policy!r}",
            author="atc-nf-env",
            description=(f"{policy} flying the {task_.name} task ({task_.description}) of the atc-nf-env "
                         f"benchmark suite {SUITE_VERSION}, training seeds {first_seed} … "
                         f"{int(first_seed) + episodes - 1}, hidden wind sigma {task_.wind_sigma_mps} m/s. "
                         "Per-aircraft figures in the infos; the run's safety so far in infos['run_safe'] and "
                         "infos['run_los_count']."),
            data_format=DATA_FORMAT,
        )


def aircraft_transitions(dataset: Any) -> Iterator[dict[str, Any]]:
    """Per-aircraft transitions of a dataset written by ``record_dataset``: for every
    episode, step and aircraft flying at that step, a dict with ``observation`` (D,),
    ``action`` (2,), ``reward`` (the aircraft's own share), ``next_observation`` (D,),
    ``terminated`` (it arrived or left during the step), ``truncated`` (the episode hit
    its time limit with it still flying), ``aircraft``, ``episode`` and ``step``."""
    for episode in dataset.iterate_episodes():
        infos = episode.infos
        actions = np.asarray(episode.actions)
        slots = actions.shape[1]
        observations = np.asarray(episode.observations).reshape(len(episode.observations), slots, -1)
        alive = np.asarray(infos["alive"])
        rewards = np.asarray(infos["aircraft_reward"])
        for step in range(actions.shape[0]):
            for aircraft in np.flatnonzero(alive[step]):
                still = bool(alive[step + 1][aircraft])
                yield {
                    "observation": observations[step, aircraft],
                    "action": actions[step, aircraft],
                    "reward": float(rewards[step + 1][aircraft]),
                    "next_observation": observations[step + 1, aircraft],
                    "terminated": not still,
                    "truncated": still and bool(episode.truncations[step]),
                    "aircraft": int(aircraft),
                    "episode": int(episode.id),
                    "step": step,
                }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="atc-nf dataset",
                                     description="Record a policy on a benchmark task as a local Minari dataset.")
    parser.add_argument("--policy", required=True, help="a registered policy name (nf, mpc, ...) or a model file")
    parser.add_argument("--task", required=True, choices=[name for name, t in TASKS.items() if not t.is_stream])
    parser.add_argument("--episodes", type=int, required=True)
    parser.add_argument("--dataset-id", required=True, help="e.g. atc-nf/converging-4/mpc-v0")
    parser.add_argument("--first-seed", type=int, default=0, help="the first training seed (default 0)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    try:
        dataset = record_dataset(args.policy, args.task, args.episodes, args.dataset_id, first_seed=args.first_seed,
                                 progress=not args.no_progress)
    except (ValueError, ImportError) as error:
        print(f"atc-nf dataset: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # a full disk or an unwritable store: nothing was left behind
        print(f"atc-nf dataset: cannot write {args.dataset_id!r}: {error.strerror or error}; no dataset was written",
              file=sys.stderr)
        return 1
    print(f"wrote {args.dataset_id}: {dataset.total_episodes} episodes, {dataset.total_steps} steps "
          "(minari.load_dataset reads it)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
