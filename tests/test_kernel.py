"""The batched kernel: finiteness, determinism, wind, arrival, bad input, calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atc_nf_env import calibration, kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import ARRIVED, FLYING, LEFT, S_STATUS, S_X, S_Y, advance
from atc_nf_env.scenarios import Scenario, converging, random_encounter
from atc_nf_env.simulation import initial_state
from atc_nf_env.units import SECONDS_PER_HOUR

CONFIG = SimConfig()


def params_for(scenario: Scenario, **kwargs) -> np.ndarray:
    return CONFIG.to_params(scenario.workspace_radius_nm, **kwargs)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(1, 6),
    seed=st.integers(0, 10_000),
    wind=st.tuples(st.floats(-60, 60), st.floats(-60, 60)),
    waypoint_scale=st.floats(0.0, 1.0),
)
def test_no_nan_or_inf_ever_leaves_the_kernel(n, seed, wind, waypoint_scale):
    scenario = random_encounter(n, seed=seed, min_separation_nm=6.0)
    rng = np.random.default_rng(seed)
    state = initial_state(scenario, n_worlds=3)
    params = params_for(scenario)
    for _ in range(3):
        # Waypoints anywhere in a disk up to the workspace edge, including on top of
        # aircraft and far behind them: the law's singular situations.
        radius = waypoint_scale * (scenario.workspace_radius_nm - 10.0)
        angles = rng.uniform(-math.pi, math.pi, (3, n))
        waypoints = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=-1)
        waypoints[0, 0] = state[0, 0, S_X : S_Y + 1]  # waypoint exactly on the aircraft
        trace = advance(state, waypoints, np.tile(wind, (3, 1)), 300.0, params)
        assert np.isfinite(state).all()
        for name in ("min_airspeed_kt", "max_airspeed_kt", "worst_excursion_kt", "min_separation_nm"):
            assert np.isfinite(getattr(trace, name)).all(), name
        # Guard 2 holds whatever other guard acts: no commanded airspeed beyond the cap.
        assert (trace.max_airspeed_kt <= CONFIG.airspeed_cap_kt).all()
        assert (trace.min_airspeed_kt >= -CONFIG.airspeed_cap_kt).all()


def test_same_input_same_trajectory_bit_for_bit_and_across_batch_sizes():
    scenario = converging(6)
    waypoints = np.tile(scenario.dest_xy, (1, 1, 1))
    wind = np.array([[7.0, -4.0]])
    single = initial_state(scenario)
    again = initial_state(scenario)
    batch = initial_state(scenario, n_worlds=64)
    params = params_for(scenario)
    for _ in range(6):
        advance(single, waypoints, wind, 300.0, params)
        advance(again, waypoints, wind, 300.0, params)
        advance(batch, np.repeat(waypoints, 64, axis=0), np.repeat(wind, 64, axis=0), 300.0, params)
    assert np.array_equal(single, again)
    for b in range(64):
        assert np.array_equal(batch[b], single[0])


def test_wind_adds_to_the_ground_velocity():
    scenario = converging(1)
    still = initial_state(scenario)
    windy = initial_state(scenario)
    params = params_for(scenario)
    wp = scenario.dest_xy[None]
    dt = CONFIG.dt_s
    advance(still, wp, np.zeros((1, 2)), dt, params)
    advance(windy, wp, np.array([[20.0, -10.0]]), dt, params)
    drift = windy[0, 0, S_X : S_Y + 1] - still[0, 0, S_X : S_Y + 1]
    np.testing.assert_allclose(drift, np.array([20.0, -10.0]) * dt / SECONDS_PER_HOUR, rtol=1e-12)


def test_an_arrived_aircraft_leaves_and_stops_being_an_obstacle():
    # Aircraft 0 starts 1 nm from its destination and arrives on the first step;
    # aircraft 1 then sees no neighbour at all.
    scenario = Scenario(
        name="arrival",
        start_xy=np.array([[0.0, 0.0], [12.0, 0.0]]),
        start_heading=np.array([0.0, math.pi / 2]),
        dest_xy=np.array([[1.0, 0.0], [12.0, 300.0]]),
        dest_heading=np.array([0.0, math.pi / 2]),
    )
    state = initial_state(scenario)
    params = params_for(scenario)
    trace = advance(state, scenario.dest_xy[None], np.zeros((1, 2)), CONFIG.dt_s, params)
    assert state[0, 0, S_STATUS] == ARRIVED
    assert state[0, 1, S_STATUS] == FLYING
    frozen = state[0, 0].copy()
    trace = advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 60.0, params)
    assert np.array_equal(state[0, 0], frozen)
    assert trace.steps_flown[0, 0] == 0
    assert trace.min_separation_nm[0] == kernel.NO_PAIR_SEPARATION_NM


def test_aircraft_blown_out_of_the_workspace_has_left():
    scenario = Scenario(
        name="edge",
        start_xy=np.array([[280.0, 0.0]]),
        start_heading=np.array([0.0]),
        dest_xy=np.array([[0.0, 0.0]]),
        dest_heading=np.array([math.pi]),
        workspace_radius_nm=300.0,
    )
    state = initial_state(scenario)
    advance(state, scenario.dest_xy[None], np.array([[3000.0, 0.0]]), 300.0, params_for(scenario))
    assert state[0, 0, S_STATUS] == LEFT
    assert math.hypot(*state[0, 0, :2]) < 300.0 + 3000.0 * CONFIG.dt_s / 3600


def test_stop_on_violation_stops_a_world_at_its_first_violation():
    scenario = converging(4)
    state = initial_state(scenario, n_worlds=2)
    waypoints = np.repeat(scenario.dest_xy[None], 2, axis=0)
    params = params_for(scenario, stop_on_violation=True)
    trace = advance(state, waypoints, np.zeros((2, 2)), 300.0, params)
    # The NF alone aimed 500 nm away commands ~1000 kt at once.
    assert trace.violated.all()
    assert (trace.steps_done == 1).all()
    assert (trace.max_airspeed_kt > CONFIG.airspeed_max_kt).all()


def test_nf_alone_breaks_the_envelope_but_keeps_separation():
    scenario = converging(4)
    state = initial_state(scenario)
    params = params_for(scenario)
    violations, flown, min_sep = 0, 0, np.inf
    for _ in range(30):
        trace = advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params)
        violations += trace.violation_steps.sum()
        flown += trace.steps_flown.sum()
        min_sep = min(min_sep, trace.min_separation_nm[0])
    assert (state[0, :, S_STATUS] == ARRIVED).all()
    assert violations / flown > 0.3
    assert min_sep > CONFIG.separation_min_nm


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda s, w, v: (s[..., :5], w, v), "state has shape"),
        (lambda s, w, v: (s, w[:, :1], v), "waypoints has shape"),
        (lambda s, w, v: (s, w, v[:, :1]), "wind_kt has shape"),
        (lambda s, w, v: (s, np.where(w == w[0, 0, 0], np.nan, w), v), "waypoints contains NaN"),
        (lambda s, w, v: (s, w, np.full_like(v, np.inf)), "wind_kt contains NaN or inf"),
    ],
)
def test_bad_kernel_input_is_a_clear_error(change, message):
    scenario = converging(3)
    state, waypoints, wind = change(initial_state(scenario), scenario.dest_xy[None], np.zeros((1, 2)))
    with pytest.raises(ValueError, match=message):
        advance(state, waypoints, wind, 300.0, params_for(scenario))


def test_duration_must_be_whole_integration_steps():
    scenario = converging(3)
    state = initial_state(scenario)
    with pytest.raises(ValueError, match="whole number of integration steps"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 7.0, params_for(scenario))
    with pytest.raises(ValueError, match="seconds"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), -5.0, params_for(scenario))


@pytest.mark.parametrize(
    "field, value",
    [("dt_s", 0.0), ("k_u", -1.0), ("k_theta", float("nan")), ("sensing_radius_nm", 4.0), ("barrier_nm", 50.0)],
)
def test_impossible_configuration_is_rejected(field, value):
    with pytest.raises(ValueError, match=field):
        SimConfig(**{field: value})
    with pytest.raises(ValueError, match="no field"):
        SimConfig().replace(not_a_gain=1.0)


def test_default_gains_are_the_calibrated_ones():
    calibrated = calibration.calibrate()
    assert calibrated.k_u == pytest.approx(CONFIG.k_u, rel=1e-9)
    assert calibrated.k_z == pytest.approx(CONFIG.k_z, rel=1e-12)


def test_calibration_meets_the_speed_targets():
    check = calibration.unobstructed_airspeed(CONFIG, np.array([100.0]))
    assert check.median_kt[0] == pytest.approx(454.0, rel=0.03)
    window = calibration.unobstructed_airspeed(CONFIG, np.linspace(60.0, 110.0, 11))
    assert window.min_kt.min() >= CONFIG.airspeed_min_kt
    assert window.max_kt.max() <= CONFIG.airspeed_max_kt
    # The NF alone aimed at a destination 500 nm away breaks the envelope at both ends.
    alone = calibration.nf_alone_airspeed(CONFIG, np.array([500.0, 1.0]))
    assert alone[0] > CONFIG.airspeed_max_kt
    assert alone[1] < CONFIG.airspeed_min_kt


def test_steps_refined_at_the_singularity_fly_the_same_alone_and_in_a_batch():
    # Converging-6 without wind reaches the saddle, where commands saturate and steps
    # are flown in sub-steps; worlds around it in the batch take other paths.
    scenario = converging(6)
    params = params_for(scenario)
    single = initial_state(scenario)
    batch = initial_state(scenario, n_worlds=5)
    waypoints = scenario.dest_xy[None]
    wind = np.zeros((1, 2))
    batch_wind = np.array([[0.0, 0.0], [12.0, 3.0], [0.0, 0.0], [-8.0, 5.0], [0.0, 0.0]])
    refined = False
    for _ in range(8):
        trace = advance(single, waypoints, wind, 300.0, params)
        refined |= bool((single[0, :, kernel.S_LAST_SUBSTEPS] > 1).any())
        refined |= bool((trace.max_airspeed_kt >= CONFIG.airspeed_cap_kt).any())
        advance(batch, np.repeat(waypoints, 5, axis=0), batch_wind, 300.0, params)
    assert refined
    for b in (0, 2, 4):
        assert np.array_equal(batch[b], single[0])


def test_a_refined_step_keeps_the_outer_grid():
    # Per-step counts stay per integration step however many sub-steps a step took.
    scenario = converging(6)
    params = params_for(scenario)
    state = initial_state(scenario)
    steps = kernel.steps_for(300.0, CONFIG.dt_s)
    saw_refined = False
    for _ in range(8):
        # A copy flown one step per call shows which steps were refined.
        copy = state.copy()
        for _ in range(steps):
            advance(copy, scenario.dest_xy[None], np.zeros((1, 2)), CONFIG.dt_s, params)
            saw_refined |= bool((copy[0, :, kernel.S_LAST_SUBSTEPS] > 1).any())
        trace = advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params, record_every=1)
        assert trace.record.shape[1] == steps + 1
        assert (trace.steps_flown <= steps).all() and (trace.violation_steps <= trace.steps_flown).all()
    assert saw_refined
    # Sub-steps add up to whole steps: every aircraft still flying has flown 40 min.
    assert (state[0, :, S_STATUS] == FLYING).all()
    np.testing.assert_allclose(state[0, :, kernel.S_TIME], 8 * 300.0, rtol=0, atol=1e-6)


def test_the_world_loop_counts_no_references_and_the_option_degrades_cleanly(monkeypatch):
    # The world loop and its per-world wrapper are compiled without numba's reference
    # counts (their atomic operations took about a quarter of a one-world flight); a numba
    # without the private option keeps the counts instead of failing to import.
    from numba.core import cpu

    from atc_nf_env import nf

    assert nf.NO_REFERENCE_COUNTS == {"_nrt": False}
    for function in (kernel._advance_world, kernel._advance_one):
        assert function.targetoptions.get("_nrt") is False
    monkeypatch.setattr(cpu, "CPUTargetOptions", type("OptionsWithoutNrt", (), {}))
    assert nf._without_reference_counts() == {}


def _trace_values(trace: kernel.Trace) -> dict[str, np.ndarray]:
    return {name: np.array(value, copy=True) for name, value in trace.__dict__.items()}


def test_a_trace_the_caller_still_holds_is_never_written_again():
    # KernelScratch reuses a trace only once nothing outside it refers to the trace or to any
    # of its arrays: a held trace, a held field and a held view of a field all keep theirs.
    scenario = converging(4)
    params = params_for(scenario)
    scratch = kernel.KernelScratch()
    state = initial_state(scenario, n_worlds=2)
    waypoints = np.repeat(scenario.dest_xy[None], 2, axis=0)
    wind = np.array([[5.0, -3.0], [-8.0, 2.0]])
    held = advance(state, waypoints, wind, 300.0, params, record_every=6, scratch=scratch)
    field = advance(state, waypoints, wind, 300.0, params, record_every=6, scratch=scratch).los_pairs
    view = advance(state, waypoints, wind, 300.0, params, record_every=6, scratch=scratch).violation_steps[:, 1:]
    snapshots = (_trace_values(held), field.copy(), view.copy())
    for _ in range(4):  # flights that differ from the held ones: any overwrite would show
        advance(state, waypoints, -wind, 600.0 if _ % 2 else 300.0, params, record_every=6, scratch=scratch)
    for name, value in snapshots[0].items():
        assert np.array_equal(getattr(held, name), value), name
    assert np.array_equal(field, snapshots[1]) and np.array_equal(view, snapshots[2])
    assert len({id(held.los_pairs), id(field), id(view.base)}) == 3


def test_a_dropped_trace_is_reused_and_reads_as_a_new_one():
    # The reuse exists (it is the point: about a fifth of a one-world period) and cannot be
    # told from new arrays: a reused trace holds exactly what a fresh scratch's holds, its
    # record included, though the world stopped early and left rows unwritten.
    scenario = converging(4)
    params = params_for(scenario, stop_on_violation=True)
    waypoints = np.repeat(scenario.dest_xy[None], 1, axis=0)
    wind = np.zeros((1, 2))
    scratch = kernel.KernelScratch()
    state = initial_state(scenario)
    first = advance(state, waypoints, wind, 600.0, params_for(scenario), record_every=2, scratch=scratch)
    first_id = id(first)
    assert first.steps_done[0] == 120 and (first.record[0, -1] != 0.0).any()  # every row written
    del first
    behind = waypoints.copy()
    behind[0, 0] = 2 * state[0, 0, S_X : S_Y + 1] - waypoints[0, 0]  # aircraft 0 reverses: a breach
    again = advance(initial_state(scenario), behind, wind, 600.0, params, record_every=2, scratch=scratch)
    fresh = advance(initial_state(scenario), behind, wind, 600.0, params, record_every=2,
                    scratch=kernel.KernelScratch())
    assert id(again) == first_id and again.steps_done[0] < 120
    for name, value in _trace_values(fresh).items():
        assert np.array_equal(getattr(again, name), value), name


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["drop", "trace", "field", "view", "record"]), st.integers(0, 3)),
                min_size=1, max_size=12))
def test_whatever_a_caller_keeps_of_a_trace_stays_as_it_was(calls):
    # Random sequences of calls that keep a whole trace, one of its arrays, a view of one, or
    # nothing, on changing shapes (1 or 2 worlds, with and without a record): nothing kept is
    # ever overwritten by a later call on the same scratch.
    scenario = converging(4)
    params = params_for(scenario)
    scratch = kernel.KernelScratch()
    kept = []
    for index, (keep, variant) in enumerate(calls):
        n_worlds = 1 + variant % 2
        state = initial_state(scenario, n_worlds=n_worlds)
        waypoints = np.repeat(scenario.dest_xy[None], n_worlds, axis=0)
        wind = np.full((n_worlds, 2), float(index) - 3.0)
        trace = advance(state, waypoints, wind, 300.0, params, record_every=30 if variant >= 2 else 0, scratch=scratch)
        held = {"trace": trace, "field": trace.min_airspeed_kt, "view": trace.steps_flown[:, 1:],
                "record": trace.record, "drop": None}[keep]
        if held is not None:
            kept.append((held, _trace_values(held) if keep == "trace" else held.copy()))
        del trace
    for held, snapshot in kept:
        if isinstance(held, kernel.Trace):
            assert all(np.array_equal(getattr(held, name), value) for name, value in snapshot.items())
        else:
            assert np.array_equal(held, snapshot)
