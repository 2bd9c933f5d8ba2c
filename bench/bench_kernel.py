"""Kernel throughput: aircraft-integration-steps per second, against a frozen yardstick.

B worlds of the converging-N encounter flown for one 5-min period (all aircraft
flying, the NF alone aimed at the destinations, neighbour terms active from the
start only where aircraft are close), by the package's kernel and by the frozen copy
of the kernel before its performance work (``bench/yardstick.py`` rebuilds it from git
history: the yardstick of the speed-up), both
through ``advance`` with its entry checks. The two are measured interleaved in rounds
within one process; reported are the medians over rounds of B · N · steps / wall
time and the median of the per-round ratios current / frozen. The first call of each
(numba compilation, or loading numba's on-disk cache) is timed apart.

The scaling table (``--scaling``): the cost of an aircraft-step as N grows from 4 to 100
at a fixed density of traffic, with the neighbour grid and with the loops over all pairs
side by side (``kernel.KernelScratch(neighbour_search=...)``, the same bits either way).
Each N flies random encounters (``scenarios.random_encounter``) on a circle whose radius
grows as √N from random-8's 250 nm, so that the aircraft per unit area stay random-8's, in
a workspace six times that radius (at least the default 1500 nm); each is first flown to
80 % of the way to the circle's centre at the nominal airspeed, where the traffic crosses,
and the period from there is timed, one world (B = 1) and a batch of 16 (the lane path).
CPU time of the process (all threads), so that other processes' load moves it less.

Run: python bench/bench_kernel.py [--write]; python bench/bench_kernel.py --scaling [--write]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from types import ModuleType

import numpy as np
from _report import machine, publish  # bench/ is on sys.path when run as a script
from yardstick import frozen_kernel

import numba

from atc_nf_env import kernel as current
from atc_nf_env import nf, trig
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import ENCOUNTER_RADIUS_NM, WORKSPACE_RADIUS_NM, Scenario, converging, random_encounter
from atc_nf_env.simulation import initial_state
from atc_nf_env.units import DECISION_PERIOD_S

KERNELS: dict[str, ModuleType] = {"frozen": frozen_kernel(), "current": current}


def start_state(module: ModuleType, scenario: Scenario, n_worlds: int) -> np.ndarray:
    """The scenario's state at t = 0 in ``module``'s layout (its ``S_*`` fields)."""
    state = module.new_state(n_worlds, scenario.n_aircraft)
    fields = {
        "S_X": scenario.start_xy[:, 0],
        "S_Y": scenario.start_xy[:, 1],
        "S_HEADING": scenario.start_heading,
        "S_THETA_NH": scenario.start_heading,
        "S_AIRSPEED": scenario.start_airspeed_kt,
        "S_DEST_X": scenario.dest_xy[:, 0],
        "S_DEST_Y": scenario.dest_xy[:, 1],
        "S_DEST_HEADING": scenario.dest_heading,
        "S_WP_X": scenario.dest_xy[:, 0],
        "S_WP_Y": scenario.dest_xy[:, 1],
        "S_THETA_D": scenario.dest_heading,
        "S_COS_D": np.cos(scenario.dest_heading),
        "S_SIN_D": np.sin(scenario.dest_heading),
        "S_FRESH": 1.0,
        "S_STATUS": module.FLYING,
    }
    for name, value in fields.items():
        state[:, :, getattr(module, name)] = value
    return state


class Case:
    """One kernel flying B worlds of converging-N for one period per call."""

    def __init__(self, module: ModuleType, n_worlds: int, n_aircraft: int) -> None:
        config = SimConfig()
        scenario = converging(n_aircraft)
        self.module = module
        self.params = np.ascontiguousarray(
            config.to_params(scenario.workspace_radius_nm)[: module.nf.N_PARAMS]
        )
        self.start = start_state(module, scenario, n_worlds)
        self.waypoints = np.repeat(scenario.dest_xy[None], n_worlds, axis=0)
        self.wind = np.random.default_rng(0).normal(0.0, 10.0, (n_worlds, 2))
        self.scratch = module.KernelScratch()
        self.n_steps = module.steps_for(DECISION_PERIOD_S, config.dt_s)
        self.aircraft_steps = n_worlds * n_aircraft * self.n_steps

    def seconds(self, state: np.ndarray) -> float:
        """Wall time of one call from ``state`` (a fresh copy of the start)."""
        t0 = time.perf_counter()
        trace = self.module.advance(
            state, self.waypoints, self.wind, DECISION_PERIOD_S, self.params, scratch=self.scratch
        )
        elapsed = time.perf_counter() - t0
        if not (trace.steps_done == self.n_steps).all():
            raise RuntimeError("a world stopped early: the benchmark would not measure full periods")
        return elapsed


@numba.njit(cache=True, fastmath=nf.FAST_MATH_FLAGS, error_model="numpy")
def _inlined_trig(x: np.ndarray, y: np.ndarray, heading: np.ndarray, out: np.ndarray) -> None:
    """The law's atan2 of the gradient (θ_nh) and sincos of the heading per element, with
    the kernel's own functions (``atc_nf_env.trig``) inlined at numba's level, as the lane
    step's loops over worlds inline them."""
    for k in range(x.shape[0]):
        s, c = trig.poly_sincos_inlined(heading[k])
        out[k] = trig.poly_atan2_inlined(y[k], x[k]) + c + s


