"""Reliability, round 4: training never flies a validation or test seed.

A reset without a seed draws the episode's seed from the env's generator. It used to draw
from [0, 2**31 - 1), which holds the benchmark's validation (1 000 000 000 …) and test
(2 000 000 000 …) splits, so every training loop built on the envs (``atc-nf train``,
SuperSuit, RLlib, BenchMARL, TorchRL) flew scored seeds. Each env form is reset thousands
of times here, after a first reset seeded on the test split, and every seed it drew (read
from its info, where each env reports ``episode_seed``) must lie in the train split: the
encounter tasks' for encounters, the stream tasks' for streams.
"""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import atc_nf_env
from atc_nf_env.benchmark import SPLITS, STREAM_SPLITS, Split
from atc_nf_env.envs import draw_episode_seed, drawn_seed_split
from atc_nf_env.envs.vector import EncounterVectorEnv, make_sb3_vec_env

ENV_ID = "atc_nf_env/Encounter-v1"
ENCOUNTER = "random-3"  # a new layout every reset: the drawn seed reaches the scenario too
STREAM = "stream-60-60min"  # a flight airborne at every reset: its info has the seed
#: A test-split seed for the first reset: seeding there must not pull the draws after it
#: out of the train split.
TEST_SEED = SPLITS["test"].first + 17
STREAM_TEST_SEED = STREAM_SPLITS["test"].first + 17
RESETS = 2000


def _assert_inside(seeds: list[int], split: Split) -> None:
    seeds_array = np.asarray(seeds, dtype=np.int64)
    outside = seeds_array[(seeds_array < split.first) | (seeds_array >= split.first + split.size)]
    assert outside.size == 0, f"{outside.size} of {seeds_array.size} drawn seeds outside the train split, e.g. {outside[:5]}"
    # Draws, not one seed repeated: a broken generator would pass the range check.
    assert len(set(seeds)) > 0.99 * len(seeds)


def _gym_seeds(scenario: str, first: int, resets: int = RESETS) -> list[int]:
    env = gym.make(ENV_ID, scenario=scenario)
    _, info = env.reset(seed=first)
    assert info["episode_seed"] == first  # a seeded reset flies the seed it was given
    return [env.reset()[1]["episode_seed"] for _ in range(resets)]


def _parallel_seeds(scenario: str, first: int) -> list[int]:
    env = atc_nf_env.parallel_env(scenario=scenario)
    _, infos = env.reset(seed=first)
    assert {info["episode_seed"] for info in infos.values()} == {first}
    seeds = []
    for _ in range(RESETS):
        _, infos = env.reset()
        (seed,) = {info["episode_seed"] for info in infos.values()}
        seeds.append(seed)
    return seeds


def _aec_seeds(scenario: str, first: int) -> list[int]:
    env = atc_nf_env.env(scenario=scenario)
    env.reset(seed=first)
    assert env.infos[env.agent_selection]["episode_seed"] == first
    seeds = []
    for _ in range(RESETS):
        env.reset()
        seeds.append(env.infos[env.agent_selection]["episode_seed"])
    return seeds


