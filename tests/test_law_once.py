"""The law is written once (``atc_nf_env/law.py``), and every path follows an edit of it.

The test copies the package, edits (5b) in the copy's ``law.py`` (the heading gain
doubled), and flies the same encounter through every path that moves aircraft: the
kernel's general path (one world), its lane path (a batch of ``LANE_MIN_WORLDS``), the
safety filter's prediction (``shield_prediction``, compiled into its own cache), the
Gymnasium env (``envs/centralized.py``, the same) and the MPC's decision (its candidates
flown by the kernel). Every path must fly the edited law: each output changes, and the
paths that fly the same flight agree bit for bit. The copy compiles into a cache of its
own, so this also shows that no compiled caller keeps a stale copy of the law.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PROBE = r'''
import json
import numpy as np
import gymnasium as gym
import atc_nf_env
from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.shield_prediction import PlanPredictor
from atc_nf_env.simulation import initial_state
from atc_nf_env.episode import run_episode
from atc_nf_env.policy import make_policy

out = {"law": atc_nf_env.law.__file__}
scenario = make_scenario("random-5", seed=2)
config = SimConfig()
params = config.to_params(scenario.workspace_radius_nm)
start = initial_state(scenario, 1)
# Waypoints 130 nm toward each destination: the NF alone toward a destination 500 nm away
# commands more than the envelope allows, and the filter's prediction stops at a breach.
toward = start[0, :, kernel.S_DEST_X:kernel.S_DEST_Y + 1] - start[0, :, :2]
dest = np.ascontiguousarray((start[0, :, :2] + 130.0 * toward / np.linalg.norm(toward, axis=1, keepdims=True))[None])
wind = np.array([[8.0, -5.0]])
for seconds in (300.0, 3600.0):
    one = start.copy()
    kernel.advance(one, dest.copy(), wind, seconds, params)
    out[f"general {seconds:.0f} s"] = one[0, :, :2].tolist()
    b = kernel.LANE_MIN_WORLDS
    many = np.repeat(start, b, axis=0)
    kernel.advance(many, np.repeat(dest, b, axis=0), np.repeat(wind, b, axis=0), seconds, params)
    out[f"lanes {seconds:.0f} s"] = many[b - 1, :, :2].tolist()
limit = 0.99 * (scenario.workspace_radius_nm - config.aircraft_radius_nm)
predictor = PlanPredictor(config.to_params(scenario.workspace_radius_nm, stop_on_violation=True), 60, 1, 130.0,
                          np.pi / 3, limit)
assert predictor.first_safe(np.ascontiguousarray(start[0]), np.ascontiguousarray(dest[0][None]), wind[0]) == 0
out["filter 300 s"] = predictor.positions.tolist()
env = gym.make("atc_nf_env/Encounter-v1", scenario="random-5")
env.reset(seed=3)
observation, *_ = env.step(env.action_space.sample() * 0.0)
out["env"] = np.asarray(observation).tolist()
result = run_episode(make_policy("mpc"), "converging-4", seed=4, max_time_s=600.0)
out["mpc"] = np.asarray(result.waypoints).tolist()
print(json.dumps(out))
'''


def _fly(package_parent: Path, cache: Path | None) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(package_parent), str(ROOT)])}
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=900,
                          cwd=package_parent)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_an_edit_of_the_law_reaches_every_path(tmp_path: Path) -> None:
    copy = tmp_path / "edited"
    shutil.copytree(ROOT / "atc_nf_env", copy / "atc_nf_env", ignore=shutil.ignore_patterns("__pycache__"))
    law = copy / "atc_nf_env" / "law.py"
    text = law.read_text()
    original = "    return -k_theta * heading_error + theta_nh_rate\n"
    assert text.count(original) == 1, "turn_rate's formula moved: update the edit this test makes"
    law.write_text(text.replace(original, "    return -2.0 * k_theta * heading_error + theta_nh_rate\n"))

    before = _fly(ROOT, None)  # the checkout's own cache
    after = _fly(copy, tmp_path / "cache-after")
    assert Path(after["law"]).resolve() == law.resolve()
    for path in before:
        if path != "law":
            assert before[path] != after[path], f"{path} did not follow the edited law"
    for flown in (before, after):
        assert flown["general 300 s"] == flown["lanes 300 s"] == flown["filter 300 s"]
        assert flown["general 3600 s"] == flown["lanes 3600 s"]
