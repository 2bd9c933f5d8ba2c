"""Hostile inputs, round 4: dataset ids that escape Minari's store or poison it, datasets
killed mid-write, sizes no machine holds, starts too close to fly, and batched actions or
seeds whose errors were unreadable (issue 51, items 13, 14, 20 and the smaller ones)."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
import time
import tracemalloc
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import atc_nf_env
from atc_nf_env import config as memory
from atc_nf_env.scenarios import CloseStartWarning, Scenario, closest_pair, make_scenario, scenario_from_dict

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --------------------------------------------------------------------------- item 13: dataset ids

@pytest.fixture
def store(tmp_path, monkeypatch):
    global minari
    minari = pytest.importorskip("minari")
    path = tmp_path / "datasets"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(path))
    return path


def _visible(store) -> list[str]:
    """Every file and folder under the store, hidden ones included."""
    if not store.exists():
        return []
    return sorted(str(p.relative_to(store)) for p in store.rglob("*"))


@pytest.mark.parametrize("dataset_id", ["foo", "x/y-v-1", "", "../../escape-v0", "/tmp/abs-v0", "a//b-v0",
                                        "atc-nf/../../up-v0", "x-v01", "x y-v0", 7])
def test_malformed_or_escaping_dataset_ids_are_refused_before_anything_flies(store, monkeypatch, tmp_path,
                                                                             dataset_id) -> None:
    from atc_nf_env import dataset, policy

    def no_flight(*args, **kwargs):
        raise AssertionError("a policy was built: the id was not checked first")

    monkeypatch.setattr(policy, "make_policy", no_flight)
    with pytest.raises(ValueError, match=r"name-vN"):
        dataset.record_dataset("nf", "converging-4", 1, dataset_id)
    assert [p for p in _visible(store)] == []
    assert not (tmp_path.parent / "escape-v0").exists() and not os.path.exists("/tmp/abs-v0")
    assert minari.list_local_datasets() == {}


def test_a_namespace_linked_out_of_the_store_is_refused(store, tmp_path) -> None:
    from atc_nf_env.dataset import record_dataset

    store.mkdir(parents=True)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (store / "linked").symlink_to(outside)
    with pytest.raises(ValueError, match="outside Minari's store"):
        record_dataset("nf", "converging-4", 1, "linked/nf-v0")
    assert list(outside.iterdir()) == []


def test_a_folder_an_interrupted_older_write_left_is_named_not_a_crash(store) -> None:
    from atc_nf_env.dataset import record_dataset

    (store / "atc-nf" / "c4" / "nf-v0" / "data").mkdir(parents=True)  # what a killed write left
    with pytest.raises(ValueError, match="holds no complete dataset.*delete"):
        record_dataset("nf", "converging-4", 1, "atc-nf/c4/nf-v0")


_KILLED_MID_WRITE = textwrap.dedent("""
    import os, signal
    from minari.dataset._storages.arrow_storage import ArrowStorage
    import atc_nf_env.dataset as dataset

    original = ArrowStorage.update_episodes

    def write_half_then_die(self, episodes):
        original(self, list(episodes)[:1])  # one episode on disk, then the process is killed
        os.kill(os.getpid(), signal.SIGKILL)

    ArrowStorage.update_episodes = write_half_then_die
    dataset.record_dataset("nf", "converging-4", 2, "atc-nf/c4/nf-v0")
