"""The NF control law of the paper, per aircraft, and the step that integrates it: the
one readable source of each formula, which every path of the kernel calls.

The law is (5a)-(5b) of G. Roussos, G. Chaloulos, K. Kyriakopoulos, J. Lygeros, "Control
of multiple non-holonomic air vehicles under wind uncertainty using model predictive
control and decentralized navigation functions", 47th IEEE CDC, 2008; for aircraft i::

    u_i = −sgn(P_i) F_i − (∂Φ_i/∂t + |∂Φ_i/∂t|) / (2 P_i)          (5a)
    ω_i = −k_θ (θ_i − θ_nh,i) + θ̇_nh,i                               (5b)

with F_i = k_u ‖∇_iΦ_i‖² + k_z ‖q_i − q_d‖², P_i = [cos θ_i, sin θ_i] · ∇_iΦ_i and θ_nh
the angle of sgn(p_i) ∇_iΦ_i. The kernel (``atc_nf_env.kernel``) evaluates the NF and
the neighbours' ∂Φ_i/∂t, and flies these functions on its general path (one aircraft at
a time, every guard) and on its lane paths (many worlds at once in SIMD lanes, the
ordinary steps only): a change here changes every path, the environments, the MPC's
and the safety filter's predictions and the evaluator alike
(``tests/test_law_once.py`` patches this file in a copy of the package and checks it).
The guards the kernel's docstring numbers are marked where they act.

Every branch is a select (``a if c else b`` of values already computed) and nothing
here allocates, so that a loop over worlds that calls these functions still runs in
SIMD lanes; on the general path the selects give the bits its branches gave.
"""

from __future__ import annotations

import math

from numba import njit

from atc_nf_env import compile_cache
from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS
from atc_nf_env.units import SECONDS_PER_HOUR

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

