"""The policy over any number of aircraft (deep sets over the neighbour set), the models'
operating range (warn once / refuse), the generated model cards, the learning curve."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents import cards, imitate  # noqa: E402
from agents.deepsets import N_NEIGHBOUR, N_OWN, NeighbourSetExtractor  # noqa: E402
from agents.policy import OutsideOperatingRangeWarning, SB3AgentPolicy, compiled_forward, env_meta  # noqa: E402
from agents.train import CURVE_HEADER, save_model  # noqa: E402
from atc_nf_env.envs import EnvConfig  # noqa: E402
from atc_nf_env.episode import run_episode  # noqa: E402
from atc_nf_env.metrics import wilson_interval  # noqa: E402
from atc_nf_env.scenarios import make_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "agents" / "models").glob("*.zip"))
K = 6


def random_observations(n: int, k: int, seed: int = 0) -> np.ndarray:
    """Ego observations with 0..k neighbours present (absent slots all zeros, as the envs write them)."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, N_OWN + N_NEIGHBOUR * k)).astype(np.float32)
    slots = obs[:, N_OWN:].reshape(n, k, N_NEIGHBOUR)
    present = np.arange(k)[None, :] < rng.integers(0, k + 1, size=n)[:, None]
    slots[:, :, 0] = present
    slots[~present] = 0.0
    return obs


@pytest.fixture(scope="module")
def deepsets_model():
    return imitate.new_model([16, 16], -1.0, seed=0, n_neighbours=K, policy_arch="deepsets", deepsets_hidden=8)


def test_deepsets_actions_ignore_the_order_of_neighbours(deepsets_model) -> None:
    obs = random_observations(64, K)
    action, _ = deepsets_model.predict(obs, deterministic=True)
    rng = np.random.default_rng(1)
    shuffled = obs.copy()
    for row in shuffled:
        slots = row[N_OWN:].reshape(K, N_NEIGHBOUR)
        slots[:] = slots[rng.permutation(K)]
    again, _ = deepsets_model.predict(shuffled, deterministic=True)
    np.testing.assert_allclose(again, action, atol=1e-5)
    # ...but not the neighbours themselves: moving one present neighbour changes some action.
    moved = obs.copy()
    has = moved[:, N_OWN] == 1
    moved[has, N_OWN + 1] += 0.5
    changed, _ = deepsets_model.predict(moved, deterministic=True)
    assert np.abs(changed[has] - action[has]).max() > 1e-4


def test_deepsets_compiled_forward_equals_sb3_predict(deepsets_model) -> None:
    forward = compiled_forward(deepsets_model)
    assert forward is not None
    obs = random_observations(50, K, seed=2)
    expected, _ = deepsets_model.predict(obs, deterministic=True)
    np.testing.assert_allclose(forward(obs), expected, atol=1e-5)


def test_deepsets_extractor_refuses_a_layout_it_cannot_read() -> None:
    from gymnasium import spaces

    with pytest.raises(ValueError, match="observation size"):
        NeighbourSetExtractor(spaces.Box(-1, 1, shape=(N_OWN + 3,)))
    with pytest.raises(ValueError, match="hidden"):
        NeighbourSetExtractor(spaces.Box(-1, 1, shape=(N_OWN + N_NEIGHBOUR,)), hidden=0)


