"""The MCMC-MPC's settings for dense traffic: conflict clusters and the progress rule.

``sampling="clusters"``: when the chain's start breaks a constraint, a decision samples
only the conflict cluster around the aircraft involved; the others keep their start.
``progress_fraction``: an aircraft that stops closing on its destination is held on its
recovery waypoint (never a silent circle).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.scenarios import Scenario, converging
from atc_nf_env.kernel import ARRIVED, S_AIRSPEED, S_STATUS, S_TIME, S_X, S_Y
from atc_nf_env.simulation import Simulation, WorldView
from baselines import MCMCMPC, mcmc_mpc


def _circling() -> Scenario:
    """One aircraft 25 nm from its destination, heading 130° off the bearing to it."""
    return Scenario(name="circling", start_xy=[[25.0, 0.0]], start_heading=[math.pi + math.radians(130.0)],
                    dest_xy=[[0.0, 0.0]], dest_heading=[math.pi])


def _two_groups() -> Scenario:
    """Aircraft 0 and 1 head-on 120 nm apart; aircraft 2 and 3, 150 nm away, side by side
    30 nm apart on parallel tracks: only the first pair conflicts."""
    return Scenario(
        name="two-groups",
        start_xy=[[-60.0, 0.0], [60.0, 0.0], [0.0, 150.0], [30.0, 150.0]],
        start_heading=[0.0, math.pi, math.pi / 2, math.pi / 2],
        dest_xy=[[200.0, 0.0], [-200.0, 0.0], [0.0, 240.0], [30.0, 240.0]],
        dest_heading=[0.0, math.pi, math.pi / 2, math.pi / 2],
    )


def test_the_progress_rule_brings_home_an_aircraft_that_circles_its_destination():
    # Without the rule the chain keeps it circling 10-40 nm out (the cost rewards staying
    # close within the horizon): on this seed it is still flying after 3 h.
    plain = MCMCMPC(extractions=300)
    m = run_episode(plain, _circling(), seed=1, max_time_s=3 * 3600.0).metrics
    assert not m.arrived[0] and m.flight_time_min[0] == 180.0
    for seed in range(3):
        ruled = MCMCMPC(extractions=300, progress_fraction=0.5)
        m = run_episode(ruled, _circling(), seed=seed, max_time_s=3 * 3600.0).metrics
        assert m.arrived[0] and m.flight_time_min[0] < 60.0
        assert 366.0 <= m.airspeed_min_kt <= m.airspeed_max_kt <= 540.0 and m.los_count == 0
        info = ruled.episode_info()
        assert info["stalled_aircraft"] == 1 and info["recovery_decisions"] >= 1 and info["fallbacks"] == 0


def test_clusters_sample_only_the_conflict_and_keep_the_others_on_their_start():
    scenario = _two_groups()
    chosen = {}
    for sampling in ("joint", "clusters"):
        policy = MCMCMPC(extractions=300, sampling=sampling)
        policy.reset(scenario, SimConfig(), seed=0)
        view = Simulation(scenario).view()
        chosen[sampling] = (policy.act(view), policy.decisions[-1], policy._start_waypoints(view))
    waypoints, decision, start = chosen["clusters"]
    assert decision.cluster_size == 2 and not decision.fallback and decision.rounds == 1
    np.testing.assert_array_equal(waypoints[2:], start[2:])  # the pair without conflict flies its start
    assert not np.array_equal(waypoints[:2], start[:2])
    joint_waypoints, joint_decision, _ = chosen["joint"]
    assert joint_decision.cluster_size == 0 and not np.array_equal(joint_waypoints[2:], start[2:])
    # Sampling the conflict alone reaches a lower cost than sampling all four jointly.
    assert decision.cost_nm < joint_decision.cost_nm


def test_clusters_decide_as_the_joint_sampler_while_the_start_is_feasible():
    results = {}
    for sampling in ("joint", "clusters"):
        policy = MCMCMPC(extractions=300, sampling=sampling)
        results[sampling] = (policy, run_episode(policy, converging(4), seed=0))
    clusters = results["clusters"][0].decisions
    first = next((k for k, d in enumerate(clusters) if d.cluster_size > 0), len(clusters))
    assert first >= 1
    np.testing.assert_array_equal(results["joint"][1].waypoints[:first], results["clusters"][1].waypoints[:first])


def test_dense_settings_fly_the_same_episode_twice():
    settings = dict(extractions=200, sampling="clusters", progress_fraction=0.5, progress_periods=2)
    a, b = (run_episode(MCMCMPC(**settings), converging(6), seed=1, record_every=1) for _ in range(2))
    np.testing.assert_array_equal(a.records, b.records)
    np.testing.assert_array_equal(a.waypoints, b.waypoints)


@pytest.mark.slow  # half a minute; test_per_cluster_flies_a_traffic_stream flies a stream by default
def test_dense_settings_fly_a_traffic_stream():
    policy = MCMCMPC(extractions=50, sampling="clusters", progress_fraction=0.5, progress_periods=2)
    result = run_episode(policy, "stream-60-60min", seed=2)
    stream = result.metrics.stream
    assert stream is not None and stream["flights_entered"] > 3
    assert len(policy.decisions) == result.metrics.decisions


def test_the_progress_rule_judges_a_slot_only_over_a_window_its_flight_flew_whole():
    """An aircraft held by the rule is released when its slot takes a new flight (its time
    flown starts again), and the new flight is judged only once it has flown a window."""
    scenario = converging(3)
    policy = MCMCMPC(extractions=10, progress_fraction=0.5, progress_periods=2)
    policy.reset(scenario, SimConfig(), seed=0)
    view = Simulation(scenario).view()
    period = policy.settings.period_s
    state = view.state.copy()
    for k in range(3):  # nobody moves for two periods: every aircraft is held
        state[:, S_TIME] = k * period
        policy._update_progress(WorldView(time_s=k * period, state=state.copy(), scenario=scenario))
    assert policy._stalled.all() and policy._ever_stalled.all()
    # Slot 0 takes a new flight (its time flown starts again at 0): released, and not
    # judged over the two periods before it, although it does not move either.
    for k in range(3, 5):
        state[:, S_TIME] = k * period
        state[0, S_TIME] = (k - 3) * period
        policy._update_progress(WorldView(time_s=k * period, state=state.copy(), scenario=scenario))
        assert not policy._stalled[0] and policy._stalled[1:].all()
    state[:, S_TIME] = 5 * period
    state[0, S_TIME] = 2 * period
    policy._update_progress(WorldView(time_s=5 * period, state=state.copy(), scenario=scenario))
    assert policy._stalled[0]  # now it has flown a whole window without progress
    # An aircraft that no longer flies is released.
    state[1, S_STATUS] = ARRIVED
    policy._update_progress(WorldView(time_s=6 * period, state=state.copy(), scenario=scenario))
    assert not policy._stalled[1]


def test_a_slots_new_flight_is_never_read_as_the_old_ones_drift():
    """The wind estimate compares where the aircraft are with where the last decision
    predicted them; a stream slot that took a new flight during the period (its time flown
    restarted) has no prediction: reading it as drift once made a 164-kt estimate of a
    12-kt wind on stream-30."""
    scenario = converging(3)
    policy = MCMCMPC(extractions=10)
    policy.reset(scenario, SimConfig(), seed=0)
    period = policy.settings.period_s
    state = Simulation(scenario).view().state.copy()
    state[:, S_TIME] = 2 * period
    drift_nm = np.array([1.0, -0.5])  # every old flight drifted this much: a 12-kt wind
    for new_flight in (False, True):
        policy._wind_estimate_kt = np.zeros(2)
        policy._predicted_positions = state[:, S_X : S_Y + 1].copy()
        policy._predicted_flying = np.ones(3, dtype=bool)
        policy._predicted_time_s = 2 * period
        now = state.copy()
        now[:, S_X : S_Y + 1] += drift_nm
        if new_flight:
            now[0, S_TIME] = 60.0  # slot 0: a flight that entered a minute ago, 300 nm away
            now[0, S_X] += 300.0
        policy._update_wind_estimate(WorldView(time_s=2 * period, state=now, scenario=scenario))
        assert np.allclose(policy._wind_estimate_kt, drift_nm * 3600.0 / period)


def test_an_empty_stream_slot_is_never_part_of_a_conflict():
    """An empty slot keeps airspeed 0 and a parked position: it breaks no constraint and
    pulls nobody into a conflict's cluster."""
    scenario = _two_groups()
    policy = MCMCMPC(extractions=10, sampling="clusters")
    policy.reset(scenario, SimConfig(), seed=0)
    view = Simulation(scenario).view()
    state = view.state.copy()
    state[2, S_STATUS] = ARRIVED  # slot 2 empty, as a stream leaves it
    state[2, S_AIRSPEED] = 0.0
    state[2, S_X : S_Y + 1] = state[3, S_X : S_Y + 1] + [5.0, 0.0]  # parked beside aircraft 3
    world = WorldView(time_s=view.time_s, state=state, scenario=scenario)
    policy._use_prediction_model(1)
    states, waypoints = mcmc_mpc._candidate_starts(state, policy._start_waypoints(world)[None])
    trace = mcmc_mpc._advance_candidates(states, waypoints, np.zeros((1, 2)), policy.settings.period_s,
                                         policy._params, policy._start_scratch)
    assert trace.steps_flown[0, 2] == 0 and trace.min_airspeed_kt[0, 2] == 0.0
    assert not policy._involved(states[0], trace)[2]
    cluster = policy._start_cluster(world, np.zeros(4, dtype=bool))
    assert cluster is not None and cluster.tolist() == [True, True, False, False]  # the head-on pair alone


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"sampling": "pairs"}, "sampling"),
        ({"cluster_radius_nm": 0.0}, "cluster_radius_nm"),
        ({"cluster_radius_nm": math.inf}, "cluster_radius_nm"),
        ({"progress_fraction": 0.0}, "progress_fraction"),
        ({"progress_fraction": 1.5}, "progress_fraction"),
        ({"progress_periods": 0}, "progress_periods"),
        ({"progress_periods": 2.5}, "progress_periods"),
        ({"proposal": "paper", "sampling": "clusters"}, "proposal='homing'"),
        ({"proposal": "paper", "progress_fraction": 0.5}, "proposal='homing'"),
    ],
)
def test_bad_dense_settings_are_clear_errors(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MCMCMPC(**kwargs)


def test_the_dense_study_prints_one_row_per_setting_and_scenario(capsys, monkeypatch):
    import importlib.util
    from pathlib import Path

    bench = Path(__file__).resolve().parent.parent / "bench"
    monkeypatch.syspath_prepend(str(bench))
    spec = importlib.util.spec_from_file_location("mpc_dense_study", bench / "mpc_dense_study.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    assert study.main(["--scenarios", "converging-3", "--runs", "1", "--first-seed", "5"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith(("| joint |", "| dense |"))]
    # converging-4 (the decision-time reference) and converging-3 for each setting, printed
    # as they come and again in the section.
    assert len(rows) == 8 and all("| 1 | 1 | 0 |" in row for row in rows)
    assert "--runs 1 --first-seed 5" in out and "seeds 5–5" in out
    with pytest.raises(SystemExit):
        study.main(["--settings", "fast"])
    assert "allowed: auto, joint, dense" in capsys.readouterr().err
    # Streams only: one row per setting and stream, in a section of their own.
    assert study.main(["--scenarios", "", "--settings", "dense", "--streams", "stream-30-20min",
                       "--stream-runs", "1"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| dense | stream-30-20min | 1 |")]
    assert len(rows) == 2 and "MCMC-MPC on traffic streams" in out and "converging" not in out
    # A proposer inside the safety filter, the MPC per cluster as its fallback.
    assert study.main(["--scenarios", "", "--settings", "per-cluster", "--streams", "stream-30-20min",
                       "--stream-runs", "1", "--shielded", "nf-leg"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| per-cluster | nf-leg | stream-30-20min | 1 |")]
    assert len(rows) == 2 and "Shielded policies on traffic streams" in out and "--shielded nf-leg" in out


def test_episode_info_has_the_same_keys_before_reset_and_after_an_episode():
    policy = MCMCMPC(extractions=50, sampling="clusters", progress_fraction=0.5)
    before = policy.episode_info()
    run_episode(policy, converging(3), seed=0, max_time_s=900.0)
    after = policy.episode_info()
    assert set(before) == set(after)
    assert before["stalled_aircraft"] == 0 and before["cluster_decisions"] == 0


# ------------------------------------------------------------- sampling="per-cluster"


def _two_conflicts() -> Scenario:
    """Two head-on pairs 150 nm apart: two conflicts that do not touch each other."""
    return Scenario(
        name="two-conflicts",
        start_xy=[[-60.0, 0.0], [60.0, 0.0], [-60.0, 150.0], [60.0, 150.0]],
        start_heading=[0.0, math.pi, 0.0, math.pi],
        dest_xy=[[200.0, 0.0], [-200.0, 0.0], [200.0, 150.0], [-200.0, 150.0]],
        dest_heading=[0.0, math.pi, 0.0, math.pi],
    )


def test_per_cluster_finds_each_independent_conflict_and_solves_them_apart():
    scenario = _two_conflicts()
    policy = MCMCMPC(extractions=300, sampling="per-cluster")
    policy.reset(scenario, SimConfig(), seed=0)
    view = Simulation(scenario).view()
    start = policy._start_waypoints(view)
    clusters = policy._conflict_clusters(view, start)
    assert [np.flatnonzero(c).tolist() for c in sorted(clusters, key=lambda c: int(np.argmax(c)))] == [[0, 1], [2, 3]]
    waypoints = policy.act(view)
    decision = policy.decisions[-1]
    assert decision.clusters == 2 and decision.cluster_size == 4 and not decision.fallback
    # What it applies is feasible when flown jointly, and every aircraft left its start.
    violating, _, cost_nm = policy._fly_alone(view, waypoints)
    assert not violating.any() and math.isfinite(cost_nm) and decision.cost_nm == cost_nm
    assert all(not np.array_equal(waypoints[i], start[i]) for i in range(4))


def test_per_cluster_sees_no_cluster_where_the_start_is_feasible():
    scenario = _two_groups()
    policy = MCMCMPC(extractions=300, sampling="per-cluster")
    policy.reset(scenario, SimConfig(), seed=0)
    view = Simulation(scenario).view()
    clusters = policy._conflict_clusters(view, policy._start_waypoints(view))
    assert [np.flatnonzero(c).tolist() for c in clusters] == [[0, 1]]  # only the head-on pair
    sides = Scenario(name="sides", start_xy=[[0.0, 0.0], [0.0, 150.0]], start_heading=[0.0, 0.0],
                     dest_xy=[[200.0, 0.0], [200.0, 150.0]], dest_heading=[0.0, 0.0])
    policy.reset(sides, SimConfig(), seed=0)
    view = Simulation(sides).view()
    assert policy._conflict_clusters(view, policy._start_waypoints(view)) == []
    policy.act(view)
    assert policy.decisions[-1].clusters == 0 and policy.decisions[-1].cluster_size == 0


def test_per_cluster_flies_the_same_episode_twice_and_keeps_its_guarantees():
    settings = dict(extractions=200, sampling="per-cluster", progress_fraction=0.5, progress_periods=2)
    a, b = (run_episode(MCMCMPC(**settings), converging(6), seed=1, record_every=1) for _ in range(2))
    np.testing.assert_array_equal(a.records, b.records)
    np.testing.assert_array_equal(a.waypoints, b.waypoints)
    m = a.metrics
    assert all(m.arrived) and m.los_count == 0 and 366.0 <= m.airspeed_min_kt <= m.airspeed_max_kt <= 540.0


def test_per_cluster_flies_a_traffic_stream():
    policy = MCMCMPC(extractions=50, sampling="per-cluster", progress_fraction=0.5, progress_periods=2)
    result = run_episode(policy, "stream-60-60min", seed=2)
    assert result.metrics.stream is not None and result.metrics.stream["flights_entered"] > 3
    assert len(policy.decisions) == result.metrics.decisions


def test_per_cluster_needs_the_every_step_check():
    with pytest.raises(ValueError, match="per-cluster.*every-step"):
        MCMCMPC(sampling="per-cluster", constraint_check="sampling-instants")
    with pytest.raises(ValueError, match="allowed: auto, joint, clusters, per-cluster"):
        MCMCMPC(sampling="per-clusters")
