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

``numpy_deepsets_forward`` computes the same deterministic action with NumPy (the
``SB3AgentPolicy`` fast path; ``tests/test_deepsets.py`` checks it against SB3's
``predict``).
"""

from __future__ import annotations

from typing import Any, Callable

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


def _layers(sequential: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(W^T, b)] of an nn.Sequential of Linear + Tanh pairs."""
    out = []
    for module in sequential:
        if isinstance(module, nn.Linear):
            out.append((np.ascontiguousarray(module.weight.detach().numpy().astype(np.float32).T),
                        module.bias.detach().numpy().astype(np.float32).copy()))
        elif not isinstance(module, nn.Tanh):
            raise TypeError(f"unexpected module {type(module).__name__}")
    return out


def numpy_deepsets_features(extractor: Any) -> Callable[[np.ndarray], np.ndarray]:
    """obs (B, D) float32 -> the extractor's features (B, 3·hidden), with NumPy."""
    own_layers = _layers(extractor.own)
    phi_layers = _layers(extractor.phi)
    k = extractor.n_slots

    def tanh_mlp(x: np.ndarray, layers: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        for weight, bias in layers:
            x = x @ weight
            x += bias
            np.tanh(x, out=x)
        return x

    def features(obs: np.ndarray) -> np.ndarray:
        b = obs.shape[0]
        own = tanh_mlp(obs[:, :N_OWN], own_layers)
        slots = obs[:, N_OWN:].reshape(b, k, N_NEIGHBOUR)
        mask = slots[:, :, :1]
        encoded = tanh_mlp(slots[:, :, 1:].reshape(b * k, N_NEIGHBOUR - 1), phi_layers).reshape(b, k, -1)
        encoded *= mask
        count = mask.sum(axis=1)
        mean = encoded.sum(axis=1) / np.maximum(count, 1.0)
        largest = np.where(mask > 0, encoded, np.float32(-2.0)).max(axis=1)
        largest = np.where(count > 0, largest, np.float32(0.0))
        return np.concatenate([own, mean, largest], axis=1).astype(np.float32, copy=False)

    return features


def policy_kwargs(hidden: int, net_arch: list[int], log_std_init: float) -> dict[str, Any]:
    """PPO ``policy_kwargs`` of a deep-sets actor-critic (actor and critic share the extractor)."""
    return {"features_extractor_class": NeighbourSetExtractor,
            "features_extractor_kwargs": {"hidden": hidden}, "share_features_extractor": True,
            "net_arch": {"pi": net_arch, "vf": net_arch}, "log_std_init": log_std_init}


__all__ = ["NeighbourSetExtractor", "numpy_deepsets_features", "policy_kwargs"]
