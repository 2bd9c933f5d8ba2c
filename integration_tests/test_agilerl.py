"""AgileRL 2.58 (its own venv): IPPO and MADDPG train on the PettingZoo parallel env over
AgileRL's multi-process vector env, and the process exits (the trainer closes it)."""

from __future__ import annotations

import math

import pytest


@pytest.mark.parametrize("algo", ["ippo", "maddpg"])
def test_agilerl_trains_on_the_parallel_env(run_example, algo: str) -> None:
    out = run_example("train_agilerl.py", "--algo", algo, "--steps", "512", "--num-envs", "2")
    line = next(line for line in out.splitlines() if line.startswith(f"{algo}: 512 env steps"))
    assert math.isfinite(float(line.rsplit(" ", 1)[1]))
