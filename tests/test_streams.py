"""Traffic streams: scenarios, the stream simulation, its metrics and its environments."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import FLYING
from atc_nf_env.metrics import RunMetrics, summarize
from atc_nf_env.scenarios import (
    MAX_STREAM_RATE_PER_H,
    StreamScenario,
    default_max_airborne,
    make_scenario,
    max_stream_flights,
    stream_scenario,
)
from atc_nf_env.streams import DONE_ARRIVED, StreamSimulation
from atc_nf_env.units import AIRSPEED_NOMINAL_KT, SEPARATION_MIN_NM
from baselines import NFDirect


# ------------------------------------------------------------------ scenarios


def test_stream_names_draw_a_seeded_schedule():
    a = make_scenario("stream-60", seed=3)
    b = make_scenario("stream-60", seed=3)
    c = make_scenario("stream-60", seed=4)
    assert isinstance(a, StreamScenario)
    assert a.canonical_json() == b.canonical_json()
    assert a.canonical_json() != c.canonical_json()
    assert a.duration_s == 120 * 60.0 and a.rate_per_hour == 60.0
    assert a.max_airborne == default_max_airborne(60.0) == a.n_aircraft
    assert 0 < a.n_flights <= max_stream_flights(60.0, 120.0)
    # Entries and destinations on the sector's edge, due in order within the length.
    assert np.allclose(np.hypot(*a.start_xy.T), a.sector_radius_nm)
    assert np.allclose(np.hypot(*a.dest_xy.T), a.sector_radius_nm)
    assert (np.diff(a.entry_time_s) >= 0).all() and a.entry_time_s[-1] < a.duration_s
    # 40 min at 30 an hour: about 20 flights (Poisson, so not exactly).
    short = make_scenario("stream-30-40min", seed=1)
    assert short.duration_s == 40 * 60.0 and short.name == "stream-30-40min"
    assert 5 <= short.n_flights <= 40


def test_stream_rate_matches_poisson_mean():
    counts = [stream_scenario(60.0, seed=s, duration_min=60.0).n_flights for s in range(200)]
    # Mean 60, standard error of the mean sqrt(60 / 200) = 0.55.
    assert abs(np.mean(counts) - 60.0) < 2.5


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: stream_scenario(-5.0, seed=0), r"rate_per_hour = -5\.0: .*\(0, 600\]"),
        (lambda: stream_scenario(0, seed=0), r"rate_per_hour = 0: .*\(0, 600\]"),
        (lambda: stream_scenario(MAX_STREAM_RATE_PER_H + 1, seed=0), r"\(0, 600\]"),
        (lambda: stream_scenario(60.0, seed=0, duration_min=0), r"duration_min = 0: .*\(0, 1440\]"),
        (lambda: stream_scenario(60.0, seed=0, duration_min=-3.0), r"duration_min = -3\.0"),
        (lambda: stream_scenario(60.0, seed=0, duration_min=math.nan), r"duration_min = nan"),
        (lambda: stream_scenario(60.0, seed=-1), r"seed = -1"),
        (lambda: stream_scenario(60.0, seed=0, max_airborne=0), r"max_airborne = 0: must be an integer >= 1"),
        (lambda: make_scenario("stream-0"), r"'stream-0': rate_per_hour = 0\.0: .*\(0, 600\]"),
        (lambda: make_scenario("stream-60-0min"), r"duration_min = 0\.0: .*\(0, 1440\]"),
        (lambda: make_scenario("stream-abc"), r"'stream-abc': the rate R is not a number"),
        (lambda: make_scenario("stream-60-xmin"), r"the length D is not a number"),
        (lambda: make_scenario("stream-60", seed=1).to_dict(), r"'stream-60' is a traffic stream"),
    ],
)
def test_bad_stream_inputs_name_the_allowed_range(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def _hand_built(entry_times, starts, dests, duration_min=60.0, max_airborne=4, clearance_nm=20.0):
    starts = np.asarray(starts, dtype=float)
    dests = np.asarray(dests, dtype=float)
    heading = np.arctan2(dests[:, 1] - starts[:, 1], dests[:, 0] - starts[:, 0])
    return StreamScenario(
        name="hand-built", start_xy=starts, start_heading=heading, dest_xy=dests, dest_heading=heading,
        entry_time_s=np.asarray(entry_times, dtype=float), duration_s=duration_min * 60.0,
        max_airborne=max_airborne, rate_per_hour=2.0, entry_clearance_nm=clearance_nm,
    )


def test_stream_scenario_validates_its_schedule():
    with pytest.raises(ValueError, match="non-decreasing"):
        _hand_built([600.0, 0.0], [[0, 0], [0, 50]], [[80, 0], [80, 50]])
    with pytest.raises(ValueError, match=r"in \[0, duration_s"):
        _hand_built([0.0, 3600.0], [[0, 0], [0, 50]], [[80, 0], [80, 50]])


# ------------------------------------------------------------------ simulation and metrics


def test_tiny_stream_metrics_by_hand():
    """Two flights 80 nm apart in time and space, no wind: both enter (the second at the
    first decision instant after it is due), both arrive, and the metrics add up."""
    scenario = _hand_built([0.0, 450.0], [[-40.0, 0.0], [-40.0, 60.0]], [[40.0, 0.0], [40.0, 60.0]])
    result = run_episode(NFDirect(), scenario, seed=0, wind_kt=np.zeros(2))
    m = result.metrics
    s = m.stream
    assert s is not None
    assert m.sim_time_min == pytest.approx(60.0)  # a stream flies its whole length
    assert s["flights_entered"] == 2 and s["flights_completed"] == 2 and s["airborne_at_end"] == 0
    assert m.arrived == [True, True] and m.success
    assert s["throughput_per_hour"] == pytest.approx(2.0)  # 2 flights in 1 h
    # Entry at the decision instants 0 and 600 s: delays 0 and 150 s; nothing held.
    assert s["entry_delay_s"] == pytest.approx({"mean": 75.0, "max": 150.0})
    assert s["entries_held"] == 0
    direct_s = 80.0 / AIRSPEED_NOMINAL_KT * 3600.0
    delays = [60.0 * t - direct_s for t in m.flight_time_min]
    assert s["delay_s"]["mean"] == pytest.approx(np.mean(delays))
    assert s["delay_s"]["max"] == pytest.approx(max(delays))
    assert s["flight_hours"] == pytest.approx(sum(m.flight_time_min) / 60.0)
    assert s["max_airborne"] in (1, 2)
    assert s["los_count"] == 0 and s["los_per_flight_hour"] == 0.0


def test_an_entry_waits_until_its_point_is_clear():
    """Two flights due together at the same point: the second waits (held) until the first
    is 20 nm away, and is never placed within the separation minimum of it."""
    scenario = _hand_built([0.0, 0.0], [[-100.0, 0.0], [-100.0, 0.0]], [[100.0, 0.0], [100.0, 0.0]])
    sim = StreamSimulation(scenario)
    assert sim.airborne == 1 and sim.flights.held.tolist() == [False, True]
    waypoints = sim.view().destinations
    sim.advance(waypoints, 300.0)  # the first flies ~38 nm: clear
    assert sim.airborne == 2
    assert sim.flights.entered_s.tolist() == [0.0, 300.0]
    metrics = sim.stream_metrics()
    assert metrics["entries_held"] == 1 and metrics["entry_delay_s"]["max"] == 300.0


def test_a_full_sector_makes_entries_wait():
    scenario = _hand_built([0.0, 0.0], [[-100.0, 0.0], [0.0, 100.0]], [[100.0, 0.0], [0.0, -100.0]], max_airborne=1)
    sim = StreamSimulation(scenario)
    assert sim.airborne == 1 and sim.flights.held[1]


class _CheckedEntries(StreamSimulation):
    """Records the distance from each entering aircraft to the nearest one already in."""

    gaps: list[float]

    def _place(self, slot: int, f: int) -> None:
        flying = self.status == FLYING
        positions = self.state[0, flying, :2]
        if positions.size:
            self.gaps.append(float(np.hypot(*(positions - self.stream.start_xy[f]).T).min()))
        super()._place(slot, f)


def test_entering_aircraft_are_never_in_loss_of_separation():
    scenario = make_scenario("stream-240-25min", seed=7)  # dense: entries meet traffic
    _CheckedEntries.gaps = []
    sim = _CheckedEntries(scenario)
    while not sim.done:
        sim.advance(sim.view().destinations, 300.0)
    assert len(_CheckedEntries.gaps) > 20
    assert min(_CheckedEntries.gaps) >= scenario.entry_clearance_nm > SEPARATION_MIN_NM
    assert sim.stream_metrics()["entries_held"] > 0  # the dense stream did make some wait


def test_streams_reproduce_bit_for_bit():
    first = run_episode(NFDirect(), "stream-90-40min", seed=11, record_every=12)
    second = run_episode(NFDirect(), "stream-90-40min", seed=11, record_every=12)
    other = run_episode(NFDirect(), "stream-90-40min", seed=12, record_every=12)
    assert first.records.tobytes() == second.records.tobytes()
    one, two = first.metrics.to_dict(), second.metrics.to_dict()
    for record in (one, two):
        record.pop("wall_s")
        record.pop("decision_s_mean")
    assert one == two
    assert first.records.tobytes() != other.records.tobytes()


def test_summary_pools_stream_metrics():
    def run(seed, completed, hours, los, delay_mean, delay_max):
        stream = {
            "flights_entered": completed + 1, "flights_completed": completed, "flights_left_workspace": 0,
            "entries_held": 1, "throughput_per_hour": completed / 2.0,
            "delay_s": {"mean": delay_mean, "max": delay_max}, "entry_delay_s": {"mean": 10.0, "max": 20.0},
            "flight_hours": hours, "los_count": los, "max_airborne": 3 + seed,
        }
        return RunMetrics(
            scenario="stream-1", seed=seed, n_aircraft=completed + 1, wind_kt=[0.0, 0.0], arrived=[True] * completed
            + [False], left_workspace=[False] * (completed + 1), flight_time_min=[60.0] * (completed + 1),
            path_length_nm=[400.0] * (completed + 1), success=True, min_separation_nm=10.0, los_count=los,
            envelope_violation_fraction=0.0, worst_excursion_kt=0.0, airspeed_min_kt=400.0, airspeed_max_kt=500.0,
            steps_flown=100, sim_time_min=120.0, wall_s=1.0, decisions=24, decision_s_mean=0.01, stream=stream,
        )

    summary = summarize([run(0, 2, 3.0, 1, 100.0, 150.0), run(1, 6, 9.0, 2, 200.0, 400.0)])["stream"]
    assert summary["los_per_flight_hour"] == pytest.approx(3 / 12.0)
    assert summary["delay_s"] == pytest.approx({"mean": (2 * 100 + 6 * 200) / 8, "max": 400.0})
    assert summary["throughput_per_hour"]["mean"] == pytest.approx(2.0)
    assert summary["max_airborne"] == 4 and summary["flights_completed"] == 8 and summary["entries_held"] == 2


def test_the_mpc_flies_a_stream():
    from baselines import MCMCMPC

    policy = MCMCMPC(extractions=40)
    result = run_episode(policy, "stream-30-30min", seed=2)
    assert result.metrics.stream["flights_entered"] >= 1
    assert result.metrics.decisions >= 1
    # It decides only for what flies: an empty sector is no decision.
    assert len(result.decision_s) == len(policy.decisions)


# ------------------------------------------------------------------ environments


def test_pettingzoo_parallel_and_aec_api_tests_pass_on_a_stream():
    from pettingzoo.test import api_test, parallel_api_test

    import atc_nf_env

    par = atc_nf_env.parallel_env(scenario="stream-60-40min")
    assert par.possible_agents[0] == "flight_0" and len(par.possible_agents) == max_stream_flights(60, 40)
    with warnings.catch_warnings():
        # Flights never scheduled in an episode never join: PettingZoo notes it, rightly.
        warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
        parallel_api_test(par, num_cycles=60)
        api_test(atc_nf_env.env(scenario="stream-60-40min"), num_cycles=60)


def test_agents_join_and_leave_a_parallel_stream():
    import atc_nf_env

    env = atc_nf_env.parallel_env(scenario="stream-60-75min")
    obs, _ = env.reset(seed=5)
    assert env.agents and set(obs) == set(env.agents)
    seen, finished, joined_later = set(env.agents), set(), False
    while env.agents:
        actions = {agent: np.zeros(2, dtype=np.float32) for agent in env.agents}
        obs, rewards, terminations, truncations, _ = env.step(actions)
        new = set(env.agents) - seen
        joined_later |= bool(new)
        assert not (set(env.agents) & finished), "a flight came back"
        finished |= {a for a in terminations if terminations[a] or truncations[a]}
        seen |= set(env.agents)
        assert all(env.observation_space(a).contains(obs[a]) for a in env.agents)
    assert joined_later
    metrics = env.stream_metrics()
    assert metrics["flights_completed"] >= 1  # some flights arrived: terminated, not truncated
    assert sum(1 for _ in finished) == metrics["flights_entered"]


def test_gym_stream_env_masks_slots():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import atc_nf_env  # noqa: F401 (registers the id)

    env = gym.make("atc_nf_env/Encounter-v1", scenario="stream-60-30min")
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    slots = default_max_airborne(60.0)
    assert obs["aircraft"].shape[0] == slots and obs["mask"].shape == (slots,)
    assert (obs["mask"] == (info["slot_flight"] >= 0)).all()
    assert not obs["aircraft"][obs["mask"] == 0].any()  # empty slots are zeros
    truncated = False
    while not truncated:
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        assert not terminated
    assert info["stream"]["flights_entered"] == int((info["slot_flight"] >= 0).sum()) + \
        info["stream"]["flights_completed"] + info["stream"]["flights_left_workspace"]
    vec = gym.make_vec("atc_nf_env/Encounter-v1", num_envs=2, scenario="stream-60-30min")
    batch, _ = vec.reset(seed=0)
    assert batch["mask"].shape == (2, slots)
    vec.close()


def test_stream_envs_render_rgb_frames():
    import atc_nf_env

    env = atc_nf_env.parallel_env(scenario="stream-60", render_mode="rgb_array", render_size_px=96)
    env.reset(seed=0)
    assert env.render().shape == (96, 96, 3)


def test_slot_counts_are_bounded_and_fixed_per_env():
    import atc_nf_env

    env = atc_nf_env.parallel_env(scenario="stream-60-30min", max_aircraft=7)
    env.reset(seed=1)
    assert env.world.sim.state.shape[1] == 7
    env.reset(seed=2)
    assert env.world.sim.state.shape[1] == 7
    assert max(env.world.sim.airborne, 0) <= 7


def test_a_stream_env_lasts_the_stream_unless_a_limit_is_given():
    import atc_nf_env

    assert atc_nf_env.parallel_env(scenario="stream-10-300min").world.limit_s == 300 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10-300min", max_cycles=6).world.limit_s == 30 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10", max_episode_minutes=60).world.limit_s == 60 * 60.0
