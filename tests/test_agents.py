"""The Stable-Baselines3 agents: tiny runs of `atc-nf train` and `atc-nf imitate`, behaviour
cloning, the agent policy (observations, actions, compiled forward pass), the shipped models."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("supersuit")

import atc_nf_env  # noqa: E402
from agents import imitate  # noqa: E402
from agents.policy import SB3AgentPolicy, compiled_forward, read_meta  # noqa: E402
from atc_nf_env import cli  # noqa: E402
from atc_nf_env.config import SimConfig  # noqa: E402
from atc_nf_env.envs.actions import waypoint_to_action  # noqa: E402
from atc_nf_env.envs.observations import ObservationSpec  # noqa: E402
from atc_nf_env.episode import run_episode  # noqa: E402
from atc_nf_env.evaluate import make_policy  # noqa: E402
from atc_nf_env.kernel import (  # noqa: E402
    S_DEST_HEADING,
    S_DEST_Y,
    S_HEADING,
    S_SIN_D,
    S_THETA_D,
    S_THETA_NH,
    S_WP_Y,
    S_Y,
)
from atc_nf_env.scenarios import make_scenario  # noqa: E402
from atc_nf_env.simulation import Simulation  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "agents" / "models").glob("*.zip"))
TINY_TRAIN = ["--total-timesteps", "128", "--num-envs", "2", "--n-steps", "16", "--batch-size", "32",
              "--no-progress", "--checkpoint-every", "64"]


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A parameter-shared PPO model from a tiny `atc-nf train` run through SuperSuit."""
    out = tmp_path_factory.mktemp("train")
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    return out / "model.zip"


# ------------------------------------------------------------------ entry points


def test_train_shared_supersuit_writes_model_checkpoints_logs(tiny_model: Path) -> None:
    out = tiny_model.parent
    assert tiny_model.is_file()
    assert sorted(p.name for p in (out / "checkpoints").glob("*.zip")) == ["model_128.zip", "model_64.zip"]
    assert any((out / "tb").rglob("events.out.tfevents.*"))
    record = json.loads((out / "config.json").read_text())
    assert record["command"].startswith("atc-nf train ")
    assert record["config"]["seed"] == 0 and record["wall_s"] > 0
    meta = read_meta(tiny_model)
    assert meta["algo"] == "ppo" and meta["mode"] == "shared"
    assert meta["env"]["n_neighbours"] == 4 and meta["env"]["expose_wind"] is False


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_train_centralized_native(tmp_path: Path, algo: str) -> None:
    args = ["train", "--mode", "centralized", "--algo", algo, "--scenario", "converging-3", "--max-aircraft", "4",
            "--out", str(tmp_path), *TINY_TRAIN]
    if algo == "sac":
        args += ["--learning-starts", "32", "--buffer-size", "1000"]
    assert cli.main(args) == 0
    policy = SB3AgentPolicy(tmp_path / "model.zip")
    assert policy.mode == "centralized" and policy.n_slots == 4
    result = run_episode(policy, make_scenario("converging-3"), seed=0, max_time_s=1800)
    assert result.metrics.decisions == 6
    obs = np.random.default_rng(0).uniform(-2, 2, (5, 4 * ObservationSpec().dim)).astype(np.float32)
    predicted, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.actions(obs).reshape(predicted.shape), predicted, atol=1e-5)


def test_train_rejects_bad_combinations(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["train", "--algo", "sac", "--mode", "shared"]) == 2
    assert "--mode centralized" in capsys.readouterr().err
    assert cli.main(["train", "--init-from", "nowhere.zip"]) == 2


@pytest.mark.parametrize("command", ["train", "imitate"])
def test_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main([command, "--help"])
    assert exit_info.value.code == 0
    assert "--out" in capsys.readouterr().out


