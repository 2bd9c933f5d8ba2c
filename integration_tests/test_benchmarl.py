"""BenchMARL 1.5.2 (its own venv: torchrl < 0.12): MAPPO on the encounter's task."""

from __future__ import annotations

from atc_nf_env.integrations.benchmarl import AtcNfTask


def test_task_specs() -> None:
    task = AtcNfTask.ENCOUNTER.get_task(config={"scenario": "converging-4", "max_cycles": 12})
    env = task.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")()
    assert task.group_map(env) == {"aircraft": [f"aircraft_{i}" for i in range(4)]}
    assert task.max_steps(env) == 12
    assert list(task.observation_spec(env)["aircraft"].keys()) == ["observation"]
    assert "state" in task.state_spec(env).keys()


def test_mappo_trains(run_example) -> None:
    out = run_example("train_benchmarl.py", "--iterations", "2")
    assert "BenchMARL MAPPO: 2 iterations, 480 frames" in out
