"""atc-nf-env: aircraft under decentralized dipolar navigation functions with a hidden
wind, as Gymnasium and PettingZoo environments.

    import gymnasium as gym
    import atc_nf_env                      # registers "atc_nf_env/Encounter-v1"

    env = gym.make("atc_nf_env/Encounter-v1", scenario="converging-4")
    vec = gym.make_vec("atc_nf_env/Encounter-v1", num_envs=256)   # one kernel call per step
    par = atc_nf_env.parallel_env(scenario="converging-6")        # PettingZoo ParallelEnv
    aec = atc_nf_env.env(scenario="converging-6")                 # PettingZoo AEC

``gym.make("atc_nf_env:atc_nf_env/Encounter-v1")`` works without importing first.
The environment modules are imported on first use, so ``import atc_nf_env`` stays light.
"""

from __future__ import annotations

from typing import Any

ENV_ID = "atc_nf_env/Encounter-v1"
#: The Gymnasium ID of the traffic-stream env (``StreamEnv``; ``scenario="stream-R..."``).
STREAM_ENV_ID = "atc_nf_env/Stream-v1"
#: IDs of dynamics no longer flown, each registered so that making it says what replaced it
#: (``atc_nf_env.envs.retired``).
RETIRED_ENV_IDS: tuple[str, ...] = ("atc_nf_env/Encounter-v0",)


def _register() -> None:
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID,
            entry_point="atc_nf_env.envs.centralized:EncounterEnv",
            vector_entry_point="atc_nf_env.envs.vector:EncounterVectorEnv",
        )
    if STREAM_ENV_ID not in gymnasium.registry:
        # Its vector form is Gymnasium's SyncVectorEnv (each stream world steps on its own).
        gymnasium.register(id=STREAM_ENV_ID, entry_point="atc_nf_env.envs.streams:StreamEnv",
                           kwargs={"scenario": "stream-30"})
    for retired in RETIRED_ENV_IDS:
        if retired not in gymnasium.registry:
            gymnasium.register(id=retired, entry_point="atc_nf_env.envs.retired:encounter_v0",
                               vector_entry_point="atc_nf_env.envs.retired:encounter_v0")


_register()

_LAZY = {
    "parallel_env": "atc_nf_env.envs.parallel",
    "env": "atc_nf_env.envs.parallel",
    "raw_env": "atc_nf_env.envs.parallel",
    "ATCParallelEnv": "atc_nf_env.envs.parallel",
    "EncounterEnv": "atc_nf_env.envs.centralized",
    "EncounterVectorEnv": "atc_nf_env.envs.vector",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'atc_nf_env' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


__all__ = ["ENV_ID", "RETIRED_ENV_IDS", "STREAM_ENV_ID", *_LAZY]