def test_imitate_tiny_run_resumes(tmp_path: Path) -> None:
    args = ["imitate", "--out", str(tmp_path), "--episodes", "converging-3:2", "--expert-extractions", "10",
            "--expert-horizon", "2", "--max-minutes", "40", "--no-arrived-only", "--bc-epochs", "2", "--dagger-iterations", "1",
            "--dagger-episodes", "converging-3:1", "--dagger-epochs", "1", "--finetune-steps", "96",
            "--finetune-num-envs", "1", "--finetune-value-warmup", "1", "--check-runs", "1", "--workers", "1",
            "--no-progress"]
    assert cli.main(args) == 0
    for name in ("bc.zip", "dagger-1.zip", "finetune/model.zip", "log.json"):
        assert (tmp_path / name).is_file(), name
    demos = sorted(p.name for p in (tmp_path / "demos" / "expert" / "converging-3").glob("*.npz"))
    assert demos == ["seed_10000.npz", "seed_10001.npz"]
    with np.load(tmp_path / "demos" / "dagger-1" / "converging-3" / "seed_110000.npz") as data:
        assert data["obs"].shape[1] == ObservationSpec().dim and data["act"].shape == (len(data["obs"]), 2)
        assert not bool(data["expert_acted"]) and np.all(np.abs(data["act"]) <= 1)
    log = json.loads((tmp_path / "log.json").read_text())
    assert log["stages"]["demonstrations"]["collected_now"] == 2
    assert set(log["stages"]) >= {"demonstrations", "bc", "dagger-1", "finetune"}
    # Run again: nothing is collected or trained twice.
    assert cli.main(args) == 0
    log = json.loads((tmp_path / "log.json").read_text())
    assert log["stages"]["demonstrations"]["collected_now"] == 0
    assert log["stages"]["bc"]["reused"] and log["stages"]["finetune"]["reused"]


# ------------------------------------------------------------------ behaviour cloning


