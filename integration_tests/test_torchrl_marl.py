"""TorchRL 0.14: the batched env (``AtcNfBatchedEnv``) and the IPPO/MAPPO trainers of
``agents.marl_torchrl`` with their policy loader (the torch venv of ``make test-integrations``)."""

from __future__ import annotations

# agents.marl_torchrl first: it sets OMP_WAIT_POLICY=PASSIVE before torch loads OpenMP.
from agents.marl_torchrl import PPOConfig, TorchRLPolicy, score, train  # noqa: I001

import csv
import importlib
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs, step_mdp

import atc_nf_env
from atc_nf_env.episode import run_episode
from atc_nf_env.integrations.torchrl import GROUP, AtcNfBatchedEnv

ROOT = Path(__file__).resolve().parents[1]
TINY = PPOConfig(num_envs=4, steps_per_batch=16, minibatch_frames=32, eval_every_batches=2, eval_runs=2)


def random_rollout(env, steps: int, seed: int):
    """``steps`` env steps with actions from a seeded generator, resets of the worlds that ended."""
    generator = torch.Generator().manual_seed(seed)
    td = env.reset()
    out = []
    for _ in range(steps):
        td.set((GROUP, "action"), torch.rand(env.num_envs, env.n_slots, 2, generator=generator) * 2 - 1)
        td, nxt = env.step_and_maybe_reset(td)
        out.append(td.clone())
        td = nxt
    return torch.stack(out, dim=1)


@pytest.mark.parametrize("kwargs", [{"scenario": "converging-4"}, {"scenario": "random-5", "max_aircraft": 7}])
def test_batched_env_passes_check_env_specs(kwargs) -> None:
    env = AtcNfBatchedEnv(3, seed=0, **kwargs)
    check_env_specs(env)
    td = env.rollout(5, break_when_any_done=False)
    m = kwargs.get("max_aircraft", 4)
    assert td[GROUP, "observation"].shape == (3, 5, m, env.observation_dim)
    assert td["next", GROUP, "reward"].shape == (3, 5, m, 1)
    assert td["next", "state"].shape == (3, 5, env.state_dim)
    if "max_aircraft" in kwargs:  # padding slots never fly and see zeros
        assert not td[GROUP, "mask"][..., 5:].any()
        assert (td[GROUP, "observation"][..., 5:, :] == 0).all()


def test_same_seed_same_rollout_bit_for_bit_and_another_seed_differs() -> None:
    first = random_rollout(AtcNfBatchedEnv(3, seed=7, scenario="random-4"), 40, seed=1)
    again = random_rollout(AtcNfBatchedEnv(3, seed=7, scenario="random-4"), 40, seed=1)
    other = random_rollout(AtcNfBatchedEnv(3, seed=8, scenario="random-4"), 40, seed=1)
    assert first["next", "done"].any()  # the rollout crossed resets
    for key in first.keys(True, True):
        assert torch.equal(first[key], again[key]), key
    assert not torch.equal(first[GROUP, "observation"], other[GROUP, "observation"])


def test_world_b_flies_as_the_parallel_env_reset_with_seed_plus_b() -> None:
    env = AtcNfBatchedEnv(2, seed=40, scenario="random-4")
    td = env.reset()
    actions = torch.rand(2, 4, 2) * 2 - 1
    td.set((GROUP, "action"), actions)
    nxt = env.step(td)["next"]
    for b in range(2):
        par = atc_nf_env.parallel_env(scenario="random-4")
        obs, _ = par.reset(seed=40 + b)
        assert np.array_equal(np.stack([obs[a] for a in par.agents]), td[GROUP, "observation"][b].numpy())
        assert np.array_equal(par.state(), td["state"][b].numpy())
        obs, rewards, *_ = par.step({a: actions[b, i].double().numpy() for i, a in enumerate(par.agents)})
        expected = np.array([rewards[a] for a in par.possible_agents], dtype=np.float32)
        assert np.array_equal(expected, nxt[GROUP, "reward"][b, :, 0].numpy())


def test_episode_seeds_iterator_gives_each_reset_the_next_seeds() -> None:
    env = AtcNfBatchedEnv(3, episode_seeds=iter(range(500, 510)), scenario="random-4", max_cycles=2)
    assert env.reset()["episode_seed"].tolist() == [500, 501, 502]
    partial = env.reset().clone()  # resets all three: 503..505
    assert partial["episode_seed"].tolist() == [503, 504, 505]
    partial.set("_reset", torch.tensor([[False], [True], [False]]))
    assert env.reset(partial)["episode_seed"].tolist() == [503, 506, 505]
    assert env.episodes_started == 7
    with pytest.raises(ValueError, match="seed or episode_seeds"):
        AtcNfBatchedEnv(2, seed=0, episode_seeds=iter(range(3)))
    with pytest.raises(ValueError, match="iterator"):
        AtcNfBatchedEnv(2, episode_seeds=[1, 2])