""")


def test_a_dataset_killed_mid_write_leaves_nothing_and_the_rerun_writes_it(store) -> None:
    from atc_nf_env.dataset import record_dataset

    done = subprocess.run([sys.executable, "-c", _KILLED_MID_WRITE], capture_output=True, text=True, timeout=600,
                          cwd=ROOT, env={**os.environ, "MINARI_DATASETS_PATH": str(store)})
    assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Minari warns "Misconfigured dataset" on a partial one
        assert minari.list_local_datasets() == {}
    data = record_dataset("nf", "converging-4", 2, "atc-nf/c4/nf-v0")
    assert data.total_episodes == 2
    assert list(minari.list_local_datasets()) == ["atc-nf/c4/nf-v0"]
    assert not any(name.startswith(".atc-nf-partial-") for name in _visible(store))  # the dead run's is gone


def test_a_full_disk_mid_write_leaves_nothing_and_says_so(store, monkeypatch) -> None:
    from minari.dataset._storages.arrow_storage import ArrowStorage

    from atc_nf_env.dataset import record_dataset

    def disk_full(self, episodes):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(ArrowStorage, "update_episodes", disk_full)
    with pytest.raises(OSError, match="No space left"):
        record_dataset("nf", "converging-4", 1, "atc-nf/c4/nf-v0")
    assert [p for p in _visible(store) if "nf-v0" in p or "partial" in p] == []
    assert minari.list_local_datasets() == {}
    monkeypatch.undo()
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(store))
    assert record_dataset("nf", "converging-4", 1, "atc-nf/c4/nf-v0").total_episodes == 1


def test_the_command_refuses_a_bad_id_in_one_line(store) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "atc_nf_env.dataset", "--policy", "nf", "--task", "converging-4", "--episodes", "1",
         "--dataset-id", "../../escape-v0", "--no-progress"],
        capture_output=True, text=True, timeout=300, cwd=ROOT, env={**os.environ, "MINARI_DATASETS_PATH": str(store)},
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().count("\n") == 0 and "name-vN" in done.stderr


# --------------------------------------------------------------------------- item 14: absurd sizes


def _refused_at_once(make, match: str, seconds: float = 5.0, megabytes: float = 200.0) -> str:
    """``make()`` raises ValueError matching ``match`` within ``seconds`` and ``megabytes``."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(ValueError, match=match) as caught:
            make()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - start < seconds
    assert peak < megabytes * 2**20
    assert "\n" not in str(caught.value) and len(str(caught.value)) < 400
    return str(caught.value)


