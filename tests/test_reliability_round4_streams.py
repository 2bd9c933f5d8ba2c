"""Round 4 of the reliability issue, traffic streams: an explicit time limit is honoured,
the AEC form survives entries at the last step and empty skies, streams render and
animate, TorchRL says what it takes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import atc_nf_env
from atc_nf_env.envs import MAX_EPISODE_MINUTES, EnvConfig
from atc_nf_env.units import DECISION_PERIOD_S


# ------------------------------------------------------------------ item 2: time limits


@pytest.mark.parametrize("make", [atc_nf_env.parallel_env, atc_nf_env.env])
def test_an_explicit_180_min_limit_is_honoured_on_a_long_stream(make):
    env = make(scenario="stream-10-300min", max_episode_minutes=180)
    assert env.unwrapped.world.limit_s == 180 * 60.0
    par = atc_nf_env.parallel_env(scenario="stream-10-300min", max_episode_minutes=MAX_EPISODE_MINUTES)
    assert par.world.limit_s == 180 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10-300min").world.limit_s == 300 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10-300min", max_episode_minutes=None).world.limit_s == 300 * 60.0


def test_a_gym_stream_env_with_180_min_ends_at_180_min():
    import gymnasium as gym

    env = gym.make("atc_nf_env/Encounter-v0", scenario="stream-2.5-300min", max_episode_minutes=180)
    env.reset(seed=4)
    truncated, info = False, {}
    while not truncated:
        _, _, _, truncated, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert info["time_s"] == pytest.approx(180 * 60.0)


def test_not_given_keeps_the_encounter_default():
    default = EnvConfig()
    assert default.max_episode_minutes == MAX_EPISODE_MINUTES and not default.time_limit_given
    assert default.max_decisions == round(MAX_EPISODE_MINUTES * 60 / DECISION_PERIOD_S)
    assert EnvConfig(max_episode_minutes=180).time_limit_given
    assert EnvConfig(max_cycles=3).time_limit_given
    assert EnvConfig.from_kwargs({"max_episode_minutes": None}, "t") == default
    with pytest.raises(ValueError, match="max_episode_minutes"):
        EnvConfig(max_episode_minutes=0)
