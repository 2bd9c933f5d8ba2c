"""Plot a learning curve written by ``atc-nf train`` (``OUT/curve.csv``).

    python -m agents.plot_curve agents/results/scratch_ppo_curve.csv --out agents/results/scratch_ppo_curve.png

Three panels against environment timesteps: the mean return per aircraft episode, the
mean episode length in 5-min decisions (padding of aircraft already home included, as
SB3's monitor counts it), and the share of aircraft episodes that ended with the aircraft
home, each over the last 100 episodes at every rollout.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Sequence


def read_curve(path: Path) -> dict[str, list[float]]:
    """The CSV's columns as float lists (rows without episodes yet are skipped)."""
    with path.open() as handle:
        rows = [row for row in csv.DictReader(handle) if row.get("mean_return")]
    if not rows:
        raise ValueError(f"{path}: no rollout with a finished episode yet")
    return {key: [float(row[key]) for row in rows] for key in rows[0]}


def plot(curve: dict[str, list[float]], out: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [t / 1e6 for t in curve["timesteps"]]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), constrained_layout=True)
    for ax, key, label in zip(axes, ("mean_return", "mean_length", "success_rate"),
                              ("mean return per aircraft", "episode length (decisions)", "aircraft home (share)")):
        ax.plot(steps, curve[key], lw=1.2)
        ax.set_xlabel("timesteps (millions)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("curve", type=Path, help="curve.csv of atc-nf train")
    parser.add_argument("--out", type=Path, required=True, help="the figure (.png)")
    parser.add_argument("--title", default="PPO from scratch, converging-4, parameter-shared")
    args = parser.parse_args(argv)
    if not args.curve.is_file():
        parser.error(f"{args.curve} does not exist")
    try:
        print(f"wrote {plot(read_curve(args.curve), args.out, args.title)}")
    except ValueError as error:
        parser.error(str(error))
    return 0


if __name__ == "__main__":
    sys.exit(main())
