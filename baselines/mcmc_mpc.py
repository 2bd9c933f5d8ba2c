"""The paper's MCMC model-predictive controller (section III, Table I; section IV-C/D).

Every T = 5 min the controller chooses one intermediate waypoint per aircraft:

1. K joint proposals Θ_k are drawn from g: for every flying aircraft, a distance
   ~ N(100 nm, 10 nm) and an angle ~ U[−π/2, π/2] around the line from the aircraft to
   its destination (IV-C).
2. All K candidates are simulated at once, in one batch of the simulator kernel (the
   oracle O of Table I is the kernel started from a copy of the state), over the
   horizon N·T. Only the first waypoint is optimized: at each later period of the
   horizon every aircraft's waypoint is shifted forward by the distance that aircraft
   covered in the period before (IV-C).
3. A candidate is infeasible, with infinite cost, if any aircraft's airspeed leaves
   [366, 540] kt or two aircraft come closer than 5 nm anywhere in the horizon: checked
   at every integration step by default (a world stops being simulated at its first
   violation), or only at the sampling instants t + pT as the paper states
   (``constraint_check="sampling-instants"``). The cost of a feasible candidate is
   L = Σ_i D(i, t + NT), the aircraft's remaining distances to their destinations at
   the horizon's end (6), nm.
4. A Metropolis-Hastings chain runs over the K candidates in their drawing order. The
   proposals do not depend on the chain's state, so simulating them first and running
   the chain afterwards is the sequential algorithm of Table I, identical in
   distribution. The target is π(Θ) ∝ C(Θ)^−J (J = ``cost_exponent``, 1 by default) and
   the acceptance is the standard independence sampler's

       ρ = min{1, (C_{k−1} / C̃)^J · g(Θ_{k−1}) / g(Θ̃)}.

   Table I prints the proposal ratio the other way up, g(Θ̃) / g(Θ_{k−1}), which does
   not leave π invariant; ``acceptance="table-i"`` reproduces the printed form.
5. The candidate of lowest cost among the chain's states is applied (Table I's last
   step).

The controller never sees the true wind. Its prediction wind model is configurable:
``"none"`` (still air), ``"sampled"`` (each candidate predicted under its own wind drawn
from N(0, σ²) per component) or ``"estimated"`` (a constant wind estimated from the
observed drift: after each period the difference between where the aircraft are and
where the controller predicted the applied candidate would put them, divided by T,
corrects the estimate).

Fallback: when no candidate is feasible, the controller applies the candidate that
stayed feasible longest (the most integration steps, or sampling instants, before its
first violation; ties broken by the distance cost) and counts the decision as a
fallback. ``episode_info()`` reports the fallbacks and the feasible fraction of every
decision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import (
    ABSENT,
    ARRIVED,
    FLYING,
    S_AIRSPEED,
    S_DEST_X,
    S_DEST_Y,
    S_STATUS,
    S_X,
    S_Y,
)
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView
from atc_nf_env.units import DECISION_PERIOD_S, KT_PER_MPS, SECONDS_PER_HOUR, WIND_SIGMA_MPS

WIND_MODELS = ("none", "sampled", "estimated")
CONSTRAINT_CHECKS = ("every-step", "sampling-instants")
ACCEPTANCES = ("standard", "table-i")

#: Costs are floored here (nm) so that a candidate that brings everyone home (cost 0)
#: still has a finite log-cost in the chain.
_COST_FLOOR_NM = 1e-9


@dataclass(frozen=True)
class MPCSettings:
    """Settings of the MCMC-MPC; the defaults are the paper's (Table I, section IV).

    Attributes:
        period_s: T, the sampling period, s.
        horizon: N, the number of periods in the prediction horizon.
        extractions: K, the number of proposals (and the chain's length) per decision.
        distance_mean_nm, distance_std_nm: the proposal's waypoint distance, nm.
        angle_range_rad: the proposal's angle is uniform in ±this around the line to
            the destination, rad.
        cost_exponent: J, the target is ∝ C^−J.
        acceptance: "standard" (independence sampler) or "table-i" (as printed).
        constraint_check: "every-step" or "sampling-instants".
        wind_model: "none", "sampled" or "estimated".
        wind_sigma_mps: σ of the "sampled" wind model, m/s.
    """

    period_s: float = DECISION_PERIOD_S
    horizon: int = 4
    extractions: int = 1000
    distance_mean_nm: float = 100.0
    distance_std_nm: float = 10.0
    angle_range_rad: float = math.pi / 2
    cost_exponent: float = 1.0
    acceptance: str = "standard"
    constraint_check: str = "every-step"
    wind_model: str = "estimated"
    wind_sigma_mps: float = WIND_SIGMA_MPS

    def __post_init__(self) -> None:
        if not isinstance(self.extractions, (int, np.integer)) or self.extractions < 1:
            raise ValueError(f"extractions (K) = {self.extractions!r}: must be an integer >= 1")
        if not isinstance(self.horizon, (int, np.integer)) or self.horizon < 1:
            raise ValueError(f"horizon (N) = {self.horizon!r}: must be an integer >= 1")
        for name in ("period_s", "distance_mean_nm", "distance_std_nm", "angle_range_rad", "cost_exponent"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a finite number > 0")
        if not (math.isfinite(self.wind_sigma_mps) and self.wind_sigma_mps >= 0):
            raise ValueError(f"wind_sigma_mps = {self.wind_sigma_mps!r}: must be a finite number >= 0")
        for name, allowed in (
            ("acceptance", ACCEPTANCES),
            ("constraint_check", CONSTRAINT_CHECKS),
            ("wind_model", WIND_MODELS),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} = {getattr(self, name)!r}: allowed: {', '.join(allowed)}")


@dataclass
class DecisionRecord:
    """What one decision saw: the feasible fraction of the K candidates, and whether
    the fallback was taken."""

    time_s: float
    feasible_fraction: float
    fallback: bool
    cost_nm: float
    chain_acceptance: float


def metropolis_hastings_best(
    costs: np.ndarray,
    log_proposal: np.ndarray,
    uniforms: np.ndarray,
    cost_exponent: float = 1.0,
    acceptance: str = "standard",
) -> tuple[int, int, np.ndarray]:
    """Run the independence-sampler chain over candidates in order.

    Args:
        costs: (K,) costs C_k (np.inf for infeasible).
        log_proposal: (K,) log g(Θ_k) up to a constant.
        uniforms: (K,) uniform draws in [0, 1) deciding the acceptances (index 0 unused).
        cost_exponent: J of the target ∝ C^−J.
        acceptance: "standard" or "table-i" (the proposal ratio as printed in Table I).

    Returns:
        (index of the lowest-cost state the chain visited, number of accepted moves,
        the chain's states (K,) as candidate indices).
    """
    n = costs.shape[0]
    states = np.empty(n, dtype=np.int64)
    current = 0
    states[0] = 0
    best = 0
    accepted = 0
    sign = 1.0 if acceptance == "standard" else -1.0
    log_cost = np.log(np.maximum(costs, _COST_FLOOR_NM))
    for k in range(1, n):
        if np.isinf(costs[k]):
            move = np.isinf(costs[current])  # between two infeasible states: no preference
        elif np.isinf(costs[current]):
            move = True
        else:
            log_rho = cost_exponent * (log_cost[current] - log_cost[k]) + sign * (
                log_proposal[current] - log_proposal[k]
            )
            move = log_rho >= 0.0 or math.log(max(uniforms[k], 1e-300)) < log_rho
        if move:
            current = k
            accepted += 1
            if costs[current] < costs[best] or np.isinf(costs[best]):
                best = current
        states[k] = current
    return best, accepted, states


class MCMCMPC:
    """The paper's MCMC-MPC as a policy of the ``atc_nf_env.policy.Policy`` interface.

    Args:
        settings: ``MPCSettings`` (the paper's by default); keyword arguments override
            single fields, e.g. ``MCMCMPC(extractions=200, wind_model="estimated")``.
    """

    name = "mpc"

    def __init__(self, settings: MPCSettings | None = None, **overrides: Any) -> None:
        base = settings or MPCSettings()
        if overrides:
            allowed = set(MPCSettings.__dataclass_fields__)
            unknown = set(overrides) - allowed
            if unknown:
                raise ValueError(f"unknown MPC settings {sorted(unknown)}; allowed: {sorted(allowed)}")
            base = MPCSettings(**{**base.__dict__, **overrides})
        self.settings = base
        self.decisions: list[DecisionRecord] = []
        self._rng = np.random.default_rng(0)
        self._scratch = kernel.KernelScratch()
        self._params: np.ndarray | None = None
        self._check_params: np.ndarray | None = None
        self._wind_estimate_kt = np.zeros(2)
        self._predicted_positions: np.ndarray | None = None
        self._predicted_time_s = -1.0

    # -- Policy interface -------------------------------------------------------------
    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Seed the controller and prepare its prediction model for ``scenario``."""
        if config.dt_s <= 0 or kernel.steps_for(self.settings.period_s, config.dt_s) < 1:
            raise ValueError(f"period_s = {self.settings.period_s}: must be >= one integration step")
        self._rng = np.random.default_rng([0 if seed is None else seed, 0x4D5043])
        stop = self.settings.constraint_check == "every-step"
        self._params = config.to_params(scenario.workspace_radius_nm, stop_on_violation=stop)
        self._config = config
        self._workspace_radius_nm = scenario.workspace_radius_nm
        self.decisions = []
        self._wind_estimate_kt = np.zeros(2)
        self._predicted_positions = None
        self._predicted_time_s = -1.0

    def act(self, view: WorldView) -> np.ndarray:
        """The waypoints (N, 2), nm, of the lowest-cost candidate in the chain."""
        if self._params is None:
            raise RuntimeError("call reset(scenario, config, seed) before act()")
        s = self.settings
        self._update_wind_estimate(view)
        flying = view.flying
        proposals, log_g = self._propose(view)
        costs, survived, after_first = self._simulate(view.state, proposals)
        feasible = np.isfinite(costs)
        uniforms = self._rng.random(s.extractions)
        if feasible.any():
            best, accepted, _ = metropolis_hastings_best(
                costs, log_g, uniforms, s.cost_exponent, s.acceptance
            )
            fallback = False
        else:
            accepted = 0
            distance = self._remaining_distance_of(proposals, view)
            best = int(np.lexsort((distance, -survived))[0])
            fallback = True
        self.decisions.append(
            DecisionRecord(
                time_s=view.time_s,
                feasible_fraction=float(feasible.mean()),
                fallback=fallback,
                cost_nm=float(costs[best]) if feasible.any() else math.inf,
                chain_acceptance=accepted / max(s.extractions - 1, 1),
            )
        )
        waypoints = view.waypoints.copy()
        waypoints[flying] = proposals[best, flying]
        self._predicted_positions = after_first[best].copy()
        self._predicted_time_s = view.time_s + s.period_s
        return waypoints

    def episode_info(self) -> dict[str, Any]:
        """Diagnostics of the episode so far (for reports and the evaluator)."""
        fractions = [d.feasible_fraction for d in self.decisions]
        return {
            "decisions": len(self.decisions),
            "fallbacks": int(sum(d.fallback for d in self.decisions)),
            "feasible_fraction": {
                "min": float(min(fractions)) if fractions else None,
                "mean": float(np.mean(fractions)) if fractions else None,
            },
            "chain_acceptance_mean": float(np.mean([d.chain_acceptance for d in self.decisions]))
            if self.decisions
            else None,
            "wind_estimate_kt": [float(w) for w in self._wind_estimate_kt],
        }

    # -- internals ----------------------------------------------------------------------
    def _propose(self, view: WorldView) -> tuple[np.ndarray, np.ndarray]:
        """K joint proposals (K, N, 2) nm and their log-densities log g (K,) up to a constant."""
        s = self.settings
        n = view.state.shape[0]
        distance = self._rng.normal(s.distance_mean_nm, s.distance_std_nm, (s.extractions, n))
        angle = self._rng.uniform(-s.angle_range_rad, s.angle_range_rad, (s.extractions, n))
        to_dest = view.destinations - view.positions
        bearing = np.arctan2(to_dest[:, 1], to_dest[:, 0])
        direction = bearing[None, :] + angle
        proposals = view.positions[None] + distance[..., None] * np.stack(
            [np.cos(direction), np.sin(direction)], axis=-1
        )
        # A waypoint must stay inside the workspace: pull it toward the centre if needed.
        limit = 0.99 * (self._workspace_radius_nm - self._config.aircraft_radius_nm)
        radius = np.hypot(proposals[..., 0], proposals[..., 1])
        scale = np.minimum(1.0, limit / np.maximum(radius, 1e-12))
        proposals *= scale[..., None]
        flying = view.flying
        z = (distance - s.distance_mean_nm) / s.distance_std_nm
        log_g = -0.5 * (z[:, flying] ** 2).sum(axis=1)
        return proposals, log_g

    def _prediction_wind(self) -> np.ndarray:
        s = self.settings
        k = s.extractions
        if s.wind_model == "sampled":
            return self._rng.normal(0.0, s.wind_sigma_mps, (k, 2)) * KT_PER_MPS
        if s.wind_model == "estimated":
            return np.repeat(self._wind_estimate_kt[None], k, axis=0)
        return np.zeros((k, 2))

    def _simulate(self, base_state: np.ndarray, proposals: np.ndarray):
        """Costs (K,), survival (K,) and positions after the first period (K, N, 2)."""
        s = self.settings
        assert self._params is not None
        states = np.repeat(base_state[None], s.extractions, axis=0)
        waypoints = proposals.copy()
        flying0 = base_state[:, S_STATUS] == FLYING
        waypoints[:, ~flying0] = base_state[None, ~flying0, kernel.S_WP_X : kernel.S_WP_Y + 1]
        wind = self._prediction_wind()
        feasible = np.ones(s.extractions, dtype=bool)
        survived = np.zeros(s.extractions, dtype=np.int64)
        after_first = None
        every_step = s.constraint_check == "every-step"
        sep2 = self._config.separation_min_nm**2
        for period in range(s.horizon):
            before = states[:, :, S_X : S_Y + 1].copy()
            trace = kernel.advance(states, waypoints, wind, s.period_s, self._params, scratch=self._scratch)
            if every_step:
                survived += np.where(feasible, trace.steps_done, 0)
                newly_bad = trace.violated & feasible
            else:
                flying = states[:, :, S_STATUS] == FLYING
                airspeed = states[:, :, S_AIRSPEED]
                outside = flying & (
                    (airspeed < self._config.airspeed_min_kt) | (airspeed > self._config.airspeed_max_kt)
                )
                pos = states[:, :, S_X : S_Y + 1]
                diff = pos[:, :, None, :] - pos[:, None, :, :]
                close = (diff**2).sum(-1) < sep2
                pair_flying = flying[:, :, None] & flying[:, None, :]
                np.einsum("kii->ki", close)[:] = False
                newly_bad = feasible & (outside.any(axis=1) | (close & pair_flying).any(axis=(1, 2)))
                survived += feasible & ~newly_bad
            feasible &= ~newly_bad
            # A world that violated is infeasible already: stop simulating it.
            states[newly_bad, :, S_STATUS] = np.where(
                states[newly_bad, :, S_STATUS] == FLYING, ABSENT, states[newly_bad, :, S_STATUS]
            )
            if after_first is None:
                after_first = states[:, :, S_X : S_Y + 1].copy()
            waypoints = waypoints + (states[:, :, S_X : S_Y + 1] - before)
        costs = np.where(feasible, self._remaining_distance(states), np.inf)
        return costs, survived, after_first

    @staticmethod
    def _remaining_distance(states: np.ndarray) -> np.ndarray:
        """Σ_i D(i): remaining distance to destination (0 once arrived), nm, per world."""
        delta = states[:, :, S_X : S_Y + 1] - states[:, :, S_DEST_X : S_DEST_Y + 1]
        distance = np.hypot(delta[..., 0], delta[..., 1])
        present = (states[:, :, S_STATUS] != ARRIVED) & (states[:, :, S_STATUS] != ABSENT)
        return np.where(present, distance, 0.0).sum(axis=1)

    @staticmethod
    def _remaining_distance_of(proposals: np.ndarray, view: WorldView) -> np.ndarray:
        """Fallback tie-break: how far the candidates' waypoints leave the aircraft from home."""
        delta = proposals - view.destinations[None]
        distance = np.hypot(delta[..., 0], delta[..., 1])
        return np.where(view.flying[None], distance, 0.0).sum(axis=1)

    def _update_wind_estimate(self, view: WorldView) -> None:
        if self.settings.wind_model != "estimated" or self._predicted_positions is None:
            return
        if not math.isclose(view.time_s, self._predicted_time_s, abs_tol=1e-6):
            return
        flying = view.flying
        if not flying.any():
            return
        error_nm = view.positions[flying] - self._predicted_positions[flying]
        self._wind_estimate_kt = self._wind_estimate_kt + error_nm.mean(axis=0) / (
            self.settings.period_s / SECONDS_PER_HOUR
        )
