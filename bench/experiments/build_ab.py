"""A build before a change and the working tree, side by side on one machine.

This script checks out a commit (``--before``) into a temporary git worktree and times the
same workloads with it and with the working tree, in fresh processes that alternate round
by round (the tree on ``PYTHONPATH`` is the one imported; each process warms up first, so
compilation and cache loads stay out of the figures). It measured:

- the kernel without numba's reference counts (``nf.NO_REFERENCE_COUNTS``, since 32bcca8):
  ``--before 530130e``;
- the safety filter's routine decision in one compiled call (``PlanPredictor.screen``):
  ``--before 2ac34f5 --what shield``.

The workloads:

- ``kernel``: one 5-min period of converging-4 and converging-6 per ``kernel.advance``
  call, B = 1 and B = 1000, in aircraft-steps per second;
- ``shield``: ``finetuned_ppo`` inside the safety filter on each of ``--scenarios``, the
  mean and the median decision over seeds 0..SEEDS-1;
- ``mpc``: the MCMC-MPC's mean decision on converging-4 and converging-6, seeds
  0..MPC_SEEDS-1.

For both changes the two trees fly the same trajectories bit for bit
(``bench/kernel_trajectory_hash.py``; the full regeneration, ``bench/regenerate.sh``, gave
every run's outcome unchanged); reported are medians over rounds of each tree's figure
and of the per-round ratio after/before.

Run: python bench/experiments/build_ab.py --before COMMIT [--what kernel,shield,mpc] [--rounds 5]
[--seeds 20] [--mpc-seeds 2] [--scenarios converging-4,converging-6,random-4,random-6]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: The measurement each process runs: prints one JSON object of figures.
WORKER = r"""
import json, sys, time
import numpy as np
what, seeds, mpc_seeds, scenarios = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4].split(",")
import atc_nf_env
out = {"tree": atc_nf_env.__file__}
if what == "kernel":
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.simulation import initial_state
    for n_worlds, n in ((1, 4), (1, 6), (1000, 4), (1000, 6)):
        sc = make_scenario(f"converging-{n}")
        start = initial_state(sc, n_worlds)
        params = SimConfig().to_params(sc.workspace_radius_nm)
        wp = start[:, :, kernel.S_WP_X : kernel.S_WP_Y + 1].copy()
        wind = np.zeros((n_worlds, 2))
        scratch = kernel.KernelScratch()
        kernel.advance(start.copy(), wp, wind, 300.0, params, scratch=scratch)
        calls, elapsed = 0, 0.0
        while elapsed < 1.5:
            state = start.copy()
            t0 = time.perf_counter()
            kernel.advance(state, wp, wind, 300.0, params, scratch=scratch)
            elapsed += time.perf_counter() - t0
            calls += 1
        out[f"B={n_worlds} N={n} (M aircraft-steps/s)"] = calls * n_worlds * n * 60 / elapsed / 1e6
else:
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    if what == "shield":
        from atc_nf_env.shield import SafetyFilter
        policy, cases, n_seeds = SafetyFilter(make_policy("agents/models/finetuned_ppo.zip")), scenarios, seeds
    else:
        policy, cases, n_seeds = make_policy("mpc"), ("converging-4", "converging-6"), mpc_seeds
    for name in cases:
        run_episode(policy, make_scenario(name, seed=10**6), seed=10**6)
        times = []
        for seed in range(n_seeds):
            times += list(run_episode(policy, make_scenario(name, seed=seed), seed=seed).decision_s)
        unit = "us" if what == "shield" else "ms"
        scale = 1e6 if unit == "us" else 1e3
        out[f"{name} mean decision ({unit})"] = float(np.mean(times)) * scale
        if what == "shield":
            out[f"{name} median decision ({unit})"] = float(np.median(times)) * scale
print(json.dumps(out))
"""


def measure(tree: Path, what: str, seeds: int, mpc_seeds: int, scenarios: str) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    result = subprocess.run([sys.executable, "-c", WORKER, what, str(seeds), str(mpc_seeds), scenarios], cwd=tree,
                            env=env,
                            capture_output=True, text=True, check=True)
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    imported = Path(figures.pop("tree")).resolve()
    if not imported.is_relative_to(tree.resolve()):
        raise RuntimeError(f"the worker imported {imported}, not the tree {tree}")
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="the commit before the change (530130e, 2ac34f5, ...)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--seeds", type=int, default=20, help="shielded episodes per scenario and round")
    parser.add_argument("--mpc-seeds", type=int, default=2, help="MPC episodes per scenario and round")
    parser.add_argument("--what", default="kernel,shield,mpc")
    parser.add_argument("--scenarios", default="converging-4,converging-6,random-4,random-6",
                        help="the shielded workload's scenarios")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        before = Path(tmp) / "before"
        subprocess.run(["git", "worktree", "add", "--detach", str(before), args.before], cwd=ROOT, check=True,
                       capture_output=True)
        try:
            for what in args.what.split(","):
                rows: dict[str, dict[str, list[float]]] = {}
                for round_ in range(args.rounds):
                    order = (("before", before), ("after", ROOT))
                    for label, tree in order if round_ % 2 == 0 else order[::-1]:
                        for key, value in measure(tree, what, args.seeds, args.mpc_seeds, args.scenarios).items():
                            rows.setdefault(key, {"before": [], "after": []})[label].append(value)
                print(f"{what}: medians over {args.rounds} rounds (before = {args.before}, after = the working tree)")
                for key, values in rows.items():
                    ratios = [a / b for a, b in zip(values["after"], values["before"])]
                    print(f"  {key}: before {statistics.median(values['before']):.2f}, after "
                          f"{statistics.median(values['after']):.2f}, after/before {statistics.median(ratios):.2f} "
                          f"[{min(ratios):.2f}-{max(ratios):.2f}]", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(before)], cwd=ROOT, check=False,
                           capture_output=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