def test_behaviour_cloning_trains_the_deepsets_encoders() -> None:
    model = imitate.new_model([16, 16], -1.0, seed=0, n_neighbours=K, policy_arch="deepsets", deepsets_hidden=8)
    obs = random_observations(1000, K, seed=3)
    act = np.tanh(obs[:, [2, N_OWN + 1]]).astype(np.float32)  # depends on own and neighbour features
    data = imitate.Dataset(obs, act, episode=np.arange(1000) // 10, episodes=100, mirrored=0, dropped=0)
    before = [p.detach().clone() for p in model.policy.features_extractor.parameters()]
    history = imitate.behaviour_cloning(model, data, epochs=4, batch_size=100, learning_rate=3e-3,
                                        val_fraction=0.2, loss="mse", seed=0)
    assert history["best_validation_loss"] < history["initial_validation_loss"]
    after = list(model.policy.features_extractor.parameters())
    assert any(not np.allclose(a.detach().numpy(), b.numpy()) for a, b in zip(after, before))


def test_wind_sigma_of_training_episodes() -> None:
    assert imitate.wind_sigma_range("") == (5.17, 5.17)
    assert imitate.wind_sigma_range("0,10") == (0.0, 10.0)
    sigmas = [imitate.episode_wind_sigma(s, (0.0, 10.0)) for s in range(200)]
    assert min(sigmas) >= 0 and max(sigmas) <= 10 and np.std(sigmas) > 2
    assert imitate.episode_wind_sigma(7, (0.0, 10.0)) == imitate.episode_wind_sigma(7, (0.0, 10.0))
    for bad in ("10,0", "a,b", "1"):
        with pytest.raises(ValueError, match="--wind-sigmas"):
            imitate.wind_sigma_range(bad)


# ------------------------------------------------------------------ operating range


@pytest.fixture(scope="module")
def ranged_model(deepsets_model, tmp_path_factory: pytest.TempPathFactory) -> Path:
    meta = {"algo": "ppo", "mode": "shared", "env": env_meta(EnvConfig(n_neighbours=K)),
            "operating_range": {"n_aircraft": [3, 5], "wind_sigma_mps": [0.0, 6.0]},
            "training": {"script": "atc-nf imitate", "command": "atc-nf imitate --policy-arch deepsets"}}
    return save_model(deepsets_model, tmp_path_factory.mktemp("ranged") / "ranged.zip", meta)


def test_model_flies_any_number_of_aircraft_and_warns_once_outside_its_range(ranged_model: Path) -> None:
    policy = SB3AgentPolicy(ranged_model)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inside the range: not a word
        run_episode(policy, make_scenario("converging-4"), seed=0, wind_sigma_mps=5.0, max_time_s=600.0)
    with pytest.warns(OutsideOperatingRangeWarning, match="8 aircraft"):
        result = run_episode(policy, make_scenario("converging-8"), seed=0, max_time_s=600.0)
    assert result.metrics.decisions == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per model and process
        run_episode(SB3AgentPolicy(ranged_model), make_scenario("random-16", seed=1), seed=1, max_time_s=600.0)
    refusing = SB3AgentPolicy(ranged_model, outside_range="refuse")
    with pytest.raises(ValueError, match="wind sigma 9 m/s"):
        run_episode(refusing, make_scenario("converging-4"), seed=0, wind_sigma_mps=9.0, max_time_s=600.0)
    with pytest.raises(ValueError, match="outside_range"):
        SB3AgentPolicy(ranged_model, outside_range="maybe")


def test_saved_models_carry_their_provenance(ranged_model: Path) -> None:
    from agents.policy import read_meta
    from atc_nf_env import build

    prov = read_meta(ranged_model)["provenance"]
    assert prov["build"] == build.fingerprint()
    assert prov["sim_config"]["dt_s"] == 5.0 and "torch" in prov["libraries"]


# ------------------------------------------------------------------ cards


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_cards_are_complete(path: Path) -> None:
    from agents.policy import read_meta

    meta = read_meta(path)
    rng = cards.operating_range(meta)
    assert rng is not None and rng["n_aircraft"][0] <= 4 <= rng["n_aircraft"][1]
    text = path.with_suffix(".md").read_text()
    for section in ("## Code version", "## Libraries", "## Simulation settings the model depends on",
                    "## Operating range", "## Results on held-out seeds", "## Intended use", "## Known failures"):
        assert section in text, section
    assert "95 % CI" in text and "arrival tolerance" in text and "dt = 5 s" in text


def test_card_of_a_fresh_model_reports_its_provenance_and_results(ranged_model: Path) -> None:
    summary = {"converging-4": {ranged_model.stem: {
        "runs": 10, "success_rate": 0.9, "runs_with_los": 1, "min_separation_nm": {"min": 4.2},
        "runs_with_envelope_violation": 2, "runs_at_airspeed_cap": 0, "worst_envelope_excursion_kt": 12.0,
        "flight_time_min": {"mean": 70.0}, "wall_s_per_decision": 3e-5,
        "study": {"wind_sigma_mps": 5.17, "seeds": [0, 9]}}}}
    text = cards.card(ranged_model, [(Path("s.json"), summary)])
    assert "Trained at git commit" in text or "build fingerprint" in text
    assert "Trained on 3–5 aircraft and wind σ 0–6 m/s" in text
    assert "| converging-4 | 5.17 | yes | 10 | 90.0 % [59.6, 98.2] | 1 |" in text
    assert "1 run(s) with a loss of separation" in text and "2 run(s) outside the envelope" in text


def test_cards_use_the_evaluators_wilson_interval() -> None:
    assert cards.wilson_interval is wilson_interval
    low, high = wilson_interval(300, 300)
    assert abs(low - 300 / (300 + 1.959963984540054**2)) < 1e-12 and abs(high - 1.0) < 1e-12
    with pytest.raises(ValueError):
        wilson_interval(0, 0)


# ------------------------------------------------------------------ learning curve


def test_train_writes_a_learning_curve_and_stops_at_its_wall_budget(tmp_path: Path) -> None:
    from atc_nf_env import cli

    argv = ["train", "--mode", "shared", "--vec", "native", "--scenario", "converging-3", "--total-timesteps",
            "100000", "--num-envs", "2", "--n-steps", "16", "--batch-size", "48", "--n-epochs", "1",
            "--max-wall-minutes", "0.0001", "--no-progress", "--checkpoint-every", "0", "--out", str(tmp_path)]
    assert cli.main(argv) == 0
    lines = (tmp_path / "curve.csv").read_text().splitlines()
    assert lines[0] == CURVE_HEADER and len(lines) == 2  # one rollout, then the budget stops it
    assert lines[1].startswith("96,")  # 2 worlds x 3 slots x 16 steps
    from agents.policy import read_meta

    # The budget is checked at each rollout's end and stops the next rollout at its first step.
    assert read_meta(tmp_path / "model.zip")["training"]["timesteps_done"] == 96 + 6


def test_shared_vec_env_reports_arrival_as_is_success() -> None:
    from atc_nf_env.envs.vector import EncounterVectorEnv, make_sb3_vec_env

    kwargs = {"scenario": "random-3", "max_episode_minutes": 100}
    venv = make_sb3_vec_env(1, mode="shared", **kwargs)
    venv.seed(3)
    venv.reset()
    twin = EncounterVectorEnv(1, **kwargs)  # the same world, whose info says who arrived
    twin.reset(seed=3)
    actions = np.array([[1.0, 0.0], [-1.0, 0.5], [0.0, -0.5]], dtype=np.float32)
    for _ in range(100):
        _, _, dones, infos = venv.step(actions)
        *_, info = twin.step(actions[None])
        if dones.any():
            break
    assert dones.all()
    assert [i["is_success"] for i in infos] == info["arrived"][0].tolist()
