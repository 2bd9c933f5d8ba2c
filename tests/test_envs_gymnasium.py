"""The centralized Gymnasium env (``atc_nf_env/Encounter-v1``), its native vector env,
the action helpers and rendering."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from hypothesis import given, settings
from hypothesis import strategies as st

import atc_nf_env
from atc_nf_env.envs import EnvConfig
from atc_nf_env.envs.actions import (
    ActionMapping,
    action_to_waypoint,
    clamp_to_workspace,
    waypoint_to_action,
    waypoints_for_state,
)
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.observations import ObservationSpec
from atc_nf_env.envs.rewards import RewardWeights
from atc_nf_env.envs.vector import EncounterVectorEnv
from atc_nf_env.episode import episode_wind_kt
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state

ENV_ID = "atc_nf_env/Encounter-v1"


def zeros(env: gym.Env) -> np.ndarray:
    return np.zeros(env.action_space.shape, dtype=np.float32)


def run_episode(env: gym.Env, seed: int, actions: str = "zeros") -> list[tuple]:
    """(obs, reward, terminated, truncated) of every step of one episode."""
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    steps = [(obs, 0.0, False, False)]
    while True:
        action = zeros(env) if actions == "zeros" else rng.uniform(-1.2, 1.2, env.action_space.shape)
        obs, reward, terminated, truncated, _ = env.step(action)
        steps.append((obs, reward, terminated, truncated))
        if terminated or truncated:
            return steps


# --------------------------------------------------------------------------- registration


def test_make_without_importing_first() -> None:
    code = (
        "import gymnasium as gym, sys\n"
        "assert 'atc_nf_env' not in sys.modules\n"
        f"env = gym.make('atc_nf_env:{ENV_ID}', scenario='converging-3')\n"
        "obs, info = env.reset(seed=0)\n"
        "print(obs.shape, type(env.unwrapped).__name__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "EncounterEnv" in out.stdout


def test_registered_on_import_and_make_vec_uses_the_native_vector_env() -> None:
    assert ENV_ID in gym.registry
    env = gym.make(ENV_ID, scenario="converging-4")
    assert isinstance(env.unwrapped, EncounterEnv)
    vec = gym.make_vec(ENV_ID, num_envs=3, scenario="converging-4")
    assert isinstance(vec.unwrapped, EncounterVectorEnv)
    assert vec.num_envs == 3
    assert vec.single_observation_space == env.observation_space
    assert vec.single_action_space == env.action_space
    env.close()
    vec.close()


# --------------------------------------------------------------------------- checkers


@pytest.mark.parametrize(
    "kwargs",
    [
        {"scenario": "converging-4"},
        {"scenario": "random-3", "max_aircraft": 5, "expose_wind": True, "n_neighbours": 2},
    ],
)
def test_gymnasium_check_env_passes_without_warnings(kwargs: dict) -> None:
    env = gym.make(ENV_ID, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    env.close()


def test_spaces_and_padding_with_more_slots_than_aircraft() -> None:
    env = gym.make(ENV_ID, scenario="converging-4", max_aircraft=6).unwrapped
    spec = ObservationSpec(n_neighbours=4)
    assert env.action_space.shape == (6, 2)
    assert env.observation_space.shape == (6 * spec.dim,)
    obs, info = env.reset(seed=1)
    per_slot = obs.reshape(6, spec.dim)
    assert (per_slot[:4, 0] == 1).all()  # alive bits
    assert (per_slot[4:] == 0).all()  # padding slots are zeros
    assert info["present"].tolist() == [True] * 4 + [False] * 2
    obs, reward, *_ , info = env.step(np.full((6, 2), 0.3, dtype=np.float32))
    assert (obs.reshape(6, spec.dim)[4:] == 0).all()
    assert info["alive"][4:].sum() == 0 and info["aircraft_reward"][4:].sum() == 0
    assert reward == pytest.approx(float(info["aircraft_reward"].sum()))


def test_max_aircraft_smaller_than_the_scenario_is_an_error() -> None:
    with pytest.raises(ValueError, match="max_aircraft = 3 is smaller than the scenario's 4"):
        gym.make(ENV_ID, scenario="converging-4", max_aircraft=3)


# --------------------------------------------------------------------------- episodes


def test_same_seed_same_episode_bit_for_bit_and_seeds_differ() -> None:
    env_a = EncounterEnv(scenario="converging-4")
    env_b = EncounterEnv(scenario="converging-4")
    first = run_episode(env_a, seed=5, actions="random")
    second = run_episode(env_b, seed=5, actions="random")
    assert len(first) == len(second)
    for (oa, ra, ta, ua), (ob, rb, tb, ub) in zip(first, second):
        assert oa.tobytes() == ob.tobytes()
        assert ra == rb and ta == tb and ua == ub
    other = run_episode(env_a, seed=6, actions="random")
    assert any(a[0].tobytes() != b[0].tobytes() for a, b in zip(first[1:], other[1:]))


def test_reset_seed_gives_the_episode_runners_wind_and_random_encounter() -> None:
    env = EncounterEnv(scenario="random-5", expose_wind=True)
    for seed in (0, 17):
        _, info = env.reset(seed=seed)
        assert np.array_equal(info["wind_kt"], episode_wind_kt(seed, 5.17))
        assert info["episode_seed"] == seed
        expected = make_scenario("random-5", seed=seed)
        assert np.array_equal(env.world.sim.scenario.start_xy, expected.start_xy)
    # Later resets draw new episodes, reproducibly.
    env.reset(seed=3)
    seeds = [env.reset()[1]["episode_seed"] for _ in range(3)]
    env.reset(seed=3)
    assert [env.reset()[1]["episode_seed"] for _ in range(3)] == seeds
    assert len(set(seeds)) == 3


def test_wind_is_hidden_unless_asked_for() -> None:
    hidden = EncounterEnv(scenario="converging-3")
    shown = EncounterEnv(scenario="converging-3", expose_wind=True)
    obs_h, info_h = hidden.reset(seed=2)
    obs_s, info_s = shown.reset(seed=2)
    assert "wind_kt" not in info_h and "wind_kt" in info_s
    assert shown.observation_space.shape[0] == hidden.observation_space.shape[0] + 3 * 2
    _, _, _, _, info_h = hidden.step(zeros(hidden))
    assert "wind_kt" not in info_h


def test_episode_terminates_when_every_aircraft_has_arrived() -> None:
    env = EncounterEnv(scenario="converging-3", wind_sigma=0.0)
    steps = run_episode(env, seed=0)
    assert steps[-1][2] and not steps[-1][3]
    assert env.world.sim.done
    # A flight of ~500 nm at ~450 kt: about 14 decisions of 5 min.
    assert 10 <= len(steps) - 1 <= 20
    total = sum(s[1] for s in steps)
    # 3 × (5 nm of progress ~ 500 nm / 100 + arrival bonus 5), minus small penalties.
    assert 20 < total < 31
    with pytest.raises(ValueError, match="episode is over.*reset"):
        env.step(zeros(env))


def test_truncation_at_the_time_limit() -> None:
    env = EncounterEnv(scenario="converging-4", max_episode_minutes=20)
    env.reset(seed=0)
    results = [env.step(zeros(env)) for _ in range(4)]
    assert [r[3] for r in results] == [False, False, False, True]
    assert not any(r[2] for r in results)
    assert results[-1][4]["time_s"] == pytest.approx(1200.0)


def test_info_has_the_per_aircraft_quantities() -> None:
    env = EncounterEnv(scenario="converging-4")
    env.reset(seed=0)
    _, reward, _, _, info = env.step(zeros(env))
    for key in (
        "airspeed_kt", "distance_to_go_nm", "min_separation_nm", "nearest_nm", "los_count",
        "envelope_violation", "envelope_violation_fraction", "action_clipped", "arrived",
        "left_workspace", "waypoint_nm", "aircraft_reward", "alive", "present", "time_s", "episode_seed",
    ):
        assert key in info, key
    assert info["airspeed_kt"].shape == (4,)
    assert info["waypoint_nm"].shape == (4, 2)
    assert (info["distance_to_go_nm"] < 500).all()
    assert info["time_s"] == 300.0
    # The waypoint is action (0, 0): 100 nm ahead on the line to the destination.
    start = make_scenario("converging-4").start_xy
    assert np.allclose(np.hypot(*(info["waypoint_nm"] - start).T), 100.0)


def test_the_reward_follows_its_weights() -> None:
    heavy = EncounterEnv(scenario="converging-3", reward_weights={"progress_per_100nm": 2.0})
    plain = EncounterEnv(scenario="converging-3")
    heavy.reset(seed=0)
    plain.reset(seed=0)
    _, r_heavy, *_ = heavy.step(zeros(heavy))
    _, r_plain, _, _, info = plain.step(zeros(plain))
    progress = 500.0 - info["distance_to_go_nm"]
    assert r_plain == pytest.approx(float(progress.sum() / 100 - info["envelope_violation_fraction"].sum()))
    assert r_heavy == pytest.approx(r_plain + float(progress.sum() / 100))


# --------------------------------------------------------------------------- bad input


@pytest.fixture
def env() -> EncounterEnv:
    env = EncounterEnv(scenario="converging-3")
    env.reset(seed=0)
    return env


def test_nan_action_is_a_value_error(env: EncounterEnv) -> None:
    action = zeros(env)
    action[1, 0] = np.nan
    with pytest.raises(ValueError, match="NaN or inf.*finite numbers in \\[-1, 1\\]"):
        env.step(action)


def test_wrong_shape_is_a_value_error(env: EncounterEnv) -> None:
    with pytest.raises(ValueError, match=r"shape \(6,\); expected \(3, 2\)"):
        env.step(np.zeros(6))
    with pytest.raises(ValueError, match="not an array of numbers"):
        env.step("left")


def test_step_before_reset_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="before reset"):
        EncounterEnv().step(np.zeros((4, 2)))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"wind_sigma": -1.0}, "wind_sigma = -1.0"),
        ({"render_mode": "ansi"}, "render_mode = 'ansi'"),
        ({"n_neighbours": -1}, "n_neighbours = -1"),
        ({"max_episode_minutes": 0}, "max_episode_minutes = 0"),
        ({"max_cycles": 0}, "max_cycles = 0"),
        ({"max_cycles": 2.5}, "max_cycles = 2.5"),
        ({"max_cycles": 4, "max_episode_minutes": 60}, "give one of them"),
        ({"scenario": "diverging-4"}, "unknown scenario 'diverging-4'"),
        ({"scenario": 4}, "scenario = 4"),
        ({"reward_weights": {"bonus": 1}}, r"reward_weights: unknown fields \['bonus'\]"),
        ({"reward_weights": {"arrival_bonus": -1}}, "must be >= 0"),
        ({"action_mapping": {"distance_nm": 10, "distance_span_nm": 20}}, "shortest waypoint distance"),
        ({"config": {"k": 2}}, "must be a SimConfig"),
    ],
)
def test_bad_keyword_arguments_are_value_errors(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        EncounterEnv(**kwargs)


def test_unknown_keyword_arguments_are_type_errors_through_gym_make() -> None:
    with pytest.raises(TypeError, match=r"got an unexpected keyword argument 'scenari'; allowed: \['scenario'"):
        EncounterEnv(scenari="converging-4")
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'scenari'"):
        gym.make(ENV_ID, scenari="converging-4")


def test_actions_outside_the_box_are_clipped_and_reported(env: EncounterEnv) -> None:
    action = np.array([[2.0, 0.0], [0.0, 0.0], [-1.0, -3.0]], dtype=np.float32)
    _, _, _, _, info = env.step(action)
    assert info["action_clipped"].tolist() == [True, False, True]
    other = EncounterEnv(scenario="converging-3")
    other.reset(seed=0)
    _, _, _, _, clipped_info = other.step(np.clip(action, -1, 1))
    assert np.array_equal(info["waypoint_nm"], clipped_info["waypoint_nm"])
    assert not clipped_info["action_clipped"].any()


# --------------------------------------------------------------------------- actions


@settings(max_examples=200, deadline=None)
@given(
    a0=st.floats(-1, 1),
    a1=st.floats(-0.999, 0.999),
    x=st.floats(-300, 300),
    y=st.floats(-300, 300),
    bearing=st.floats(-math.pi, math.pi),
)
def test_waypoint_to_action_inverts_action_to_waypoint(a0, a1, x, y, bearing) -> None:
    position = np.array([x, y])
    destination = position + 400.0 * np.array([math.cos(bearing), math.sin(bearing)])
    waypoint = action_to_waypoint(np.array([a0, a1]), position, destination)
    assert math.hypot(*(waypoint - position)) == pytest.approx(100 + 40 * a0)
    back = waypoint_to_action(waypoint, position, destination)
    assert back == pytest.approx(np.array([a0, a1]), abs=1e-5)


def test_action_mapping_defaults_and_ranges() -> None:
    mapping = ActionMapping()
    assert mapping.distance_range_nm == (60.0, 140.0)
    position, destination = np.array([0.0, 0.0]), np.array([0.0, 500.0])
    # a = (1, 1): 140 nm, 90° counter-clockwise of north = west.
    assert action_to_waypoint(np.array([1.0, 1.0]), position, destination) == pytest.approx([-140.0, 0.0], abs=1e-9)
    wide = ActionMapping(distance_nm=50, distance_span_nm=10, angle_span_deg=45)
    assert action_to_waypoint(np.array([-1.0, 0.0]), position, destination, wide) == pytest.approx([0.0, 40.0])
    # A waypoint beyond reach maps to a clipped action.
    assert waypoint_to_action(np.array([0.0, 300.0]), position, destination).tolist() == [1.0, 0.0]


def test_waypoints_are_pulled_inside_the_workspace() -> None:
    position, destination = np.array([1450.0, 0.0]), np.array([1490.0, 0.0])
    waypoint = action_to_waypoint(np.array([1.0, 0.0]), position, destination, workspace_radius_nm=1500.0)
    assert math.hypot(*waypoint) == pytest.approx(1500.0 - 2.5 - 1.0)
    assert clamp_to_workspace(np.array([[10.0, 0.0]]), 1500.0).tolist() == [[10.0, 0.0]]


def test_compiled_waypoints_match_the_helper() -> None:
    scenario = make_scenario("random-6", seed=4)
    state = initial_state(scenario, n_worlds=2)
    actions = np.random.default_rng(0).uniform(-1.5, 1.5, (2, 6, 2))
    compiled = waypoints_for_state(actions, state, ActionMapping(), scenario.workspace_radius_nm)
    helper = action_to_waypoint(actions, state[..., 0:2], state[..., 8:10], ActionMapping(), scenario.workspace_radius_nm)
    assert np.allclose(compiled, helper, rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- vector env


def collect(vec, actions: list[np.ndarray], seed: int) -> list[tuple]:
    out = [vec.reset(seed=seed)[0]]
    for action in actions:
        obs, reward, terminated, truncated, _ = vec.step(action)
        out.append((obs, reward, terminated, truncated))
    return out


def test_native_vector_env_equals_sync_vector_env_including_autoresets() -> None:
    kwargs = {"scenario": "random-3", "max_episode_minutes": 60}
    b = 4
    native = gym.make_vec(ENV_ID, num_envs=b, **kwargs)
    sync = SyncVectorEnv([lambda: EncounterEnv(**kwargs) for _ in range(b)])
    rng = np.random.default_rng(1)
    actions = [rng.uniform(-1, 1, (b, 3, 2)).astype(np.float32) for _ in range(30)]  # > 2 episodes
    got = collect(native, actions, seed=10)
    want = collect(sync, actions, seed=10)
    assert np.array_equal(got[0], want[0])
    autoresets = 0
    for step, (g, w) in enumerate(zip(got[1:], want[1:])):
        assert np.array_equal(g[0], w[0]), f"observations differ at step {step}"
        assert np.allclose(g[1], w[1], rtol=1e-12, atol=1e-12), f"rewards differ at step {step}"
        assert np.array_equal(g[2], w[2]) and np.array_equal(g[3], w[3])
        autoresets += int(g[3].sum() + g[2].sum())
    assert autoresets >= b


def test_vector_env_obs_in_space_and_infos_masked() -> None:
    vec = EncounterVectorEnv(num_envs=5, scenario="converging-4", max_aircraft=5)
    obs, info = vec.reset(seed=0)
    assert obs in vec.observation_space
    assert info["_airspeed_kt"].all() and info["present"].shape == (5, 5)
    obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
    assert obs in vec.observation_space
    assert obs.dtype == np.float32 and reward.shape == (5,) and terminated.dtype == bool
    assert np.allclose(reward, info["aircraft_reward"].sum(axis=1))
    assert info["airspeed_kt"].shape == (5, 5) and info["min_separation_nm"].shape == (5,)


def test_vector_env_same_step_autoreset_reports_final_observation() -> None:
    vec = EncounterVectorEnv(num_envs=2, scenario="converging-3", max_episode_minutes=10, autoreset_mode="SameStep")
    assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    first, _ = vec.reset(seed=0)
    vec.step(np.zeros((2, 3, 2)))
    obs, _, terminated, truncated, info = vec.step(np.zeros((2, 3, 2)))
    assert truncated.all() and not terminated.any()
    assert info["_final_obs"].all()
    assert not np.array_equal(info["final_obs"][0], obs[0])
    assert (obs[:, 7] == 0).all()  # slot 0's time feature: a fresh episode
    assert (info["time_s"] == 0).all() and (info["final_info"]["time_s"] == 600).all()


def test_vector_env_disabled_autoreset_needs_reset_mask() -> None:
    vec = EncounterVectorEnv(num_envs=3, scenario="converging-3", max_episode_minutes=5, autoreset_mode="Disabled")
    vec.reset(seed=0)
    _, _, _, truncated, _ = vec.step(np.zeros((3, 3, 2)))
    assert truncated.all()
    with pytest.raises(ValueError, match="are over; reset them"):
        vec.step(np.zeros((3, 3, 2)))
    obs, info = vec.reset(options={"reset_mask": np.array([True, False, True])})
    assert info["_time_s"].tolist() == [True, False, True]
    with pytest.raises(ValueError, match=r"world\(s\) \[1\] are over"):
        vec.step(np.zeros((3, 3, 2)))


def test_vector_env_bad_input() -> None:
    with pytest.raises(ValueError, match="num_envs = 0"):
        EncounterVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="autoreset_mode = 'sometimes'"):
        EncounterVectorEnv(num_envs=2, autoreset_mode="sometimes")
    with pytest.raises(ValueError, match="does not render"):
        EncounterVectorEnv(num_envs=2, render_mode="rgb_array")
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'speed'"):
        gym.make_vec(ENV_ID, num_envs=2, speed=3)
    vec = EncounterVectorEnv(num_envs=2, scenario="converging-3")
    with pytest.raises(ValueError, match="before reset"):
        vec.step(np.zeros((2, 3, 2)))
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(3, 2\); expected \(2, 3, 2\)"):
        vec.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        vec.step(np.full((2, 3, 2), np.nan))


# --------------------------------------------------------------------------- rendering


def test_rgb_array_frame_shape_and_it_changes_as_aircraft_move() -> None:
    env = gym.make(ENV_ID, scenario="converging-4", render_mode="rgb_array", render_size_px=320)
    env.reset(seed=0)
    before = env.render()
    assert before.shape == (320, 320, 3) and before.dtype == np.uint8
    env.step(zeros(env))
    after = env.render()
    assert after.shape == before.shape
    changed = np.any(before != after, axis=2).mean()
    assert changed > 0.001
    env.close()


def test_human_render_mode_runs_without_a_display() -> None:
    env = gym.make(ENV_ID, scenario="converging-3", render_mode="human", render_size_px=128)
    env.reset(seed=0)
    env.step(zeros(env))
    assert env.render() is None
    env.close()


def test_render_without_render_mode_warns_and_returns_none() -> None:
    env = EncounterEnv(scenario="converging-3")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="without specifying any render mode"):
        assert env.render() is None


def test_save_animation_from_env_episode_result_and_frames(tmp_path) -> None:
    from PIL import Image

    from atc_nf_env.episode import run_episode as fly
    from atc_nf_env.rendering import save_animation
    from baselines import NFDirect

    env = gym.make(ENV_ID, scenario="converging-3", render_mode="rgb_array", render_size_px=128,
                   max_episode_minutes=15)
    path = save_animation(env, tmp_path / "env.gif", seed=0)
    with Image.open(path) as gif:
        assert gif.n_frames == 4 and gif.size == (128, 128)

    scenario = make_scenario("converging-3")
    result = fly(NFDirect(), scenario, seed=0, wind_sigma_mps=0.0, record_every=6, max_time_s=1200.0)
    path = save_animation(result, tmp_path / "run.gif", scenario=scenario, frame_every_s=300.0, size_px=128)
    with Image.open(path) as gif:
        assert gif.n_frames == 5

    frames = [np.full((32, 48, 3), value, dtype=np.uint8) for value in (0, 128, 255)]
    with Image.open(save_animation(frames, tmp_path / "frames.gif")) as gif:
        assert gif.n_frames == 3 and gif.size == (48, 32)

    with pytest.raises(ValueError, match="needs scenario="):
        save_animation(result, tmp_path / "x.gif")
    with pytest.raises(ValueError, match="render_mode='rgb_array'"):
        save_animation(EncounterEnv(scenario="converging-3"), tmp_path / "x.gif")
    with pytest.raises(ValueError, match="not understood"):
        save_animation(42, tmp_path / "x.gif")
    with pytest.raises(ValueError, match="at least one frame"):
        save_animation([], tmp_path / "x.gif")


def test_env_config_defaults() -> None:
    cfg = EnvConfig()
    assert cfg.max_decisions == 36
    assert cfg.reward_weights == RewardWeights()
    assert EnvConfig(max_episode_minutes=7).max_decisions == 2
    assert atc_nf_env.ENV_ID == ENV_ID
    assert callable(atc_nf_env.parallel_env) and callable(atc_nf_env.env)
    with pytest.raises(AttributeError):
        atc_nf_env.nonexistent  # noqa: B018
