"""Train AgileRL's IPPO or MADDPG on the PettingZoo parallel env (one population member,
no evolution: the plain algorithm).

    python examples/train_agilerl.py --algo ippo --steps 20000
    python examples/train_agilerl.py --algo maddpg --steps 20000 --num-envs 4

Needs ``agilerl`` and ``peft`` (``examples/requirements-agilerl.txt``; give it its own
venv, ``make test-integrations`` builds one). AgileRL's ``AsyncPettingZooVecEnv`` runs
``--num-envs`` copies of the env in worker processes and keeps aircraft that have
arrived as placeholders, so the env needs no wrapper. MADDPG's exploration noise has one
row per env copy: it must be built with ``vect_noise_dim`` equal to ``--num-envs``.
AgileRL's trainer closes the vector env when it returns.
"""

from __future__ import annotations

import argparse

from agilerl.algorithms import IPPO, MADDPG
from agilerl.components.replay_buffer import ReplayBuffer
from agilerl.training.train_multi_agent_off_policy import train_multi_agent_off_policy
from agilerl.training.train_multi_agent_on_policy import train_multi_agent_on_policy
from agilerl.vector.pz_async_vec_env import AsyncPettingZooVecEnv

import atc_nf_env


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=["ippo", "maddpg"], default="ippo")
    parser.add_argument("--scenario", default="converging-4")
    parser.add_argument("--steps", type=int, default=512, help="environment steps over all copies")
    parser.add_argument("--num-envs", type=int, default=2, help="env copies in worker processes")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    def make_env() -> object:
        return atc_nf_env.parallel_env(scenario=args.scenario, max_cycles=36)

    env = AsyncPettingZooVecEnv([make_env for _ in range(args.num_envs)])
    env.reset(seed=args.seed)
    agent_ids = list(env.agents)
    observation_spaces = [env.single_observation_space(agent) for agent in agent_ids]
    action_spaces = [env.single_action_space(agent) for agent in agent_ids]
    evo_steps = max(args.steps // 2, 1)
    if args.algo == "ippo":
        agent = IPPO(observation_spaces, action_spaces, agent_ids=agent_ids, learn_step=128, batch_size=64)
        _, fitnesses = train_multi_agent_on_policy(
            env, "atc_nf_env", "IPPO", [agent], max_steps=args.steps, evo_steps=evo_steps, verbose=False
        )
    else:
        agent = MADDPG(
            observation_spaces, action_spaces, agent_ids=agent_ids, vect_noise_dim=args.num_envs, batch_size=64,
            learn_step=16,
        )
        _, fitnesses = train_multi_agent_off_policy(
            env, "atc_nf_env", "MADDPG", [agent], ReplayBuffer(max_size=100_000), max_steps=args.steps,
            evo_steps=evo_steps, learning_delay=64, verbose=False,
        )
    fitness = float(fitnesses[-1])
    print(f"{args.algo}: {args.steps} env steps, last evaluation return {fitness:.2f}", flush=True)
    return fitness


if __name__ == "__main__":
    main()
