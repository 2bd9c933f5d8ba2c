"""The MCMC-MPC at the paper's settings: wall time per episode and decision, memory.

One episode of converging-4 and of converging-6 under wind (σ = 5.17 m/s), K = 1000,
N = 4, T = 5 min, for several seeds, each in a fresh process (so that peak memory is
that of one episode, numba's compiled code loaded from its cache). Reported: median
wall time per episode and per decision, the feasible fraction of the candidates per
decision, and the peak resident memory.

Targets (issue): 4 aircraft <= 1 s, 6 aircraft <= 5 s per episode on this 2-core
machine, peak memory <= 300 MB.

Run: python bench/bench_mpc.py [--seeds 5] [--write]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

from _report import machine, write_section  # bench/ is on sys.path when run as a script

CHILD = r"""
import json, sys, time
from atc_nf_env.episode import run_episode
from atc_nf_env.metrics import peak_rss_mb
from atc_nf_env.scenarios import converging
from baselines import MCMCMPC
n, seed = int(sys.argv[1]), int(sys.argv[2])
# Load the compiled kernel before timing (a cold start is not an episode's cost).
run_episode(MCMCMPC(extractions=10), converging(n), seed=seed, max_time_s=600.0)
policy = MCMCMPC()
t0 = time.perf_counter()
m = run_episode(policy, converging(n), seed=seed, wind_sigma_mps=5.17).metrics
wall = time.perf_counter() - t0
info = policy.episode_info()
print(json.dumps({"wall_s": wall, "decisions": m.decisions, "decision_s": m.decision_s_mean,
                  "success": m.success, "feasible_mean": info["feasible_fraction"]["mean"],
                  "feasible_min": info["feasible_fraction"]["min"], "fallbacks": info["fallbacks"],
                  "peak_rss_mb": peak_rss_mb()}))
"""


def episode(n: int, seed: int) -> dict:
    output = subprocess.run([sys.executable, "-c", CHILD, str(n), str(seed)], check=True,
                            capture_output=True, text=True).stdout
    return json.loads(output.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    rows = [
        "| aircraft | episode wall (median) | per decision (median) | decisions | feasible fraction per decision (mean; min) | fallbacks | peak memory |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in (4, 6):
        runs = [episode(n, seed) for seed in range(args.seeds)]
        rows.append(
            f"| {n} | {statistics.median(r['wall_s'] for r in runs):.2f} s "
            f"| {1e3 * statistics.median(r['decision_s'] for r in runs):.1f} ms "
            f"| {statistics.median(r['decisions'] for r in runs):.0f} "
            f"| {statistics.mean(r['feasible_mean'] for r in runs):.2f}; {min(r['feasible_min'] for r in runs):.3f} "
            f"| {sum(r['fallbacks'] for r in runs)} "
            f"| {max(r['peak_rss_mb'] for r in runs):.0f} MB |"
        )
        print(rows[-1], flush=True)
    text = "\n".join(
        [
            "## MCMC-MPC at the paper's settings",
            "",
            f"`python bench/bench_mpc.py` — K = 1000, N = 4, T = 5 min, converging-N under wind "
            f"(σ = 5.17 m/s), seeds 0..{args.seeds - 1}, one fresh process per episode, {machine()}.",
            "",
            *rows,
            "",
            "Targets: 4 aircraft <= 1 s and 6 aircraft <= 5 s per episode, peak memory <= 300 MB "
            "(the paper: 200 s and 1500 s, 110 MB and 130 MB).",
        ]
    )
    print(text)
    if args.write:
        write_section("mpc", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
