"""Side by side: our PettingZoo env against BlueSky-Gym's sector conflict-resolution env.

BlueSky-Gym (`pip install bluesky-gym`, with `torch==2.13.0` installed first so that
pip does not pull a CUDA build) lives in its own virtual environment; pass its Python
with ``--bluesky-python``. Both envs take uniform random actions and reset when an
episode ends; each is timed for ``--seconds`` at a time, alternating, three rounds.
Reported: median steps per second of each and their ratio.

Run: python bench/bench_bluesky_gym.py --bluesky-python /path/to/venv/bin/python [--write]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

from _report import machine, publish  # bench/ is on sys.path when run as a script

BLUESKY = r"""
import sys, time
import bluesky_gym, gymnasium as gym
bluesky_gym.register_envs()
env = gym.make("SectorCREnv-v0", render_mode=None)
env.reset(seed=0)
env.action_space.seed(0)
seconds = float(sys.argv[1])
t0 = time.perf_counter(); n = 0
while time.perf_counter() - t0 < seconds:
    obs, r, term, trunc, info = env.step(env.action_space.sample()); n += 1
    if term or trunc:
        env.reset()
print(n / (time.perf_counter() - t0))
"""


def ours(seconds: float, scenario: str) -> float:
    import atc_nf_env

    env = atc_nf_env.parallel_env(scenario=scenario)
    env.reset(seed=0)
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < seconds:
        if not env.agents:
            env.reset()
        env.step({a: env.action_space(a).sample() for a in env.agents})
        n += 1
    return n / (time.perf_counter() - t0)


def theirs(python: str, seconds: float) -> float:
    out = subprocess.run([python, "-c", BLUESKY, str(seconds)], check=True, capture_output=True, text=True)
    return float(out.stdout.strip().splitlines()[-1])


def their_version(python: str) -> str:
    """The bluesky-gym and bluesky-simulator versions of ``python``'s environment."""
    code = ("from importlib.metadata import version; "
            "print(version('bluesky-gym'), version('bluesky-simulator'))")
    out = subprocess.run([python, "-c", code], check=True, capture_output=True, text=True)
    gym_version, simulator_version = out.stdout.split()
    return f"bluesky-gym {gym_version}, bluesky-simulator {simulator_version}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bluesky-python", required=True, help="Python of a venv with bluesky-gym")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args(argv)
    ours(1.0, "converging-4")  # compile / load the kernel
    rates_ours, rates_theirs = [], []
    for _ in range(3):
        rates_ours.append(ours(args.seconds, "converging-4"))
        rates_theirs.append(theirs(args.bluesky_python, args.seconds))
        print(f"ours {rates_ours[-1]:.0f} steps/s, BlueSky-Gym SectorCREnv {rates_theirs[-1]:.0f} steps/s", flush=True)
    a, b = statistics.median(rates_ours), statistics.median(rates_theirs)
    text = "\n".join([
        "## Side by side with BlueSky-Gym",
        "",
        f"`python bench/bench_bluesky_gym.py` — random actions, {args.seconds:g} s per round, three "
        f"alternating rounds, {machine()}. One step of ours is one 5-min decision of 4 aircraft "
        "(`parallel_env`, converging-4); one step of BlueSky-Gym's `SectorCREnv-v0` is its own decision step "
        f"({their_version(args.bluesky_python)}, in its own virtual environment).",
        "",
        "| env | steps / s (median) |",
        "|---|---:|",
        f"| atc-nf-env `parallel_env`, converging-4 | {a:,.0f} |",
        f"| BlueSky-Gym `SectorCREnv-v0` | {b:,.0f} |",
        "",
        f"Ratio: **{a / b:.0f}×** (the issue asks for about 20×).",
    ])
    return publish("bluesky-gym", text, args.write)


if __name__ == "__main__":
    sys.exit(main())
