"""Train PPO with RLlib on the encounter: one policy shared by every aircraft.

    python examples/train_rllib.py                    # PettingZoo parallel form
    python examples/train_rllib.py --form aec         # AEC form (agents act in turn)
    python examples/train_rllib.py --form centralized # one agent steering every aircraft
    RAY_ADDRESS=auto python examples/train_rllib.py --env-runners 64 --iterations 500

Needs ``ray[rllib]`` (``examples/requirements-rllib.txt``: it pins gymnasium 1.2.2, so
give it its own venv; ``make test-integrations`` builds one).

The one setting that spreads the env runners over a Ray cluster is the address given to
``ray.init``: run this on a node of the cluster with ``RAY_ADDRESS=auto`` (or the head's
address) and the ``--env-runners`` actors are placed across its nodes; every runner
builds its env from the name registered by ``register_envs``.
"""

from __future__ import annotations

import argparse
import os

import ray
from ray.rllib.algorithms.ppo import PPOConfig

from atc_nf_env.integrations.rllib import register_envs


def shared_policy(agent_id: str, episode: object, **kwargs: object) -> str:
    return "shared"


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--form", choices=["parallel", "aec", "centralized"], default="parallel")
    parser.add_argument("--scenario", default="converging-4")
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--env-runners", type=int, default=1, help="remote env runners (0: sample in this process)")
    parser.add_argument("--batch", type=int, default=256, help="agent steps per training batch")
    args = parser.parse_args(argv)

    ray.init(address=os.environ.get("RAY_ADDRESS"), include_dashboard=False, log_to_driver=False)
    names = dict(zip(("parallel", "aec", "centralized"), register_envs()))
    config = (
        PPOConfig()
        .environment(names[args.form], env_config={"scenario": args.scenario, "max_cycles": 36})
        .env_runners(num_env_runners=args.env_runners, rollout_fragment_length="auto")
        .training(train_batch_size_per_learner=args.batch, minibatch_size=64, num_epochs=2, lr=3e-4)
        .debugging(seed=0)
    )
    if args.form != "centralized":  # one policy shared by every aircraft
        config = config.multi_agent(policies={"shared"}, policy_mapping_fn=shared_policy)
    algo = config.build_algo()
    episode_return = float("nan")
    try:
        for iteration in range(args.iterations):
            result = algo.train()
            runners = result["env_runners"]
            episode_return = float(runners.get("episode_return_mean", float("nan")))
            print(
                f"iteration {iteration + 1}: env steps {runners.get('num_env_steps_sampled_lifetime')}, "
                f"episodes {runners.get('num_episodes_lifetime')}, mean return {episode_return:.2f}",
                flush=True,
            )
    finally:
        algo.stop()
        ray.shutdown()
    return episode_return


if __name__ == "__main__":
    main()
