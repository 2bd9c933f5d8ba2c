"""A safety filter around any policy: predict the proposed waypoints, change them only if unsafe.

``SafetyFilter(policy)`` is itself a policy of the ``atc_nf_env.policy.Policy`` interface,
so it wraps the MCMC-MPC, the NF alone and trained agents alike (``atc-nf fly|evaluate
--policy P --shield``). At every decision (every T = 5 min) it

1. asks the wrapped policy for its waypoints (N, 2) nm; a waypoint that is not finite or
   lies outside the workspace's bounding square is unsafe by definition and replaced by
   the aircraft's homing waypoint (counted in ``shield_invalid_waypoints``);
2. predicts them with the simulator kernel, one world started from a copy of the state,
   over the coming period and, with ``lookahead_periods=2`` (the default), one more
   period in which every aircraft is re-aimed home (``home_distance_nm`` toward its
   destination, turned at most ``recovery_angle_rad`` from its heading): a waypoint set
   that is safe for one period but leaves no safe continuation is caught a period
   early. The prediction checks, at every integration step, the airspeed envelope
   narrowed by ``envelope_margin_kt`` on each side (the wind is hidden: the prediction
   uses an estimate, and its error moves the airspeed) and the separation minimum
   (the wind moves every aircraft alike, so separation needs no margin);
3. if the prediction is safe, returns the policy's waypoints unchanged (the same array);
4. otherwise tries a small set of alternatives: for each aircraft the prediction blames
   (an envelope breach or a loss of separation), its proposed waypoint turned by ±10°,
   ±20°, ±40°, moved to 100 or 130 nm in the same direction, or replaced by the homing
   waypoint 100 or 130 nm out, every other aircraft keeping its proposal; only if none of
   these is safe, all flying aircraft changed together: all homing (100, 130 nm), all
   proposals turned by ±20° or ±40°; only if none of these is safe either,
   ``SAMPLED_ALTERNATIVES`` waypoint sets drawn from the MCMC-MPC's proposal distribution
   (``atc_nf_env.proposals``, shaped by ``mpc_settings``; by default every aircraft at
   100 ± 10 nm, aimed within ±90° of the line to its destination or, a quarter of the
   time, within ±60° of its heading; drawn from the episode's seed). The closest safe alternative of the first tier that has one
   is applied: fewest aircraft changed, then the least total displacement of the changed
   waypoints (nm). The alternatives are predicted one world at a time in that order, in
   one compiled call (``shield_prediction``), and the first safe one is applied: the
   choice a batch prediction of the whole set would make, without flying the
   alternatives ranked after it. The sampled tier exists because the structured ones
   can all fail where every aircraft must change course a little (random traffic of six
   or more); there it finds a safe set in a fraction of a millisecond, where the MPC's
   decision takes tens;
5. if no alternative is safe, applies the fallback policy's decision (``fallback="mpc"``,
   the default: the policy ``mpc`` of the registry, ``atc_nf_env.policy.make_policy``,
   i.e. the MCMC-MPC, with the filter's wind estimate; on a traffic stream in the
   settings ``STREAM_FALLBACK_MPC_SETTINGS``, see there; or any policy object given as
   ``fallback``), or the alternative that stayed safe for the most integration steps
   (``fallback="least-bad"``).

The progress rule (``progress_fraction``, ``progress_periods``; on by default) keeps a
policy from holding an aircraft short of home or flying it away, which no safety check
catches. Over every window of ``progress_periods`` periods, a flying aircraft must come
closer to its destination by at least ``progress_fraction`` of what a direct flight at the
nominal airspeed (454 kt) covers in the window (by default 0.5 × 113.5 nm over 15 min),
or, if it was within that much (plus the arrival tolerance Δ) of home at the window's
start, arrive. One that does not is taken from the policy until it arrives: from then on
its waypoint is the homing waypoint (``home_distance_nm`` toward its destination, turned at
most ``recovery_angle_rad`` from its heading: the NF's own way home, the one the
look-ahead period flies), before the waypoint set is checked as above, so that a homing
waypoint that is unsafe is changed like any other. Why these choices:

- The rule acts early, a window of 15 min after the aircraft stops closing in, so that the
  aircraft is still where the NF's speed law is calibrated (within a few hundred nm of the
  encounter) when it turns home; handed over 600-850 nm out and heading away, aircraft
  once left the envelope by up to 1,077 kt.
- It asks for a share of a direct flight's progress, not merely some progress: a proposer
  holding every aircraft 30-80° off its bearing home closes in slowly, then circles its
  destination forever; asking only "no farther than 4 periods ago" caught it near the
  destination, where it kept circling.
- Near home it asks for arrival, not for a share of what is left: a share of what is left
  can be closed forever without arriving.
- Handed-over aircraft fly the homing waypoint, not the MCMC-MPC: the MPC optimizes the
  distance left at its horizon's end and, near a destination, finds circling as good as
  arriving; measured, it kept such aircraft circling until the time limit. The homing
  waypoint takes an aircraft through its destination.
- What it bounds: until handed over, an aircraft closes ``progress_fraction`` × 454 kt
  on average over every window, so it is home or handed over within about
  ``D / (progress_fraction × 454 kt)`` plus two windows, D its distance at the start
  (2.7 h for 500 nm at the default); handed over, it flies home at about the nominal
  airspeed, inside the evaluator's 4-h limit for the encounters of the paper.
- Its cost to a policy that does aim home is small: such a policy closes in at nearly
  the full rate, and where the rule does take an aircraft, the homing waypoint is close
  to the policy's own choice (the measured cost is on the documentation's safety-filter
  page).

The filter sees what the policy sees, the state and not the wind. Its wind estimate is
the MCMC-MPC's "estimated" model: after each period, the drift of the aircraft from
where the filter predicted the applied waypoints would put them, divided by T.

``episode_info()`` reports the wrapped policy's diagnostics with the filter's counts
added under names of their own (``SHIELD_INFO_KEYS``, all prefixed ``shield_``; the same
keys at every call): decisions seen, decisions changed for safety, aircraft changed,
decisions whose change was needed only by the look-ahead period, by kind the decisions
settled by a single-aircraft alternative, by an all-aircraft one, by a sampled one and by
the MPC fallback,
aircraft-decisions whose proposed waypoint was not a finite point of the workspace,
decisions applied although predicted unsafe (``shield_unresolved``: a least-bad fallback,
or an MPC decision the filter's prediction still finds unsafe), aircraft handed over by
the progress rule (``shield_stalled_aircraft``) and the decisions in which one flew its
homing waypoint (``shield_homing_decisions``).

Units: nautical miles, knots, seconds, radians.
"""