@numba.njit(cache=True, fastmath=nf.FAST_MATH_FLAGS, error_model="numpy")
def _called_trig(x: np.ndarray, y: np.ndarray, heading: np.ndarray, out: np.ndarray) -> None:
    """The same with the kernel's own functions called (numba functions compiled on their
    own, not inlined at numba's level), as the lane step called them before it inlined them."""
    for k in range(x.shape[0]):
        s, c = trig.poly_sincos(heading[k])
        out[k] = trig.poly_atan2(y[k], x[k]) + c + s


@numba.njit(cache=True, fastmath=nf.FAST_MATH_FLAGS, error_model="numpy")
def _libm_trig(x: np.ndarray, y: np.ndarray, heading: np.ndarray, out: np.ndarray) -> None:
    """The same with libm's atan2, cos and sin (one sincos call), which the kernel called
    before it had its own."""
    for k in range(x.shape[0]):
        out[k] = math.atan2(y[k], x[k]) + math.cos(heading[k]) + math.sin(heading[k])


def transcendental_floor(rounds: int) -> dict[str, float]:
    """Single-threaded: ns per aircraft-step of the current kernel (B = 1000, N = 4) and ns
    of the law's atan2 and sincos per aircraft-step, the kernel's own and libm's, timed
    alternately (medians over rounds)."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        case = Case(current, 1000, 4)
        # The arguments the kernel meets: the headings of the benchmark's own flight, and a
        # gradient direction near each (the gradient's scale does not matter to atan2).
        trace = current.advance(case.start.copy(), case.waypoints, case.wind, DECISION_PERIOD_S, case.params,
                                record_every=1)
        heading = np.ascontiguousarray(trace.record[:, 1:, :, current.R_HEADING].reshape(-1))
        offset = np.random.default_rng(1).normal(0.0, 0.2, heading.shape)
        x, y = 0.3 * np.cos(heading + offset), 0.3 * np.sin(heading + offset)
        out = np.empty_like(heading)
        loops = {"inlined_ns": _inlined_trig, "called_ns": _called_trig, "libm_ns": _libm_trig}
        for loop in loops.values():
            loop(x, y, heading, out)
        case.seconds(case.start.copy())
        times: dict[str, list[float]] = {"step_ns": [], **{name: [] for name in loops}}
        for _ in range(rounds):
            times["step_ns"].append(case.seconds(case.start.copy()) / case.aircraft_steps * 1e9)
            for name, loop in loops.items():
                t0 = time.perf_counter()
                loop(x, y, heading, out)
                times[name].append((time.perf_counter() - t0) / case.aircraft_steps * 1e9)
    finally:
        numba.set_num_threads(threads)
    return {name: statistics.median(values) for name, values in times.items()}


def first_call_seconds() -> dict[str, float]:
    """Wall time of each kernel's first calls in this process (B = 1 and B = 2, the serial
    and the parallel entry): numba compilation, or loading its on-disk cache."""
    result = {}
    for name, module in KERNELS.items():
        t0 = time.perf_counter()
        for n_worlds in (1, 2):
            case = Case(module, n_worlds, 4)
            case.seconds(case.start.copy())
        result[name] = time.perf_counter() - t0
    return result


def measure(n_worlds: int, n_aircraft: int, rounds: int) -> dict[str, float]:
    """Median rates (aircraft-steps/s) of both kernels, the median per-round ratio current /
    frozen and its quartiles ("q1", "q3")."""
    cases = {name: Case(module, n_worlds, n_aircraft) for name, module in KERNELS.items()}
    # Enough calls per round for ~10 ms of work, the two kernels' calls alternating one
    # by one (the first of each pair alternating between rounds), from fresh copies of
    # the start made outside the timed region.
    calls = max(1, round(250_000 / cases["current"].aircraft_steps))
    for case in cases.values():
        case.seconds(case.start.copy())  # warm the scratch and the caches
    rates: dict[str, list[float]] = {name: [] for name in cases}
    for r in range(rounds):
        order = list(cases) if r % 2 == 0 else list(reversed(cases))
        states = {name: [cases[name].start.copy() for _ in range(calls)] for name in order}
        elapsed = dict.fromkeys(order, 0.0)
        for k in range(calls):
            for name in order if k % 2 == 0 else reversed(order):
                elapsed[name] += cases[name].seconds(states[name][k])
        for name in order:
            rates[name].append(calls * cases[name].aircraft_steps / elapsed[name])
    ratios = [c / f for c, f in zip(rates["current"], rates["frozen"])]
    q1, _, q3 = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else (ratios[0],) * 3
    return {
        "frozen": statistics.median(rates["frozen"]),
        "current": statistics.median(rates["current"]),
        "ratio": statistics.median(ratios),
        "q1": q1,
        "q3": q3,
    }


#: Aircraft per world of the scaling table.
SCALING_N = (4, 8, 16, 32, 64, 100)
#: Worlds per call of the scaling table: one world, and a batch on the lane path.
SCALING_B = (1, 16)
#: Aircraft of the encounter whose density every row keeps (random-8 on its default circle).
DENSITY_OF = 8
#: Nominal airspeed used to place the traffic where it crosses, kt.
_NOMINAL_KT = 450.0


def dense_encounter(n_aircraft: int, seed: int) -> Scenario:
    """random-N at random-8's density: its circle's radius 250 nm · √(N / 8), the workspace
    six times that (at least the default)."""
    radius = ENCOUNTER_RADIUS_NM * math.sqrt(n_aircraft / DENSITY_OF)
    return random_encounter(n_aircraft, seed, radius_nm=radius,
                            workspace_radius_nm=max(WORKSPACE_RADIUS_NM, 6.0 * radius))


class ScalingCase:
    """B copies of one dense encounter, flown to where its traffic crosses; one period per call."""

    def __init__(self, n_worlds: int, n_aircraft: int, seed: int) -> None:
        config = SimConfig()
        scenario = dense_encounter(n_aircraft, seed)
        self.params = config.to_params(scenario.workspace_radius_nm)
        self.waypoints = np.repeat(scenario.dest_xy[None], n_worlds, axis=0)
        self.wind = np.random.default_rng(seed).normal(0.0, 10.0, (n_worlds, 2))
        radius = ENCOUNTER_RADIUS_NM * math.sqrt(n_aircraft / DENSITY_OF)
        approach_s = round(0.8 * radius / _NOMINAL_KT * 3600.0 / DECISION_PERIOD_S) * DECISION_PERIOD_S
        self.start = initial_state(scenario, n_worlds)
        current.advance(self.start, self.waypoints, self.wind, float(approach_s), self.params,
                        scratch=current.KernelScratch("grid"))
        self.scratch = {search: current.KernelScratch(search) for search in ("all_pairs", "grid")}
        # Aircraft-steps and aircraft-sub-steps (the law's evaluations) of the timed period,
        # counted on a copy flown one step at a time (the same bits as one call).
        state = self.start.copy()
        self.aircraft_steps = 0
        self.evaluations = 0
        dt = config.dt_s
        for _ in range(current.steps_for(DECISION_PERIOD_S, dt)):
            trace = current.advance(state, self.waypoints, self.wind, dt, self.params, scratch=self.scratch["grid"])
            flew = trace.steps_flown > 0
            self.aircraft_steps += int(flew.sum())
            self.evaluations += int((np.maximum(state[:, :, current.S_LAST_SUBSTEPS], 1.0) * flew).sum())

    def cpu_seconds(self, search: str) -> float:
        """CPU time of the process for one period from a fresh copy of the start."""
        state = self.start.copy()
        t0 = time.process_time()
        current.advance(state, self.waypoints, self.wind, DECISION_PERIOD_S, self.params,
                        scratch=self.scratch[search])
        return time.process_time() - t0


def scaling(rounds: int, seeds: int) -> list[dict[str, float]]:
    """Per N and B: ns of CPU per aircraft-step and per aircraft-evaluation (sub-steps
    counted), all pairs and grid, over ``seeds`` encounters; medians over ``rounds``
    rounds, the two searches alternating call by call."""
    rows = []
    for n_worlds in SCALING_B:
        for n_aircraft in SCALING_N:
            cases = [ScalingCase(n_worlds, n_aircraft, seed) for seed in range(seeds)]
            for case in cases:
                for search in case.scratch:
                    case.cpu_seconds(search)  # warm the scratch and the caches
            totals: dict[str, list[float]] = {"all_pairs": [], "grid": []}
            for r in range(rounds):
                order = ("all_pairs", "grid") if r % 2 == 0 else ("grid", "all_pairs")
                spent = dict.fromkeys(order, 0.0)
                for case in cases:
                    for search in order:
                        spent[search] += case.cpu_seconds(search)
                for search in order:
                    totals[search].append(spent[search])
            steps = sum(case.aircraft_steps for case in cases)
            evaluations = sum(case.evaluations for case in cases)
            row = {"B": n_worlds, "N": n_aircraft, "sub_steps": evaluations / steps}
            for search, values in totals.items():
                row[f"{search}_step_ns"] = statistics.median(values) / steps * 1e9
                row[f"{search}_eval_ns"] = statistics.median(values) / evaluations * 1e9
            rows.append(row)
            print(row, flush=True)
    return rows


def scaling_text(rows: list[dict[str, float]], rounds: int, seeds: int) -> str:
    """The scaling section of BENCHMARKS.md."""
    default_search = {n: "grid" if n >= current.GRID_MIN_AIRCRAFT else "all_pairs" for n in SCALING_N}
    table = [
        "| B | N | sub-steps per step | ns per aircraft-step: all pairs | grid | ns per aircraft-evaluation: "
        "all pairs | grid | default's evaluation / N = 4's |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    ratios = {}
    for row in rows:
        base = next(r for r in rows if r["B"] == row["B"] and r["N"] == SCALING_N[0])
        ratio = row[f"{default_search[row['N']]}_eval_ns"] / base[f"{default_search[base['N']]}_eval_ns"]
        ratios[row["B"], row["N"]] = ratio
        table.append(
            f"| {row['B']} | {row['N']} | {row['sub_steps']:.2f} | {row['all_pairs_step_ns']:.0f} | "
            f"{row['grid_step_ns']:.0f} | {row['all_pairs_eval_ns']:.0f} | {row['grid_eval_ns']:.0f} | "
            f"{ratio:.2f}× |"
        )
    at_most = {b: ratios[b, SCALING_N[-1]] for b in SCALING_B}
    return "\n".join([
        "## Kernel scaling with the number of aircraft",
        "",
        f"`python bench/bench_kernel.py --scaling` — {machine()}, numba "
        f"{numba.__version__} with {numba.get_num_threads()} threads. Random encounters at random-8's density "
        f"(the circle's radius 250 nm · √(N / 8), {seeds} seeds), timed over one 5-min period from 80 % of the way "
        "to the centre, where the traffic crosses; CPU time of the process (all threads), medians over "
        f"{rounds} rounds with the neighbour grid and the loops over all pairs alternating (the same bits). "
        "An aircraft-evaluation is an aircraft flown for one sub-step: a step in which any aircraft of a "
        "world needs sub-steps (the kernel's guard 8) is flown in sub-steps by every aircraft of that world, so "
        "the sub-steps per step grow with N at a fixed density, and the cost per aircraft-step with them. The "
        f"last column: the default's cost per evaluation (the grid from {current.GRID_MIN_AIRCRAFT} aircraft, "
        "all pairs below) against N = 4's.",
        "",
        *table,
        "",
        f"Target: the default's cost per aircraft-evaluation at N = {SCALING_N[-1]} within 2× of N = "
        f"{SCALING_N[0]}'s: " + ("met" if max(at_most.values()) <= 2.0 else "not met") + " in this run ("
        + ", ".join(f"B = {b}: {ratio:.2f}×" for b, ratio in at_most.items()) + "). The cost per aircraft-step "
        "is not: it grows with the sub-steps per step, which the grid does not change (they are the law's, "
        "guard 8). Rows between measure how the encounters' mix of ordinary steps (cheap, no pair in range) and "
        "sub-stepped ones moves the cost, more than N does. At B = 16 the few aircraft's steps are mostly "
        "ordinary and flown in SIMD lanes, cheaper per evaluation than the scalar path; at this density a world "
        "of many aircraft nearly always has a pair within the sensing radius, and its steps take the scalar path "
        "whatever the pair search.",
    ])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    parser.add_argument("--rounds", type=int, default=31, help="interleaved rounds per row (default 31; "
                        "--scaling: 5)")
    parser.add_argument("--scaling", action="store_true", help="the scaling table with N instead")
    parser.add_argument("--seeds", type=int, default=3, help="--scaling: encounters per row (default 3)")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.seeds < 1:
        parser.error("--rounds and --seeds must be >= 1")
    if args.scaling:
        rounds = args.rounds if "--rounds" in (argv if argv is not None else sys.argv) else 5
        return publish("kernel-scaling", scaling_text(scaling(rounds, args.seeds), rounds, args.seeds), args.write)
    dt = SimConfig().dt_s
    compile_s = first_call_seconds()
    print(f"first calls (compile or cache load): frozen {compile_s['frozen']:.2f} s, "
          f"current {compile_s['current']:.2f} s", flush=True)
    rows = [
        (
            "| B | N | frozen kernel (aircraft-steps/s) | current kernel (aircraft-steps/s) | current / frozen "
            "[quartiles over rounds] |"
        ),
        "|---:|---:|---:|---:|---:|",
    ]
    ratios = {}
    lower_quartiles = {}
    for n_worlds in (1000, 1):
        for n_aircraft in (4, 6):
            result = measure(n_worlds, n_aircraft, args.rounds)
            ratios[n_worlds, n_aircraft] = result["ratio"]
            lower_quartiles[n_worlds, n_aircraft] = result["q1"]
            rows.append(
                f"| {n_worlds} | {n_aircraft} | {result['frozen'] / 1e6:.2f} M | "
                f"{result['current'] / 1e6:.2f} M | {result['ratio']:.2f}× [{result['q1']:.2f}–{result['q3']:.2f}] |"
            )
            print(rows[-1], flush=True)
    floor = transcendental_floor(args.rounds)
    print(f"one thread: {floor['step_ns']:.1f} ns per aircraft-step; atan2 + sincos alone: the kernel's own "
          f"{floor['inlined_ns']:.1f} ns inlined, {floor['called_ns']:.1f} ns called, libm's {floor['libm_ns']:.1f} ns",
          flush=True)
    text = "\n".join(
        [
            "## Kernel throughput",
            "",
            f"`python bench/bench_kernel.py` — one 5-min period (dt = {dt:g} s) of converging-N per "
            f"`advance` call (entry checks included), {machine()}, numba {numba.__version__} with "
            f"{numba.get_num_threads()} threads. The current kernel against the frozen copy of the "
            f"kernel before its performance work (`bench/yardstick.py`, rebuilt from git history), interleaved in "
            f"{args.rounds} rounds in one process; medians over rounds, and the median of the "
            "per-round ratios with their quartiles (how far the machine's load moved a round's ratio):",
            "",
            *rows,
            "",
            f"First calls in the process (numba compilation, or loading its on-disk cache when "
            f"warm), apart from the figures above: frozen {compile_s['frozen']:.2f} s, current "
            f"{compile_s['current']:.2f} s.",
            "",
            "Target: current / frozen >= 2 at B = 1000 and at B = 1: "
            + ("met in this run. " if min(ratios.values()) >= 2.0 else
               f"not met in this run (lowest ratio {min(ratios.values()):.2f}× at B = {min(ratios, key=ratios.get)[0]}, "
               f"N = {min(ratios, key=ratios.get)[1]}). ")
            + "".join(
                f"At B = {b}, N = {n} a quarter of the rounds measured below {q:.2f}×: that ratio is at the "
                "target's edge, not clear of it. "
                for (b, n), q in lower_quartiles.items()
                if q < 2.0 <= ratios[b, n]
            )
            + "What the current kernel does that the frozen copy does not: it checks its inputs and its "
            "result in the same compiled call as the flight; it compiles its world loop without numba's "
            "reference counts; its atan2 and sincos are polynomials of its own (`atc_nf_env.trig`, within "
            "2 ulps of libm, the same bits on every path); batches of "
            f"{current.LANE_MIN_WORLDS} worlds or more fly their ordinary steps (no pair within the sensing "
            f"radius, no guard acting) {current.LANE_CHUNK} worlds at a time in SIMD lanes, and one world "
            "flies runs of such steps with its aircraft in lanes; each path is compiled when first used. It "
            "also flies the right-hand rule at the NF's saddle (guard 9), work the frozen copy skips. Every "
            "path gives the same bits (`tests/test_kernel_lanes.py`, `tests/test_kernel_ordinary_step.py`; "
            "`bench/kernel_trajectory_hash.py` compares builds), so a world flies bit for bit the same alone "
            "or in a batch of any size. Every world of this benchmark's period is ordinary. Absolute rates "
            "move with the machine's load; the ratios, measured side by side, are what to compare.",
            "",
            f"Where a step's time goes, on one thread (B = 1000, N = 4, medians over {args.rounds} rounds "
            f"timed alternately): {floor['step_ns']:.0f} ns per aircraft-step, nearly all of them lane "
            "steps. Of that, the law's atan2 and sincos, timed alone on the flight's own angles as the lane "
            f"step runs them: {floor['inlined_ns']:.1f} ns ({floor['inlined_ns'] / floor['step_ns']:.0%}); "
            f"the same functions called rather than inlined {floor['called_ns']:.1f} ns; libm's "
            f"{floor['libm_ns']:.1f} ns.",
        ]
    )
    return publish("kernel", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
