"""The safety filter of an earlier commit and of the working tree, episode by episode in one process.

Since the routine decision moved into one compiled call (``PlanPredictor.screen``: the wind
estimate, the stall rule's window and the prediction of the proposal), a shielded decision
runs far less Python. How much that saves inside an episode is hard to see across
processes on a shared machine: two processes of the same build differ by more than the
change (``bench/experiments/build_ab.py --what shield`` gave per-round ratios from 0.6 to
1.7). Here both filters run in one process, around one agent, episode by episode in
alternating order, so that the machine's load moves both alike.

The earlier filter is ``atc_nf_env/shield.py`` of ``--before`` (default 2ac34f5, the
commit before the change), loaded as a module of its own next to the current one; it
imports the current ``shield_prediction``, whose ``first_safe`` it calls as before. Both
filters apply the same waypoints at every decision (checked here on every episode:
the script stops if they ever differ).

Reported per scenario: both filters' mean and median decision (µs) over all decisions,
and the median, over seeds, of each seed's mean decision new / old, with its quartiles.

Run: python bench/experiments/shield_screen_ab.py [--seeds 40] [--before 2ac34f5]
[--scenarios converging-4,converging-6,random-4,random-6] [--model agents/models/finetuned_ppo.zip]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def load_old_filter(commit: str, folder: Path) -> type:
    """``SafetyFilter`` of ``atc_nf_env/shield.py`` at ``commit``, as module ``shield_before``."""
    source = subprocess.run(["git", "show", f"{commit}:atc_nf_env/shield.py"], cwd=ROOT, check=True,
                            capture_output=True, text=True).stdout
    path = folder / "shield_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("shield_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SafetyFilter


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", default="2ac34f5", help="the commit whose filter is the 'old' one")
    parser.add_argument("--seeds", type=int, default=40, help="episodes per scenario and filter")
    parser.add_argument("--scenarios", default="converging-4,converging-6,random-4,random-6")
    parser.add_argument("--model", default=str(ROOT / "agents/models/finetuned_ppo.zip"))
    args = parser.parse_args(argv)

    from _alternating import fly_alternately  # bench/experiments/ is on sys.path when run as a script

    from atc_nf_env.policy import make_policy
    from atc_nf_env.shield import SafetyFilter

    agent = make_policy(args.model)
    with tempfile.TemporaryDirectory() as tmp:
        old_class = load_old_filter(args.before, Path(tmp))
        filters = {"old": old_class(agent), "new": SafetyFilter(agent)}
        print(f"{Path(args.model).stem} inside the safety filter of {args.before} (old) and of the working tree (new), "
              f"seeds 0..{args.seeds - 1}, alternating episode by episode in one process:")
        for name in args.scenarios.split(","):
            print(f"  {name}: {fly_alternately(filters, name, args.seeds)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
