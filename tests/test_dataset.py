"""Offline datasets in Minari's format: what minari.load_dataset reads back is what the
env flew, episode by episode, with each run's safety and per-aircraft transitions."""

from __future__ import annotations

import subprocess
import sys

import minari
import numpy as np
import pytest

from atc_nf_env.dataset import aircraft_transitions, record_dataset


@pytest.fixture(autouse=True)
def minari_root(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "datasets"))
    return tmp_path / "datasets"


def test_a_recorded_dataset_replays_bit_for_bit_in_the_recovered_env() -> None:
    record_dataset("mpc", "converging-4", 2, "atc-nf/converging-4/mpc-v0", first_seed=3)
    data = minari.load_dataset("atc-nf/converging-4/mpc-v0")
    env = data.recover_environment()
    assert data.total_episodes == 2 and data.action_space == env.action_space
    assert data.observation_space == env.observation_space
    for episode, seed in zip(data.iterate_episodes(), (3, 4)):
        assert episode.infos["episode_seed"][0, 0] == seed
        obs, _ = env.reset(seed=seed)
        assert np.array_equal(obs, episode.observations[0])
        for step, action in enumerate(episode.actions):
            obs, reward, terminated, truncated, _ = env.step(action)
            assert np.array_equal(obs, episode.observations[step + 1]) and reward == episode.rewards[step]
        assert terminated == episode.terminations[-1] and truncated == episode.truncations[-1]
        # The MPC's waypoints lie within the action mapping's range: the dataset is its flight.
        assert not episode.infos["policy_waypoint_clipped"].any()
        los = int(episode.infos["los_count"].sum())
        outside = bool(episode.infos["envelope_violation"].any())
        assert bool(episode.infos["run_safe"][-1, 0]) == (los == 0 and not outside)


def test_per_aircraft_transitions_cover_every_flying_aircraft_once_per_step() -> None:
    data = record_dataset("mpc", "random-4", 1, "atc-nf/random-4/mpc-v0")
    episode = next(data.iterate_episodes())
    transitions = list(aircraft_transitions(data))
    assert len(transitions) == int(episode.infos["alive"][:-1].sum())
    assert sum(t["terminated"] for t in transitions) == int(episode.infos["arrived"][-1].sum()
                                                            + episode.infos["left_workspace"][-1].sum())
    first = transitions[0]
    assert first["observation"].shape == (data.observation_space.shape[0] // 4,)
    assert np.array_equal(first["action"], episode.actions[0, first["aircraft"]])
    assert sum(t["reward"] for t in transitions) == pytest.approx(float(episode.rewards.sum()))


def test_the_nf_alones_out_of_range_waypoints_are_flagged_as_clipped() -> None:
    data = record_dataset("nf", "converging-4", 1, "atc-nf/converging-4/nf-v0")
    episode = next(data.iterate_episodes())
    assert episode.infos["policy_waypoint_clipped"][1].all()  # 500 nm away: beyond the mapping


def test_bad_requests_are_refused_before_anything_flies() -> None:
    record_dataset("nf", "converging-4", 1, "atc-nf/converging-4/nf-v0")
    with pytest.raises(ValueError, match="already exists"):
        record_dataset("nf", "converging-4", 1, "atc-nf/converging-4/nf-v0")
    with pytest.raises(ValueError, match="training seeds"):
        record_dataset("nf", "converging-4", 1, "atc-nf/x/nf-v0", first_seed=1_000_000_000)
    with pytest.raises(ValueError, match="episodes"):
        record_dataset("nf", "converging-4", 0, "atc-nf/x/nf-v0")
    with pytest.raises(ValueError, match="converging-4"):
        record_dataset("nf", "converging-5", 1, "atc-nf/x/nf-v0")


def test_the_command_writes_a_dataset_minari_loads(minari_root) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "atc_nf_env.dataset", "--policy", "mpc", "--task", "converging-4", "--episodes", "1",
         "--dataset-id", "atc-nf/converging-4/mpc-v0", "--no-progress"],
        capture_output=True, text=True, timeout=600, env={**__import__("os").environ,
                                                           "MINARI_DATASETS_PATH": str(minari_root)},
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "wrote atc-nf/converging-4/mpc-v0: 1 episodes" in done.stdout
    assert minari.load_dataset("atc-nf/converging-4/mpc-v0").total_episodes == 1
