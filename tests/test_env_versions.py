"""Env IDs and versions: a change of trajectories bumps the version (CONTRIBUTING.md)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import DeprecatedEnv
from gymnasium.utils.env_checker import check_env

import atc_nf_env


def test_the_retired_v0_names_v1_and_what_changed() -> None:
    for make in (lambda: gym.make("atc_nf_env/Encounter-v0"), lambda: gym.make_vec("atc_nf_env/Encounter-v0", 2)):
        with pytest.raises(DeprecatedEnv, match="atc_nf_env/Encounter-v1.*sensing radius"):
            make()


def test_v1_is_the_encounter_env() -> None:
    env = gym.make(atc_nf_env.ENV_ID, scenario="converging-4")
    assert atc_nf_env.ENV_ID == "atc_nf_env/Encounter-v1"
    assert type(env.unwrapped).__name__ == "EncounterEnv"
    env.close()


def test_the_stream_id_makes_a_stream_env_that_passes_gymnasiums_checker() -> None:
    env = gym.make(atc_nf_env.STREAM_ENV_ID, scenario="stream-30-30min")
    assert type(env.unwrapped).__name__ == "StreamEnv"
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3_000_000_000)
    assert set(obs) == {"aircraft", "mask"}
    env.close()
    assert gym.make(atc_nf_env.STREAM_ENV_ID).unwrapped.world.spec == "stream-30"


def test_the_stream_id_refuses_an_encounter_saying_where_it_goes() -> None:
    with pytest.raises(ValueError, match="not a traffic stream.*Encounter-v1"):
        gym.make(atc_nf_env.STREAM_ENV_ID, scenario="converging-4")


def test_the_stream_ids_vector_form_steps() -> None:
    vec = gym.make_vec(atc_nf_env.STREAM_ENV_ID, num_envs=2, scenario="stream-30-30min")
    obs, _ = vec.reset(seed=3_000_000_000)
    assert obs["mask"].shape[0] == 2
    vec.step(np.zeros(vec.action_space.shape, dtype=np.float32))
    vec.close()


def test_every_env_docstring_has_its_version_history() -> None:
    from atc_nf_env.envs import centralized, parallel, streams

    for doc in (centralized.EncounterEnv.__doc__, parallel.ATCParallelEnv.__doc__, streams.__doc__):
        assert "Version History" in doc and "v1" in doc and "v0" in doc
    assert parallel.ATCParallelEnv.metadata["name"] == "atc_nf_env_v1"
    assert streams.StreamParallelEnv.metadata["name"] == "atc_nf_stream_v1"
