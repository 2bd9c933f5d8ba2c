"""The NF alone, reproduced (paper IV-B, Figs. 3, 5, 7).

- 4 aircraft, no wind: all arrive, no loss of separation, the minimum separation
  (paper: 22 nm), airspeed decaying toward zero on the approach (Figs. 3 and 5);
- 6 aircraft, no wind: the roundabout and its radius (paper: about 190 nm) (Fig. 7);
- 4 aircraft with wind σ = 5.17 m/s: the paper's failure mode (NF airspeed plus wind
  equal to zero short of the destination), as the fraction of seeded runs in which
  some aircraft never arrives.

Run: python -m atc_nf_env.experiments.nf_alone --out DIR [--runs 100]
Writes the figures and ``nf_alone.json`` into DIR and prints the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from atc_nf_env.episode import EpisodeResult, run_episode
from atc_nf_env.kernel import R_FLEW, R_X, R_Y
from atc_nf_env.plotting import plot_airspeed, plot_trajectories
from atc_nf_env.policy import make_policy
from atc_nf_env.scenarios import converging
from atc_nf_env.units import WIND_SIGMA_MPS


def closest_approach_to_centre_nm(result: EpisodeResult) -> np.ndarray:
    """Per aircraft, the smallest distance to the encounter's centre along its track, nm:
    the radius of the roundabout the aircraft fly around the centre."""
    records = result.records
    radius = np.hypot(records[..., R_X], records[..., R_Y])
    radius = np.where(records[..., R_FLEW] > 0, radius, np.inf)
    return radius.min(axis=0)


def windless(n: int, out: Path | None) -> tuple[dict[str, Any], EpisodeResult]:
    result = run_episode(make_policy("nf"), converging(n), seed=0, wind_sigma_mps=0.0, record_every=1)
    m = result.metrics
    last_minutes = result.records[-1]  # airspeed on the final approach
    summary = {
        "arrived": sum(m.arrived),
        "aircraft": m.n_aircraft,
        "los_count": m.los_count,
        "min_separation_nm": m.min_separation_nm,
        "roundabout_radius_nm": float(np.mean(closest_approach_to_centre_nm(result))),
        "flight_time_min": m.flight_time_min,
        "path_length_nm": m.path_length_nm,
        "envelope_violation_fraction": m.envelope_violation_fraction,
        "airspeed_kt": [m.airspeed_min_kt, m.airspeed_max_kt],
        "airspeed_at_arrival_kt": [float(v) for v in last_minutes[:, 3]],
    }
    if out is not None:
        plot_trajectories(result, out / f"nf_alone_converging{n}_trajectories.png",
                          title=f"NF alone, {n} aircraft, no wind (paper Fig. {5 if n == 4 else 7})")
        plot_airspeed(result, out / f"nf_alone_converging{n}_airspeed.png",
                      title=f"NF alone, {n} aircraft, no wind (paper Fig. 3)")
    return summary, result


def windy(runs: int, out: Path | None) -> dict[str, Any]:
    scenario = converging(4)
    failed_runs, stall_distances, los_runs = 0, [], 0
    example = None
    for seed in range(runs):
        result = run_episode(make_policy("nf"), scenario, seed=seed, wind_sigma_mps=WIND_SIGMA_MPS, record_every=40)
        m = result.metrics
        los_runs += m.los_count > 0
        if m.success:
            continue
        failed_runs += 1
        example = example or result
        final = result.records[-1]
        for i, arrived in enumerate(m.arrived):
            if not arrived:
                stall_distances.append(float(np.hypot(*(final[i, :2] - scenario.dest_xy[i]))))
    if out is not None and example is not None:
        plot_trajectories(example, out / "nf_alone_wind_failure_trajectories.png",
                          title=f"NF alone under wind (seed {example.metrics.seed}): stranded short of the goal")
    return {
        "runs": runs,
        "wind_sigma_mps": WIND_SIGMA_MPS,
        "runs_with_an_aircraft_that_never_arrives": failed_runs,
        "fraction_of_runs_failing": failed_runs / runs,
        "aircraft_never_arriving": len(stall_distances),
        "runs_with_a_loss_of_separation": los_runs,
        "stall_distance_nm": {
            "min": min(stall_distances, default=None),
            "median": float(np.median(stall_distances)) if stall_distances else None,
            "max": max(stall_distances, default=None),
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/nf_alone"), help="folder for figures and JSON")
    parser.add_argument("--runs", type=int, default=100, help="seeded runs under wind")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs {args.runs}: must be >= 1")
    args.out.mkdir(parents=True, exist_ok=True)
    four, _ = windless(4, args.out)
    six, _ = windless(6, args.out)
    wind = windy(args.runs, args.out)
    report = {"converging-4": four, "converging-6": six, "converging-4 with wind": wind}
    (args.out / "nf_alone.json").write_text(json.dumps(report, indent=2) + "\n")
    print(f"4 aircraft, no wind: {four['arrived']}/4 arrived, {four['los_count']} losses of separation, "
          f"minimum separation {four['min_separation_nm']:.1f} nm (paper: 22 nm), airspeed at arrival "
          + ", ".join(f"{v:.0f}" for v in four["airspeed_at_arrival_kt"]) + " kt")
    print(f"6 aircraft, no wind: {six['arrived']}/6 arrived, {six['los_count']} losses of separation, "
          f"roundabout radius {six['roundabout_radius_nm']:.1f} nm (paper: about 190 nm), minimum "
          f"separation {six['min_separation_nm']:.1f} nm")
    print(f"4 aircraft, wind sigma {WIND_SIGMA_MPS} m/s: {wind['runs_with_an_aircraft_that_never_arrives']}"
          f"/{wind['runs']} runs have an aircraft that never arrives ({wind['aircraft_never_arriving']} "
          f"aircraft of {4 * wind['runs']}), stranded a median "
          f"{wind['stall_distance_nm']['median'] or float('nan'):.1f} nm short of the destination")
    print(f"figures and nf_alone.json written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
