"""The compiled forward pass of the agents (``agents.compiled_forward``): its tanh, its dense
layers against a plain float64 reference, a row alone against the same row in a batch,
the packing's refusals, and the shipped models against SB3's ``predict``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.compiled_forward import (
    CLIP,
    IDENTITY,
    RELU,
    SQUASH,
    TANH,
    mlp_actions,
    pack_layers,
    tanh32,
    widest,
)

ROOT = Path(__file__).resolve().parents[1]


def run_mlp(layers, obs: np.ndarray, output: int = CLIP) -> np.ndarray:
    weights, layout = pack_layers(layers)
    buffers = [np.zeros(widest(layout), dtype=np.float32) for _ in range(2)]
    out = np.empty((obs.shape[0], layout[-1, 1]), dtype=np.float32)
    assert mlp_actions(np.ascontiguousarray(obs, dtype=np.float32), weights, layout, output, *buffers, out)
    return out


def random_layers(rng: np.random.Generator, sizes: list[int], activations: list[int]):
    return [
        (rng.normal(0, 0.4, (d_in, d_out)).astype(np.float32), rng.normal(0, 0.2, d_out).astype(np.float32),
         act)
        for d_in, d_out, act in zip(sizes[:-1], sizes[1:], activations)
    ]


def reference(layers, obs: np.ndarray, output: int) -> np.ndarray:
    x = obs.astype(np.float64)
    for weight, bias, act in layers:
        x = x @ weight.astype(np.float64) + bias
        x = np.tanh(x) if act == TANH else np.maximum(x, 0.0) if act == RELU else x
    return np.tanh(x) if output == SQUASH else np.clip(x, -1.0, 1.0)


@settings(max_examples=300, deadline=None)
@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=32))
def test_tanh32_is_within_three_float32_ulps_up_to_its_clamp_and_2_4e_7_beyond(x: float) -> None:
    """Beyond the clamp (|x| > 7.905) tanh32 returns its value there, within 2.4e-7 of +-1:
    3.5 ulps of a float32 near 1 (hypothesis found x = 9.0 at 3.5 ulps)."""
    from agents.compiled_forward import _TANH_CLAMP

    value = np.float32(x)
    exact = np.tanh(np.float64(value))
    got = float(tanh32(value))
    ulps = 3.0 if abs(float(value)) <= _TANH_CLAMP else 3.5
    assert abs(got - exact) <= ulps * np.spacing(np.float32(abs(exact))) + 1e-45
    assert abs(got - exact) <= 2.4e-7
    assert -1.0 <= got <= 1.0


def test_tanh32_at_values_beyond_its_clamp() -> None:
    for x in (8.66435, 9.0, 12.0, 1e6):
        exact = np.tanh(np.float64(np.float32(x)))
        assert abs(float(tanh32(np.float32(x))) - exact) <= 3.5 * np.spacing(np.float32(exact))


def test_tanh32_on_a_dense_grid_and_its_symmetry() -> None:
    x = np.linspace(-12.0, 12.0, 200_001).astype(np.float32)
    got = np.array([tanh32(v) for v in x[::97]], dtype=np.float64)
    exact = np.tanh(x[::97].astype(np.float64))
    assert np.abs(got - exact).max() < 3e-7
    assert all(tanh32(np.float32(v)) == -tanh32(np.float32(-v)) for v in (0.25, 1.5, 4.0, 9.0))
    assert tanh32(np.float32(0.0)) == 0.0


@pytest.mark.parametrize("sizes,activations,output", [
    ([28, 64, 64, 2], [TANH, TANH, IDENTITY], CLIP),
    ([7, 5, 3, 9, 2], [RELU, TANH, RELU, IDENTITY], SQUASH),
    ([3, 2], [IDENTITY], CLIP),
])
def test_mlp_matches_a_float64_reference(sizes, activations, output) -> None:
    rng = np.random.default_rng(sum(sizes))
    layers = random_layers(rng, sizes, activations)
    obs = rng.normal(0, 2, (40, sizes[0])).astype(np.float32)
    np.testing.assert_allclose(run_mlp(layers, obs, output), reference(layers, obs, output), atol=2e-5)


def test_a_row_alone_gives_the_same_bits_as_in_any_batch() -> None:
    rng = np.random.default_rng(3)
    layers = random_layers(rng, [28, 64, 64, 2], [TANH, TANH, IDENTITY])
    obs = rng.normal(0, 2, (33, 28)).astype(np.float32)
    batch = run_mlp(layers, obs)
    alone = np.concatenate([run_mlp(layers, obs[i : i + 1]) for i in range(len(obs))])
    assert np.array_equal(batch, alone)
    assert np.array_equal(run_mlp(layers, obs[::-1])[::-1], batch)


def test_packing_refuses_layers_that_do_not_chain() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="at least one layer"):
        pack_layers([])
    with pytest.raises(ValueError, match="inputs after one of"):
        pack_layers(random_layers(rng, [4, 5], [TANH]) + random_layers(rng, [6, 2], [IDENTITY]))
    with pytest.raises(ValueError, match="bias of shape"):
        pack_layers([(np.zeros((3, 2), np.float32), np.zeros(3, np.float32), IDENTITY)])
    with pytest.raises(ValueError, match="activation"):
        pack_layers([(np.zeros((3, 2), np.float32), np.zeros(2, np.float32), 7)])


def test_the_policy_refuses_observations_of_the_wrong_size_or_not_finite() -> None:
    pytest.importorskip("stable_baselines3")
    from agents.policy import SB3AgentPolicy

    policy = SB3AgentPolicy(ROOT / "agents" / "models" / "finetuned_ppo.zip")
    dim = int(np.prod(policy.model.observation_space.shape))
    with pytest.raises(ValueError, match=rf"expected \(B, {dim}\)"):
        policy.actions(np.zeros((2, dim + 1), dtype=np.float32))
    for bad in (np.nan, np.inf, 1e39):  # 1e39 overflows float32 to inf
        obs = np.zeros((3, dim))
        obs[1, 2] = bad
        with pytest.raises(ValueError, match="NaN or inf"), np.errstate(over="ignore"):
            policy.actions(obs)


@pytest.mark.parametrize("model", ["finetuned_ppo.zip", "deepsets_mixed.zip"])
def test_both_architectures_refuse_observations_that_are_not_finite(model: str) -> None:
    pytest.importorskip("stable_baselines3")
    from agents.policy import SB3AgentPolicy

    policy = SB3AgentPolicy(ROOT / "agents" / "models" / model)
    dim = int(np.prod(policy.model.observation_space.shape))
    obs = np.zeros((4, dim), dtype=np.float32)
    obs[3, dim - 1] = np.nan  # the last row's last value: checked before anything is computed
    with pytest.raises(ValueError, match="NaN or inf"):
        policy.actions(obs)


@pytest.mark.parametrize("model", sorted(p.name for p in (ROOT / "agents" / "models").glob("*.zip")))
def test_shipped_models_agree_with_sb3_predict(model: str) -> None:
    pytest.importorskip("stable_baselines3")
    from agents.deepsets import N_NEIGHBOUR, N_OWN
    from agents.policy import SB3AgentPolicy

    policy = SB3AgentPolicy(ROOT / "agents" / "models" / model)
    assert policy._forward is not None, "every shipped model has a compiled forward pass"
    dim = int(np.prod(policy.model.observation_space.shape))
    rng = np.random.default_rng(5)
    obs = rng.uniform(-2, 2, (64, dim)).astype(np.float32)
    if model.startswith("deepsets"):
        for slot in range((dim - N_OWN) // N_NEIGHBOUR):
            present = rng.uniform(size=64) < 0.5
            base = N_OWN + slot * N_NEIGHBOUR
            obs[:, base] = present
            obs[~present, base : base + N_NEIGHBOUR] = 0.0
    expected, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.actions(obs), expected, atol=1e-5)


@pytest.mark.parametrize("model", ["finetuned_ppo.zip", "deepsets_mixed.zip"])
def test_the_benchs_numpy_yardstick_computes_the_same_actions(model: str) -> None:
    """``bench/bench_agent_forward.py`` times the compiled pass against a NumPy pass: both
    must compute the same function for the ratio to mean anything."""
    pytest.importorskip("stable_baselines3")
    import sys

    from agents.policy import SB3AgentPolicy

    sys.path.insert(0, str(ROOT / "bench"))
    from bench_agent_forward import numpy_actions

    policy = SB3AgentPolicy(ROOT / "agents" / "models" / model)
    dim = int(np.prod(policy.model.observation_space.shape))
    obs = np.random.default_rng(8).uniform(-2, 2, (40, dim)).astype(np.float32)
    obs[:, 8::5] = obs[:, 8::5] > 0  # slot masks of the deep-sets layout (own features: 8)
    np.testing.assert_allclose(numpy_actions(policy.model)(obs), policy.actions(obs), atol=1e-5)


@pytest.mark.parametrize("model", ["finetuned_ppo.zip", "deepsets_mixed.zip"])
def test_act_on_kept_buffers_gives_the_waypoints_of_the_general_path_bit_for_bit(model: str) -> None:
    """``SB3AgentPolicy.act`` decides on buffers it keeps between decisions where the state
    fits them; elsewhere (a state of another shape or layout) it takes the general path.
    Both must give the same waypoints, and a returned array must not change afterwards."""
    pytest.importorskip("stable_baselines3")
    from agents.policy import SB3AgentPolicy
    from atc_nf_env.config import SimConfig
    from atc_nf_env.kernel import S_STATUS, S_X
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.simulation import WorldView, initial_state

    policy = SB3AgentPolicy(ROOT / "agents" / "models" / model)
    scenario = make_scenario("random-6", seed=3)
    policy.reset(scenario, SimConfig(), 0)
    assert policy._buffers is not None
    rng = np.random.default_rng(11)
    kept = []
    for k in range(5):
        state = initial_state(scenario)[0]
        state[:, S_X] += rng.normal(0.0, 30.0, len(state))
        state[k % len(state), S_STATUS] = 1.0  # one aircraft home: it keeps its waypoint
        view = WorldView(time_s=300.0 * k, state=state, scenario=scenario)
        fast = policy.act(view)
        general = policy.act(WorldView(time_s=300.0 * k, state=np.asfortranarray(state), scenario=scenario))
        assert np.array_equal(fast, general)
        kept.append((fast, fast.copy()))
    assert all(np.array_equal(a, b) for a, b in kept)
