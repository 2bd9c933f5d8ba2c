"""Train PPO (Stable-Baselines3) on copies of the PettingZoo env in worker processes
(SuperSuit), one policy shared by every aircraft, seeded with ``seed=0``.

    python examples/train_supersuit_sb3.py --copies 8 --cpus 2 --timesteps 200000

Needs stable-baselines3 and supersuit (``pip install '.[rl]'``). For one process, the
native vector env is faster: ``atc_nf_env.envs.vector.make_sb3_vec_env(B, mode="shared")``.
"""

from __future__ import annotations

import argparse

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor

from atc_nf_env.integrations.supersuit import make_supersuit_sb3_vec_env


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="converging-4")
    parser.add_argument("--copies", type=int, default=2, help="copies of the env (each with every aircraft)")
    parser.add_argument("--cpus", type=int, default=2, help="worker processes")
    parser.add_argument("--timesteps", type=int, default=1024, help="agent steps to train")
    args = parser.parse_args(argv)

    venv = VecMonitor(make_supersuit_sb3_vec_env(args.copies, args.cpus, scenario=args.scenario, max_cycles=36))
    model = PPO("MlpPolicy", venv, seed=0, n_steps=64, batch_size=128, n_epochs=2, verbose=0)
    model.learn(args.timesteps)
    returns = [info["r"] for info in model.ep_info_buffer]
    mean_return = float(np.mean(returns)) if returns else float("nan")
    print(f"{model.num_timesteps} agent steps in {venv.num_envs} SB3 envs over {args.cpus} processes; "
          f"{len(returns)} aircraft episodes, mean return {mean_return:.2f}", flush=True)
    venv.close()
    return mean_return


if __name__ == "__main__":
    main()
