"""``advance``'s entry: inputs of the exact types it needs take a quick path whose value
checks run in compiled code; anything else is checked in Python. Both paths fly the same
and refuse the same inputs with the same errors."""

from __future__ import annotations

import numpy as np
import pytest

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
