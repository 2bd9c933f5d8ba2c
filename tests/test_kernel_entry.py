"""``advance``'s entry: inputs of the exact types it needs take a quick path whose value
checks run in compiled code; anything else is checked in Python. Both paths fly the same
and refuse the same inputs with the same errors."""

from __future__ import annotations

import numpy as np
import pytest

from atc_nf_env import kernel, nf
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import advance
from atc_nf_env.scenarios import converging
from atc_nf_env.simulation import initial_state

SCENARIO = converging(4)
PARAMS = SimConfig().to_params(SCENARIO.workspace_radius_nm)


def _inputs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return initial_state(SCENARIO, n_worlds=2), np.repeat(SCENARIO.dest_xy[None], 2, axis=0), np.array(
        [[3.0, -2.0], [-5.0, 1.0]]
    )


def test_lists_strided_params_and_numpy_integers_fly_as_exact_arrays_do() -> None:
    state, waypoints, wind = _inputs()
    advance(state, waypoints, wind, 300.0, PARAMS)
    other, _, _ = _inputs()
    strided = np.empty(2 * PARAMS.size)
    strided[::2] = PARAMS
    trace = advance(other, waypoints.tolist(), wind.tolist(), 300, strided[::2], record_every=np.int64(0))
    assert np.array_equal(other, state)
    assert trace.steps_done.tolist() == [60, 60]


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda s, w, v, p: s.__setitem__((1, 2, 0), np.nan), "state contains NaN or inf"),
        (lambda s, w, v, p: w.__setitem__((0, 3, 1), np.inf), "waypoints contains NaN or inf"),
        (lambda s, w, v, p: v.__setitem__((1, 0), -np.inf), "wind_kt contains NaN or inf"),
        (lambda s, w, v, p: p.__setitem__(0, 0.0), r"params\[0\] \(k\) = .*0\.0\)?: must be > 0"),
        (lambda s, w, v, p: p.__setitem__(1, np.nan), r"params contains NaN or inf at index \[1\]"),
    ],
)
def test_a_bad_value_is_refused_before_anything_moves(change, message) -> None:
    state, waypoints, wind = _inputs()
    params = PARAMS.copy()
    change(state, waypoints, wind, params)
    before = state.copy()
    with pytest.raises(ValueError, match=message):
        advance(state, waypoints, wind, 300.0, params)
    assert np.array_equal(state, before, equal_nan=True)


def test_the_first_bad_input_is_named_whichever_path_checks_it() -> None:
    state, waypoints, wind = _inputs()
    params = PARAMS.copy()
    params[0] = -1.0
    state[0, 0, 0] = np.nan
    # params are checked before the values of the arrays, and before the duration.
    with pytest.raises(ValueError, match=r"params\[0\] \(k\)"):
        advance(state, waypoints, wind, 301.0, params)
    with pytest.raises(ValueError, match="state contains NaN"):
        advance(state, waypoints, wind, 301.0, PARAMS)
    with pytest.raises(ValueError, match="not a whole number of integration steps"):
        advance(_inputs()[0], waypoints, wind, 301.0, PARAMS)
    with pytest.raises(ValueError, match=r"record_every = True"):
        advance(_inputs()[0], waypoints, wind, 300.0, PARAMS, record_every=True)


def _one_world() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    state, waypoints, wind = _inputs()
    return state[:1].copy(), waypoints[:1].copy(), wind[:1].copy()


@pytest.mark.parametrize("inputs", [_inputs, _one_world], ids=["batch", "one world"])
@pytest.mark.parametrize("as_lists", [False, True], ids=["compiled check", "Python check"])
@pytest.mark.parametrize(
    "index, value, message",
    [
        (nf.P_SUBSTEP, 0.0, r"params\[22\] \(substep_s\) = 0\.0: must be at least 0\.001 s"),
        (nf.P_SUBSTEP, -1.0, r"params\[22\] \(substep_s\) = -1\.0: must be at least 0\.001 s"),
        (nf.P_SUBSTEP, 1e-7, r"params\[22\] \(substep_s\) = 1e-07: must be at least 0\.001 s"),
        (nf.P_SUBSTEP, np.inf, r"params contains NaN or inf at index \[22\]"),
        (nf.P_DT, 1e-7, r"params\[12\] \(dt_s\) = 1e-07: must be at least 0\.001 s"),
        (nf.P_DT, -1.0, r"params\[12\] \(dt_s\) = -1\.0: must be at least 0\.001 s"),
    ],
)
def test_a_step_or_sub_step_too_short_is_refused(inputs, as_lists, index, value, message) -> None:
    state, waypoints, wind = inputs()
    params = PARAMS.copy()
    params[index] = value
    before = state.copy()
    if as_lists:
        waypoints = waypoints.tolist()
    with pytest.raises(ValueError, match=message):
        advance(state, waypoints, wind, 0.0 if index == nf.P_DT else 300.0, params)
    assert np.array_equal(state, before)


def test_a_step_with_too_many_sub_steps_is_refused() -> None:
    state, waypoints, wind = _one_world()
    params = PARAMS.copy()
    params[nf.P_DT] = 60.0
    params[nf.P_SUBSTEP] = 60.0 / (kernel.MAX_SUBSTEPS + 1)
    with pytest.raises(ValueError, match=r"more than 10000 sub-steps; substep_s must be at least dt_s / 10000"):
        advance(state, waypoints, wind, 300.0, params)
    params[nf.P_SUBSTEP] = 60.0 / kernel.MAX_SUBSTEPS  # the bound itself is accepted
    assert advance(state, waypoints, wind, 300.0, params).steps_done.tolist() == [5]


def test_an_advance_of_too_many_steps_is_refused() -> None:
    state, waypoints, wind = _one_world()
    before = state.copy()
    seconds = (kernel.MAX_STEPS_PER_CALL + 1) * PARAMS[nf.P_DT]
    with pytest.raises(ValueError, match=r"is 10000001 integration steps of 5\.0 s; at most 10000000"):
        advance(state, waypoints, wind, seconds, PARAMS, record_every=1)
    assert np.array_equal(state, before)
    with pytest.raises(ValueError, match=r"dt_s = 0\.0: the integration step must be a finite number >= 0\.001 s"):
        kernel.steps_for(300.0, 0.0)


@pytest.mark.parametrize("inputs", [_inputs, _one_world], ids=["batch", "one world"])
@pytest.mark.parametrize("as_lists", [False, True], ids=["compiled check", "Python check"])
@pytest.mark.parametrize("status", [42.0, -1.0, 0.5, 4.0])
def test_an_unknown_aircraft_status_is_refused(inputs, as_lists, status) -> None:
    state, waypoints, wind = inputs()
    state[-1, 1, kernel.S_STATUS] = status
    before = state.copy()
    if as_lists:
        waypoints = waypoints.tolist()
    allowed = r"allowed: 0\.0 \(FLYING\), 1\.0 \(ARRIVED\), 2\.0 \(LEFT\), 3\.0 \(ABSENT\)"
    with pytest.raises(ValueError, match=rf"state\[{len(state) - 1}, 1, S_STATUS\] = {status!r} is not an aircraft "
                                         rf"status; {allowed}"):
        advance(state, waypoints, wind, 300.0, PARAMS)
    assert np.array_equal(state, before)