def _grid(n: int, spacing_nm: float = 5.0) -> list[dict]:
    side = int(np.ceil(np.sqrt(n)))
    return [{"start": [spacing_nm * (k % side) - 600.0, spacing_nm * (k // side) - 600.0], "destination": [0.0, 0.0]}
            for k in range(n)]


def test_scenarios_beyond_one_worlds_memory_are_refused_at_once() -> None:
    limit = str(memory.MAX_AIRCRAFT)
    assert limit in _refused_at_once(lambda: make_scenario("converging-10000"), "at most")
    assert limit in _refused_at_once(lambda: make_scenario("converging-1000000000"), "at most")
    for n in (10_000, 60_000):
        aircraft = _grid(n)
        assert limit in _refused_at_once(lambda: scenario_from_dict({"aircraft": aircraft}), "len\\(aircraft\\)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CloseStartWarning)
        assert make_scenario("converging-300").n_aircraft == 300


def test_envs_beyond_the_memory_bounds_are_refused_at_once() -> None:
    import gymnasium as gym

    from atc_nf_env.envs.vector import EncounterVectorEnv

    _refused_at_once(lambda: gym.make(atc_nf_env.ENV_ID, scenario="converging-4", max_aircraft=10**6),
                     "max_aircraft = 1000000: at most 7827")
    _refused_at_once(lambda: atc_nf_env.parallel_env(scenario="converging-4", max_aircraft=10**6), "at most 7827")
    most = memory.max_batch_worlds(4)
    message = _refused_at_once(lambda: EncounterVectorEnv(10**7, scenario="converging-4"), "num_envs = 10000000")
    assert f"at most {most} worlds of 4 aircraft" in message
    assert EncounterVectorEnv(2, scenario="converging-4", max_aircraft=memory.MAX_AIRCRAFT).n_slots == 7827


def test_the_memory_model_bounds_what_the_vector_env_holds() -> None:
    """The per-world estimate behind the bounds is an upper bound of what the vector env's
    worlds hold at their peak (and not one inflated past twice and a half of it)."""
    from atc_nf_env.envs.vector import EncounterVectorEnv

    for scenario, worlds in (("converging-4", 256), ("converging-40", 128)):
        # The same batch size first: the kernel picks its path by batch size, and a first
        # compilation inside the traced window (a fresh cache) would count numba's memory.
        warm = EncounterVectorEnv(worlds, scenario=scenario)
        warm.reset(seed=0)
        warm.step(np.zeros(warm.action_space.shape, np.float32))
        warm.close()
        del warm
        tracemalloc.start()
        env = EncounterVectorEnv(worlds, scenario=scenario)
        env.reset(seed=0)
        for _ in range(2):
            env.step(np.zeros(env.action_space.shape, np.float32))
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        estimate = worlds * memory.world_memory_bytes(env.n_slots)
        assert peak <= estimate <= 2.5 * peak, (scenario, peak, estimate)


def test_the_duplicate_start_check_is_linear_in_memory() -> None:
    starts = np.array([a["start"] for a in _grid(memory.MAX_AIRCRAFT)])
    tracemalloc.start()
    distance, i, j = closest_pair(starts)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert (distance, i, j) == (5.0, 0, 1)
    assert peak < 100 * 2**20  # the full matrix was 17 * 7827² bytes ≈ 1 GB


@settings(max_examples=150, deadline=None)
@given(st.integers(2, 40).flatmap(lambda n: st.tuples(
    st.lists(st.tuples(st.integers(-6, 6), st.integers(-6, 6)), min_size=n, max_size=n),
    st.sampled_from([1.0, 2.5, 0.37]), st.integers(1, 50))))
def test_closest_pair_is_the_full_matrixs_argmin(case) -> None:
    """Ties included (integer grids): the pair is the one np.argmin finds first in the full
    matrix, whatever the block size."""
    import atc_nf_env.scenarios as scenarios

    cells, scale, block_rows = case
    points = np.array(cells, dtype=np.float64) * scale
    n = len(points)
    diff = points[:, None] - points[None]
    full = np.hypot(diff[..., 0], diff[..., 1]) + np.diag(np.full(n, np.inf))
    i, j = np.unravel_index(int(np.argmin(full)), full.shape)
    saved = scenarios._PAIR_BLOCK_ELEMENTS
    try:
        scenarios._PAIR_BLOCK_ELEMENTS = block_rows * n
        assert closest_pair(points) == (float(full[i, j]), int(i), int(j))
    finally:
        scenarios._PAIR_BLOCK_ELEMENTS = saved


def test_mpc_sizes_beyond_memory_or_any_flight_are_refused_at_once() -> None:
    from baselines.mcmc_mpc import MAX_EXTRACTIONS, MCMCMPC, MPCSettings

    from atc_nf_env.config import SimConfig

    assert str(MAX_EXTRACTIONS) in _refused_at_once(lambda: MPCSettings(extractions=10**9), "extractions")
    _refused_at_once(lambda: MPCSettings(horizon=10**6), r"longer than any flight.*N <= 288")
    _refused_at_once(lambda: MPCSettings(horizon=25, period_s=3600.0), r"N <= 24 at T = 3600 s")
    assert MPCSettings(horizon=288).horizon == 288
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CloseStartWarning)
        crowded = make_scenario("converging-300")
    _refused_at_once(lambda: MCMCMPC(extractions=100_000).reset(crowded, SimConfig()),
                     f"at most {memory.max_batch_worlds(300)} worlds of 300 aircraft")


def test_the_cli_refuses_absurd_sizes_in_one_line() -> None:
    from baselines.mcmc_mpc import MAX_EXTRACTIONS

    for args, bound in (
        (["fly", "--policy", "mpc", "--scenario", "converging-4", "--extractions", "1000000000"], str(MAX_EXTRACTIONS)),
        (["fly", "--policy", "mpc", "--scenario", "converging-4", "--horizon", "1000000"], "N <= 288"),
        (["fly", "--policy", "nf", "--scenario", "converging-10000"], f"at most {memory.MAX_AIRCRAFT}"),
    ):
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "atc_nf_env.cli", *args], capture_output=True, text=True,
                              timeout=300, cwd=ROOT)
        assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
        assert done.stderr.strip().count("\n") == 0 and bound in done.stderr, done.stderr
        assert time.perf_counter() - start < 60


# --------------------------------------------------------------------------- item 20: close starts


def _side_by_side(apart_nm: float) -> dict:
    return {"aircraft": [{"start": [-250.0, 0.0], "destination": [250.0, 0.0]},
                         {"start": [-250.0, apart_nm], "destination": [250.0, apart_nm]}]}


@pytest.mark.parametrize("apart_nm", [5.0, 6.0, 7.0, 8.0, 11.9])
def test_starts_inside_the_nfs_sensing_radius_warn(apart_nm) -> None:
    with pytest.warns(CloseStartWarning, match=rf"aircraft 0 and 1 start {apart_nm:.2f} nm apart.*sensing radius "
                                               r"\(12 nm\).*barrier distance \(7 nm\)"):
        scenario_from_dict(_side_by_side(apart_nm))


def test_starts_beyond_it_and_the_benchmark_encounters_do_not_warn() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", CloseStartWarning)
        scenario_from_dict(_side_by_side(12.0))
        for name in ("converging-3", "converging-4", "converging-6", "converging-12"):
            make_scenario(name)
        for seed in range(20):
            make_scenario("random-18", seed=seed)


def test_what_the_warning_says_is_what_the_nf_flies() -> None:
    """Side by side, waypoints 100 nm ahead: 8 nm apart the NF leaves the envelope at once
    (the cap), 12 nm apart it holds it."""
    from atc_nf_env.config import SimConfig
    from atc_nf_env.simulation import Simulation

    def airspeeds(apart_nm: float) -> tuple[float, float]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CloseStartWarning)
            sim = Simulation(scenario_from_dict(_side_by_side(apart_nm)), SimConfig())
        view = sim.view()
        trace = sim.advance(view.positions + np.array([100.0, 0.0]), 300.0)
        return float(trace.min_airspeed_kt.min()), float(trace.max_airspeed_kt.max())

    config = SimConfig()
    assert airspeeds(8.0)[1] >= config.airspeed_cap_kt
    low, high = airspeeds(config.sensing_radius_nm)
    assert config.airspeed_min_kt <= low and high <= config.airspeed_max_kt


