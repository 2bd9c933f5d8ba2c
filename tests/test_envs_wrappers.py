"""FlattenActions: the centralized env with a flat Box(2M,) action, for single-agent
learners (RLlib's PPO) whose models emit one flat vector."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import atc_nf_env
from atc_nf_env.envs.wrappers import FlattenActions


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped version")  # the wrapper is what is checked
def test_flat_action_space_passes_gymnasiums_checker() -> None:
    env = FlattenActions(gym.make(atc_nf_env.ENV_ID, scenario="converging-4"))
    assert env.action_space.shape == (8,) and env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1.0) and np.all(env.action_space.high == 1.0)
    check_env(env, skip_render_check=True)


def test_flat_actions_fly_exactly_the_shaped_actions_slot_by_slot() -> None:
    shaped = gym.make(atc_nf_env.ENV_ID, scenario="random-4")
    flat = FlattenActions(gym.make(atc_nf_env.ENV_ID, scenario="random-4"))
    obs_a, _ = shaped.reset(seed=11)
    obs_b, _ = flat.reset(seed=11)
    rng = np.random.default_rng(0)
    for _ in range(4):
        action = rng.uniform(-1, 1, size=(4, 2)).astype(np.float32)
        obs_a, reward_a, *_ = shaped.step(action)
        obs_b, reward_b, *_ = flat.step(action.reshape(-1))
        assert np.array_equal(obs_a, obs_b) and reward_a == reward_b


def test_a_flat_action_of_the_wrong_size_is_refused_with_the_expected_shape() -> None:
    env = FlattenActions(gym.make(atc_nf_env.ENV_ID, scenario="converging-3"))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        env.step(np.zeros(4))


def test_an_env_without_a_per_aircraft_action_box_is_refused() -> None:
    with pytest.raises(ValueError, match=r"shape \(M, 2\)"):
        FlattenActions(gym.make("CartPole-v1"))


def test_the_rllib_creator_builds_the_flat_env_from_its_config_without_ray() -> None:
    from atc_nf_env.integrations.rllib import centralized_env_creator

    env = centralized_env_creator({"scenario": "converging-6"})
    assert isinstance(env, FlattenActions) and env.action_space.shape == (12,)
