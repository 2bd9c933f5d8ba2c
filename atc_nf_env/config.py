"""Gains and settings of the navigation-function controller and the integrator.

The defaults are the calibrated ones: ``atc_nf_env.calibration`` derives k_u and k_z
from the speed targets and checks the envelope over the workspace; the integration
step comes from the convergence study in ``bench/integration_step_study.py``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from atc_nf_env import nf
from atc_nf_env.units import (
    AIRCRAFT_RADIUS_NM,
    AIRSPEED_MAX_KT,
    AIRSPEED_MIN_KT,
    SEPARATION_MIN_NM,
)


@dataclass(frozen=True)
class SimConfig:
    """Settings of the NF control law (5a)-(5b) and of the integrator.

    Attributes:
        k: exponent of the NF (2); 2 makes the unobstructed gradient nearly constant
            along the dipole axis, which is what lets a waypoint ~100 nm ahead hold a
            steady airspeed.
        eps_nh: ε_nh of (3), in units of L² (sets where the approach slows: ~√ε_nh·L).
        length_scale_nm: L, the unit of length inside the NF, nm.
        k_u: gain of ‖∇Φ‖² in F_i, kt.
        k_z: gain of ‖q − q_d‖² (in units of L²) in F_i, kt.
        k_theta: heading gain k_θ of (5b), 1/s.
        sensing_radius_nm: centre-to-centre distance beyond which a neighbour does not
            enter G_i, nm.
        f_a0: f_i(0), in units of L².
        f_cutoff: X, f_i vanishes for G_i ≥ X (dimensionless, G_i ∈ [0, 1]).
        arrival_tolerance_nm: Δ, an aircraft within Δ of its destination has arrived, nm.
        dt_s: integration step, s.
        airspeed_min_kt, airspeed_max_kt: the airspeed envelope, kt.
        separation_min_nm: the separation minimum, nm (a loss of separation below it).
        aircraft_radius_nm: r_i, nm.
        airspeed_cap_kt: saturation of the commanded airspeed, kt. A guard: the 1/P_i
            term of (5a) is unbounded as P_i → 0; the cap keeps positions finite and,
            being far outside the envelope, changes no feasibility verdict.
        p_floor: floor on ``|P_i|`` (units of 1/L) in the 1/P_i term of (5a) (guard).
        grad_floor: below this ‖∇Φ_i‖ (units of 1/L) θ_nh is taken as θ_d (guard; the
            paper's rule at q_i = q_d, extended to where the gradient has no direction).
        dphi_dt_gain: weight of ∂Φ_i/∂t in (5a) (1: the paper's law).
        substep_s: longest sub-step, s, of an integration step in which a command
            saturates at ``airspeed_cap_kt`` or the 1/P_i term of (5a) exceeds
            ``substep_from_kt`` (the law's singularity, kernel guard 8): such a step is
            flown in ceil(dt_s / substep_s) sub-steps.
        substep_from_kt: the 1/P_i term of (5a), kt, above which a step is flown in
            sub-steps (guard 8), so that the right-hand rule's ramp (from
            ``right_turn_from_kt``) is entered at the sub-step's resolution whatever dt is.
        step_tolerance_nm: error control of the steps among neighbours (kernel guard 10):
            a step with two aircraft within the sensing radius at its start or its end is
            flown in as many sub-steps (at most ceil(dt_s / substep_s)) as bring its
            estimated local position error within this, nm; 0 turns the estimate off (the
            step is then refined only where its end asks for it, guard 8).
        right_turn_deg: the right-hand rule at the law's singularity (kernel guard 9):
            where the 1/P_i term of (5a) exceeds ``right_turn_from_kt`` the desired
            heading θ_nh is turned to the right, by this angle, deg, once the term reaches
            ``right_turn_full_kt`` (smoothly in between); 0 turns the rule off.
        right_turn_from_kt, right_turn_full_kt: where the rule starts to act and where
            it acts in full, kt of the 1/P_i term.
    """

    k: float = 2.0
    eps_nh: float = 0.4
    length_scale_nm: float = 100.0
    k_u: float = 80714.74301826005  # = calibration.calibrate().k_u (checked by a test)
    k_z: float = 30.0
    k_theta: float = 1.0 / 30.0
    sensing_radius_nm: float = 12.0
    barrier_nm: float = 7.0
    f_a0: float = 0.01
    f_cutoff: float = 0.5
    arrival_tolerance_nm: float = 5.0
    dt_s: float = 5.0
    airspeed_min_kt: float = AIRSPEED_MIN_KT
    airspeed_max_kt: float = AIRSPEED_MAX_KT
    separation_min_nm: float = SEPARATION_MIN_NM
    aircraft_radius_nm: float = AIRCRAFT_RADIUS_NM
    airspeed_cap_kt: float = 1500.0
    p_floor: float = 1e-9
    grad_floor: float = 1e-12
    dphi_dt_gain: float = 1.0
    substep_s: float = 0.1
    substep_from_kt: float = 50.0
    step_tolerance_nm: float = 0.002
    right_turn_deg: float = 45.0
    right_turn_from_kt: float = 200.0
    right_turn_full_kt: float = 800.0

    def __post_init__(self) -> None:
        for field in fields(self):
            value = getattr(self, field.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"SimConfig.{field.name} = {value!r}: must be a finite number")
        positive = (
            "k", "eps_nh", "length_scale_nm", "k_theta", "sensing_radius_nm", "barrier_nm", "f_cutoff",
            "arrival_tolerance_nm", "dt_s", "aircraft_radius_nm", "airspeed_cap_kt",
            "p_floor", "grad_floor", "separation_min_nm", "substep_s", "substep_from_kt",
        )
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"SimConfig.{name} = {getattr(self, name)!r}: must be > 0")
        for name in ("k_u", "k_z", "f_a0", "step_tolerance_nm"):
            if getattr(self, name) < 0:
                raise ValueError(f"SimConfig.{name} = {getattr(self, name)!r}: must be >= 0")
        if not 0 <= self.right_turn_deg <= 180:
            raise ValueError(f"SimConfig.right_turn_deg = {self.right_turn_deg!r}: must lie in [0, 180]")
        if not 0 <= self.right_turn_from_kt < self.right_turn_full_kt:
            raise ValueError(
                f"SimConfig: need 0 <= right_turn_from_kt < right_turn_full_kt, got "
                f"{self.right_turn_from_kt}, {self.right_turn_full_kt}"
            )
        if self.sensing_radius_nm <= 2 * self.aircraft_radius_nm:
            raise ValueError(
                f"SimConfig.sensing_radius_nm = {self.sensing_radius_nm!r}: must exceed the "
                f"contact distance 2 * aircraft_radius_nm = {2 * self.aircraft_radius_nm}"
            )
        if not 2 * self.aircraft_radius_nm < self.barrier_nm < self.sensing_radius_nm:
            raise ValueError(
                f"SimConfig.barrier_nm = {self.barrier_nm!r}: must lie between the contact distance "
                f"{2 * self.aircraft_radius_nm} nm and sensing_radius_nm = {self.sensing_radius_nm}"
            )
        if not 0 < self.airspeed_min_kt < self.airspeed_max_kt < self.airspeed_cap_kt:
            raise ValueError(
                "SimConfig: need 0 < airspeed_min_kt < airspeed_max_kt < airspeed_cap_kt, got "
                f"{self.airspeed_min_kt}, {self.airspeed_max_kt}, {self.airspeed_cap_kt}"
            )

    @classmethod
    def preset(cls, name: str) -> "SimConfig":
        """A named physics: ``"default"`` (the calibrated defaults) or ``"paper-nf"``.

        ``"paper-nf"`` widens the proximity range to sensing 30 nm / barrier 15 nm, the
        range whose NF alone keeps the paper's 22 nm between 4 converging aircraft
        without wind (``python -m atc_nf_env.experiments.proximity_range``, table in
        REPRODUCTION.md). Everything else is the default.
        """
        if not isinstance(name, str) or name not in PHYSICS_PRESETS:
            raise ValueError(f"physics {name!r}: allowed: {', '.join(PHYSICS_PRESETS)}")
        return cls(**PHYSICS_PRESETS[name])

    def replace(self, **changes: Any) -> "SimConfig":
        """A copy with some fields changed (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(
                f"SimConfig has no field {sorted(unknown)}; fields: {[f.name for f in fields(self)]}"
            )
        return replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def to_params(self, workspace_radius_nm: float, stop_on_violation: bool = False) -> np.ndarray:
        """The float64 parameter vector read by the compiled NF and kernel."""
        params = np.zeros(nf.N_PARAMS)
        params[nf.P_K] = self.k
        params[nf.P_EPS_NH] = self.eps_nh
        params[nf.P_LENGTH] = self.length_scale_nm
        params[nf.P_K_U] = self.k_u
        params[nf.P_K_Z] = self.k_z
        params[nf.P_K_THETA] = self.k_theta
        params[nf.P_R_WORLD] = workspace_radius_nm
        params[nf.P_RADIUS] = self.aircraft_radius_nm
        params[nf.P_R_SENSE] = self.sensing_radius_nm
        params[nf.P_BARRIER] = self.barrier_nm
        params[nf.P_A0] = self.f_a0
        params[nf.P_X] = self.f_cutoff
        params[nf.P_DELTA] = self.arrival_tolerance_nm
        params[nf.P_DT] = self.dt_s
        params[nf.P_U_MIN] = self.airspeed_min_kt
        params[nf.P_U_MAX] = self.airspeed_max_kt
        params[nf.P_SEP_MIN] = self.separation_min_nm
        params[nf.P_U_CAP] = self.airspeed_cap_kt
        params[nf.P_STOP_ON_VIOLATION] = 1.0 if stop_on_violation else 0.0
        params[nf.P_P_FLOOR] = self.p_floor
        params[nf.P_GRAD_FLOOR] = self.grad_floor
        params[nf.P_DPHI_DT_GAIN] = self.dphi_dt_gain
        params[nf.P_SUBSTEP] = self.substep_s
        params[nf.P_SUBSTEP_FROM] = self.substep_from_kt
        params[nf.P_STEP_TOLERANCE] = self.step_tolerance_nm
        params[nf.P_RIGHT_TURN] = math.radians(self.right_turn_deg)
        params[nf.P_RIGHT_TURN_FROM] = self.right_turn_from_kt
        params[nf.P_RIGHT_TURN_FULL] = self.right_turn_full_kt
        return params


#: Named physics for ``SimConfig.preset`` and ``--physics``: field overrides of the defaults.
PHYSICS_PRESETS: dict[str, dict[str, float]] = {
    "default": {},
    "paper-nf": {"sensing_radius_nm": 30.0, "barrier_nm": 15.0},
}


# --------------------------------------------------------------------------- memory bounds
#
# A world of N aircraft holds, while it flies, the kernel's pairwise scratch: the gradient
# of every aircraft's NF with respect to every other, (N, N, 2) float64 (``KernelScratch.grad``),
# and the loss-of-separation pairs, (N, N) uint8 (``Trace.los_pairs``): 17 N² bytes. Beyond
# it each aircraft holds its state, waypoints, the kernel's command and lane scratch, the
# trace's figures, and in the envs its observation, info arrays and spaces: 2.1-2.3 kB
# measured with tracemalloc (the vector env, 256 worlds of 4, 40 and 120 aircraft, after
# two steps), taken twice here. The bounds below refuse, before anything is allocated, what
# a 24-GiB machine cannot hold beside everything else a study runs.

#: Bytes of pairwise scratch per pair of aircraft slots of one world (16 + 1).
PAIRWISE_BYTES: int = 2 * 8 + 1
#: Bytes per aircraft slot of one world beyond the pairwise scratch (twice the 2.1-2.3 kB measured).
PER_AIRCRAFT_BYTES: int = 4096
#: Most memory one world may hold, bytes: 1 GiB. A study flies one world in each worker
#: process, beside its recording, the policy and the tables; at 1 GiB a world, a study on
#: every core of a 16-core machine still leaves a third of 24 GiB free.
WORLD_MEMORY_BYTES: int = 2**30
#: Most memory the worlds of one batch may hold, bytes: 8 GiB, a third of a 24-GiB machine.
#: A batch is flown in one kernel call: the B worlds of a vector env (``EncounterVectorEnv``,
#: ``SB3VecEnv``, TorchRL's ``AtcNfBatchedEnv``) or the K candidate worlds of the MPC.
BATCH_MEMORY_BYTES: int = 8 * 2**30


def world_memory_bytes(n_aircraft: int) -> int:
    """An upper estimate of the bytes one world of ``n_aircraft`` slots holds while it
    flies (see the notes above ``PAIRWISE_BYTES``)."""
    n = int(n_aircraft)
    return PAIRWISE_BYTES * n * n + PER_AIRCRAFT_BYTES * n


def _largest_within(budget_bytes: int) -> int:
    """The most aircraft slots one world may have for ``world_memory_bytes`` to stay within
    ``budget_bytes``."""
    a, b = PAIRWISE_BYTES, PER_AIRCRAFT_BYTES
    n = int((-b + math.sqrt(b * b + 4.0 * a * budget_bytes)) / (2.0 * a))
    while world_memory_bytes(n + 1) <= budget_bytes:
        n += 1
    while world_memory_bytes(n) > budget_bytes:
        n -= 1
    return n


#: Most aircraft (slots) of one world: ``world_memory_bytes`` within ``WORLD_MEMORY_BYTES``
#: (7 827: 1.04 GB of pairwise scratch).
MAX_AIRCRAFT: int = _largest_within(WORLD_MEMORY_BYTES)


def check_aircraft_count(n_aircraft: int, name: str = "number of aircraft") -> int:
    """``n_aircraft`` if one world of that many slots fits ``WORLD_MEMORY_BYTES``, else
    ValueError naming ``name``, the bound and why."""
    if n_aircraft > MAX_AIRCRAFT:
        raise ValueError(
            f"{name} = {n_aircraft}: at most {MAX_AIRCRAFT} aircraft in one world (its kernel scratch grows as "
            f"{PAIRWISE_BYTES} N² bytes; {n_aircraft} would need about {world_memory_bytes(n_aircraft) / 2**30:.1f} "
            f"GiB, the bound is {WORLD_MEMORY_BYTES / 2**30:g} GiB)"
        )
    return int(n_aircraft)


def max_batch_worlds(n_aircraft: int) -> int:
    """Most worlds of ``n_aircraft`` slots one batch may fly: ``BATCH_MEMORY_BYTES`` over
    ``world_memory_bytes``."""
    return max(1, BATCH_MEMORY_BYTES // world_memory_bytes(max(int(n_aircraft), 1)))


def check_batch_size(n_worlds: int, n_aircraft: int, name: str) -> int:
    """``n_worlds`` if that many worlds of ``n_aircraft`` slots fit ``BATCH_MEMORY_BYTES``,
    else ValueError naming ``name``, the bound for this many aircraft and why."""
    most = max_batch_worlds(n_aircraft)
    if n_worlds > most:
        raise ValueError(
            f"{name} = {n_worlds}: at most {most} worlds of {n_aircraft} aircraft in one batch (about "
            f"{world_memory_bytes(n_aircraft) / 1024:.1f} KiB each; {n_worlds} would need "
            f"{n_worlds * world_memory_bytes(n_aircraft) / 2**30:.1f} GiB, the bound is "
            f"{BATCH_MEMORY_BYTES / 2**30:g} GiB)"
        )
    return int(n_worlds)
