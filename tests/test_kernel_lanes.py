"""The kernel's lane path (batches of ``kernel.LANE_MIN_WORLDS`` worlds or more): a world
flies bit for bit the same trajectory, with the same outcome, in such a batch as alone
(where the scalar path flies every step), whichever of its steps the lanes fly."""

from __future__ import annotations

import numba
import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from atc_nf_env import kernel, nf
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import converging, make_scenario
from atc_nf_env.simulation import initial_state

TRACE_FIELDS = ("min_airspeed_kt", "max_airspeed_kt", "violation_steps", "worst_excursion_kt", "steps_flown",
                "los_pairs", "min_separation_nm", "steps_done", "violated", "record")
MIX = ("random-4", "random-6", "converging-4", "converging-6", "random-5", "converging-3")


def _batch(n_worlds: int, seed: int, n_slots: int = 6) -> tuple[np.ndarray, float]:
    scenarios = [make_scenario(MIX[b % len(MIX)], seed=seed * 100 + b) for b in range(n_worlds)]
    state = np.stack([initial_state(s, 1, n_slots)[0] for s in scenarios])
    return state, max(s.workspace_radius_nm for s in scenarios)


def _fly_both(state: np.ndarray, radius: float, seed: int, periods: int, stop_on_violation: bool,
              record_every: int) -> None:
    """Fly the batch at once and each world alone, period after period; assert equal."""
    params = SimConfig().to_params(radius, stop_on_violation=stop_on_violation)
    rng = np.random.default_rng(seed)
    wind = rng.normal(0.0, 10.0, (state.shape[0], 2))
    batch, alone = state.copy(), state.copy()
    for period in range(periods):
        waypoints = batch[:, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy()
        if period % 2:
            waypoints += rng.normal(0.0, 30.0, waypoints.shape)
        together = kernel.advance(batch, waypoints, wind, 300.0, params, record_every=record_every)
        for b in range(state.shape[0]):
            world = alone[b : b + 1].copy()
            one = kernel.advance(world, waypoints[b : b + 1], wind[b : b + 1], 300.0, params, record_every=record_every)
            alone[b] = world[0]
            for name in TRACE_FIELDS:
                assert np.array_equal(getattr(together, name)[b], getattr(one, name)[0]), (period, b, name)
        assert np.array_equal(batch, alone), period


def test_mixed_batch_flies_as_each_world_alone() -> None:
    """Waypoint switches, neighbours in range, arrivals, padding slots and records: the
    lanes fly some steps of each world and the scalar path the others."""
    state, radius = _batch(40, seed=1)
    assert state.shape[0] >= kernel.LANE_MIN_WORLDS
    _fly_both(state, radius, seed=1, periods=24, stop_on_violation=False, record_every=3)


def test_batch_stopping_at_violations_flies_as_each_world_alone() -> None:
    state, radius = _batch(kernel.LANE_MIN_WORLDS + 5, seed=2)
    _fly_both(state, radius, seed=2, periods=10, stop_on_violation=True, record_every=1)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_worlds=st.integers(kernel.LANE_MIN_WORLDS, 3 * kernel.LANE_CHUNK + 1),
       jitter_nm=st.floats(0.0, 40.0), heading_jitter=st.floats(0.0, 3.0))
def test_perturbed_batches_fly_as_each_world_alone(seed: int, n_worlds: int, jitter_nm: float,
                                                    heading_jitter: float) -> None:
    """Batch sizes across chunk boundaries; starts moved and turned at random."""
    rng = np.random.default_rng(seed)
    state, radius = _batch(n_worlds, seed=seed % 1000)
    flying = state[:, :, kernel.S_STATUS] == kernel.FLYING
    state[:, :, kernel.S_X] += np.where(flying, rng.normal(0.0, jitter_nm, flying.shape), 0.0)
    state[:, :, kernel.S_Y] += np.where(flying, rng.normal(0.0, jitter_nm, flying.shape), 0.0)
    state[:, :, kernel.S_HEADING] = np.where(
        flying, np.angle(np.exp(1j * (state[:, :, kernel.S_HEADING] + rng.normal(0.0, heading_jitter, flying.shape)))),
        state[:, :, kernel.S_HEADING])
    _fly_both(state, radius, seed=seed, periods=3, stop_on_violation=bool(seed % 2), record_every=seed % 3)


