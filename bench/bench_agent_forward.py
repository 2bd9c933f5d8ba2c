"""The agents' forward pass: compiled (``agents.compiled_forward``) against the NumPy pass it
replaced, side by side.

The NumPy pass is kept here, as it was, as the yardstick (``numpy_actions``): per layer a
matrix product, a bias addition and an activation; for the deep-sets extractor the masks,
the pooling and the concatenation as arrays. For every shipped model the observations of
every decision of seeds 0..SEEDS-1 of each scenario are collected from the model flying
them, and then each decision's observations go through both passes, alternately, in
rounds:

- **hot**: one pass after the other on the same observations, again and again (medians);
- **between flights**: each decision's pass timed once after the kernel has flown that
  decision's 5-min period (``kernel.advance`` on a copy of the world), as in an episode,
  where the kernel's code and data have pushed the pass's out of the caches.

Both passes are checked to give the same actions to float32 rounding (and against SB3's
``predict``) before anything is timed.

Run: python bench/bench_agent_forward.py [--seeds 20] [--scenarios converging-4,random-6] [--write]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from _report import machine, publish  # bench/ is on sys.path when run as a script

ROOT = Path(__file__).resolve().parent.parent


def numpy_actions(model) -> callable:
    """The NumPy forward pass as ``SB3AgentPolicy`` computed it before the compiled one
    (PPO's clipped Gaussian mean, MLP or deep-sets extractor)."""
    import torch.nn as nn

    from agents.deepsets import N_NEIGHBOUR, N_OWN, NeighbourSetExtractor

    def layers_of(sequential):
        out = []
        for module in sequential:
            if isinstance(module, nn.Linear):
                out.append([np.ascontiguousarray(module.weight.detach().numpy().astype(np.float32).T),
                            module.bias.detach().numpy().astype(np.float32).copy(), False])
            elif isinstance(module, nn.Tanh):
                out[-1][2] = True
            else:
                raise TypeError(f"the yardstick handles Linear and Tanh, not {type(module).__name__}")
        return out

    def mlp(x, layers):
        for weight, bias, tanh in layers:
            x = x @ weight
            x += bias
            if tanh:
                np.tanh(x, out=x)
        return x

    policy = model.policy
    head = layers_of(policy.mlp_extractor.policy_net) + layers_of([policy.action_net])
    extractor = policy.features_extractor
    if isinstance(extractor, NeighbourSetExtractor):
        own_layers, phi_layers, k = layers_of(extractor.own), layers_of(extractor.phi), extractor.n_slots

        def features(obs):
            b = obs.shape[0]
            own = mlp(obs[:, :N_OWN], own_layers)
            slots = obs[:, N_OWN:].reshape(b, k, N_NEIGHBOUR)
            mask = slots[:, :, :1]
            encoded = mlp(slots[:, :, 1:].reshape(b * k, N_NEIGHBOUR - 1), phi_layers).reshape(b, k, -1)
            encoded *= mask
            count = mask.sum(axis=1)
            mean = encoded.sum(axis=1) / np.maximum(count, 1.0)
            largest = np.where(mask > 0, encoded, np.float32(-2.0)).max(axis=1)
            largest = np.where(count > 0, largest, np.float32(0.0))
            return np.concatenate([own, mean, largest], axis=1).astype(np.float32, copy=False)
    else:
        def features(obs):
            return obs

    def forward(obs):
        x = mlp(features(np.asarray(obs, dtype=np.float32)), head)
        np.minimum(x, 1.0, out=x)
        return np.maximum(x, -1.0, out=x)

    return forward


def collect(model_path: str, scenario_name: str, seeds: int) -> list[tuple]:
    """(observations, state, waypoints, wind) of every decision the model makes on the seeds."""
    from agents.policy import SB3AgentPolicy
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario

    policy = SB3AgentPolicy(model_path, outside_range="ignore")
    decisions: list[tuple] = []
    act = policy.act

    def recording_act(view):
        waypoints = act(view)
        decisions.append((policy.observe(view), view.state.copy(), np.asarray(waypoints, dtype=np.float64)))
        return waypoints

    policy.act = recording_act
    for seed in range(seeds):
        start = len(decisions)
        result = run_episode(policy, make_scenario(scenario_name, seed=seed), seed=seed)
        wind = np.asarray(result.metrics.wind_kt, dtype=np.float64)
        decisions[start:] = [(*d, wind) for d in decisions[start:]]
    return decisions


def measure(model_path: str, scenario_name: str, seeds: int, rounds: int) -> dict:
    from agents.policy import SB3AgentPolicy
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.units import DECISION_PERIOD_S

    policy = SB3AgentPolicy(model_path, outside_range="ignore")
    compiled, yardstick = policy._forward, numpy_actions(policy.model)
    decisions = collect(model_path, scenario_name, seeds)
    for obs, *_ in decisions[:: max(1, len(decisions) // 50)]:
        expected, _ = policy.model.predict(obs, deterministic=True)
        for forward in (compiled, yardstick):
            np.testing.assert_allclose(forward(obs), expected, atol=1e-5)
    hot = {"compiled": [], "numpy": []}
    for r in range(rounds):
        for name, forward in (("compiled", compiled), ("numpy", yardstick))[:: 1 if r % 2 else -1]:
            times = []
            for obs, *_ in decisions:
                t0 = time.perf_counter()
                forward(obs)
                times.append(time.perf_counter() - t0)
            hot[name].append(np.median(times))
    config = SimConfig()
    params = config.to_params(make_scenario(scenario_name, seed=0).workspace_radius_nm)
    scratch = kernel.KernelScratch()
    cold = {"compiled": [], "numpy": []}
    for i, (obs, state, waypoints, wind) in enumerate(decisions):
        for name, forward in (("compiled", compiled), ("numpy", yardstick))[:: 1 if i % 2 else -1]:
            world = state[None].copy()
            kernel.advance(world, waypoints[None], wind[None], DECISION_PERIOD_S, params, scratch=scratch)
            t0 = time.perf_counter()
            forward(obs)
            cold[name].append(time.perf_counter() - t0)
    return {
        "decisions": len(decisions),
        "hot": {k: float(np.median(v)) for k, v in hot.items()},
        "cold": {k: (float(np.median(v)), float(np.mean(v))) for k, v in cold.items()},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=20, help="episodes per scenario and model (seeds 0..N-1)")
    parser.add_argument("--scenarios", default="converging-4,random-6")
    parser.add_argument("--models", default=",".join(str(p.relative_to(ROOT)) for p in
                                                     sorted((ROOT / "agents" / "models").glob("*.zip"))))
    parser.add_argument("--rounds", type=int, default=7, help="hot rounds per pass (alternating)")
    parser.add_argument("--write", action="store_true", help="rewrite the section of BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.rounds < 1:
        parser.error("--seeds and --rounds must be >= 1")

    def us(seconds: float) -> str:
        return f"{seconds * 1e6:.1f} µs"

    rows = [
        "| scenario | model | decisions | hot: NumPy / compiled (median) | ratio | between flights: NumPy / "
        "compiled (median; mean) | ratio of medians |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    load = [os.getloadavg()[0]]
    for scenario in [s for s in args.scenarios.split(",") if s]:
        for model in [m for m in args.models.split(",") if m]:
            r = measure(model, scenario, args.seeds, args.rounds)
            hot, cold = r["hot"], r["cold"]
            rows.append(
                f"| {scenario} | {Path(model).stem} | {r['decisions']} | {us(hot['numpy'])} / {us(hot['compiled'])} "
                f"| {hot['numpy'] / hot['compiled']:.1f}× | {us(cold['numpy'][0])} / {us(cold['compiled'][0])} "
                f"({us(cold['numpy'][1])} / {us(cold['compiled'][1])}) | {cold['numpy'][0] / cold['compiled'][0]:.1f}× |"
            )
            print(rows[-1], flush=True)
            load.append(os.getloadavg()[0])
    text = "\n".join([
        "## Agents: the forward pass",
        "",
        f"`python bench/bench_agent_forward.py --seeds {args.seeds} --scenarios {args.scenarios}` — each shipped "
        "model's deterministic action for all aircraft of one decision: the compiled pass "
        "(`agents/compiled_forward.py`, what `SB3AgentPolicy` flies) against the NumPy pass it replaced (kept in "
        "the bench as the yardstick), side by side on the observations of every decision of seeds "
        f"0..{args.seeds - 1}; both checked against SB3's `predict` first. Hot: medians over the decisions, "
        f"the median of {args.rounds} alternating rounds. Between flights: each decision's pass timed once right "
        "after the kernel flew that decision's period, as in an episode. "
        f"{machine()}; 1-min load average {min(load):.1f}–{max(load):.1f} during the run. The observation and "
        "the action mapping around the pass are the same for both and not included.",
        "",
        *rows,
    ])
    return publish("agent-forward", text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
