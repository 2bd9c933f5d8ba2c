"""Environment throughput: each single-world env against the bare kernel, measured
interleaved in one run, and the native vector env's aircraft-decisions per second.

Single-world envs, one process, converging-N (wind σ = 5.17 m/s), uniform random
actions in [-1, 1]² for every live agent, reset when the episode ends (resets included):

- PettingZoo ``parallel_env``: steps per second (one step = one 5-min decision period
  for every aircraft);
- PettingZoo AEC ``env``: cycles per second (one cycle = every live agent acts once,
  i.e. one decision period);
- the centralized ``gym.make("atc_nf_env/Encounter-v1")``: steps per second;
- the bare kernel: ``kernel.advance`` flying one world of the same scenario one 300 s
  period per call, with random actions mapped to waypoints as the envs map them and the
  envs' 36-period limit (so it flies what the envs fly): periods per second.

Every loop is warmed up first (numba compilation and caches, not timed), so all of
them fly the same compiled kernel. Then rounds of short chunks, one chunk of each loop
per round, the order rotated from round to round (no loop always runs right after the
same one): each round's ratio env / kernel compares figures taken within a second or two
of each other, under the same load. Reported: the median rates over rounds and the
median of the per-round ratios, with their quartiles (1 would mean the env costs nothing
beyond the physics). On a shared machine the load moves within seconds; ratios within a
round are what to compare, rates between runs are not.

Vector env: ``EncounterVectorEnv`` with B worlds (next-step autoreset), random actions;
an aircraft-decision is one aircraft flying one decision period (aircraft that have
arrived, padding and worlds being reset are not counted). For comparison the same
worlds through Gymnasium's ``SyncVectorEnv`` over ``EncounterEnv``, and the SB3 adapter
in parameter-shared mode.

Run: python bench/bench_envs.py [--write] [--rounds R] [--seconds S] [--skip-vector]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import gymnasium as gym
import numba
import numpy as np
from _report import machine, publish  # bench/ is on sys.path when run as a script
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
    cycle's random actions are drawn at once, as the other loops draw theirs; each agent
    takes its own aircraft's row. The loop is the usual one (selection, ``last()``,
    ``step()``), with bookkeeping of its own kept to a dict look-up."""

    def __init__(self, n_aircraft: int) -> None:
        self.env = atc_nf_env.env(scenario=f"converging-{n_aircraft}")
        self.rng = np.random.default_rng(0)
        self.env.reset(seed=0)
        self.n = n_aircraft
        self.row = {agent: i for i, agent in enumerate(self.env.possible_agents)}
        self.actions = self.rng.uniform(-1.0, 1.0, (n_aircraft, 2)).astype(np.float32)

    def run(self, cycles: int) -> None:
        env, rng, row = self.env, self.rng, self.row
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
            if agent == env.agents[0]:  # the first live agent: a new cycle
                done_cycles += 1
                actions = rng.uniform(-1.0, 1.0, (self.n, 2)).astype(np.float32)
            env.step(actions[row[agent]])
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


