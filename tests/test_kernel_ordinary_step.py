"""The kernel's one-world ordinary steps (``kernel._ordinary_run``): a world's flight with
its ordinary steps flown by it is bit for bit the flight of the general scalar path, with
the same outcome, whichever steps are ordinary (neighbours in range, arrivals, padding
slots, waypoint switches, violations and records in between)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state

MIX = ("random-4", "random-6", "converging-4", "converging-6", "random-5", "converging-3")


def _outcome_buffers(n: int, n_record: int) -> list[np.ndarray]:
    return [np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n, dtype=np.int64),
            np.zeros((n, n), dtype=np.uint8), np.zeros((n_record, n, kernel.N_RECORD))]


def _fly(state: np.ndarray, waypoints: np.ndarray, wind: np.ndarray, n_steps: int, params: np.ndarray,
         record_every: int, ordinary_steps: bool) -> tuple[tuple, list[np.ndarray], np.ndarray]:
    """One call of ``_advance_world`` on ``state`` (changed in place): its return value, its
    outcome arrays and its command buffer."""
    n = state.shape[0]
    n_record = n_steps // record_every + 1 if record_every else 0
    outcomes = _outcome_buffers(n, n_record)
    command = np.zeros((n, kernel.N_COMMAND))
    minimum, maximum, violations, worst, flown, los, record = outcomes
    result = kernel._advance_world(
        state, waypoints, float(wind[0]), float(wind[1]), n_steps, params, np.zeros((n, n, 2)), command,
        np.zeros((kernel.N_AIRCRAFT_LANE, n)), minimum,
        maximum, violations, worst, flown, los, record, max(record_every, 1), ordinary_steps,
    )
    return result, outcomes, command


def _compare(seed: int, spec: str, periods: int, stop_on_violation: bool, record_every: int,
             jitter_nm: float = 0.0) -> int:
    """Fly one world period after period both ways, assert equal; returns how many periods
    ended with a step flown by the ordinary step."""
    rng = np.random.default_rng(seed)
    scenario = make_scenario(spec, seed=seed)
    state = np.ascontiguousarray(initial_state(scenario, 1, 6)[0])
    flying = state[:, kernel.S_STATUS] == kernel.FLYING
    state[flying, kernel.S_X] += rng.normal(0.0, jitter_nm, flying.sum())
    state[flying, kernel.S_Y] += rng.normal(0.0, jitter_nm, flying.sum())
    params = SimConfig().to_params(scenario.workspace_radius_nm, stop_on_violation=stop_on_violation)
    wind = rng.normal(0.0, 10.0, 2)
    general, ordinary = state.copy(), state.copy()
    ended_ordinary = 0
    for period in range(periods):
        waypoints = general[:, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy()
        if period % 2:
            waypoints += rng.normal(0.0, 30.0, waypoints.shape)
        expected = _fly(general, waypoints, wind, 60, params, record_every, ordinary_steps=False)
        got = _fly(ordinary, waypoints, wind, 60, params, record_every, ordinary_steps=True)
        assert expected[0] == got[0], (spec, seed, period)
        for want, have in zip(expected[1], got[1]):
            assert np.array_equal(want, have), (spec, seed, period)
        assert np.array_equal(general, ordinary), (spec, seed, period)
        # The ordinary step leaves its move in the command's scratch columns.
        moved = ordinary[:, kernel.S_STATUS] == kernel.FLYING
        ended_ordinary += bool(moved.any()) and bool(
            np.array_equal(got[2][moved, kernel.C_X1], ordinary[moved, kernel.S_X]))
    return ended_ordinary


def test_mixed_worlds_fly_the_general_paths_bits() -> None:
    ended_ordinary = sum(_compare(seed, MIX[seed % len(MIX)], periods=20, stop_on_violation=False, record_every=3)
                         for seed in range(12))
    # Not a vacuous comparison: the ordinary step flew the last step of many periods.
    assert ended_ordinary >= 20


def test_worlds_stopping_at_violations_fly_the_general_paths_bits() -> None:
    for seed in range(6):
        _compare(seed, MIX[seed % len(MIX)], periods=8, stop_on_violation=True, record_every=1)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), spec=st.sampled_from(MIX), jitter_nm=st.floats(0.0, 40.0),
       stop=st.booleans(), record_every=st.integers(0, 3))
def test_perturbed_worlds_fly_the_general_paths_bits(seed: int, spec: str, jitter_nm: float, stop: bool,
                                                     record_every: int) -> None:
    _compare(seed, spec, periods=3, stop_on_violation=stop, record_every=record_every, jitter_nm=jitter_nm)
