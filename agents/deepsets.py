"""A policy over any number of aircraft: a permutation-invariant features extractor.

The ego observation (``atc_nf_env.envs.observations``) is the aircraft's own 8 features
followed by K neighbour slots of 5 values each (mask, forward, left, vel_forward,
vel_left), nearest first, zeros where fewer than K other aircraft fly. An MLP on that
vector depends on the slot order and on K. ``NeighbourSetExtractor`` reads the slots as a
*set* (deep sets, Zaheer et al., "Deep Sets", NeurIPS 2017, as MARL work on variable team
sizes uses them): each present neighbour goes through one shared encoder φ; the encodings
are pooled over the present neighbours by a masked mean and a masked max; the pooled
vectors are concatenated with an encoding of the own features. The result does not
change when neighbour slots are permuted, and it has the same size for any number of
neighbours, so a model trained with 2..9 neighbours flies 15 without a new network.
With K = 15 slots it sees every other aircraft of a 16-aircraft encounter; beyond K + 1
aircraft it sees the K nearest.

``agents.compiled_forward.deepsets_actions`` computes the same deterministic action in
one compiled call (the ``SB3AgentPolicy`` fast path; ``tests/test_agents_any_n.py``
checks it against SB3's ``predict``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn as nn
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from atc_nf_env.envs.observations import NEIGHBOUR_FEATURES, OWN_FEATURES

N_OWN = len(OWN_FEATURES)
N_NEIGHBOUR = len(NEIGHBOUR_FEATURES)


class NeighbourSetExtractor(BaseFeaturesExtractor):
    """Features [own encoding, masked mean of φ(neighbours), masked max of φ(neighbours)].

    Args:
        observation_space: the ego observation's Box (8 + 5·K values, no wind).
        hidden: width of the own encoder and of φ (two tanh layers each).
    """

    def __init__(self, observation_space: Any, hidden: int = 64) -> None:
        dim = int(np.prod(observation_space.shape))
        if dim < N_OWN or (dim - N_OWN) % N_NEIGHBOUR:
            raise ValueError(f"observation size {dim}: expected {N_OWN} + {N_NEIGHBOUR}·K values (no wind)")
        if isinstance(hidden, bool) or not isinstance(hidden, int) or hidden < 1:
            raise ValueError(f"hidden = {hidden!r}: must be an integer >= 1")
        super().__init__(observation_space, features_dim=3 * hidden)
        self.n_slots = (dim - N_OWN) // N_NEIGHBOUR
        self.hidden = hidden
        self.own = nn.Sequential(nn.Linear(N_OWN, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh())
        self.phi = nn.Sequential(nn.Linear(N_NEIGHBOUR - 1, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        own = self.own(obs[:, :N_OWN])
        slots = obs[:, N_OWN:].reshape(obs.shape[0], self.n_slots, N_NEIGHBOUR)
        mask = slots[:, :, :1]  # (B, K, 1): 1 where a neighbour is present
        encoded = self.phi(slots[:, :, 1:]) * mask
        count = mask.sum(dim=1)
        mean = encoded.sum(dim=1) / count.clamp(min=1.0)
        # tanh > -1, so -2 never wins the max; no neighbour at all gives zeros.
        largest = torch.where(mask > 0, encoded, torch.full_like(encoded, -2.0)).amax(dim=1)
        largest = torch.where(count > 0, largest, torch.zeros_like(largest))
        return torch.cat([own, mean, largest], dim=1)


def policy_kwargs(hidden: int, net_arch: list[int], log_std_init: float) -> dict[str, Any]:
    """PPO ``policy_kwargs`` of a deep-sets actor-critic (actor and critic share the extractor)."""
    return {"features_extractor_class": NeighbourSetExtractor,
            "features_extractor_kwargs": {"hidden": hidden}, "share_features_extractor": True,
            "net_arch": {"pi": net_arch, "vf": net_arch}, "log_std_init": log_std_init}


__all__ = ["NeighbourSetExtractor", "policy_kwargs"]