#: A jump of θ_nh larger than this in one step is not a rate (guard 5), rad.
HEADING_JUMP_LIMIT_RAD = math.pi / 2


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def feedback(gx: float, gy: float, cos_h: float, sin_h: float, dx: float, dy: float, k_u: float, k_z: float,
             p_floor: float, grad_floor: float) -> tuple[float, float, bool]:
    """The feedback term of (5a), −sgn(P_i) F_i, and what the rest of the law needs of P_i
    and of the gradient.

    Args:
        gx, gy: ∇_iΦ_i, 1/L; cos_h, sin_h: of the heading θ_i; dx, dy: q_i − q_d in
            units of L; k_u, k_z: the gains of F_i, kt; p_floor: guard 1's floor of |P_i|,
            1/L; grad_floor: guard 3's floor of ‖∇_iΦ_i‖, 1/L.

    Returns:
        (−sgn(P_i) F_i in kt; P_i as the 1/P_i term divides by it, its magnitude floored at
        ``p_floor`` and its sign kept (guard 1), 1/L; whether the gradient has a direction
        for θ_nh: where ‖∇_iΦ_i‖ < ``grad_floor`` (at q_d, or a critical point) θ_nh is θ_d
        instead (guard 3)).
    """
    p_dir = cos_h * gx + sin_h * gy
    grad_norm2 = gx * gx + gy * gy
    f_speed = k_u * grad_norm2 + k_z * (dx * dx + dy * dy)
    sgn_p = 1.0 if p_dir >= 0.0 else -1.0
    return -sgn_p * f_speed, sgn_p * max(abs(p_dir), p_floor), grad_norm2 > grad_floor * grad_floor


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def turn_rate(heading_error: float, jump: float, fresh: float, last_substeps: float, inv_dt: float,
              k_theta: float) -> float:
    """ω_i of (5b), rad/s.

    Args:
        heading_error: θ_i − θ_nh wrapped to [−π, π) (guard 4), rad.
        jump: the change of θ_nh since the last step, wrapped to [−π, π), rad.
        fresh: ≠ 0 under a new waypoint; last_substeps: the sub-steps of the last step;
        inv_dt: 1 / dt, 1/s; k_theta: the heading gain k_θ, 1/s.

    θ̇_nh is the backward difference ``jump`` over the last step's length, dt / its
    sub-steps (guard 5), and 0 under a new waypoint and where θ_nh jumped by more than
    π/2, which is a switch of sgn(p_i), not a rate.
    """
    rate = jump * (max(last_substeps, 1.0) * inv_dt)
    theta_nh_rate = 0.0 if (fresh != 0.0) | (abs(jump) > HEADING_JUMP_LIMIT_RAD) else rate
    return -k_theta * heading_error + theta_nh_rate


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def airspeed(u_feedback: float, dphi_dt: float, p_floored: float, u_cap: float) -> tuple[float, bool]:
    """u_i of (5a), kt: the feedback term less the 1/P_i term, which (∂Φ_i/∂t + |∂Φ_i/∂t|)
    makes exactly 0 where ∂Φ_i/∂t ≤ 0 (so nothing is subtracted), saturated at ± ``u_cap``
    (guard 2). Returns (u_i, whether it saturated)."""
    u = u_feedback - (dphi_dt + abs(dphi_dt)) / (2.0 * p_floored) if dphi_dt > 0.0 else u_feedback
    return saturate(u, u_cap)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def saturate(u: float, u_cap: float) -> tuple[float, bool]:
    """An airspeed command saturated at ± ``u_cap`` (guard 2), kt, and whether it reached
    the cap (a step with such a command is flown in sub-steps: guard 8)."""
    return min(max(u, -u_cap), u_cap), not ((-u_cap < u) & (u < u_cap))


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def right_turn_weight(dphi_dt: float, p_floored: float, angle: float, from_kt: float, full_kt: float) -> float:
    """Weight in [0, 1] of the right-hand rule (guard 9): 0 while the 1/P_i term of (5a),
    (∂Φ_i/∂t)⁺ / |P_i| in kt, is below ``from_kt``, 1 from ``full_kt`` on, a C¹
    smoothstep between (so the flow it defines stays Lipschitz); 0 when the rule is off
    (``angle`` ≤ 0, rad). Under the rule θ_nh turns right by weight · ``angle`` and u_i
    blends toward F_i (``right_turn_blend``)."""
    if angle <= 0.0 or dphi_dt <= 0.0:
        return 0.0
    term_kt = dphi_dt / abs(p_floored)
    if term_kt <= from_kt:
        return 0.0
    x = min((term_kt - from_kt) / (full_kt - from_kt), 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def right_turn_blend(u: float, weight: float, u_feedback: float) -> float:
    """Guard 9's airspeed, kt: ``u`` blended toward the feedback magnitude F_i =
    |``u_feedback``| by the rule's ``weight``. For aircraft i, ``u`` is (5a)'s u_i (the
    caller caps the blend again: F_i alone can exceed the cap); for a neighbour j in
    ∂Φ_i/∂t, ``u`` is its −sgn(P_j) F_j, which flips at random where P_j ≈ 0."""
    return (1.0 - weight) * u + weight * abs(u_feedback)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def integrate(x0: float, y0: float, heading: float, u: float, cos_h: float, sin_h: float, wind_x: float,
              wind_y: float, omega: float, vx_prev: float, vy_prev: float, omega_prev: float, h: float,
              ab2: bool) -> tuple[float, float, float, float, float]:
    """One step of ``h`` s of (1) from (x0, y0 nm, ``heading`` rad) at airspeed ``u`` (kt)
    along the heading plus the wind (kt, which the NF never sees) and turn rate ``omega``
    (rad/s): second-order Adams-Bashforth with the previous step's rates where ``ab2``,
    explicit Euler otherwise (the kernel flies Euler after a waypoint switch and within or
    after a refined step, where the previous rates belong to another law or another step
    length). Returns (x1, y1 nm, the new heading rad, not wrapped, and the ground
    velocity vx, vy kt)."""
    vx = u * cos_h + wind_x
    vy = u * sin_h + wind_y
    nm_per_kt_step = h / SECONDS_PER_HOUR
    x_ab2 = x0 + (1.5 * vx - 0.5 * vx_prev) * nm_per_kt_step
    y_ab2 = y0 + (1.5 * vy - 0.5 * vy_prev) * nm_per_kt_step
    h_ab2 = heading + (1.5 * omega - 0.5 * omega_prev) * h
    x_euler = x0 + vx * nm_per_kt_step
    y_euler = y0 + vy * nm_per_kt_step
    h_euler = heading + omega * h
    return (x_ab2 if ab2 else x_euler), (y_ab2 if ab2 else y_euler), (h_ab2 if ab2 else h_euler), vx, vy
