"""RLlib: env creators for ``ray.tune.register_env``.

    from ray.rllib.algorithms.ppo import PPOConfig
    from atc_nf_env.integrations.rllib import register_envs

    register_envs()   # "atc_nf_env_parallel", "atc_nf_env_aec", "atc_nf_env_encounter"
    config = (
        PPOConfig()
        .environment("atc_nf_env_parallel", env_config={"scenario": "converging-4"})
        .multi_agent(policies={"shared"}, policy_mapping_fn=lambda agent_id, *a, **k: "shared")
    )

``env_config`` holds the environment's keyword arguments (``atc_nf_env.envs``). Every
env runner, on any node of a Ray cluster, builds its env from the registered name, so
the same config scales from a laptop to a cluster (``examples/train_rllib.py``).

Single-agent algorithms take the centralized env under ``"atc_nf_env_encounter"``:
``gym.make("atc_nf_env/Encounter-v1", **env_config)`` with its (M, 2) action flattened to
(2M,) (``atc_nf_env.envs.wrappers.FlattenActions``), since RLlib's default models emit
one flat action vector. Passing the Gymnasium id itself to ``.environment()`` fails on
remote env runners, which have not imported ``atc_nf_env``; the registered creator
imports it wherever it runs.
"""

from __future__ import annotations

from typing import Any, Mapping

#: Names under which ``register_envs`` registers the two forms.
PARALLEL_ENV_NAME = "atc_nf_env_parallel"
AEC_ENV_NAME = "atc_nf_env_aec"
CENTRALIZED_ENV_NAME = "atc_nf_env_encounter"


def _kwargs(env_config: Mapping[str, Any] | None) -> dict[str, Any]:
    # RLlib passes an EnvContext (a dict with worker_index etc. as attributes): its items
    # are exactly the user's env_config.
    return dict(env_config or {})


def parallel_env_creator(env_config: Mapping[str, Any] | None = None) -> Any:
    """RLlib's ``ParallelPettingZooEnv`` over ``atc_nf_env.parallel_env(**env_config)``."""
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from atc_nf_env.envs.parallel import parallel_env

    return ParallelPettingZooEnv(parallel_env(**_kwargs(env_config)))


def aec_env_creator(env_config: Mapping[str, Any] | None = None) -> Any:
    """RLlib's ``PettingZooEnv`` over ``atc_nf_env.env(**env_config)`` (agents in turn)."""
    from ray.rllib.env.wrappers.pettingzoo_env import PettingZooEnv

    from atc_nf_env.envs.parallel import env

    return PettingZooEnv(env(**_kwargs(env_config)))


def centralized_env_creator(env_config: Mapping[str, Any] | None = None) -> Any:
    """``gym.make("atc_nf_env/Encounter-v1", **env_config)`` with a flat Box(2M,) action
    space (``FlattenActions``), for RLlib's single-agent algorithms."""
    import gymnasium as gym

    import atc_nf_env
    from atc_nf_env.envs.wrappers import FlattenActions

    return FlattenActions(gym.make(atc_nf_env.ENV_ID, **_kwargs(env_config)))


def register_envs(
    parallel_name: str = PARALLEL_ENV_NAME,
    aec_name: str = AEC_ENV_NAME,
    centralized_name: str = CENTRALIZED_ENV_NAME,
) -> tuple[str, str, str]:
    """Register the three creators with ``ray.tune.register_env``; returns their names
    (parallel, AEC, centralized)."""
    from ray.tune.registry import register_env

    register_env(parallel_name, parallel_env_creator)
    register_env(aec_name, aec_env_creator)
    register_env(centralized_name, centralized_env_creator)
    return parallel_name, aec_name, centralized_name


__all__ = [
    "AEC_ENV_NAME",
    "CENTRALIZED_ENV_NAME",
    "PARALLEL_ENV_NAME",
    "aec_env_creator",
    "centralized_env_creator",
    "parallel_env_creator",
    "register_envs",
]
