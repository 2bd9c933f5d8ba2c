"""What RL libraries assume of an environment, checked without the libraries: the same
info keys, shapes and dtypes at reset and at every step, no info key shadowing a
standard one, ``render(mode)``, PettingZoo's ``max_cycles``, and an AEC episode whose
last agents end on one step (some terminated, some truncated) ending cleanly."""

from __future__ import annotations

import types

import gymnasium as gym
import numpy as np
import pytest
from pettingzoo.test import max_cycles_test

import atc_nf_env
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.rewards import RewardWeights, period_outcome, reward_weight_vector
from atc_nf_env.envs.vector import EncounterVectorEnv
from atc_nf_env.kernel import Trace

#: Keys that mean something to a client (Gymnasium/TorchRL/RLlib/SB3 step results and
#: their vector-env bookkeeping); an info key of that name would overwrite or confuse it.
STANDARD_NAMES = {
    "reward", "rewards", "terminated", "truncated", "done", "terminal_observation", "final_obs",
    "final_info", "episode", "action", "observation", "obs", "TimeLimit.truncated", "__all__",
}


def signature(value):
    """Type, and for arrays shape and dtype, of an info value."""
    if isinstance(value, np.ndarray):
        return ("ndarray", value.shape, value.dtype.str)
    return (type(value).__name__,)


def info_signature(info: dict) -> dict:
    return {key: signature(value) for key, value in info.items()}


@pytest.mark.parametrize(
    "kwargs",
    [{"scenario": "converging-4"}, {"scenario": "random-3", "expose_wind": True}, {"scenario": "converging-6"}],
)
def test_parallel_infos_have_the_same_keys_and_types_at_reset_and_every_step(kwargs: dict) -> None:
    env = atc_nf_env.parallel_env(max_cycles=30, **kwargs)
    rng = np.random.default_rng(1)
    for episode in range(2):
        _, infos = env.reset(seed=episode)
        expected = info_signature(infos["aircraft_0"])
        assert all(info_signature(info) == expected for info in infos.values())
        assert not (set(expected) & STANDARD_NAMES)
        steps = 0
        while env.agents:
            actions = {agent: rng.uniform(-1.3, 1.3, 2).astype(np.float32) for agent in env.agents}
            _, rewards, _, _, infos = env.step(actions)
            steps += 1
            for agent, info in infos.items():
                assert info_signature(info) == expected, (agent, steps)
                assert info["aircraft_reward"] == rewards[agent]
        assert steps >= 5


def test_parallel_reset_infos_are_neutral() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-4")
    _, infos = env.reset(seed=3)
    for agent, info in infos.items():
        assert info["aircraft_reward"] == 0.0 and info["los_count"] == 0
        assert info["envelope_violation"] is False and info["action_clipped"] is False
        assert info["arrived"] is False and info["left_workspace"] is False
        assert info["airspeed_min_kt"] == info["airspeed_max_kt"] == info["airspeed_kt"]
        assert info["envelope_violation_fraction"] == 0.0 and info["time_s"] == 0.0
        start = env.unwrapped.world.sim.scenario
        index = int(agent.split("_")[1])
        assert np.array_equal(info["waypoint_nm"], start.dest_xy[index])
    # The paper's encounter starts 250 nm out, evenly spaced: the closest pair is a chord.
    assert infos["aircraft_0"]["min_separation_nm"] == pytest.approx(2 * 250 * np.sin(np.pi / 4))


@pytest.mark.parametrize("kwargs", [{"scenario": "converging-4"}, {"scenario": "converging-4", "max_aircraft": 6}])
def test_centralized_and_vector_infos_keep_their_keys_shapes_and_dtypes(kwargs: dict) -> None:
    env = EncounterEnv(max_cycles=12, **kwargs)
    _, info = env.reset(seed=0)
    expected = info_signature(info)
    assert not (set(expected) & STANDARD_NAMES)
    rng = np.random.default_rng(0)
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        assert info_signature(info) == expected
        done = terminated or truncated
    vec = EncounterVectorEnv(num_envs=3, max_cycles=4, **kwargs)
    _, info = vec.reset(seed=0)
    expected = info_signature(info)
    assert not ({key for key in expected if not key.startswith("_")} & STANDARD_NAMES)
    for _ in range(6):  # through the autoresets
        _, _, _, _, info = vec.step(rng.uniform(-1, 1, vec.action_space.shape))
        assert info_signature(info) == expected


