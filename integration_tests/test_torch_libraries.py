"""TorchRL 0.14 and SuperSuit + Stable-Baselines3 (one venv): rollouts of the PettingZoo
env, the centralized env and the vector env, the MAPPO example (``examples/train_torchrl.py``),
and PPO on SuperSuit's multi-process vector env with seed=0. The batched TorchRL env and
the IPPO/MAPPO trainers have their own file, ``test_torchrl_marl.py``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from torchrl.envs import GymEnv, GymWrapper
from torchrl.envs.utils import check_env_specs

import atc_nf_env
from atc_nf_env.integrations.torchrl import make_torchrl_env


def test_pettingzoo_rollout_keeps_the_encounter_until_the_last_aircraft_ends() -> None:
    env = make_torchrl_env(scenario="converging-4", return_state=True, seed=0)
    check_env_specs(env)
    rollout = env.rollout(200, break_when_any_done=True)
    mask = rollout["next", "aircraft", "mask"].sum(-1)
    done = rollout["next", "done"].squeeze(-1)
    assert done[-1] and not done[:-1].any()  # done_on_any=False: one reset per encounter
    assert mask[0] == 4 and mask[-1] == 0 and (mask[1:] <= mask[:-1]).all()
    assert rollout["next", "aircraft", "info", "aircraft_reward"].shape == (len(done), 4)
    assert torch.equal(rollout["next", "aircraft", "info", "aircraft_reward"], rollout["next", "aircraft", "reward"].squeeze(-1))
    assert rollout["next", "state"].shape[-1] == atc_nf_env.parallel_env().state_space.shape[0]


def test_aec_form_rolls_out() -> None:
    env = make_torchrl_env(parallel=False, scenario="converging-3", max_cycles=4, seed=0)
    rollout = env.rollout(40, break_when_any_done=True)
    assert rollout["next", "done"][-1].all()


def test_centralized_env_through_gym_env_and_the_vector_env_through_gym_wrapper() -> None:
    env = GymEnv("atc_nf_env/Encounter-v1", scenario="converging-4")
    check_env_specs(env)
    assert env.rollout(5)["next", "reward"].shape == (5, 1)
    vec = GymWrapper(gym.make_vec("atc_nf_env/Encounter-v1", num_envs=4, max_cycles=3,
                                  autoreset_mode=gym.vector.AutoresetMode.SAME_STEP))
    rollout = vec.rollout(8, break_when_any_done=False)
    assert rollout["next", "reward"].shape == (4, 8, 1)
    assert np.isfinite(rollout["next", "reward"].numpy()).all()


def test_mappo_example_trains_and_scores(run_example, tmp_path) -> None:
    out = run_example("train_torchrl.py", "--algorithm", "mappo", "--frames", "128", "--num-envs", "4",
                      "--steps-per-batch", "16", "--eval-runs", "2", "--test-runs", "1", "--out", str(tmp_path))
    assert "trained" in out and ": 128 frames in" in out
    assert "runs 1   home" in out
    assert (tmp_path / "policy.pt").is_file()


def test_supersuit_multiprocess_ppo_with_seed_0(run_example) -> None:
    first = run_example("train_supersuit_sb3.py", "--copies", "2", "--cpus", "2", "--timesteps", "1024")
    assert "1024 agent steps in 8 SB3 envs over 2 processes" in first
    assert run_example("train_supersuit_sb3.py", "--copies", "2", "--cpus", "2", "--timesteps", "1024") == first