from __future__ import annotations

import dataclasses
import math
from types import MappingProxyType
from typing import Any, Callable, Union

import numpy as np

from atc_nf_env import kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.kernel import (
    ABSENT,
    FLYING,
    S_DEST_X,
    S_DEST_Y,
    S_HEADING,
    S_STATUS,
    S_WP_X,
    S_WP_Y,
    S_X,
    S_Y,
)
from atc_nf_env.policy import Policy, make_policy
from atc_nf_env.proposals import PROPOSAL_FIELDS, WaypointProposal, homing_mixture_draws, inside_workspace
from atc_nf_env.scenarios import Scenario, StreamScenario
from atc_nf_env.shield_prediction import (
    NONE_SAFE,
    SCREEN_HOMED,
    SCREEN_NONE_FLYING,
    SCREEN_NOT_FINITE,
    SCREEN_SAFE,
    DecisionMemory,
    PlanPredictor,
    _homing_waypoints,
    _structured_alternatives,
)
from atc_nf_env.simulation import WorldView
from atc_nf_env.units import AIRSPEED_NOMINAL_KT, DECISION_PERIOD_S, SECONDS_PER_HOUR

#: The fallbacks by name: the registry's MCMC-MPC, or the alternative that stayed safe longest.
FALLBACKS = ("mpc", "least-bad")
#: What ``SafetyFilter(fallback=...)`` takes: a name of ``FALLBACKS``, a policy object, or a
#: factory called once, without arguments, for one.
Fallback = Union[str, Policy, Callable[[], Policy]]

#: The filter's counts in ``episode_info()`` (prefixed so that none shadows a key of the
#: wrapped policy, such as the MPC's ``fallbacks``).
SHIELD_INFO_KEYS = (
    "shield_decisions",
    "shield_filtered",
    "shield_aircraft_changed",
    "shield_filtered_for_lookahead",
    "shield_single_changes",
    "shield_joint_changes",
    "shield_sampled_changes",
    "shield_mpc_fallbacks",
    "shield_unresolved",
    "shield_stalled_aircraft",
    "shield_homing_decisions",
    "shield_invalid_waypoints",
)

#: Turns of a proposed waypoint about its aircraft tried per aircraft, rad.
TURNS_RAD = tuple(math.radians(a) for a in (10.0, -10.0, 20.0, -20.0, 40.0, -40.0))
#: Turns tried for all flying aircraft at once, rad.
JOINT_TURNS_RAD = tuple(math.radians(a) for a in (20.0, -20.0, 40.0, -40.0))
#: Waypoint distances tried in the proposal's direction and toward home, nm.
DISTANCES_NM = (100.0, 130.0)
_TURNS, _JOINT_TURNS, _DISTANCES = np.array(TURNS_RAD), np.array(JOINT_TURNS_RAD), np.array(DISTANCES_NM)
#: The tiers of alternatives, tried in this order (see the module's docstring).
ALTERNATIVE_KINDS = ("single", "joint", "sampled")
#: An aircraft handed over by the progress rule that is within this distance of its
#: destination (nm) and heading more than ``APPROACH_TURN_RAD`` (rad) off its bearing flies
#: straight on before it turns home (see ``SafetyFilter._handover_waypoints``).
APPROACH_RADIUS_NM = 60.0
APPROACH_TURN_RAD = math.radians(75.0)
#: Waypoint sets of the sampled tier (each flown only until the first safe one).
SAMPLED_ALTERNATIVES = 64
#: The "mpc" fallback's settings on a traffic stream (``StreamScenario``), under those of
#: ``mpc_settings``: each independent conflict cluster searched by a chain of its own, and
#: the MPC's progress rule over 30 min (``baselines.MPCSettings``' fields). With the MPC's
#: joint defaults, nf-leg and deepsets_mixed inside the filter left the envelope on
#: stream-30 in every run tried (the joint sampler finds no feasible candidate among tens
#: of aircraft); these settings are the fallback of BENCHMARKS.md's "Shielded policies on
#: traffic streams" (``bench/mpc_dense_study.py``'s "per-cluster"), none outside there.
STREAM_FALLBACK_MPC_SETTINGS = MappingProxyType({"sampling": "per-cluster", "progress_fraction": 0.5,
                                                 "progress_periods": 6})
