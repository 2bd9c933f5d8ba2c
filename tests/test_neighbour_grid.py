"""The kernel's neighbour grid (``atc_nf_env.neighbour_grid``): its answers are those of the
loops over all pairs, and the kernel flies the same bits with it as without it, on every
path, on states chosen to be awkward (aircraft on cell borders, coincident, far outside the
workspace, absent or arrived, up to 120 of them)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atc_nf_env import kernel
from atc_nf_env import neighbour_grid as grid
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import FLYING, KernelScratch
from atc_nf_env.nf import ABSENT, ARRIVED, nf_constants

TRACE_FIELDS = ("min_airspeed_kt", "max_airspeed_kt", "violation_steps", "worst_excursion_kt", "steps_flown",
                "los_pairs", "min_separation_nm", "steps_done", "violated", "record")
SENSING_NM = SimConfig().sensing_radius_nm
SEPARATION_NM = SimConfig().separation_min_nm


def _points(draw_seed: int, n: int, spread_nm: float, kinds: int) -> np.ndarray:
    """n positions (nm): clustered at random, on multiples of the sensing radius (cell
    borders), coincident pairs, and with ``kinds`` > 2 a few far outside."""
    rng = np.random.default_rng(draw_seed)
    xy = rng.uniform(-spread_nm, spread_nm, (n, 2))
    border = rng.random(n) < 0.3
    xy[border] = np.round(xy[border] / SENSING_NM) * SENSING_NM
    twins = rng.random(n) < 0.15
    xy[twins] = xy[rng.integers(0, n, twins.sum())]
    near = rng.random(n) < 0.2
    xy[near] = xy[rng.integers(0, n, near.sum())] + rng.normal(0.0, 4.0, (near.sum(), 2))
    if kinds > 2:
        far = rng.random(n) < 0.05
        xy[far] = rng.choice([1e5, -3e6, 1e12], (far.sum(), 2))
    return xy


def _grid_answers(xy: np.ndarray, member: np.ndarray, params: np.ndarray, g: np.ndarray
                  ) -> tuple[list[list[int]], bool, float, np.ndarray, bool]:
    n = xy.shape[0]
    base = 0
    g[base + grid.GRID_X, :n] = xy[:, 0]
    g[base + grid.GRID_Y, :n] = xy[:, 1]
    g[base + grid.GRID_MEMBER, :n] = member
    cell_nm = max(params[kernel.P_R_SENSE], params[kernel.nf.P_SEP_MIN])
    nx, ny, width, skin = grid.prepare(g, base, n, cell_nm)
    consts = nf_constants(params)
    lists = []
    for i in range(n):
        if member[i]:
            count = grid.neighbours(g, base, i, nx, ny, consts[7], consts[0])
            lists.append([int(j) for j in g[base + grid.GRID_LIST, :count]])
        else:
            lists.append([])
    near = grid.any_within(g, base, n, nx, ny, consts[7], consts[0])
    los = np.zeros((n, n), dtype=np.uint8)
    least2, lost = grid.separation(g, base, n, nx, ny, width, skin, 1e18, SEPARATION_NM**2, los, True)
    return lists, near, least2, los, lost


def _all_pairs_answers(xy: np.ndarray, member: np.ndarray, params: np.ndarray
                       ) -> tuple[list[list[int]], bool, float, np.ndarray, bool]:
    """The same questions over all pairs, in the kernel's arithmetic (numpy's float64)."""
    n = xy.shape[0]
    consts = nf_constants(params)
    inv_len, r_sense2 = consts[0], consts[7]
    lists = [[] for _ in range(n)]
    near = False
    least2 = 1e18
    los = np.zeros((n, n), dtype=np.uint8)
    lost = False
    for i in range(n):
        if not member[i]:
            continue
        for j in range(n):
            if j == i or not member[j]:
                continue
            rx = xy[i, 0] * inv_len - xy[j, 0] * inv_len
            ry = xy[i, 1] * inv_len - xy[j, 1] * inv_len
            if rx * rx + ry * ry < r_sense2:
                lists[i].append(j)
                near = True
            if j > i:
                sx = xy[i, 0] - xy[j, 0]
                sy = xy[i, 1] - xy[j, 1]
                sep2 = sx * sx + sy * sy
                least2 = min(least2, sep2)
                if sep2 < SEPARATION_NM**2:
                    los[i, j] = los[j, i] = 1
                    lost = True
    return lists, near, least2, los, lost


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 120), spread_nm=st.sampled_from([5.0, 40.0, 300.0, 3000.0]),
       kinds=st.integers(0, 3), moves=st.integers(0, 3))
def test_grid_answers_as_all_pairs(seed: int, n: int, spread_nm: float, kinds: int, moves: int) -> None:
    """Neighbour lists in index order, whether any pair is within the sensing radius, the
    smallest separation (exact, however far) and the losses of separation; then again after
    small moves with fewer members (the grid built before serves, or is rebuilt)."""
    rng = np.random.default_rng(seed)
    params = SimConfig().to_params(1500.0)
    xy = _points(seed, n, spread_nm, kinds)
    member = (rng.random(n) < 0.85).astype(float)
    g = np.zeros((grid.grid_rows(n), n))
    for _ in range(moves + 1):
        got = _grid_answers(xy, member, params, g)
        want = _all_pairs_answers(xy, member, params)
        assert got[0] == want[0]
        assert got[1] == want[1]
        assert got[2] == want[2]
        assert np.array_equal(got[3], want[3])
        assert got[4] == want[4]
        # Moves within and beyond half a skin; some members leave.
        xy = xy + rng.normal(0.0, rng.choice([0.01, 1.0, 3.0]), xy.shape)
        member = member * (rng.random(n) < 0.9)


def _random_world(rng: np.random.Generator, n: int, spread_nm: float) -> np.ndarray:
    """One world of n aircraft: flying ones heading about for destinations across, clustered
    so that neighbours are in range, some coincident or on cell borders, some absent or
    arrived, two far outside the workspace (absent and arrived there: a flying one would
    meet the NF where it is undefined)."""
    state = kernel.new_state(1, n)[0]
    xy = _points(int(rng.integers(2**31)), n, spread_nm, kinds=2)
    dest = -xy + rng.normal(0.0, 20.0, xy.shape)
    state[:, kernel.S_X], state[:, kernel.S_Y] = xy[:, 0], xy[:, 1]
    state[:, kernel.S_DEST_X], state[:, kernel.S_DEST_Y] = dest[:, 0], dest[:, 1]
    state[:, kernel.S_WP_X], state[:, kernel.S_WP_Y] = dest[:, 0], dest[:, 1]
    heading = np.arctan2(dest[:, 1] - xy[:, 1], dest[:, 0] - xy[:, 0]) + rng.normal(0.0, 0.5, n)
    state[:, kernel.S_HEADING] = np.angle(np.exp(1j * heading))
    state[:, kernel.S_THETA_NH] = state[:, kernel.S_HEADING]
    state[:, kernel.S_DEST_HEADING] = np.arctan2(dest[:, 1] - xy[:, 1], dest[:, 0] - xy[:, 0])
    state[:, kernel.S_THETA_D] = state[:, kernel.S_DEST_HEADING]
    state[:, kernel.S_COS_D] = np.cos(state[:, kernel.S_THETA_D])
    state[:, kernel.S_SIN_D] = np.sin(state[:, kernel.S_THETA_D])
    state[:, kernel.S_AIRSPEED] = 450.0
    state[:, kernel.S_FRESH] = 1.0
    state[:, kernel.S_STATUS] = rng.choice([FLYING, FLYING, FLYING, FLYING, ARRIVED, ABSENT], n)
    if n > 3:
        state[n - 2 :, kernel.S_X] = [5000.0, -1e9]
        state[n - 2 :, kernel.S_STATUS] = [ABSENT, ARRIVED]
    return state


def _fly(state: np.ndarray, search: str, params: np.ndarray, wind: np.ndarray, periods: int,
         record_every: int) -> tuple[np.ndarray, list[dict[str, np.ndarray]], str]:
    """The state after ``periods`` periods, each period's trace, and the error that stopped
    the flight ("" if none: coincident aircraft can drive the law to a NaN)."""
    state = state.copy()
    scratch = KernelScratch(search)
    traces = []
    for _ in range(periods):
        waypoints = state[:, :, kernel.S_WP_X : kernel.S_WP_Y + 1].copy()
        try:
            trace = kernel.advance(state, waypoints, wind, 300.0, params, record_every=record_every,
                                   scratch=scratch)
        except FloatingPointError as error:
            return state, traces, str(error)
        traces.append({name: getattr(trace, name).copy() for name in TRACE_FIELDS})
    return state, traces, ""


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 120), n_worlds=st.sampled_from([1, 3, kernel.LANE_MIN_WORLDS]),
       spread_nm=st.sampled_from([30.0, 120.0, 600.0]), stop=st.booleans(), record_every=st.integers(0, 2))
def test_kernel_flies_the_same_bits_with_the_grid(seed: int, n: int, n_worlds: int, spread_nm: float, stop: bool,
                                                  record_every: int) -> None:
    """Every field of the state and of each period's trace, one world, a small batch and the
    lane path, the grid against the loops over all pairs."""
    rng = np.random.default_rng(seed)
    state = np.stack([_random_world(rng, n, spread_nm) for _ in range(n_worlds)])
    params = SimConfig().to_params(1500.0, stop_on_violation=stop)
    wind = rng.normal(0.0, 10.0, (n_worlds, 2))
    pairs_state, pairs_traces, pairs_error = _fly(state, "all_pairs", params, wind, 2, record_every)
    grid_state, grid_traces, grid_error = _fly(state, "grid", params, wind, 2, record_every)
    assert pairs_error == grid_error
    assert np.array_equal(pairs_state, grid_state, equal_nan=True)
    assert len(pairs_traces) == len(grid_traces)
    for pairs, gridded in zip(pairs_traces, grid_traces):
        for name in TRACE_FIELDS:
            assert np.array_equal(pairs[name], gridded[name]), name


def test_scratch_search_choice() -> None:
    """"auto" gives the grid from ``GRID_MIN_AIRCRAFT`` aircraft; a bad name is refused."""
    small, large = kernel.GRID_MIN_AIRCRAFT - 1, kernel.GRID_MIN_AIRCRAFT

    def cells(scratch: KernelScratch, n: int) -> np.ndarray | None:
        scratch.get(2, n)
        return scratch.cells

    assert cells(KernelScratch(), small) is None
    assert cells(KernelScratch(), large).shape == (2, grid.grid_rows(large), large)
    assert cells(KernelScratch("grid"), 2).shape == (2, grid.grid_rows(2), 2)
    assert cells(KernelScratch("all_pairs"), 200) is None
    with pytest.raises(ValueError, match="neighbour_search"):
        KernelScratch("kd-tree")


def test_aircraft_exactly_on_cell_borders() -> None:
    """Aircraft placed on the cells' borders of the grid their box gets (and a sensing radius
    to either side of them, and a hair inside): the same answers as over all pairs."""
    n = 40
    params = SimConfig().to_params(1500.0)
    cell_nm = max(SENSING_NM, SEPARATION_NM)
    g = np.zeros((grid.grid_rows(n), n))
    xy = np.zeros((n, 2))
    xy[1] = (300.0, 300.0)  # the box: (0, 0) to (300, 300)
    g[grid.GRID_X, :n], g[grid.GRID_Y, :n], g[grid.GRID_MEMBER, :n] = xy[:, 0], xy[:, 1], 1.0
    _, _, width, _ = grid.prepare(g, 0, n, cell_nm)
    k = np.arange(n - 2) % 5 + 1
    offsets = np.array([0.0, SENSING_NM, -SENSING_NM, 1e-12, -1e-12])[np.arange(n - 2) // 5 % 5]
    xy[2:, 0] = k * width + offsets
    xy[2:, 1] = (np.arange(n - 2) % 3) * width
    grid.forget(g, 0)
    got = _grid_answers(xy, np.ones(n), params, g)
    assert g[grid.GRID_META + 3, 0] == width  # the same box, so the same cells
    want = _all_pairs_answers(xy, np.ones(n), params)
    assert got[0] == want[0] and got[1] == want[1] and got[2] == want[2] and got[4] == want[4]
    assert np.array_equal(got[3], want[3])
    assert want[1]  # pairs within the sensing radius across a border exist
