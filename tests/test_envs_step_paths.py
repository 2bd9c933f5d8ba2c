"""The single-world envs' quick step paths keep the contracts of the plain ones: the AEC
env does what PettingZoo's own conversion wrapper does around the ParallelEnv, call by
call; what an env hands out (observations, infos) never changes afterwards; odd action
types take the careful path."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

import atc_nf_env
from atc_nf_env.config import SimConfig
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.parallel import ATCParallelEnv


def assert_same_value(got: Any, want: Any, where: str) -> None:
    assert type(got) is type(want), f"{where}: {type(got).__name__} != {type(want).__name__}"
    if isinstance(want, np.ndarray):
        assert got.dtype == want.dtype and got.shape == want.shape, where
        assert got.tobytes() == want.tobytes(), where
    elif isinstance(want, dict):
        assert list(got) == list(want), where
        for key in want:
            assert_same_value(got[key], want[key], f"{where}[{key!r}]")
    elif isinstance(want, float) and np.isnan(want):
        assert np.isnan(got), where
    else:
        assert got == want, where


def assert_same_aec(ours: Any, reference: Any, where: str) -> None:
    for name in ("agents", "agent_selection", "rewards", "_cumulative_rewards", "terminations", "truncations", "infos"):
        assert_same_value(getattr(ours, name), getattr(reference, name), f"{where}: {name}")
    for agent in reference.agents:
        assert_same_value(ours.observe(agent), reference.observe(agent), f"{where}: observe({agent})")
    if reference.agents:  # once none is left, the selection names the last agent removed
        for got, want in zip(ours.last(), reference.last()):
            assert_same_value(got, want, f"{where}: last()")


def action_forms(rng: np.random.Generator) -> Any:
    """Actions of the types clients pass: float32/float64 arrays, lists, tuples, values
    outside the box (clipped)."""
    value = rng.uniform(-1.3, 1.3, 2)
    form = rng.integers(0, 4)
    if form == 0:
        return value.astype(np.float32)
    if form == 1:
        return value
    if form == 2:
        return value.tolist()
    return tuple(value.tolist())


@pytest.mark.parametrize(
    ("kwargs", "seeds"),
    [
        ({"scenario": "random-5"}, [3, None, 11]),  # arrivals on different steps, a reset without seed
        ({"scenario": "converging-3", "max_episode_minutes": 10}, [0]),  # the time limit ends it
        ({"scenario": "random-4", "max_cycles": 11}, [2]),  # an arrival on the time limit's step
        ({"scenario": "converging-4", "max_aircraft": 6, "expose_wind": True}, [1]),
    ],
)
def test_aec_env_does_what_pettingzoos_conversion_wrapper_does(kwargs: dict[str, Any], seeds: list) -> None:
    ours = atc_nf_env.raw_env(**kwargs)
    reference = parallel_to_aec_wrapper(ATCParallelEnv(**kwargs))
    rng = np.random.default_rng(0)
    saw_dead_step = False
    for episode, seed in enumerate(seeds):
        ours.reset(seed=seed)
        reference.reset(seed=seed)
        assert_same_aec(ours, reference, f"episode {episode} reset")
        calls = 0
        while reference.agents:
            _, _, terminated, truncated, _ = reference.last()
            if terminated or truncated:
                saw_dead_step = True
                action = None
            else:
                action = action_forms(rng)
            ours.step(action)
            reference.step(copy.deepcopy(action))
            calls += 1
            assert_same_aec(ours, reference, f"episode {episode} call {calls}")
        assert not ours.agents
    assert saw_dead_step


def test_aec_env_bad_action_raises_like_the_conversion_wrapper_and_can_be_retried() -> None:
    ours = atc_nf_env.raw_env(scenario="converging-3")
    reference = parallel_to_aec_wrapper(ATCParallelEnv(scenario="converging-3"))
    for env in (ours, reference):
        env.reset(seed=0)
        env.step(np.zeros(2, dtype=np.float32))
        env.step(np.zeros(2, dtype=np.float32))
    for bad, message in (
        (np.array([np.nan, 0.0]), "contains NaN or inf"),
        (np.zeros(3), r"has shape \(3,\)"),
        (np.array([1j, 0.0]), "is not a pair of numbers"),
        ("up", "is not a pair of numbers"),
    ):
        for env in (ours, reference):
            with pytest.raises(ValueError, match=message):
                env.step(bad)
        assert_same_aec(ours, reference, f"after {bad!r}")
    for env in (ours, reference):
        env.step(np.zeros(2, dtype=np.float32))
    assert_same_aec(ours, reference, "after the retry")
    with pytest.raises(ValueError, match="only valid action is None"):
        dead = atc_nf_env.raw_env(scenario="converging-3", max_cycles=1)
        dead.reset(seed=0)
        for _ in range(3):
            dead.step(np.zeros(2))
        dead.step(np.zeros(2))  # a truncated agent's turn


def snapshot(value: Any) -> Any:
    return copy.deepcopy(value)


def test_what_the_envs_hand_out_never_changes_afterwards() -> None:
    """A client that keeps an observation or an info (replay buffers do) must not see it
    change when the env steps on: nothing handed out is a view of a buffer reused later."""
    kwargs = {"scenario": "converging-4", "max_aircraft": 5, "expose_wind": True, "max_cycles": 6}
    kept: list[tuple[str, Any, Any]] = []

    def keep(where: str, value: Any) -> None:
        kept.append((where, value, snapshot(value)))

    par = atc_nf_env.parallel_env(**kwargs)
    obs, infos = par.reset(seed=0)
    keep("parallel reset obs", obs)
    keep("parallel reset infos", infos)
    keep("parallel state", par.state())
    while par.agents:
        out = par.step({agent: np.full(2, 0.3) for agent in par.agents})
        keep("parallel step", out)
        keep("parallel state", par.state())

    aec = atc_nf_env.env(**kwargs)
    aec.reset(seed=0)
    for agent in aec.agent_iter():
        keep(f"aec last {agent}", aec.last())
        keep(f"aec observe {agent}", aec.observe(agent))
        # (the dicts themselves are live attributes, cleared and pruned as PettingZoo's AEC
        # API says: what is kept is what they hold)
        keep(f"aec info {agent}", aec.infos[agent])
        _, _, terminated, truncated, _ = aec.last(observe=False)
        aec.step(None if terminated or truncated else np.full(2, -0.2, dtype=np.float32))

    cen = EncounterEnv(**kwargs)
    keep("gym reset", cen.reset(seed=0))
    done = False
    while not done:
        out = cen.step(np.full(cen.action_space.shape, 0.5, dtype=np.float32))
        keep("gym step", out)
        done = out[2] or out[3]

    for where, value, copy_then in kept:
        assert_same_value_deep(value, copy_then, where)


def assert_same_value_deep(got: Any, want: Any, where: str) -> None:
    if isinstance(want, (tuple, list)):
        assert len(got) == len(want), where
        for index, (g, w) in enumerate(zip(got, want)):
            assert_same_value_deep(g, w, f"{where}[{index}]")
    elif isinstance(want, dict):
        assert list(got) == list(want), where
        for key in want:
            assert_same_value_deep(got[key], want[key], f"{where}[{key!r}]")
    else:
        assert_same_value(got, want, where)


def test_parallel_env_takes_every_action_form_and_flies_them_alike() -> None:
    """The quick stacking path and the careful one fly the same episode bit for bit."""

    def episode(form: Any) -> list:
        env = atc_nf_env.parallel_env(scenario="random-4")
        rng = np.random.default_rng(5)
        env.reset(seed=8)
        trace = []
        while env.agents:
            # outside the box too (clipped alike); float32 values, so that every form carries them
            values = rng.uniform(-1.5, 1.5, (4, 2)).astype(np.float32).astype(np.float64)
            obs, rewards, _, _, infos = env.step({a: form(values[i]) for i, a in enumerate(env.agents)})
            trace.append([(a, obs[a].tobytes(), rewards[a], infos[a]["action_clipped"]) for a in obs])
        return trace

    base = episode(lambda v: v)
    assert any(clipped for step in base for *_, clipped in step)
    for form in (lambda v: v.astype(np.float32), list, tuple, lambda v: [float(v[0]), np.float32(v[1])],
                 lambda v: np.array([v[0], v[1]], dtype=object)):
        assert episode(form) == base


def test_gym_env_takes_every_action_form_and_flies_them_alike() -> None:
    def episode(form: Any) -> list:
        env = EncounterEnv(scenario="random-3", max_aircraft=4)
        rng = np.random.default_rng(6)
        env.reset(seed=4)
        trace, done = [], False
        while not done:
            values = rng.uniform(-1.5, 1.5, (4, 2)).astype(np.float32).astype(np.float64)
            obs, reward, terminated, truncated, info = env.step(form(values))
            trace.append((obs.tobytes(), reward, info["action_clipped"].tobytes()))
            done = terminated or truncated
        return trace

    base = episode(lambda v: v)
    for form in (lambda v: v.astype(np.float32), lambda v: v.tolist(), lambda v: np.asfortranarray(v),
                 lambda v: np.repeat(v, 2, axis=0)[::2], lambda v: v.astype(object)):
        assert episode(form) == base


@pytest.mark.parametrize("kwargs", [{"scenario": "converging-4"}, {"scenario": "converging-3", "expose_wind": True,
                                                                    "max_aircraft": 4}])
def test_a_world_reset_after_episodes_flies_as_a_fresh_one(kwargs: dict[str, Any]) -> None:
    """Resets reuse what does not change between episodes of a fixed scenario: an episode
    flown after others (and one cut short) is the fresh env's, bit for bit."""

    def scribble(value: Any) -> None:
        """What a careless client does to what it was handed (must not reach the env)."""
        if isinstance(value, np.ndarray):
            value[...] = 99
        elif isinstance(value, (tuple, list)):
            for item in value:
                scribble(item)
        elif isinstance(value, dict):
            for item in value.values():
                scribble(item)

    def episode(env: ATCParallelEnv, seed: int, steps: int | None = None) -> list:
        rng = np.random.default_rng(seed)
        out = env.reset(seed=seed)
        trace = [(snapshot(out), env.state().tobytes())]
        scribble(out)
        while env.agents and (steps is None or len(trace) <= steps):
            out = env.step({a: rng.uniform(-1.2, 1.2, 2) for a in env.agents})
            trace.append((snapshot(out), env.state().tobytes()))
            scribble(out)
        return trace

    used = atc_nf_env.parallel_env(**kwargs)
    episode(used, 3)
    episode(used, 5, steps=4)
    again = episode(used, 11)
    fresh = episode(atc_nf_env.parallel_env(**kwargs), 11)
    assert len(again) == len(fresh)
    for index, (got, want) in enumerate(zip(again, fresh)):
        assert_same_value_deep(got, want, f"step {index}")

    used_gym, fresh_gym = EncounterEnv(**kwargs), EncounterEnv(**kwargs)
    for seed in (2, 9, 4):
        scribble(used_gym.reset(seed=seed))
        for _ in range(3):
            scribble(used_gym.step(used_gym.action_space.sample()))
    for env in (used_gym, fresh_gym):
        env.action_space.seed(0)
    got, want = used_gym.reset(seed=4), fresh_gym.reset(seed=4)
    assert_same_value_deep(got, want, "gym reset")
    for step in range(5):
        action = used_gym.action_space.sample()
        fresh_gym.action_space.sample()
        assert_same_value_deep(used_gym.step(action), fresh_gym.step(action), f"gym step {step}")