def single_world_rates(n_aircraft: int, rounds: int, seconds: float) -> dict[str, dict[str, float]]:
    """Per loop: the median rate over rounds ("rate") and, for the envs, the median and
    quartiles of the per-round ratio env rate / kernel rate ("ratio", "q1", "q3")."""
    loops = {
        "kernel": KernelLoop(n_aircraft),
        "parallel": ParallelLoop(n_aircraft),
        "aec": AECLoop(n_aircraft),
        "centralized": CentralizedLoop(n_aircraft),
    }
    counts = {}
    for name, loop in loops.items():  # warm up (compilation, caches), then size each chunk
        loop.run(20)
        loop.run(200)
        counts[name] = max(20, int(rate(loop, 200) * seconds))
    names = list(loops)
    rates: dict[str, list[float]] = {name: [] for name in loops}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for round_index in range(rounds):
        shift = round_index % len(names)
        for name in names[shift:] + names[:shift]:
            rates[name].append(rate(loops[name], counts[name]))
    # The process's CPU time over its wall time: below 1, other jobs took the core from it.
    cpu_share = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
    result = {"kernel": {"rate": statistics.median(rates["kernel"]), "cpu_share": cpu_share}}
    for name in names[1:]:
        ratios = [env_rate / kernel_rate for env_rate, kernel_rate in zip(rates[name], rates["kernel"])]
        q1, _, q3 = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else (ratios[0],) * 3
        result[name] = {"rate": statistics.median(rates[name]), "ratio": statistics.median(ratios), "q1": q1, "q3": q3}
    return result


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
    parser.add_argument("--rounds", type=int, default=25, help="interleaved rounds of the single-world envs")
    parser.add_argument("--seconds", type=float, default=0.3, help="length of one loop's chunk in a round, s")
    parser.add_argument("--repeats", type=int, default=7, help="repeats of the vector env measurements")
    parser.add_argument("--worlds", type=int, default=256, help="B of the vector env")
    parser.add_argument("--skip-vector", action="store_true", help="only the single-world envs")
    args = parser.parse_args(argv)
    if args.write and args.skip_vector:
        parser.error("--write needs the whole section: leave out --skip-vector")
    b = args.worlds
    loads = [os.getloadavg()[0]]
    cpu_shares: list[float] = []

    single_rows = [
        "| scenario | bare kernel (periods/s) | parallel_env (steps/s) | ratio [quartiles] | AEC env (cycles/s) "
        "| ratio [quartiles] | gym.make (steps/s) | ratio [quartiles] |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in (4, 6):
        r = single_world_rates(n, args.rounds, args.seconds)
        cells = [f"converging-{n}", f"{r['kernel']['rate']:,.0f}"]
        for name in ("parallel", "aec", "centralized"):
            e = r[name]
            cells += [f"{e['rate']:,.0f}", f"**{e['ratio']:.2f}** [{e['q1']:.2f}–{e['q3']:.2f}]"]
        single_rows.append("| " + " | ".join(cells) + " |")
        cpu_shares.append(r["kernel"]["cpu_share"])
        loads.append(os.getloadavg()[0])
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
            loads.append(os.getloadavg()[0])
            print(vec_rows[-1], flush=True)

    text = "\n".join(
        [
            "## Environment throughput",
            "",
            f"`python bench/bench_envs.py` — {machine()}, numba {numba.__version__} with "
            f"{numba.get_num_threads()} threads; 1-min load average {min(loads):.1f}–{max(loads):.1f} during "
            "the run (2 cores: above about 1, other jobs share the machine). One env step = one 5-min decision period "
            "(60 kernel steps of 5 s); wind σ = 5.17 m/s; uniform random actions; resets included.",
            "",
            "Single-world envs against the bare kernel (`kernel.advance`, one world, one period per call, "
            "random actions mapped to waypoints as the envs map them), one process, every loop warmed up "
            f"first (compilation not timed), then {args.rounds} rounds of {args.seconds:g}-s chunks, one of "
            "each loop per round in rotating order. Rates: medians over rounds. Ratio: median over rounds "
            "of env rate / kernel rate in the same round, with its quartiles (target >= 0.5). The bench "
            f"process ran {min(cpu_shares):.0%}–{max(cpu_shares):.0%} of its wall time on a core (CPU time / "
            "wall time over each scenario's rounds; less: other jobs took the core from it):",
            "",
            *single_rows,
            "",
            "Why per-round ratios (until this version the ratio was that of the medians of 7 rounds of 1-s "
            "chunks in a fixed order): on a shared machine the load moves within seconds, and two medians "
            "can pair figures taken under different loads; a round's chunks run within about a second of "
            "each other, and the quartiles show how far the load moved the ratio. On this 2-core machine the "
            "ratios fell as the load rose (the envs' Python code slowed more than the compiled kernel): "
            "compare ratios taken at similar load averages.",
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
    return publish("envs", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
