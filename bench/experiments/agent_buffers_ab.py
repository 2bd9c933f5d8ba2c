"""``SB3AgentPolicy.act`` on its kept buffers against its general path, episode by episode in one process.

Since ``act`` decides on buffers it keeps between decisions (``ObservationSpec.observe_into``
and the compiled forward pass's ``compute``, where the state fits them), it skips the
Python layers of ``observe`` and ``actions``. Here one agent flies every seed twice, with
the buffers and with them switched off (``_buffers = None`` after each reset: the general
path), in alternating order, and the two flights are checked to give the same waypoints.

Reported per scenario: the mean and median decision (µs) of each path over all decisions,
and the median, over seeds, of each seed's mean decision kept / general, with quartiles.

Run: python bench/experiments/agent_buffers_ab.py [--seeds 40] [--scenarios converging-4,random-6]
[--model agents/models/finetuned_ppo.zip]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--scenarios", default="converging-4,random-6")
    parser.add_argument("--model", default=str(ROOT / "agents/models/finetuned_ppo.zip"))
    args = parser.parse_args(argv)

    from agents.policy import SB3AgentPolicy
    from atc_nf_env.episode import run_episode
    from atc_nf_env.scenarios import make_scenario

    class General(SB3AgentPolicy):
        def reset(self, scenario, config, seed=None) -> None:
            super().reset(scenario, config, seed)
            self._buffers = None

    agents = {"kept": SB3AgentPolicy(args.model), "general": General(args.model)}
    print(f"{Path(args.model).stem}: act on kept buffers and on the general path, seeds 0..{args.seeds - 1}, "
          "alternating episode by episode in one process:")
    for name in args.scenarios.split(","):
        for agent in agents.values():
            run_episode(agent, make_scenario(name, seed=10**6), seed=10**6)  # warm-up, not timed
        times: dict[str, list[float]] = {"kept": [], "general": []}
        per_seed: dict[str, list[float]] = {"kept": [], "general": []}
        for seed in range(args.seeds):
            flown = {}
            for label in (("kept", "general") if seed % 2 else ("general", "kept")):
                result = run_episode(agents[label], make_scenario(name, seed=seed), seed=seed)
                flown[label] = result.waypoints
                times[label] += list(result.decision_s)
                per_seed[label].append(float(np.mean(result.decision_s)))
            if not np.array_equal(flown["kept"], flown["general"]):
                raise SystemExit(f"{name} seed {seed}: the two paths gave different waypoints")
        kept, general = (np.array(times[label]) * 1e6 for label in ("kept", "general"))
        ratio = np.array(per_seed["kept"]) / np.array(per_seed["general"])
        q25, q50, q75 = np.percentile(ratio, [25, 50, 75])
        print(f"  {name}: general mean {general.mean():.1f} µs, median {np.median(general):.1f} µs; kept mean "
              f"{kept.mean():.1f} µs, median {np.median(kept):.1f} µs; kept/general per seed {q50:.3f} "
              f"[{q25:.3f}-{q75:.3f}]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
