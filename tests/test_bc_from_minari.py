"""examples/bc_from_minari.py: behaviour cloning from a Minari dataset learns from the
same samples as ``atc-nf imitate`` on the fly, and writes a model that flies."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("minari")

from agents import imitate  # noqa: E402
from agents.policy import SB3AgentPolicy, read_meta  # noqa: E402
from atc_nf_env.dataset import record_dataset  # noqa: E402
from atc_nf_env.episode import run_episode  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples"))
from bc_from_minari import clone, cloning_dataset, main  # noqa: E402

#: A small MPC (K = 100) keeps the episodes quick; both sides fly the same one.
MPC = {"extractions": 100}
SEED = 10_000


@pytest.fixture(autouse=True)
def minari_root(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    return tmp_path / "datasets"


def test_the_dataset_holds_the_samples_imitate_learns_from_on_the_fly(tmp_path) -> None:
    args = imitate.Args(out=tmp_path / "imitate", episodes="converging-4:1", first_seed=SEED, workers=1,
                        expert_extractions=MPC["extractions"], bc_epochs=1, canonical_chirality=False, check_runs=0,
                        progress=False)
    imitate.run(args, "test")
    on_the_fly = imitate.load_dataset([args.out / "demos" / "expert"], False, True, args.n_neighbours)
    dataset = record_dataset("mpc", "converging-4", 1, "atc-nf/converging-4/mpc-v0", first_seed=SEED,
                             policy_kwargs=MPC)
    offline = cloning_dataset(dataset)
    assert offline.obs.shape == on_the_fly.obs.shape and offline.episodes == 1
    # The time feature is rescaled from the dataset's 240-min limit to the model env's.
    np.testing.assert_allclose(offline.obs, on_the_fly.obs, rtol=0, atol=1e-6)
    np.testing.assert_allclose(offline.act, on_the_fly.act, rtol=0, atol=1e-6)


def test_a_model_cloned_from_a_dataset_flies_and_says_where_it_came_from(tmp_path) -> None:
    dataset = record_dataset("mpc", "converging-4", 2, "atc-nf/converging-4/mpc-v0", first_seed=SEED,
                             policy_kwargs=MPC)
    history = clone(dataset, tmp_path / "bc.zip", epochs=3)
    assert history["dataset"]["episodes"] == 2 and history["dataset"]["samples"] > 0
    assert history["best_validation_loss"] <= history["initial_validation_loss"]
    training = read_meta(tmp_path / "bc.zip")["training"]
    assert training["stage"] == "bc-offline" and training["dataset"]["minari_dataset"] == "atc-nf/converging-4/mpc-v0"
    result = run_episode(SB3AgentPolicy(str(tmp_path / "bc.zip")), "converging-4", seed=0, max_time_s=600.0)
    assert np.isfinite(result.metrics.min_separation_nm)


def test_clipped_labels_and_aircraft_that_never_arrived_are_no_samples(tmp_path) -> None:
    # The NF alone aims 500 nm away, beyond the action mapping: most of its labels are clipped.
    dataset = record_dataset("nf", "converging-4", 1, "atc-nf/converging-4/nf-v0")
    episode = next(dataset.iterate_episodes())
    clipped = np.asarray(episode.infos["policy_waypoint_clipped"])[1:]
    arrived = np.asarray(episode.infos["arrived"])[-1]
    alive = np.asarray(episode.infos["alive"])[:-1].astype(bool)
    usable = alive & ~clipped & arrived[None, :]
    kept = cloning_dataset(dataset)
    assert 0 < len(kept.obs) == int(usable.sum()) < int(alive.sum())
    assert kept.dropped == int(alive.sum() - usable.sum())
    assert len(cloning_dataset(dataset, arrived_only=False).obs) == int((alive & ~clipped).sum())


def test_a_dataset_that_is_not_there_is_an_error_not_a_model(tmp_path, capsys) -> None:
    assert main(["--dataset-id", "atc-nf/converging-4/absent-v0", "--out", str(tmp_path / "bc.zip")]) == 2
    assert "absent-v0" in capsys.readouterr().err and not (tmp_path / "bc.zip").exists()
