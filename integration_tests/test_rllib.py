"""RLlib 2.60 (its own venv: it pins gymnasium 1.2.2): PPO on the parallel and AEC forms,
the AEC wrapper's episode end when an arrival meets the time limit, and render()."""

from __future__ import annotations

import numpy as np
import pytest
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv, PettingZooEnv

import atc_nf_env
from atc_nf_env.integrations.rllib import aec_env_creator, parallel_env_creator


def test_ppo_trains_on_the_parallel_form_with_a_remote_env_runner(run_example) -> None:
    out = run_example("train_rllib.py", "--form", "parallel", "--iterations", "2", "--env-runners", "1")
    assert "iteration 2: env steps 512" in out


def test_single_agent_ppo_trains_on_the_centralized_form_with_a_remote_env_runner(run_example) -> None:
    """The remote runner has not imported atc_nf_env, and RLlib's default model emits one
    flat action vector: the registered creator imports it and flattens the (M, 2) action."""
    out = run_example("train_rllib.py", "--form", "centralized", "--iterations", "2", "--env-runners", "1")
    assert "iteration 2: env steps 512" in out


def test_ppo_trains_on_the_aec_form(run_example) -> None:
    out = run_example("train_rllib.py", "--form", "aec", "--iterations", "2", "--env-runners", "0")
    assert "iteration 2:" in out


def first_arrival_step(scenario: str, seed: int) -> int:
    env = atc_nf_env.parallel_env(scenario=scenario)
    env.reset(seed=seed)
    for step in range(1, 100):
        _, _, terminations, _, _ = env.step({agent: np.zeros(2) for agent in env.agents})
        if any(terminations.values()):
            assert not all(terminations.values())
            return step
    raise AssertionError("no arrival")


@pytest.mark.parametrize("creator", [aec_env_creator, parallel_env_creator])
def test_episode_ends_for_rllib_when_an_arrival_meets_the_time_limit(creator) -> None:
    """RLlib steps until ``__all__``; with an aircraft arriving on the step the others are
    truncated, the old env gave neither __all__ and RLlib stepped ``{}`` (KeyError)."""
    scenario, seed = "random-4", 2
    limit = first_arrival_step(scenario, seed)
    env = creator({"scenario": scenario, "max_cycles": limit})
    obs, _ = env.reset(seed=seed)
    done = set()
    for _ in range(4 * limit + 4):
        actions = {agent: np.zeros(2, dtype=np.float32) for agent in obs if agent not in done}
        obs, _, terminated, truncated, _ = env.step(actions)
        done |= {agent for agent in terminated if agent != "__all__" and (terminated[agent] or truncated[agent])}
        if terminated["__all__"] or truncated["__all__"]:
            break
    else:
        raise AssertionError("the episode never ended for RLlib")
    assert truncated["__all__"] and len(done) == 4


def test_rllib_wrappers_render_frames() -> None:
    for wrapper, make in ((ParallelPettingZooEnv, atc_nf_env.parallel_env), (PettingZooEnv, atc_nf_env.env)):
        env = wrapper(make(scenario="converging-3", render_mode="rgb_array", render_size_px=64))
        env.reset(seed=0)
        frame = env.render()
        assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
