"""The PettingZoo environment: API and seed tests, agents' lifecycle, observations,
state, infos, consistency with the centralized env, and bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

import atc_nf_env
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.envs.parallel import ATCParallelEnv, raw_env


def straight(env) -> dict[str, np.ndarray]:
    return {agent: np.zeros(2, dtype=np.float32) for agent in env.agents}


# --------------------------------------------------------------------------- PettingZoo's tests


@pytest.mark.parametrize("scenario", ["converging-4", "random-5"])
def test_parallel_api_test(scenario: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(atc_nf_env.parallel_env(scenario=scenario), num_cycles=100)


def test_parallel_seed_test() -> None:
    parallel_seed_test(lambda: atc_nf_env.parallel_env(scenario="random-4"), num_cycles=50)


def test_aec_api_test_and_seed_test() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        api_test(atc_nf_env.env(scenario="converging-3"), num_cycles=100)
    seed_test(lambda: atc_nf_env.env(scenario="converging-3"), num_cycles=50)


def test_metadata_and_forms() -> None:
    par = atc_nf_env.parallel_env()
    assert par.metadata["name"] == "atc_nf_env_v1"
    assert par.metadata["render_modes"] == ["human", "rgb_array"]
    assert par.metadata["is_parallelizable"] is True
    assert par.metadata["render_fps"] > 0
    assert par.render_mode is None
    aec = atc_nf_env.env(scenario="converging-6", render_mode="rgb_array")
    assert isinstance(aec.unwrapped, ATCParallelEnv)
    assert aec.render_mode == "rgb_array"
    assert isinstance(atc_nf_env.raw_env(), parallel_to_aec_wrapper)
    assert atc_nf_env.raw_env is raw_env
    assert aec.possible_agents == [f"aircraft_{i}" for i in range(6)]


# --------------------------------------------------------------------------- episodes


def test_agents_leave_when_they_arrive_and_the_episode_ends_empty() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-4", wind_sigma=0.0)
    obs, infos = env.reset(seed=0)
    assert set(obs) == set(infos) == set(env.possible_agents)
    finished: set[str] = set()
    steps = 0
    while env.agents:
        live = set(env.agents)
        obs, rewards, terminations, truncations, infos = env.step(straight(env))
        steps += 1
        assert set(obs) == set(rewards) == set(terminations) == set(truncations) == set(infos) == live
        for agent in live:
            if terminations[agent]:
                assert infos[agent]["arrived"] and agent not in env.agents
                assert obs[agent][0] == 0.0  # the alive bit of its final observation
                finished.add(agent)
    assert finished == set(env.possible_agents)
    assert steps < 36
    # After the end: step({}) is a no-op (SuperSuit's black death relies on it), actions are errors.
    assert env.step({}) == ({}, {}, {}, {}, {})
    with pytest.raises(ValueError, match="episode is over.*reset"):
        env.step({"aircraft_0": np.zeros(2)})


def test_time_limit_truncates_every_live_agent() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-6", max_episode_minutes=30)
    env.reset(seed=1)
    for step in range(6):
        _, _, terminations, truncations, _ = env.step(straight(env))
    assert all(truncations.values()) and not any(terminations.values())
    assert env.agents == []


def test_observations_are_ego_centric_with_masked_neighbours() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-3", n_neighbours=4)
    spec = ObservationSpec(n_neighbours=4)
    obs, _ = env.reset(seed=0)
    assert env.observation_space("aircraft_0").shape == (spec.dim,)
    labels = spec.labels()
    first = dict(zip(labels, obs["aircraft_0"]))
    assert first["alive"] == 1.0
    assert first["dest_distance"] == pytest.approx(5.0)  # 500 nm / 100 nm
    # Heading straight for the destination: bearing dead ahead.
    assert first["dest_cos"] == pytest.approx(1.0) and first["dest_sin"] == pytest.approx(0.0, abs=1e-6)
    # Two neighbours present, two padded.
    assert [first[f"n{k}_mask"] for k in range(4)] == [1.0, 1.0, 0.0, 0.0]
    assert all(first[f"n3_{name}"] == 0.0 for name in ("forward", "left", "vel_forward", "vel_left"))
    # Neighbours sorted nearest first; the other two are equidistant on the 250 nm circle.
    d0 = np.hypot(first["n0_forward"], first["n0_left"])
    d1 = np.hypot(first["n1_forward"], first["n1_left"])
    assert d0 <= d1 and d0 == pytest.approx(250 * np.sqrt(3) / 100, rel=1e-5)
    for agent in env.agents:
        assert obs[agent] in env.observation_space(agent)
        assert obs[agent].dtype == np.float32


def test_state_is_global_and_fixed_size() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-4", max_aircraft=6, expose_wind=True)
    env.reset(seed=0)
    state = env.state()
    assert state.shape == env.state_space.shape == (6 * 11 + 1 + 2,)
    assert state in env.state_space
    assert state[:4 * 11:11].tolist() == [1.0] * 4 and state[4 * 11 : 6 * 11].sum() == 0.0
    env.step(straight(env))
    assert env.state()[-3] == pytest.approx(300 / (36 * 300))


def test_infos_per_agent_and_hidden_wind() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-4")
    _, infos = env.reset(seed=0)
    assert "wind_kt" not in infos["aircraft_0"]
    _, rewards, _, _, infos = env.step(straight(env))
    info = infos["aircraft_2"]
    for key in ("airspeed_kt", "distance_to_go_nm", "min_separation_nm", "envelope_violation", "los_count"):
        assert key in info, key
    assert isinstance(info["envelope_violation"], bool)
    assert 300 < info["airspeed_kt"] < 600
    assert info["distance_to_go_nm"] < 500
    assert rewards["aircraft_2"] == pytest.approx(info["aircraft_reward"])
    windy = atc_nf_env.parallel_env(scenario="converging-4", expose_wind=True)
    _, infos = windy.reset(seed=0)
    assert infos["aircraft_0"]["wind_kt"].shape == (2,)
    assert windy.observation_space("aircraft_0").shape[0] == env.observation_space("aircraft_0").shape[0] + 2


def test_parallel_and_centralized_envs_agree() -> None:
    par = atc_nf_env.parallel_env(scenario="random-4")
    cen = EncounterEnv(scenario="random-4")
    rng = np.random.default_rng(3)
    obs_p, _ = par.reset(seed=9)
    obs_c, _ = cen.reset(seed=9)
    dim = par.observation_space("aircraft_0").shape[0]
    while par.agents:
        assert np.array_equal(np.stack([obs_p[a] for a in par.possible_agents if a in obs_p]),
                              obs_c.reshape(4, dim)[[par.possible_agents.index(a) for a in obs_p]])
        action = rng.uniform(-1, 1, (4, 2)).astype(np.float32)
        obs_p, rewards, *_ = par.step({a: action[i] for i, a in enumerate(par.possible_agents) if a in par.agents})
        obs_c, reward, terminated, truncated, info = cen.step(action)
        assert sum(rewards.values()) == pytest.approx(reward, rel=1e-12, abs=1e-12)
    assert terminated or truncated


def test_same_seed_same_episode_bit_for_bit() -> None:
    def episode(seed: int) -> list:
        env = atc_nf_env.parallel_env(scenario="random-6")
        rng = np.random.default_rng(seed)
        obs, _ = env.reset(seed=seed)
        trace = [sorted((a, o.tobytes()) for a, o in obs.items())]
        while env.agents:
            obs, rewards, *_ = env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
            trace.append(sorted((a, o.tobytes(), rewards[a]) for a, o in obs.items()))
        return trace

    assert episode(4) == episode(4)
    assert episode(4) != episode(5)


def test_random_scenario_changes_every_reset_but_not_its_agents() -> None:
    env = atc_nf_env.parallel_env(scenario="random-5")
    env.reset(seed=0)
    starts = []
    for _ in range(3):
        env.reset()
        assert env.agents == env.possible_agents and len(env.agents) == 5
        starts.append(env.unwrapped.world.sim.scenario.start_xy.copy())
    assert not np.array_equal(starts[0], starts[1])


# --------------------------------------------------------------------------- bad input


@pytest.fixture
def env() -> ATCParallelEnv:
    env = atc_nf_env.parallel_env(scenario="converging-3")
    env.reset(seed=0)
    return env


def test_nan_action_is_a_value_error(env: ATCParallelEnv) -> None:
    actions = straight(env)
    actions["aircraft_1"] = np.array([np.nan, 0.0])
    with pytest.raises(ValueError, match=r"aircraft_1 contains NaN or inf.*finite numbers in \[-1, 1\]"):
        env.step(actions)


def test_wrong_shape_is_a_value_error(env: ATCParallelEnv) -> None:
    actions = straight(env)
    actions["aircraft_2"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"aircraft_2 has shape \(3,\); expected \(2,\)"):
        env.step(actions)
    actions = {agent: 0.5 for agent in env.agents}
    with pytest.raises(ValueError, match=r"has shape \(\); expected \(2,\)"):
        env.step(actions)
    actions = straight(env)
    actions["aircraft_0"] = "north"
    with pytest.raises(ValueError, match="aircraft_0 = 'north' is not a pair of numbers"):
        env.step(actions)
    with pytest.raises(ValueError, match="must be a dict"):
        env.step([np.zeros(2)] * 3)


def test_unknown_or_missing_agent_is_a_value_error(env: ATCParallelEnv) -> None:
    actions = straight(env)
    actions["aircraft_7"] = np.zeros(2)
    with pytest.raises(ValueError, match=r"unknown agent\(s\) \['aircraft_7'\]; agents of this env: \['aircraft_0'"):
        env.step(actions)
    with pytest.raises(ValueError, match=r"no action for live agent\(s\) \['aircraft_1'\]"):
        env.step({"aircraft_0": np.zeros(2), "aircraft_2": np.zeros(2)})
    with pytest.raises(ValueError, match="unknown agent 'pilot'"):
        env.observation_space("pilot")
    with pytest.raises(ValueError, match="unknown agent 'pilot'"):
        env.action_space("pilot")


def test_unknown_keyword_argument_is_a_type_error() -> None:
    with pytest.raises(TypeError, match=r"parallel_env: got an unexpected keyword argument 'n_aircraft'; allowed:"):
        atc_nf_env.parallel_env(n_aircraft=4)
    with pytest.raises(TypeError, match="unexpected keyword argument 'windsigma'"):
        atc_nf_env.env(windsigma=3)


def test_step_or_state_before_reset_is_a_value_error() -> None:
    env = atc_nf_env.parallel_env()
    with pytest.raises(ValueError, match="before reset"):
        env.step({})
    with pytest.raises(ValueError, match="before reset"):
        env.state()


def test_clipping_is_reported_in_info(env: ATCParallelEnv) -> None:
    actions = straight(env)
    actions["aircraft_0"] = np.array([1.5, -0.2], dtype=np.float32)
    _, _, _, _, infos = env.step(actions)
    assert infos["aircraft_0"]["action_clipped"] is True
    assert infos["aircraft_1"]["action_clipped"] is False
    # Clipped to 140 nm.
    start = env.unwrapped.world.sim.scenario.start_xy[0]
    assert np.hypot(*(infos["aircraft_0"]["waypoint_nm"] - start)) == pytest.approx(140.0)


def test_aec_steps_in_turn_and_dead_agents_take_none() -> None:
    aec = atc_nf_env.env(scenario="converging-3", max_episode_minutes=10)
    aec.reset(seed=0)
    for agent in aec.agent_iter():
        _, _, terminated, truncated, _ = aec.last()
        aec.step(None if terminated or truncated else np.zeros(2, dtype=np.float32))
    assert aec.agents == []


def test_rgb_array_render() -> None:
    env = atc_nf_env.parallel_env(scenario="converging-4", render_mode="rgb_array", render_size_px=256)
    env.reset(seed=0)
    before = env.render()
    assert before.shape == (256, 256, 3) and before.dtype == np.uint8
    env.step(straight(env))
    assert np.any(env.render() != before)
    env.close()
