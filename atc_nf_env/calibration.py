"""Calibration of the NF speed gains k_u and k_z, as code (and a figure).

The paper (IV-C) observes that a waypoint about 100 nm ahead makes the NF command the
nominal cruise airspeed. With k = 2 the unobstructed ‖∇Φ‖² is nearly constant along
the dipole axis, so F = k_u ‖∇Φ‖² + k_z ‖q − q_d‖² changes little while the waypoint
distance falls from 110 to 60 nm (one 5-min period at 454 kt): k_u carries most of the
airspeed, and k_z a small part that grows with the square of the distance, so that
the NF alone aimed at a destination 500 nm away is far too fast (and, with ε_nh > 0,
slows to zero at the goal), as the paper's Fig. 3 shows.

Procedure: k_z is fixed by ``K_Z_SHARE_KT`` (its contribution at 100 nm); k_u is chosen
so that the mean of F over a fixed set of unobstructed situations in the flight region
(aircraft within ``region_radius_nm`` of the centre, every bearing, waypoint 100 nm
ahead on the aircraft's track) equals the nominal 454 kt. ``envelope_check`` then
reports the airspeed's range over that set from 110 down to 60 nm.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from atc_nf_env import nf
from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import ENCOUNTER_RADIUS_NM, WORKSPACE_RADIUS_NM
from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT, AIRSPEED_NOMINAL_KT

#: k_z's contribution to F at 100 nm from the waypoint, kt.
K_Z_SHARE_KT: float = 30.0
#: Waypoint distance at which the nominal airspeed is asked for, nm.
CALIBRATION_DISTANCE_NM: float = 100.0
#: The distances one 5-min period spans when the waypoint is reset to ~100 nm ahead, nm.
WINDOW_NM: tuple[float, float] = (60.0, 110.0)


def reference_situations(region_radius_nm: float = ENCOUNTER_RADIUS_NM) -> tuple[np.ndarray, np.ndarray]:
    """Fixed set of aircraft positions (M, 2) nm and tracks (M,) rad covering the region:
    rings at 0, 1/4 … 4/4 of the radius, 12 positions per ring, 8 tracks per position."""
    positions, tracks = [], []
    for ring in np.linspace(0.0, region_radius_nm, 5):
        for bearing in np.linspace(0.0, 2 * np.pi, 12, endpoint=False):
            for track in np.linspace(0.0, 2 * np.pi, 8, endpoint=False):
                positions.append((ring * math.cos(bearing), ring * math.sin(bearing)))
                tracks.append(track)
    return np.array(positions), np.array(tracks)


def unobstructed_terms(
    config: SimConfig,
    workspace_radius_nm: float,
    positions: np.ndarray,
    tracks: np.ndarray,
    distance_nm: float,
) -> tuple[np.ndarray, float]:
    """‖∇Φ‖² (units of 1/L²) for a lone aircraft at each position with its waypoint
    ``distance_nm`` ahead along its track (θ_d = the track), and ‖q − q_d‖² in units of L²."""
    params = config.to_params(workspace_radius_nm)
    status = np.zeros(1)
    grad = np.zeros((1, 2))
    out = np.empty(len(positions))
    for m, ((x, y), track) in enumerate(zip(positions, tracks)):
        wx = x + distance_nm * math.cos(track)
        wy = y + distance_nm * math.sin(track)
        nf.nf_value_and_gradients(0, np.array([[x, y]]), status, wx, wy, track, params, grad)
        out[m] = grad[0, 0] ** 2 + grad[0, 1] ** 2
    return out, (distance_nm / config.length_scale_nm) ** 2


def calibrate(
    config: SimConfig | None = None,
    workspace_radius_nm: float = WORKSPACE_RADIUS_NM,
    region_radius_nm: float = ENCOUNTER_RADIUS_NM,
    nominal_kt: float = AIRSPEED_NOMINAL_KT,
) -> SimConfig:
    """``config`` with k_u and k_z calibrated for the workspace (see module docstring)."""
    config = config or SimConfig()
    positions, tracks = reference_situations(region_radius_nm)
    grad2, dist2 = unobstructed_terms(config, workspace_radius_nm, positions, tracks, CALIBRATION_DISTANCE_NM)
    k_z = K_Z_SHARE_KT / dist2
    k_u = (nominal_kt - K_Z_SHARE_KT) / float(np.mean(grad2))
    return config.replace(k_u=k_u, k_z=k_z)


@dataclass
class EnvelopeCheck:
    """Unobstructed airspeed over the reference situations, kt, at each distance (nm)."""

    distances_nm: np.ndarray
    median_kt: np.ndarray
    min_kt: np.ndarray
    max_kt: np.ndarray


def unobstructed_airspeed(
    config: SimConfig,
    distances_nm: np.ndarray,
    workspace_radius_nm: float = WORKSPACE_RADIUS_NM,
    region_radius_nm: float = ENCOUNTER_RADIUS_NM,
) -> EnvelopeCheck:
    """Commanded airspeed F (kt) of a lone aircraft flying straight at a waypoint, for
    each distance, summarised over the reference situations of the region."""
    positions, tracks = reference_situations(region_radius_nm)
    med, lo, hi = [], [], []
    for d in distances_nm:
        grad2, dist2 = unobstructed_terms(config, workspace_radius_nm, positions, tracks, float(d))
        speed = config.k_u * grad2 + config.k_z * dist2
        med.append(np.median(speed))
        lo.append(speed.min())
        hi.append(speed.max())
    return EnvelopeCheck(np.asarray(distances_nm, float), np.array(med), np.array(lo), np.array(hi))


def nf_alone_airspeed(
    config: SimConfig,
    distances_nm: np.ndarray,
    radius_nm: float = ENCOUNTER_RADIUS_NM,
    workspace_radius_nm: float = WORKSPACE_RADIUS_NM,
) -> np.ndarray:
    """Commanded airspeed (kt) of a lone aircraft of the converging encounter flying
    at its destination 2·radius away, at each remaining distance (the NF alone)."""
    params = config.to_params(workspace_radius_nm)
    grad = np.zeros((1, 2))
    dest = np.array([-radius_nm, 0.0])
    out = []
    for d in distances_nm:
        pos = np.array([[dest[0] + d, 0.0]])
        nf.nf_value_and_gradients(0, pos, np.zeros(1), dest[0], dest[1], math.pi, params, grad)
        dist2 = (d / config.length_scale_nm) ** 2
        out.append(config.k_u * (grad[0, 0] ** 2 + grad[0, 1] ** 2) + config.k_z * dist2)
    return np.array(out)


def check_calibrated(config: SimConfig, workspace_radius_nm: float) -> None:
    """Refuse a workspace (or gains) outside the range the calibration holds for.

    The NF's unobstructed airspeed scales roughly with 1/β0², so gains calibrated for one
    workspace radius command a very different cruise elsewhere (with the default gains:
    ~136 kt at 3000 nm, ~3700 kt at 500 nm; inside the envelope from about 1364 to 1681
    nm, a range a test pins). A flight is accepted where the median
    unobstructed airspeed 100 nm from the waypoint over the flight region lies within
    the airspeed envelope [366, 540] kt; otherwise a ValueError says so and how to
    recalibrate (``calibrate(workspace_radius_nm=R)``). About 3 ms, once per (gains,
    radius) pair.
    """
    median_kt = _cruise_airspeed_kt(config, float(workspace_radius_nm))
    if not (math.isfinite(median_kt) and AIRSPEED_MIN_KT <= median_kt <= AIRSPEED_MAX_KT):
        raise ValueError(
            f"workspace_radius_nm = {workspace_radius_nm!r} with k_u = {config.k_u:.6g}, k_z = {config.k_z:.6g}: "
            f"the NF would cruise at {median_kt:.0f} kt 100 nm from its waypoint, outside the envelope "
            f"[{AIRSPEED_MIN_KT:g}, {AIRSPEED_MAX_KT:g}] kt; the default gains are calibrated for a "
            f"{WORKSPACE_RADIUS_NM:g} nm workspace (they hold from about 1364 to 1681 nm). Refused, not "
            "recalibrated: pass config=atc_nf_env.calibration.calibrate(workspace_radius_nm=R) to fly "
            "another workspace"
        )


@functools.lru_cache(maxsize=64)
def _cruise_airspeed_kt(config: SimConfig, workspace_radius_nm: float) -> float:
    with np.errstate(all="ignore"):
        check = unobstructed_airspeed(
            config, np.array([CALIBRATION_DISTANCE_NM]), workspace_radius_nm=workspace_radius_nm
        )
    return float(check.median_kt[0])


def plot_calibration(config: SimConfig, path: str) -> None:
    """Figure: airspeed against distance to the waypoint (median and range over the
    flight region), the envelope, and the NF alone aimed 500 nm away."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    distances = np.linspace(5.0, 200.0, 79)
    check = unobstructed_airspeed(config, distances)
    far = np.linspace(0.5, 2 * ENCOUNTER_RADIUS_NM, 200)
    alone = nf_alone_airspeed(config, far)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    ax = axes[0]
    ax.fill_between(distances, check.min_kt, check.max_kt, alpha=0.3, label="range over the region")
    ax.plot(distances, check.median_kt, label="median")
    ax.axvspan(*WINDOW_NM, color="grey", alpha=0.12, label="one 5-min period")
    envelope = f"envelope {config.airspeed_min_kt:g}–{config.airspeed_max_kt:g} kt"
    ax.axhline(config.airspeed_min_kt, color="k", ls="--", lw=1)
    ax.axhline(config.airspeed_max_kt, color="k", ls="--", lw=1, label=envelope)
    ax.axhline(AIRSPEED_NOMINAL_KT, color="0.45", ls="-.", lw=1, label=f"nominal {AIRSPEED_NOMINAL_KT:g} kt")
    ax.set_xlabel("distance to the waypoint (nm)")
    ax.set_ylabel("commanded airspeed (kt)")
    ax.set_ylim(top=max(ax.get_ylim()[1], config.airspeed_max_kt + 40))  # keep 540 kt off the frame
    ax.set_title("Unobstructed NF airspeed, waypoint ahead")
    ax.legend(fontsize=8)
    ax = axes[1]
    ax.plot(far, alone, label="commanded airspeed")
    ax.axhline(config.airspeed_min_kt, color="k", ls="--", lw=1)
    ax.axhline(config.airspeed_max_kt, color="k", ls="--", lw=1, label=envelope)
    ax.legend(fontsize=8)
    ax.set_xlabel("distance to the destination (nm)")
    ax.set_ylabel("commanded airspeed (kt)")
    ax.set_title("NF alone, destination 500 nm away")
    ax.invert_xaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Recompute the gains, print the speed targets, and write the figure."""
    import argparse

    parser = argparse.ArgumentParser(description="Calibrate the NF speed gains and check the envelope.")
    parser.add_argument("--figure", default="out/calibration.png", help="where to write the figure")
    args = parser.parse_args(argv)
    config = calibrate()
    print(f"k_u = {config.k_u:.6g} kt, k_z = {config.k_z:.6g} kt (workspace {WORKSPACE_RADIUS_NM:g} nm)")
    at_100 = unobstructed_airspeed(config, np.array([CALIBRATION_DISTANCE_NM]))
    print(
        f"airspeed 100 nm from the waypoint: median {at_100.median_kt[0]:.1f} kt, "
        f"range {at_100.min_kt[0]:.1f}..{at_100.max_kt[0]:.1f} kt over the flight region"
    )
    window = unobstructed_airspeed(config, np.linspace(WINDOW_NM[0], WINDOW_NM[1], 11))
    print(
        f"airspeed from {WINDOW_NM[1]:g} down to {WINDOW_NM[0]:g} nm: "
        f"{window.min_kt.min():.1f}..{window.max_kt.max():.1f} kt (envelope "
        f"[{config.airspeed_min_kt:g}, {config.airspeed_max_kt:g}])"
    )
    alone = nf_alone_airspeed(config, np.array([500.0, 100.0, 10.0, 1.0]))
    print("NF alone aimed 500 nm away: " + ", ".join(
        f"{s:.0f} kt at {d:g} nm" for s, d in zip(alone, (500, 100, 10, 1))))
    from pathlib import Path

    Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
    plot_calibration(config, args.figure)
    print(f"figure written to {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
