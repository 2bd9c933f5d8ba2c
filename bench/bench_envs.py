"""Environment throughput: PettingZoo ParallelEnv steps per second, and the native vector
env's aircraft-decisions per second.

ParallelEnv: one process, converging-N (wind σ = 5.17 m/s), uniform random actions in
[-1, 1]² for every live agent, reset when the episode ends (resets included in the
time). Reported: the median over repeats of env steps / wall time (one step = one 5-min
decision period for every aircraft).

Vector env: ``EncounterVectorEnv`` with B worlds (next-step autoreset), random actions;
an aircraft-decision is one aircraft flying one decision period (aircraft that have
arrived, padding and worlds being reset are not counted). For comparison the same
worlds through Gymnasium's ``SyncVectorEnv`` over ``EncounterEnv``, and the SB3 adapter
in parameter-shared mode.

Run: python bench/bench_envs.py [--write] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numba
import numpy as np
from _report import machine, write_section  # bench/ is on sys.path when run as a script
from gymnasium.vector import SyncVectorEnv

import atc_nf_env
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.vector import EncounterVectorEnv, make_sb3_vec_env


def parallel_steps_per_s(n_aircraft: int, steps: int, repeats: int) -> float:
    env = atc_nf_env.parallel_env(scenario=f"converging-{n_aircraft}")
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    for _ in range(50):  # warm up (compilation, caches)
        if not env.agents:
            env.reset()
        env.step({agent: rng.uniform(-1, 1, 2) for agent in env.agents})
    rates = []
    for _ in range(repeats):
        env.reset(seed=1)
        t0 = time.perf_counter()
        for _ in range(steps):
            if not env.agents:
                env.reset()
            actions = rng.uniform(-1.0, 1.0, (len(env.agents), 2)).astype(np.float32)
            env.step(dict(zip(env.agents, actions)))
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def _vector_decisions_per_s(vec, n_worlds: int, n_aircraft: int, steps: int, repeats: int) -> float:
    rng = np.random.default_rng(0)
    shape = (n_worlds, n_aircraft, 2)
    vec.reset(seed=0)
    for _ in range(3):
        vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
    rates = []
    for _ in range(repeats):
        _, info = vec.reset(seed=1)
        alive = info["alive"]
        ended = np.zeros(n_worlds, dtype=bool)
        decisions = 0
        t0 = time.perf_counter()
        for _ in range(steps):
            decisions += int(alive[~ended].sum())
            _, _, terminated, truncated, info = vec.step(rng.uniform(-1, 1, shape).astype(np.float32))
            alive = info["alive"]
            ended = terminated | truncated
        rates.append(decisions / (time.perf_counter() - t0))
    return statistics.median(rates)


def vector_decisions_per_s(n_worlds: int, n_aircraft: int, steps: int, repeats: int) -> float:
    vec = EncounterVectorEnv(num_envs=n_worlds, scenario=f"converging-{n_aircraft}")
    return _vector_decisions_per_s(vec, n_worlds, n_aircraft, steps, repeats)


def sync_decisions_per_s(n_worlds: int, n_aircraft: int, steps: int, repeats: int) -> float:
    vec = SyncVectorEnv([lambda: EncounterEnv(scenario=f"converging-{n_aircraft}") for _ in range(n_worlds)])
    return _vector_decisions_per_s(vec, n_worlds, n_aircraft, steps, repeats)


def sb3_shared_steps_per_s(n_worlds: int, n_aircraft: int, steps: int, repeats: int) -> float:
    """SB3 adapter, parameter-shared mode: agent-steps (B·M SB3 envs) per second."""
    venv = make_sb3_vec_env(n_worlds, mode="shared", scenario=f"converging-{n_aircraft}")
    rng = np.random.default_rng(0)
    venv.seed(0)
    venv.reset()
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            venv.step_async(rng.uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32))
            venv.step_wait()
        rates.append(steps * venv.num_envs / (time.perf_counter() - t0))
    return statistics.median(rates)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write the tables into BENCHMARKS.md")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--steps", type=int, default=2000, help="ParallelEnv steps per repeat")
    parser.add_argument("--worlds", type=int, default=256, help="B of the vector env")
    args = parser.parse_args(argv)
    b = args.worlds

    par_rows = ["| scenario | ParallelEnv steps / s (median) | target |", "|---|---:|---:|"]
    for n in (4, 6):
        rate = parallel_steps_per_s(n, args.steps, args.repeats)
        par_rows.append(f"| converging-{n} | {rate:,.0f} | >= 3,000 |")
        print(par_rows[-1], flush=True)

    vec_rows = [
        "| scenario | native vector env (decisions/s) | SyncVectorEnv (decisions/s) | native / sync "
        "| SB3 adapter, shared (agent-steps/s) |",
        "|---|---:|---:|---:|---:|",
    ]
    vec_steps = 40
    for n in (4, 6):
        native = vector_decisions_per_s(b, n, vec_steps, args.repeats)
        sync = sync_decisions_per_s(b, n, vec_steps // 4, max(1, args.repeats // 2))
        shared = sb3_shared_steps_per_s(b, n, vec_steps, args.repeats)
        vec_rows.append(f"| converging-{n} | {native:,.0f} | {sync:,.0f} | {native / sync:.1f}× | {shared:,.0f} |")
        print(vec_rows[-1], flush=True)

    text = "\n".join(
        [
            "## Environment throughput",
            "",
            f"`python bench/bench_envs.py` — {machine()}, numba {numba.__version__} with "
            f"{numba.get_num_threads()} threads. One env step = one 5-min decision period "
            "(60 kernel steps of 5 s); wind σ = 5.17 m/s; uniform random actions; resets included.",
            "",
            "PettingZoo `parallel_env`, one process:",
            "",
            *par_rows,
            "",
            f"Aircraft-decisions per second (an aircraft flying one decision period; finished aircraft "
            f"and resetting worlds not counted), B = {b} worlds in one process:",
            "",
            *vec_rows,
            "",
            f"Target: >= 50,000 aircraft-decisions/s for the native vector env at B = {b}.",
        ]
    )
    print(text)
    if args.write:
        write_section("envs", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
