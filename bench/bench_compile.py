"""The kernel's first compilation: CPU time (user + sys) of a first ``advance`` call on an
empty numba cache, per path, each in a fresh process with a cache directory of its own.

The paths are compiled when first used: one world (B = 1: the environments, a single
simulation, the safety filter's prediction), the scalar batch (2 <= B < 16) and the lane
path (B >= 16: the MPC's candidates, the vector envs); "all" flies B = 1, 2 and 1000 in one
process, as the MPC demo does. CPU time rather than wall time: on a shared machine the wall
time measures the other processes too. Reported: the median and the range over the
repetitions, and the import of the package apart.

Run: python bench/bench_compile.py [--repeat 3] [--cases one,batch,lanes,all]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The batch sizes each case flies, in order, in one process.
CASES = {"one": (1,), "batch": (2,), "lanes": (1000,), "all": (1, 2, 1000)}

_PROGRAM = """
import sys, time
t0 = time.process_time()
import numpy as np
from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import converging
from atc_nf_env.simulation import initial_state
imported = time.process_time() - t0
scenario = converging(4)
params = SimConfig().to_params(scenario.workspace_radius_nm)
for n_worlds in map(int, sys.argv[1:]):
    state = initial_state(scenario, n_worlds)
    kernel.advance(state, np.repeat(scenario.dest_xy[None], n_worlds, axis=0), np.zeros((n_worlds, 2)), 300.0, params)
print(imported)
"""


def cold_cpu_seconds(worlds: tuple[int, ...]) -> tuple[float, float]:
    """(CPU s of the whole child process, CPU s of its imports) for first calls at ``worlds``
    on an empty numba cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, (str(ROOT), env.get("PYTHONPATH", ""))))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run([sys.executable, "-c", _PROGRAM, *map(str, worlds)], env=env, capture_output=True,
                              text=True, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, float(done.stdout.split()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="processes per case (default 3)")
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    args = parser.parse_args(argv)
    cases = args.cases.split(",")
    unknown = [case for case in cases if case not in CASES]
    if unknown or args.repeat < 1:
        parser.error(f"unknown case {unknown}; allowed: {', '.join(CASES)}" if unknown else "--repeat must be >= 1")
    print("| path (B flown) | first call on an empty cache, CPU s: median [range] | of which imports, s |")
    print("|---|---:|---:|")
    for case in cases:
        runs = [cold_cpu_seconds(CASES[case]) for _ in range(args.repeat)]
        total = [cpu for cpu, _ in runs]
        print(f"| {case} ({', '.join(map(str, CASES[case]))}) | {statistics.median(total):.1f} "
              f"[{min(total):.1f}–{max(total):.1f}] | {statistics.median(i for _, i in runs):.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
