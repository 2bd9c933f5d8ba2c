"""TorchRL env throughput: ``AtcNfBatchedEnv`` (B worlds in one kernel call) against
TorchRL's ``PettingZooWrapper`` over ``parallel_env`` (one world), side by side.

Both fly converging-4 (wind σ = 5.17 m/s) with uniform random actions drawn from the
env's action spec (TorchRL's ``rollout`` without a policy), resets included
(``break_when_any_done=False``: TorchRL resets the worlds that ended, the batched env
through its ``"_reset"`` mask). A *frame* is one decision period (5 min) of one world,
TorchRL's count of env steps over the batch; an aircraft-decision is one aircraft slot
of one frame (M = 4 per frame here). Both are warmed up first (numba compilation, not
timed), then measured in alternating rounds; the medians over rounds are printed, and
the ratio batched / PettingZooWrapper of frames per second.

Run (needs torchrl, ``examples/requirements-torch.txt``):

    OMP_WAIT_POLICY=PASSIVE python bench/bench_torchrl_env.py [--worlds 32 256] [--rounds 3] [--seconds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch


def frames_per_s(env, steps: int, seconds: float) -> float:
    """Frames per second of ``env.rollout(steps)`` repeated for about ``seconds``."""
    frames = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        rollout = env.rollout(steps, break_when_any_done=False)
        frames += rollout.numel()
    return frames / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, nargs="+", default=[32, 256], help="B of the batched env")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=3.0, help="per loop and round")
    parser.add_argument("--scenario", default="converging-4")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)

    from atc_nf_env.integrations.torchrl import AtcNfBatchedEnv, make_torchrl_env

    envs = {"PettingZooWrapper (1 world)": (make_torchrl_env(scenario=args.scenario, seed=0), 64)}
    for b in args.worlds:
        envs[f"AtcNfBatchedEnv (B = {b})"] = (AtcNfBatchedEnv(b, seed=0, scenario=args.scenario), 32)
    for env, steps in envs.values():  # warm-up: compilation and caches
        env.rollout(steps, break_when_any_done=False)
    rates: dict[str, list[float]] = {name: [] for name in envs}
    for _ in range(args.rounds):
        for name, (env, steps) in envs.items():
            rates[name].append(frames_per_s(env, steps, args.seconds))
    slots = next(iter(envs.values()))[0].group_map["aircraft"].__len__()
    base = statistics.median(rates["PettingZooWrapper (1 world)"])
    print(f"{args.scenario}, random actions, resets included; median of {args.rounds} rounds of {args.seconds:g} s; "
          f"torch {torch.__version__}")
    print(f"{'env':<30} {'frames/s':>10} {'aircraft-decisions/s':>22} {'ratio':>8}")
    for name, values in rates.items():
        rate = statistics.median(values)
        print(f"{name:<30} {rate:>10.0f} {rate * slots:>22.0f} {rate / base:>8.1f}")


if __name__ == "__main__":
    main()
