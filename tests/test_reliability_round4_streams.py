"""Round 4 of the reliability issue, traffic streams: an explicit time limit is honoured,
the AEC form survives entries at the last step and empty skies, streams render and
animate, TorchRL says what it takes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import atc_nf_env
from atc_nf_env.envs import MAX_EPISODE_MINUTES, EnvConfig
from atc_nf_env.units import DECISION_PERIOD_S


# ------------------------------------------------------------------ item 2: time limits


@pytest.mark.parametrize("make", [atc_nf_env.parallel_env, atc_nf_env.env])
def test_an_explicit_180_min_limit_is_honoured_on_a_long_stream(make):
    env = make(scenario="stream-10-300min", max_episode_minutes=180)
    assert env.unwrapped.world.limit_s == 180 * 60.0
    par = atc_nf_env.parallel_env(scenario="stream-10-300min", max_episode_minutes=MAX_EPISODE_MINUTES)
    assert par.world.limit_s == 180 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10-300min").world.limit_s == 300 * 60.0
    assert atc_nf_env.parallel_env(scenario="stream-10-300min", max_episode_minutes=None).world.limit_s == 300 * 60.0


def test_a_gym_stream_env_with_180_min_ends_at_180_min():
    import gymnasium as gym

    env = gym.make("atc_nf_env/Encounter-v1", scenario="stream-2.5-300min", max_episode_minutes=180)
    env.reset(seed=4)
    truncated, info = False, {}
    while not truncated:
        _, _, _, truncated, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert info["time_s"] == pytest.approx(180 * 60.0)


def test_not_given_keeps_the_encounter_default():
    default = EnvConfig()
    assert default.max_episode_minutes == MAX_EPISODE_MINUTES and not default.time_limit_given
    assert default.max_decisions == round(MAX_EPISODE_MINUTES * 60 / DECISION_PERIOD_S)
    assert EnvConfig(max_episode_minutes=180).time_limit_given
    assert EnvConfig(max_cycles=3).time_limit_given
    assert EnvConfig.from_kwargs({"max_episode_minutes": None}, "t") == default
    with pytest.raises(ValueError, match="max_episode_minutes"):
        EnvConfig(max_episode_minutes=0)


# ------------------------------------------------------------------ item 11: the AEC stream env


def _fly_aec(env, seed: int) -> tuple[int, set[str], set[str]]:
    """One AEC episode with zero actions: (agents at the reset, agents seen, agents done)."""
    env.reset(seed=seed)
    at_reset, seen, done = len(env.agents), set(), set()
    for agent in env.agent_iter():
        _, _, terminated, truncated, _ = env.last()
        seen.add(agent)
        if terminated or truncated:
            done.add(agent)
        env.step(None if terminated or truncated else np.zeros(2, dtype=np.float32))
    return at_reset, seen, done


def test_aec_stream_survives_flights_entering_at_the_truncating_step():
    env = atc_nf_env.env(scenario="stream-60", max_cycles=2)
    for seed in range(6):
        _, seen, done = _fly_aec(env, seed)
        assert seen and seen == done  # every flight that acted ended, none was left over
        assert not env.agents
        # A flight that entered at the last instant is in the stream's books, not an agent.
        metrics = env.unwrapped.stream_metrics()
        assert len(done) <= metrics["flights_entered"]


def test_aec_and_parallel_streams_take_empty_skies():
    env = atc_nf_env.env(scenario="stream-2.5-60min", max_cycles=3)
    par = atc_nf_env.parallel_env(scenario="stream-2.5-60min", max_cycles=3)
    empty = 0
    for seed in range(12):
        at_reset, seen, done = _fly_aec(env, seed)
        assert seen == done
        obs, _ = par.reset(seed=seed)
        assert len(par.agents) == at_reset and set(obs) == set(par.agents)
        if at_reset == 0:
            empty += 1
            assert env.agent_selection is None
            assert par.step({}) == ({}, {}, {}, {}, {})
            with pytest.raises(ValueError, match="episode is over"):
                par.step({"flight_0": np.zeros(2)})
    assert empty >= 3  # the seeds do fly windows in which no flight enters


@pytest.mark.parametrize("kwargs", [
    {"scenario": "stream-60", "max_cycles": 2},
    {"scenario": "stream-60", "max_cycles": 1},
    {"scenario": "stream-2.5-60min"},  # the sky empties between flights
])
def test_pettingzoo_api_tests_pass_on_short_and_sparse_streams(kwargs):
    from pettingzoo.test import api_test, parallel_api_test

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
        api_test(atc_nf_env.env(**kwargs), num_cycles=40)
        parallel_api_test(atc_nf_env.parallel_env(**kwargs), num_cycles=40)


def test_parallel_api_test_passes_with_resets_that_find_no_flight():
    from pettingzoo.test import parallel_api_test

    par = atc_nf_env.parallel_env(scenario="stream-2.5-60min", max_cycles=3)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
        parallel_api_test(par, num_cycles=10)


# ------------------------------------------------------------------ item 12: TorchRL and streams


@pytest.mark.parametrize("scenario", ["stream-30-60min", "stream-2.5"])
def test_make_torchrl_env_refuses_a_stream_and_says_what_takes_one(scenario):
    from atc_nf_env.integrations.torchrl import make_torchrl_env

    with pytest.raises(ValueError, match=r"traffic stream.*GymEnv\(\"atc_nf_env/Encounter-v1\""):
        make_torchrl_env(scenario=scenario)  # refused before torchrl is imported


def test_batched_torchrl_env_refuses_a_stream_at_construction():
    pytest.importorskip("torchrl")
    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    with pytest.raises(ValueError, match="AtcNfBatchedEnv: scenario = 'stream-30' is a traffic stream"):
        AtcNfBatchedEnv(2, scenario="stream-30")
    assert AtcNfBatchedEnv(2, scenario="converging-4").reset()["aircraft", "mask"].all()


def test_torchrl_gym_env_takes_a_stream_as_the_refusal_says():
    pytest.importorskip("torchrl")
    from torchrl.envs import GymEnv

    env = GymEnv("atc_nf_env/Encounter-v1", scenario="stream-2.5-60min", max_cycles=4)
    rollout = env.rollout(6, break_when_any_done=False)
    assert rollout["aircraft"].shape[1:] == (env.observation_spec["mask"].shape[-1], rollout["aircraft"].shape[-1])
    assert rollout["next", "truncated"].any()


# ------------------------------------------------------------------ item 10: streams render and animate


def _stream_result(scenario_name: str = "stream-30-90min", seed: int = 1):
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario
    from baselines import NFLeg

    scenario = make_scenario(scenario_name, seed=seed)
    return scenario, run_episode(NFLeg(), scenario, seed=seed, record_every=1)


def test_slot_history_names_the_flight_each_record_shows():
    from atc_nf_env.kernel import R_X, R_Y
    from atc_nf_env.rendering import occupancy_start_rows, occupants_of_records

    scenario, result = _stream_result()
    occupant = occupants_of_records(result.times_s, result.slot_flight_times_s, result.slot_flight)
    assert occupant.shape == result.records.shape[:2]
    start = occupancy_start_rows(occupant)
    entries = [(r, s) for r, s in zip(*np.nonzero(start == np.arange(len(occupant))[:, None]))
               if r > 0 and occupant[r, s] >= 0]
    assert len(entries) >= 10
    for r, s in entries:
        # The first record of a flight in its slot is one 5-s step from its entry point.
        gap = np.hypot(*(result.records[r, s, R_X : R_Y + 1] - scenario.start_xy[occupant[r, s]]))
        assert gap < 1.0, (r, s, gap)
    assert set(occupant[occupant >= 0]) == set(np.flatnonzero(np.isfinite(_entered(scenario, result))))


def _entered(scenario, result):
    """Entry times of the flights (NaN: never entered), from the slot history."""
    entered = np.full(scenario.n_flights, np.nan)
    for t, row in zip(result.slot_flight_times_s, result.slot_flight):
        for f in row[row >= 0]:
            entered[f] = t if np.isnan(entered[f]) else entered[f]
    return entered


def test_stream_animation_frames_follow_the_slots_as_they_fill_and_empty():
    from atc_nf_env.rendering import snapshots_of_stream_recording

    scenario, result = _stream_result()
    snaps = snapshots_of_stream_recording(
        result.times_s, result.records, scenario, result.slot_flight_times_s, result.slot_flight,
        decision_times_s=result.decision_times_s, waypoints=result.waypoints,
    )
    counts = [len(s.positions) for s in snaps]
    assert counts[0] == 0 and max(counts) >= 10  # the sector fills
    labels = [set(s.labels) for s in snaps]
    assert any(a - b for a, b in zip(labels, labels[1:]))  # and flights leave it
    for snap in snaps:
        flights = np.array([int(label) for label in snap.labels], dtype=np.int64)
        assert (snap.destinations == scenario.dest_xy[flights]).all()
        assert all((trail[0] == scenario.start_xy[f]).all() for trail, f in zip(snap.trails, flights))


def test_cli_fly_animates_a_stream(tmp_path):
    from PIL import Image

    from atc_nf_env.cli import main

    gif = tmp_path / "stream.gif"
    # The command: an IndexError in rendering.py before.
    assert main(["fly", "--policy", "nf-leg", "--scenario", "stream-30-60min", "--seed", "1",
                 "--animate", str(gif)]) == 0
    with Image.open(gif) as image:
        assert image.n_frames >= 10


@pytest.mark.parametrize("form", ["parallel", "aec", "gym"])
def test_stream_envs_render_rgb_arrays(form):
    import gymnasium as gym

    kwargs = {"scenario": "stream-2.5-60min", "render_mode": "rgb_array", "render_size_px": 128}
    if form == "gym":
        env = gym.make("atc_nf_env/Encounter-v1", **kwargs)
    else:
        env = atc_nf_env.parallel_env(**kwargs) if form == "parallel" else atc_nf_env.env(**kwargs)
    env.reset(seed=6)
    first = env.render()
    assert first.shape == (128, 128, 3) and first.dtype == np.uint8
    if form == "parallel":
        env.step({agent: np.zeros(2) for agent in env.agents})
    elif form == "aec":
        for _ in env.agents[:]:
            env.step(np.zeros(2, dtype=np.float32))
    else:
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert not np.array_equal(env.render(), first)  # the aircraft moved
    env.close()


def test_an_empty_sector_renders_and_a_stream_env_animates(tmp_path):
    from atc_nf_env.rendering import save_animation

    env = atc_nf_env.parallel_env(scenario="stream-2.5-60min", max_cycles=3, render_mode="rgb_array",
                                  render_size_px=96)
    env.reset(seed=1)  # no flight enters in the first 15 min
    assert not env.agents and env.render().shape == (96, 96, 3)
    path = save_animation(env, tmp_path / "env.gif", seed=6)
    assert path.stat().st_size > 0


def test_animation_refuses_a_result_of_another_scenario(tmp_path):
    from atc_nf_env.rendering import save_animation
    from atc_nf_env.scenarios import make_scenario

    _, result = _stream_result("stream-2.5-60min", seed=6)
    with pytest.raises(ValueError, match="is of a traffic stream"):
        save_animation(result, tmp_path / "x.gif", scenario=make_scenario("converging-4", seed=0))
