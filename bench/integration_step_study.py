"""Convergence study of the integration step (second-order Adams-Bashforth).

A 66-min flight in the MPC's regime: one aircraft under wind whose waypoint is reset
every 5 min to 100 nm ahead on the line to its destination (so the NF commands
cruise airspeed throughout, as under the MPC), plus two aircraft of a crossing pair
passing about 11 nm apart with the same waypoint rule (the neighbour terms of the law
active). For each step dt the end position after 66 min is compared with the one at
dt/2; the default step is the largest whose halving moves every end point by less
than 0.1 nm.

The saddle case: the NF alone in the converging encounters of 4 and 6 aircraft
without wind, where every aircraft is driven toward a critical point of its NF and
the 1/P_i term of the law saturates (kernel guard 8). Its figure is the episode's
minimum separation at each step, and how much it moves when the step is halved.

Run: python bench/integration_step_study.py  (writes its table into BENCHMARKS.md
with --write).
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from _report import write_section  # bench/ is on sys.path when run as a script

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import S_X, S_Y, advance
from atc_nf_env.scenarios import Scenario, converging
from atc_nf_env.simulation import initial_state

from baselines import NFDirect

FLIGHT_S = 66 * 60.0
PERIOD_S = 300.0
STEPS = (20.0, 10.0, 5.0, 2.5, 1.25, 0.625)


def cases() -> list[tuple[str, Scenario, np.ndarray]]:
    lone = [
        (
            f"lone, wind ({w[0]:+.0f}, {w[1]:+.0f}) kt",
            Scenario(
                name="lone",
                start_xy=np.array([[-250.0, 0.0]]),
                start_heading=np.array([0.0]),
                dest_xy=np.array([[700.0, 0.0]]),
                dest_heading=np.array([0.0]),
            ),
            np.array(w),
        )
        for w in ((0.0, 0.0), (14.0, -9.0), (-20.0, 12.0))
    ]
    crossing = Scenario(
        name="crossing",
        start_xy=np.array([[-250.0, -8.0], [8.0, -250.0]]),
        start_heading=np.array([0.0, math.pi / 2]),
        dest_xy=np.array([[700.0, -8.0], [8.0, 700.0]]),
        dest_heading=np.array([0.0, math.pi / 2]),
    )
    return lone + [("crossing pair", crossing, np.array([6.0, 8.0]))]


def end_positions(scenario: Scenario, wind: np.ndarray, dt: float) -> np.ndarray:
    config = SimConfig(dt_s=dt)
    params = config.to_params(scenario.workspace_radius_nm)
    state = initial_state(scenario)
    t = 0.0
    while t < FLIGHT_S - 1e-9:
        pos = state[0, :, S_X : S_Y + 1]
        to_dest = scenario.dest_xy - pos
        unit = to_dest / np.linalg.norm(to_dest, axis=1, keepdims=True)
        advance(state, (pos + 100.0 * unit)[None], wind[None], PERIOD_S, params)
        t += PERIOD_S
    return state[0, :, S_X : S_Y + 1].copy()


def study() -> tuple[list[str], float]:
    rows = ["| case | " + " | ".join(f"dt {dt:g} s vs {dt / 2:g} s" for dt in STEPS[:-1]) + " |"]
    rows.append("|---" * len(STEPS) + "|")
    worst = np.zeros(len(STEPS) - 1)
    for label, scenario, wind in cases():
        ends = [end_positions(scenario, wind, dt) for dt in STEPS]
        moves = [float(np.linalg.norm(ends[k] - ends[k + 1], axis=1).max()) for k in range(len(STEPS) - 1)]
        worst = np.maximum(worst, moves)
        rows.append(f"| {label} | " + " | ".join(f"{m:.4f} nm" for m in moves) + " |")
    passing = [dt for dt, w in zip(STEPS[:-1], worst) if w < 0.1]
    chosen = max(passing) if passing else float("nan")
    return rows, chosen


SADDLE_STEPS = (10.0, 5.0, 2.5, 1.25, 0.625)


def saddle_study() -> tuple[list[str], float]:
    """Minimum separation of the NF alone, converging-4 and -6 without wind, per step."""
    header = " | ".join(f"dt {dt:g} s" for dt in SADDLE_STEPS)
    rows = [f"| case | {header} | largest move on halving |", "|---" * (len(SADDLE_STEPS) + 2) + "|"]
    worst = 0.0
    for physics, n in (("default", 4), ("default", 6), ("paper-nf", 4), ("paper-nf", 6)):
        cells = []
        seps = []
        for dt in SADDLE_STEPS:
            config = SimConfig.preset(physics).replace(dt_s=dt)
            m = run_episode(NFDirect(), converging(n), seed=0, wind_kt=np.zeros(2), config=config).metrics
            seps.append(float(m.min_separation_nm))
            flags = [] if m.los_count == 0 else [f"{m.los_count} LoS"]
            flags += [] if m.success else ["not all home"]
            cells.append(f"{seps[-1]:.2f} nm" + (f" ({', '.join(flags)})" if flags else ""))
        moves = np.abs(np.diff(seps))
        worst = max(worst, float(moves[1:].max()))  # from the default step down
        rows.append(f"| converging-{n}, no wind, NF alone, {physics} physics | " + " | ".join(cells) + f" | {moves.max():.2f} nm |")
    return rows, worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    rows, chosen = study()
    saddle_rows, saddle_worst = saddle_study()
    text = "\n".join(
        [
            "## Integration step: convergence study",
            "",
            "End point after a 66-min flight: how far it moves when the step is halved "
            "(largest over the aircraft).",
            "",
            *rows,
            "",
            f"Largest step whose halving moves every end point by < 0.1 nm: **{chosen:g} s** "
            f"(default `SimConfig.dt_s` = {SimConfig().dt_s:g} s). The integrator is second-order "
            "Adams-Bashforth. The default is not the largest passing step: the MPC checks the "
            "envelope and the separation at every integration step, and 5 s (0.63 nm of flight "
            "at 454 kt) keeps that check fine while its halving error stays ten times under "
            "the criterion.",
            "",
            "### The saddle: the NF alone in the converging encounters without wind",
            "",
            "Minimum separation over the episode (`NFDirect`, wind 0) at each step.",
            "",
            *saddle_rows,
            "",
            f"Largest move when a step of {SimConfig().dt_s:g} s or less is halved: "
            f"**{saddle_worst:.2f} nm** (goal: < 0.2 nm). Steps in which a command saturates are "
            f"flown in sub-steps of at most {SimConfig().substep_s:g} s (kernel guard 8), which "
            "removed the loss of separation that the 6-aircraft encounter had at 5 s without "
            "them, and the overshoot of up to u_cap · dt = 2 nm per step. What still moves is not the sub-step. The encounter is "
            "symmetric under reflection about each aircraft's radial line, and the exact flow keeps "
            "that symmetry, so each aircraft would stay on its own line and the N of them would stop "
            "where they meet, at a critical point of their NFs near the centre (a saddle of the "
            "joint flow). Every flight that passes has broken the symmetry through rounding and "
            "truncation errors, so which way it breaks, and the scramble that follows, depends on "
            "the step. Neither physics meets the goal (`paper-nf`: G_i's range 30/15 nm, see "
            "REPRODUCTION.md); no loss of separation occurs at 5 s or less.",
            "",
        ]
    )
    print(text)
    if args.write:
        write_section("integration-step", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