def _vector_seeds(scenario: str, first: int) -> list[int]:
    num_envs = 50
    env = EncounterVectorEnv(num_envs, scenario=scenario)
    _, info = env.reset(seed=first)
    assert list(info["episode_seed"]) == [first + b for b in range(num_envs)]
    seeds: list[int] = []
    for _ in range(RESETS // num_envs):
        seeds.extend(int(s) for s in env.reset()[1]["episode_seed"])
    return seeds


FORMS: dict[str, Callable[[str, int], list[int]]] = {
    "gymnasium": _gym_seeds,
    "parallel": _parallel_seeds,
    "aec": _aec_seeds,
    "vector": _vector_seeds,
}


@pytest.mark.parametrize("form", FORMS)
def test_every_encounter_env_form_draws_inside_the_train_split(form: str) -> None:
    seeds = FORMS[form](ENCOUNTER, TEST_SEED)
    assert len(seeds) == RESETS
    _assert_inside(seeds, SPLITS["train"])


@pytest.mark.parametrize("form", FORMS)
def test_every_stream_env_form_draws_inside_the_stream_train_split(form: str) -> None:
    seeds = FORMS[form](STREAM, STREAM_TEST_SEED)
    _assert_inside(seeds, STREAM_SPLITS["train"])


def test_the_documented_split_is_the_benchmarks_train_split() -> None:
    assert drawn_seed_split() is SPLITS["train"]
    assert drawn_seed_split(stream=True) is STREAM_SPLITS["train"]


@settings(max_examples=200, deadline=None)
@given(generator_seed=st.integers(0, 2**63 - 1), stream=st.booleans())
def test_draws_from_any_generator_stay_inside(generator_seed: int, stream: bool) -> None:
    rng = np.random.default_rng(generator_seed)
    split = drawn_seed_split(stream)
    seeds = [draw_episode_seed(rng, stream=stream) for _ in range(50)]
    assert all(split.first <= s < split.first + split.size for s in seeds)


def test_the_draws_are_the_same_for_the_same_seed() -> None:
    """One seed fixes every later episode, as before (only the range of the draws changed)."""
    first = _gym_seeds(ENCOUNTER, 5, resets=50)
    assert first == _gym_seeds(ENCOUNTER, 5, resets=50) and len(set(first)) == 50


def test_autoresets_of_the_vector_envs_draw_inside_the_train_split() -> None:
    """Episodes of one decision: every step ends every world, so each is an autoreset."""
    env = EncounterVectorEnv(16, scenario=ENCOUNTER, max_cycles=1)
    env.reset(seed=TEST_SEED)
    seeds: list[int] = []
    for _ in range(80):
        _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        if not (terminated | truncated).any():  # NEXT_STEP mode: this step was the resets'
            seeds.extend(int(s) for s in info["episode_seed"])
    assert len(seeds) >= 16 * 30
    _assert_inside(seeds, SPLITS["train"])


def _sb3_step_seeds(venv: Any, steps: int) -> list[int]:
    """Every episode seed in the step infos of an SB3 VecEnv (one info per sub-env)."""
    venv.reset()
    seeds = set()
    for _ in range(steps):
        actions = np.zeros((venv.num_envs, *venv.action_space.shape), dtype=np.float32)
        _, _, _, infos = venv.step(actions)
        seeds.update(int(info["episode_seed"]) for info in infos if "episode_seed" in info)
    return sorted(seeds)


@pytest.mark.parametrize("vec", ["native", "supersuit"])
def test_atc_nf_train_vector_envs_draw_inside_the_train_split(vec: str) -> None:
    """``atc-nf train``'s own vector envs (SB3 over the native vector env, or SuperSuit's
    chain over the PettingZoo env, the route of docs/marl.md), one-decision episodes."""
    pytest.importorskip("stable_baselines3")
    if vec == "supersuit":
        pytest.importorskip("supersuit")
    from agents.train import Args, make_vec_env

    args = Args(scenario="converging-3", vec=vec, num_envs=4, max_episode_minutes=5.0)
    venv = make_vec_env(args)
    venv.seed(TEST_SEED)
    seeds = _sb3_step_seeds(venv, 150)
    venv.close()
    assert len(seeds) >= 100
    _assert_inside([s for s in seeds if s not in range(TEST_SEED, TEST_SEED + 4)], SPLITS["train"])


def test_sb3_adapter_of_the_native_vector_env_draws_inside() -> None:
    pytest.importorskip("stable_baselines3")
    venv = make_sb3_vec_env(8, mode="centralized", scenario=ENCOUNTER, max_cycles=1)
    seeds = _sb3_step_seeds(venv, 100)
    assert len(seeds) >= 500
    _assert_inside(seeds, SPLITS["train"])


def test_torchrl_batched_env_draws_inside_the_train_split() -> None:
    pytest.importorskip("torchrl")
    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    env = AtcNfBatchedEnv(50, seed=TEST_SEED, scenario=ENCOUNTER)
    assert env.reset()["episode_seed"].tolist() == [TEST_SEED + b for b in range(50)]
    seeds: list[int] = []
    for _ in range(RESETS // 50):
        seeds.extend(env.reset()["episode_seed"].tolist())
    _assert_inside(seeds, SPLITS["train"])


@pytest.mark.parametrize(
    ("argv", "shown"),
    [
        (["--env-seed-offset", str(SPLITS["validation"].first)], "leave the train split"),
        (["--seed", "999999"], "leave the train split"),  # 10 000 + 999 999 000: past 999 999 999
        (["--env-seed-offset", "-20000"], "leave the train split"),
    ],
)
def test_atc_nf_train_refuses_first_seeds_outside_the_train_split(argv: list[str], shown: str, capsys, tmp_path) -> None:
    pytest.importorskip("stable_baselines3")
    from agents.train import main

    assert main([*argv, "--out", str(tmp_path / "run"), "--total-timesteps", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert shown in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run").exists()


def test_atc_nf_train_first_seeds_are_unchanged_for_encounters_and_in_the_stream_split() -> None:
    from agents.train import Args, first_training_seed

    assert first_training_seed(Args(seed=3)) == 13_000  # today's --env-seed-offset + 1000 * seed
    assert first_training_seed(Args(seed=3, scenario="stream-30")) == STREAM_SPLITS["train"].first + 13_000


def test_torchrl_pettingzoo_wrapper_draws_inside_the_train_split() -> None:
    """``make_torchrl_env``: TorchRL's PettingZooWrapper, BenchMARL's route (AtcNfTask)."""
    pytest.importorskip("torchrl")
    from atc_nf_env.integrations.torchrl import make_torchrl_env

    env = make_torchrl_env(scenario=ENCOUNTER, seed=TEST_SEED)
    seeds = [int(env.reset()["aircraft", "info", "episode_seed"][0]) for _ in range(300)]
    env.close()
    _assert_inside(seeds, SPLITS["train"])
