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

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--scenarios", default="converging-4,random-6")
    parser.add_argument("--model", default=str(ROOT / "agents/models/finetuned_ppo.zip"))
    args = parser.parse_args(argv)

    from _alternating import fly_alternately  # bench/experiments/ is on sys.path when run as a script

    from agents.policy import SB3AgentPolicy

    class General(SB3AgentPolicy):
        def reset(self, scenario, config, seed=None) -> None:
            super().reset(scenario, config, seed)
            self._buffers = None

    agents = {"general": General(args.model), "kept": SB3AgentPolicy(args.model)}
    print(f"{Path(args.model).stem}: act on kept buffers and on the general path, seeds 0..{args.seeds - 1}, "
          "alternating episode by episode in one process:")
    for name in args.scenarios.split(","):
        print(f"  {name}: {fly_alternately(agents, name, args.seeds)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