def test_lanes_fly_the_ordinary_steps() -> None:
    """Converging-6's first period has every aircraft far from every other: the lanes fly
    every world's last step (the scalar path alone would be correct, and slow)."""
    scenario = converging(6)
    state = initial_state(scenario, 100)
    params = SimConfig().to_params(scenario.workspace_radius_nm)
    scratch = kernel.KernelScratch()
    kernel.advance(state, state[:, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy(), np.zeros((100, 2)), 300.0,
                   params, scratch=scratch)
    ordinary = scratch.lane_world[:, kernel.W_ORDINARY, : kernel.lane_chunk(100)].reshape(-1)[:100]
    assert (ordinary == 1.0).all()


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-150.0, 150.0), y=st.floats(-150.0, 150.0), wx=st.floats(-150.0, 150.0),
       wy=st.floats(-150.0, 150.0), theta_d=st.floats(-3.2, 3.2))
def test_own_gradient_alone_is_the_nf_gradient_without_neighbours(x: float, y: float, wx: float, wy: float,
                                                                   theta_d: float) -> None:
    assume(x * x + y * y < 190.0**2)  # inside the workspace, where Φ is defined
    params = SimConfig().to_params(200.0)
    consts = nf.nf_constants(params)
    pos = np.array([[x, y], [x + 500.0, y]])  # the other aircraft far beyond the sensing radius
    status = np.array([nf.FLYING, nf.FLYING])
    grad = np.zeros((2, 2))
    ed_x, ed_y = np.cos(theta_d), np.sin(theta_d)
    _, n_near = nf.nf_along_direction(0, pos, status, wx, wy, ed_x, ed_y, consts, grad)
    gx, gy, _, sgn_along = nf.own_gradient_alone(x, y, wx, wy, ed_x, ed_y, consts)
    assert n_near == 0
    assert (gx, gy) == (grad[0, 0], grad[0, 1])
    inv_len = consts[0]
    assert sgn_along == (1.0 if ed_x * ((x - wx) * inv_len) + ed_y * ((y - wy) * inv_len) >= 0.0 else -1.0)


def _entries_called(monkeypatch, calls: list[str]) -> None:
    for name in ("_advance_checked_one", "_advance_checked_batch", "_advance_checked_lanes"):
        entry = getattr(kernel, name)

        def spy(*arguments, _entry=entry, _name=name):
            calls.append(_name)
            return _entry(*arguments)

        monkeypatch.setattr(kernel, name, spy)


def test_after_load_paths_every_batch_size_flies_on_the_lanes_with_the_same_bits(monkeypatch) -> None:
    """``load_paths`` (the MPC's reset) compiles the lane path alone and sends every batch
    size to it: one world and small batches fly the bits the scalar paths fly."""
    state, radius = _batch(15, seed=4)
    params = SimConfig().to_params(radius)
    wind = np.random.default_rng(4).normal(0.0, 10.0, (15, 2))
    waypoints = state[:, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy()
    scalar = {}
    for n_worlds in (1, 2, 7, 15):
        world = state[:n_worlds].copy()
        trace = kernel.advance(world, waypoints[:n_worlds], wind[:n_worlds], 1800.0, params, record_every=2)
        scalar[n_worlds] = (world, trace)
    calls: list[str] = []
    _entries_called(monkeypatch, calls)
    kernel.load_paths(state[0], params)
    assert kernel._lanes_for_every_size
    for n_worlds in (1, 2, 7, 15):
        calls.clear()
        world = state[:n_worlds].copy()
        trace = kernel.advance(world, waypoints[:n_worlds], wind[:n_worlds], 1800.0, params, record_every=2)
        assert calls == ["_advance_checked_lanes"], n_worlds
        assert np.array_equal(world, scalar[n_worlds][0]), n_worlds
        for name in TRACE_FIELDS:
            assert np.array_equal(getattr(trace, name), getattr(scalar[n_worlds][1], name)), (n_worlds, name)


def test_load_paths_keeps_the_scalar_paths_for_a_law_the_lanes_do_not_fly(monkeypatch) -> None:
    """The lanes fly k = 2 only: with another k, ``load_paths`` compiles the one-world and
    batch paths and batches keep their path by size."""
    state, radius = _batch(2, seed=5)
    params = SimConfig(k=3.0).to_params(radius)
    calls: list[str] = []
    _entries_called(monkeypatch, calls)
    kernel.load_paths(state[0], params)
    assert not kernel._lanes_for_every_size
    assert set(calls) <= {"_advance_checked_one", "_advance_checked_batch"}
    calls.clear()
    kernel.advance(state[:1].copy(), state[:1, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy(), np.zeros((1, 2)),
                   300.0, params)
    assert calls == ["_advance_checked_one"]


def test_a_small_batch_is_spread_over_the_threads_in_chunks() -> None:
    threads = numba.get_num_threads()
    assert kernel.lane_chunk(1) == 1
    assert kernel.lane_chunk(kernel.LANE_CHUNK * threads * 3) == kernel.LANE_CHUNK
    assert kernel.lane_chunk(2 * threads) == 2
