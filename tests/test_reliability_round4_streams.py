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


# ------------------------------------------------------------------ item 11: the AEC stream env


def _fly_aec(env, seed: int) -> tuple[int, set[str], set[str]]:
    """One AEC episode with zero actions: (agents at the reset, agents seen, agents done)."""
    env.reset(seed=seed)
    at_reset, seen, done = len(env.agents), set(), set()
    for agent in env.agent_iter():
        _, _, terminated, truncated, _ = env.last()
        seen.add(agent)
        if terminated or truncated:
            done.add(agent)
        env.step(None if terminated or truncated else np.zeros(2, dtype=np.float32))
    return at_reset, seen, done


def test_aec_stream_survives_flights_entering_at_the_truncating_step():
    env = atc_nf_env.env(scenario="stream-60", max_cycles=2)
    for seed in range(6):
        _, seen, done = _fly_aec(env, seed)
        assert seen and seen == done  # every flight that acted ended, none was left over
        assert not env.agents
        # A flight that entered at the last instant is in the stream's books, not an agent.
        metrics = env.unwrapped.stream_metrics()
        assert len(done) <= metrics["flights_entered"]


def test_aec_and_parallel_streams_take_empty_skies():
    env = atc_nf_env.env(scenario="stream-2.5-60min", max_cycles=3)
    par = atc_nf_env.parallel_env(scenario="stream-2.5-60min", max_cycles=3)
    empty = 0
    for seed in range(12):
        at_reset, seen, done = _fly_aec(env, seed)
        assert seen == done
        obs, _ = par.reset(seed=seed)
        assert len(par.agents) == at_reset and set(obs) == set(par.agents)
        if at_reset == 0:
            empty += 1
            assert env.agent_selection is None
            assert par.step({}) == ({}, {}, {}, {}, {})
            with pytest.raises(ValueError, match="episode is over"):
                par.step({"flight_0": np.zeros(2)})
    assert empty >= 3  # the seeds do fly windows in which no flight enters


@pytest.mark.parametrize("kwargs", [
    {"scenario": "stream-60", "max_cycles": 2},
    {"scenario": "stream-60", "max_cycles": 1},
    {"scenario": "stream-2.5-60min"},  # the sky empties between flights
])
def test_pettingzoo_api_tests_pass_on_short_and_sparse_streams(kwargs):
    from pettingzoo.test import api_test, parallel_api_test

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
        api_test(atc_nf_env.env(**kwargs), num_cycles=40)
        parallel_api_test(atc_nf_env.parallel_env(**kwargs), num_cycles=40)


def test_parallel_api_test_passes_with_resets_that_find_no_flight():
    from pettingzoo.test import parallel_api_test

    par = atc_nf_env.parallel_env(scenario="stream-2.5-60min", max_cycles=3)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
        parallel_api_test(par, num_cycles=10)


# ------------------------------------------------------------------ item 12: TorchRL and streams


@pytest.mark.parametrize("scenario", ["stream-30-60min", "stream-2.5"])
def test_make_torchrl_env_refuses_a_stream_and_says_what_takes_one(scenario):
    from atc_nf_env.integrations.torchrl import make_torchrl_env

    with pytest.raises(ValueError, match=r"traffic stream.*GymEnv\(\"atc_nf_env/Encounter-v0\""):
        make_torchrl_env(scenario=scenario)  # refused before torchrl is imported


def test_batched_torchrl_env_refuses_a_stream_at_construction():
    pytest.importorskip("torchrl")
    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    with pytest.raises(ValueError, match="AtcNfBatchedEnv: scenario = 'stream-30' is a traffic stream"):
        AtcNfBatchedEnv(2, scenario="stream-30")
    assert AtcNfBatchedEnv(2, scenario="converging-4").reset()["aircraft", "mask"].all()


def test_torchrl_gym_env_takes_a_stream_as_the_refusal_says():
    pytest.importorskip("torchrl")
    from torchrl.envs import GymEnv

    env = GymEnv("atc_nf_env/Encounter-v0", scenario="stream-2.5-60min", max_cycles=4)
    rollout = env.rollout(6, break_when_any_done=False)
    assert rollout["aircraft"].shape[1:] == (env.observation_spec["mask"].shape[-1], rollout["aircraft"].shape[-1])
    assert rollout["next", "truncated"].any()
