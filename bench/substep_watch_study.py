"""Guard 8's watch on the 1/P_i term: what each threshold buys at the saddle and costs elsewhere.

The kernel flies a step in 0.1-s sub-steps where any aircraft's 1/P_i term of (5a),
(∂Φ_i/∂t)⁺ / |P_i|, exceeds ``SimConfig.substep_from_kt`` (the watch), so that the
right-hand rule's ramp, from ``right_turn_from_kt``, is entered finely whatever the
step (at a step's start, and among neighbours at its end: guard 10). For each threshold:

* at the saddle (the NF alone, converging-3 ... 8 without wind): the largest move of the
  minimum separation when a step of 5 s or less is halved, for the exact encounter and
  for the mean of an ensemble of starts perturbed by 1e-9 nm
  (``integration_step_study``);
* elsewhere: the mean decision time of the MCMC-MPC and of ``finetuned_ppo`` inside the
  safety filter on converging-6 and random-6 under wind (σ = 5.17 m/s, seeds 0..S-1),
  flown side by side in one process, as a ratio to the kernel without a watch (the
  threshold beyond any term: a step is refined only where a command saturates or the
  right-hand rule acts).
  A neighbour closing in gives a term of tens of kt in ordinary flight, where the watch
  refines steps that need no refining.

Run: python bench/substep_watch_study.py [--seeds 8] [--write]
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np
from _report import machine, publish  # bench/ is on sys.path when run as a script
from integration_step_study import (
    ENSEMBLE_SIZE,
    PERTURBATION_NM,
    SADDLE_AIRCRAFT,
    SMALL_STEPS,
    ensemble_study,
    saddle_separations,
)

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.shield import SafetyFilter

from baselines import MCMCMPC

#: Thresholds studied, kt; the last, beyond any term, is the kernel without a watch.
NO_WATCH_KT = 1e9
THRESHOLDS_KT = (10.0, 25.0, 50.0, 100.0, NO_WATCH_KT)
AGENT = "agents/models/finetuned_ppo.zip"
COST_CASES = (("mpc", "converging-6"), ("mpc", "random-6"), ("shield", "converging-6"), ("shield", "random-6"))


def saddle_moves(threshold: float) -> tuple[float, float]:
    """(largest move of the exact encounter's minimum separation, of the ensemble's mean)
    on halving a step of 5 s or less, over converging-3 ... 8, nm."""
    overrides = {"substep_from_kt": threshold}
    exact = 0.0
    for n in SADDLE_AIRCRAFT:
        seps = [sep for sep, _, _ in saddle_separations("default", overrides, n, SMALL_STEPS)]
        exact = max(exact, float(np.abs(np.diff(seps)).max()))
    _, ensemble, _ = ensemble_study("default", overrides)
    return exact, ensemble


def decision_seconds(kind: str, scenario: str, seed: int, config: SimConfig) -> float:
    """Mean wall time of a decision over one episode, s."""
    if kind == "mpc":
        policy = MCMCMPC()
    else:
        from agents.policy import SB3AgentPolicy

        policy = SafetyFilter(SB3AgentPolicy(AGENT, outside_range="ignore"))
    return run_episode(policy, make_scenario(scenario, seed=seed), seed=seed, config=config).metrics.decision_s_mean


def costs(seeds: int) -> dict[tuple[str, str], dict[float, float]]:
    """Per case and threshold: the mean decision time over the seeds as a ratio to the
    kernel without a watch, every threshold flown on each seed in turn."""
    configs = {t: SimConfig().replace(substep_from_kt=t) for t in THRESHOLDS_KT}
    out = {}
    for kind, scenario in COST_CASES:
        decision_seconds(kind, scenario, 0, configs[NO_WATCH_KT])  # warm-up, untimed
        times: dict[float, list[float]] = {t: [] for t in THRESHOLDS_KT}
        for seed in range(seeds):
            for t, config in configs.items():
                times[t].append(decision_seconds(kind, scenario, seed, config))
        base = float(np.mean(times[NO_WATCH_KT]))
        out[(kind, scenario)] = {t: float(np.mean(v)) / base for t, v in times.items()}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=8, help="seeds per cost case")
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*outside its operating range.*")
    moves = {t: saddle_moves(t) for t in THRESHOLDS_KT}
    cost = costs(args.seeds)
    default = SimConfig().substep_from_kt
    cases = [f"{'MPC' if kind == 'mpc' else 'finetuned_ppo+shield'}, {scenario}" for kind, scenario in COST_CASES]
    lines = [
        "## Guard 8's watch: the threshold",
        "",
        f"`python bench/substep_watch_study.py --seeds {args.seeds}` — {machine()}. Saddle: the NF alone, "
        "converging-3 ... 8 without wind, largest move of the minimum separation on halving a step of 5 s or "
        f"less, for the exact encounter and for the mean of {ENSEMBLE_SIZE} starts perturbed by {PERTURBATION_NM:g} nm. "
        "Cost: mean decision "
        f"time over seeds 0..{args.seeds - 1} (σ = 5.17 m/s), flown side by side, over the kernel without a watch "
        "(sub-steps only where a command saturates or the right-hand rule acts).",
        "",
        "| watch from (kt) | saddle: exact encounter | saddle: ensemble mean | " + " | ".join(cases) + " |",
        "|---:|---:|---:|" + "---:|" * len(cases),
    ]
    for t in THRESHOLDS_KT:
        label = "none" if t == NO_WATCH_KT else f"{t:g}" + (" (default)" if t == default else "")
        ratios = " | ".join(f"{cost[case][t]:.2f}×" for case in COST_CASES)
        lines.append(f"| {label} | {moves[t][0]:.2f} nm | {moves[t][1]:.2f} nm | {ratios} |")
    lines += [
        "",
        f"The default watch is {default:g} kt; the right-hand rule acts from {SimConfig().right_turn_from_kt:g} kt.",
        "",
    ]
    text = "\n".join(lines)
    return publish("substep-watch", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
