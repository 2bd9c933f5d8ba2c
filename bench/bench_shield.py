"""The safety filter's decision latency: each shipped agent alone and inside the filter,
side by side on the same decisions.

For every scenario (converging-4, converging-6, random-4, random-6 by default) and model,
episodes on seeds
0..SEEDS-1 are flown inside ``atc_nf_env.shield.SafetyFilter`` (one untimed episode first:
numba's cache and the model's first call are kept out of the figures). At every decision
the agent alone is timed on the decision's view, then the filter's whole decision (which
calls the agent again, predicts two periods and, if unsafe, the alternatives or the MPC).
Reported: mean, median, p99 and max over every decision for both, the median of the
decisions the filter let through unchanged, how many it changed or left to the MPC, and
the share of the filter's time spent in the kernel's flights of its prediction.

A second table splits the shielded mean per decision into the agent (timed alone), the
check of its proposal (``PlanPredictor.screen``: the two-period prediction), the flights of
the alternatives (``PlanPredictor.first_safe``) and the rest (the filter's Python, MPC
decisions), and gives two floors that no faster choice of alternatives can go below with
this prediction on this machine: the agent and the check alone (alternatives free), and
that plus, for every decision changed, one prediction of the waypoints it applied (timed
after the decision, untimed in the decision itself: an oracle that knew the safe set).

Goal: a shielded agent decides in ≤ 150 µs on average, ≤ 2 ms at the 99th percentile.

Run: python bench/bench_shield.py [--seeds 50] [--scenarios converging-4,...] [--write]
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


def measure(model: str, scenario_name: str, seeds: int) -> dict:
    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    from atc_nf_env.shield_prediction import PlanPredictor

    inner = make_policy(model)
    shield = SafetyFilter(inner)
    alone: list[float] = []
    shielded: list[float] = []
    changed: list[bool] = []
    # Time inside the compiled prediction (the proposal's flight in ``screen``, with the
    # filter's bookkeeping that shares its call, and every flight of the alternatives),
    # summed per decision and by call (the check, the alternatives): a perf_counter pair per
    # call, ~0.2 µs.
    by_call: dict[str, list[float]] = {"screen": [], "first_safe": []}
    # One prediction of the waypoints a changed decision applied, timed after it (0 where unchanged).
    oracle: list[float] = []
    unwrapped = {name: getattr(PlanPredictor, name) for name in ("screen", "first_safe")}
    deciding = False  # inside a timed decision of the filter

    def timed(name):
        def call(self, *args, **kwargs):
            t0 = time.perf_counter()
            try:
                return unwrapped[name](self, *args, **kwargs)
            finally:
                if deciding:  # not the calls of the filter's own warm-up in reset()
                    by_call[name][-1] += time.perf_counter() - t0
        return call

    def one_prediction(state: np.ndarray, applied: np.ndarray, wind_kt: np.ndarray) -> float:
        """Seconds of one prediction of ``applied`` (the filter's own predictor, unwrapped:
        outside the decision's timing), the least a change could cost beyond the check."""
        candidates = np.ascontiguousarray(applied[None], dtype=np.float64)
        t0 = time.perf_counter()
        unwrapped["first_safe"](shield._predictor, state, candidates, wind_kt)
        return time.perf_counter() - t0

    class SideBySide:
        name = "side-by-side"

        def reset(self, scenario, config, seed=None) -> None:
            shield.reset(scenario, config, seed)

        def act(self, view):
            t0 = time.perf_counter()
            inner.act(view)
            t1 = time.perf_counter()
            before = shield.episode_info()["shield_filtered"]
            for per_call in by_call.values():
                per_call.append(0.0)
            nonlocal deciding
            deciding = True
            t2 = time.perf_counter()
            waypoints = shield.act(view)
            t3 = time.perf_counter()
            deciding = False
            alone.append(t1 - t0)
            shielded.append(t3 - t2)
            changed.append(shield.episode_info()["shield_filtered"] > before)
            # The view's state is the decision's: the filter only reads it, and the flight comes after.
            oracle.append(one_prediction(np.ascontiguousarray(view.state, dtype=np.float64), waypoints,
                                         shield._memory.wind_kt.copy()) if changed[-1] else 0.0)
            return waypoints

    for name in unwrapped:
        setattr(PlanPredictor, name, timed(name))
    try:
        run_episode(SideBySide(), make_scenario(scenario_name, seed=0), seed=0)  # warm-up, untimed
        for recorded in (alone, shielded, changed, oracle, *by_call.values()):
            recorded.clear()
        fallbacks = sampled = 0
        for seed in range(seeds):
            run_episode(SideBySide(), make_scenario(scenario_name, seed=seed), seed=seed)
            fallbacks += shield.episode_info()["shield_mpc_fallbacks"]
            sampled += shield.episode_info()["shield_sampled_changes"]
    finally:
        for name, method in unwrapped.items():
            setattr(PlanPredictor, name, method)
    a, s, c, o = np.array(alone), np.array(shielded), np.array(changed), np.array(oracle)
    check, alternatives = np.array(by_call["screen"]), np.array(by_call["first_safe"])
    f = check + alternatives  # the prediction's flights per decision
    return {
        "split": (s.mean(), a.mean(), check.mean(), alternatives.mean(), s.mean() - a.mean() - check.mean()
                  - alternatives.mean()),
        "floors": ((a + check).mean(), (a + check + o).mean()),
        "alone": (a.mean(), np.median(a), np.percentile(a, 99), a.max()),
        "shielded": (s.mean(), np.median(s), np.percentile(s, 99), s.max()),
        "passed_median": float(np.median(s[~c])) if (~c).any() else float("nan"),
        "flight_share": float(f.sum() / s.sum()),
        "flight_share_passed": float(f[~c].sum() / s[~c].sum()) if (~c).any() else float("nan"),
        "decisions": len(s),
        "changed": int(c.sum()),
        "fallbacks": fallbacks,
        "sampled": sampled,
    }


def _us(seconds: float) -> str:
    return f"{seconds * 1e3:.2f} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.0f} µs"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--scenarios", default="converging-4,converging-6,random-4,random-6")
    parser.add_argument("--models", default=",".join(str(p.relative_to(ROOT)) for p in
                                                     sorted((ROOT / "agents" / "models").glob("*.zip"))))
    parser.add_argument("--write", action="store_true", help="write the table into BENCHMARKS.md")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    rows = [
        "| scenario | model | agent alone: mean / median / p99 / max | shielded: mean / median / p99 / max "
        "| shielded, decisions passed unchanged: median | decisions changed | settled by a sampled set "
        "| MPC fallbacks | shielded time in the prediction's flights: all / passed decisions |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    split_rows = [
        ("| scenario | model | shielded mean | agent | check of the proposal | alternatives' flights | rest "
         "| floor: alternatives free | floor: one prediction per change | floor ≤ 150 µs |"),
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    load = [os.getloadavg()[0]]
    scenarios = [s for s in args.scenarios.split(",") if s]
    for scenario, model in [(s, m) for s in scenarios for m in args.models.split(",") if m]:
        r = measure(model, scenario, args.seeds)
        rows.append(
            f"| {scenario} | {Path(model).stem} | {' / '.join(_us(x) for x in r['alone'])} "
            f"| {' / '.join(_us(x) for x in r['shielded'])} | {_us(r['passed_median'])} "
            f"| {r['changed']} of {r['decisions']} | {r['sampled']} | {r['fallbacks']} "
            f"| {r['flight_share']:.0%} / {r['flight_share_passed']:.0%} |"
        )
        print(rows[-1], flush=True)
        mean, agent, check, alternatives, rest = r["split"]
        free, one_each = r["floors"]
        split_rows.append(
            f"| {scenario} | {Path(model).stem} | {_us(mean)} | {_us(agent)} | {_us(check)} | {_us(alternatives)} "
            f"| {_us(rest)} | {_us(free)} | {_us(one_each)} | {'yes' if one_each <= 150e-6 else 'no'} |"
        )
        print(split_rows[-1], flush=True)
        load.append(os.getloadavg()[0])
    text = "\n".join([
        "## Safety filter: decision latency",
        "",
        f"`python bench/bench_shield.py --seeds {args.seeds} --scenarios {args.scenarios}` — each shipped agent "
        f"alone and inside `atc_nf_env.shield.SafetyFilter` (two-period prediction; the alternatives flown one "
        f"world at a time in the order they would be chosen, in one compiled call per tier; MPC fallback), timed "
        f"side by "
        f"side on every decision of seeds 0..{args.seeds - 1} (σ = 5.17 m/s) after an untimed warm-up episode; "
        f"{machine()}; 1-min load average {min(load):.1f}–{max(load):.1f} during the run (other jobs inflate "
        "means and tails; the medians side by side are what to quote on a shared machine). Goal: shielded mean "
        "≤ 150 µs, p99 ≤ 2 ms. An MPC fallback is a full MCMC-MPC decision (tens of milliseconds); the sampled "
        "tier settles most of what the structured alternatives cannot before it comes to that. The last column: "
        "the share of the shielded decisions' time spent inside the compiled prediction "
        "(`PlanPredictor.screen`: the kernel flying the proposal, in one call with the filter's wind estimate "
        "and progress rule; `PlanPredictor.first_safe`: the alternatives), over all decisions "
        "and over those passed unchanged; the rest is the agent and the filter's Python (and an MPC decision "
        "where it falls back).",
        "",
        *rows,
        "",
        ("Where the shielded mean goes, per decision, in the same run: the agent (its time alone), the check of "
         "its proposal (the two-period prediction, with the filter's wind estimate and progress rule), the "
         "alternatives' flights, and the rest (the filter's Python; MPC decisions). The floors bound what faster "
         "alternatives could reach with this prediction on this machine: the agent and the check alone, and that "
         "plus one prediction of the applied waypoints for every decision changed (timed after the decision: an "
         "oracle that flies only the safe set). Where the last floor is above 150 µs, only a cheaper check (the "
         "prediction itself), a faster agent or fewer changes can meet the goal."),
        "",
        *split_rows,
    ])
    return publish("shield", text, args.write)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
