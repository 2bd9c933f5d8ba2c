"""The compile notice: one line on stderr before a compilation that will happen, once per
process, and nothing when numba's on-disk cache holds the compiled code."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from atc_nf_env import kernel

ROOT = Path(__file__).resolve().parents[1]
NOTICE = "compiling the simulator (first run only"


def _run(code: str, cache_dir: Path, extra_path: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), str(extra_path or ""), env.get("PYTHONPATH", "")) if p)
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                          timeout=600, check=True)


def test_the_notice_comes_once_before_a_compilation_and_never_from_a_warm_cache(tmp_path: Path) -> None:
    (tmp_path / "tiny_functions.py").write_text(textwrap.dedent("""
        from numba import njit

        @njit(cache=True)
        def twice(x):
            return 2.0 * x

        @njit(cache=True)
        def thrice(x):
            return 3.0 * x
    """))
    code = """
        import tiny_functions as f
        from atc_nf_env import kernel
        print(kernel.will_compile(f.twice, (1.0,)))
        kernel.compile_notice(f.twice, (1.0,), 3)
        f.twice(1.0)
        print(kernel.will_compile(f.twice, (1.0,)))  # in memory now
        kernel.compile_notice(f.thrice, (1.0,), 3)  # another compilation: no second line
        f.thrice(1.0)
    """
    cold = _run(code, tmp_path / "cache", tmp_path)
    assert cold.stdout.split() == ["True", "False"]
    assert cold.stderr.count(NOTICE) == 1
    assert "about 3 s" in cold.stderr
    warm = _run(code, tmp_path / "cache", tmp_path)
    assert warm.stdout.split() == ["False", "False"]
    assert NOTICE not in warm.stderr


@pytest.mark.slow
def test_advance_gives_the_notice_on_an_empty_cache_only(tmp_path: Path) -> None:
    code = """
        import numpy as np
        from atc_nf_env import kernel
        from atc_nf_env.config import SimConfig
        from atc_nf_env.scenarios import converging
        from atc_nf_env.simulation import initial_state
        scenario = converging(4)
        params = SimConfig().to_params(scenario.workspace_radius_nm)
        batch = (kernel._advance_checked_batch, kernel._advance_batch, kernel._advance_checked_lanes,
                 kernel._advance_lanes, kernel._fly_lanes, kernel._lane_step)
        for n_worlds in (1, 1, 2):
            state = initial_state(scenario, n_worlds)
            kernel.advance(state, np.repeat(scenario.dest_xy[None], n_worlds, axis=0), np.zeros((n_worlds, 2)), 300.0,
                           params)
            # Functions compiled (or loaded) in this process: a one-world flight needs neither batch path.
            print(len(kernel._advance_checked_one.signatures), sum(len(f.signatures) for f in batch))
    """
    cold = _run(code, tmp_path / "cache")
    assert cold.stderr.count(NOTICE) == 1  # the one-world path; the batch path's compilation follows silently
    assert cold.stdout.split()[:4] == ["1", "0", "1", "0"]  # compiled, not loaded: callees count too
    assert cold.stdout.split()[5] != "0"
    assert NOTICE not in _run(code, tmp_path / "cache").stderr



def test_the_first_env_step_announces_its_compilation_and_a_warm_one_does_not(tmp_path: Path) -> None:
    """The env flies a period in one compiled call of its own (not through ``advance``):
    its first step says so too, and only when numba's cache does not hold it."""
    code = """
        import gymnasium as gym
        import atc_nf_env
        env = gym.make("atc_nf_env/Encounter-v1", scenario="converging-3")
        env.reset(seed=0)
        env.step(env.action_space.sample())
        env.step(env.action_space.sample())
    """
    cold = _run(code, tmp_path / "cache")
    warm = _run(code, tmp_path / "cache")
    assert cold.stderr.count(NOTICE) == 1
    assert NOTICE not in warm.stderr


@pytest.mark.slow  # a cold compile of the lane path, about a minute
def test_the_mpc_compiles_the_lane_path_when_reset_and_flies_every_batch_on_it(tmp_path: Path) -> None:
    """The MPC flies its candidates in batches of every size: its reset compiles (or loads)
    the lane path, so the first episode's decisions are timed warm, and from then on the
    process flies every batch, the real world's included, on that one path: the one-world
    and batch paths are never compiled."""
    code = """
        from atc_nf_env import kernel
        from atc_nf_env.config import SimConfig
        from atc_nf_env.episode import run_episode
        from atc_nf_env.policy import make_policy
        from atc_nf_env.scenarios import make_scenario
        policy = make_policy("mpc")
        policy.reset(make_scenario("converging-3"), SimConfig(), 0)
        print(kernel._ENTRIES_CALLED == {kernel._advance_checked_lanes})
        result = run_episode(policy, "converging-3", seed=0)
        print(kernel._ENTRIES_CALLED == {kernel._advance_checked_lanes})
        print(len(kernel._advance_checked_one.signatures), len(kernel._advance_checked_batch.signatures))
    """
    done = _run(code, tmp_path / "cache")
    assert done.stdout.split() == ["True", "True", "0", "0"]
    assert done.stderr.count(NOTICE) == 1
    assert f"about {kernel._FIRST_COMPILE_S['_advance_checked_lanes']} s" in done.stderr
