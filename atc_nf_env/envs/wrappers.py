"""Wrappers for learning libraries that take only flat action vectors.

``atc_nf_env/Encounter-v1`` takes one (distance, angle) pair per aircraft slot, a Box of
shape (M, 2). Single-agent learners whose models emit one flat vector (RLlib's PPO,
for one) need a Box of shape (2M,): ``FlattenActions`` is that view, nothing else.
Gymnasium ships no action-flattening wrapper for Box spaces, hence this one.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class FlattenActions(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """A flat Box(2M,) action space over an env whose action space is Box(M, 2).

    The flat vector is the (M, 2) action in row-major order: ``[d_0, a_0, d_1, a_1, ...]``
    for aircraft slots 0, 1, ... (each in [-1, 1], mapped to a waypoint as in the wrapped
    env). ``env`` must have a Box action space of shape (M, 2) with M ≥ 1.

        env = FlattenActions(gym.make("atc_nf_env/Encounter-v1", scenario="converging-4"))
        env.action_space     # Box(-1.0, 1.0, (8,), float32)
    """

    def __init__(self, env: gym.Env) -> None:
        space = env.action_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 2 or space.shape[1] != 2 or space.shape[0] < 1:
            raise ValueError(
                f"FlattenActions wraps an env whose action space is a Box of shape (M, 2), M >= 1; got {space}"
            )
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.ActionWrapper.__init__(self, env)
        self._shape = space.shape
        self.action_space = spaces.Box(space.low.reshape(-1), space.high.reshape(-1), dtype=space.dtype)

    def action(self, action: Any) -> np.ndarray:
        array = np.asarray(action)
        if array.shape != self.action_space.shape:
            raise ValueError(
                f"FlattenActions: the action must have shape {self.action_space.shape} (2 values per aircraft "
                f"slot, slot by slot); got shape {array.shape}"
            )
        return array.reshape(self._shape)


__all__ = ["FlattenActions"]
