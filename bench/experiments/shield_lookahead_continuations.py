"""Does the safety filter's look-ahead flag traps, or only the one continuation it flies?

The filter checks a proposal over the coming period and one more, in which every aircraft
is re-aimed home (130 nm toward its destination, turned at most 60° from its heading). A
proposal safe for the coming period but not through that homing period is changed. Were
the homing continuation a poor choice, another continuation might be safe, and the filter
would change proposals (and fly alternatives, most of a changed decision's time) that a
better look-ahead would pass.

For every proposal of a shipped model that the filter finds unsafe (seeds 0..SEEDS-1),
this script prints what breached (the envelope, separation or both; in the coming period
or only in the look-ahead) and, for those unsafe only in the look-ahead, flies the coming
period again and then each of these continuations over the look-ahead period, with the
filter's parameters and wind estimate: homing at 100, 130 (the filter's) and 160 nm; homing
at 130 nm turned at most 30° or 90°; every aircraft keeping its waypoint; a waypoint 100 or
130 nm out toward the current one; 100 or 130 nm straight ahead. Printed per scenario: how
many of those proposals each continuation makes safe, and how many any of them does.

Run: python bench/experiments/shield_lookahead_continuations.py [--model agents/models/finetuned_ppo.zip]
     [--scenarios converging-6,random-6] [--seeds 30]
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter

import numpy as np

from atc_nf_env.kernel import FLYING, S_HEADING, S_STATUS, S_WP_X, S_WP_Y, S_X, S_Y
from atc_nf_env.shield_prediction import (
    NONE_SAFE,
    SCREEN_UNSAFE,
    PlanPredictor,
    _homing_waypoints,
    _inside,
)


def continuations(world: np.ndarray, limit_nm: float, max_turn_rad: float) -> dict[str, np.ndarray]:
    """Waypoints (N, 2) nm of each continuation from ``world`` (N, N_STATE), the state after
    the coming period."""
    n = world.shape[0]
    current = np.ascontiguousarray(world[:, S_WP_X : S_WP_Y + 1])
    out: dict[str, np.ndarray] = {}
    for name, distance, turn in (("home 130 nm (the filter's)", 130.0, max_turn_rad),
                                 ("home 100 nm", 100.0, max_turn_rad), ("home 160 nm", 160.0, max_turn_rad),
                                 ("home 130 nm, turn <= 30°", 130.0, math.radians(30.0)),
                                 ("home 130 nm, turn <= 90°", 130.0, math.pi / 2)):
        home = np.zeros((n, 2))
        _homing_waypoints(world, current, distance, turn, limit_nm, home)
        out[name] = home
    out["keep the waypoint"] = current.copy()
    for label, angle_of in (("toward the waypoint", lambda i: math.atan2(world[i, S_WP_Y] - world[i, S_Y],
                                                                         world[i, S_WP_X] - world[i, S_X])),
                            ("straight ahead", lambda i: world[i, S_HEADING])):
        for distance in (100.0, 130.0):
            waypoints = np.zeros((n, 2))
            for i in range(n):
                angle = angle_of(i)
                waypoints[i] = _inside(world[i, S_X] + distance * math.cos(angle),
                                       world[i, S_Y] + distance * math.sin(angle), limit_nm)
            out[f"{distance:.0f} nm {label}"] = waypoints
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="agents/models/finetuned_ppo.zip")
    parser.add_argument("--scenarios", default="converging-6,random-6")
    parser.add_argument("--seeds", type=int, default=30)
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")

    from atc_nf_env.episode import run_episode
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import SafetyFilter

    breaches: Counter = Counter()
    rescued: Counter = Counter()
    screen = PlanPredictor.screen

    def studied(self, state, proposal, time_s, period_s, memory, stall_progress_nm):
        verdict = screen(self, state, proposal, time_s, period_s, memory, stall_progress_nm)
        if verdict != SCREEN_UNSAFE:
            return verdict
        survived, blamed = int(self.survived[0]), self.blamed[0].copy()
        planned = np.ascontiguousarray(memory.planned)
        when = "coming period" if survived < self.period_steps else "look-ahead only"
        # What breached: the same prediction flown again, its envelope counts and LoS pairs read.
        self.first_safe(state, planned, memory.wind_kt, checked=False)
        envelope, separation = bool(self._counts[0].any()), bool(self._los_pairs.any())
        breaches[(when, {(True, False): "envelope", (False, True): "separation"}.get((envelope, separation),
                                                                                    "both"))] += 1
        if when == "look-ahead only":
            one_period = PlanPredictor(self.params, self.period_steps, 1, *self._homing)
            if one_period.first_safe(state, planned, memory.wind_kt, checked=False) != NONE_SAFE:
                world = one_period._world.copy()
                flying = world[:, S_STATUS] == FLYING
                any_safe = False
                for name, waypoints in continuations(world, self._homing[2], self._homing[1]).items():
                    waypoints = np.where(flying[:, None], waypoints, world[:, S_WP_X : S_WP_Y + 1])
                    safe = one_period.first_safe(world, np.ascontiguousarray(waypoints[None]), memory.wind_kt,
                                                 checked=False) == 0
                    rescued[name] += safe
                    any_safe |= safe
                rescued["any of them"] += any_safe
        self.survived[0], self.blamed[0] = survived, blamed  # as the filter left them
        return verdict

    PlanPredictor.screen = studied
    try:
        for scenario in [s for s in args.scenarios.split(",") if s]:
            breaches.clear()
            rescued.clear()
            shielded = SafetyFilter(make_policy(args.model))
            for seed in range(args.seeds):
                run_episode(shielded, make_scenario(scenario, seed=seed), seed=seed)
            later = sum(v for (when, _), v in breaches.items() if when == "look-ahead only")
            print(f"{scenario}, seeds 0..{args.seeds - 1}: proposals found unsafe, by when and what: "
                  + ", ".join(f"{when} / {what}: {v}" for (when, what), v in sorted(breaches.items())))
            print(f"  of the {later} unsafe only in the look-ahead, made safe by: "
                  + ", ".join(f"{name} {v}" for name, v in rescued.items()), flush=True)
    finally:
        PlanPredictor.screen = screen
    return 0


if __name__ == "__main__":
    sys.exit(main())
