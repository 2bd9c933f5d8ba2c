"""SuperSuit + Stable-Baselines3: copies of the PettingZoo env in worker processes, one
SB3 env per aircraft (parameter sharing), seedable by ``PPO(..., seed=...)``.

    from stable_baselines3 import PPO
    from atc_nf_env.integrations.supersuit import make_supersuit_sb3_vec_env
    venv = make_supersuit_sb3_vec_env(num_vec_envs=4, num_cpus=2, scenario="converging-4")
    PPO("MlpPolicy", venv, seed=0).learn(10_000)
    venv.close()   # without it, the worker processes keep the interpreter from exiting

SuperSuit's chain is ``black_death_v3`` (an aircraft that has arrived sees zeros until
its encounter ends, so every copy keeps a fixed number of agents) →
``pettingzoo_env_to_vec_env_v1`` → ``concat_vec_envs_v1(..., base_class=
"stable_baselines3")``; the last lacks the ``seed`` method SB3 calls, which
``atc_nf_env.envs.vector.seedable_sb3_vec_env`` adds. Build the chain yourself only with
``black_death_v3`` first: ``pettingzoo_env_to_vec_env_v1`` needs every agent alive at
every step, and without it the multi-process chain hangs the main process (SuperSuit 3.11). For speed in one process the
native ``atc_nf_env.envs.vector.make_sb3_vec_env(B, mode="shared")`` steps B worlds in
one kernel call instead.
"""

from __future__ import annotations

from typing import Any

from atc_nf_env.envs.vector import seedable_sb3_vec_env


def make_supersuit_sb3_vec_env(num_vec_envs: int = 4, num_cpus: int = 2, **kwargs: Any) -> Any:
    """``num_vec_envs`` copies of ``atc_nf_env.parallel_env(**kwargs)`` over ``num_cpus``
    processes (0: in this process), as one seedable SB3 ``VecEnv`` of
    ``num_vec_envs × n_aircraft`` envs."""
    import supersuit as ss

    from atc_nf_env.envs.parallel import parallel_env

    env = ss.black_death_v3(parallel_env(**kwargs))
    venv = ss.pettingzoo_env_to_vec_env_v1(env)
    venv = ss.concat_vec_envs_v1(venv, num_vec_envs, num_cpus=num_cpus, base_class="stable_baselines3")
    return seedable_sb3_vec_env(venv)


__all__ = ["make_supersuit_sb3_vec_env", "seedable_sb3_vec_env"]
