"""The per-aircraft reward of one decision period (T = 300 s) and its weights.

Aircraft i's reward for the period from t to t + T::

    r_i = progress_per_100nm · (d_i(t) − d_i(t + T)) / 100 nm
          − envelope_violation · (steps outside the airspeed envelope / steps flown)
          − loss_of_separation · (number of other aircraft closer than 5 nm at some step)
          + arrival_bonus · [i arrived during the period]
          − left_workspace_penalty · [i left the workspace during the period]

d_i is the distance to go (nm) from the aircraft to its destination. The envelope and
separation terms are measured by the kernel at integration-step resolution (dt = 5 s):
``Trace.violation_steps / Trace.steps_flown`` and ``Trace.los_pairs``. A loss of
separation is charged to both aircraft of the pair, so the centralized env's summed
reward charges it twice. Aircraft that were no longer flying at the start of the
period get 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

import numpy as np

from numba import njit

from atc_nf_env.envs.coerce import coerce_settings
from atc_nf_env.kernel import ARRIVED, LEFT, S_DEST_X, S_DEST_Y, S_STATUS, S_X, S_Y, Trace
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the reward terms (all >= 0; see the module docstring).

    Attributes:
        progress_per_100nm: reward per 100 nm of distance to go flown off.
        envelope_violation: penalty for a period flown entirely outside the airspeed
            envelope [366, 540] kt (scaled by the fraction of integration steps outside).
        loss_of_separation: penalty per other aircraft that came within the separation
            minimum (5 nm) during the period.
        arrival_bonus: bonus on arrival (within Δ = ``SimConfig.arrival_tolerance_nm``
            of the destination).
        left_workspace_penalty: penalty on leaving the workspace (0 by default: leaving
            needs over 1000 nm flown away, which the progress term already punishes).
    """

    progress_per_100nm: float = 1.0
    envelope_violation: float = 1.0
    loss_of_separation: float = 5.0
    arrival_bonus: float = 5.0
    left_workspace_penalty: float = 0.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"RewardWeights.{field.name} = {value!r}: must be a finite number")
            if value < 0:
                raise ValueError(
                    f"RewardWeights.{field.name} = {value!r}: must be >= 0 (penalties are subtracted)"
                )

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def coerce(cls, value: "RewardWeights | Mapping[str, Any] | None") -> "RewardWeights":
        """A RewardWeights from itself, a dict of (some of) its fields, or None (the defaults)."""
        return coerce_settings(cls, value, "reward_weights")


@dataclass
class StepOutcome:
    """What one decision period did to every aircraft of B worlds (arrays (B, N)).

    Attributes:
        rewards: per-aircraft rewards (0 for aircraft not flying at the start).
        flew: the aircraft was flying at the start of the period.
        arrived_now, left_now: it arrived / left the workspace during the period.
        violation_fraction: fraction of its integration steps outside the envelope.
        los_count: other aircraft that came within the separation minimum.
        progress_nm: distance to go flown off, nm.
        distance_to_go_nm: distance to the destination at the end, nm.
    """

    rewards: np.ndarray
    flew: np.ndarray
    arrived_now: np.ndarray
    left_now: np.ndarray
    violation_fraction: np.ndarray
    los_count: np.ndarray
    progress_nm: np.ndarray
    distance_to_go_nm: np.ndarray


@njit(cache=True, error_model="numpy")
def aircraft_reward(weights: np.ndarray, progress_nm: float, violation_fraction: float, los_count: int,
                    arrived_now: bool, left_now: bool) -> float:
    """r_i of the module docstring: the one place of the formula, which the envs' compiled
    outcomes (``period_outcome``, the centralized env's period) call.

    Args:
        weights: ``reward_weight_vector(weights)``.
        progress_nm: d_i(t) − d_i(t + T), 0 for an aircraft that did not fly, nm.
        violation_fraction: steps outside the envelope / steps flown.
        los_count: other aircraft closer than the separation minimum at some step.
        arrived_now, left_now: it flew and arrived / left during the period.
    """
    return (
        weights[0] * progress_nm
        - weights[1] * violation_fraction
        - weights[2] * los_count
        + weights[3] * (1.0 if arrived_now else 0.0)
        - weights[4] * (1.0 if left_now else 0.0)
    )


@njit(cache=True, error_model="numpy")
def _period_outcome(
    state: np.ndarray,
    flying_before: np.ndarray,
    distance_before: np.ndarray,
    violation_steps: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    weights: np.ndarray,
    rewards: np.ndarray,
    arrived_now: np.ndarray,
    left_now: np.ndarray,
    fraction: np.ndarray,
    los_count: np.ndarray,
    progress: np.ndarray,
    distance_after: np.ndarray,
) -> None:
    n_worlds, n = flying_before.shape
    for b in range(n_worlds):
        for i in range(n):
            after = math.hypot(state[b, i, S_DEST_X] - state[b, i, S_X], state[b, i, S_DEST_Y] - state[b, i, S_Y])
            distance_after[b, i] = after
            flew = flying_before[b, i]
            status = state[b, i, S_STATUS]
            arrived = flew and status == ARRIVED
            left = flew and status == LEFT
            arrived_now[b, i] = arrived
            left_now[b, i] = left
            share = violation_steps[b, i] / max(steps_flown[b, i], 1)
            fraction[b, i] = share
            count = 0
            for j in range(n):
                count += los_pairs[b, i, j]
            los_count[b, i] = count
            gain = (distance_before[b, i] - after) * (1.0 if flew else 0.0)
            progress[b, i] = gain
            rewards[b, i] = aircraft_reward(weights, gain, share, count, arrived, left)


def period_outcome(
    state_after: np.ndarray,
    flying_before: np.ndarray,
    distance_before_nm: np.ndarray,
    trace: Trace,
    weights: np.ndarray,
) -> StepOutcome:
    """Rewards and per-aircraft outcome of one period of B worlds of N aircraft, from the
    kernel's state after it and its trace.

    Args:
        state_after: (B, N', N_STATE) kernel state at the end of the period, N' >= N.
        flying_before: (B, N) bool, flying at the start of the period.
        distance_before_nm: (B, N) distance to go at the start, nm.
        trace: the kernel's trace of the period.
        weights: ``reward_weight_vector(weights)``.
    """
    shape = flying_before.shape
    outcome = StepOutcome(
        rewards=np.empty(shape),
        flew=flying_before,
        arrived_now=np.empty(shape, dtype=np.bool_),
        left_now=np.empty(shape, dtype=np.bool_),
        violation_fraction=np.empty(shape),
        los_count=np.empty(shape, dtype=np.int64),
        progress_nm=np.empty(shape),
        distance_to_go_nm=np.empty(shape),
    )
    _period_outcome(
        state_after,
        flying_before,
        distance_before_nm,
        trace.violation_steps,
        trace.steps_flown,
        trace.los_pairs,
        weights,
        outcome.rewards,
        outcome.arrived_now,
        outcome.left_now,
        outcome.violation_fraction,
        outcome.los_count,
        outcome.progress_nm,
        outcome.distance_to_go_nm,
    )
    return outcome


def reward_weight_vector(weights: RewardWeights) -> np.ndarray:
    """The weights as ``period_outcome`` takes them: [progress per nm, envelope, loss of
    separation, arrival, left workspace]."""
    return np.array(
        [
            weights.progress_per_100nm / 100.0,
            weights.envelope_violation,
            weights.loss_of_separation,
            weights.arrival_bonus,
            weights.left_workspace_penalty,
        ]
    )


__all__ = ["RewardWeights", "StepOutcome", "aircraft_reward", "period_outcome", "reward_weight_vector"]
