"""The kernel's first compilation: CPU time (user + sys) of a first ``advance`` call on an
empty numba cache, per path, each in a fresh process with a cache directory of its own.

The paths are compiled when first used: one world (B = 1: the environments, a single
simulation, the safety filter's prediction), the scalar batch (2 <= B < 16) and the lane
path (B >= 16: the vector envs); "all" flies B = 1, 2 and 1000 in one process. The MPC's
reset compiles the lane path alone and the process then flies every batch size on it
(``kernel.load_paths``). CPU time rather than wall time: on a shared machine the wall
time measures the other processes too. Reported: the median and the range over the
repetitions, and the import of the package apart.

"demo" is ``make demo``'s command (``atc-nf fly --policy mpc --scenario converging-4``) on
an empty cache: its CPU time and the warm-up it reports as ``compile_s`` (wall s).

Run: python bench/bench_compile.py [--repeat 3] [--cases one,batch,lanes,all,demo] [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine, publish  # noqa: E402  (bench/ is on sys.path when run as a script)

#: The batch sizes each case flies, in order, in one process ("demo": make demo's command).
CASES = {"one": (1,), "batch": (2,), "lanes": (1000,), "all": (1, 2, 1000), "demo": ()}
DEMO = ["-m", "atc_nf_env.cli", "fly", "--policy", "mpc", "--scenario", "converging-4", "--wind-sigma", "5.17",
        "--seed", "0"]

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


def cold_cpu_seconds(case: str) -> tuple[float, float | None]:
    """(CPU s of the whole child process, CPU s of its imports, or for "demo" the
    ``compile_s`` it reports) for ``case``'s first calls on an empty numba cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, (str(ROOT), env.get("PYTHONPATH", ""))))
        summary = Path(cache) / "summary.json"
        argv = [*DEMO, "--summary-json", str(summary)] if case == "demo" else ["-c", _PROGRAM, *map(str, CASES[case])]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run([sys.executable, *argv], env=env, capture_output=True, text=True, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        other = json.loads(summary.read_text())["compile_s"] if case == "demo" else float(done.stdout.split()[-1])
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, other


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="processes per case (default 3)")
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    cases = args.cases.split(",")
    unknown = [case for case in cases if case not in CASES]
    if unknown or args.repeat < 1:
        parser.error(f"unknown case {unknown}; allowed: {', '.join(CASES)}" if unknown else "--repeat must be >= 1")
    lines = [
        "## Cold start: the simulator's first compilation",
        "",
        f"`python bench/bench_compile.py --repeat {args.repeat}` — {machine()}. CPU time (user + sys) of a fresh "
        "process on an empty numba cache; each kernel path is compiled when first used (one world: the "
        "environments, a simulation, the safety filter; the scalar batch: 2–15 worlds; the lanes: 16 worlds or "
        "more, the vector envs), later runs load numba's cache. \"demo\" is `make demo`'s command: the MPC's reset "
        "compiles the lane path alone, and the process flies every batch on it, its candidates and the real world "
        "(`kernel.load_paths`); its last column is the warm-up it reports as `compile_s` (wall s), the rest of the "
        "process being imports and the warm episode.",
        "",
        "| case (B flown) | CPU s: median [range] | imports CPU s (demo: compile_s) |",
        "|---|---:|---:|",
    ]
    for case in cases:
        runs = [cold_cpu_seconds(case) for _ in range(args.repeat)]
        total = [cpu for cpu, _ in runs]
        flown = ", ".join(map(str, CASES[case])) or "make demo"
        lines.append(f"| {case} ({flown}) | {statistics.median(total):.1f} [{min(total):.1f}–{max(total):.1f}] | "
                     f"{statistics.median(other for _, other in runs):.1f} |")
        print(lines[-1], file=sys.stderr, flush=True)
    publish("compile", "\n".join(lines), args.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
