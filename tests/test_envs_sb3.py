"""Stable-Baselines3 and SuperSuit: SB3's env checker, PPO through SuperSuit's wrappers
(seeded), and PPO on the native SB3 adapter (centralized and parameter-shared)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
ss = pytest.importorskip("supersuit")

from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.env_checker import check_env as sb3_check_env  # noqa: E402
from stable_baselines3.common.vec_env import VecMonitor  # noqa: E402

import atc_nf_env  # noqa: E402
from atc_nf_env.envs.centralized import EncounterEnv  # noqa: E402
from atc_nf_env.envs.vector import make_sb3_vec_env, seedable_sb3_vec_env  # noqa: E402

PPO_ARGS = {"n_steps": 128, "batch_size": 128, "n_epochs": 2, "policy_kwargs": {"net_arch": [32, 32]}}


def supersuit_vec_env(num_vec_envs: int = 2, **kwargs):
    par = atc_nf_env.parallel_env(**kwargs)
    par = ss.black_death_v3(par)
    vec = ss.pettingzoo_env_to_vec_env_v1(par)
    return ss.concat_vec_envs_v1(vec, num_vec_envs, num_cpus=0, base_class="stable_baselines3")


def test_sb3_check_env() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(EncounterEnv(scenario="converging-4"), warn=True)
        sb3_check_env(EncounterEnv(scenario="random-3", max_aircraft=4, expose_wind=True), warn=True)


def test_ppo_through_supersuit_for_a_few_thousand_steps() -> None:
    venv = seedable_sb3_vec_env(supersuit_vec_env(2, scenario="converging-4"))
    assert venv.num_envs == 2 * 4  # two copies of four agents
    venv = VecMonitor(venv)  # counts one episode per agent (parameter sharing)
    model = PPO("MlpPolicy", venv, seed=0, **PPO_ARGS)
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    # Several whole episodes went through SuperSuit's black death and autoreset.
    assert len(model.ep_info_buffer) >= 8
    venv.close()


def test_seeding_through_the_supersuit_pipeline_reproduces_rollouts() -> None:
    def rollout(seed: int) -> np.ndarray:
        venv = seedable_sb3_vec_env(supersuit_vec_env(2, scenario="converging-4"))
        venv.seed(seed)
        observations = [venv.reset()]
        for _ in range(20):  # past the end of the first episodes
            venv.step_async(np.zeros((venv.num_envs, 2), dtype=np.float32))
            observations.append(venv.step_wait()[0])
        return np.stack(observations)

    assert np.array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3), rollout(4))


@pytest.mark.parametrize("mode", ["centralized", "shared"])
def test_ppo_on_the_native_adapter(mode: str) -> None:
    venv = make_sb3_vec_env(8, mode=mode, scenario="converging-4", max_aircraft=5, max_episode_minutes=60)
    assert venv.num_envs == (8 if mode == "centralized" else 40)
    model = PPO("MlpPolicy", VecMonitor(venv), seed=0, **{**PPO_ARGS, "n_steps": 32})
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    assert len(model.ep_info_buffer) > 0


def test_native_adapter_same_step_reset_and_terminal_observation() -> None:
    venv = make_sb3_vec_env(3, mode="shared", scenario="converging-3", max_episode_minutes=10)
    venv.seed(5)
    first = venv.reset()
    assert first.shape == (9, venv.observation_space.shape[0])
    actions = np.zeros((9, 2), dtype=np.float32)
    venv.step_async(actions)
    _, rewards, dones, infos = venv.step_wait()
    assert rewards.shape == (9,) and not dones.any()
    venv.step_async(actions)
    obs, _, dones, infos = venv.step_wait()
    assert dones.all()
    assert all(info["TimeLimit.truncated"] for info in infos)
    assert all(info["episode_seed"] in (5, 6, 7) for info in infos)
    assert not np.array_equal(infos[0]["terminal_observation"], obs[0])
    assert np.array_equal(obs[:, 7], np.zeros(9))  # a new episode starts at time 0
    with pytest.raises(ValueError, match="mode = 'both'"):
        make_sb3_vec_env(2, mode="both")
    venv.step_async(np.full((9, 2), np.nan))
    with pytest.raises(ValueError, match="NaN"):
        venv.step_wait()


def test_native_adapter_seeding_reproduces() -> None:
    def rollout(seed: int) -> np.ndarray:
        venv = make_sb3_vec_env(4, mode="centralized", scenario="random-3")
        venv.seed(seed)
        out = [venv.reset()]
        for _ in range(5):
            venv.step_async(np.zeros((4, 3, 2), dtype=np.float32))
            out.append(venv.step_wait()[0])
        return np.stack(out)

    assert np.array_equal(rollout(1), rollout(1))
    assert not np.array_equal(rollout(1), rollout(2))
