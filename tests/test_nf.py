"""The dipolar NF (2)-(4): closed-form gradients, range, and the proximity function."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atc_nf_env import nf
from atc_nf_env.config import SimConfig

CONFIG = SimConfig()
WORKSPACE = 1500.0
PARAMS = CONFIG.to_params(WORKSPACE)


def phi_and_grad(i, pos, wp, theta_d, params=PARAMS, status=None):
    status = np.zeros(len(pos)) if status is None else status
    grad = np.zeros((len(pos), 2))
    phi = nf.nf_value_and_gradients(i, pos, status, wp[0], wp[1], theta_d, params, grad)
    return phi, grad


def finite_difference_gradient(i, pos, wp, theta_d, params=PARAMS, h_nm=1e-4):
    """Central differences with respect to every position, in units of L."""
    grad = np.zeros((len(pos), 2))
    for j in range(len(pos)):
        for axis in range(2):
            plus = pos.copy()
            minus = pos.copy()
            plus[j, axis] += h_nm
            minus[j, axis] -= h_nm
            f_plus, _ = phi_and_grad(i, plus, wp, theta_d, params)
            f_minus, _ = phi_and_grad(i, minus, wp, theta_d, params)
            grad[j, axis] = (f_plus - f_minus) / (2 * h_nm) * params[nf.P_LENGTH]
    return grad


@st.composite
def configurations(draw):
    """Random separated aircraft (some within sensing range of aircraft 0) and a waypoint."""
    n = draw(st.integers(2, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    pos = [rng.uniform(-300, 300, 2)]
    while len(pos) < n:
        # Half the neighbours close to aircraft 0, inside the sensing radius.
        centre = pos[0] if rng.random() < 0.5 else np.zeros(2)
        spread = 12.0 if centre is pos[0] else 300.0
        candidate = centre + rng.uniform(-spread, spread, 2)
        # Stay off the kinks of the C¹ cut-offs, where one-sided derivatives differ
        # at second order and finite differences are not a fair judge.
        if all(np.linalg.norm(candidate - p) > 5.5 for p in pos):
            pos.append(candidate)
    pos = np.array(pos)
    distance = rng.uniform(1.0, 300.0)
    angle = rng.uniform(-math.pi, math.pi)
    wp = pos[0] + distance * np.array([math.cos(angle), math.sin(angle)])
    theta_d = rng.uniform(-math.pi, math.pi)
    return pos, wp, theta_d


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configurations())
def test_closed_form_gradients_match_central_differences(config):
    pos, wp, theta_d = config
    _, analytic = phi_and_grad(0, pos, wp, theta_d)
    numeric = finite_difference_gradient(0, pos, wp, theta_d)
    scale = max(np.abs(analytic).max(), 1e-6)
    assert np.abs(analytic - numeric).max() / scale <= 1e-6, (analytic, numeric)


def test_gradients_with_neighbours_inside_the_barrier():
    """A neighbour 6 nm away (inside the 7 nm barrier) and one at 10 nm (inside the 12 nm
    sensing radius): ∇_jΦ_i is non-zero for both, zero for the one beyond."""
    pos = np.array([[0.0, 0.0], [6.0, 1.0], [-8.0, 6.0], [200.0, 0.0]])
    wp = np.array([90.0, 30.0])
    _, analytic = phi_and_grad(0, pos, wp, 0.3)
    numeric = finite_difference_gradient(0, pos, wp, 0.3)
    assert np.abs(analytic[1]).max() > 1e-3
    assert np.abs(analytic[2]).max() > 0
    assert np.all(analytic[3] == 0.0)  # beyond the sensing radius: no influence
    assert np.abs(analytic - numeric).max() / np.abs(analytic).max() <= 1e-6


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-1000, 1000),
    y=st.floats(-1000, 1000),
    wx=st.floats(-1000, 1000),
    wy=st.floats(-1000, 1000),
    theta_d=st.floats(-math.pi, math.pi),
)
def test_phi_lies_in_unit_interval(x, y, wx, wy, theta_d):
    pos = np.array([[x, y]])
    phi, grad = phi_and_grad(0, pos, (wx, wy), theta_d)
    assert 0.0 <= phi <= 1.0
    assert np.isfinite(grad).all()


def test_phi_is_zero_only_at_the_destination():
    wp = (40.0, -25.0)
    phi_at, _ = phi_and_grad(0, np.array([wp]), wp, 0.0)
    assert phi_at == 0.0
    for offset in (1e-3, 0.1, 1.0, 50.0):
        for angle in np.linspace(0, 2 * np.pi, 7):
            pos = np.array([[wp[0] + offset * math.cos(angle), wp[1] + offset * math.sin(angle)]])
            phi, _ = phi_and_grad(0, pos, wp, 0.0)
            assert phi > 0.0


def test_phi_is_positive_at_the_destination_when_a_neighbour_is_close():
    """f_i(G_i) keeps Φ_i > 0 at the destination while a neighbour is close (paper II-C)."""
    wp = (0.0, 0.0)
    pos = np.array([[0.0, 0.0], [5.5, 0.0]])
    phi, _ = phi_and_grad(0, pos, wp, 0.0)
    assert phi > 0.0


def test_proximity_is_zero_exactly_when_disks_touch():
    status = np.zeros(2)
    contact = 2 * CONFIG.aircraft_radius_nm
    touching = np.array([[0.0, 0.0], [contact, 0.0]])
    assert nf.proximity_function(0, touching, status, PARAMS) == 0.0
    for gap in (1e-6, 0.5, 3.0, 6.9):
        apart = np.array([[0.0, 0.0], [contact + gap, 0.0]])
        g = nf.proximity_function(0, apart, status, PARAMS)
        assert 0.0 < g < 1.0
    far = np.array([[0.0, 0.0], [CONFIG.sensing_radius_nm + 1e-9, 0.0]])
    assert nf.proximity_function(0, far, status, PARAMS) == 1.0
    # Touching makes Φ_i its maximum, 1, away from the destination.
    phi, _ = phi_and_grad(0, touching, (100.0, 0.0), 0.0)
    assert math.isclose(phi, 1.0, rel_tol=0, abs_tol=1e-15)


def test_aircraft_that_left_are_not_obstacles():
    pos = np.array([[0.0, 0.0], [6.0, 0.0]])
    flying = np.zeros(2)
    arrived = np.array([nf.FLYING, nf.ARRIVED])
    assert nf.proximity_function(0, pos, flying, PARAMS) < 1.0
    assert nf.proximity_function(0, pos, arrived, PARAMS) == 1.0


def test_proximity_is_monotone_in_distance():
    status = np.zeros(2)
    distances = np.linspace(5.0, 45.0, 200)
    values = [nf.proximity_function(0, np.array([[0.0, 0.0], [d, 0.0]]), status, PARAMS) for d in distances]
    assert np.all(np.diff(values) >= 0)