#: Tag of the sampled tier's random stream (the episode's seed is the other part).
_SAMPLE_STREAM = 0x5348


def _finite_number(name: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} = {value!r}: must be a number")
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{name} = {value!r}: must be a finite number in [{low:g}, {high:g}]")
    return float(value)


class SafetyFilter:
    """A policy that flies ``policy``'s waypoints unless the kernel predicts them unsafe.

    Args:
        policy: any object of the ``Policy`` interface (``reset``, ``act``, ``name``).
        lookahead_periods: 1 (the coming period) or 2 (and one more period with every
            aircraft re-aimed home), periods of ``period_s``.
        envelope_margin_kt: the prediction keeps the airspeed this far inside
            [366, 540] kt, kt (the MCMC-MPC's default margin, 4 kt).
        fallback: who decides when no alternative is safe: "mpc" (the registry's
            ``make_policy("mpc", **mpc_settings)``, the MCMC-MPC), "least-bad" (the
            alternative that stayed safe longest), a policy object (reset with the filter; given the filter's wind
            estimate through ``set_wind_estimate(wind_kt)`` if it has one), or a factory
            called once without arguments for one.
        home_distance_nm: distance of the homing waypoint of the look-ahead period, nm.
        recovery_angle_rad: a homing waypoint turns at most this far from the heading, rad
            (a waypoint behind the aircraft commands a reverse airspeed).
        period_s: the decision period T, s.
        mpc_settings: settings of the "mpc" fallback (``MPCSettings`` field names), each
            over the fallback's defaults: the MPC's own on an encounter, and
            ``STREAM_FALLBACK_MPC_SETTINGS`` on a traffic stream (give ``sampling="joint",
            progress_fraction=None`` to fly the joint MPC there); the proposal's fields
            among them (``atc_nf_env.proposals.PROPOSAL_FIELDS``) also shape the sampled
            tier, whatever the fallback. With another fallback, only those fields are
            allowed.
        progress_fraction: the progress rule (see the module's docstring): over every
            window of ``progress_periods`` periods a flying aircraft must close this
            fraction of what a direct flight at 454 kt covers in the window (or arrive, if
            it was within that of home), or it flies its homing waypoint from then on until
            it arrives; in [0, 1], None turns the rule off (the filter then guards safety
            only, and a proposer may keep aircraft from home). 0 asks only that an aircraft
            be no farther from home than a window ago.
        progress_periods: the progress rule's window, periods of ``period_s``.

    Example:
        >>> from atc_nf_env.episode import run_episode
        >>> from atc_nf_env.policy import make_policy
        >>> from atc_nf_env.scenarios import make_scenario
        >>> shielded = SafetyFilter(make_policy("nf"))
        >>> result = run_episode(shielded, make_scenario("converging-4"), seed=0)  # doctest: +SKIP
        >>> shielded.episode_info()["shield_filtered"]  # doctest: +SKIP
    """

    #: Whether this process has loaded the batched kernel (see ``reset``).
    _batch_warm = False

    def __init__(
        self,
        policy: Policy,
        *,
        lookahead_periods: int = 2,
        envelope_margin_kt: float = 4.0,
        fallback: Fallback = "mpc",
        home_distance_nm: float = 130.0,
        recovery_angle_rad: float = math.pi / 3,
        period_s: float = DECISION_PERIOD_S,
        mpc_settings: dict[str, Any] | None = None,
        progress_fraction: float | None = 0.5,
        progress_periods: int = 3,
    ) -> None:
        if isinstance(policy, SafetyFilter):
            raise TypeError("policy is already a SafetyFilter; wrap the policy itself once")
        if not (callable(getattr(policy, "act", None)) and callable(getattr(policy, "reset", None))):
            raise TypeError(
                f"policy is a {type(policy).__name__}; expected an object of the atc_nf_env.policy.Policy "
                "interface (reset(scenario, config, seed) and act(view))"
            )
        if isinstance(lookahead_periods, bool) or lookahead_periods not in (1, 2):
            raise ValueError(f"lookahead_periods = {lookahead_periods!r}: allowed: 1, 2")
        if isinstance(fallback, str) and fallback not in FALLBACKS:
            raise ValueError(f"fallback = {fallback!r}: allowed: {', '.join(FALLBACKS)}, a policy, or a factory of one")
        if mpc_settings is not None and not isinstance(mpc_settings, dict):
            raise TypeError(f"mpc_settings = {mpc_settings!r}: must be a dict of MPCSettings fields or None")
        self.policy = policy
        self.lookahead_periods = int(lookahead_periods)
        self.envelope_margin_kt = _finite_number("envelope_margin_kt", envelope_margin_kt, 0.0, 40.0)
        self.home_distance_nm = _finite_number("home_distance_nm", home_distance_nm, 1.0, 1000.0)
        self.recovery_angle_rad = _finite_number("recovery_angle_rad", recovery_angle_rad, 1e-6, math.pi / 2)
        self.period_s = _finite_number("period_s", period_s, 1e-9, 86400.0)
        self.mpc_settings = dict(mpc_settings or {})
        # The fallback first: the registry's "mpc" checks every one of mpc_settings' fields.
        self._fallback_policy = self._make_fallback(fallback)
        #: The "mpc" fallbacks built so far, by whether they fly a traffic stream.
        self._mpc_fallbacks: dict[bool, Policy] = {}
        if isinstance(fallback, str) and fallback == "mpc":
            self._mpc_fallbacks[False] = self._fallback_policy
        self.fallback = fallback if isinstance(fallback, str) else "policy"
        # The sampled tier draws from the MCMC-MPC's proposal distribution.
        proposal_settings = {k: v for k, v in self.mpc_settings.items() if k in PROPOSAL_FIELDS}
        try:
            self._proposal = WaypointProposal(**proposal_settings)
        except ValueError as error:
            raise ValueError(f"mpc_settings = {self.mpc_settings!r}: {error}") from None
        self.progress_fraction = (
            None if progress_fraction is None else _finite_number("progress_fraction", progress_fraction, 0.0, 1.0)
        )
        if (isinstance(progress_periods, bool) or not isinstance(progress_periods, (int, np.integer))
                or not 1 <= progress_periods <= 100):
            raise ValueError(f"progress_periods = {progress_periods!r}: must be an integer in [1, 100]")
        self.progress_periods = int(progress_periods)
        self.name = f"{getattr(policy, 'name', type(policy).__name__)}+shield"
        self._params: np.ndarray | None = None
        self._scratch = kernel.KernelScratch()
        self._counts = dict.fromkeys(SHIELD_INFO_KEYS, 0)
        self._memory = DecisionMemory(0, self.progress_periods)

    def _make_fallback(self, fallback: Fallback) -> Policy | None:
        """The fallback policy of ``fallback`` (None for "least-bad")."""
        if isinstance(fallback, str):
            if fallback == "least-bad":
                unused = sorted(set(self.mpc_settings) - set(PROPOSAL_FIELDS))
                if unused:
                    raise ValueError(
                        f"mpc_settings {unused} apply to fallback='mpc' only; with fallback={fallback!r} the "
                        f"sampled tier reads only {list(PROPOSAL_FIELDS)}"
                    )
                return None
            return make_policy("mpc", **self.mpc_settings)  # ValueError on a setting it does not take
        made = fallback
        if not _is_policy(made):
            if not callable(made):
                raise TypeError(
                    f"fallback is a {type(made).__name__}; expected one of {', '.join(FALLBACKS)}, an object of the "
                    "atc_nf_env.policy.Policy interface, or a factory of one"
                )
            made = made()
            if not _is_policy(made):
                raise TypeError(f"the fallback factory returned a {type(made).__name__}, not a Policy")
        if isinstance(made, SafetyFilter) or made is self.policy:
            raise TypeError("fallback must be a policy of its own, neither a SafetyFilter nor the policy filtered")
        unused = sorted(set(self.mpc_settings) - set(PROPOSAL_FIELDS))
        if unused:
            raise ValueError(
                f"mpc_settings {unused} apply to fallback='mpc' only; give a fallback policy its settings itself"
            )
        return made

    def fallback_mpc_settings(self, scenario: Scenario) -> dict[str, Any] | None:
        """The settings (``MPCSettings`` fields over its defaults) of the "mpc" fallback on
        ``scenario``: ``mpc_settings`` over ``STREAM_FALLBACK_MPC_SETTINGS`` on a traffic
        stream, ``mpc_settings`` on an encounter; None with another fallback."""
        if not self._mpc_fallbacks:
            return None
        if isinstance(scenario, StreamScenario):
            return {**STREAM_FALLBACK_MPC_SETTINGS, **self.mpc_settings}
        return dict(self.mpc_settings)

    def fallback_for(self, scenario: Scenario) -> Policy | None:
        """The fallback policy that ``scenario`` is flown with (None for "least-bad"): the
        "mpc" fallback in ``fallback_mpc_settings(scenario)``, built the first time it is
        needed. ValueError when ``mpc_settings`` do not go with the stream's settings."""
        if not self._mpc_fallbacks:
            return self._fallback_policy
        stream = isinstance(scenario, StreamScenario)
        if stream not in self._mpc_fallbacks:
            settings = self.fallback_mpc_settings(scenario)
            try:
                self._mpc_fallbacks[stream] = make_policy("mpc", **settings)
            except ValueError as error:
                raise ValueError(
                    f"mpc_settings = {self.mpc_settings!r}: on a traffic stream the MPC fallback flies them over "
                    f"{dict(STREAM_FALLBACK_MPC_SETTINGS)!r} ({error}); give the stream's settings explicitly, "
                    "e.g. sampling='joint', progress_fraction=None"
                ) from None
        return self._mpc_fallbacks[stream]

    # -- Policy interface -------------------------------------------------------------
    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Reset the wrapped policy (and the fallback policy) for a new episode."""
        self._fallback_policy = self.fallback_for(scenario)
        self.policy.reset(scenario, config, seed)
        if self._fallback_policy is not None:
            self._fallback_policy.reset(scenario, config, seed)
        margin = min(self.envelope_margin_kt, 0.25 * (config.airspeed_max_kt - config.airspeed_min_kt))
        self._config = dataclasses.replace(
            config, airspeed_min_kt=config.airspeed_min_kt + margin, airspeed_max_kt=config.airspeed_max_kt - margin
        )
        self._params = self._config.to_params(scenario.workspace_radius_nm, stop_on_violation=True)
        self._period_steps = kernel.steps_for(self.period_s, config.dt_s)
        self._waypoint_limit_nm = 0.99 * (scenario.workspace_radius_nm - config.aircraft_radius_nm)
        self._workspace_radius_nm = float(scenario.workspace_radius_nm)
        # The progress rule's ask over a window: its share of a direct flight at the nominal airspeed.
        self._progress_asked_nm = (None if self.progress_fraction is None else self.progress_fraction
                                   * AIRSPEED_NOMINAL_KT * self.progress_periods * self.period_s / SECONDS_PER_HOUR)
        self._arrival_nm = float(config.arrival_tolerance_nm)
        self._rng = np.random.default_rng([0 if seed is None else seed, _SAMPLE_STREAM])
        self._predictor = PlanPredictor(self._params, self._period_steps, self.lookahead_periods,
                                        self.home_distance_nm, self.recovery_angle_rad, self._waypoint_limit_nm)
        self._counts = dict.fromkeys(SHIELD_INFO_KEYS, 0)
        self._memory = DecisionMemory(scenario.n_aircraft, self.progress_periods)
        if not SafetyFilter._batch_warm:
            # Load the batched kernel (numba's cache, or a compilation) now, not inside the
            # first timed decision that needs alternatives.
            from atc_nf_env.simulation import initial_state

            state = initial_state(scenario, 2)
            kernel.advance(state, state[:, :, S_WP_X : S_WP_Y + 1].copy(), np.zeros((2, 2)), config.dt_s,
                           self._params, scratch=kernel.KernelScratch())
            # And the structured alternatives' code (a cache load of several ms otherwise
            # falls into the first decision changed).
            view = WorldView(0.0, np.ascontiguousarray(state[0]), scenario)
            for kind in ("single", "joint"):
                self._alternatives(view, view.waypoints, np.zeros(scenario.n_aircraft, dtype=np.bool_), kind)
            # And the alternatives' prediction, a compiled entry of its own: its cache load
            # (about 25 ms) fell into the first decision changed, inside a timed run.
            self._predictor.first_safe(view.state, np.ascontiguousarray(view.waypoints[None], dtype=np.float64),
                                       np.zeros(2), checked=False)
            SafetyFilter._batch_warm = True

    def act(self, view: WorldView) -> np.ndarray:
        """The wrapped policy's waypoints (N, 2) nm, or the closest safe alternative."""
        if self._params is None:
            raise RuntimeError("call reset(scenario, config, seed) before act()")
        proposal = self.policy.act(view)
        if type(proposal) is not np.ndarray or proposal.dtype != np.float64:
            if np.iscomplexobj(proposal):
                raise ValueError(f"{type(self.policy).__name__}.act returned complex waypoints; expected real (N, 2) nm")
            proposal = np.asarray(proposal, dtype=np.float64)
        state = np.ascontiguousarray(view.state, dtype=np.float64)  # the compiled prediction reads it as is
        n = state.shape[0]
        if proposal.shape != (n, 2):
            raise ValueError(f"{type(self.policy).__name__}.act returned shape {proposal.shape}; expected ({n}, 2) nm")
        if not proposal.flags.c_contiguous:
            proposal = np.ascontiguousarray(proposal)
        if not (np.abs(proposal) <= self._workspace_radius_nm).all():  # NaN fails the test too
            proposal = self._replace_invalid(state, proposal)
        memory = self._memory
        # The routine decision, wind estimate and progress rule included, in one compiled call
        # (``PlanPredictor.screen``): its Python took about a fifth of a shielded decision.
        verdict = self._predictor.screen(state, proposal, float(view.time_s), self.period_s, memory,
                                         self._progress_asked_nm, self._arrival_nm)
        if verdict == SCREEN_NOT_FINITE:  # the proposal was made finite above: the state is not
            raise ValueError(f"the state has NaN or inf values; the filter cannot predict it: {state.tolist()}")
        counts = self._counts
        counts["shield_decisions"] += 1
        counts["shield_stalled_aircraft"] = int(memory.counts[1])  # the progress rule counts them in ``screen``
        if verdict == SCREEN_SAFE or verdict == SCREEN_NONE_FLYING:
            return proposal
        flying = state[:, S_STATUS] == FLYING
        planned = memory.planned[0].copy()
        homed = verdict == SCREEN_HOMED
        if homed:
            # The progress rule: the aircraft handed over fly their homing waypoints (the
            # module's docstring says why not the fallback policy's), every other aircraft
            # keeping the policy's waypoint.
            handed = np.flatnonzero(memory.homebound & flying)
            planned[handed] = self._handover_waypoints(state, planned)[handed]
            outcome = self._check(state, planned)
            counts["shield_homing_decisions"] += 1
            if outcome[0] is None:
                memory.remember(view.time_s + self.period_s, outcome[3], outcome[4])
                return self._apply(proposal, planned, flying)
        else:
            outcome = self._breach()
        survived, period1_ok, blamed = outcome[0], outcome[1], outcome[2]
        counts["shield_filtered"] += 1
        if period1_ok:
            counts["shield_filtered_for_lookahead"] += 1
        # Unsafe: tier by tier (ALTERNATIVE_KINDS), the alternatives in the order they would
        # be chosen (fewest aircraft changed, then the least displacement), each predicted
        # alone until the first safe one.
        tried = []
        for kind in ALTERNATIVE_KINDS:
            candidates, changed = self._alternatives(view, planned, blamed, kind)
            displacement = np.hypot(*(candidates - planned[None]).transpose(2, 0, 1)).sum(axis=1)
            tried.append((candidates, changed))
            ordered = np.ascontiguousarray(candidates[np.lexsort((displacement, changed.sum(axis=1)))], dtype=np.float64)
            # Unchecked: the filter built every input (the state passed the screen's flight).
            index = self._predictor.first_safe(state, ordered, memory.wind_kt, checked=False)
            if index != NONE_SAFE:
                counts[f"shield_{kind}_changes"] += 1
                memory.remember(view.time_s + self.period_s, self._predictor.positions, self._predictor.alive)
                return self._apply(proposal, ordered[index], flying)
        if self._fallback_policy is not None:
            counts["shield_mpc_fallbacks"] += 1
            self._share_wind_estimate()
            applied = self._apply(proposal, np.asarray(self._fallback_policy.act(view), dtype=np.float64), flying)
            survived_m, positions_m, alive_m = self._predict(state, applied[None])
            if survived_m[0] < self._full_steps():
                counts["shield_unresolved"] += 1
            if survived_m[0] < self._period_steps:
                memory.forget()  # a prediction cut short at a breach says nothing of the wind
            else:
                memory.remember(view.time_s + self.period_s, positions_m[0], alive_m[0])
            return applied
        counts["shield_unresolved"] += 1
        candidates, changed = (np.concatenate(parts) for parts in zip(*tried))
        survived_c = self._predict(state, candidates)[0]
        displacement = np.hypot(*(candidates - planned[None]).transpose(2, 0, 1)).sum(axis=1)
        best = int(np.lexsort((displacement, changed.sum(axis=1), -survived_c))[0])
        if survived_c[best] <= survived:
            return self._apply(proposal, planned, flying)  # no alternative stays safe longer than the plan
        memory.forget()  # a prediction cut short at a breach says nothing of the wind
        return self._apply(proposal, candidates[best], flying)

    def episode_info(self) -> dict[str, Any]:
        """The wrapped policy's diagnostics and the filter's counts (``SHIELD_INFO_KEYS``)."""
        inner = getattr(self.policy, "episode_info", None)
        info = dict(inner()) if callable(inner) else {}
        info.update(self._counts)
        info["shield_wind_estimate_kt"] = self._memory.wind_kt.tolist()
        return info

    # -- internals ----------------------------------------------------------------------
    def _full_steps(self) -> int:
        return self.lookahead_periods * self._period_steps

    def _replace_invalid(self, state: np.ndarray, proposal: np.ndarray) -> np.ndarray:
        """The proposal with every waypoint that is not finite or lies outside the
        workspace's bounding square replaced: a flying aircraft's by its homing waypoint
        (counted as a change), any other's by its current waypoint. Such a waypoint is
        unsafe by definition: the kernel cannot fly it (NaN, inf) or its navigation
        function overflows (1e100 nm)."""
        invalid = ~(np.abs(proposal) <= self._workspace_radius_nm).all(axis=1)  # NaN fails the test too
        flying = state[:, S_STATUS] == FLYING
        replaced = np.where(invalid[:, None], state[:, S_WP_X : S_WP_Y + 1], proposal)
        homed = invalid & flying
        if homed.any():
            replaced[homed] = self._homing(state)[homed]
            self._counts["shield_invalid_waypoints"] += int(homed.sum())
            self._counts["shield_aircraft_changed"] += int(homed.sum())
        return np.ascontiguousarray(replaced)

    def _apply(self, proposal: np.ndarray, applied: np.ndarray, flying: np.ndarray) -> np.ndarray:
        """``applied`` (N, 2) nm for the flying aircraft (``flying`` (N,) bool), the proposal
        for the others; counts the aircraft whose waypoint differs from the proposal."""
        changed = flying & (applied != proposal).any(axis=1)
        self._counts["shield_aircraft_changed"] += int(changed.sum())
        return np.where(changed[:, None], applied, proposal)

    def _check(
        self, state: np.ndarray, planned: np.ndarray
    ) -> tuple[int | None, bool, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Predict one waypoint set (N, 2) over the look-ahead, one world from a copy of
        ``state``. Safe: (None, True, None, positions (N, 2) and flying flags (N,) after
        the first period). Unsafe: (integration steps it stayed safe, whether the first
        period was safe, the aircraft the breach involved (N,), None, None)."""
        predictor = self._predictor
        if predictor.first_safe(state, np.ascontiguousarray(planned[None]), self._memory.wind_kt,
                                checked=False) != NONE_SAFE:
            return None, True, None, predictor.positions.copy(), predictor.alive.copy()
        return self._breach()

    def _breach(self) -> tuple[int, bool, np.ndarray, None, None]:
        """``_check``'s unsafe outcome of the predictor's last prediction of one waypoint set
        (``screen``'s or ``first_safe``'s candidate 0)."""
        survived = int(self._predictor.survived[0])
        return survived, survived >= self._period_steps, self._predictor.blamed[0].copy(), None, None

    def _predict(
        self, base_state: np.ndarray, waypoints: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fly B candidate waypoint sets (B, N, 2) from ``base_state`` under the wind estimate.

        Returns the integration steps each world stayed safe (the full look-ahead when it
        never breached, or when every aircraft arrived), and the positions (B, N, 2) and
        flying flags (B, N) after the first period.
        """
        n_worlds = waypoints.shape[0]
        states = np.repeat(base_state[None], n_worlds, axis=0)
        flying0 = base_state[:, S_STATUS] == FLYING
        wind = np.repeat(self._memory.wind_kt[None], n_worlds, axis=0)
        survived = np.zeros(n_worlds, dtype=np.int64)
        safe = np.ones(n_worlds, dtype=bool)
        positions = alive = None
        for period in range(self.lookahead_periods):
            if period > 0:
                waypoints = self._homing(states)
                waypoints[:, ~flying0] = base_state[None, ~flying0, S_WP_X : S_WP_Y + 1]
            trace = kernel.advance(states, waypoints, wind, self.period_s, self._params, scratch=self._scratch)
            done = np.where(trace.violated, trace.steps_done - 1, self._period_steps)
            survived += np.where(safe, done, 0)
            newly_bad = trace.violated & safe
            if period == 0:
                positions = states[:, :, S_X : S_Y + 1].copy()
                alive = states[:, :, S_STATUS] == FLYING
            safe &= ~newly_bad
            if not safe.any():
                break
            # A world that breached is unsafe already: stop simulating it.
            status = states[:, :, S_STATUS]
            status[newly_bad] = np.where(status[newly_bad] == FLYING, ABSENT, status[newly_bad])
        return survived, positions, alive

    def _homing(self, states: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
        """Waypoints (B, N, 2) of worlds ``states`` (B, N, N_STATE), or (N, 2) of one world
        (N, N_STATE): each flying aircraft aimed at its destination ``home_distance_nm``
        out, turned at most ``recovery_angle_rad`` from its heading, inside the workspace
        (the prediction's own compiled ``_homing_waypoints``); the others keep ``keep``
        (same shape as the result; their current waypoints by default)."""
        one = states.ndim == 2
        worlds = states[None] if one else states
        home = (worlds[:, :, S_WP_X : S_WP_Y + 1] if keep is None else np.reshape(keep, (len(worlds), -1, 2))).copy()
        for world, out in zip(worlds, home):
            # ``out`` is also what the others keep: their rows are read back unchanged.
            _homing_waypoints(world, out, self.home_distance_nm, self.recovery_angle_rad, self._waypoint_limit_nm, out)
        return home[0] if one else home

    def _handover_waypoints(self, state: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """The waypoints (N, 2) nm of aircraft handed over by the progress rule, in world
        ``state`` (N, N_STATE): the homing waypoint (``_homing``), except for an aircraft
        within ``APPROACH_RADIUS_NM`` of its destination and heading more than
        ``APPROACH_TURN_RAD`` off its bearing there, which flies straight on,
        ``home_distance_nm`` ahead, until it is farther out or better aligned.

        Why: the homing waypoint turns an aircraft at most ``recovery_angle_rad`` a period,
        and the NF's path to a waypoint curves where the heading is off the line to it; close
        to home and badly aligned, the aircraft then passes its destination wide of the
        arrival tolerance and circles it (measured: one aircraft 10-40 nm out, 90-135° off,
        circled for 3 h). Flying out first and turning back from beyond 60 nm, it lined up and
        arrived from every start tried (6-65 nm out, 45-170° off, within 45 min). The
        ``keep`` rows (N, 2) are returned for the aircraft not flying."""
        waypoints = self._homing(state, keep)
        position = state[:, S_X : S_Y + 1]
        to_dest = state[:, S_DEST_X : S_DEST_Y + 1] - position
        heading = state[:, S_HEADING]
        error = (np.arctan2(to_dest[:, 1], to_dest[:, 0]) - heading + np.pi) % (2.0 * np.pi) - np.pi
        straight = ((state[:, S_STATUS] == FLYING) & (np.hypot(to_dest[:, 0], to_dest[:, 1]) < APPROACH_RADIUS_NM)
                    & (np.abs(error) > APPROACH_TURN_RAD))
        if straight.any():
            ahead = position + self.home_distance_nm * np.stack([np.cos(heading), np.sin(heading)], axis=1)
            limit = self._waypoint_limit_nm
            scale = np.minimum(1.0, limit / np.maximum(np.hypot(ahead[:, 0], ahead[:, 1]), 1e-12))
            waypoints[straight] = (ahead * scale[:, None])[straight]
        return waypoints

    def _alternatives(
        self, view: WorldView, planned: np.ndarray, blamed: np.ndarray, kind: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """Candidate waypoint sets (M, N, 2) and which aircraft each changes (M, N), of one
        tier of ``ALTERNATIVE_KINDS``: the single-aircraft changes of the blamed aircraft,
        the all-aircraft ones, or the sampled ones."""
        if kind == "sampled":
            return self._sampled(view, planned)
        flying = view.flying
        suspects = np.flatnonzero(blamed & flying)
        if suspects.size == 0:
            suspects = np.flatnonzero(flying)
        joint = kind == "joint"
        return _structured_alternatives(
            view.state, np.ascontiguousarray(planned, dtype=np.float64), suspects, joint,
            _JOINT_TURNS if joint else _TURNS, _DISTANCES, _DISTANCES, self.recovery_angle_rad,
            self._waypoint_limit_nm,
        )

    def _sampled(self, view: WorldView, planned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``SAMPLED_ALTERNATIVES`` waypoint sets (M, N, 2) from the MCMC-MPC's proposal
        distribution (``WaypointProposal``), every flying aircraft changed, and (M, N) which."""
        settings, flying, state = self._proposal, view.flying, view.state
        position = state[:, S_X : S_Y + 1]
        to_dest = state[:, S_DEST_X : S_DEST_Y + 1] - position
        direction, distance = homing_mixture_draws(
            self._rng, settings, state[:, S_HEADING], np.arctan2(to_dest[:, 1], to_dest[:, 0]),
            SAMPLED_ALTERNATIVES, settings.recovery_fraction, settings.distance_std_nm,
        )
        distance = np.maximum(distance, 1.0)
        variants = inside_workspace(position + distance[..., None] * np.stack([np.cos(direction), np.sin(direction)],
                                                                              axis=-1), self._waypoint_limit_nm)
        return np.where(flying[None, :, None], variants, planned[None]), np.repeat(flying[None], SAMPLED_ALTERNATIVES,
                                                                                   axis=0)

    def _share_wind_estimate(self) -> None:
        """Hand the filter's wind estimate to the fallback policy, which is not called every
        period and so cannot keep an estimate of its own."""
        setter = getattr(self._fallback_policy, "set_wind_estimate", None)
        if callable(setter):
            setter(self._memory.wind_kt.copy())


def _is_policy(candidate: Any) -> bool:
    return callable(getattr(candidate, "act", None)) and callable(getattr(candidate, "reset", None))


def summarize_interventions(
    infos: list[dict[str, Any]], records: list[dict[str, Any]] | None = None
) -> dict[str, Any] | None:
    """The filter's counts over runs (their ``episode_info()``): totals, the runs with any
    change, and the share of decisions changed; None when no run was shielded. With the
    runs' ``records`` (the results file's run lines, whose ``policy_info`` are ``infos``),
    also the runs that breached anyway (``breached_runs``)."""
    shielded = [info for info in infos if "shield_decisions" in info]
    if not shielded:
        return None
    # .get: runs recorded before a count existed lack its key.
    totals = {key.removeprefix("shield_"): int(sum(info.get(key, 0) for info in shielded)) for key in SHIELD_INFO_KEYS}
    decisions = totals["decisions"]
    summary = {
        **totals,
        "runs": len(shielded),
        "runs_filtered": int(sum(info["shield_filtered"] > 0 for info in shielded)),
        "runs_with_mpc_fallback": int(sum(info["shield_mpc_fallbacks"] > 0 for info in shielded)),
        "filtered_fraction": totals["filtered"] / decisions if decisions else 0.0,
    }
    if records is not None:
        summary.update(breached_runs([r for r in records if "shield_decisions" in (r.get("policy_info") or {})]))
    return summary


def breached_runs(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Of shielded runs (run records of a results file), those that breached although
    filtered (``runs_breached``: an integration step outside [366, 540] kt, even one step
    a fraction of a knot out, or a loss of separation; the predicates of the summary's
    ``runs_with_envelope_violation`` and ``runs_with_los``), how many of them had the filter
    apply a decision its own prediction found unsafe (``runs_breached_after_unresolved``:
    ``shield_unresolved`` > 0), and the range of such decisions per breached run
    (``unresolved_per_breached_run``, None without a breached run): whether the breaches
    are the filter's known give-ups or escaped its prediction (the wind estimate off by
    more than the envelope margin)."""
    breached = [r for r in records if r["envelope_violation_fraction"] > 0 or r["los_count"] > 0]
    unresolved = [int((r.get("policy_info") or {}).get("shield_unresolved", 0)) for r in breached]
    given_up = [u for u in unresolved if u > 0]
    return {
        "runs_breached": len(breached),
        "runs_breached_after_unresolved": len(given_up),
        "unresolved_per_breached_run": [min(unresolved), max(unresolved)] if unresolved else None,
    }


__all__ = ["ALTERNATIVE_KINDS", "FALLBACKS", "Fallback", "SAMPLED_ALTERNATIVES", "SHIELD_INFO_KEYS",
           "STREAM_FALLBACK_MPC_SETTINGS", "SafetyFilter", "breached_runs", "summarize_interventions"]