def test_vector_same_step_autoreset_reward_is_not_overwritten_by_an_info_key() -> None:
    vec = gym.make_vec(atc_nf_env.ENV_ID, num_envs=4, max_cycles=2, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    vec.reset(seed=0)
    for _ in range(2):
        _, rewards, _, _, info = vec.step(np.zeros(vec.action_space.shape, dtype=np.float32))
    assert rewards.shape == (4,) and "reward" not in info and "reward" not in info["final_info"]
    assert np.allclose(rewards, info["final_info"]["aircraft_reward"].sum(axis=1))


def test_render_takes_the_mode_wrappers_pass() -> None:
    for make in (atc_nf_env.parallel_env, atc_nf_env.env, atc_nf_env.raw_env, EncounterEnv):
        env = make(scenario="converging-3", render_mode="rgb_array", render_size_px=64)
        env.reset(seed=0)
        for frame in (env.render(), env.render("rgb_array"), env.render(mode="rgb_array")):
            assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
        with pytest.raises(ValueError, match=r"render\(mode='human'\) on an env made with render_mode='rgb_array'"):
            env.render("human")
        env.close()
    plain = atc_nf_env.env(scenario="converging-3")
    plain.reset(seed=0)
    with pytest.warns(UserWarning, match="without specifying any render mode"):
        assert plain.render(None) is None


def test_pettingzoo_max_cycles_test() -> None:
    max_cycles_test(atc_nf_env)
    max_cycles_test(types.SimpleNamespace(
        parallel_env=lambda **kw: atc_nf_env.parallel_env(scenario="converging-6", **kw),
        env=lambda **kw: atc_nf_env.env(scenario="converging-6", **kw),
    ))


def test_max_cycles_sets_the_episode_length_and_the_time_observation() -> None:
    env = atc_nf_env.parallel_env(max_cycles=3)
    env.reset(seed=0)
    for step in range(3):
        obs, _, _, truncations, _ = env.step({agent: np.zeros(2) for agent in env.agents})
    assert all(truncations.values()) and not env.agents
    assert obs["aircraft_0"][7] == pytest.approx(1.0)  # elapsed time / the episode's limit
    assert EncounterEnv(max_cycles=7).cfg.max_decisions == 7
    assert EncounterEnv(max_episode_minutes=31).cfg.max_decisions == 7


def first_arrival_step(scenario: str, seed: int) -> int:
    env = atc_nf_env.parallel_env(scenario=scenario)
    env.reset(seed=seed)
    step = 0
    while True:
        step += 1
        _, _, terminations, _, _ = env.step({agent: np.zeros(2) for agent in env.agents})
        if any(terminations.values()):
            assert not all(terminations.values()), "pick an encounter whose aircraft do not all arrive together"
            return step


def test_aec_episode_ends_cleanly_when_an_arrival_meets_the_time_limit() -> None:
    """One aircraft arrives on the very step the others hit the time limit: the last
    agents then end together, every one truncated (the arriving one terminated as well),
    and an RLlib-style loop (step dead agents with None until none is left) finds them
    all truncated and no agent left to select."""
    scenario, seed = "random-4", 2
    limit = first_arrival_step(scenario, seed)
    env = atc_nf_env.env(scenario=scenario, max_cycles=limit)
    env.reset(seed=seed)
    ended: dict[str, tuple[bool, bool]] = {}
    for agent in env.agent_iter():
        _, _, terminated, truncated, _ = env.last()
        if terminated or truncated:
            ended[agent] = (terminated, truncated)
            env.step(None)
        else:
            env.step(np.zeros(2, dtype=np.float32))
    assert not env.agents
    assert len(ended) == 4 and all(truncated for _, truncated in ended.values())
    assert 1 <= sum(terminated for terminated, _ in ended.values()) < 4


def test_the_period_outcome_is_the_reward_of_the_rewards_docstring() -> None:
    rng = np.random.default_rng(7)
    b, n = 64, 5
    weights = RewardWeights(progress_per_100nm=1.3, envelope_violation=0.7, loss_of_separation=5.0,
                            arrival_bonus=5.0, left_workspace_penalty=2.0)
    from atc_nf_env.kernel import ARRIVED, FLYING, LEFT, N_STATE, S_DEST_X, S_DEST_Y, S_STATUS, S_X, S_Y

    state = np.zeros((b, n, N_STATE))
    state[:, :, [S_X, S_Y, S_DEST_X, S_DEST_Y]] = rng.normal(0, 300, (b, n, 4))
    state[:, :, S_STATUS] = rng.choice([FLYING, ARRIVED, LEFT], (b, n))
    flying_before = rng.random((b, n)) < 0.8
    distance_before = rng.uniform(0, 600, (b, n))
    steps_flown = rng.integers(0, 61, (b, n))
    trace = Trace(
        min_airspeed_kt=np.zeros((b, n)), max_airspeed_kt=np.zeros((b, n)),
        violation_steps=np.minimum(rng.integers(0, 61, (b, n)), steps_flown), worst_excursion_kt=np.zeros((b, n)),
        steps_flown=steps_flown, los_pairs=(rng.random((b, n, n)) < 0.2).astype(np.uint8),
        min_separation_nm=np.zeros(b), steps_done=np.zeros(b, dtype=np.int64), violated=np.zeros(b, dtype=bool),
        record=np.zeros((b, 0, n, 1)),
    )
    # The formula of rewards' docstring, written out over the arrays: the oracle.
    after = np.hypot(state[:, :, S_DEST_X] - state[:, :, S_X], state[:, :, S_DEST_Y] - state[:, :, S_Y])
    fraction = trace.violation_steps / np.maximum(trace.steps_flown, 1)
    los_count = trace.los_pairs.sum(axis=-1, dtype=np.int64)
    arrived_now = flying_before & (state[:, :, S_STATUS] == ARRIVED)
    left_now = flying_before & (state[:, :, S_STATUS] == LEFT)
    progress = (distance_before - after) * flying_before
    want = {
        "rewards": (weights.progress_per_100nm / 100.0) * progress - weights.envelope_violation * fraction
        - weights.loss_of_separation * los_count + weights.arrival_bonus * arrived_now
        - weights.left_workspace_penalty * left_now,
        "arrived_now": arrived_now, "left_now": left_now, "violation_fraction": fraction, "los_count": los_count,
        "progress_nm": progress, "distance_to_go_nm": after,
    }
    got = period_outcome(state, flying_before, distance_before, trace, reward_weight_vector(weights))
    for field, value in want.items():
        assert np.array_equal(getattr(got, field), value), field
        assert getattr(got, field).dtype == value.dtype, field


def test_fast_paths_still_refuse_complex_and_non_numeric_actions() -> None:
    par = atc_nf_env.parallel_env(scenario="converging-3")
    par.reset(seed=0)
    for bad in (np.array([0.1 + 1j, 0.2]), ["0.1", "x"], object()):
        actions = {agent: np.zeros(2) for agent in par.agents} | {"aircraft_1": bad}
        with pytest.raises(ValueError, match="action for aircraft_1"):
            par.step(actions)
    cen = EncounterEnv(scenario="converging-3")
    cen.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        cen.step(np.zeros((3, 2)) + 0.5j)
    # float32, float64, int and bool actions are numbers and go through.
    par.step({agent: value for agent, value in zip(par.agents, ([1, 0], np.float32([0.5, 0.5]), [True, False]))})
