"""Environment throughput: each single-world env against the bare kernel, measured
interleaved in one run, and the native vector env's aircraft-decisions per second.

Single-world envs, one process, converging-N (wind σ = 5.17 m/s), uniform random
actions in [-1, 1]² for every live agent, reset when the episode ends (resets included):

- PettingZoo ``parallel_env``: steps per second (one step = one 5-min decision period
  for every aircraft);
- PettingZoo AEC ``env``: cycles per second (one cycle = every live agent acts once,
  i.e. one decision period);
- the centralized ``gym.make("atc_nf_env/Encounter-v0")``: steps per second;
- the bare kernel: ``kernel.advance`` flying one world of the same scenario one 300 s
  period per call, with random actions mapped to waypoints as the envs map them and the
  envs' 36-period limit (so it flies what the envs fly): periods per second.

Rounds alternate kernel, parallel, AEC, centralized, so that every ratio compares
figures taken under the same load; reported: medians over rounds, and the ratio env /
kernel (1 would mean the env costs nothing beyond the physics).

Vector env: ``EncounterVectorEnv`` with B worlds (next-step autoreset), random actions;
an aircraft-decision is one aircraft flying one decision period (aircraft that have
arrived, padding and worlds being reset are not counted). For comparison the same
worlds through Gymnasium's ``SyncVectorEnv`` over ``EncounterEnv``, and the SB3 adapter
in parameter-shared mode.

Run: python bench/bench_envs.py [--write] [--rounds R] [--seconds S]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import gymnasium as gym
import numba
import numpy as np
from _report import machine, write_section  # bench/ is on sys.path when run as a script
from gymnasium.vector import SyncVectorEnv

import atc_nf_env
from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.envs.centralized import EncounterEnv
from atc_nf_env.envs.vector import EncounterVectorEnv, make_sb3_vec_env
from atc_nf_env.episode import episode_wind_kt
from atc_nf_env.envs import EnvConfig
from atc_nf_env.envs.actions import ActionMapping, waypoints_for_state
from atc_nf_env.kernel import FLYING, S_STATUS
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import initial_state
from atc_nf_env.units import DECISION_PERIOD_S


class KernelLoop:
    """The bare kernel flying what the envs fly: one world, one 300 s period per
    ``kernel.advance`` call, uniform random actions mapped to waypoints as the envs map
    them, restarted when every aircraft has arrived or after the envs' 36 periods."""

    def __init__(self, n_aircraft: int) -> None:
        scenario = make_scenario(f"converging-{n_aircraft}")
        self.n = n_aircraft
        self.radius_nm = scenario.workspace_radius_nm
        self.template = initial_state(scenario)
        self.state = self.template.copy()
        self.params = SimConfig().to_params(scenario.workspace_radius_nm)
        self.wind = episode_wind_kt(0, 5.17)[None]
        self.scratch = kernel.KernelScratch()
        self.mapping = ActionMapping()
        self.limit = EnvConfig().max_decisions
        self.periods = 0
        self.rng = np.random.default_rng(0)

    def run(self, periods: int) -> None:
        state, rng = self.state, self.rng
        for _ in range(periods):
            if self.periods == self.limit or not (state[0, :, S_STATUS] == FLYING).any():
                state[:] = self.template
                self.periods = 0
            actions = rng.uniform(-1.0, 1.0, (1, self.n, 2)).astype(np.float32)
            waypoints = waypoints_for_state(actions, state, self.mapping, self.radius_nm)
            kernel.advance(state, waypoints, self.wind, DECISION_PERIOD_S, self.params, scratch=self.scratch)
            self.periods += 1


class ParallelLoop:
    def __init__(self, n_aircraft: int) -> None:
        self.env = atc_nf_env.parallel_env(scenario=f"converging-{n_aircraft}")
        self.rng = np.random.default_rng(0)
        self.env.reset(seed=0)

    def run(self, steps: int) -> None:
        env, rng = self.env, self.rng
        for _ in range(steps):
            if not env.agents:
                env.reset()
            actions = rng.uniform(-1.0, 1.0, (len(env.agents), 2)).astype(np.float32)
            env.step(dict(zip(env.agents, actions)))