def test_a_copied_aec_env_flies_on_alone() -> None:
    """After its first reset the AEC env's wrapper answers ``last``/``observe`` with the raw
    env's methods: a deep copy (or a pickle) must answer with its own raw env's."""
    import pickle

    env = atc_nf_env.env(scenario="converging-3")
    env.reset(seed=1)
    env.step(np.zeros(2))
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    for other in copies:
        assert other.last.__self__ is other.env and other.observe.__self__ is other.env
    for step in range(5):
        for index, other in enumerate([env, *copies]):
            other.step(np.full(2, 0.1 * index, dtype=np.float32))
    last = [other.last() for other in (env, *copies)]
    assert last[1][0].tobytes() != last[0][0].tobytes() and last[2][0].tobytes() != last[1][0].tobytes()
    replay = atc_nf_env.env(scenario="converging-3")
    replay.reset(seed=1)
    replay.step(np.zeros(2))
    for step in range(5):
        replay.step(np.full(2, 0.1, dtype=np.float32))
    assert_same_value_deep(replay.last(), last[1], "the deep copy")


def _compiled_and_recorded(kwargs: dict[str, Any]) -> tuple[ATCParallelEnv, ATCParallelEnv]:
    """A parallel env without a render mode (its world flies the compiled period) and one
    with (the recorded path), on the same settings."""
    quick = atc_nf_env.parallel_env(**kwargs)
    recorded = atc_nf_env.parallel_env(render_mode="rgb_array", **kwargs)
    assert quick.world.record_every == 0 and recorded.world.record_every > 0
    return quick, recorded


