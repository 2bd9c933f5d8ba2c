"""Train MAPPO with TorchRL on the encounter: a policy shared by every aircraft, a
centralized critic, a collector and PPO's clipped loss.

    python examples/train_torchrl.py --iterations 50

Needs torchrl and tensordict (``examples/requirements-torch.txt``). The env comes from
``atc_nf_env.integrations.torchrl.make_torchrl_env`` (``use_mask=True``: aircraft leave
on arrival; ``done_on_any=False``: the encounter goes on until the last has).
"""

from __future__ import annotations

import argparse

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from atc_nf_env.integrations.torchrl import make_torchrl_env

GROUP = "aircraft"


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="converging-4")
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--frames", type=int, default=120, help="env steps per iteration")
    args = parser.parse_args(argv)
    torch.manual_seed(0)

    env = make_torchrl_env(scenario=args.scenario, max_cycles=36, seed=0)
    env = TransformedEnv(env, RewardSum(in_keys=[(GROUP, "reward")], out_keys=[(GROUP, "episode_reward")]))
    n_agents = len(env.group_map[GROUP])
    obs_dim = env.observation_spec[GROUP, "observation"].shape[-1]
    action_spec = env.full_action_spec[GROUP, "action"]

    actor_net = nn.Sequential(
        MultiAgentMLP(obs_dim, 2 * action_spec.shape[-1], n_agents, centralized=False, share_params=True,
                      depth=2, num_cells=64, activation_class=nn.Tanh),
        NormalParamExtractor(),
    )
    policy = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "loc"), (GROUP, "scale")]),
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        spec=env.full_action_spec,
        return_log_prob=True,
    )
    critic = TensorDictModule(  # MAPPO: each aircraft's value from every aircraft's observation
        MultiAgentMLP(obs_dim, 1, n_agents, centralized=True, share_params=True, depth=2, num_cells=64,
                      activation_class=nn.Tanh),
        in_keys=[(GROUP, "observation")],
        out_keys=[(GROUP, "state_value")],
    )
    collector = Collector(env, policy, frames_per_batch=args.frames,
                                  total_frames=args.frames * args.iterations)
    loss = ClipPPOLoss(policy, critic, clip_epsilon=0.2, entropy_coeff=1e-3, normalize_advantage=False)
    loss.set_keys(reward=(GROUP, "reward"), action=(GROUP, "action"), value=(GROUP, "state_value"),
                  done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=0.99, lmbda=0.95)
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)

    mean_return = float("nan")
    for iteration, batch in enumerate(collector):
        with torch.no_grad():
            loss.value_estimator(batch, params=loss.critic_network_params, target_params=loss.target_critic_network_params)
        for _ in range(4):
            terms = loss(batch)
            total = terms["loss_objective"] + terms["loss_critic"] + terms["loss_entropy"]
            optimizer.zero_grad()
            total.backward()
            nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
            optimizer.step()
        collector.update_policy_weights_()
        ended = batch["next", GROUP, "done"].squeeze(-1).any(-1)  # steps where some aircraft ended
        returns = batch["next", GROUP, "episode_reward"][ended]
        mean_return = float(returns.mean()) if returns.numel() else float("nan")
        print(f"iteration {iteration + 1}: frames {batch.numel()}, loss {float(total):.3f}, "
              f"mean return of aircraft that ended {mean_return:.2f}", flush=True)
    collector.shutdown()
    return mean_return


if __name__ == "__main__":
    main()