class AECLoop:
    """Counts cycles: one cycle = one decision period (every live agent acted once). The
    cycle's random actions are drawn at once, as the other loops draw theirs."""

    def __init__(self, n_aircraft: int) -> None:
        self.env = atc_nf_env.env(scenario=f"converging-{n_aircraft}")
        self.rng = np.random.default_rng(0)
        self.env.reset(seed=0)
        self.n = n_aircraft
        self.actions = self.rng.uniform(-1.0, 1.0, (n_aircraft, 2)).astype(np.float32)

    def run(self, cycles: int) -> None:
        env, rng = self.env, self.rng
        done_cycles = 0
        actions = self.actions
        while done_cycles < cycles:
            if not env.agents:
                env.reset()
            agent = env.agent_selection
            _, _, terminated, truncated, _ = env.last()
            if terminated or truncated:
                env.step(None)
                continue
            index = env.agents.index(agent)
            if index == 0:
                done_cycles += 1
                actions = rng.uniform(-1.0, 1.0, (self.n, 2)).astype(np.float32)
            env.step(actions[index])
        self.actions = actions


class CentralizedLoop:
    def __init__(self, n_aircraft: int) -> None:
        self.env = gym.make(atc_nf_env.ENV_ID, scenario=f"converging-{n_aircraft}")
        self.rng = np.random.default_rng(0)
        self.env.reset(seed=0)
        self.shape = self.env.action_space.shape
        self.done = False

    def run(self, steps: int) -> None:
        env, rng = self.env, self.rng
        for _ in range(steps):
            if self.done:
                env.reset()
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1.0, 1.0, self.shape).astype(np.float32))
            self.done = terminated or truncated


def rate(loop, count: int) -> float:
    t0 = time.perf_counter()
    loop.run(count)
    return count / (time.perf_counter() - t0)


def single_world_rates(n_aircraft: int, rounds: int, seconds: float) -> dict[str, float]:
    loops = {
        "kernel": KernelLoop(n_aircraft),
        "parallel": ParallelLoop(n_aircraft),
        "aec": AECLoop(n_aircraft),
        "centralized": CentralizedLoop(n_aircraft),
    }
    counts = {}
    for name, loop in loops.items():  # warm up (compilation, caches), then size each chunk
        loop.run(20)
        counts[name] = max(20, int(rate(loop, 100) * seconds))
    rates: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(rounds):
        for name, loop in loops.items():
            rates[name].append(rate(loop, counts[name]))
    return {name: statistics.median(values) for name, values in rates.items()}


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
    parser.add_argument("--rounds", type=int, default=7, help="interleaved rounds of the single-world envs")
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one env's chunk in a round, s")
    parser.add_argument("--repeats", type=int, default=7, help="repeats of the vector env measurements")
    parser.add_argument("--worlds", type=int, default=256, help="B of the vector env")
    parser.add_argument("--skip-vector", action="store_true", help="only the single-world envs")
    args = parser.parse_args(argv)
    b = args.worlds

    single_rows = [
        "| scenario | bare kernel (periods/s) | parallel_env (steps/s) | ratio | AEC env (cycles/s) | ratio "
        "| gym.make (steps/s) | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in (4, 6):
        r = single_world_rates(n, args.rounds, args.seconds)
        k = r["kernel"]
        single_rows.append(
            f"| converging-{n} | {k:,.0f} | {r['parallel']:,.0f} | {r['parallel'] / k:.2f} | {r['aec']:,.0f} "
            f"| {r['aec'] / k:.2f} | {r['centralized']:,.0f} | {r['centralized'] / k:.2f} |"
        )
        print(single_rows[-1], flush=True)

    vec_rows = [
        "| scenario | native vector env (decisions/s) | SyncVectorEnv (decisions/s) | native / sync "
        "| SB3 adapter, shared (agent-steps/s) |",
        "|---|---:|---:|---:|---:|",
    ]
    if not args.skip_vector:
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
            f"Single-world envs against the bare kernel (`kernel.advance`, one world, one period per call), "
            f"one process, measured interleaved in {args.rounds} rounds (medians); ratio = env rate / "
            "kernel rate (target >= 0.5):",
            "",
            *single_rows,
            "",
            f"Aircraft-decisions per second (an aircraft flying one decision period; finished aircraft "
            f"and resetting worlds not counted), B = {b} worlds in one process:",
            "",
            *vec_rows,
            "",
            f"Target: >= 50,000 aircraft-decisions/s for the native vector env at B = {b}.",
            "",
            "Absolute rates move with the machine's load (the threaded vector env most); the ratios, "
            "measured interleaved, are what to compare between runs.",
        ]
    )
    print(text)
    if args.write:
        write_section("envs", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
