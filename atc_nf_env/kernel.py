"""The one batched simulator kernel: B worlds of N aircraft under the NF control law.

Its entry point::

    advance(state[B, N], waypoints[B, N], wind[B], seconds) -> trace

Every part of the project that moves aircraft calls this: the environments (B = 1 or
the number of vector envs), the MPC (B = K candidates, one decision at once) and the
Monte Carlo evaluator. It is compiled with numba, parallel over worlds, and allocates
nothing inside its integration loop (its scratch comes from the caller). The checks of
its inputs' values and of its result run in the same compiled call as the flight. Its three
paths (one world, a small batch, the lane path below) are compiled entries of their own,
each compiled when a call first needs it.
A batch of ``LANE_MIN_WORLDS`` worlds or more takes the lane path (see the section of that
name below), and so does every batch, one world included, in a process where a policy that
flies batches of every size (the MPC) called ``load_paths``. On it a world's ordinary steps,
with no neighbour in range and no guard acting, are flown for chunks of worlds at once in
SIMD lanes, its other steps by the scalar path, in the
same arithmetic; a world flies bit for bit the same trajectory either way. On the scalar
path (one world, small batches, the safety filter's prediction) the same ordinary steps
are flown by ``_ordinary_run``, the lane step's arithmetic over the world's aircraft without
the neighbour loops and the guards' branches, the other steps by the general path.
Pairs of aircraft (the NF's neighbours within the sensing radius, whether a step is
ordinary, the losses of separation and the trace's smallest separation, exact over every
pair) are found over all pairs, or, where ``advance``'s scratch gives a world the neighbour
grid (``KernelScratch``: from ``GRID_MIN_AIRCRAFT`` aircraft), through a uniform grid of
cells (``neighbour_grid``) in O(N) a step: the same neighbours in the same order, the same
bits (``tests/test_neighbour_grid.py``). The scaling with N is in BENCHMARKS.md
(``bench/bench_kernel.py --scaling``).

Physics per aircraft i, integrated at ``dt_s`` with the second-order Adams-Bashforth
scheme (explicit Euler on the first step under a new waypoint) (paper (1), (5))::

    ẋ_i = u_i cos θ_i + w_x,   ẏ_i = u_i sin θ_i + w_y,   θ̇_i = ω_i
    u_i = −sgn(P_i) F_i − (∂Φ_i/∂t + |∂Φ_i/∂t|) / (2 P_i)
    ω_i = −k_θ (θ_i − θ_nh,i) + θ̇_nh,i

with F_i = k_u ‖∇_iΦ_i‖² + k_z ‖q_i − q_d‖², P_i = [cos θ_i, sin θ_i] · ∇_iΦ_i,
∂Φ_i/∂t = Σ_j u_j ∇_jΦ_i · [cos θ_j, sin θ_j] evaluated with the neighbours' feedback
airspeeds u_j = −sgn(P_j) F_j of the same instant (the law is implicit in u_j, whose own
∂Φ_j/∂t term depends on u_i; the previous step's u_j diverged in head-on encounters),
and θ_nh the angle of sgn(p_i) ∇_iΦ_i. The wind w enters the ground velocity only: the envelope
constrains airspeed, and the NF never sees the wind.

Each formula of the law and of the step is written once, in ``atc_nf_env.law``
(``feedback``, ``airspeed`` and its cap ``saturate``, ``turn_rate``, the right-hand
rule's ``right_turn_weight`` and ``right_turn_blend``, ``integrate``); the general path
and the lane paths below call those functions, so an edit there changes every path (``tests/test_law_once.py``). The NF
itself is ``atc_nf_env.nf``.

Guards against the law's singularities and the step's error (each keeps a value finite
that the law leaves undefined, or a step accurate; none acts in an ordinary flight but
guards 8 and 10, which only fly some of its steps finer):

1. ``|P_i|`` is floored at ``p_floor`` in the 1/P_i term: P_i = 0 when the heading is
   normal to the gradient, e.g. just after a waypoint switch.
2. The commanded airspeed is saturated at ± ``airspeed_cap_kt``: as P_i → 0 the 1/P_i
   term grows without bound. The cap is far outside the envelope, so a saturated
   step is still counted as a violation and no feasibility verdict changes.
   A step in which any command saturates is flown in sub-steps (guard 8).
3. Where ‖∇_iΦ_i‖ < ``grad_floor`` (at q_i = q_d, or a critical point) the gradient
   has no direction, and θ_nh = θ_d (the paper's rule at q_i = q_d).
4. Heading errors are wrapped to [−π, π): θ_i − θ_nh is an angle, and an unwrapped
   difference of 2π would command a full useless turn.
5. θ̇_nh is a backward difference of θ_nh over the last step or sub-step, divided by its
   length (the law needs it; the closed form would need the Hessian of Φ). It is reset
   to 0 on a waypoint switch and when θ_nh jumps by more than π/2 in one step (sgn(p_i)
   flipping, or a switch): a jump is not a rate, and differencing it would command an
   arbitrary turn.
6. Disks that overlap give G_i = 0 (see ``nf.proximity_bump``), not a negative G_i.
7. An aircraft whose disk reaches the workspace boundary (β0 ≤ 0) has left and is no
   longer simulated, so Φ is never evaluated where it is undefined.
8. Sub-steps at the singularity. Near a critical point of Φ_i with neighbours closing
   in (∂Φ_i/∂t > 0, ``|P_i|`` → 0), the 1/P_i term saturates and its sign follows the sign
   of P_i: u_i = −u_cap sgn(P_i). A step of dt overshoots P_i = 0 by up to u_cap · dt
   (2 nm at 5 s) and the sign then alternates step by step, so the flight depended on
   dt. A step in which any command saturates, in which the right-hand rule acts (guard
   9), or in which any aircraft's 1/P_i term, ``(∂Φ_i/∂t)⁺ / |P_i|``, exceeds
   ``substep_from_kt`` (50 kt: the watch) at its start, or, among neighbours, at its end
   (guard 10), is therefore flown in ceil(dt / ``substep_s``) explicit-Euler sub-steps,
   each with fresh commands; the overshoot falls to u_cap · substep_s (0.04 nm at 0.1 s)
   whatever dt is. The term grows like 1/(t₀ − t) as P_i → 0, so a full step of 5 s can
   go from below the watch to the blow-up: the test at the step's end catches it. The
   outer grid is kept: traces, records and violation counts stay per integration step
   (min/max airspeed, separation and arrival are checked on every sub-step), and the
   step after a refined one is Euler (AB2's previous rates are a sub-step old). Where the
   world stops at this step anyway (``stop_on_violation`` and a command outside the
   envelope, as in the MPC's candidates) the step is not refined: its first sub-step has
   the same command and the same verdict.
9. The right-hand rule at the saddle. The converging encounters are symmetric under
   reflection about each aircraft's radial line, and so is the law, so the exact flow
   keeps every aircraft on its line. There ∇_iΦ_i is radial, and it vanishes where the
   neighbours' repulsion balances the pull of the destination: P_i = 0 at a critical
   point of Φ_i, while ∂Φ_i/∂t > 0. The law has no solution there (even solved
   implicitly in the u_j, the common airspeed u of the N aircraft obeys u (g − c) = F g,
   g = ``|∇_iΦ_i|`` and c = Σ_j ∇_jΦ_i · J_j, which blows up as g → c, with no solution
   beyond): the N aircraft meet at a saddle of the joint flow, and which way each leaves
   its line is decided by rounding errors. A generic near-head-on pass reaches the same
   blow-up. A rule is needed there, not a finer step. We take the rules of the air (ICAO
   Annex 2, 3.2.2.2: aircraft approaching head-on each alter heading to the right): where
   the 1/P_i term exceeds ``right_turn_from_kt`` (200 kt) the desired heading θ_nh is
   turned to the right by w_i · ``right_turn_deg`` (45°), the airspeed blends toward the
   feedback magnitude F_i, u_i = (1 − w_i) u_i^(5a) + w_i F_i, saturated again by guard 2
   (F_i alone exceeds the cap for a waypoint far enough away), and the neighbours'
   airspeeds in ∂Φ_i/∂t are blended the same way (−sgn(P_j) F_j flips at random where
   P_j ≈ 0). The weight w_i rises from 0 to 1 as a C¹ smoothstep of the term up to
   ``right_turn_full_kt`` (800 kt), a function of the state and not switched at a grid
   instant, so the heading's θ̇_nh feed-forward turns the aircraft as fast as w_i rises,
   and the flow is again a Lipschitz ODE off P_i = 0. Where w_i = 0 nothing changes, bit
   for bit. The angle and the ramp were chosen with ``bench/integration_convergence_study.py``
   (seeds 880000+; checked on the held-out seeds 881000+): with 90° from 100 to 400 kt,
   the ramp tuned before θ̇_nh was taken at its true rate (guard 5), perturbed converging
   encounters moved by up to 3 nm with dt and hit the cap; 45° from 200 to 800 kt
   settles both families. What is left: the rule keeps the encounter's rotation
   symmetry, and the pinwheel it flies around the centre settles in one of a few modes;
   which one can change with dt, so a converging encounter's minimum separation moves
   by up to about 0.3 nm on halving the step (BENCHMARKS.md, the saddle and
   "integration-convergence").
10. Error control among neighbours. An integration step with two aircraft within the
    sensing radius at its start or at its end is first tried whole: every aircraft is
    moved as the step would move it, and the law's commands are taken there. If they ask
    for refinement (guard 8) the step is flown in ceil(dt / ``substep_s``) sub-steps; else
    its local position error is estimated from the ground velocities of the last step,
    this one and the next (AB2's against the next order's: ``(5/12) dt |v₊ − 2v + v₋|``; after
    a switch or a refined step, Euler's: ``dt |v₊ − v| / 2``), and where it exceeds
    ``step_tolerance_nm`` (0.002 nm) the step is flown in as many Euler sub-steps as bring
    it within (their error falls as 1 / their number), at most ceil(dt / ``substep_s``).
    A step flown whole keeps its trial's commands for the next step (the trial moved every
    aircraft by the step's own move, ``_move_aircraft``, so they are the same bits), unless an aircraft
    arrived or left. Why: at 5 s, AB2 enters a pass late and coarse (the neighbour's
    repulsion switches on within one step as it enters the sensing radius), and the NF
    alone on random encounters missed the converged minimum separation by up to 2 nm;
    with the control the figures at 5 s and at dt/8 agree within the goal of 0.2 nm on the
    random encounters of the study. Steps with no pair in range at either end are
    untouched: an ordinary step is one with no pair within the sensing radius before and
    after its move (``_ordinary_run``, the lane step), so every path flies the same bits.

An aircraft that arrives (its path passes within Δ of its destination, checked on
every integration step's segment) or leaves is frozen and stops being an obstacle.

State layout: float64 array (B, N, N_STATE), fields ``S_*``. The waypoint's desired
orientation θ_d is set by the kernel when a waypoint changes: the bearing from the
aircraft to the waypoint (so the aircraft starts on the dipole axis, flying toward it),
or the scenario's arrival heading when the waypoint is the destination itself.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np
from numba import get_num_threads, njit, prange

from atc_nf_env import law, nf, trig
from atc_nf_env import neighbour_grid as cells_grid
from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS
from atc_nf_env.nf import (
    ABSENT,
    ARRIVED,
    FLYING,
    LEFT,
    P_DELTA,
    P_DT,
    P_GRAD_FLOOR,
    P_K_THETA,
    P_K_U,
    P_K_Z,
    P_LENGTH,
    P_P_FLOOR,
    P_R_SENSE,
    P_R_WORLD,
    P_RADIUS,
    P_SEP_MIN,
    P_STOP_ON_VIOLATION,
    P_SUBSTEP,
    P_U_CAP,
    P_U_MAX,
    P_U_MIN,
)
from atc_nf_env.units import SECONDS_PER_HOUR
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

# State fields.
S_X = 0  # position x, nm
S_Y = 1  # position y, nm
S_HEADING = 2  # heading θ, rad (east = 0, counter-clockwise)
S_AIRSPEED = 3  # airspeed of the last step, kt
S_THETA_NH = 4  # θ_nh of the last step, rad
S_WP_X = 5  # current waypoint x, nm
S_WP_Y = 6  # current waypoint y, nm
S_THETA_D = 7  # desired orientation at the waypoint, rad
S_DEST_X = 8  # destination x, nm
S_DEST_Y = 9  # destination y, nm
S_DEST_HEADING = 10  # arrival heading at the destination, rad
S_STATUS = 11  # FLYING, ARRIVED, LEFT or ABSENT
S_TIME = 12  # time flown, s (frozen at arrival or departure)
S_PATH = 13  # path length flown over the ground, nm
S_FRESH = 14  # 1 while no step has been flown under the current waypoint
S_COS_D = 15  # cos θ_d (cached: set with θ_d)
S_SIN_D = 16  # sin θ_d
S_VX_PREV = 17  # ground velocity of the last step, kt (for the AB2 integrator)
S_VY_PREV = 18
S_OMEGA_PREV = 19  # turn rate of the last step, rad/s
S_LAST_SUBSTEPS = 20  # sub-steps the last integration step was flown in (0 or 1: not refined)
N_STATE = 21

# Scratch columns of the per-step commands.
C_U_FEEDBACK = 0  # −sgn(P_i) F_i, kt
C_OMEGA = 1  # ω_i, rad/s
C_THETA_NH = 2  # θ_nh, rad
C_FLEW = 3  # 1 if the aircraft flew this step
C_P = 4  # P_i, floored (guard 1)
C_U = 5  # airspeed command of (5a), kt
C_COS = 6  # cos θ_i
C_SIN = 7  # sin θ_i
C_NEAR = 8  # neighbours within the sensing radius
C_VIOLATED = 9  # 1 once the aircraft's airspeed left the envelope during this step
C_DPHI_DT = 10  # ∂Φ_i/∂t of (5a), per s
C_RIGHT_TURN = 11  # weight in [0, 1] of the right-hand rule (guard 9)
C_STEP_MIN = 12  # lowest airspeed over the sub-steps flown in this step, kt
C_STEP_MAX = 13  # highest, kt
# The last ordinary step's move (``_ordinary_run``), as the one-step form of it left it.
C_X1, C_Y1, C_HEADING1, C_VX, C_VY, C_STEP_NM = 14, 15, 16, 17, 18, 19
N_COMMAND = 20
#: The columns ``_commands`` writes.
_COMMAND_COLUMNS = (C_U_FEEDBACK, C_OMEGA, C_THETA_NH, C_P, C_U, C_COS, C_SIN, C_NEAR, C_DPHI_DT, C_RIGHT_TURN)

# Rows of one world's aircraft lanes (``_ordinary_run``: one column per flying aircraft).
# The state's fields a run of ordinary steps reads or writes, the rows ``A_X`` ...
# ``A_LAST_SUBSTEPS`` holding the fields ``_STATE_FIELD_OF_LANE`` of the state, then the
# step's own values and the aircraft's row in the state.
(A_X, A_Y, A_HEADING, A_AIRSPEED, A_THETA_NH, A_WP_X, A_WP_Y, A_THETA_D, A_DEST_X, A_DEST_Y, A_TIME, A_PATH,
 A_FRESH, A_COS_D, A_SIN_D, A_VX_PREV, A_VY_PREV, A_OMEGA_PREV, A_LAST_SUBSTEPS) = range(19)
_STATE_FIELD_OF_LANE = (S_X, S_Y, S_HEADING, S_AIRSPEED, S_THETA_NH, S_WP_X, S_WP_Y, S_THETA_D, S_DEST_X, S_DEST_Y,
                        S_TIME, S_PATH, S_FRESH, S_COS_D, S_SIN_D, S_VX_PREV, S_VY_PREV, S_OMEGA_PREV, S_LAST_SUBSTEPS)
N_AIRCRAFT_FIELDS = 19
(A_GX, A_GY, A_ARG_X, A_ATAN2, A_SIN, A_COS, A_X1, A_Y1, A_HEADING1, A_VX, A_VY, A_OMEGA, A_U, A_THETA_NH1,
 A_STEP_NM, A_VIOLATED, A_INDEX) = range(19, 36)
#: Then, after the lanes' rows, the trial of guard 10's error control: a state (N_STATE
#: values per aircraft) and its commands (N_COMMAND), each read as an (N, fields) array.
TRIAL_STATE_ROW = 36
TRIAL_COMMAND_ROW = TRIAL_STATE_ROW + N_STATE
N_AIRCRAFT_LANE = TRIAL_COMMAND_ROW + N_COMMAND
#: First row of the neighbour grid's own scratch (``cells``, ``neighbour_grid.grid_rows``).
_GRID = 0
#: Fewest aircraft for which ``KernelScratch`` gives a world the neighbour grid: below it the
#: loops over all pairs are as fast or faster (``bench/bench_kernel.py``, the scaling table).
GRID_MIN_AIRCRAFT = 24

# Record fields (optional per-step recording).
R_X, R_Y, R_HEADING, R_AIRSPEED, R_FLEW = 0, 1, 2, 3, 4  # R_FLEW: 1 if it flew that step
# Lowest and highest airspeed over the sub-steps of that step (a step refined at the
# singularity can leave the envelope between its ends); R_AIRSPEED where it flew none.
R_AIRSPEED_MIN, R_AIRSPEED_MAX = 5, 6
N_RECORD = 7

#: Value of ``Trace.min_separation_nm`` when fewer than two aircraft flew.
NO_PAIR_SEPARATION_NM = 1.0e9

_TWO_PI = 2.0 * math.pi


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _cell_nm(params: np.ndarray) -> float:
    """Narrowest cell of the neighbour grid, nm: the sensing radius (the NF's neighbours) or
    the separation minimum (the losses of separation), whichever is larger."""
    return max(params[P_R_SENSE], params[P_SEP_MIN])


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _wrap(angle: float) -> float:
    """Angle wrapped to [−π, π)."""
    # Differences of wrapped angles lie within ±2π: one conditional shift is enough
    # there, and cheaper than the general floor that other angles fall back to.
    if -math.pi <= angle < math.pi:
        return angle
    if -3.0 * math.pi <= angle < 3.0 * math.pi:
        return angle - _TWO_PI if angle >= math.pi else angle + _TWO_PI
    return angle - _TWO_PI * math.floor((angle + math.pi) / _TWO_PI)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _assign_waypoints(state: np.ndarray, waypoints: np.ndarray) -> None:
    """Store new waypoints and set θ_d where a waypoint changed."""
    for i in range(state.shape[0]):
        if state[i, S_STATUS] != FLYING:
            continue
        wx = waypoints[i, 0]
        wy = waypoints[i, 1]
        if wx == state[i, S_WP_X] and wy == state[i, S_WP_Y]:
            continue
        state[i, S_WP_X] = wx
        state[i, S_WP_Y] = wy
        if wx == state[i, S_DEST_X] and wy == state[i, S_DEST_Y]:
            state[i, S_THETA_D] = state[i, S_DEST_HEADING]
        else:
            state[i, S_THETA_D] = trig.poly_atan2(wy - state[i, S_Y], wx - state[i, S_X])
        state[i, S_SIN_D], state[i, S_COS_D] = trig.sincos(state[i, S_THETA_D])
        state[i, S_FRESH] = 1.0


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _segment_distance(x0: float, y0: float, x1: float, y1: float, px: float, py: float) -> float:
    """Distance from point p to the segment from (x0, y0) to (x1, y1)."""
    sx = x1 - x0
    sy = y1 - y0
    length2 = sx * sx + sy * sy
    t = 0.0
    if length2 > 0.0:
        t = ((px - x0) * sx + (py - y0) * sy) / length2
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    ex = x0 + t * sx - px
    ey = y0 + t * sy - py
    return math.sqrt(ex * ex + ey * ey)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _right_turn_weight(dphi_dt: float, p_floored: float, params: np.ndarray) -> float:
    """Weight in [0, 1] of the right-hand rule (guard 9): 0 while the 1/P_i term of (5a),
    (∂Φ_i/∂t)⁺ / |P_i| in kt, is below ``right_turn_from_kt``, 1 from ``right_turn_full_kt``
    on, a C¹ smoothstep between (``law.right_turn_weight`` with the parameters')."""
    return law.right_turn_weight(dphi_dt, p_floored, params[nf.P_RIGHT_TURN], params[nf.P_RIGHT_TURN_FROM],
                                 params[nf.P_RIGHT_TURN_FULL])


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _commands(
    state: np.ndarray,
    pos: np.ndarray,
    status: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    nf_consts: tuple,
    params: np.ndarray,
    inv_dt: float,
    cells,
) -> tuple[bool, bool, bool]:
    """The law's commands (5a)-(5b) of every flying aircraft from the current positions,
    into ``command``; the neighbours found over all pairs (``cells`` None), or through the
    neighbour grid in ``cells`` (the same neighbours in the same order, so the same bits).
    Returns (any aircraft flying, the step is to be refined: a command
    saturated at the cap (guard 2), under the right-hand rule (guard 9) or with a 1/P_i
    term above ``substep_from_kt`` (guard 8), any command outside the envelope)."""
    n = state.shape[0]
    inv_len = 1.0 / params[P_LENGTH]
    k_u = params[P_K_U]
    k_z = params[P_K_Z]
    k_theta = params[P_K_THETA]
    u_cap = params[P_U_CAP]
    p_floor = params[P_P_FLOOR]
    grad_floor = params[P_GRAD_FLOOR]
    dphi_dt_gain = params[nf.P_DPHI_DT_GAIN]
    substep_from = params[nf.P_SUBSTEP_FROM]
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    inv_len_nf = nf_consts[0]
    r_sense2 = nf_consts[7]
    nx = 0
    ny = 0
    if cells is not None:
        for i in range(n):
            cells[_GRID + cells_grid.GRID_X, i] = state[i, S_X]
            cells[_GRID + cells_grid.GRID_Y, i] = state[i, S_Y]
            cells[_GRID + cells_grid.GRID_MEMBER, i] = 1.0 if status[i] == FLYING else 0.0
        nx, ny, _, _ = cells_grid.prepare(cells, _GRID, n, _cell_nm(params))
    any_flying = False
    # Pass 1, from the positions at the start of the step: every flying aircraft's
    # gradients, feedback airspeed −sgn(P_i) F_i and heading rate.
    for i in range(n):
        if status[i] != FLYING:
            continue
        any_flying = True
        wx = state[i, S_WP_X]
        wy = state[i, S_WP_Y]
        theta_d = state[i, S_THETA_D]
        cos_d = state[i, S_COS_D]
        sin_d = state[i, S_SIN_D]
        if cells is not None:
            n_near = cells_grid.neighbours(cells, _GRID, i, nx, ny, r_sense2, inv_len_nf)
            nf.nf_along_neighbours(i, pos, cells[_GRID + cells_grid.GRID_LIST], n_near, wx, wy, cos_d, sin_d,
                                   nf_consts, grad[i])
        else:
            _, n_near = nf.nf_along_direction(i, pos, status, wx, wy, cos_d, sin_d, nf_consts, grad[i])
        command[i, C_NEAR] = n_near
        gx = grad[i, i, 0]
        gy = grad[i, i, 1]
        heading = state[i, S_HEADING]
        sin_h, cos_h = trig.sincos(heading)
        dx = (state[i, S_X] - wx) * inv_len
        dy = (state[i, S_Y] - wy) * inv_len
        u_feedback, p_floored, has_direction = law.feedback(gx, gy, cos_h, sin_h, dx, dy, k_u, k_z, p_floor,
                                                            grad_floor)
        if has_direction:
            along = cos_d * dx + sin_d * dy
            sgn_along = 1.0 if along >= 0.0 else -1.0
            theta_nh = trig.poly_atan2(sgn_along * gy, sgn_along * gx)
        else:
            theta_nh = theta_d  # guard 3
        command[i, C_U_FEEDBACK] = u_feedback
        command[i, C_OMEGA] = law.turn_rate(_wrap(heading - theta_nh), _wrap(theta_nh - state[i, S_THETA_NH]),
                                            state[i, S_FRESH], state[i, S_LAST_SUBSTEPS], inv_dt, k_theta)
        command[i, C_THETA_NH] = theta_nh
        command[i, C_P] = p_floored
        command[i, C_COS] = cos_h
        command[i, C_SIN] = sin_h
    refine = False
    outside = False
    if not any_flying:
        return any_flying, refine, outside
    # Pass 2: the ∂Φ_i/∂t term of (5a) with the neighbours' feedback airspeeds, and the
    # weight of the right-hand rule (guard 9) that the 1/P_i term it gives sets.
    any_turning = False
    for i in range(n):
        if status[i] != FLYING:
            continue
        dphi_dt = 0.0
        # Over the neighbours only: a farther aircraft's gradient row is zero (its term ±0).
        m = n if command[i, C_NEAR] > 0 else 0
        if cells is not None:
            if m > 0:
                m = cells_grid.neighbours(cells, _GRID, i, nx, ny, r_sense2, inv_len_nf)
        for q in range(m):
            j = q if cells is None else int(cells[_GRID + cells_grid.GRID_LIST, q])
            if j == i or status[j] != FLYING:
                continue
            along_j = grad[i, j, 0] * command[j, C_COS] + grad[i, j, 1] * command[j, C_SIN]
            dphi_dt += command[j, C_U_FEEDBACK] * along_j
        dphi_dt *= dphi_dt_gain
        command[i, C_DPHI_DT] = dphi_dt
        command[i, C_RIGHT_TURN] = _right_turn_weight(dphi_dt, command[i, C_P], params)
        any_turning |= command[i, C_RIGHT_TURN] > 0.0
        # Guard 8's watch: a 1/P_i term this large can cross the rule's whole ramp, or
        # P_i = 0, within one full step.
        refine |= dphi_dt > substep_from * abs(command[i, C_P])
    if any_turning:
        # A neighbour under the rule flies forward at F_j, not at −sgn(P_j) F_j, whose
        # sign flips at random where P_j ≈ 0: ∂Φ_i/∂t is taken again with that airspeed.
        for i in range(n):
            if status[i] != FLYING:
                continue
            dphi_dt = 0.0
            m = n if command[i, C_NEAR] > 0 else 0
            if cells is not None:
                if m > 0:
                    m = cells_grid.neighbours(cells, _GRID, i, nx, ny, r_sense2, inv_len_nf)
            for q in range(m):
                j = q if cells is None else int(cells[_GRID + cells_grid.GRID_LIST, q])
                if j == i or status[j] != FLYING:
                    continue
                along_j = grad[i, j, 0] * command[j, C_COS] + grad[i, j, 1] * command[j, C_SIN]
                u_j = command[j, C_U_FEEDBACK]
                dphi_dt += law.right_turn_blend(u_j, command[j, C_RIGHT_TURN], u_j) * along_j
            command[i, C_DPHI_DT] = dphi_dt * dphi_dt_gain
    for i in range(n):
        if status[i] != FLYING:
            continue
        dphi_dt = command[i, C_DPHI_DT]
        u, saturated = law.airspeed(command[i, C_U_FEEDBACK], dphi_dt, command[i, C_P], u_cap)
        refine |= saturated
        w = _right_turn_weight(dphi_dt, command[i, C_P], params) if any_turning else 0.0
        if w > 0.0:  # guard 9
            refine = True
            theta_nh = command[i, C_THETA_NH] - w * params[nf.P_RIGHT_TURN]
            command[i, C_THETA_NH] = theta_nh
            command[i, C_OMEGA] = law.turn_rate(_wrap(state[i, S_HEADING] - theta_nh),
                                                _wrap(theta_nh - state[i, S_THETA_NH]), state[i, S_FRESH],
                                                state[i, S_LAST_SUBSTEPS], inv_dt, k_theta)
            # F_i itself can exceed the cap (a waypoint far away), so the blend can too.
            u, _ = law.saturate(law.right_turn_blend(u, w, command[i, C_U_FEEDBACK]), u_cap)
        if not u_min <= u <= u_max:
            outside = True
        command[i, C_U] = u
    return any_flying, refine, outside


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _begin_world(
    state: np.ndarray,
    waypoints: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    record: np.ndarray,
) -> None:
    """A world's new waypoints, its outcome arrays zeroed and its record's first row."""
    n = state.shape[0]
    _assign_waypoints(state, waypoints)
    for i in range(n):
        min_airspeed[i] = state[i, S_AIRSPEED]
        max_airspeed[i] = state[i, S_AIRSPEED]
        violation_steps[i] = 0
        worst_excursion[i] = 0.0
        steps_flown[i] = 0
        for j in range(n):
            los_pairs[i, j] = 0
    if record.shape[0] > 0:
        for i in range(n):
            record[0, i, R_X] = state[i, S_X]
            record[0, i, R_Y] = state[i, S_Y]
            record[0, i, R_HEADING] = state[i, S_HEADING]
            record[0, i, R_AIRSPEED] = state[i, S_AIRSPEED]
            record[0, i, R_FLEW] = 1.0 if state[i, S_STATUS] == FLYING else 0.0
            record[0, i, R_AIRSPEED_MIN] = state[i, S_AIRSPEED]
            record[0, i, R_AIRSPEED_MAX] = state[i, S_AIRSPEED]


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _record_step(state: np.ndarray, command: np.ndarray, record: np.ndarray, step: int, record_every: int) -> None:
    """The world's state after integration step ``step`` into its record, every
    ``record_every`` steps."""
    if record.shape[0] > 0 and step % record_every == 0 and step // record_every < record.shape[0]:
        r = step // record_every
        for i in range(state.shape[0]):
            record[r, i, R_X] = state[i, S_X]
            record[r, i, R_Y] = state[i, S_Y]
            record[r, i, R_HEADING] = state[i, S_HEADING]
            record[r, i, R_AIRSPEED] = state[i, S_AIRSPEED]
            record[r, i, R_FLEW] = command[i, C_FLEW]
            flew_step = command[i, C_FLEW] > 0.0
            record[r, i, R_AIRSPEED_MIN] = command[i, C_STEP_MIN] if flew_step else state[i, S_AIRSPEED]
            record[r, i, R_AIRSPEED_MAX] = command[i, C_STEP_MAX] if flew_step else state[i, S_AIRSPEED]


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _flown_airspeed(
    u: float, first_flown: bool, lowest: float, highest: float, worst: float, u_min: float, u_max: float
) -> tuple[float, float, float, float]:
    """An aircraft's lowest and highest airspeed and its worst excursion outside [u_min,
    u_max] (kt) after it flew at ``u`` (kt); the first step it flies in a call starts the
    extremes (the airspeed held before it was never flown). Returns (lowest, highest,
    worst, this step's excursion: > 0 outside the envelope)."""
    if first_flown or u < lowest:
        lowest = u
    if first_flown or u > highest:
        highest = u
    excursion = max(u_min - u, u - u_max)
    return lowest, highest, max(worst, excursion), excursion


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _ordinary_run(
    state: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    wind_x: float,
    wind_y: float,
    params: np.ndarray,
    nf_consts: tuple,
    min_sep2: float,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    max_steps: int,
    stop_on_violation: bool,
    record: np.ndarray,
    record_every: int,
    step0: int,
    los_pairs: np.ndarray,
    cells,
) -> tuple[int, bool, float, bool]:
    """As many consecutive integration steps of one world as are ordinary, up to
    ``max_steps``, by the lane step's arithmetic: every flying aircraft without a flying
    neighbour within the sensing radius, no command at the cap, no angle beyond 3π, no
    arrival or departure within reach, no loss of separation and no neighbour within the
    sensing radius after the move (k = 2 only). The flying aircraft stay in the lanes of ``aircraft_lanes`` (``A_*`` rows, one
    column per aircraft) from the first of these steps to the last, and the state is
    written back once; a step that proves not ordinary is abandoned with nothing written
    (the scalar path flies it). ``step0``: steps done before this call (for the record).
    ``cells``: the neighbour grid's scratch, through which the pairs are found (``los_pairs``:
    not written), or None: over all pairs; the same bits.

    Returns (steps flown; whether a step left the envelope; the smallest squared
    separation so far, nm²; whether it stopped at a step that is not ordinary, which the
    caller flies by the general path).

    The same operations as ``_commands`` and the move of ``_advance_world`` for such steps,
    without the neighbour loops, the second pass and the guards' branches: the same bits
    (``tests/test_kernel_ordinary_step.py``). Kept in lanes between steps, the aircraft's
    loops have no dependence from one aircraft to the next, and the state's rows are read
    and written once per run instead of once per step: 1.29-1.40x as fast as the one-step
    form it replaced on the safety filter's checks (measured when it was adopted, commit
    a52acb8). Compiled on its own, not inlined
    into ``_advance_world``: inlined, the one-step form lengthened the kernel's first
    compilation more (in one run, by 24 s against 16 s, on 73 s)."""
    n = state.shape[0]
    inv_len = nf_consts[0]
    r_sense2 = nf_consts[7]
    dt = params[P_DT]
    inv_dt = 1.0 / dt
    k_theta = params[P_K_THETA]
    u_cap = params[P_U_CAP]
    delta = params[P_DELTA]
    sep_min = params[P_SEP_MIN]
    exit_radius = params[P_R_WORLD] - params[P_RADIUS]
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    lanes = aircraft_lanes
    count = np.int64(0)  # not a literal 0: see ``step`` in ``_advance_world``
    for i in range(n):
        if state[i, S_STATUS] == FLYING:
            lanes[A_INDEX, count] = i
            count += 1
    if count == 0:
        return 0, False, min_sep2, True
    for k in range(count):
        i = int(lanes[A_INDEX, k])
        for f in range(N_AIRCRAFT_FIELDS):
            lanes[f, k] = state[i, _STATE_FIELD_OF_LANE[f]]
    flown = 0
    violated = False
    abandoned = False
    while flown < max_steps:
        # No two flying aircraft within the sensing radius, in the NF's own arithmetic (its
        # test is symmetric in the pair: q_j − q_i is exactly −(q_i − q_j)).
        near = False
        if cells is not None:
            _fill_grid(cells, lanes, A_X, A_Y, count, n)
            nx, ny, _, _ = cells_grid.prepare(cells, _GRID, n, _cell_nm(params))
            near = cells_grid.any_within(cells, _GRID, n, nx, ny, r_sense2, inv_len)
        else:
            for a in range(count):
                xa = lanes[A_X, a] * inv_len
                ya = lanes[A_Y, a] * inv_len
                for b in range(a + 1, count):
                    rx = xa - lanes[A_X, b] * inv_len
                    ry = ya - lanes[A_Y, b] * inv_len
                    near |= rx * rx + ry * ry < r_sense2
        if near:
            abandoned = True
            break
        for k in range(count):
            gx, gy, _, sgn_along = nf.own_gradient_alone(
                lanes[A_X, k], lanes[A_Y, k], lanes[A_WP_X, k], lanes[A_WP_Y, k], lanes[A_COS_D, k],
                lanes[A_SIN_D, k], nf_consts,
            )
            lanes[A_GX, k] = gx
            lanes[A_GY, k] = gy
            lanes[A_ARG_X, k] = sgn_along * gx
            lanes[A_ATAN2, k] = sgn_along * gy
        for k in range(count):
            lanes[A_ATAN2, k] = trig.poly_atan2_inlined(lanes[A_ATAN2, k], lanes[A_ARG_X, k])
        for k in range(count):
            lanes[A_SIN, k], lanes[A_COS, k] = trig.poly_sincos_inlined(lanes[A_HEADING, k])
        unusual = False
        for k in range(count):
            cos_h = lanes[A_COS, k]
            sin_h = lanes[A_SIN, k]
            x0 = lanes[A_X, k]
            y0 = lanes[A_Y, k]
            u, theta_nh = _lane_feedback(lanes[A_GX, k], lanes[A_GY, k], cos_h, sin_h,
                                         (x0 - lanes[A_WP_X, k]) * inv_len, (y0 - lanes[A_WP_Y, k]) * inv_len,
                                         lanes[A_ATAN2, k], lanes[A_THETA_D, k], params)
            x1, y1, heading1, vx, vy, omega, far = _lane_move(
                u, cos_h, sin_h, wind_x, wind_y, x0, y0, lanes[A_HEADING, k], theta_nh, lanes[A_THETA_NH, k],
                lanes[A_FRESH, k], lanes[A_LAST_SUBSTEPS, k], lanes[A_VX_PREV, k], lanes[A_VY_PREV, k],
                lanes[A_OMEGA_PREV, k], dt, inv_dt, k_theta,
            )
            step_nm = math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
            ex = x1 - lanes[A_DEST_X, k]
            ey = y1 - lanes[A_DEST_Y, k]
            reach = delta + step_nm
            unusual |= law.saturate(u, u_cap)[1] | far | (ex * ex + ey * ey <= reach * reach) | (
                x1 * x1 + y1 * y1 >= exit_radius * exit_radius)
            lanes[A_X1, k] = x1
            lanes[A_Y1, k] = y1
            lanes[A_HEADING1, k] = heading1
            lanes[A_VX, k] = vx
            lanes[A_VY, k] = vy
            lanes[A_OMEGA, k] = omega
            lanes[A_U, k] = u
            lanes[A_THETA_NH1, k] = theta_nh
            lanes[A_STEP_NM, k] = step_nm
        if unusual:
            abandoned = True
            break
        new_min_sep2 = min_sep2
        lost = False
        # Nor a pair within the sensing radius after the move: guard 10 controls that step.
        if cells is not None:
            _fill_grid(cells, lanes, A_X1, A_Y1, count, n)
            nx, ny, width, skin = cells_grid.prepare(cells, _GRID, n, _cell_nm(params))
            new_min_sep2, lost = cells_grid.separation(cells, _GRID, n, nx, ny, width, skin, min_sep2,
                                                       sep_min * sep_min, los_pairs, False)
            lost |= cells_grid.any_within(cells, _GRID, n, nx, ny, r_sense2, inv_len)
        else:
            for a in range(count):
                xa = lanes[A_X1, a] * inv_len
                ya = lanes[A_Y1, a] * inv_len
                for b in range(a + 1, count):
                    sx = lanes[A_X1, a] - lanes[A_X1, b]
                    sy = lanes[A_Y1, a] - lanes[A_Y1, b]
                    sep2 = sx * sx + sy * sy
                    lost |= sep2 < sep_min * sep_min
                    new_min_sep2 = min(new_min_sep2, sep2)
                    rx = xa - lanes[A_X1, b] * inv_len
                    ry = ya - lanes[A_Y1, b] * inv_len
                    lost |= rx * rx + ry * ry < r_sense2
        if lost:
            abandoned = True
            break
        # Ordinary: the step as ``_advance_world`` writes it.
        min_sep2 = new_min_sep2
        for k in range(count):
            lanes[A_VX_PREV, k] = lanes[A_VX, k]
            lanes[A_VY_PREV, k] = lanes[A_VY, k]
            lanes[A_OMEGA_PREV, k] = lanes[A_OMEGA, k]
            lanes[A_LAST_SUBSTEPS, k] = 1.0
            lanes[A_X, k] = lanes[A_X1, k]
            lanes[A_Y, k] = lanes[A_Y1, k]
            lanes[A_HEADING, k] = lanes[A_HEADING1, k]
            lanes[A_AIRSPEED, k] = lanes[A_U, k]
            lanes[A_THETA_NH, k] = lanes[A_THETA_NH1, k]
            lanes[A_FRESH, k] = 0.0
            lanes[A_TIME, k] += dt
            lanes[A_PATH, k] += lanes[A_STEP_NM, k]
        step_violation = False
        for k in range(count):
            i = int(lanes[A_INDEX, k])
            min_airspeed[i], max_airspeed[i], worst_excursion[i], excursion = _flown_airspeed(
                lanes[A_U, k], steps_flown[i] == 0, min_airspeed[i], max_airspeed[i], worst_excursion[i], u_min,
                u_max,
            )
            lanes[A_VIOLATED, k] = 1.0 if excursion > 0.0 else 0.0
            if excursion > 0.0:
                step_violation = True
                violation_steps[i] += 1
            steps_flown[i] += 1
        flown += 1
        if record.shape[0] > 0:
            _commit_aircraft_lanes(state, command, lanes, count, n, False)
            _record_step(state, command, record, step0 + flown, record_every)
        if step_violation:
            violated = True
            if stop_on_violation:
                break
    if flown > 0:
        # The last step flown, as the one-step form left the state and the command's columns.
        _commit_aircraft_lanes(state, command, lanes, count, n, True)
    return flown, violated, min_sep2, abandoned


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _fill_grid(cells: np.ndarray, lanes: np.ndarray, row_x: int, row_y: int, count: int, n: int) -> None:
    """The neighbour grid's members: the aircraft of ``lanes``' first ``count`` lanes
    (``A_INDEX``) at the positions of rows ``row_x``, ``row_y`` (nm), by aircraft index (of
    ``n``)."""
    for i in range(n):
        cells[_GRID + cells_grid.GRID_MEMBER, i] = 0.0
    for k in range(count):
        i = int(lanes[A_INDEX, k])
        cells[_GRID + cells_grid.GRID_X, i] = lanes[row_x, k]
        cells[_GRID + cells_grid.GRID_Y, i] = lanes[row_y, k]
        cells[_GRID + cells_grid.GRID_MEMBER, i] = 1.0


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _commit_aircraft_lanes(state: np.ndarray, command: np.ndarray, lanes: np.ndarray, count: int, n: int,
                           every_field: bool) -> None:
    """The last step committed in ``_ordinary_run``'s lanes into the state (every field of
    the flying aircraft, or only those a record reads) and into the command's columns that
    the record reads (all of its step's columns with ``every_field``)."""
    for i in range(n):
        command[i, C_FLEW] = 0.0
        command[i, C_VIOLATED] = 0.0
    for k in range(count):
        i = int(lanes[A_INDEX, k])
        if every_field:
            for f in range(N_AIRCRAFT_FIELDS):
                state[i, _STATE_FIELD_OF_LANE[f]] = lanes[f, k]
            command[i, C_X1] = lanes[A_X1, k]
            command[i, C_Y1] = lanes[A_Y1, k]
            command[i, C_HEADING1] = lanes[A_HEADING1, k]
            command[i, C_VX] = lanes[A_VX, k]
            command[i, C_VY] = lanes[A_VY, k]
            command[i, C_OMEGA] = lanes[A_OMEGA, k]
            command[i, C_U] = lanes[A_U, k]
            command[i, C_THETA_NH] = lanes[A_THETA_NH1, k]
            command[i, C_STEP_NM] = lanes[A_STEP_NM, k]
            command[i, C_VIOLATED] = lanes[A_VIOLATED, k]
        else:
            state[i, S_X] = lanes[A_X, k]
            state[i, S_Y] = lanes[A_Y, k]
            state[i, S_HEADING] = lanes[A_HEADING, k]
            state[i, S_AIRSPEED] = lanes[A_AIRSPEED, k]
        command[i, C_FLEW] = 1.0
        command[i, C_STEP_MIN] = lanes[A_U, k]
        command[i, C_STEP_MAX] = lanes[A_U, k]


# Without reference counts (``nf.NO_REFERENCE_COUNTS``): it allocates nothing, and the counts
# of the arrays it passes to its helpers took about a quarter of a one-world flight (the
# helpers that take arrays are compiled without them too). The helpers are compiled on
# their own and left to LLVM to inline: numba-level inlining copies each callee's IR into
# every call site, and nearly doubled the one-world path's first compilation (41 s of CPU
# against 22 s, in one run on a loaded machine) for no speed.
@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _take_commands(source: np.ndarray, command: np.ndarray, status: np.ndarray) -> None:
    """The columns ``_commands`` writes, of the flying aircraft, from ``source``."""
    for i in range(status.shape[0]):
        if status[i] != FLYING:
            continue
        for c in _COMMAND_COLUMNS:
            command[i, c] = source[i, c]


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _move_aircraft(
    source: np.ndarray, target: np.ndarray, command: np.ndarray, i: int, wind_x: float, wind_y: float, h: float,
    n_sub: int,
) -> tuple[float, float, float, float]:
    """Aircraft ``i`` of ``source`` moved over one (sub-)step of ``h`` s under its
    ``command`` and the wind (kt), written into ``target`` (``source`` itself, or guard
    10's trial): the one move of the general path, so that a trial and the step it tries
    fly the same bits. ``n_sub``: the sub-steps of the step this one belongs to. Returns
    (x0, y0, x1, y1) nm."""
    u = command[i, C_U]
    x0 = source[i, S_X]
    y0 = source[i, S_Y]
    omega = command[i, C_OMEGA]
    # Second-order Adams-Bashforth (AB2): the airspeed falls steadily as the waypoint
    # nears, and explicit Euler's O(dt) error in that distance is what the convergence
    # study saw. AB2 needs the previous step's rates at this step's length; after a
    # waypoint switch they belong to another law, and within or after a refined step the
    # command is not smooth (or the step length changed), so those steps are plain Euler.
    ab2 = source[i, S_FRESH] == 0.0 and source[i, S_LAST_SUBSTEPS] <= 1.0 and n_sub == 1
    x1, y1, new_heading, vx, vy = law.integrate(x0, y0, source[i, S_HEADING], u, command[i, C_COS],
                                                command[i, C_SIN], wind_x, wind_y, omega, source[i, S_VX_PREV],
                                                source[i, S_VY_PREV], source[i, S_OMEGA_PREV], h, ab2)
    target[i, S_VX_PREV] = vx
    target[i, S_VY_PREV] = vy
    target[i, S_OMEGA_PREV] = omega
    target[i, S_LAST_SUBSTEPS] = n_sub
    target[i, S_X] = x1
    target[i, S_Y] = y1
    target[i, S_HEADING] = _wrap(new_heading)
    target[i, S_AIRSPEED] = u
    target[i, S_THETA_NH] = command[i, C_THETA_NH]
    target[i, S_FRESH] = 0.0
    return x0, y0, x1, y1


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _step_control(
    state: np.ndarray,
    command: np.ndarray,
    trial_state: np.ndarray,
    trial_command: np.ndarray,
    grad: np.ndarray,
    wind_x: float,
    wind_y: float,
    nf_consts: tuple,
    params: np.ndarray,
    inv_dt: float,
    n_refined: int,
    cells,
) -> tuple[int, bool, bool, bool]:
    """Guard 10: the sub-steps a step that its start does not refine is flown in, from a
    trial of the full step. The trial moves every flying aircraft by ``_move_aircraft``
    over an unrefined step, as ``_advance_world`` does (so the same bits), into
    ``trial_state``, and takes the law's commands there into ``trial_command`` (``grad``
    is overwritten). Where no two aircraft are within the sensing radius at the step's
    start or end, the step is flown whole (an ordinary step, as ``_ordinary_run`` and the
    lane step fly it). Otherwise it is refined into ``n_refined`` sub-steps if the commands
    at its end ask for it (guards 2, 8, 9, as at a step's start), else into as many as
    bring the estimated local error of the positions within ``step_tolerance_nm``: the
    difference of the step's scheme from the next order's, (5/12) dt |v₊ − 2v + v₋| for
    AB2 and dt |v₊ − v| / 2 for Euler (v₋, v, v₊: an aircraft's ground velocity over the
    last step, this one and, from the trial, the next), with Euler sub-steps, whose error
    falls as 1 / (their number).

    Returns (sub-steps, then ``_commands``' three flags at the trial's end: the commands
    of the next step where this one is flown whole and no aircraft arrives or leaves)."""
    n = state.shape[0]
    dt = params[P_DT]
    nm_per_kt_step = dt / SECONDS_PER_HOUR
    for i in range(n):
        for f in range(N_STATE):
            trial_state[i, f] = state[i, f]
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        _move_aircraft(state, trial_state, command, i, wind_x, wind_y, dt, 1)
    any_flying, refine, outside = _commands(
        trial_state, trial_state[:, S_X : S_Y + 1], trial_state[:, S_STATUS], grad, trial_command, nf_consts, params,
        inv_dt, cells,
    )
    near = False
    for i in range(n):
        if state[i, S_STATUS] == FLYING and (command[i, C_NEAR] > 0 or trial_command[i, C_NEAR] > 0):
            near = True
    if not near:
        return 1, any_flying, refine, outside
    if refine:
        return n_refined, any_flying, refine, outside
    tolerance = params[nf.P_STEP_TOLERANCE]
    if not tolerance > 0.0:
        return 1, any_flying, refine, outside
    worst = 0.0
    for i in range(n):
        if state[i, S_STATUS] != FLYING:
            continue
        vx = command[i, C_U] * command[i, C_COS]
        vy = command[i, C_U] * command[i, C_SIN]
        # The wind is constant: it cancels from the differences.
        next_vx = trial_command[i, C_U] * trial_command[i, C_COS]
        next_vy = trial_command[i, C_U] * trial_command[i, C_SIN]
        if state[i, S_FRESH] == 0.0 and state[i, S_LAST_SUBSTEPS] <= 1.0:
            ex = next_vx - 2.0 * vx + (state[i, S_VX_PREV] - wind_x)
            ey = next_vy - 2.0 * vy + (state[i, S_VY_PREV] - wind_y)
            error = (5.0 / 12.0) * math.sqrt(ex * ex + ey * ey) * nm_per_kt_step
        else:
            ex = next_vx - vx
            ey = next_vy - vy
            error = 0.5 * math.sqrt(ex * ex + ey * ey) * nm_per_kt_step
        worst = max(worst, error)
    if worst <= tolerance:
        return 1, any_flying, refine, outside
    return min(n_refined, int(math.ceil(worst / tolerance))), any_flying, refine, outside


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _advance_world(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind_x: float,
    wind_y: float,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    record: np.ndarray,
    record_every: int,
    ordinary_steps: bool,
    cells=None,
) -> tuple[float, int, bool]:
    """Advance one world by n_steps; returns (min separation, steps done, violated).
    ``aircraft_lanes`` (N_AIRCRAFT_LANE, N): scratch of the runs of ordinary steps.
    ``ordinary_steps``: fly the ordinary steps by ``_ordinary_run`` (every caller; False
    flies every step by the general path, which the tests compare it with).
    ``cells``: the neighbour grid's scratch (``neighbour_grid.grid_rows``, N), through which
    the pairs are found, the same bits as over all pairs in O(N) a step; or None (the
    default): over all pairs. None is a type of its own to numba, which then compiles no
    grid at all (``_advance_one`` passes it on)."""
    n = state.shape[0]
    dt = params[P_DT]
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    delta = params[P_DELTA]
    sep_min = params[P_SEP_MIN]
    exit_radius = params[P_R_WORLD] - params[P_RADIUS]
    stop_on_violation = params[P_STOP_ON_VIOLATION] != 0.0
    substep_max = params[P_SUBSTEP]
    # Sub-steps of a refined step: the fewest whose length is at most substep_max.
    n_refined = max(1, int(math.ceil(dt / substep_max - 1e-9)))
    pos = state[:, S_X : S_Y + 1]
    status = state[:, S_STATUS]
    nf_consts = nf.nf_constants(params)
    inv_dt = 1.0 / dt

    _begin_world(state, waypoints, min_airspeed, max_airspeed, violation_steps, worst_excursion, steps_flown,
                 los_pairs, record)
    # The trial of a step's error control (guard 10), in the scratch's rows after the lanes'.
    trial_state = aircraft_lanes[TRIAL_STATE_ROW:TRIAL_COMMAND_ROW].reshape((n, N_STATE))
    trial_command = aircraft_lanes[TRIAL_COMMAND_ROW:N_AIRCRAFT_LANE].reshape((n, N_COMMAND))
    if cells is not None:
        cells_grid.forget(cells, _GRID)
    min_sep2 = NO_PAIR_SEPARATION_NM * NO_PAIR_SEPARATION_NM
    sep_min2 = sep_min * sep_min
    violated = False

    # The ordinary steps by ``_ordinary_run`` (its arithmetic is for k = 2 only).
    ordinary_law = ordinary_steps and params[nf.P_K] == 2.0
    # Typed int64 from the start (not the literal 0): numba compiles a callee once per
    # argument type, and ``_ordinary_run`` took a second compilation for a literal 0.
    step = np.int64(0)
    # Guard 10's trial of a step flown whole gives the next step's commands.
    next_ready = False
    next_flying = next_refine = next_outside = False
    while step < n_steps:
        if ordinary_law:
            flew, step_violation, min_sep2, abandoned = _ordinary_run(
                state, command, aircraft_lanes, wind_x, wind_y, params, nf_consts, min_sep2, min_airspeed,
                max_airspeed, violation_steps, worst_excursion, steps_flown, n_steps - step, stop_on_violation,
                record, record_every, step, los_pairs, cells,
            )
            step += flew
            if flew > 0:
                next_ready = False
            if step_violation:
                violated = True
                if stop_on_violation:
                    break
            if not abandoned:
                continue  # every step asked for was ordinary
            # The step the run abandoned is flown below.
        if next_ready:
            # The last step was flown whole and no aircraft arrived or left: its trial's
            # commands are those of this step's start, bit for bit (guard 10).
            _take_commands(trial_command, command, status)
            any_flying, refine, outside = next_flying, next_refine, next_outside
        else:
            any_flying, refine, outside = _commands(state, pos, status, grad, command, nf_consts, params, inv_dt,
                                                    cells)
        next_ready = False
        if not any_flying:
            break
        # Step-size control at the law's singularity: where a command is saturated
        # (|P_i| → 0 with ∂Φ_i/∂t > 0), the sign of the 1/P_i term flips as the
        # aircraft crosses P_i = 0, and a full step overshoots the crossing by up to
        # u_cap · dt (2 nm at 5 s). That step is flown in sub-steps of at most
        # ``substep_max``, each with fresh commands, so that the motion along P_i ≈ 0
        # converges as dt shrinks. Not where the world stops at this step anyway: its
        # first sub-step has the same command, outside the envelope.
        n_sub = 1
        if refine and not (stop_on_violation and outside):
            n_sub = n_refined
        elif n_refined > 1 and not (stop_on_violation and outside):
            n_sub, next_flying, next_refine, next_outside = _step_control(
                state, command, trial_state, trial_command, grad, wind_x, wind_y, nf_consts, params, inv_dt,
                n_refined, cells,
            )
            next_ready = n_sub == 1
        h = dt / n_sub
        step_violation = False
        for i in range(n):
            command[i, C_FLEW] = 0.0
            command[i, C_VIOLATED] = 0.0
        for sub in range(n_sub):
            if sub > 0:
                # inv_dt, not n_sub * inv_dt: the previous sub-step's length is dt /
                # S_LAST_SUBSTEPS, which ``_commands`` divides θ_nh's change by (guard 5).
                any_flying, _, _ = _commands(state, pos, status, grad, command, nf_consts, params, inv_dt, cells)
                if not any_flying:
                    break
            # Move, then check arrival, departure and the envelope.
            for i in range(n):
                if status[i] != FLYING:
                    continue
                # The first sub-step this call flies: the extremes start there, not at
                # the airspeed held before it (a scenario's start airspeed was never flown).
                first_flown = steps_flown[i] == 0 and command[i, C_FLEW] == 0.0
                u = command[i, C_U]
                if command[i, C_FLEW] == 0.0:
                    command[i, C_STEP_MIN] = u
                    command[i, C_STEP_MAX] = u
                else:
                    command[i, C_STEP_MIN] = min(command[i, C_STEP_MIN], u)
                    command[i, C_STEP_MAX] = max(command[i, C_STEP_MAX], u)
                command[i, C_FLEW] = 2.0  # flew this sub-step (1: flew an earlier one)
                x0, y0, x1, y1 = _move_aircraft(state, state, command, i, wind_x, wind_y, h, n_sub)
                state[i, S_TIME] += h
                step_nm = math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
                state[i, S_PATH] += step_nm
                min_airspeed[i], max_airspeed[i], worst_excursion[i], excursion = _flown_airspeed(
                    u, first_flown, min_airspeed[i], max_airspeed[i], worst_excursion[i], u_min, u_max
                )
                if excursion > 0.0:
                    step_violation = True
                    if command[i, C_VIOLATED] == 0.0:
                        violation_steps[i] += 1  # once per integration step
                        command[i, C_VIOLATED] = 1.0
                dest_x = state[i, S_DEST_X]
                dest_y = state[i, S_DEST_Y]
                reach = delta + step_nm
                near = (x1 - dest_x) ** 2 + (y1 - dest_y) ** 2 <= reach * reach
                if near and _segment_distance(x0, y0, x1, y1, dest_x, dest_y) <= delta:
                    status[i] = ARRIVED
                    next_ready = False
                elif x1 * x1 + y1 * y1 >= exit_radius * exit_radius:  # guard 7
                    status[i] = LEFT
                    next_ready = False

            # Separation among the aircraft that flew this sub-step (one that arrived on
            # it still counts: it was in the airspace during the step).
            if cells is not None:
                for i in range(n):
                    cells[_GRID + cells_grid.GRID_X, i] = state[i, S_X]
                    cells[_GRID + cells_grid.GRID_Y, i] = state[i, S_Y]
                    cells[_GRID + cells_grid.GRID_MEMBER, i] = 1.0 if command[i, C_FLEW] == 2.0 else 0.0
                nx, ny, width, skin = cells_grid.prepare(cells, _GRID, n, _cell_nm(params))
                min_sep2, lost = cells_grid.separation(cells, _GRID, n, nx, ny, width, skin, min_sep2,
                                                       sep_min2, los_pairs, True)
                step_violation |= lost
            else:
                for i in range(n):
                    if command[i, C_FLEW] != 2.0:
                        continue
                    for j in range(i + 1, n):
                        if command[j, C_FLEW] != 2.0:
                            continue
                        sx = state[i, S_X] - state[j, S_X]
                        sy = state[i, S_Y] - state[j, S_Y]
                        sep2 = sx * sx + sy * sy
                        if sep2 < min_sep2:
                            min_sep2 = sep2
                        if sep2 < sep_min2:
                            los_pairs[i, j] = 1
                            los_pairs[j, i] = 1
                            step_violation = True
            for i in range(n):
                if command[i, C_FLEW] == 2.0:
                    command[i, C_FLEW] = 1.0
        for i in range(n):
            if command[i, C_FLEW] == 1.0:
                steps_flown[i] += 1
        step += 1
        _record_step(state, command, record, step, record_every)
        if step_violation:
            violated = True
            if stop_on_violation:
                break
    return math.sqrt(min_sep2), step, violated


# Not inlined: an inlined body would take its caller's flags, and ``_advance_checked_one``
# compiles without fast-math; a world must fly the same code alone and in a batch. Without
# reference counts: the threads of ``_advance_batch`` count on the same arrays' counters.
@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _advance_one(
    b: int,
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    cells=None,
) -> None:
    """World b of the batch: ``_advance_world`` on its slices, its outcome into the
    per-world result arrays. ``cells``: the batch's neighbour grids (B, rows, N), or None
    (the default: all pairs, and no grid compiled)."""
    # ``record_every`` as an int64 whatever the caller passed (a literal 1 is a type of its
    # own, and would compile ``_advance_world`` once more).
    if cells is None:
        sep, done, bad = _advance_world(
            state[b], waypoints[b], wind[b, 0], wind[b, 1], n_steps, params, grad[b], command[b], aircraft_lanes[b],
            min_airspeed[b], max_airspeed[b], violation_steps[b], worst_excursion[b], steps_flown[b], los_pairs[b],
            record[b], np.int64(record_every), True,
        )
    else:
        sep, done, bad = _advance_world(
            state[b], waypoints[b], wind[b, 0], wind[b, 1], n_steps, params, grad[b], command[b], aircraft_lanes[b],
            min_airspeed[b], max_airspeed[b], violation_steps[b], worst_excursion[b], steps_flown[b], los_pairs[b],
            record[b], np.int64(record_every), True, cells[b],
        )
    min_separation[b] = sep
    steps_done[b] = done
    violated[b] = bad


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", parallel=True)
def _advance_batch(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    cells,
) -> None:
    for b in prange(state.shape[0]):
        # ``b`` as an int64, as ``_advance_checked_one`` passes it: numba compiles
        # ``_advance_one`` once per argument type (prange's index is a uint64 once parallelized).
        _advance_one(
            np.int64(b), state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed, max_airspeed,
            violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done,
            violated, record, record_every, cells,
        )


# -- The lane path: many worlds' ordinary steps in the lanes of SIMD registers ---------------
#
# A step of a world in which every aircraft flies, no two are within the sensing radius, and
# nothing unusual happens (no command at the cap, no arrival or departure within reach, no
# loss of separation, no angle beyond 3π) takes none of the guards' branches: the NF has no
# neighbour terms, ∂Φ_i/∂t = 0, and the step is one AB2 or Euler step. That step is flown
# here for a chunk of worlds at once, with the worlds in the innermost loop, the state as
# structure of arrays (field, aircraft, world) and every branch a select, so that LLVM flies
# several worlds per instruction (packed square roots and divisions; atan2 and sincos stay
# scalar calls, in loops of their own, bit for bit the scalar ones). The arithmetic is the
# scalar path's operation for operation, so a world flies bit for bit the same trajectory
# whichever path flies a step (``tests/test_kernel_lanes.py``). Every other step of a world
# (neighbours in range, the guards, arrivals) is flown by ``_advance_world``, the scalar
# path, for that one step on the world's own rows. ``bench/bench_kernel.py`` measures what
# it gains. Why these loops vectorize: each chunk has buffers of its own indexed from 0
# (an index numba cannot prove non-negative gets a wraparound branch, and LLVM vectorizes
# no loop with one), and every value is loaded before any select.

#: Fewest worlds in a call for the lane path (fewer fill too few lanes to pay its transposes).
LANE_MIN_WORLDS = 16
#: Worlds per chunk of the lane path: a chunk's fields stay in the L1/L2 caches.
LANE_CHUNK = 64
#: Length of a chunk's rows: a chunk and a few more, so that rows of the same field and
#: of different fields do not lie a multiple of 4 KiB apart (loads and stores at such
#: distances alias in the L1 cache and stall each other).
LANE_ROW = LANE_CHUNK + 8

# Per-aircraft scratch of the lane path (T_*, aircraft, world).
T_COS, T_SIN, T_GX, T_GY, T_ARG_X, T_THETA, T_X1, T_Y1, T_HEADING1, T_VX, T_VY, T_OMEGA, T_U, T_STEP_NM = range(14)
N_LANE_TEMP = 14
# Per-world scratch of the lane path (W_*, world).
W_ACTIVE = 0  # 1 while the world steps (0 once it stopped at a violation or has nobody flying)
W_ORDINARY = 1  # 1 if the lane step is this step's flight of the world
W_MIN_SEP2 = 2  # smallest squared separation over the lane steps, nm²
W_NEW_MIN_SEP2 = 3  # the same after the lane step
W_STEP_VIOLATION = 4  # 1 if the lane step left the envelope
W_STEPS = 5  # integration steps done
W_VIOLATED = 6  # 1 once a step left the envelope or lost separation
W_WIND_X = 7  # the world's wind, kt
W_WIND_Y = 8
W_MIN_SEP_SCALAR = 9  # smallest separation over the steps flown by the scalar path, nm
N_LANE_WORLD = 10


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _select(condition: bool, if_true: float, if_false: float) -> float:
    """``if_true if condition else if_false`` of two values already loaded (a function
    argument is evaluated before the call: no load under a condition, no branch)."""
    return if_true if condition else if_false


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _lane_wrap(angle: float) -> float:
    """``_wrap`` for |angle| < 3π as a select (its third case, a floor, for larger angles,
    sends the step to the scalar path)."""
    near = angle - _TWO_PI if angle >= math.pi else angle + _TWO_PI
    # & instead of a chained comparison: ``and`` short-circuits, a branch the vectorizer cannot take.
    return angle if (angle >= -math.pi) & (angle < math.pi) else near


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _lane_feedback(gx: float, gy: float, cos_h: float, sin_h: float, dx: float, dy: float, atan2_nh: float,
                   theta_d: float, params: np.ndarray) -> tuple[float, float]:
    """``_commands``' pass 1 after the NF, without neighbours: (−sgn(P_i) F_i kt, θ_nh rad),
    θ_d where the gradient has no direction (guard 3); dx, dy: q_i − q_d in units of L."""
    u_feedback, _, has_direction = law.feedback(gx, gy, cos_h, sin_h, dx, dy, params[P_K_U], params[P_K_Z],
                                                params[P_P_FLOOR], params[P_GRAD_FLOOR])
    theta_nh = atan2_nh if has_direction else theta_d
    return u_feedback, theta_nh


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _lane_move(u: float, cos_h: float, sin_h: float, wind_x: float, wind_y: float, x0: float, y0: float,
               heading: float, theta_nh: float, theta_nh_before: float, fresh: float, last_sub: float,
               vx_prev: float, vy_prev: float, omega_prev: float, dt: float, inv_dt: float,
               k_theta: float) -> tuple[float, float, float, float, float, float, bool]:
    """The heading law (5b) and the move of one unrefined step (AB2, or Euler after a
    waypoint switch or a refined step), every branch a select: (x1, y1 nm, the wrapped
    heading rad, vx, vy kt, ω rad/s, whether an angle reached 3π)."""
    jump_raw = theta_nh - theta_nh_before
    error_raw = heading - theta_nh
    omega = law.turn_rate(_lane_wrap(error_raw), _lane_wrap(jump_raw), fresh, last_sub, inv_dt, k_theta)
    ab2 = (fresh == 0.0) & (last_sub <= 1.0)
    x1, y1, new_heading, vx, vy = law.integrate(x0, y0, heading, u, cos_h, sin_h, wind_x, wind_y, omega, vx_prev,
                                                vy_prev, omega_prev, dt, ab2)
    far = max(abs(jump_raw), abs(error_raw), abs(new_heading)) >= 3.0 * math.pi
    return x1, y1, _lane_wrap(new_heading), vx, vy, omega, far


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _lane_step(count: int, lanes: np.ndarray, temp: np.ndarray, world: np.ndarray, params: np.ndarray,
               nf_consts: tuple, pairs_by_grid: bool) -> None:
    """The lane step of the first ``count`` worlds of a chunk, ``lanes`` (N_STATE, N,
    LANE_CHUNK), into ``temp`` (N_LANE_TEMP, N, LANE_CHUNK), and ``world[W_ORDINARY]`` set
    where it is the world's step. With ``pairs_by_grid`` its two loops over pairs are left
    to ``_lane_pairs_by_grid``, which the caller runs next. Indices from 0 over a chunk's own buffers: numba then
    knows them non-negative and emits no wraparound branch, which would keep LLVM from
    vectorizing the loops."""
    n = lanes.shape[1]
    inv_len, _, _, _, _, _, _, r_sense2, _, _, _ = nf_consts
    dt = params[P_DT]
    inv_dt = 1.0 / dt
    k_theta = params[P_K_THETA]
    u_cap = params[P_U_CAP]
    delta = params[P_DELTA]
    sep_min = params[P_SEP_MIN]
    sep_min2 = sep_min * sep_min
    exit_radius = params[P_R_WORLD] - params[P_RADIUS]
    exit2 = exit_radius * exit_radius
    length = params[P_LENGTH]
    ordinary = world[W_ORDINARY]
    for b in range(count):
        ordinary[b] = world[W_ACTIVE, b]
    for i in range(n):
        status = lanes[S_STATUS, i]
        for b in range(count):
            # Every load before any select: a load under a condition would keep the branch.
            flag = ordinary[b]
            ordinary[b] = flag if status[b] == FLYING else 0.0
    # No neighbour within the sensing radius, in the NF's own arithmetic (its test is
    # symmetric in the pair: q_j − q_i is exactly −(q_i − q_j)).
    for i in range(0 if pairs_by_grid else n):
        for j in range(i + 1, n):
            for b in range(count):
                rx = lanes[S_X, i, b] * inv_len - lanes[S_X, j, b] * inv_len
                ry = lanes[S_Y, i, b] * inv_len - lanes[S_Y, j, b] * inv_len
                flag = ordinary[b]
                ordinary[b] = flag if rx * rx + ry * ry >= r_sense2 else 0.0
    for i in range(n):
        x, y, wp_x, wp_y = lanes[S_X, i], lanes[S_Y, i], lanes[S_WP_X, i], lanes[S_WP_Y, i]
        cos_d, sin_d, heading = lanes[S_COS_D, i], lanes[S_SIN_D, i], lanes[S_HEADING, i]
        gx_out, gy_out, arg_x, theta = temp[T_GX, i], temp[T_GY, i], temp[T_ARG_X, i], temp[T_THETA, i]
        for b in range(count):
            # A world the lane step does not fly is fed a harmless point (inside the
            # workspace, off its waypoint), so that no lane computes a NaN or inf.
            use = ordinary[b] != 0.0
            xb, yb, wp_xb, wp_yb, cos_db, sin_db = x[b], y[b], wp_x[b], wp_y[b], cos_d[b], sin_d[b]
            gx, gy, _, sgn_along = nf.own_gradient_alone(
                xb if use else 0.0, yb if use else 0.0, wp_xb if use else length, wp_yb if use else 0.0,
                cos_db if use else 1.0, sin_db if use else 0.0, nf_consts,
            )
            gx_out[b] = gx
            gy_out[b] = gy
            arg_x[b] = sgn_along * gx
            theta[b] = sgn_along * gy
        for b in range(count):
            theta[b] = trig.poly_atan2_inlined(theta[b], arg_x[b])  # θ_nh where the gradient has a direction
        cos_h, sin_h = temp[T_COS, i], temp[T_SIN, i]
        for b in range(count):
            sin_h[b], cos_h[b] = trig.poly_sincos_inlined(heading[b])
    for i in range(n):
        x, y, wp_x, wp_y = lanes[S_X, i], lanes[S_Y, i], lanes[S_WP_X, i], lanes[S_WP_Y, i]
        for b in range(count):
            # Every load before any select: a load under a condition would keep the branch.
            c = temp[T_COS, i, b]
            sn = temp[T_SIN, i, b]
            x0 = x[b]
            y0 = y[b]
            u, theta_nh = _lane_feedback(
                temp[T_GX, i, b], temp[T_GY, i, b], c, sn, (x0 - wp_x[b]) * inv_len, (y0 - wp_y[b]) * inv_len,
                temp[T_THETA, i, b], lanes[S_THETA_D, i, b], params,
            )
            _, saturated = law.saturate(u, u_cap)
            x1, y1, heading1, vx, vy, omega, far = _lane_move(
                u, c, sn, world[W_WIND_X, b], world[W_WIND_Y, b], x0, y0, lanes[S_HEADING, i, b], theta_nh, lanes[S_THETA_NH, i, b],
                lanes[S_FRESH, i, b], lanes[S_LAST_SUBSTEPS, i, b], lanes[S_VX_PREV, i, b], lanes[S_VY_PREV, i, b],
                lanes[S_OMEGA_PREV, i, b], dt, inv_dt, k_theta,
            )
            step_nm = math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
            ex = x1 - lanes[S_DEST_X, i, b]
            ey = y1 - lanes[S_DEST_Y, i, b]
            reach = delta + step_nm
            # Within reach of its destination (an arrival to test) or at the boundary (guard 7).
            unusual = saturated | far | (ex * ex + ey * ey <= reach * reach) | (x1 * x1 + y1 * y1 >= exit2)
            flag = ordinary[b]
            ordinary[b] = 0.0 if unusual else flag
            temp[T_X1, i, b] = x1
            temp[T_Y1, i, b] = y1
            temp[T_HEADING1, i, b] = heading1
            temp[T_VX, i, b] = vx
            temp[T_VY, i, b] = vy
            temp[T_OMEGA, i, b] = omega
            temp[T_U, i, b] = u
            temp[T_THETA, i, b] = theta_nh
            temp[T_STEP_NM, i, b] = step_nm
    new_min = world[W_NEW_MIN_SEP2]
    for b in range(count):
        new_min[b] = world[W_MIN_SEP2, b]
    # Nor a loss of separation after the move, nor a pair within the sensing radius then
    # (guard 10 controls that step).
    for i in range(0 if pairs_by_grid else n):
        for j in range(i + 1, n):
            for b in range(count):
                sx = temp[T_X1, i, b] - temp[T_X1, j, b]
                sy = temp[T_Y1, i, b] - temp[T_Y1, j, b]
                rx = temp[T_X1, i, b] * inv_len - temp[T_X1, j, b] * inv_len
                ry = temp[T_Y1, i, b] * inv_len - temp[T_Y1, j, b] * inv_len
                sep2 = sx * sx + sy * sy
                least = new_min[b]
                flag = ordinary[b]
                new_min[b] = sep2 if sep2 < least else least
                ordinary[b] = 0.0 if (sep2 < sep_min2) | (rx * rx + ry * ry < r_sense2) else flag


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _lane_pairs_by_grid(b0: int, count: int, lanes: np.ndarray, temp: np.ndarray, world: np.ndarray,
                        cells: np.ndarray, los_pairs: np.ndarray, params: np.ndarray,
                        nf_consts: tuple) -> None:
    """``_lane_step``'s two loops over pairs, through each world's neighbour grid
    (``cells``, B rows × N), for the worlds whose lane step is
    still ordinary: not where a pair is within the sensing radius at the start or after
    the move, nor where one is closer than the separation minimum after the move;
    ``W_NEW_MIN_SEP2`` exact. A
    world at a time (no SIMD lanes), in O(N) instead of O(N²); where the lane step is not
    the world's, what it left is never read."""
    n = lanes.shape[1]
    inv_len = nf_consts[0]
    r_sense2 = nf_consts[7]
    cell_nm = _cell_nm(params)
    sep_min = params[P_SEP_MIN]
    for k in range(count):
        if world[W_ORDINARY, k] == 0.0:
            continue
        world_cells = cells[b0 + k]
        for i in range(n):
            world_cells[_GRID + cells_grid.GRID_X, i] = lanes[S_X, i, k]
            world_cells[_GRID + cells_grid.GRID_Y, i] = lanes[S_Y, i, k]
            world_cells[_GRID + cells_grid.GRID_MEMBER, i] = 1.0
        nx, ny, _, _ = cells_grid.prepare(world_cells, _GRID, n, cell_nm)
        if cells_grid.any_within(world_cells, _GRID, n, nx, ny, r_sense2, inv_len):
            world[W_ORDINARY, k] = 0.0
            continue
        for i in range(n):
            world_cells[_GRID + cells_grid.GRID_X, i] = temp[T_X1, i, k]
            world_cells[_GRID + cells_grid.GRID_Y, i] = temp[T_Y1, i, k]
        nx, ny, width, skin = cells_grid.prepare(world_cells, _GRID, n, cell_nm)
        least2, lost = cells_grid.separation(world_cells, _GRID, n, nx, ny, width, skin, world[W_MIN_SEP2, k],
                                             sep_min * sep_min, los_pairs[b0 + k], False)
        world[W_NEW_MIN_SEP2, k] = least2
        if lost or cells_grid.any_within(world_cells, _GRID, n, nx, ny, r_sense2, inv_len):
            world[W_ORDINARY, k] = 0.0


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _lane_commit(count: int, lanes: np.ndarray, temp: np.ndarray, world: np.ndarray, params: np.ndarray) -> None:
    """The lane step into the chunk's state where it is the world's step, as
    ``_advance_world`` would write it (the outcome arrays: ``_lane_outcomes``)."""
    n = lanes.shape[1]
    dt = params[P_DT]
    ordinary = world[W_ORDINARY]
    for i in range(n):
        for b in range(count):
            use = ordinary[b] != 0.0
            # Both sides loaded before the select (a load under a condition would keep the branch).
            lanes[S_VX_PREV, i, b] = _select(use, temp[T_VX, i, b], lanes[S_VX_PREV, i, b])
            lanes[S_VY_PREV, i, b] = _select(use, temp[T_VY, i, b], lanes[S_VY_PREV, i, b])
            lanes[S_OMEGA_PREV, i, b] = _select(use, temp[T_OMEGA, i, b], lanes[S_OMEGA_PREV, i, b])
            lanes[S_X, i, b] = _select(use, temp[T_X1, i, b], lanes[S_X, i, b])
            lanes[S_Y, i, b] = _select(use, temp[T_Y1, i, b], lanes[S_Y, i, b])
            lanes[S_HEADING, i, b] = _select(use, temp[T_HEADING1, i, b], lanes[S_HEADING, i, b])
            lanes[S_AIRSPEED, i, b] = _select(use, temp[T_U, i, b], lanes[S_AIRSPEED, i, b])
            lanes[S_THETA_NH, i, b] = _select(use, temp[T_THETA, i, b], lanes[S_THETA_NH, i, b])
            lanes[S_LAST_SUBSTEPS, i, b] = _select(use, 1.0, lanes[S_LAST_SUBSTEPS, i, b])
            lanes[S_FRESH, i, b] = _select(use, 0.0, lanes[S_FRESH, i, b])
            lanes[S_TIME, i, b] += _select(use, dt, 0.0)
            lanes[S_PATH, i, b] += _select(use, temp[T_STEP_NM, i, b], 0.0)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _lane_outcomes(b0: int, count: int, temp: np.ndarray, world: np.ndarray, params: np.ndarray,
                   min_airspeed: np.ndarray, max_airspeed: np.ndarray, violation_steps: np.ndarray,
                   worst_excursion: np.ndarray, steps_flown: np.ndarray) -> None:
    """The lane step into the outcome arrays of the worlds b0 … b0 + count − 1 it flies, as
    ``_advance_world`` would write them."""
    n = temp.shape[1]
    u_min = params[P_U_MIN]
    u_max = params[P_U_MAX]
    ordinary = world[W_ORDINARY]
    for k in range(count):
        world[W_STEP_VIOLATION, k] = 0.0
        if ordinary[k] == 0.0:
            continue
        b = b0 + k
        for i in range(n):
            u = temp[T_U, i, k]
            min_airspeed[b, i], max_airspeed[b, i], worst_excursion[b, i], excursion = _flown_airspeed(
                u, steps_flown[b, i] == 0, min_airspeed[b, i], max_airspeed[b, i], worst_excursion[b, i], u_min, u_max
            )
            if excursion > 0.0:
                world[W_STEP_VIOLATION, k] = 1.0
                violation_steps[b, i] += 1
            steps_flown[b, i] += 1
        world[W_MIN_SEP2, k] = world[W_NEW_MIN_SEP2, k]


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")
def _fly_lanes(
    b0: int,
    b1: int,
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    lanes: np.ndarray,
    temp: np.ndarray,
    world: np.ndarray,
    cells,
) -> None:
    """Worlds b0..b1−1 of the batch flown step by step: each step by the lane step where it
    is ordinary, by ``_advance_world`` for that step where it is not; for each world the
    same outcome as ``_advance_world`` over all the steps. ``lanes``, ``temp``, ``world``:
    the chunk's own buffers (N_STATE, N, LANE_ROW), (N_LANE_TEMP, N, LANE_ROW),
    (N_LANE_WORLD, LANE_ROW)."""
    n = state.shape[1]
    stop_on_violation = params[P_STOP_ON_VIOLATION] != 0.0
    nf_consts = nf.nf_constants(params)
    count = b1 - b0
    # One step of a world flown by ``_advance_world``: its outcome arrays for that step.
    step_min = np.empty(n)
    step_max = np.empty(n)
    step_violations = np.empty(n, dtype=violation_steps.dtype)
    step_worst = np.empty(n)
    step_flown = np.empty(n, dtype=steps_flown.dtype)
    step_los = np.empty((n, n), dtype=los_pairs.dtype)
    no_record = np.empty((0, n, N_RECORD))
    step_waypoints = np.empty((n, 2))
    for k in range(count):
        b = b0 + k
        _begin_world(state[b], waypoints[b], min_airspeed[b], max_airspeed[b], violation_steps[b],
                     worst_excursion[b], steps_flown[b], los_pairs[b], record[b])
        for i in range(n):
            for field in range(N_STATE):
                lanes[field, i, k] = state[b, i, field]
        world[W_ACTIVE, k] = 1.0
        if cells is not None:
            cells_grid.forget(cells[b], _GRID)
        world[W_MIN_SEP2, k] = NO_PAIR_SEPARATION_NM * NO_PAIR_SEPARATION_NM
        world[W_MIN_SEP_SCALAR, k] = NO_PAIR_SEPARATION_NM
        world[W_STEPS, k] = 0.0
        world[W_VIOLATED, k] = 0.0
        world[W_WIND_X, k] = wind[b, 0]
        world[W_WIND_Y, k] = wind[b, 1]
    n_record = record.shape[1]
    for step in range(n_steps):
        _lane_step(count, lanes, temp, world, params, nf_consts, cells is not None)
        if cells is not None:
            _lane_pairs_by_grid(b0, count, lanes, temp, world, cells, los_pairs, params, nf_consts)
        _lane_commit(count, lanes, temp, world, params)
        _lane_outcomes(b0, count, temp, world, params, min_airspeed, max_airspeed, violation_steps, worst_excursion,
                       steps_flown)
        any_active = False
        for k in range(count):
            b = b0 + k
            if world[W_ACTIVE, k] == 0.0:
                continue
            if world[W_ORDINARY, k] != 0.0:
                step_violation = world[W_STEP_VIOLATION, k] != 0.0
                if n_record > 0 and (step + 1) % record_every == 0 and (step + 1) // record_every < n_record:
                    r = (step + 1) // record_every
                    for i in range(n):
                        u = lanes[S_AIRSPEED, i, k]
                        record[b, r, i, R_X] = lanes[S_X, i, k]
                        record[b, r, i, R_Y] = lanes[S_Y, i, k]
                        record[b, r, i, R_HEADING] = lanes[S_HEADING, i, k]
                        record[b, r, i, R_AIRSPEED] = u
                        record[b, r, i, R_FLEW] = 1.0
                        record[b, r, i, R_AIRSPEED_MIN] = u
                        record[b, r, i, R_AIRSPEED_MAX] = u
            else:
                # Not ordinary: ``_advance_world`` flies this step on the world's own rows,
                # its outcome arrays for the step merged into the call's.
                rows = state[b]
                for i in range(n):
                    for field in range(N_STATE):
                        rows[i, field] = lanes[field, i, k]
                for i in range(n):
                    step_waypoints[i, 0] = rows[i, S_WP_X]
                    step_waypoints[i, 1] = rows[i, S_WP_Y]
                # The world's own waypoints (no switch), in a buffer of the layout that
                # ``_advance_one`` passes, and ``record_every`` as an int64 as there (a literal
                # 1 is a type of its own): one compiled ``_advance_world`` serves both.
                # Without recording, the world is handed to it for all its remaining steps:
                # a world dense or stopping enough to leave the lanes once mostly stays out,
                # and each lane step it would take costs the transposes around it.
                handed_over = n_record == 0
                steps_left = n_steps - step if handed_over else 1
                if cells is None:
                    step_sep, flown, step_violation = _advance_world(
                        rows, step_waypoints, wind[b, 0], wind[b, 1], steps_left, params, grad[b], command[b],
                        aircraft_lanes[b], step_min, step_max, step_violations, step_worst, step_flown, step_los,
                        no_record, record_every, True,
                    )
                else:
                    step_sep, flown, step_violation = _advance_world(
                        rows, step_waypoints, wind[b, 0], wind[b, 1], steps_left, params, grad[b], command[b],
                        aircraft_lanes[b], step_min, step_max, step_violations, step_worst, step_flown, step_los,
                        no_record, record_every, True, cells[b],
                    )
                for i in range(n):
                    for field in range(N_STATE):
                        lanes[field, i, k] = rows[i, field]
                if flown == 0:
                    world[W_ACTIVE, k] = 0.0
                    continue
                # min(√a, √b) = √min(a, b): the square root is correctly rounded, so monotonic.
                world[W_MIN_SEP_SCALAR, k] = min(world[W_MIN_SEP_SCALAR, k], step_sep)
                for i in range(n):
                    if step_flown[i] > 0:
                        first_flown = steps_flown[b, i] == 0
                        if first_flown or step_min[i] < min_airspeed[b, i]:
                            min_airspeed[b, i] = step_min[i]
                        if first_flown or step_max[i] > max_airspeed[b, i]:
                            max_airspeed[b, i] = step_max[i]
                    violation_steps[b, i] += step_violations[i]
                    worst_excursion[b, i] = max(worst_excursion[b, i], step_worst[i])
                    steps_flown[b, i] += step_flown[i]
                    for j in range(n):
                        los_pairs[b, i, j] |= step_los[i, j]
                _record_step(rows, command[b], record[b], step + 1, record_every)
                if handed_over:
                    # Its whole remaining flight is done: steps_done counts what it flew.
                    world[W_STEPS, k] = step + flown
                    if step_violation:
                        world[W_VIOLATED, k] = 1.0
                    world[W_ACTIVE, k] = 0.0
                    continue
            world[W_STEPS, k] = step + 1
            if step_violation:
                world[W_VIOLATED, k] = 1.0
                if stop_on_violation:
                    world[W_ACTIVE, k] = 0.0
            any_active |= world[W_ACTIVE, k] != 0.0
        if not any_active:
            break
    for k in range(count):
        b = b0 + k
        for i in range(n):
            for field in range(N_STATE):
                state[b, i, field] = lanes[field, i, k]
        min_separation[b] = min(math.sqrt(world[W_MIN_SEP2, k]), world[W_MIN_SEP_SCALAR, k])
        steps_done[b] = int(world[W_STEPS, k])
        violated[b] = world[W_VIOLATED, k] != 0.0


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", parallel=True)
def _advance_lanes(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    lanes: np.ndarray,
    temp: np.ndarray,
    world: np.ndarray,
    chunk: int,
    cells,
) -> None:
    """The batch in chunks of ``chunk`` worlds (at most ``LANE_CHUNK``), the chunks in parallel."""
    n_worlds = state.shape[0]
    n_chunks = (n_worlds + chunk - 1) // chunk
    for c in prange(n_chunks):
        b0 = c * chunk
        _fly_lanes(
            b0, min(b0 + chunk, n_worlds), state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes,
            min_airspeed, max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, min_separation,
            steps_done, violated, record, record_every, lanes[c], temp[c], world[c], cells,
        )

# Outcomes of the ``_advance_checked_*`` entries.
_DONE = 0
_BAD_INPUT = 1  # a NaN or inf in an input, or a parameter out of range: nothing was flown
_NON_FINITE_RESULT = 2  # the integration produced a NaN or inf


# No fast-math in the checks: under its no-NaN, no-inf flags they would be compiled away.
@njit(cache=True, error_model="numpy")
def _all_finite(values: np.ndarray) -> bool:
    for value in values.flat:  # any layout (a params vector may be a strided view)
        if not math.isfinite(value):
            return False
    return True


# The three paths have an entry each, chosen in Python by the batch's size (``advance``):
# numba compiles a function with every function it calls, so one entry reaching all three
# paths compiled all of them on any first call, and a one-world flight (an environment, a
# single simulation) paid for the parallel batch paths too.
@njit(cache=True, error_model="numpy")
def _inputs_valid(params: np.ndarray, state: np.ndarray, waypoints: np.ndarray, wind: np.ndarray) -> bool:
    """Every input value finite, the parameters that are divided by > 0, the step lengths
    within ``_check_step_lengths``' bounds and every status a defined code
    (``_check_inputs`` names what is wrong)."""
    if not (_all_finite(params) and _all_finite(state) and _all_finite(waypoints) and _all_finite(wind)):
        return False
    for index in _POSITIVE_INDEX:
        if not params[index] > 0.0:
            return False
    if not (params[P_DT] >= MIN_STEP_S and params[P_SUBSTEP] >= MIN_STEP_S
            and params[P_DT] <= MAX_SUBSTEPS * params[P_SUBSTEP]):
        return False
    for b in range(state.shape[0]):
        for i in range(state.shape[1]):
            status = state[b, i, S_STATUS]
            if not (status == FLYING or status == ARRIVED or status == LEFT or status == ABSENT):
                return False
    return True


@njit(cache=True, error_model="numpy")
def _advance_checked_one(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    cells,
) -> int:
    """``advance``'s compiled part for one world: the checks of the values
    (``_inputs_valid``) before anything moves, the flight, and the check that the state
    came out finite; one call from Python instead of a dozen numpy reductions. No thread pool: waking it costs more than one world's work, and far more
    when other processes hold the cores."""
    if not _inputs_valid(params, state, waypoints, wind):
        return _BAD_INPUT
    if cells is None:  # no grid compiled for None (``_advance_one``'s default, as the envs call it)
        _advance_one(
            np.int64(0), state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed,
            max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done,
            violated, record, record_every,
        )
    else:
        _advance_one(
            np.int64(0), state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed,
            max_airspeed, violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done,
            violated, record, record_every, cells,
        )
    if not _all_finite(state):
        return _NON_FINITE_RESULT
    return _DONE


@njit(cache=True, error_model="numpy")
def _advance_checked_batch(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    cells,
) -> int:
    """``_advance_checked_one`` for a batch flown by the scalar path, the worlds in parallel."""
    if not _inputs_valid(params, state, waypoints, wind):
        return _BAD_INPUT
    _advance_batch(
        state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed, max_airspeed,
        violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done, violated, record,
        record_every, cells,
    )
    if not _all_finite(state):
        return _NON_FINITE_RESULT
    return _DONE


@njit(cache=True, error_model="numpy")
def _advance_checked_lanes(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind: np.ndarray,
    n_steps: int,
    params: np.ndarray,
    grad: np.ndarray,
    command: np.ndarray,
    aircraft_lanes: np.ndarray,
    min_airspeed: np.ndarray,
    max_airspeed: np.ndarray,
    violation_steps: np.ndarray,
    worst_excursion: np.ndarray,
    steps_flown: np.ndarray,
    los_pairs: np.ndarray,
    min_separation: np.ndarray,
    steps_done: np.ndarray,
    violated: np.ndarray,
    record: np.ndarray,
    record_every: int,
    lanes: np.ndarray,
    temp: np.ndarray,
    world: np.ndarray,
    chunk: int,
    cells,
) -> int:
    """``_advance_checked_one`` for a batch flown by the lane path (k = 2 only), the chunks
    of ``chunk`` worlds in parallel."""
    if not _inputs_valid(params, state, waypoints, wind):
        return _BAD_INPUT
    _advance_lanes(
        state, waypoints, wind, n_steps, params, grad, command, aircraft_lanes, min_airspeed, max_airspeed,
        violation_steps, worst_excursion, steps_flown, los_pairs, min_separation, steps_done, violated, record,
        record_every, lanes, temp, world, chunk, cells,
    )
    if not _all_finite(state):
        return _NON_FINITE_RESULT
    return _DONE


@dataclass
class Trace:
    """What happened during one ``advance`` call, at integration-step resolution.

    Attributes (B worlds, N aircraft):
        min_airspeed_kt, max_airspeed_kt: (B, N) extreme airspeeds over the steps flown
            (the airspeed at entry where an aircraft flew no step), kt.
        violation_steps: (B, N) steps flown with airspeed outside the envelope.
        worst_excursion_kt: (B, N) largest distance outside the envelope, kt (0 if none).
        steps_flown: (B, N) integration steps flown by each aircraft.
        los_pairs: (B, N, N) 1 where the pair was closer than the separation minimum.
        min_separation_nm: (B,) smallest distance between two aircraft that were flying,
            nm (``NO_PAIR_SEPARATION_NM`` if fewer than two flew).
        steps_done: (B,) integration steps simulated (fewer than asked when the world
            stopped at a violation, or when every aircraft had arrived or left).
        violated: (B,) an envelope violation or a loss of separation occurred.
        record: (B, R, N, N_RECORD) the state every ``record_every`` steps (R = 0 when
            recording is off); fields ``R_*``.
    """

    min_airspeed_kt: np.ndarray
    max_airspeed_kt: np.ndarray
    violation_steps: np.ndarray
    worst_excursion_kt: np.ndarray
    steps_flown: np.ndarray
    los_pairs: np.ndarray
    min_separation_nm: np.ndarray
    steps_done: np.ndarray
    violated: np.ndarray
    record: np.ndarray


#: The ways ``KernelScratch`` lets the kernel find pairs of aircraft (all give the same bits).
NEIGHBOUR_SEARCHES = ("auto", "grid", "all_pairs")


class KernelScratch:
    """Scratch buffers of the kernel, reused across calls of the same batch shape, and the
    last two calls' ``Trace`` objects, reused once their callers have dropped them
    (``trace``).

    ``neighbour_search``: how the kernel finds the pairs of aircraft within the sensing
    radius and the closest pair, "auto" (the neighbour grid from ``GRID_MIN_AIRCRAFT``
    aircraft, all pairs below), "grid" or "all_pairs"; every choice flies the same bits,
    only the time differs (O(N) against O(N²) a step)."""

    def __init__(self, neighbour_search: str = "auto") -> None:
        if neighbour_search not in NEIGHBOUR_SEARCHES:
            raise ValueError(
                f"neighbour_search = {neighbour_search!r}: allowed: {', '.join(map(repr, NEIGHBOUR_SEARCHES))}"
            )
        self.neighbour_search = neighbour_search
        self._shape: tuple[int, int, int] = (-1, -1, -1)
        self.grad = np.zeros((0, 0, 0, 2))
        self.command = np.zeros((0, 0, N_COMMAND))
        self.aircraft_lanes = np.zeros((0, N_AIRCRAFT_LANE, 0))
        self.cells: np.ndarray | None = None
        self.lanes = np.zeros((0, N_STATE, 0, LANE_ROW))
        self.lane_temp = np.zeros((0, N_LANE_TEMP, 0, LANE_ROW))
        self.lane_world = np.zeros((0, N_LANE_WORLD, LANE_ROW))
        # Two slots of (trace, its arrays, its shapes): a loop ``trace = advance(...)`` still
        # holds the last trace during the call.
        empty: tuple[Trace | None, tuple[np.ndarray, ...], tuple[int, int, int]] = (None, (), (-1, -1, -1))
        self._slots = [empty, empty]
        self._newest = 0

    def get(self, n_worlds: int, n_aircraft: int, lane_chunk: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scalar path's buffers (gradients, commands, aircraft lanes) for this batch
        shape, and the lane path's (``lanes``, ``lane_temp``, ``lane_world``) for chunks of
        ``lane_chunk`` worlds (none when 0)."""
        if self._shape != (n_worlds, n_aircraft, lane_chunk):
            self.grad = np.zeros((n_worlds, n_aircraft, n_aircraft, 2))
            self.command = np.zeros((n_worlds, n_aircraft, N_COMMAND))
            by_grid = self.neighbour_search == "grid" or (
                self.neighbour_search == "auto" and n_aircraft >= GRID_MIN_AIRCRAFT)
            self.aircraft_lanes = np.zeros((n_worlds, N_AIRCRAFT_LANE, n_aircraft))
            # The kernel's switch: None flies all pairs (and compiles no grid).
            self.cells = np.zeros((n_worlds, cells_grid.grid_rows(n_aircraft), n_aircraft)) if by_grid else None
            chunks = -(-n_worlds // lane_chunk) if lane_chunk > 0 else 0
            self.lanes = np.zeros((chunks, N_STATE, n_aircraft, LANE_ROW))
            self.lane_temp = np.zeros((chunks, N_LANE_TEMP, n_aircraft, LANE_ROW))
            self.lane_world = np.zeros((chunks, N_LANE_WORLD, LANE_ROW))
            self._shape = (n_worlds, n_aircraft, lane_chunk)
        return self.grad, self.command, self.aircraft_lanes

    def trace(self, n_worlds: int, n_aircraft: int, n_record: int) -> Trace:
        """A ``Trace`` for a call on B = ``n_worlds`` worlds of ``n_aircraft`` with
        ``n_record`` records: one of the last two this scratch handed out, its record
        zeroed, if nothing else refers to it or to any of its arrays any more (its caller
        dropped it, so no one can tell it from new arrays), else new arrays. At B = 1 the
        ten arrays and the dataclass took about a fifth of a converging-4 period's
        ``advance``."""
        key = (n_worlds, n_aircraft, n_record)
        if _REUSE_TRACES:
            for slot in (1 - self._newest, self._newest):
                # No local name for the trace before its counts are read: it would be one more.
                if self._slots[slot][2] == key and _reference_counts(self, slot) == _DROPPED_COUNTS:
                    trace = self._slots[slot][0]
                    if n_record:
                        trace.record.fill(0.0)
                    self._newest = slot
                    return trace
        trace = Trace(
            min_airspeed_kt=np.empty((n_worlds, n_aircraft)),
            max_airspeed_kt=np.empty((n_worlds, n_aircraft)),
            violation_steps=np.empty((n_worlds, n_aircraft), dtype=np.int64),
            worst_excursion_kt=np.empty((n_worlds, n_aircraft)),
            steps_flown=np.empty((n_worlds, n_aircraft), dtype=np.int64),
            los_pairs=np.empty((n_worlds, n_aircraft, n_aircraft), dtype=np.uint8),
            min_separation_nm=np.empty(n_worlds),
            steps_done=np.empty(n_worlds, dtype=np.int64),
            violated=np.empty(n_worlds, dtype=np.bool_),
            record=np.zeros((n_worlds, n_record, n_aircraft, N_RECORD)),
        )
        slot = 1 - self._newest  # the older one makes way
        self._slots[slot] = (trace, tuple(trace.__dict__.values()), key)
        self._newest = slot
        return trace


def _reference_counts(scratch: KernelScratch, slot: int) -> tuple[int, tuple[int, ...]]:
    """References to ``scratch``'s trace in ``slot`` and to each of its arrays (CPython's
    counts)."""
    trace, arrays, _ = scratch._slots[slot]
    # ``trace`` here is one reference more; ``_DROPPED_COUNTS`` is measured through this function too.
    return sys.getrefcount(trace), tuple(map(sys.getrefcount, arrays))


def _counts_when_dropped() -> tuple[int, tuple[int, ...]]:
    """``_reference_counts`` of a trace that only its scratch holds, measured rather than
    assumed (the counts an interpreter takes for arguments and locals differ by version)."""
    scratch = KernelScratch()
    scratch.trace(1, 1, 0)
    return _reference_counts(scratch, scratch._newest)


#: Reuse a dropped trace (``KernelScratch.trace``) only where reference counts say who holds
#: an object: not in a free-threaded CPython, whose counts can be deferred.
_REUSE_TRACES = getattr(sys, "_is_gil_enabled", lambda: True)()
_DROPPED_COUNTS = _counts_when_dropped()


_DEFAULT_SCRATCH = KernelScratch()


#: Shortest integration step and sub-step (``dt_s``, ``substep_s``) ``advance`` accepts, s:
#: a finer one makes a flight take absurd numbers of steps (a 3-h flight at 1 ms is already
#: 10.8 million per aircraft; SimConfig's default is 5 s, its sub-steps 0.1 s).
MIN_STEP_S = 1e-3
#: Most sub-steps of one refined integration step, ceil(dt_s / substep_s) (50 by default).
MAX_SUBSTEPS = 10_000
#: Most integration steps of one ``advance`` call (a longer flight is several calls).
MAX_STEPS_PER_CALL = 10_000_000


def steps_for(seconds: float, dt_s: float) -> int:
    """Number of integration steps of ``dt_s`` (s, at least ``MIN_STEP_S``) in ``seconds``;
    it must be a whole number of steps, and at most ``MAX_STEPS_PER_CALL``."""
    if not (math.isfinite(dt_s) and dt_s >= MIN_STEP_S):
        raise ValueError(f"dt_s = {dt_s!r}: the integration step must be a finite number >= {MIN_STEP_S} s")
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"seconds = {seconds!r}: must be a finite number >= 0")
    n_steps = round(seconds / dt_s)
    if abs(n_steps * dt_s - seconds) > 1e-6 * max(1.0, seconds):
        raise ValueError(
            f"seconds = {seconds!r} is not a whole number of integration steps of {dt_s} s; "
            f"use a multiple of {dt_s}"
        )
    if n_steps > MAX_STEPS_PER_CALL:
        raise ValueError(
            f"seconds = {seconds!r} is {n_steps} integration steps of {dt_s} s; at most {MAX_STEPS_PER_CALL} "
            "are flown in one call: advance a longer flight in several calls"
        )
    return n_steps


#: Parameters that must be > 0 (a zero or negative one divides by zero or flies backwards).
_POSITIVE_PARAMS = {
    nf.P_K: "k",
    nf.P_LENGTH: "length_scale_nm",
    nf.P_R_WORLD: "workspace radius",
    nf.P_RADIUS: "aircraft_radius_nm",
    nf.P_R_SENSE: "sensing_radius_nm",
    nf.P_X: "f_cutoff",
    nf.P_DELTA: "arrival_tolerance_nm",
    nf.P_DT: "dt_s",
    nf.P_U_CAP: "airspeed_cap_kt",
    nf.P_P_FLOOR: "p_floor",
    nf.P_GRAD_FLOOR: "grad_floor",
    nf.P_SUBSTEP: "substep_s",
}

_POSITIVE_INDEX = np.array(sorted(_POSITIVE_PARAMS))


def _check_params(params: np.ndarray) -> None:
    """The parameter vector's length, dtype and the ranges the compiled code divides by
    (the compiled code reads it unchecked: a short vector would be read out of bounds)."""
    if not isinstance(params, np.ndarray) or params.dtype != np.float64 or params.shape != (nf.N_PARAMS,):
        shape = getattr(params, "shape", None)
        dtype = getattr(params, "dtype", type(params).__name__)
        raise ValueError(
            f"params has shape {shape} and dtype {dtype}; expected ({nf.N_PARAMS},) float64 "
            "from SimConfig.to_params"
        )
    if not (np.isfinite(params).all() and (params[_POSITIVE_INDEX] > 0).all()):  # fast path: every call
        if not np.isfinite(params).all():
            raise ValueError(f"params contains NaN or inf at index {np.flatnonzero(~np.isfinite(params)).tolist()}")
        _check_step_lengths(params)  # the steps first: their message gives their whole range
        for index, name in _POSITIVE_PARAMS.items():
            if not params[index] > 0:
                raise ValueError(f"params[{index}] ({name}) = {float(params[index])!r}: must be > 0")
    _check_step_lengths(params)


def _check_step_lengths(params: np.ndarray) -> None:
    """The integration step and the sub-step (finite, > 0 already): at least ``MIN_STEP_S``,
    and at most ``MAX_SUBSTEPS`` sub-steps to a refined step."""
    for index, name in ((nf.P_DT, "dt_s"), (nf.P_SUBSTEP, "substep_s")):
        if not params[index] >= MIN_STEP_S:
            raise ValueError(
                f"params[{index}] ({name}) = {float(params[index])!r}: must be at least {MIN_STEP_S} s "
                "(a finer step would take absurd numbers of steps)"
            )
    if not params[nf.P_DT] <= MAX_SUBSTEPS * params[nf.P_SUBSTEP]:
        raise ValueError(
            f"params[{nf.P_DT}] (dt_s) = {float(params[nf.P_DT])!r} and params[{nf.P_SUBSTEP}] (substep_s) = "
            f"{float(params[nf.P_SUBSTEP])!r}: a refined step would take more than {MAX_SUBSTEPS} sub-steps; "
            f"substep_s must be at least dt_s / {MAX_SUBSTEPS}"
        )


#: The status codes of an aircraft (``S_STATUS``) and their names.
STATUS_NAMES = {FLYING: "FLYING", ARRIVED: "ARRIVED", LEFT: "LEFT", ABSENT: "ABSENT"}
_STATUS_CODES = np.array(sorted(STATUS_NAMES))


def _check_statuses(state: np.ndarray) -> None:
    """Every aircraft's ``S_STATUS`` one of the codes of ``STATUS_NAMES``."""
    status = state[:, :, S_STATUS]
    unknown = ~np.isin(status, _STATUS_CODES)
    if unknown.any():
        world, aircraft = np.argwhere(unknown)[0].tolist()
        allowed = ", ".join(f"{code!r} ({name})" for code, name in STATUS_NAMES.items())
        raise ValueError(
            f"state[{world}, {aircraft}, S_STATUS] = {float(status[world, aircraft])!r} is not an aircraft status; "
            f"allowed: {allowed}"
        )


def _check_finite_result(state: np.ndarray) -> None:
    """The kernel never hands back a non-finite state silently: that world's numbers are
    meaningless (a setting far outside the calibrated range)."""
    if not np.isfinite(state).all():
        world, aircraft = np.argwhere(~np.isfinite(state).all(axis=2))[0].tolist()
        raise FloatingPointError(
            f"the integration produced NaN or inf (world {world}, aircraft {aircraft}); "
            "the scenario or gains lie outside the range the NF is calibrated for"
        )


def _check_inputs(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind_kt: np.ndarray,
    seconds: float,
    params: np.ndarray,
    record_every: int,
) -> tuple[np.ndarray, np.ndarray, int]:
    """``advance``'s checks of its inputs, in order, raising on the first bad one; returns
    (waypoints, wind_kt as contiguous float64 arrays, number of steps)."""
    if not isinstance(state, np.ndarray):
        raise TypeError(f"state is a {type(state).__name__}; expected a numpy array (B, N, {N_STATE}) float64")
    if state.ndim != 3 or state.shape[2] != N_STATE or state.dtype != np.float64:
        raise ValueError(
            f"state has shape {state.shape} and dtype {state.dtype}; expected (B, N, {N_STATE}) float64"
        )
    if not (state.flags.c_contiguous and state.flags.writeable):
        raise ValueError("state must be a C-contiguous, writeable array: it is advanced in place")
    n_worlds, n_aircraft, _ = state.shape
    for name, array in (("waypoints", waypoints), ("wind_kt", wind_kt)):
        if np.iscomplexobj(array):
            raise ValueError(f"{name} is complex; expected real numbers")
    waypoints = np.ascontiguousarray(waypoints, dtype=np.float64)
    wind_kt = np.ascontiguousarray(wind_kt, dtype=np.float64)
    if waypoints.shape != (n_worlds, n_aircraft, 2):
        raise ValueError(
            f"waypoints has shape {waypoints.shape}; expected (B, N, 2) = ({n_worlds}, {n_aircraft}, 2)"
        )
    if wind_kt.shape != (n_worlds, 2):
        raise ValueError(f"wind_kt has shape {wind_kt.shape}; expected (B, 2) = ({n_worlds}, 2)")
    _check_params(params)
    for name, array in (("state", state), ("waypoints", waypoints), ("wind_kt", wind_kt)):
        if not np.isfinite(array).all():
            raise ValueError(f"{name} contains NaN or inf; all values must be finite")
    _check_statuses(state)
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 0:
        raise ValueError(f"record_every = {record_every!r}: must be an integer >= 0")
    return waypoints, wind_kt, steps_for(seconds, float(params[nf.P_DT]))


_FLOAT64 = np.dtype(np.float64)


def _quick_steps(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind_kt: np.ndarray,
    seconds: float,
    params: np.ndarray,
    record_every: int,
) -> int:
    """The number of steps when the inputs have the exact types, shapes and layouts
    ``advance`` needs (checked here in a few attribute look-ups), else −1: then
    ``_check_inputs`` checks everything (and raises on what is wrong). Never raises.
    The values themselves (finite, params in range) are checked in compiled code."""
    if not (
        type(state) is np.ndarray
        and type(waypoints) is np.ndarray
        and type(wind_kt) is np.ndarray
        and type(params) is np.ndarray
        and type(record_every) is int
        and record_every >= 0
        and state.dtype is _FLOAT64
        and waypoints.dtype is _FLOAT64
        and wind_kt.dtype is _FLOAT64
        and params.dtype is _FLOAT64
        and state.ndim == 3
        and state.shape[2] == N_STATE
        and waypoints.shape == (state.shape[0], state.shape[1], 2)
        and wind_kt.shape == (state.shape[0], 2)
        and params.shape == (nf.N_PARAMS,)
        and state.flags.c_contiguous
        and state.flags.writeable
        and waypoints.flags.c_contiguous
        and wind_kt.flags.c_contiguous
    ):
        return -1
    key = (seconds, params[nf.P_DT])
    n_steps = _STEPS_SEEN.get(key, -1) if type(seconds) is float else -1
    if n_steps < 0 and 0.0 < key[1] < math.inf:
        try:
            n_steps = steps_for(seconds, float(key[1]))
        except (TypeError, ValueError):
            return -1
        if type(seconds) is float and len(_STEPS_SEEN) < 64:
            _STEPS_SEEN[key] = n_steps
    return n_steps


#: ``steps_for`` of the (seconds, dt) pairs seen (callers use one or two durations).
_STEPS_SEEN: dict[tuple[float, float], int] = {}


#: About how long each entry's first compilation takes on one core when it is the first in
#: the process, s: the notice's estimate (``bench/bench_compile.py`` measured 12, 16 and 31 s
#: of CPU; a path compiled after another reuses the scalar path's functions).
_FIRST_COMPILE_S = {"_advance_checked_one": 12, "_advance_checked_batch": 15, "_advance_checked_lanes": 30}
#: The same for the one-world and the batch paths compiled one after the other in one process
#: (``load_paths`` for a law whose k is not 2).
_ALL_PATHS_COMPILE_S = 20
#: Whether this process flies every batch size on the lane path (set by ``load_paths``).
_lanes_for_every_size = False
#: The estimate the notice gives while ``load_paths`` compiles every path (None otherwise).
_notice_estimate_s: float | None = None
#: The entries ``advance`` has called in this process (their notice is given or not needed).
_ENTRIES_CALLED: set = set()
#: Whether this process printed the compile notice.
_NOTICE_GIVEN = False


def will_compile(dispatcher, arguments: tuple) -> bool:
    """Whether calling the numba ``dispatcher`` on ``arguments`` compiles it: no overload for
    their types in this process, nor in numba's on-disk cache. False where numba's cache
    cannot be inspected (its private interface moved: ``tests/test_kernel_compile.py``
    pins it), so that a warm start never prints a false notice."""
    try:
        types = tuple(dispatcher.typeof_pyval(argument) for argument in arguments)
        if types in dispatcher.overloads:
            return False
        cache = dispatcher._cache
        if not hasattr(cache, "_cache_file"):
            return True  # a function compiled without cache=True
        key = cache._index_key(types, dispatcher.targetctx.codegen())
        return key not in cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - any failure of numba's private interface
        return False


def compile_notice(dispatcher, arguments: tuple, estimate_s: float) -> None:
    """One line on stderr before the first call of ``dispatcher`` on ``arguments`` that
    compiles it (``will_compile``), at most once per process: the first run sits through
    numba's compilation of the simulator (``estimate_s``, s, on an idle core), later runs
    load it from numba's cache."""
    global _NOTICE_GIVEN
    if _NOTICE_GIVEN or not will_compile(dispatcher, arguments):
        return
    _NOTICE_GIVEN = True
    print(f"compiling the simulator (first run only, about {estimate_s:.0f} s)…", file=sys.stderr, flush=True)


def lane_chunk(n_worlds: int) -> int:
    """Worlds per chunk when the lane path flies ``n_worlds`` worlds: ``LANE_CHUNK``, or
    fewer so that a batch smaller than ``LANE_CHUNK`` per thread still spreads over numba's
    threads (a chunk is one thread's work; the chunking changes no world's bits)."""
    return max(1, min(LANE_CHUNK, -(-n_worlds // get_num_threads())))


def load_paths(world: np.ndarray, params: np.ndarray) -> None:
    """Compile (or load from numba's cache) what ``advance`` needs for batches of any size
    of worlds like ``world`` (N, N_STATE) flown with ``params``, by flying one integration
    step of copies of it under no wind. A policy that flies batches of every size (the
    MPC's candidates) calls it when reset, so that no compilation falls into a timed
    decision.

    With the law's k = 2 (the paper's), the process flies every batch size on the lane
    path from then on, one world included: one compiled path instead of three
    (``bench/bench_compile.py`` measures the first run's compilation), one world at about
    the speed of its own path, and a world flies the same bits on every path. Otherwise it compiles the one-world and
    the batch paths. Paths already compiled in this process cost nothing."""
    global _notice_estimate_s, _lanes_for_every_size
    if params[nf.P_K] == 2.0:
        _lanes_for_every_size = True
        sizes: tuple[int, ...] = (1,)
        if _advance_checked_lanes in _ENTRIES_CALLED:
            return
    else:
        sizes = (1, 2)
        if {_advance_checked_one, _advance_checked_batch} <= _ENTRIES_CALLED:
            return
    dt_s = float(params[nf.P_DT])
    _notice_estimate_s = _FIRST_COMPILE_S["_advance_checked_lanes"] if sizes == (1,) else _ALL_PATHS_COMPILE_S
    try:
        for n_worlds in sizes:
            states = np.repeat(np.ascontiguousarray(world, dtype=np.float64)[None], n_worlds, axis=0)
            advance(states, states[:, :, S_WP_X : S_WP_Y + 1].copy(), np.zeros((n_worlds, 2)), dt_s, params)
    finally:
        _notice_estimate_s = None


def advance(
    state: np.ndarray,
    waypoints: np.ndarray,
    wind_kt: np.ndarray,
    seconds: float,
    params: np.ndarray,
    *,
    record_every: int = 0,
    scratch: KernelScratch | None = None,
) -> Trace:
    """Advance B worlds of N aircraft by ``seconds`` under the NF law, in place.

    Args:
        state: (B, N, N_STATE) float64, modified in place (see ``S_*``; positions nm,
            headings rad, airspeeds kt, times s).
        waypoints: (B, N, 2) current waypoint of every aircraft, nm. A waypoint that
            differs from the stored one is a switch (θ_d is set then).
        wind_kt: (B, 2) constant wind of each world, kt (east, north).
        seconds: duration, s; a whole number of integration steps.
        params: parameter vector from ``SimConfig.to_params``.
        record_every: record the state every this many steps (0: no recording).
        scratch: reusable buffers (a module-level one by default; pass your own when
            calling from several threads).

    The first call of each path in a process (one world, a batch below ``LANE_MIN_WORLDS``
    worlds, a larger one, or after ``load_paths`` the lane path for every size) compiles it, or loads it from numba's on-disk cache; a compilation
    that will happen is announced by one line on stderr, once per process (``compile_notice``).

    Returns:
        The ``Trace`` of the call: new arrays, or those of an earlier trace of the same
        scratch and shapes that nothing refers to any more (``KernelScratch.trace``), which
        no one can tell apart. A trace you keep is never written again.

    Raises:
        TypeError: if ``state`` is not a numpy array.
        ValueError: on a wrong shape, dtype or layout, a params vector of the wrong
            length or with a non-positive scale, an integration step or sub-step shorter
            than ``MIN_STEP_S`` (or more than ``MAX_SUBSTEPS`` sub-steps to a step), a
            duration that is not a whole number of steps or longer than
            ``MAX_STEPS_PER_CALL`` of them, an aircraft status that is not one of
            ``STATUS_NAMES``, or a NaN/inf in any input.
        FloatingPointError: if the integration produced a non-finite state.
    """
    n_steps = _quick_steps(state, waypoints, wind_kt, seconds, params, record_every)
    if n_steps < 0:
        waypoints, wind_kt, n_steps = _check_inputs(state, waypoints, wind_kt, seconds, params, record_every)
    n_worlds, n_aircraft, _ = state.shape
    scratch = scratch or _DEFAULT_SCRATCH
    on_lanes = params[nf.P_K] == 2.0 and (n_worlds >= LANE_MIN_WORLDS or _lanes_for_every_size)
    chunk = lane_chunk(n_worlds) if on_lanes else 0
    grad, command, aircraft_lanes = scratch.get(n_worlds, n_aircraft, chunk)
    trace = scratch.trace(n_worlds, n_aircraft, n_steps // record_every + 1 if record_every > 0 else 0)
    arguments = (
        state, waypoints, wind_kt, n_steps, params, grad, command, aircraft_lanes, trace.min_airspeed_kt,
        trace.max_airspeed_kt, trace.violation_steps, trace.worst_excursion_kt, trace.steps_flown, trace.los_pairs,
        trace.min_separation_nm, trace.steps_done, trace.violated, trace.record, max(record_every, 1), scratch.cells,
    )
    if on_lanes:
        entry = _advance_checked_lanes
        arguments = (*arguments[:-1], scratch.lanes, scratch.lane_temp, scratch.lane_world, chunk, scratch.cells)
    elif n_worlds == 1:
        entry = _advance_checked_one
    else:
        entry = _advance_checked_batch
    if entry not in _ENTRIES_CALLED:
        compile_notice(entry, arguments, _notice_estimate_s or _FIRST_COMPILE_S[entry.__name__])
        _ENTRIES_CALLED.add(entry)
    outcome = entry(*arguments)
    if outcome == _BAD_INPUT:
        _check_inputs(state, waypoints, wind_kt, seconds, params, record_every)  # raises, naming the input
        raise AssertionError("the compiled and the Python checks of advance's inputs disagree")
    if outcome == _NON_FINITE_RESULT:
        _check_finite_result(state)  # raises, naming the world and the aircraft
        raise AssertionError("the compiled and the Python checks of advance's result disagree")
    return trace


def new_state(n_worlds: int, n_aircraft: int) -> np.ndarray:
    """An empty state: every slot ABSENT."""
    state = np.zeros((n_worlds, n_aircraft, N_STATE))
    state[:, :, S_STATUS] = ABSENT
    return state


__all__ = [
    "ARRIVED",
    "ABSENT",
    "FLYING",
    "LEFT",
    "Trace",
    "KernelScratch",
    "advance",
    "compile_notice",
    "will_compile",
    "MIN_STEP_S",
    "MAX_SUBSTEPS",
    "MAX_STEPS_PER_CALL",
    "STATUS_NAMES",
    "new_state",
    "steps_for",
]
