"""The decentralized dipolar navigation function of the paper, equations (2)-(4).

The navigation function of aircraft i::

    Φ_i = (γ_i + f_i) / ((γ_i + f_i)^k + H_i · G_i · β0_i)^(1/k)

with, for aircraft i aimed at its current waypoint q_d with desired orientation θ_d:

- γ_i = ‖q_i − q_d‖², the squared distance to the waypoint;
- H_i = ε_nh + n_i, n_i = (e_d · (q_i − q_d))², e_d = [cos θ_d, sin θ_d]. The paper's
  (4) prints the vehicle's heading θ_i in n_i; the dipolar construction it cites uses
  the desired orientation (the artificial obstacle is the line through q_d normal
  to θ_d), and so do we;
- β0_i = r_world² − ‖q_i‖² − r_i², the circular workspace's boundary obstacle;
- G_i = Π_j h(s_ij), the decentralized proximity function: s_ij = β_ij / β_s with
  β_ij = ‖q_i − q_j‖² − (r_i + r_j)² and β_s its value at the sensing radius R_s;
  h (``proximity_bump``) is 0 when the disks touch, rises like a log barrier within
  the barrier distance, and reaches 1 with zero slope at R_s (a C¹ cut-off). G_i is 1
  when no aircraft is within R_s, 0 exactly when two disks touch, and costs O(N).
  The paper's reference [13] leaves the shape of the cut-off open. Airspeed goes with
  ‖∇Φ‖², so a neighbour that tilts the gradient by 20 % moves the airspeed by 40 %:
  with the defaults (sensing 12 nm, barrier 7 nm) two aircraft passing 11.5 nm apart
  under waypoints 100 nm ahead keep their airspeed inside [366, 540] kt (as under the
  paper's MPC, 11.5-16 nm), while a 40 nm sensing radius breaks the envelope at 20 nm;
- f_i(G_i) = a0 (1 − 3 (G/X)² + 2 (G/X)³) for G < X and 0 beyond: the polynomial of
  the paper's reference [13] that keeps Φ_i > 0 at the destination while a neighbour
  is close, vanishing with its slope at G = X.

All lengths are measured in units of the length scale L (``length_scale_nm``), so
that gradients are dimensionless; the functions take and return positions in nm and
gradients with respect to positions in units of L (multiply by 1/L for per-nm).

The functions are numba-compiled, allocation-free and shared by the batched kernel
and the tests (one implementation, checked against finite differences).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: Fast-math flags that cannot change a finite result: no NaN, no inf, no signed zero.
#: Reassociation, contraction into FMA and approximate functions are left out, because
#: they let the compiler round differently in different call sites, and a world must
#: fly the same trajectory bit for bit whether it is simulated alone or in a batch.
FAST_MATH_FLAGS = {"nnan", "ninf", "nsz"}


def _without_reference_counts() -> dict:
    """``njit`` options that compile a function without numba's reference counting.

    numba counts references to every array a compiled function passes on or slices, with
    an atomic increment and decrement per count (``NRT_incref``/``NRT_decref``), and the
    NF's helpers, called in the integration loop, pass arrays at every aircraft and
    step: sampled with ``perf``, those atomic operations took about 28 % of a one-world
    prediction. A function that allocates nothing needs no counts, and the arithmetic is
    unchanged (bit for bit). The option is numba's own (``_nrt``, of its CPU target
    options, present since before 0.60) but private: where a numba lacks it, the counts
    stay and only the speed differs."""
    try:
        from numba.core.cpu import CPUTargetOptions
    except ImportError:  # pragma: no cover - a numba that moved its target options
        return {}
    return {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}


#: ``njit`` options of the allocation-free hot loops (``_without_reference_counts``).
NO_REFERENCE_COUNTS = _without_reference_counts()

# Layout of the float64 parameter vector shared by the NF and the kernel.
P_K = 0  # exponent k of (2)
P_EPS_NH = 1  # ε_nh of (3), in units of L²
P_LENGTH = 2  # length scale L, nm
P_K_U = 3  # k_u of F_i, kt
P_K_Z = 4  # k_z of F_i, kt
P_K_THETA = 5  # heading gain k_θ of (5b), 1/s
P_R_WORLD = 6  # workspace radius, nm
P_RADIUS = 7  # aircraft disk radius r_i, nm
P_R_SENSE = 8  # sensing radius R_s (centre to centre), nm
P_A0 = 9  # f_i(0), in units of L²
P_X = 10  # f_i vanishes for G_i ≥ X
P_DELTA = 11  # arrival tolerance Δ, nm
P_DT = 12  # integration step, s
P_U_MIN = 13  # envelope lower bound, kt
P_U_MAX = 14  # envelope upper bound, kt
P_SEP_MIN = 15  # separation minimum, nm
P_U_CAP = 16  # saturation of the commanded airspeed, kt (guard, see kernel)
P_STOP_ON_VIOLATION = 17  # 1.0: stop simulating a world at its first violation
P_P_FLOOR = 18  # floor on |P_i| in the 1/P term of (5a) (guard)
P_GRAD_FLOOR = 19  # below this ‖∇Φ‖ the gradient has no direction (guard)
P_DPHI_DT_GAIN = 20  # weight of ∂Φ_i/∂t in (5a): 1 is the paper's law
P_BARRIER = 21  # barrier distance (centre to centre) of the proximity function, nm
P_SUBSTEP = 22  # longest sub-step of an integration step refined at the singularity, s
P_RIGHT_TURN = 23  # right-hand rule at the singularity: largest rotation of θ_nh, rad (0: off)
P_RIGHT_TURN_FROM = 24  # 1/P_i term of (5a), kt, where the right-hand rule starts to act
P_RIGHT_TURN_FULL = 25  # 1/P_i term of (5a), kt, from which it acts in full
P_SUBSTEP_FROM = 26  # 1/P_i term of (5a), kt, above which a step is flown in sub-steps
P_STEP_TOLERANCE = 27  # local error allowed to a full step among neighbours, nm (0: no error control)
N_PARAMS = 28

# Status of an aircraft (stored as float in the state array).
FLYING = 0.0
ARRIVED = 1.0
LEFT = 2.0
ABSENT = 3.0  # padding slot of a world with fewer aircraft than the batch's N


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def proximity_bump(s: float, c: float) -> tuple[float, float]:
    """h(s) and h'(s) of the decentralized proximity function.

    With w(s) = (1 + c) s / (s + c), h(s) = w (2 − w) on [0, 1] and 1 for s ≥ 1: h(0) = 0
    (disks touching), h(1) = 1 with h'(1) = 0 (a C¹ cut-off at the sensing radius), and
    h rises like a log barrier only where s ≲ c, so the repulsion is concentrated
    within the barrier distance instead of spread over the whole sensing disk.
    Overlapping disks (s < 0) are inside a conflict, where the NF is undefined;
    h = 0 there makes G_i = 0 (Φ_i = 1, its maximum) instead of negative (guard).
    """
    if s >= 1.0:
        return 1.0, 0.0
    if s <= 0.0:
        return 0.0, 0.0
    inv = 1.0 / (s + c)
    w = (1.0 + c) * s * inv
    dw = (1.0 + c) * c * inv * inv
    return w * (2.0 - w), 2.0 * (1.0 - w) * dw


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def nf_value_and_gradients(
    i: int,
    pos: np.ndarray,
    status: np.ndarray,
    waypoint_x: float,
    waypoint_y: float,
    theta_d: float,
    params: np.ndarray,
    grad_out: np.ndarray,
) -> float:
    """Φ_i and ∇_jΦ_i for every j; see ``nf_along_direction`` (θ_d given as an angle, rad)."""
    phi, _ = nf_along_direction(
        i,
        pos,
        status,
        waypoint_x,
        waypoint_y,
        math.cos(theta_d),
        math.sin(theta_d),
        nf_constants(params),
        grad_out,
    )
    return phi


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def nf_constants(params: np.ndarray) -> tuple:
    """The NF's constants derived from the parameter vector, computed once per kernel
    call instead of once per aircraft and step (a tuple, to stay allocation-free):
    (1/L, k, 1/k, r_world² − r², (2r)², 1/β_s, c of the barrier, R_s², ε_nh, a0, X),
    lengths in units of L."""
    inv_len = 1.0 / params[P_LENGTH]
    radius = params[P_RADIUS] * inv_len
    r_world = params[P_R_WORLD] * inv_len
    r_sense = params[P_R_SENSE] * inv_len
    barrier = params[P_BARRIER] * inv_len
    contact2 = 4.0 * radius * radius
    beta_s = r_sense * r_sense - contact2
    return (
        inv_len,
        params[P_K],
        1.0 / params[P_K],
        r_world * r_world - radius * radius,
        contact2,
        1.0 / beta_s,
        (barrier * barrier - contact2) / beta_s,
        r_sense * r_sense,
        params[P_EPS_NH],
        params[P_A0],
        params[P_X],
    )


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _value_and_own_gradient(
    gamma: float, p_axis: float, h_nh: float, beta0: float, g_prox: float, grad_g_ix: float, grad_g_iy: float,
    dx: float, dy: float, xi: float, yi: float, ed_x: float, ed_y: float, k: float, inv_k: float, a0: float,
    x_cut: float,
) -> tuple[float, float, float, float]:
    """The part of ``nf_along_direction`` after G_i and ∇_iG_i: (Φ_i, the coefficient of
    ∇_jG_i in ∇_jΦ_i, ∇_iΦ_i's x and y)."""
    # f_i(G_i) and f_i'(G_i).
    if g_prox < x_cut:
        g_rel = g_prox / x_cut
        f = a0 * (1.0 - 3.0 * g_rel * g_rel + 2.0 * g_rel * g_rel * g_rel)
        df = a0 * (-6.0 * g_rel + 6.0 * g_rel * g_rel) / x_cut
    else:
        f = 0.0
        df = 0.0

    a = gamma + f
    m = h_nh * g_prox * beta0
    if k == 2.0:
        a_k = a * a
    else:
        a_k = a**k
    d = a_k + m
    if k == 2.0:
        d_root = math.sqrt(d)
    else:
        d_root = d**inv_k
    phi = a / d_root
    # dΦ = D^(−1/k−1) [M dA − (A/k)(G β0 dH + H β0 dG + H G dβ0)], dA = dγ + f' dG.
    scale = 1.0 / (d_root * d)
    a_over_k = a * inv_k
    coef_g = scale * (m * df - a_over_k * h_nh * beta0)
    coef_gamma = scale * m
    coef_h = -scale * a_over_k * g_prox * beta0
    coef_beta0 = -scale * a_over_k * h_nh * g_prox
    own_x = (
        coef_gamma * 2.0 * dx
        + coef_h * 2.0 * p_axis * ed_x
        + coef_beta0 * (-2.0 * xi)
        + coef_g * grad_g_ix
    )
    own_y = (
        coef_gamma * 2.0 * dy
        + coef_h * 2.0 * p_axis * ed_y
        + coef_beta0 * (-2.0 * yi)
        + coef_g * grad_g_iy
    )
    return phi, coef_g, own_x, own_y


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def nf_along_direction(
    i: int,
    pos: np.ndarray,
    status: np.ndarray,
    waypoint_x: float,
    waypoint_y: float,
    ed_x: float,
    ed_y: float,
    constants: tuple,
    grad_out: np.ndarray,
) -> tuple[float, int]:
    """Φ_i and its closed-form gradients with respect to every aircraft's position.

    Args:
        i: index of the aircraft whose NF is evaluated.
        pos: positions of the N aircraft of one world, shape (N, 2), nm.
        status: status of each aircraft, shape (N,); only FLYING aircraft are obstacles.
        waypoint_x, waypoint_y: aircraft i's current waypoint q_d, nm.
        ed_x, ed_y: unit vector of the desired orientation θ_d at the waypoint.
        constants: ``nf_constants(params)``.
        grad_out: output, shape (N, 2): row j receives ∇_jΦ_i (row i: ∇_iΦ_i), with
            respect to positions in units of L; rows of non-neighbours are zero.

    Returns:
        (Φ_i, dimensionless in [0, 1]; the number of neighbours within the sensing radius).
    """
    n = pos.shape[0]
    (inv_len, k, inv_k, beta0_max, contact2, inv_beta_s, c_bar, r_sense2, eps_nh, a0, x_cut) = constants
    xi = pos[i, 0] * inv_len
    yi = pos[i, 1] * inv_len
    dx = (pos[i, 0] - waypoint_x) * inv_len
    dy = (pos[i, 1] - waypoint_y) * inv_len

    gamma = dx * dx + dy * dy
    p_axis = ed_x * dx + ed_y * dy
    h_nh = eps_nh + p_axis * p_axis
    beta0 = beta0_max - (xi * xi + yi * yi)

    # G_i = Π h(s_ij) and, in grad_out's neighbour rows, Π_{k≠j} h_k · h'_j · ∇_j s_ij.
    g_prox = 1.0
    n_near = 0
    for j in range(n):
        grad_out[j, 0] = 0.0
        grad_out[j, 1] = 0.0
    for j in range(n):
        if j == i or status[j] != FLYING:
            continue
        rx = xi - pos[j, 0] * inv_len
        ry = yi - pos[j, 1] * inv_len
        dist2 = rx * rx + ry * ry
        if dist2 >= r_sense2:
            continue  # beyond the sensing radius: h = 1, h' = 0
        n_near += 1
        h, dh = proximity_bump((dist2 - contact2) * inv_beta_s, c_bar)
        g_prox *= h
        # Kept for the second pass, which needs G_i first: h_j and h'_j (h_j > 0 marks a
        # neighbour there, since the second pass runs only where G_i > 0).
        grad_out[j, 0] = h
        grad_out[j, 1] = dh
    # ∇_j G_i = Π_{k≠j} h_k · h'_j ∇_j s_ij, with ∇_j s_ij = −2 (q_i − q_j) / β_s. Every
    # neighbour has h_j > 0 when G_i > 0, so Π_{k≠j} h_k = G_i / h_j (zero when another
    # neighbour touches, as it must be).
    grad_g_ix = 0.0
    grad_g_iy = 0.0
    if n_near > 0 and g_prox > 0.0:
        for j in range(n):
            h = grad_out[j, 0]
            if h == 0.0:
                continue
            dh = grad_out[j, 1]
            rx = xi - pos[j, 0] * inv_len
            ry = yi - pos[j, 1] * inv_len
            others = g_prox / h
            grad_out[j, 0] = -2.0 * rx * inv_beta_s * dh * others
            grad_out[j, 1] = -2.0 * ry * inv_beta_s * dh * others
            grad_g_ix -= grad_out[j, 0]
            grad_g_iy -= grad_out[j, 1]
    elif n_near > 0:
        for j in range(n):
            grad_out[j, 0] = 0.0
            grad_out[j, 1] = 0.0

    phi, coef_g, own_x, own_y = _value_and_own_gradient(
        gamma, p_axis, h_nh, beta0, g_prox, grad_g_ix, grad_g_iy, dx, dy, xi, yi, ed_x, ed_y, k, inv_k, a0, x_cut
    )
    if n_near > 0:
        for j in range(n):
            grad_out[j, 0] *= coef_g
            grad_out[j, 1] *= coef_g
    grad_out[i, 0] = own_x
    grad_out[i, 1] = own_y
    return phi, n_near


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def nf_along_neighbours(
    i: int,
    pos: np.ndarray,
    near: np.ndarray,
    n_near: int,
    waypoint_x: float,
    waypoint_y: float,
    ed_x: float,
    ed_y: float,
    constants: tuple,
    grad_out: np.ndarray,
) -> float:
    """``nf_along_direction`` given aircraft i's neighbours: ``near[:n_near]``, the flying
    aircraft within the sensing radius in increasing index (as float64), found by the
    kernel's neighbour grid. The same operations in the same order, so the same bits; only
    the rows of the neighbours and row i of ``grad_out`` are written (the others are left
    as they were, not zeroed: O(neighbours) instead of O(N)). Returns Φ_i."""
    inv_len, k, inv_k, beta0_max, contact2, inv_beta_s, c_bar, _, eps_nh, a0, x_cut = constants
    xi = pos[i, 0] * inv_len
    yi = pos[i, 1] * inv_len
    dx = (pos[i, 0] - waypoint_x) * inv_len
    dy = (pos[i, 1] - waypoint_y) * inv_len
    gamma = dx * dx + dy * dy
    p_axis = ed_x * dx + ed_y * dy
    h_nh = eps_nh + p_axis * p_axis
    beta0 = beta0_max - (xi * xi + yi * yi)
    g_prox = 1.0
    for q in range(n_near):
        j = int(near[q])
        rx = xi - pos[j, 0] * inv_len
        ry = yi - pos[j, 1] * inv_len
        h, dh = proximity_bump((rx * rx + ry * ry - contact2) * inv_beta_s, c_bar)
        g_prox *= h
        grad_out[j, 0] = h
        grad_out[j, 1] = dh
    grad_g_ix = 0.0
    grad_g_iy = 0.0
    if n_near > 0 and g_prox > 0.0:
        for q in range(n_near):
            j = int(near[q])
            h = grad_out[j, 0]
            if h == 0.0:
                continue
            dh = grad_out[j, 1]
            rx = xi - pos[j, 0] * inv_len
            ry = yi - pos[j, 1] * inv_len
            others = g_prox / h
            grad_out[j, 0] = -2.0 * rx * inv_beta_s * dh * others
            grad_out[j, 1] = -2.0 * ry * inv_beta_s * dh * others
            grad_g_ix -= grad_out[j, 0]
            grad_g_iy -= grad_out[j, 1]
    elif n_near > 0:
        for q in range(n_near):
            j = int(near[q])
            grad_out[j, 0] = 0.0
            grad_out[j, 1] = 0.0
    phi, coef_g, own_x, own_y = _value_and_own_gradient(
        gamma, p_axis, h_nh, beta0, g_prox, grad_g_ix, grad_g_iy, dx, dy, xi, yi, ed_x, ed_y, k, inv_k, a0, x_cut
    )
    for q in range(n_near):
        j = int(near[q])
        grad_out[j, 0] *= coef_g
        grad_out[j, 1] *= coef_g
    grad_out[i, 0] = own_x
    grad_out[i, 1] = own_y
    return phi



@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", inline="always")
def own_gradient_alone(
    x: float, y: float, waypoint_x: float, waypoint_y: float, ed_x: float, ed_y: float, constants: tuple
) -> tuple[float, float, float, float]:
    """∇_iΦ_i of ``nf_along_direction`` for k = 2 where aircraft i has no neighbour within
    the sensing radius (G_i = 1, ∇_iG_i = 0), every branch a select, so that a loop over
    worlds can run in SIMD lanes (the kernel's lane path). Its arithmetic is that function's
    operation for operation, so the gradient is bit for bit the same (tested).

    Args:
        x, y: aircraft i's position, nm; waypoint_x, waypoint_y: its waypoint q_d, nm.
        ed_x, ed_y: unit vector of θ_d; constants: ``nf_constants(params)``.

    Returns:
        (∂Φ_i/∂x_i, ∂Φ_i/∂y_i in units of 1/L, the coefficient of ∇_iG_i, the sign of
        e_d · (q_i − q_d), which side of the dipole's axis line the aircraft is on).
    """
    inv_len, _, inv_k, beta0_max, _, _, _, _, eps_nh, a0, x_cut = constants
    g_prox = 1.0
    grad_g_ix = 0.0
    grad_g_iy = 0.0
    xi = x * inv_len
    yi = y * inv_len
    dx = (x - waypoint_x) * inv_len
    dy = (y - waypoint_y) * inv_len
    gamma = dx * dx + dy * dy
    p_axis = ed_x * dx + ed_y * dy
    h_nh = eps_nh + p_axis * p_axis
    beta0 = beta0_max - (xi * xi + yi * yi)
    g_rel = g_prox / x_cut
    f_in = a0 * (1.0 - 3.0 * g_rel * g_rel + 2.0 * g_rel * g_rel * g_rel)
    df_in = a0 * (-6.0 * g_rel + 6.0 * g_rel * g_rel) / x_cut
    f = f_in if g_prox < x_cut else 0.0
    df = df_in if g_prox < x_cut else 0.0
    a = gamma + f
    m = h_nh * g_prox * beta0
    d = a * a + m
    d_root = math.sqrt(d)
    scale = 1.0 / (d_root * d)
    a_over_k = a * inv_k
    coef_g = scale * (m * df - a_over_k * h_nh * beta0)
    coef_gamma = scale * m
    coef_h = -scale * a_over_k * g_prox * beta0
    coef_beta0 = -scale * a_over_k * h_nh * g_prox
    gx = coef_gamma * 2.0 * dx + coef_h * 2.0 * p_axis * ed_x + coef_beta0 * (-2.0 * xi) + coef_g * grad_g_ix
    gy = coef_gamma * 2.0 * dy + coef_h * 2.0 * p_axis * ed_y + coef_beta0 * (-2.0 * yi) + coef_g * grad_g_iy
    sgn_along = 1.0 if p_axis >= 0.0 else -1.0
    return gx, gy, coef_g, sgn_along

@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def proximity_function(i: int, pos: np.ndarray, status: np.ndarray, params: np.ndarray) -> float:
    """G_i alone (dimensionless, in [0, 1]); for tests and diagnostics."""
    inv_len, _, _, _, contact2, inv_beta_s, c_bar, r_sense2, _, _, _ = nf_constants(params)
    g = 1.0
    for j in range(pos.shape[0]):
        if j == i or status[j] != FLYING:
            continue
        rx = (pos[i, 0] - pos[j, 0]) * inv_len
        ry = (pos[i, 1] - pos[j, 1]) * inv_len
        dist2 = rx * rx + ry * ry
        if dist2 < r_sense2:
            h, _ = proximity_bump((dist2 - contact2) * inv_beta_s, c_bar)
            g *= h
    return g
