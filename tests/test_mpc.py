"""The MCMC-MPC: the chain, the candidates, and closed-loop safety under wind."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import R_AIRSPEED, R_FLEW
from atc_nf_env.scenarios import converging
from atc_nf_env.simulation import Simulation
from baselines import MCMCMPC, MPCSettings
from baselines.mcmc_mpc import metropolis_hastings_best


def test_chain_samples_its_target_in_a_case_with_known_answer():
    """Three candidates, each proposed with probability ∝ g: the chain's states must be
    distributed as the target ∝ C^-J (independence sampler), whatever g is."""
    rng = np.random.default_rng(0)
    values = np.array([1.0, 2.0, 4.0])  # costs
    g = np.array([0.6, 0.3, 0.1])  # proposal probabilities
    n = 200_000
    picks = rng.choice(3, size=n, p=g)
    costs = values[picks]
    _, _, states = metropolis_hastings_best(costs, np.log(g[picks]), rng.random(n), cost_exponent=1.0)
    visited = values[picks[states]]
    frequencies = np.array([(visited == v).mean() for v in values])
    target = (1 / values) / (1 / values).sum()
    np.testing.assert_allclose(frequencies, target, atol=0.01)
    # J = 2 sharpens the target.
    _, _, states2 = metropolis_hastings_best(costs, np.log(g[picks]), rng.random(n), cost_exponent=2.0)
    visited2 = values[picks[states2]]
    target2 = (1 / values**2) / (1 / values**2).sum()
    np.testing.assert_allclose([(visited2 == v).mean() for v in values], target2, atol=0.01)


def test_table_i_acceptance_as_printed_does_not_sample_the_target():
    rng = np.random.default_rng(1)
    values = np.array([1.0, 2.0, 4.0])
    g = np.array([0.6, 0.3, 0.1])
    n = 200_000
    picks = rng.choice(3, size=n, p=g)
    _, _, states = metropolis_hastings_best(
        values[picks], np.log(g[picks]), rng.random(n), cost_exponent=1.0, acceptance="table-i"
    )
    visited = values[picks[states]]
    target = (1 / values) / (1 / values).sum()
    frequencies = np.array([(visited == v).mean() for v in values])
    assert np.abs(frequencies - target).max() > 0.05


def test_chain_returns_the_best_state_it_visited_and_skips_infeasible():
    costs = np.array([np.inf, 5.0, np.inf, 3.0, 4.0])
    log_g = np.zeros(5)
    best, _, states = metropolis_hastings_best(costs, log_g, np.zeros(5))  # u = 0: always accept
    assert best == 3
    assert list(states) == [0, 1, 1, 3, 4]


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_mpc_flies_the_four_aircraft_encounter_under_wind_safely(seed):
    policy = MCMCMPC(extractions=250)
    result = run_episode(policy, converging(4), seed=seed, wind_sigma_mps=5.17, record_every=1)
    m = result.metrics
    assert all(m.arrived), m.flight_time_min
    assert m.los_count == 0
    assert m.min_separation_nm is not None and m.min_separation_nm >= 5.0
    # The envelope holds at every integration step of the real (windy) flight.
    assert m.envelope_violation_fraction == 0.0
    flew = result.records[..., R_FLEW] > 0
    speeds = result.records[..., R_AIRSPEED][flew]
    assert speeds.min() >= 366.0 and speeds.max() <= 540.0
    assert policy.episode_info()["fallbacks"] == 0


def test_mpc_is_reproducible():
    a = run_episode(MCMCMPC(extractions=100), converging(3), seed=5, wind_sigma_mps=5.17, record_every=5)
    b = run_episode(MCMCMPC(extractions=100), converging(3), seed=5, wind_sigma_mps=5.17, record_every=5)
    assert np.array_equal(a.records, b.records)
    assert np.array_equal(a.waypoints, b.waypoints)


def test_candidates_follow_the_proposal():
    scenario = converging(4)
    sim = Simulation(scenario)
    policy = MCMCMPC(extractions=4000)
    policy.reset(scenario, SimConfig(), seed=0)
    view = sim.view()
    proposals, _ = policy._propose(view)
    offset = proposals - view.positions[None]
    distance = np.hypot(offset[..., 0], offset[..., 1])
    to_dest = view.destinations - view.positions
    relative = np.arctan2(offset[..., 1], offset[..., 0]) - np.arctan2(to_dest[:, 1], to_dest[:, 0])
    relative = (relative + math.pi) % (2 * math.pi) - math.pi
    assert abs(distance.mean() - 100.0) < 0.5 and abs(distance.std() - 10.0) < 0.5
    assert relative.min() >= -math.pi / 2 - 1e-9 and relative.max() <= math.pi / 2 + 1e-9
    assert abs(relative.mean()) < 0.05


def test_no_feasible_candidate_takes_the_counted_fallback():
    # A 1-knot-wide envelope no candidate can hold.
    config = SimConfig(airspeed_min_kt=460.0, airspeed_max_kt=461.0)
    policy = MCMCMPC(extractions=50)
    result = run_episode(policy, converging(3), config=config, seed=0, max_time_s=900.0)
    info = policy.episode_info()
    assert info["fallbacks"] == info["decisions"] == result.metrics.decisions == 3
    assert info["feasible_fraction"]["mean"] == 0.0


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"extractions": 0}, "extractions"),
        ({"horizon": 0}, "horizon"),
        ({"wind_sigma_mps": -1.0}, "wind_sigma_mps"),
        ({"wind_model": "oracle"}, "wind_model"),
        ({"acceptance": "greedy"}, "acceptance"),
        ({"not_a_setting": 1}, "not_a_setting"),
    ],
)
def test_bad_mpc_settings_are_clear_errors(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MCMCMPC(**kwargs)


def test_settings_default_to_the_paper():
    s = MPCSettings()
    assert (s.period_s, s.horizon, s.extractions) == (300.0, 4, 1000)
    assert (s.distance_mean_nm, s.distance_std_nm, s.angle_range_rad) == (100.0, 10.0, math.pi / 2)
