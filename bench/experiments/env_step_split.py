"""Where a single-world env step's time goes, layer by layer, on converging-N.

``bench/bench_envs.py`` gives each env's rate against the bare kernel's. This probe splits
the difference: per call, warm, in rounds that time every layer once each, in rotating
order (medians over rounds of each layer's mean over its chunk):

- ``kernel``: the bare kernel flying one period of one world, random actions mapped to
  waypoints as the envs map them (``bench_envs.KernelLoop``);
- ``world.step``: the envs' shared world (``atc_nf_env.envs.centralized``): the action
  mapping, the kernel and the compiled observations, rewards and info records;
- ``parallel._advance``: the parallel env's step after the actions are checked: the world,
  the agents' observation views, info dicts, rewards and terminations;
- ``parallel_env.step``: the whole step (the actions' checks, the returned dicts), with the
  loop's own random actions, as ``bench_envs.ParallelLoop``;
- ``AEC cycle``: one decision period of the AEC env, every agent stepped once
  (``bench_envs.AECLoop``);
- ``gym.make step``: the centralized env (``bench_envs.CentralizedLoop``);
- ``info dicts``: ``ATCParallelEnv._info_list`` alone, the per-agent info dicts of one
  step (their 16 keys each) from the world's records.

Each layer's time less the one before it is what that layer adds. Resets are included
where a loop ends its episode, as in ``bench_envs``.

Run: python bench/experiments/env_step_split.py [--rounds 15] [--calls 300]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import bench_envs  # bench/ on the path first


class WorldLoop:
    """The parallel env's world stepped alone with random actions."""

    def __init__(self, env) -> None:
        self.world = env.world
        self.rng = np.random.default_rng(1)

    def run(self, calls: int) -> None:
        world, rng = self.world, self.rng
        for _ in range(calls):
            if world.over:
                world.reset(int(rng.integers(1 << 30)))
            world.step(rng.uniform(-1.0, 1.0, (world.n_aircraft, 2)))


class AdvanceLoop:
    """``ATCParallelEnv._advance`` with random actions for the live agents."""

    def __init__(self, env) -> None:
        self.env = env
        self.rng = np.random.default_rng(2)

    def run(self, calls: int) -> None:
        env, rng = self.env, self.rng
        for _ in range(calls):
            if not env.agents:
                env.reset()
            env._advance(rng.uniform(-1.0, 1.0, (len(env.agents), 2)))


class InfoLoop:
    """``ATCParallelEnv._info_list`` of every aircraft after one step (``env`` just reset)."""

    def __init__(self, env) -> None:
        self.env = env
        env._advance(np.zeros((len(env.agents), 2)))

    def run(self, calls: int) -> None:
        env = self.env
        for _ in range(calls):
            env._info_list(None)


def split(n_aircraft: int, rounds: int, calls: int) -> dict[str, float]:
    """Median over rounds of each layer's µs per call."""
    # Each layer on an env of its own: stepping a world alone leaves its env's agents behind.
    loops = {
        "kernel": bench_envs.KernelLoop(n_aircraft),
        "world.step": WorldLoop(bench_envs.ParallelLoop(n_aircraft).env),
        "parallel._advance": AdvanceLoop(bench_envs.ParallelLoop(n_aircraft).env),
        "parallel_env.step": bench_envs.ParallelLoop(n_aircraft),
        "AEC cycle": bench_envs.AECLoop(n_aircraft),
        "gym.make step": bench_envs.CentralizedLoop(n_aircraft),
    }
    info = InfoLoop(bench_envs.ParallelLoop(n_aircraft).env)
    for loop in (*loops.values(), info):
        loop.run(max(calls // 5, 1))  # warm: compilation and caches out of the timings
    names = [*loops, "info dicts"]
    per_call: dict[str, list[float]] = {name: [] for name in names}
    every = {**loops, "info dicts": info}
    for r in range(rounds):
        for k in range(len(names)):
            name = names[(r + k) % len(names)]
            t0 = time.perf_counter()
            every[name].run(calls)
            per_call[name].append((time.perf_counter() - t0) / calls * 1e6)
    return {name: float(np.median(values)) for name, values in per_call.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--calls", type=int, default=300)
    parser.add_argument("--scenarios", default="4,6", help="aircraft counts of converging-N")
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.calls < 1:
        parser.error("--rounds and --calls must be >= 1")
    for n in (int(part) for part in args.scenarios.split(",")):
        result = split(n, args.rounds, args.calls)
        line = ", ".join(f"{name} {us:.1f} µs" for name, us in result.items())
        print(f"converging-{n}: {line}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