def test_behaviour_cloning_lowers_the_imitation_loss_on_a_fixed_dataset() -> None:
    rng = np.random.default_rng(0)
    dim = ObservationSpec().dim
    obs = rng.normal(size=(2000, dim)).astype(np.float32)
    weights = rng.normal(scale=0.3, size=(dim, 2))
    act = np.clip(np.tanh(obs @ weights), -1, 1).astype(np.float32)
    data = imitate.Dataset(obs, act, episode=np.arange(2000) // 20, episodes=100, mirrored=0, dropped=0)
    for loss in ("nll", "mse"):
        model = imitate.new_model([32, 32], -1.0, seed=0)
        history = imitate.behaviour_cloning(model, data, epochs=8, batch_size=128, learning_rate=3e-3,
                                            val_fraction=0.2, loss=loss, seed=0)
        first, last = history["epochs"][0], history["epochs"][-1]
        assert history["best_validation_loss"] < 0.5 * history["initial_validation_loss"]
        assert last["val_mse"] < 0.5 * first["val_mse"] or last["val_mse"] < 0.02
        assert last["train_loss"] < first["train_loss"]


def _mirror_state(state: np.ndarray) -> np.ndarray:
    """The world reflected in the x axis (y -> -y, angles -> -angles)."""
    m = state.copy()
    for index in (S_Y, S_DEST_Y, S_WP_Y, S_SIN_D):
        m[..., index] = -m[..., index]
    for index in (S_HEADING, S_THETA_NH, S_THETA_D, S_DEST_HEADING):
        m[..., index] = -m[..., index]
    return m


def test_mirroring_an_observation_is_observing_the_mirrored_world() -> None:
    sim = Simulation(make_scenario("random-5", seed=3), wind_kt=(10.0, -20.0))
    sim.advance(sim.view().destinations, 900)
    spec = ObservationSpec.for_config(SimConfig(), 4, False)
    state = sim.state
    obs = spec.observe(state, np.array([0.1]), np.zeros((1, 2)))
    mirrored = spec.observe(_mirror_state(state), np.array([0.1]), np.zeros((1, 2)))
    np.testing.assert_allclose(mirrored, obs * imitate.mirror_signs(4), atol=1e-5)
    # And the action's angle changes sign.
    view = sim.view()
    waypoints = view.positions + np.array([80.0, 30.0])
    action = waypoint_to_action(waypoints, view.positions, view.destinations)
    flip = np.array([1.0, -1.0])
    mirrored_action = waypoint_to_action(waypoints * flip, view.positions * flip, view.destinations * flip)
    np.testing.assert_allclose(mirrored_action, action * flip, atol=1e-5)


def test_chirality_sign() -> None:
    angles = np.linspace(0, 1, 5)
    ccw = np.stack([np.cos(angles), np.sin(angles)], axis=-1)[:, None, :] * 100
    flying = np.ones((5, 1), dtype=bool)
    assert imitate.chirality(ccw, flying) > 0
    assert imitate.chirality(ccw * np.array([1, -1]), flying) < 0


# ------------------------------------------------------------------ the agent policy


def test_agent_observations_and_waypoints_are_the_envs(tiny_model: Path) -> None:
    """The parallel env flown with the model's actions on its own observations moves the
    aircraft exactly as run_episode with SB3AgentPolicy does."""
    policy = SB3AgentPolicy(tiny_model)
    env = atc_nf_env.parallel_env(scenario="converging-4")
    obs, _ = env.reset(seed=7)
    waypoints_env = []
    for _ in range(5):
        batch = np.stack([obs[a] for a in env.agents])
        predicted, _ = policy.model.predict(batch, deterministic=True)
        obs, _, _, _, infos = env.step({a: predicted[i] for i, a in enumerate(env.agents)})
        waypoints_env.append(np.stack([infos[a]["waypoint_nm"] for a in env.possible_agents]))
    result = run_episode(policy, make_scenario("converging-4"), seed=7, max_time_s=5 * 300)
    # float32 rounding differs between NumPy and torch (~1e-6 nm); everything else is identical.
    np.testing.assert_allclose(result.waypoints, np.stack(waypoints_env), atol=1e-3)


def test_compiled_forward_equals_sb3_predict(tiny_model: Path) -> None:
    policy = SB3AgentPolicy(tiny_model)
    obs = np.random.default_rng(1).uniform(-3, 3, (64, ObservationSpec().dim)).astype(np.float32)
    predicted, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(compiled_forward(policy.model)(obs), predicted, atol=1e-5)
    slow = SB3AgentPolicy(tiny_model, fast=False)
    assert slow._forward is None
    np.testing.assert_allclose(slow.actions(obs), predicted, atol=1e-6)


def test_make_policy_accepts_a_zip_and_says_what_is_wrong(tiny_model: Path, tmp_path: Path) -> None:
    assert isinstance(make_policy(str(tiny_model)), SB3AgentPolicy)
    with pytest.raises(ValueError, match="no such model file"):
        make_policy(str(tmp_path / "missing.zip"))
    with pytest.raises(ValueError, match=r"\.zip"):
        make_policy("ppo")
    bad = tmp_path / "bad.zip"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model"):
        SB3AgentPolicy(bad)


def test_cli_fly_with_a_model(tiny_model: Path, tmp_path: Path) -> None:
    summary = tmp_path / "s.json"
    assert cli.main(["fly", "--policy", str(tiny_model), "--scenario", "converging-3", "--max-minutes", "30",
                     "--summary-json", str(summary), "--plots", str(tmp_path / "figs")]) == 0
    assert json.loads(summary.read_text())["runs"] == 1
    assert (tmp_path / "figs" / "converging-3_model_trajectories.png").is_file()


# ------------------------------------------------------------------ shipped models


def test_models_are_shipped_with_cards() -> None:
    assert SHIPPED, "agents/models/ holds no model"
    for path in SHIPPED:
        assert path.stat().st_size < 5 * 2**20, f"{path.name} is over 5 MB"
        card = path.with_suffix(".md")
        assert card.is_file(), f"{path.name} has no model card {card.name}"
        text = card.read_text()
        assert "atc-nf" in text and "seed" in text.lower()


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_model_loads_and_flies_an_episode(path: Path) -> None:
    policy = SB3AgentPolicy(path)
    result = run_episode(policy, make_scenario("converging-4"), seed=0)
    metrics = result.metrics
    assert metrics.decisions > 5 and metrics.steps_flown > 0
    assert metrics.los_count == 0


@pytest.mark.parametrize("path", SHIPPED[:1], ids=[p.stem for p in SHIPPED[:1]])
def test_cli_evaluate_with_a_shipped_model(path: Path, tmp_path: Path) -> None:
    summary = tmp_path / "summary.json"
    rel = path.relative_to(ROOT)
    argv = ["evaluate", "--policy", str(rel), "--runs", "2", "--workers", "1", "--no-progress",
            "--summary-json", str(summary)]
    import os

    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        assert cli.main(argv) == 0
    finally:
        os.chdir(cwd)
    data = json.loads(summary.read_text())
    assert data["runs"] == 2 and data["policy"] == str(rel)


def test_benchmark_table_and_mpc_reuse(tmp_path: Path) -> None:
    from agents import benchmark
    from atc_nf_env.evaluate import Study

    model = str(SHIPPED[0])
    results = benchmark.run([model], ["converging-3"], runs=1, mpc_runs=1, out=tmp_path / "a", reuse_mpc=None,
                            workers=1, progress=False)
    assert set(results["converging-3"]) == {"nf", "mpc", SHIPPED[0].stem}
    text = benchmark.table(results)
    assert text.count("\n") == 2 + 3 and "| converging-3 | mpc | 1 |" in text
    header, _, *rows = text.splitlines()
    for column in ("runs with LoS", "min separation", "runs outside envelope", "runs at airspeed cap",
                   "worst excursion", "95 % CI"):
        assert column in header
    assert all(row.count("|") == header.count("|") for row in rows)
    assert "n/a" not in "".join(row.split("|")[7] for row in rows)  # every policy counts runs outside
    # An earlier MPC study of the same seeds (e.g. the reproduction's) is copied, not flown again.
    source = tmp_path / "reproduction"
    source.mkdir()
    lines = (tmp_path / "a" / "converging-3" / "mpc.jsonl").read_text().splitlines()
    header = json.loads(lines[0]) | {"airspeed_every_s": 60.0}
    (source / "mpc_converging3.jsonl").write_text("\n".join([json.dumps(header), *lines[1:]]) + "\n")
    target = tmp_path / "b" / "mpc.jsonl"
    assert benchmark.reuse_mpc_runs(Study(policy="mpc", scenario="converging-3"), 1, source, target) == 1
    assert benchmark.reuse_mpc_runs(Study(policy="mpc", scenario="converging-4"), 1, source, tmp_path / "c.jsonl") == 0


def test_benchmark_starts_at_the_first_seed_it_is_given(tmp_path: Path) -> None:
    from agents import benchmark
    from atc_nf_env.evaluate import read_results

    results = benchmark.run([], ["converging-3"], runs=2, mpc_runs=2, out=tmp_path, reuse_mpc=None, workers=1,
                            progress=False, baselines=("nf",), first_seed=1_000_000_000)
    assert results["converging-3"]["nf"]["study"]["seeds"] == [1_000_000_000, 1_000_000_001]
    _, records = read_results(tmp_path / "converging-3" / "nf.jsonl")
    assert sorted(r["seed"] for r in records) == [1_000_000_000, 1_000_000_001]


def test_train_progress_bar_ends_at_what_really_runs(capsys) -> None:
    from stable_baselines3 import PPO

    from agents._config import planned_timesteps, progress_callback
    from atc_nf_env.envs.vector import make_sb3_vec_env

    venv = make_sb3_vec_env(2, mode="shared", scenario="converging-3")
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, seed=0)
    rollout = 8 * venv.num_envs
    assert planned_timesteps(model, 10) == rollout and planned_timesteps(model, rollout + 1) == 2 * rollout
    callback = progress_callback(rollout + 1, enabled=True)
    model.learn(rollout + 1, callback=callback)
    assert model.num_timesteps == 2 * rollout
    assert callback.bar.n == callback.bar.total == 2 * rollout
    venv.close()
