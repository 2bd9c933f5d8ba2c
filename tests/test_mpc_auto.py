"""The default MCMC-MPC picks its search by the traffic it flies (``sampling="auto"``):
the paper's joint search on the paper's encounters, bit for bit, and the per-cluster
search with the progress rule in dense traffic and on streams."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from atc_nf_env.episode import run_episode
from atc_nf_env.scenarios import make_scenario
from baselines.mcmc_mpc import DENSE_TRAFFIC_SETTINGS, JOINT_SEARCH_MAX_AIRCRAFT, MCMCMPC, NAMED_SETTINGS, MPCSettings


@pytest.mark.parametrize("name", ["converging-4", "converging-6", "random-4", "random-6", "converging-3"])
def test_the_paper_s_encounters_are_searched_jointly(name):
    scenario = make_scenario(name, seed=11)
    resolved = MPCSettings().for_traffic(scenario)
    assert resolved == dataclasses.replace(MPCSettings(), sampling="joint")


@pytest.mark.parametrize("name", ["converging-7", "random-8", "converging-16", "random-16", "stream-30", "stream-2.5-60min"])
def test_dense_traffic_and_streams_fly_the_per_cluster_search_with_the_progress_rule(name):
    scenario = make_scenario(name, seed=11)
    assert scenario.n_aircraft > JOINT_SEARCH_MAX_AIRCRAFT or name.startswith("stream")
    resolved = MPCSettings().for_traffic(scenario)
    assert resolved == MPCSettings(**DENSE_TRAFFIC_SETTINGS)
    assert resolved == MPCSettings(**NAMED_SETTINGS["per-cluster"])


def test_auto_keeps_what_was_given_and_what_needs_the_joint_search():
    dense = make_scenario("random-16", seed=2)
    assert MPCSettings(progress_fraction=0.3, progress_periods=4).for_traffic(dense) == MPCSettings(
        sampling="per-cluster", progress_fraction=0.3, progress_periods=4)
    assert MPCSettings(extractions=300).for_traffic(dense).extractions == 300
    # Table I as printed, and the paper's check at the sampling instants: joint only.
    assert MPCSettings(proposal="paper").for_traffic(dense).sampling == "joint"
    assert MPCSettings(constraint_check="sampling-instants").for_traffic(dense).sampling == "joint"
    for sampling in ("joint", "clusters", "per-cluster"):
        given = MPCSettings(sampling=sampling)
        assert given.for_traffic(dense) is given
    with pytest.raises(ValueError, match="proposal='homing'"):
        MPCSettings(proposal="paper", sampling="per-cluster")
    with pytest.raises(ValueError, match="allowed: auto, joint, clusters, per-cluster"):
        MPCSettings(sampling="automatic")


def test_the_controller_flies_what_the_traffic_asks_and_keeps_what_was_requested():
    mpc = MCMCMPC()
    from atc_nf_env.config import SimConfig

    mpc.reset(make_scenario("random-12", seed=4), SimConfig(), 4)
    assert mpc.settings.sampling == "per-cluster" and mpc.requested_settings.sampling == "auto"
    mpc.reset(make_scenario("converging-4"), SimConfig(), 4)
    assert mpc.settings.sampling == "joint" and mpc.settings.progress_fraction is None


def _flown(policy, scenario, seed, **kwargs):
    result = run_episode(policy, scenario, seed=seed, **kwargs)
    return result.waypoints, result.metrics.flight_time_min, result.metrics.worst_excursion_kt


def test_the_default_flies_the_joint_search_bit_for_bit_on_the_paper_s_encounters():
    for name, seed in (("converging-4", 2_000_000_101), ("random-6", 2_000_000_102)):
        default = _flown(MCMCMPC(), name, seed)
        joint = _flown(MCMCMPC(sampling="joint"), name, seed)
        assert np.array_equal(default[0], joint[0]) and default[1:] == joint[1:]


def test_the_default_flies_the_per_cluster_setting_bit_for_bit_in_dense_traffic():
    default = _flown(MCMCMPC(), "random-12", 2_000_000_103, max_time_s=1500.0)
    named = _flown(MCMCMPC(**NAMED_SETTINGS["per-cluster"]), "random-12", 2_000_000_103, max_time_s=1500.0)
    joint = _flown(MCMCMPC(sampling="joint"), "random-12", 2_000_000_103, max_time_s=1500.0)
    assert np.array_equal(default[0], named[0]) and default[1:] == named[1:]
    assert not np.array_equal(default[0], joint[0]), "the two searches differ on this seed"