def _fly_both(quick: ATCParallelEnv, recorded: ATCParallelEnv, seed: int, action_bound: float) -> int:
    """One episode of ``seed`` flown by both envs with the same uniform actions in
    ±``action_bound``: asserts the same reset, the same step results, states and clocks at
    every step, and both episodes over together. Returns the steps flown."""
    rng = np.random.default_rng(seed)
    assert_same_value_deep(quick.reset(seed=seed), recorded.reset(seed=seed), f"seed {seed}: reset")
    steps = 0
    while quick.agents:
        actions = {agent: rng.uniform(-action_bound, action_bound, 2) for agent in quick.agents}
        assert_same_value_deep(quick.step(actions), recorded.step(actions), f"seed {seed}, step {steps}")
        assert quick.state().tobytes() == recorded.state().tobytes(), f"seed {seed}, step {steps}"
        assert quick.world.sim.time_s == recorded.world.sim.time_s
        steps += 1
    assert not recorded.agents
    return steps


def test_the_compiled_period_flies_as_the_recorded_path_bit_for_bit() -> None:
    """Without a render mode a world flies its period in one compiled call
    (``centralized._fly_world_period``); with one, through ``Simulation.advance`` (the
    renderer's trails) and the same bookkeeping in steps: both hand out the same bits."""
    quick, recorded = _compiled_and_recorded({"scenario": "random-5", "expose_wind": True})
    for seed in (4, 8):  # the same two envs: the second episode follows a reset
        assert _fly_both(quick, recorded, seed, 1.2) > 3, f"seed {seed}"
    recorded.close()


