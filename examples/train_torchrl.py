"""Train IPPO or MAPPO with TorchRL on a benchmark task, then score the policy on the test split.

    python examples/train_torchrl.py --algorithm mappo --task converging-4 --frames 100000 --out runs/mappo-c4

Needs torchrl and tensordict (``examples/requirements-torch.txt``). The env is
``atc_nf_env.integrations.torchrl.AtcNfBatchedEnv`` (all worlds of a batch in one kernel
call); the networks, PPO loop, learning curve and saved policy are those of
``agents.marl_torchrl.train`` (read it for the details: a policy shared by every
aircraft, MultiAgentMLP, ClipPPOLoss, GAE per aircraft; MAPPO's critic also sees the
global state). The saved ``policy.pt`` flies anywhere a policy file does:
``atc-nf benchmark --policy runs/mappo-c4/policy.pt --task converging-4 --split test``.
"""

from __future__ import annotations

# agents.marl_torchrl first: it sets OMP_WAIT_POLICY=PASSIVE before torch loads OpenMP
# (otherwise the kernel's idle threads spin against torch's updates on a small machine).
from agents.marl_torchrl import ALGORITHMS, PPOConfig, score, train  # noqa: I001

import argparse
import csv
from pathlib import Path

from atc_nf_env.benchmark import format_card


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algorithm", choices=ALGORITHMS, default="mappo")
    parser.add_argument("--task", default="converging-4")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=100_000, help="decision periods summed over worlds")
    parser.add_argument("--num-envs", type=int, default=PPOConfig.num_envs)
    parser.add_argument("--steps-per-batch", type=int, default=PPOConfig.steps_per_batch)
    parser.add_argument("--eval-runs", type=int, default=PPOConfig.eval_runs)
    parser.add_argument("--test-runs", type=int, default=50, help="test-split runs to score (0: none)")
    parser.add_argument("--out", type=Path, default=Path("runs/torchrl"))
    args = parser.parse_args(argv)

    config = PPOConfig(num_envs=args.num_envs, steps_per_batch=args.steps_per_batch,
                       minibatch_frames=min(PPOConfig.minibatch_frames, args.num_envs * args.steps_per_batch),
                       eval_runs=args.eval_runs)
    policy = train(args.algorithm, args.task, args.seed, args.frames, args.out, config)
    with open(args.out / "curve.csv") as handle:
        last = list(csv.DictReader(handle))[-1]
    print(f"trained {policy}: {last['frames']} frames in {last['wall_s']} s; validation runs safe "
          f"{float(last['eval_safe_share']):.0%}, home {float(last['eval_home_share']):.0%}")
    if args.test_runs:
        print(format_card(score(policy, args.task, "test", args.test_runs)))


if __name__ == "__main__":
    main()
