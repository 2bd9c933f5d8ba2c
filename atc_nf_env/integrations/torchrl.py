"""TorchRL: the PettingZoo env in ``PettingZooWrapper`` with the settings it needs.

    from atc_nf_env.integrations.torchrl import make_torchrl_env
    env = make_torchrl_env(scenario="converging-4")
    rollout = env.rollout(40)          # group "aircraft": observation, mask, info, ...

Aircraft leave the episode when they arrive, so TorchRL needs ``use_mask=True`` (the
group's ``mask`` says which are still flying), and ``done_on_any=False`` (its default
for parallel envs resets the whole encounter as soon as the first aircraft arrives).
The centralized env needs nothing: ``torchrl.envs.GymEnv("atc_nf_env/Encounter-v0")``.
"""

from __future__ import annotations

from typing import Any


def make_torchrl_env(
    *, parallel: bool = True, return_state: bool = False, seed: int | None = None, device: Any = None, **kwargs: Any
) -> Any:
    """``torchrl.envs.PettingZooWrapper`` over ``atc_nf_env.parallel_env(**kwargs)``
    (or the AEC ``atc_nf_env.env`` with ``parallel=False``), with ``use_mask=True`` and
    ``done_on_any=False``. ``return_state`` adds the global state (``state()``) as
    ``"state"`` for centralized critics (MAPPO); ``seed`` seeds the first reset."""
    from torchrl.envs import PettingZooWrapper

    from atc_nf_env.envs.parallel import env, parallel_env

    base = parallel_env(**kwargs) if parallel else env(**kwargs)
    extra = {} if device is None else {"device": device}
    return PettingZooWrapper(
        base, use_mask=True, done_on_any=False, return_state=return_state, seed=seed, **extra
    )


__all__ = ["make_torchrl_env"]