# --------------------------------------------------------------------------- smaller


def test_a_nan_in_a_large_batched_action_names_the_world_and_aircraft_briefly() -> None:
    from atc_nf_env.envs.vector import EncounterVectorEnv

    env = EncounterVectorEnv(256, scenario="random-8")
    env.reset(seed=0)
    action = np.zeros((256, 8, 2), np.float32)
    action[37, 5, 1] = np.nan
    action[200, 1, 0] = np.inf
    with pytest.raises(ValueError) as caught:
        env.step(action)
    message = str(caught.value)
    assert len(message) < 400 and "world 37, aircraft 5, angle" in message and "2 non-finite values" in message


def test_a_nan_in_one_envs_action_names_the_aircraft() -> None:
    import gymnasium as gym

    env = gym.make(atc_nf_env.ENV_ID, scenario="converging-4")
    env.reset(seed=0)
    action = np.zeros((4, 2), np.float32)
    action[2, 0] = np.nan
    with pytest.raises(ValueError, match=r"nan at aircraft 2, distance \(1 non-finite value"):
        env.step(action)


def test_the_batched_torchrl_env_refuses_a_float_seed_and_absurd_sizes_with_the_projects_messages() -> None:
    pytest.importorskip("torchrl")
    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv

    with pytest.raises(ValueError, match=r"seed = 1\.5: must be an integer in \[0, 2\*\*63 - 1\]"):
        AtcNfBatchedEnv(2, seed=1.5, scenario="converging-4")
    _refused_at_once(lambda: AtcNfBatchedEnv(10**7, scenario="converging-4"), "num_envs = 10000000: at most")