def test_partial_reset_restarts_only_the_worlds_that_ended() -> None:
    env = AtcNfBatchedEnv(4, seed=0, scenario="converging-4", max_cycles=3)
    td = env.reset()
    seeds = td["episode_seed"].clone()
    for _ in range(3):
        td.set((GROUP, "action"), torch.zeros(4, 4, 2))
        td, nxt = env.step_and_maybe_reset(td)
        td = nxt
    assert not torch.equal(td["episode_seed"], seeds)  # every world truncated and was reset
    partial = td.clone()
    partial.set("_reset", torch.tensor([[True], [False], [False], [False]]))
    before = td["episode_seed"].clone()
    after = env.reset(partial)
    assert after["episode_seed"][0] != before[0] and torch.equal(after["episode_seed"][1:], before[1:])


def test_bad_input_gets_clear_errors() -> None:
    with pytest.raises(TypeError, match="unexpected keyword argument 'scenaro'"):
        AtcNfBatchedEnv(2, scenaro="converging-4")
    with pytest.raises(ValueError, match="num_envs"):
        AtcNfBatchedEnv(0)
    env = AtcNfBatchedEnv(2, seed=0)
    td = env.reset()
    td.set((GROUP, "action"), torch.full((2, 4, 2), float("nan")))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(td)
    with pytest.raises(ValueError, match="algorithm"):
        train("dqn", "converging-4", 0, 10, Path("unused"))
    with pytest.raises(ValueError, match="task"):
        train("ippo", "converging-5", 0, 10, Path("unused"))
    with pytest.raises(ValueError, match="traffic stream.*allowed: converging-4"):
        train("ippo", "stream-30", 0, 10, Path("unused"))


@pytest.mark.parametrize("algorithm", ["ippo", "mappo"])
def test_tiny_training_writes_its_files_and_the_loader_flies_them(algorithm: str, tmp_path: Path) -> None:
    path = train(algorithm, "converging-4", 3, 192, tmp_path / "run", TINY, progress=False)
    assert path == tmp_path / "run" / "policy.pt"
    rows = list(csv.DictReader(open(tmp_path / "run" / "curve.csv")))
    assert [int(r["frames"]) for r in rows] == [0, 128, 192]  # batches of 4 worlds x 16 steps
    for row in rows:
        assert 0.0 <= float(row["eval_safe_share"]) <= 1.0 and int(row["eval_runs"]) == 2
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert (meta["algorithm"], meta["task"], meta["seed"], meta["frames"]) == (algorithm, "converging-4", 3, 192)
    assert meta["versions"]["torchrl"].startswith("0.14")

    policy = TorchRLPolicy(path)
    result = run_episode(policy, "converging-4", seed=2_000_000_000)
    assert result.metrics.n_aircraft == 4 and result.metrics.decisions > 0
    card = score(path, "converging-4", "validation", 1)
    assert card["runs"] == 1 and card["policy"] == str(path)


def test_same_training_seed_same_weights(tmp_path: Path) -> None:
    weights = []
    for k in range(2):
        saved = torch.load(train("mappo", "random-4", 1, 128, tmp_path / str(k), TINY, progress=False), weights_only=True)
        weights.append(torch.cat([torch.cat([l["weight"].flatten(), l["bias"]]) for l in saved["layers"]]))
    assert torch.equal(weights[0], weights[1])


def test_loader_matches_the_actor_and_rejects_foreign_files(tmp_path: Path) -> None:
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from agents.marl_torchrl import _networks

    path = train("ippo", "converging-4", 0, 64, tmp_path / "run", TINY, progress=False)
    env = AtcNfBatchedEnv(4, seed=5)
    actor, _ = _networks("ippo", 4, env.observation_dim, env.state_dim, TINY.hidden, env.full_action_spec)
    actor.load_state_dict(torch.load(path, weights_only=True)["actor_state_dict"])
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = actor(td)[GROUP, "action"].reshape(-1, 2).numpy()
    got = TorchRLPolicy(path).actions(td[GROUP, "observation"].reshape(-1, env.observation_dim).numpy())
    np.testing.assert_allclose(got, expected, atol=1e-5)
    foreign = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a policy written by"):
        TorchRLPolicy(foreign)


def test_policy_file_entry_point_names_the_loader() -> None:
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    module, _, name = declared["atc_nf_env.policy_files"]["pt"].partition(":")
    assert getattr(importlib.import_module(module), name) is TorchRLPolicy