@settings(max_examples=12, deadline=None)
@given(
    kind=st.sampled_from(["converging", "random"]),
    n_aircraft=st.integers(2, 7),
    seed=st.integers(0, 10_000),
    wind_sigma=st.sampled_from([0.0, 5.17, 25.0]),
    n_neighbours=st.integers(1, 5),
    spare_slots=st.integers(0, 2),
    episode_minutes=st.sampled_from([20.0, 240.0]),
    dt_s=st.sampled_from([5.0, 2.5]),
    expose_wind=st.booleans(),
    action_scale=st.sampled_from([0.0, 1.0, 3.0]),
)
def test_the_compiled_period_flies_as_the_recorded_path_on_drawn_settings(
    kind: str, n_aircraft: int, seed: int, wind_sigma: float, n_neighbours: int, spare_slots: int,
    episode_minutes: float, dt_s: float, expose_wind: bool, action_scale: float,
) -> None:
    """Over drawn encounters, wind, observation settings, episode lengths (truncation),
    integration steps and actions up to 3× outside the box (clipped): the compiled period
    and the recorded path hand out the same bits at the reset and every step, to the end
    of the episode."""
    kwargs: dict[str, Any] = {
        "scenario": f"{kind}-{n_aircraft}", "wind_sigma": wind_sigma, "n_neighbours": n_neighbours,
        "max_aircraft": n_aircraft + spare_slots, "max_episode_minutes": episode_minutes,
        "expose_wind": expose_wind, "config": SimConfig(dt_s=dt_s),
    }
    quick, recorded = _compiled_and_recorded(kwargs)
    assert _fly_both(quick, recorded, seed, action_scale) >= 1
    recorded.close()


def test_the_compiled_period_raises_as_the_kernel_does_and_keeps_the_world() -> None:
    """A NaN in the world's state (written by hand) or a flight that overflows raise the
    kernel's errors, naming what was wrong, and leave the world's buffers as they were."""
    from atc_nf_env.kernel import S_X

    env = atc_nf_env.parallel_env(scenario="converging-3")
    env.reset(seed=0)
    world = env.world
    before = (world.flying, world._flying_spare, world._distance, world._distance_spare, world.info)
    world.sim.state[0, 1, S_X] = np.nan
    with pytest.raises(ValueError, match="state contains NaN or inf"):
        env.step({agent: np.zeros(2) for agent in env.agents})
    assert all(a is b for a, b in zip(before, (world.flying, world._flying_spare, world._distance,
                                               world._distance_spare, world.info)))
    assert world.decisions == 0 and world.sim.time_s == 0.0
    env.reset(seed=0)
    world.sim.state[0, 1, S_X] = 1e308  # finite, but the flight's squares overflow
    with pytest.raises(FloatingPointError, match="NaN or inf"):
        env.step({agent: np.zeros(2) for agent in env.agents})
    env.reset(seed=0)  # a reset brings the world back
    observations, _, _, _, _ = env.step({agent: np.zeros(2) for agent in env.agents})
    assert all(np.isfinite(obs).all() for obs in observations.values())
