"""The paper's MCMC model-predictive controller (section III, Table I; section IV-C/D).

Every T = 5 min the controller chooses one intermediate waypoint per aircraft:

1. K joint proposals Θ_k are drawn from g: for every flying aircraft, a distance
   ~ N(100 nm, 10 nm) and an angle ~ U[−π/2, π/2] around the line from the aircraft to
   its destination (IV-C). (The default "homing" proposal differs: see below.)
2. All K candidates are simulated at once, in one batch of the simulator kernel (the
   oracle O of Table I is the kernel started from a copy of the state), over the
   horizon N·T. Only the first waypoint is optimized: at each later period of the
   horizon every aircraft's waypoint is shifted forward by the distance that aircraft
   covered in the period before (IV-C).
3. A candidate is infeasible, with infinite cost, if any aircraft's airspeed leaves
   [366, 540] kt or two aircraft come closer than 5 nm anywhere in the horizon: checked
   at every integration step by default (a world stops being simulated at its first
   violation), or only at the sampling instants t + pT as the paper states
   (``constraint_check="sampling-instants"``). The cost of a feasible candidate is
   L = Σ_i D(i, t + NT), the aircraft's remaining distances to their destinations at
   the horizon's end (6), nm.
4. A Metropolis-Hastings chain runs over the K candidates in their drawing order. The
   proposals do not depend on the chain's state, so simulating them first and running
   the chain afterwards is the sequential algorithm of Table I, identical in
   distribution. The target is π(Θ) ∝ C(Θ)^−J (J = ``cost_exponent``, 1 by default) and
   the acceptance is the standard independence sampler's::

       ρ = min{1, (C_{k−1} / C̃)^J · g(Θ_{k−1}) / g(Θ̃)}.

   Table I prints the proposal ratio the other way up, g(Θ̃) / g(Θ_{k−1}), which does
   not leave π invariant; ``acceptance="table-i"`` reproduces the printed form.
5. The candidate of lowest cost among the chain's states is applied (Table I's last
   step).

## What the default (``proposal="homing"``) changes, and why

Table I's sampler, proposal and cost stay available as ``proposal="paper"`` (CLI
``--proposal paper``). Flown as printed, they leave aircraft holding short of home and
breach the envelope at fallbacks: ``atc-nf evaluate --policy mpc --proposal paper
--scenario converging-6 --runs 60 --workers 1`` brought every aircraft home in 51 of 60
runs, and seed 32 flew −471 kt after 2 fallbacks (converging-4: 54 of 60). Each cause
is met by one change:

* Joint sampling. Every candidate draws every aircraft's angle independently, so when
  several aircraft are on final approach together almost no joint candidate brings all
  of them in, and the chain keeps the best state it visited. Table I leaves the
  chain's initial state free; here it is Θ_0 = every aircraft aimed at its destination,
  ``home_distance_nm`` (130 nm) out (turned at most ``recovery_angle_rad`` from its
  heading, see below). 130 nm rather than the mean 100 nm because the NF flies faster
  toward a farther waypoint (5-min average from 454 kt: 452 kt at 100 nm, 464 kt at
  130 nm); measured on converging-4 seeds 100–119, mean flight 68.4 min at 100 nm,
  67.2 at 130, 66.7 at 160 (160 nm flew more steps within 1 kt of 540). Θ_0 lies 3σ
  out in g, so its weight π/g is large and the chain leaves it only for a candidate
  of clearly lower cost, or when Θ_0 is infeasible (a conflict): then it runs as in
  Table I.
* Cost. An aircraft that arrives within the horizon counts 0 in (6) whenever it
  arrives, so on final approach every candidate costs the same and nothing favours
  arriving sooner. The cost adds the time each aircraft flies within the horizon
  (until its arrival, or N·T), as distance at the nominal 454 kt:
  L = Σ_i [D(i, t + NT) + 454 kt · τ_i]. While no aircraft arrives within the horizon
  this adds the same constant to every candidate, so their order is (6)'s.
* An aircraft that has missed (a gust, a conflict): all of Table I's angles lie within
  90° of the line home, so once home is behind the aircraft every waypoint is too, the
  NF answers with P_i > 0, i.e. a reverse airspeed u = −F, and every candidate is
  infeasible. The proposal is therefore a mixture per aircraft: with probability
  1 − f (``recovery_fraction`` f = 0.25) Table I's angle, with probability f an angle
  uniform in ± ``recovery_angle_rad`` (60°) around the current heading, which turns the
  aircraft back over a few periods. The mixture's density enters the MH ratio, so the
  chain still samples π ∝ C^−J. (The test suite flies an aircraft that starts facing
  away from home: Table I reverses it at −450 kt, "homing" turns it home inside the
  envelope.)
* Fallbacks. When no candidate of a round is feasible, up to ``search_rounds`` (2) more
  rounds of K candidates are drawn, each giving the heading-relative angles a larger
  share (f_r = 1 − (1 − f)/2^r) and the distance a wider σ (σ·(1 + r)); the first
  round with a feasible candidate runs the chain. Only when every round fails is the
  fallback flown (the candidate, of any round, that stayed feasible longest), and
  ``episode_info()`` counts it (``fallbacks``), the decisions that needed a wider
  search (``wider_searches``, ``rescued_by_wider_search``), and the fallbacks whose
  applied candidate was predicted to breach within the first period
  (``fallbacks_breach_predicted``).
* Prediction error. The predicted wind is an estimate, so a candidate predicted to
  touch 366 kt may fly at 365. The prediction holds the airspeed
  ``envelope_margin_kt`` (4 kt) inside the envelope; the real flight is judged against
  [366, 540] kt. At an episode's first decision no drift has been seen yet, and the
  prediction flies without wind: ``first_decision_margin_kt`` (10 kt) holds there. With
  4 kt there too, ``atc-nf reproduce --runs 1000`` found 1 random-4 and 3 random-6 runs
  (winds of 26-30 kt) that dipped 0.03-2.2 kt below 366 kt in their first period; with
  10 kt those four runs stay inside and the converging runs checked fly unchanged.

Later horizon waypoints stay shifted copies, as in IV-C: with the decision re-planned
every period, the recovery angles turned every missed aircraft home in the runs below
without re-aiming them.

What the defaults and Table I's proposal fly on the paper's encounters is measured in
REPRODUCTION.md (``atc-nf reproduce``, 1000 runs each); in dense traffic and on streams
in docs/mpc.md and BENCHMARKS.md.

## Traffic of any density (``sampling="auto"``)

The joint search is the paper's, and it is what the default flies on the paper's
encounters (at most ``JOINT_SEARCH_MAX_AIRCRAFT`` = 6 aircraft), bit for bit as before
``"auto"`` existed. With more aircraft in conflict at once, almost no joint candidate is
feasible: the default then flies ``DENSE_TRAFFIC_SETTINGS``, the per-cluster search with
the progress rule (``sampling="per-cluster"``, ``progress_fraction=0.5``,
``progress_periods=6``), and on every traffic stream. The choice is made at ``reset``
from the scenario (``MPCSettings.for_traffic``); ``settings`` is what flies, and
``requested_settings`` what was asked. Give ``sampling`` to choose yourself; the named
settings that the benchmark pages compare are ``NAMED_SETTINGS``.

## Lazy search

The chain needs a candidate's cost only to decide whether to move to it, so by default
(``search="lazy"``) a candidate is flown only as far as that decision needs. Its cost
is bounded from below by what the rest of the horizon can still change: ground speed
at most the envelope's top airspeed plus the predicted wind, the time term known up to
the arrival (``_LazyCandidates._bound``). While the chain sits on a feasible state, a
candidate whose bound already gives ρ ≤ u (u its pre-drawn uniform) is rejected
whatever its cost, as an infeasible one would be; the first candidate the bound does not
decide is flown a period further and looked at again, and a state the chain moves to is
flown to the end. With it, in the same batch of the kernel, fly the later candidates that
the chain would also find undecided if it ran ahead on guessed costs (each aircraft flying
straight home at the nominal airspeed): a guess only chooses what to fly, never a verdict.
When Θ_0 is feasible, its weight π/g makes the chain reject nearly every candidate on
the bound alone, and Θ_0 is the only candidate flown. When Θ_0 is infeasible, the chain
moves to every candidate until a feasible one: the candidates are flown to the end in
the chain's order, in batches of 8, 16, ..., until the first feasible one, and from there
the chain wanders among the random draws as above, flying a fraction of the K · N
candidate-periods the exhaustive search flies. Batches of fewer than
``_PARALLEL_FROM_WORLDS`` candidates are flown on one thread. Every verdict is the
exhaustive chain's, taken with the same arithmetic, and a round without a feasible
candidate has flown every candidate (the wider rounds and the fallback see exactly the
exhaustive search's survivals), so the applied waypoints, the chain's moves, the rounds
and the random stream are the same bit for bit (``tests/test_mpc_search.py``). The
price: the feasible fraction of the candidates is known only where every candidate was
flown (in practice, a round without a feasible candidate); ``search="exhaustive"`` flies
all K over the whole horizon and reports it for every decision
(``DecisionRecord.feasible_fraction`` is None otherwise).

## Dense traffic (opt-in)

Two settings for many aircraft, off by default (the defaults above fly bit for bit as
without them):

* ``sampling="clusters"``. Joint sampling draws every aircraft's angle in every
  candidate, so beyond about ten aircraft few joint candidates are feasible where
  conflicts meet, and a fallback is flown. Here the chain's start Θ_0 is flown alone
  first. If it is feasible, the decision is the joint one. Otherwise the aircraft
  involved in its first violation (out of the prediction's envelope, or in a loss of
  separation) and every flying aircraft within ``cluster_radius_nm`` of one of them,
  where they are when it happens, form a cluster; the K candidates draw only the
  cluster's waypoints and the other aircraft keep Θ_0's. Every candidate is still flown
  with every aircraft, so feasibility is the joint prediction's, and candidate 0 is Θ_0,
  so the chain is Table I's over the cluster's coordinates. After a round without a
  feasible candidate: if a candidate put the first violation off (it stayed feasible
  longer than the start), it becomes the chain's start and the next round samples the
  cluster of its own first violation (a repair; at most ``CLUSTER_REPAIRS`` a decision);
  otherwise the violations of the longest survivor grow the cluster and the round runs
  again at the same width; only when neither is possible does the next, wider round
  follow, and the fallback is chosen among every candidate flown. (Giving a round up
  after its first 256 candidates halved the decision time on converging-16 but brought
  fallbacks back: every round searches all K.)
* ``sampling="per-cluster"``. With several conflicts in the horizon, "clusters" goes
  from one to the next within one chain, and its cluster grows to most of them. Here the
  chain's start Θ_0 is flown alone through the whole horizon, past its violations; an
  aircraft that breaks a constraint at an integration step is linked to every flying
  aircraft within ``cluster_radius_nm`` of it at that step (and to the other aircraft of
  its loss of separation), and each connected set of links is an independent conflict
  cluster. None: the decision is the joint one. One: the "clusters" search of that
  cluster. Several: each, in the order of its first violation, is searched by a chain of
  its own ("clusters"' rounds, repairs and growth) in a world without the other
  clusters' aircraft (they would break the constraints of every candidate), and the
  choices, put together, are flown jointly. If they hold (no violation), they are
  applied; if not (a changed path met another cluster), the "clusters" search runs from
  them over the cluster of their first violation, with its fallback. Every applied plan is
  feasible in the joint prediction unless the decision counts as a fallback. Needs
  ``constraint_check="every-step"``: the clusters are found at integration-step
  resolution.
* The progress rule (``progress_fraction``, ``progress_periods``). The cost looks one
  horizon (20 min) ahead, so an aircraft that overshot near its destination can be kept
  circling it: every candidate that flies out and back costs more within the horizon
  than one that circles close (converging-12 seed 880001 under the defaults: one
  aircraft circled 14-57 nm from home for 2.5 h with no fallback). An aircraft that
  closed less than ``progress_fraction`` of a direct flight's progress over the last
  ``progress_periods`` periods it flew whole is held, in every candidate, on its
  recovery waypoint: Θ_0's, or, within ``shield.APPROACH_RADIUS_NM`` (60 nm) of home and
  more than ``shield.APPROACH_TURN_RAD`` (75°) off its bearing, straight ahead (the
  safety filter's hand-over, whose docstring says why). It stays held until it arrives;
  a wider round, after one without a feasible candidate, samples it again. In a traffic
  stream a slot's next flight starts unheld.
* Turning near home (``approach_angle_rad``). A recovery turn of at most
  ``recovery_angle_rad`` (60°) a 5-minute period circles about 35 nm out, at 454 kt: an
  aircraft pushed past its destination (most often by a conflict where its approach
  would go) can orbit it for most of an hour outside the 5-nm arrival radius, because
  the horizon's shifted waypoints cannot represent a go-around. With
  ``approach_angle_rad`` set, an aircraft within ``shield.APPROACH_RADIUS_NM`` (60 nm) of
  its destination turns up to that angle instead (its heading share of the proposal, its
  start direction, the progress rule's recovery waypoint); elsewhere nothing changes, so
  a crowd far from home is searched as before. The candidates stay checked against the
  envelope like any other. A wider turn shrinks the circle; it does not end the orbit.

## Prediction wind and fallback

The controller never sees the true wind. Its prediction wind model is configurable:
``"none"`` (still air), ``"sampled"`` (each candidate predicted under its own wind drawn
from N(0, σ²) per component) or ``"estimated"`` (a constant wind estimated from the
observed drift: after each period the difference between where the aircraft are and
where the controller predicted the applied candidate would put them, divided by T,
corrects the estimate). The prediction compared with always covers the whole period: a
fallback that breaks a constraint in its first period, whose prediction stopped at the
breach, is predicted again for the whole period without stopping
(``MCMCMPC._whole_first_period`` says why it is re-flown, not skipped).

Fallback: when no candidate is feasible, the controller applies the candidate that
stayed feasible longest (the most integration steps, or sampling instants, before its
first violation; ties broken by the distance cost) and counts the decision as a
fallback. ``episode_info()`` reports the fallbacks and the feasible fraction of the
first round of every decision that measured it (all under ``search="exhaustive"``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numba
import numpy as np
from numba import njit

from atc_nf_env import kernel, nf
from atc_nf_env.config import BATCH_MEMORY_BYTES, SimConfig, check_batch_size, max_batch_worlds, world_memory_bytes
from atc_nf_env.episode import MAX_TIME_LIMIT_S
from atc_nf_env.kernel import (
    ABSENT,
    ARRIVED,
    FLYING,
    S_AIRSPEED,
    S_DEST_X,
    S_DEST_Y,
    S_STATUS,
    S_TIME,
    S_X,
    S_Y,
)
# The proposal's draws live in the core, which the safety filter's sampled tier shares;
# re-exported here, where they were first defined.
from atc_nf_env.proposals import homing_mixture_draws, inside_workspace
from atc_nf_env.scenarios import Scenario, StreamScenario
from atc_nf_env.shield import APPROACH_RADIUS_NM, APPROACH_TURN_RAD, STREAM_FALLBACK_MPC_SETTINGS
from atc_nf_env.simulation import WorldView, initial_state
from atc_nf_env.units import AIRSPEED_NOMINAL_KT, DECISION_PERIOD_S, KT_PER_MPS, SECONDS_PER_HOUR, WIND_SIGMA_MPS
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

WIND_MODELS = ("none", "sampled", "estimated")
PROPOSALS = ("homing", "paper")
CONSTRAINT_CHECKS = ("every-step", "sampling-instants")
ACCEPTANCES = ("standard", "table-i")
SEARCHES = ("lazy", "exhaustive")
SAMPLINGS = ("auto", "joint", "clusters", "per-cluster")

#: ``sampling="auto"`` searches jointly up to this many aircraft (the paper's encounters
#: have 4 and 6; its Table I is a joint search) and per conflict cluster above it.
JOINT_SEARCH_MAX_AIRCRAFT = 6
#: What ``sampling="auto"`` flies in traffic the joint search cannot cope with (encounters
#: of more than ``JOINT_SEARCH_MAX_AIRCRAFT`` aircraft, every traffic stream): each
#: independent conflict cluster searched by a chain of its own, and the progress rule over
#: 30 min (unless ``progress_fraction`` is given; then it is the one given, over
#: ``progress_periods``). Measured against the joint search: docs/mpc.md.
#: The same settings as the safety filter's MPC fallback on streams, which is where they
#: were measured first (the core's constant: the filter cannot import this package).
DENSE_TRAFFIC_SETTINGS = STREAM_FALLBACK_MPC_SETTINGS
#: Documented settings of the one controller, by name (``MCMCMPC(**NAMED_SETTINGS[name])``):
#: what BENCHMARKS.md and docs/mpc.md compare. "auto" is the default.
NAMED_SETTINGS = MappingProxyType({
    "auto": MappingProxyType({}),
    "joint": MappingProxyType({"sampling": "joint"}),
    "dense": MappingProxyType({**DENSE_TRAFFIC_SETTINGS, "sampling": "clusters"}),
    "per-cluster": DENSE_TRAFFIC_SETTINGS,
    # Turning up to 70° instead of 60° a period: near home, 60° a period circles ~35 nm out.
    "per-cluster-70": MappingProxyType({**DENSE_TRAFFIC_SETTINGS, "recovery_angle_rad": math.radians(70.0)}),
    # Turning up to 80° only within 60 nm of home, where the orbits are.
    "per-cluster-approach-80": MappingProxyType({**DENSE_TRAFFIC_SETTINGS, "approach_angle_rad": math.radians(80.0)}),
})

#: The default margin inside the airspeed envelope that "homing" predicts with, kt.
HOMING_ENVELOPE_MARGIN_KT = 4.0

#: "homing"'s margin at an episode's first decision, kt: no drift has been seen yet, so
#: the prediction flies without any wind while the true one is N(0, σ²) per component.
HOMING_FIRST_DECISION_MARGIN_KT = 10.0

#: Costs are floored here (nm) so that a candidate that brings everyone home (cost 0)
#: still has a finite log-cost in the chain.
_COST_FLOOR_NM = 1e-9

#: Largest K: the candidates of one decision are worlds flown in one kernel call, so K of
#: them within ``atc_nf_env.config.BATCH_MEMORY_BYTES`` at one aircraft (about 2 million;
#: ``reset`` checks K against the scenario's own aircraft count).
MAX_EXTRACTIONS: int = max_batch_worlds(1)


@dataclass(frozen=True)
class MPCSettings:
    """Settings of the MCMC-MPC.

    The defaults are this project's controller, not the paper's: Table I's sampler with
    the paper's K = 1000, N = 4, T = 5 min and distance N(100 nm, 10 nm) (section IV-C),
    under the default ``proposal="homing"``, which adds to Table I

    - the chain's start Θ_0: every aircraft aimed at its destination,
      ``home_distance_nm`` (130 nm) out, turned at most ``recovery_angle_rad`` from its
      heading (Table I leaves the start free; "paper" starts from the first draw);
    - a mixture proposal: with probability ``recovery_fraction`` (0.25) an aircraft's
      angle is uniform within ± ``recovery_angle_rad`` (60°) of its heading instead of
      within ± ``angle_range_rad`` (90°) of the line to its destination;
    - a cost term: each aircraft's time flown in the horizon, as distance at 454 kt, is
      added to (6)'s remaining distances;
    - envelope margins: the prediction holds the airspeed 4 kt inside [366, 540] kt
      (``HOMING_ENVELOPE_MARGIN_KT``), 10 kt at an episode's first decision
      (``HOMING_FIRST_DECISION_MARGIN_KT``) ("paper": 0 kt);
    - wider rounds: up to ``search_rounds`` (2) more rounds of K candidates, each wider,
      before a fallback ("paper": none).

    ``proposal="paper"`` (CLI ``--proposal paper``) is Table I's proposal, chain start and
    cost (6) as printed. Under either proposal three defaults are not the paper's either:
    ``constraint_check="every-step"`` (the paper checks at the sampling instants t + pT:
    ``"sampling-instants"``), ``acceptance="standard"`` (Table I prints the proposal
    ratio the other way up: ``"table-i"``) and ``wind_model="estimated"`` (the paper
    does not say what wind its prediction assumes; ``"none"`` predicts still air, the
    forecast the paper sets to zero). ``MPCSettings(proposal="paper",
    constraint_check="sampling-instants", acceptance="table-i", wind_model="none")`` comes
    closest to Table I and section III as printed.

    Attributes:
        period_s: T, the sampling period, s.
        horizon: N, the number of periods in the prediction horizon.
        extractions: K, the number of proposals (and the chain's length) per decision.
        distance_mean_nm, distance_std_nm: the proposal's waypoint distance, nm.
        angle_range_rad: the proposal's angle is uniform in ±this around the line to
            the destination, rad.
        cost_exponent: J, the target is ∝ C^−J.
        acceptance: "standard" (independence sampler) or "table-i" (as printed).
        constraint_check: "every-step" or "sampling-instants".
        wind_model: "none", "sampled" or "estimated".
        wind_sigma_mps: σ of the "sampled" wind model, m/s.
        proposal: "homing" (default: the chain starts from every aircraft aimed home,
            and the proposal mixes in angles around the current heading) or "paper"
            (Table I exactly: independent draws, the chain starting from the first).
        recovery_fraction: "homing": probability that an aircraft's angle is drawn
            around its current heading instead of around the line to its destination.
        recovery_angle_rad: "homing": that angle is uniform in ±this around the heading,
            and the aimed-home initial state turns at most this far from the heading, rad.
        search_rounds: "homing": when no candidate is feasible, up to this many more
            rounds of K candidates, each wider than the last, before a fallback.
        home_distance_nm: "homing": the distance of the chain's initial state's
            waypoints, nm.
        envelope_margin_kt: the prediction holds the airspeed this far inside the
            envelope (at most a quarter of its width), against the error of the
            predicted wind, kt; None: 0 under "paper", ``HOMING_ENVELOPE_MARGIN_KT``
            under "homing".
        first_decision_margin_kt: the same at an episode's first decision, before any
            drift has been observed to estimate the wind from, kt; None: the
            ``envelope_margin_kt`` under "paper", ``HOMING_FIRST_DECISION_MARGIN_KT``
            under "homing".
        search: "lazy" (default) simulates a candidate only as far as the chain needs
            to decide on it, or "exhaustive" simulates every candidate over the whole
            horizon. Both pick the same candidate from the same draws; only
            "exhaustive" knows every decision's feasible fraction (see "Lazy search").
        sampling: "auto" (default: "joint" on the paper's encounters, of at most
            ``JOINT_SEARCH_MAX_AIRCRAFT`` aircraft, ``DENSE_TRAFFIC_SETTINGS`` on more
            aircraft and on traffic streams; ``for_traffic`` says exactly), "joint"
            (every candidate draws every flying aircraft's waypoint) or "clusters"
            ("homing" only; see "Dense traffic"): when the chain's start breaks a constraint, the candidates draw only the waypoints of
            the conflict cluster around the aircraft involved.
            "per-cluster" ("homing" and "every-step" only): each independent conflict
            cluster of the chain's start is searched by a chain of its own.
        cluster_radius_nm: "clusters": flying aircraft within this distance of an aircraft
            involved in a violation, where they are when it happens, join its cluster, nm.
        progress_fraction: the progress rule ("homing" only; None: off, the default): an
            aircraft that closes less than this share of a direct flight's progress at
            454 kt (or of its remaining distance, if less) over ``progress_periods``
            periods is held on its recovery waypoint until it stops flying.
        progress_periods: the progress rule's window, periods.
        approach_angle_rad: "homing": within ``shield.APPROACH_RADIUS_NM`` (60 nm) of its
            destination an aircraft turns up to this far from its heading (its share of
            the proposal around the heading, and the chain's start) instead of
            ``recovery_angle_rad``, rad, in (0, π/2); None (the default): no difference
            near home. See "Turning near home".
    """

    period_s: float = DECISION_PERIOD_S
    horizon: int = 4
    extractions: int = 1000
    distance_mean_nm: float = 100.0
    distance_std_nm: float = 10.0
    angle_range_rad: float = math.pi / 2
    cost_exponent: float = 1.0
    acceptance: str = "standard"
    constraint_check: str = "every-step"
    wind_model: str = "estimated"
    wind_sigma_mps: float = WIND_SIGMA_MPS
    proposal: str = "homing"
    recovery_fraction: float = 0.25
    recovery_angle_rad: float = math.pi / 3
    search_rounds: int = 2
    home_distance_nm: float = 130.0
    envelope_margin_kt: float | None = None
    first_decision_margin_kt: float | None = None
    search: str = "lazy"
    sampling: str = "auto"
    cluster_radius_nm: float = 30.0
    progress_fraction: float | None = None
    progress_periods: int = 3
    approach_angle_rad: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.extractions, bool) or not isinstance(self.extractions, (int, np.integer)) \
                or not 1 <= self.extractions <= MAX_EXTRACTIONS:
            raise ValueError(
                f"extractions (K) = {self.extractions!r}: must be an integer in [1, {MAX_EXTRACTIONS}] (K candidate "
                f"worlds of even one aircraft hold {world_memory_bytes(1)} bytes each; the bound keeps them within "
                f"{BATCH_MEMORY_BYTES / 2**30:g} GiB)"
            )
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, (int, np.integer)) or self.horizon < 1:
            raise ValueError(f"horizon (N) = {self.horizon!r}: must be an integer >= 1")
        for name in (
            "period_s", "distance_mean_nm", "distance_std_nm", "angle_range_rad", "cost_exponent", "home_distance_nm",
            "cluster_radius_nm",
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a finite number > 0")
        if self.horizon * self.period_s > MAX_TIME_LIMIT_S * (1 + 1e-12):
            raise ValueError(
                f"horizon (N) = {self.horizon} periods of {self.period_s:g} s: a prediction of "
                f"{self.horizon * self.period_s / 3600:g} h, longer than any flight ({MAX_TIME_LIMIT_S / 3600:g} h); "
                f"allowed: N <= {int(MAX_TIME_LIMIT_S // self.period_s)} at T = {self.period_s:g} s"
            )
        if not isinstance(self.search_rounds, (int, np.integer)) or self.search_rounds < 0:
            raise ValueError(f"search_rounds = {self.search_rounds!r}: must be an integer >= 0")
        if not (isinstance(self.recovery_fraction, (int, float)) and 0.0 <= self.recovery_fraction <= 1.0):
            raise ValueError(f"recovery_fraction = {self.recovery_fraction!r}: must be a number in [0, 1]")
        if not (isinstance(self.recovery_angle_rad, (int, float)) and 0.0 < self.recovery_angle_rad < math.pi / 2):
            raise ValueError(f"recovery_angle_rad = {self.recovery_angle_rad!r}: must be a number in (0, π/2)")
        if self.approach_angle_rad is not None and (
            isinstance(self.approach_angle_rad, bool)
            or not (isinstance(self.approach_angle_rad, (int, float)) and 0.0 < self.approach_angle_rad < math.pi / 2)
        ):
            raise ValueError(f"approach_angle_rad = {self.approach_angle_rad!r}: must be None or a number in (0, π/2)")
        if self.progress_fraction is not None and not (
            isinstance(self.progress_fraction, (int, float)) and 0.0 < self.progress_fraction <= 1.0
        ):
            raise ValueError(f"progress_fraction = {self.progress_fraction!r}: must be None or a number in (0, 1]")
        if (isinstance(self.progress_periods, bool) or not isinstance(self.progress_periods, (int, np.integer))
                or not 1 <= self.progress_periods <= 100):
            raise ValueError(f"progress_periods = {self.progress_periods!r}: must be an integer in [1, 100]")
        for name in ("envelope_margin_kt", "first_decision_margin_kt"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and 0.0 <= value < 50.0):
                raise ValueError(f"{name} = {value!r}: must be None or a number in [0, 50)")
        if not (math.isfinite(self.wind_sigma_mps) and self.wind_sigma_mps >= 0):
            raise ValueError(f"wind_sigma_mps = {self.wind_sigma_mps!r}: must be a finite number >= 0")
        for name, allowed in (
            ("acceptance", ACCEPTANCES),
            ("constraint_check", CONSTRAINT_CHECKS),
            ("wind_model", WIND_MODELS),
            ("proposal", PROPOSALS),
            ("search", SEARCHES),
            ("sampling", SAMPLINGS),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} = {getattr(self, name)!r}: allowed: {', '.join(allowed)}")
        if self.proposal == "paper" and (self.sampling not in ("auto", "joint") or self.progress_fraction is not None):
            raise ValueError(
                f"sampling = {self.sampling!r}, progress_fraction = {self.progress_fraction!r}: the conflict "
                "clusters and the progress rule need proposal='homing' (proposal='paper' is Table I as printed)"
            )
        if self.sampling == "per-cluster" and self.constraint_check != "every-step":
            raise ValueError(
                f"sampling = 'per-cluster' with constraint_check = {self.constraint_check!r}: the clusters are "
                "found at integration-step resolution, so the chains must check every step ('every-step')"
            )

    def for_traffic(self, scenario: Scenario) -> MPCSettings:
        """These settings with ``sampling="auto"`` resolved for ``scenario``: the joint
        search on an encounter of at most ``JOINT_SEARCH_MAX_AIRCRAFT`` aircraft, under
        ``proposal="paper"`` (Table I as printed) and under
        ``constraint_check="sampling-instants"`` (the clusters need every step);
        ``DENSE_TRAFFIC_SETTINGS`` otherwise (more aircraft, or a traffic stream), with
        the progress rule given, if one is. Any other ``sampling`` is returned as is."""
        if self.sampling != "auto":
            return self
        stream = isinstance(scenario, StreamScenario)
        if (self.proposal == "paper" or self.constraint_check != "every-step"
                or (not stream and scenario.n_aircraft <= JOINT_SEARCH_MAX_AIRCRAFT)):
            return dataclasses.replace(self, sampling="joint")
        if self.progress_fraction is None:
            return dataclasses.replace(self, **DENSE_TRAFFIC_SETTINGS)
        return dataclasses.replace(self, sampling=DENSE_TRAFFIC_SETTINGS["sampling"])


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to [−π, π), rad."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class DecisionRecord:
    """What one decision saw: the feasible fraction of the K candidates (None where the
    lazy search did not fly every candidate to the end), and whether the fallback was
    taken."""

    time_s: float
    feasible_fraction: float | None
    fallback: bool
    cost_nm: float
    chain_acceptance: float
    rounds: int = 1
    applied_breach_predicted: bool = False
    #: Aircraft sampled by a conflict cluster's rounds (``sampling="clusters"``), 0 when the
    #: decision sampled every aircraft jointly.
    cluster_size: int = 0
    #: Aircraft the progress rule held on their recovery waypoint at this decision.
    recovering: int = 0
    #: ``sampling="per-cluster"``: the independent conflict clusters the chain's start
    #: showed, each searched by a chain of its own (0: the start was feasible).
    clusters: int = 0


@dataclass
class _SearchResult:
    """What one search (``MCMCMPC._search``) chose: the waypoints (N, 2) nm and the
    positions after one period (N, 2) nm of the applied candidate, and how it got there."""

    applied: np.ndarray
    applied_after_first: np.ndarray
    fallback: bool
    cost_nm: float
    accepted: int
    rounds: int
    breach_predicted: bool
    first_fraction: float | None
    cluster_size: int


@njit(cache=True)
def log_acceptance(log_cost_from: float, log_cost_to: float, log_g_from: float, log_g_to: float,
                   cost_exponent: float, sign: float) -> float:
    """log ρ of the chain's move from one feasible state to another: the target ∝ C^−J
    and the independence sampler's proposal ratio, J (log C_from − log C_to) +
    sign · (log g_from − log g_to), with ``sign`` 1 for the standard acceptance and −1
    for Table I's as printed. The one place of the formula: the exhaustive chain
    (``metropolis_hastings_best``) and the lazy one (``_chain_until_undecided``, where a
    cost's lower bound gives the largest ρ a candidate can reach) call it. IEEE
    arithmetic, no fast-math, so Python and compiled callers take the same verdicts."""
    return cost_exponent * (log_cost_from - log_cost_to) + sign * (log_g_from - log_g_to)


@njit(cache=True)
def accepts(log_rho: float, log_u: float) -> bool:
    """Metropolis-Hastings' verdict: move when ρ ≥ 1, or when log u < log ρ for the
    move's uniform draw u."""
    return log_rho >= 0.0 or log_u < log_rho


def metropolis_hastings_best(
    costs: np.ndarray,
    log_proposal: np.ndarray,
    uniforms: np.ndarray,
    cost_exponent: float = 1.0,
    acceptance: str = "standard",
) -> tuple[int, int, np.ndarray]:
    """Run the independence-sampler chain over candidates in order.

    Args:
        costs: (K,) costs C_k (np.inf for infeasible).
        log_proposal: (K,) log g(Θ_k) up to a constant.
        uniforms: (K,) uniform draws in [0, 1) deciding the acceptances (index 0 unused).
        cost_exponent: J of the target ∝ C^−J.
        acceptance: "standard" or "table-i" (the proposal ratio as printed in Table I).

    Returns:
        (index of the lowest-cost state the chain visited, number of accepted moves,
        the chain's states (K,) as candidate indices).
    """
    n = costs.shape[0]
    states = np.empty(n, dtype=np.int64)
    current = 0
    states[0] = 0
    best = 0
    accepted = 0
    sign = 1.0 if acceptance == "standard" else -1.0
    log_cost = np.log(np.maximum(costs, _COST_FLOOR_NM))
    for k in range(1, n):
        if np.isinf(costs[k]):
            move = np.isinf(costs[current])  # between two infeasible states: no preference
        elif np.isinf(costs[current]):
            move = True
        else:
            log_rho = log_acceptance(log_cost[current], log_cost[k], log_proposal[current], log_proposal[k],
                                     cost_exponent, sign)
            move = accepts(log_rho, math.log(max(uniforms[k], 1e-300)))
        if move:
            current = k
            accepted += 1
            if costs[current] < costs[best] or np.isinf(costs[best]):
                best = current
        states[k] = current
    return best, accepted, states


class MCMCMPC:
    """The paper's MCMC-MPC as a policy of the ``atc_nf_env.policy.Policy`` interface.

    Args:
        settings: ``MPCSettings`` (the paper's by default); keyword arguments override
            single fields, e.g. ``MCMCMPC(extractions=200, wind_model="estimated")``.
    """

    name = "mpc"

    def __init__(self, settings: MPCSettings | None = None, **overrides: Any) -> None:
        base = settings or MPCSettings()
        if overrides:
            allowed = list(MPCSettings.__dataclass_fields__)
            unknown = sorted(set(overrides) - set(allowed))
            if unknown:
                # Python's own wording for an unknown keyword argument (a TypeError; a bad
                # value of a known setting is a ValueError).
                more = f" (and {unknown[1:]})" if len(unknown) > 1 else ""
                raise TypeError(
                    f"{type(self).__name__}: got an unexpected keyword argument {unknown[0]!r}{more}; "
                    f"allowed: {allowed}"
                )
            base = MPCSettings(**{**base.__dict__, **overrides})
        #: The settings as given (``sampling`` may be "auto").
        self.requested_settings = base
        #: The settings flown: ``requested_settings.for_traffic`` of the scenario of the
        #: last ``reset`` (the requested ones before any).
        self.settings = base
        self.decisions: list[DecisionRecord] = []
        self._rng = np.random.default_rng(0)
        self._scratch = kernel.KernelScratch()
        # The chain's start is flown alone (``sampling="clusters"``): its own buffers, so that
        # the candidates' batch shape keeps its own.
        self._start_scratch = kernel.KernelScratch()
        self._stalled = np.zeros(0, dtype=bool)
        self._ever_stalled = np.zeros(0, dtype=bool)
        self._progress_history: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._params: np.ndarray | None = None
        self._survey_params: np.ndarray | None = None
        self._check_params: np.ndarray | None = None
        self._wind_estimate_kt = np.zeros(2)
        self._predicted_positions: np.ndarray | None = None
        self._predicted_time_s = -1.0
        #: Candidate-periods flown by the search (K · N per round for the exhaustive one).
        self.search_world_periods = 0

    @property
    def envelope_margin_kt(self) -> float:
        """The margin inside the airspeed envelope that the prediction holds, kt."""
        s = self.settings
        if s.envelope_margin_kt is not None:
            return float(s.envelope_margin_kt)
        return 0.0 if s.proposal == "paper" else HOMING_ENVELOPE_MARGIN_KT

    @property
    def first_decision_margin_kt(self) -> float:
        """The margin inside the airspeed envelope at an episode's first decision, kt."""
        s = self.settings
        if s.first_decision_margin_kt is not None:
            return float(s.first_decision_margin_kt)
        return self.envelope_margin_kt if s.proposal == "paper" else HOMING_FIRST_DECISION_MARGIN_KT

    # -- Policy interface -------------------------------------------------------------
    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Seed the controller and prepare its prediction model for ``scenario`` (and pick
        its search for the traffic: ``MPCSettings.for_traffic``)."""
        self.settings = self.requested_settings.for_traffic(scenario)
        if config.dt_s <= 0 or kernel.steps_for(self.settings.period_s, config.dt_s) < 1:
            raise ValueError(f"period_s = {self.settings.period_s}: must be >= one integration step")
        check_batch_size(self.settings.extractions, scenario.n_aircraft, "MPC extractions (K)")
        self._rng = np.random.default_rng([0 if seed is None else seed, 0x4D5043])
        if self.settings.search == "lazy":
            _load_compiled_chain()  # numba's compilation (or cache load) outside act's time
        stop = self.settings.constraint_check == "every-step"
        # The prediction's envelope: narrower by the margin; the real flight's is config's.
        # (config, params, survey params) at the first decision, then at every later one.
        # sampling="per-cluster" flies the chain's start through the whole horizon, past its
        # violations, to see every conflict: the survey is the same prediction without the stop.
        self._prediction_models = []
        for margin in (self.first_decision_margin_kt, self.envelope_margin_kt):
            # A margin never takes more than a quarter of the envelope's width.
            margin = min(margin, 0.25 * (config.airspeed_max_kt - config.airspeed_min_kt))
            narrowed = dataclasses.replace(
                config, airspeed_min_kt=config.airspeed_min_kt + margin, airspeed_max_kt=config.airspeed_max_kt - margin
            )
            params = narrowed.to_params(scenario.workspace_radius_nm, stop_on_violation=stop)
            survey = params.copy()
            survey[nf.P_STOP_ON_VIOLATION] = 0.0
            self._prediction_models.append((narrowed, params, survey))
        self._use_prediction_model(0)
        # Every kernel path the candidates' batches can take, compiled (or loaded) now: a
        # first compilation inside a decision would be timed as the decision.
        kernel.load_paths(initial_state(scenario)[0], self._params)
        self._wind_estimate_given = False
        self._workspace_radius_nm = scenario.workspace_radius_nm
        self.decisions = []
        self.search_world_periods = 0
        self._wind_estimate_kt = np.zeros(2)
        self._predicted_positions = None
        self._predicted_time_s = -1.0
        self._predicted_flying = np.zeros(0, dtype=bool)
        self._stalled = np.zeros(scenario.n_aircraft, dtype=bool)
        self._ever_stalled = np.zeros(scenario.n_aircraft, dtype=bool)
        self._progress_history = []
        self._arrival_nm = float(self._params[nf.P_DELTA])

    def _use_prediction_model(self, index: int) -> None:
        """Predict with the first decision's model (``index`` 0) or every later one's (1)."""
        self._config, self._params, self._survey_params = self._prediction_models[index]

    def act(self, view: WorldView) -> np.ndarray:
        """The waypoints (N, 2), nm, of the lowest-cost candidate in the chain."""
        if self._params is None:
            raise RuntimeError("call reset(scenario, config, seed) before act()")
        s = self.settings
        # The first decision's wider margin until drift has been seen or an estimate given.
        first = not self.decisions and not self._wind_estimate_given
        self._use_prediction_model(0 if first else 1)
        self._update_wind_estimate(view)
        flying = view.flying
        self._update_progress(view)
        recovering = self._stalled & flying
        n_clusters = 0
        if s.sampling == "per-cluster":
            result, n_clusters = self._search_per_cluster(view, recovering)
        else:
            # Which aircraft each round samples: all of them (joint), or, under "clusters" when
            # the chain's start breaks a constraint, the conflict cluster around those involved.
            cluster = self._start_cluster(view, recovering) if s.sampling == "clusters" else None
            result = self._search(view, recovering, cluster)
        self.decisions.append(
            DecisionRecord(
                time_s=view.time_s,
                feasible_fraction=result.first_fraction,
                fallback=result.fallback,
                cost_nm=result.cost_nm,
                chain_acceptance=result.accepted / max(s.extractions - 1, 1),
                rounds=result.rounds,
                applied_breach_predicted=result.breach_predicted,
                cluster_size=result.cluster_size,
                recovering=int(recovering.sum()),
                clusters=n_clusters,
            )
        )
        waypoints = view.waypoints.copy()
        waypoints[flying] = result.applied[flying]
        predicted = result.applied_after_first
        if result.breach_predicted and s.wind_model == "estimated" and s.constraint_check == "every-step":
            # That prediction stopped at its breach; the aircraft fly the whole period.
            predicted = self._whole_first_period(view, result.applied)
        self._predicted_positions = predicted.copy()
        self._predicted_flying = flying.copy()
        self._predicted_time_s = view.time_s + s.period_s
        return waypoints

    def _search(
        self, view: WorldView, recovering: np.ndarray, cluster: np.ndarray | None, start: np.ndarray | None = None
    ) -> _SearchResult:
        """One decision's rounds of the chain over the aircraft flying in ``view``: every one
        of them (``cluster`` None) or the cluster's, the others keeping the chain's start
        (Θ_0, or ``start`` (N, 2) nm); the applied candidate, or the fallback."""
        s = self.settings
        flying = view.flying
        rounds = 1 + (s.search_rounds if s.proposal == "homing" else 0)
        tried: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        first_fraction: float | None = None
        chain: tuple[int, int] | None = None
        repairs = 0
        round_index = 0
        attempts = 0
        while round_index < rounds:
            sampled = flying if cluster is None else cluster
            if round_index == 0:
                sampled = sampled & ~recovering  # held on their recovery waypoints (progress rule)
            proposals, log_g = self._propose(view, round_index, flying & ~sampled, start)
            if s.search == "exhaustive":
                costs, survived, after_first = self._simulate(view.state, proposals)
                self.search_world_periods += s.extractions * s.horizon
                feasible = np.isfinite(costs)
                any_feasible = bool(feasible.any())
            else:
                candidates = _LazyCandidates(self, view.state, proposals, self._prediction_wind())
                # The chain's uniforms are the generator's next draws if this round has a
                # feasible candidate (no further round is drawn then): read them ahead.
                ahead = np.random.Generator(type(self._rng.bit_generator)())
                ahead.bit_generator.state = self._rng.bit_generator.state
                best, accepted, any_feasible = _lazy_chain(
                    candidates, log_g, ahead.random(s.extractions), s.cost_exponent, s.acceptance
                )
                chain = (best, accepted)
                self.search_world_periods += candidates.world_periods
                costs, survived, after_first = candidates.costs, candidates.survived, candidates.after_first
                feasible = candidates.done & np.isfinite(costs)
            if attempts == 0 and (s.search == "exhaustive" or candidates.done.all()):
                first_fraction = float(feasible.mean())
            tried.append((proposals, survived, after_first))
            attempts += 1
            if any_feasible:
                break
            if cluster is not None:
                longest = int(np.argmax(survived))
                if survived[longest] > survived[0] and repairs < CLUSTER_REPAIRS:
                    # A candidate put the first violation off: it becomes the start, and the
                    # next round samples the cluster of its own first violation.
                    repaired = self._violation_cluster(view, proposals[longest])
                    if repaired.any():
                        start, cluster = proposals[longest].copy(), repaired
                        repairs += 1
                        continue
                if not cluster[flying].all():
                    # Nothing put it off: the violations of the longest survivor (other
                    # aircraft) grow the cluster before the search widens.
                    grown = cluster | self._violation_cluster(view, proposals[longest])
                    if (grown & ~cluster).any():
                        cluster = grown
                        continue
            round_index += 1
        uniforms = self._rng.random(s.extractions)
        if any_feasible:
            if chain is None:
                best, accepted, _ = metropolis_hastings_best(costs, log_g, uniforms, s.cost_exponent, s.acceptance)
            else:
                best, accepted = chain
            return _SearchResult(
                applied=proposals[best], applied_after_first=after_first[best], fallback=False,
                cost_nm=float(costs[best]), accepted=accepted, rounds=len(tried), breach_predicted=False,
                first_fraction=first_fraction, cluster_size=0 if cluster is None else int(cluster.sum()),
            )
        # Every round failed: fly the candidate (of any round) that stayed feasible
        # longest, ties broken by how far its waypoints leave the aircraft from home.
        proposals = np.concatenate([t[0] for t in tried])
        survived = np.concatenate([t[1] for t in tried])
        after_first = np.concatenate([t[2] for t in tried])
        distance = self._remaining_distance_of(proposals, view)
        best = int(np.lexsort((distance, -survived))[0])
        breach_predicted = bool(survived[best] < self._units_per_period())
        return _SearchResult(
            applied=proposals[best], applied_after_first=after_first[best], fallback=True, cost_nm=math.inf,
            accepted=0, rounds=len(tried), breach_predicted=breach_predicted, first_fraction=first_fraction,
            cluster_size=0 if cluster is None else int(cluster.sum()),
        )

    def set_wind_estimate(self, wind_kt: np.ndarray) -> None:
        """Replace the "estimated" wind model's estimate (east, north), kt, e.g. by that of a
        safety filter that calls this controller only now and then, too rarely to keep its own;
        the next decision starts from it uncorrected."""
        wind = np.asarray(wind_kt, dtype=np.float64)
        if wind.shape != (2,) or not np.isfinite(wind).all():
            raise ValueError(f"wind_kt = {wind_kt!r}: must be two finite numbers (east, north) in kt")
        self._wind_estimate_kt = wind.copy()
        self._wind_estimate_given = True
        self._predicted_positions = None

    def episode_info(self) -> dict[str, Any]:
        """Diagnostics of the episode so far (for reports and the evaluator)."""
        fractions = [d.feasible_fraction for d in self.decisions if d.feasible_fraction is not None]
        return {
            "decisions": len(self.decisions),
            "fallbacks": int(sum(d.fallback for d in self.decisions)),
            "fallbacks_breach_predicted": int(sum(d.applied_breach_predicted for d in self.decisions)),
            "wider_searches": int(sum(d.rounds > 1 for d in self.decisions)),
            "rescued_by_wider_search": int(sum(d.rounds > 1 and not d.fallback for d in self.decisions)),
            # Decisions whose chain accepted no move: they apply the chain's start (under
            # "homing" every aircraft aimed home, under "paper" the first draw).
            "start_kept": int(sum(not d.fallback and d.chain_acceptance == 0.0 for d in self.decisions)),
            "feasible_fraction": {
                "min": float(min(fractions)) if fractions else None,
                "mean": float(np.mean(fractions)) if fractions else None,
                "decisions": len(fractions),
            },
            "chain_acceptance_mean": float(np.mean([d.chain_acceptance for d in self.decisions]))
            if self.decisions
            else None,
            "wind_estimate_kt": [float(w) for w in self._wind_estimate_kt],
            # sampling="clusters": decisions whose chain sampled a conflict cluster, its mean size.
            "cluster_decisions": int(sum(d.cluster_size > 0 for d in self.decisions)),
            "cluster_size_mean": float(np.mean([d.cluster_size for d in self.decisions if d.cluster_size > 0]))
            if any(d.cluster_size > 0 for d in self.decisions) else None,
            # The progress rule: aircraft it ever held on a recovery waypoint, and the decisions it did.
            "stalled_aircraft": int(self._ever_stalled.sum()),
            "recovery_decisions": int(sum(d.recovering > 0 for d in self.decisions)),
        }

    # -- internals ----------------------------------------------------------------------
    def _units_per_period(self) -> int:
        """What ``survived`` counts in one period: integration steps, or one sampling instant."""
        if self.settings.constraint_check == "every-step":
            return kernel.steps_for(self.settings.period_s, self._config.dt_s)
        return 1

    def _propose(
        self, view: WorldView, round_index: int = 0, held: np.ndarray | None = None, start: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """K joint proposals (K, N, 2) nm and their log-densities log g (K,) up to a constant.

        ``round_index`` > 0 (proposal "homing" only): a wider search after a round in
        which no candidate was feasible. ``held`` (N,) bool ("homing" only): aircraft that
        keep the chain's start's waypoint in every candidate (outside the sampled cluster,
        or held by the progress rule); they add nothing to log g. ``start`` (N, 2) nm
        ("homing" only): the chain's start (candidate 0) instead of Θ_0.
        """
        s = self.settings
        n = view.state.shape[0]
        to_dest = view.destinations - view.positions
        bearing = np.arctan2(to_dest[:, 1], to_dest[:, 0])
        flying = view.flying
        if s.proposal == "paper":
            distance = self._rng.normal(s.distance_mean_nm, s.distance_std_nm, (s.extractions, n))
            angle = self._rng.uniform(-s.angle_range_rad, s.angle_range_rad, (s.extractions, n))
            direction = bearing[None, :] + angle
            z = (distance - s.distance_mean_nm) / s.distance_std_nm
            log_g = -0.5 * (z[:, flying] ** 2).sum(axis=1)
        else:
            direction, distance, log_g = self._homing_draws(view, bearing, round_index, held, start)
        proposals = view.positions[None] + distance[..., None] * np.stack(
            [np.cos(direction), np.sin(direction)], axis=-1
        )
        # A waypoint must stay inside the workspace: pull it toward the centre if needed.
        return inside_workspace(proposals, 0.99 * (self._workspace_radius_nm - self._config.aircraft_radius_nm)), log_g

    def _homing_draws(
        self, view: WorldView, bearing: np.ndarray, round_index: int, held: np.ndarray | None = None,
        start: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions (K, N) rad, distances (K, N) nm and log g (K,) of the "homing" proposal.

        Per aircraft, a mixture (``homing_mixture_draws``): with probability 1 − f the
        paper's angle (uniform in ±angle_range around the line to the destination), with
        probability f an angle uniform in ±recovery_angle around the current heading; the
        distance is normal around the paper's mean. Candidate 0, the chain's initial state, is every
        aircraft aimed home at the mean distance (turned at most recovery_angle from its
        heading). Each wider round halves the paper's share 1 − f and adds the paper's σ to
        the distance's.
        """
        s = self.settings
        heading = view.headings
        # Round r leaves the paper's angles a share (1 − f) / 2^r.
        f = 1.0 - (1.0 - s.recovery_fraction) / 2**round_index
        sigma = s.distance_std_nm * (1 + round_index)
        turn = self._turn_limits(view)
        direction, distance = homing_mixture_draws(self._rng, s, heading, bearing, s.extractions, f, sigma, turn)
        home = self._start_directions(view, bearing, f)
        home_distance = np.full(home.shape, s.home_distance_nm)
        if start is not None:
            offset = start - view.positions
            home, home_distance = np.arctan2(offset[:, 1], offset[:, 0]), np.hypot(offset[:, 0], offset[:, 1])
        direction[0] = home
        distance[0] = home_distance
        if held is not None and held.any():
            direction[:, held] = home[held]
            distance[:, held] = home_distance[held]
        z = (distance - s.distance_mean_nm) / sigma
        from_bearing = np.abs(_wrap(direction - bearing[None, :])) <= s.angle_range_rad + 1e-12
        from_heading = np.abs(_wrap(direction - heading[None, :])) <= turn[None, :] + 1e-12
        density = (1.0 - f) * from_bearing / (2.0 * s.angle_range_rad) + f * from_heading / (2.0 * turn[None, :])
        log_angle = np.log(np.maximum(density, 1e-300))
        drawn = view.flying if held is None else view.flying & ~held
        log_g = (-0.5 * z**2 + log_angle)[:, drawn].sum(axis=1)
        return direction, distance, log_g

    def _start_directions(self, view: WorldView, bearing: np.ndarray, heading_share: float) -> np.ndarray:
        """The directions (N,) rad of the chain's initial state's waypoints: aimed home, or as
        near home as a turn of ``recovery_angle_rad`` allows (a waypoint far behind the
        heading would command a reverse airspeed). An aircraft held by the progress rule
        within ``APPROACH_RADIUS_NM`` of home and more than ``APPROACH_TURN_RAD`` off its
        bearing flies straight on instead, as the safety filter's handed-over aircraft do
        (``SafetyFilter._handover_waypoints`` says why: turned home from there it circles)."""
        s = self.settings
        heading = view.headings
        if heading_share == 0.0:
            return bearing.copy()  # outside the paper's support otherwise
        error = _wrap(bearing - heading)
        turn = self._turn_limits(view)
        home = heading + np.clip(error, -turn, turn)
        if self._stalled.any():
            to_dest = view.destinations - view.positions
            straight = (self._stalled & view.flying & (np.hypot(to_dest[:, 0], to_dest[:, 1]) < APPROACH_RADIUS_NM)
                        & (np.abs(error) > APPROACH_TURN_RAD))
            home = np.where(straight, heading, home)
        return home

    def _turn_limits(self, view: WorldView) -> np.ndarray:
        """(N,) rad: how far each aircraft's heading share of the proposal and its start
        direction may turn from its heading: ``approach_angle_rad`` within
        ``APPROACH_RADIUS_NM`` of its destination, ``recovery_angle_rad`` elsewhere."""
        s = self.settings
        turn = np.full(len(view.headings), s.recovery_angle_rad)
        if s.approach_angle_rad is not None:
            to_dest = view.destinations - view.positions
            turn[np.hypot(to_dest[:, 0], to_dest[:, 1]) < APPROACH_RADIUS_NM] = s.approach_angle_rad
        return turn

    def _start_waypoints(self, view: WorldView) -> np.ndarray:
        """The chain's initial state Θ_0 (N, 2) nm, as ``_propose`` makes its candidate 0."""
        s = self.settings
        to_dest = view.destinations - view.positions
        bearing = np.arctan2(to_dest[:, 1], to_dest[:, 0])
        home = self._start_directions(view, bearing, s.recovery_fraction)
        start = view.positions + s.home_distance_nm * np.stack([np.cos(home), np.sin(home)], axis=-1)
        return inside_workspace(start[None], 0.99 * (self._workspace_radius_nm - self._config.aircraft_radius_nm))[0]

    def _violation_cluster(self, view: WorldView, waypoints: np.ndarray) -> np.ndarray:
        """(N,) bool: the flying aircraft within ``cluster_radius_nm`` of an aircraft involved
        in the first violation (the envelope, or a loss of separation) of ``waypoints`` (N, 2)
        nm flown alone over the horizon under the prediction, where they were when it
        stopped; none when it stays feasible."""
        return self._fly_alone(view, waypoints)[0]

    def _cluster_around(self, view: WorldView, state: np.ndarray, trace: kernel.Trace) -> np.ndarray:
        """(N,) bool: the aircraft of one world (N, N_STATE) stopped at its first violation
        that broke a constraint in the period ``trace`` records, and every aircraft flying in
        ``view`` within ``cluster_radius_nm`` of one of them, where they are."""
        involved = self._involved(state, trace)
        where = state[:, S_X : S_Y + 1]
        gap = np.hypot(*(where[:, None, :] - where[None, involved, :]).transpose(2, 0, 1))
        near = (gap <= self.settings.cluster_radius_nm).any(axis=1) if involved.any() else np.zeros(len(state), bool)
        return view.flying & (near | involved)

    def _search_per_cluster(self, view: WorldView, recovering: np.ndarray) -> tuple[_SearchResult, int]:
        """``sampling="per-cluster"``: the chain's start Θ_0 flown through the horizon; each
        independent conflict cluster it shows searched by a chain of its own, in a world
        without the other clusters' aircraft; the clusters' choices, put together, flown
        jointly. Where they do not hold together, the "clusters" search from them. Returns
        the applied search result and the number of independent clusters."""
        start = self._start_waypoints(view)
        clusters = self._conflict_clusters(view, start)
        if not clusters:
            return self._search(view, recovering, None), 0
        if len(clusters) == 1:
            return self._search(view, recovering, clusters[0]), 1
        in_some = np.logical_or.reduce(clusters)
        composed = start.copy()
        rounds = 0
        for cluster in clusters:
            state = view.state.copy()
            state[in_some & ~cluster, S_STATUS] = ABSENT
            alone = WorldView(time_s=view.time_s, state=state, scenario=view.scenario)
            result = self._search(alone, recovering, cluster)
            composed[cluster] = result.applied[cluster]
            rounds += result.rounds
        violating, after_first, cost_nm = self._fly_alone(view, composed)
        if not violating.any():
            return _SearchResult(
                applied=composed, applied_after_first=after_first, fallback=False, cost_nm=cost_nm, accepted=0,
                rounds=rounds, breach_predicted=False, first_fraction=None, cluster_size=int(in_some.sum()),
            ), len(clusters)
        # The clusters' choices meet (a changed path reached another cluster): the joint
        # prediction's search, from them, over the cluster of their first violation.
        result = self._search(view, recovering, violating, start=composed)
        return dataclasses.replace(result, rounds=rounds + result.rounds), len(clusters)

    def _conflict_clusters(self, view: WorldView, waypoints: np.ndarray) -> list[np.ndarray]:
        """The independent conflict clusters (N,) bool of ``waypoints`` (N, 2) nm flown alone
        under the prediction through the whole horizon, past any violation, in the order of
        their first violation. An aircraft that breaks a constraint at an integration step
        (out of the prediction's envelope, or in a loss of separation) is linked to every
        flying aircraft within ``cluster_radius_nm`` of it at that step, and to the other
        aircraft of its loss of separation; a cluster is a connected set of links."""
        s = self.settings
        assert self._survey_params is not None and self._config is not None
        survey_params = self._survey_params
        states, flown_waypoints = _candidate_starts(view.state, waypoints[None])
        wind = self._prediction_wind_of_one()
        n = view.state.shape[0]
        link = np.zeros((n, n), dtype=bool)
        first_violation = np.full(n, np.inf)
        lowest, highest = self._config.airspeed_min_kt, self._config.airspeed_max_kt
        steps = 0
        for _ in range(s.horizon):
            before = states[:, :, S_X : S_Y + 1].copy()
            trace = _advance_candidates(
                states, flown_waypoints, wind, s.period_s, survey_params, self._start_scratch, record_every=1
            )
            record = trace.record[0]
            flew = record[:, :, kernel.R_FLEW] > 0
            where = record[:, :, kernel.R_X : kernel.R_Y + 1]
            gap = np.sqrt(((where[:, :, None, :] - where[:, None, :, :]) ** 2).sum(-1))
            both = flew[:, :, None] & flew[:, None, :]
            both[:, np.arange(n), np.arange(n)] = False
            outside = flew & ((record[:, :, kernel.R_AIRSPEED_MIN] < lowest) | (
                record[:, :, kernel.R_AIRSPEED_MAX] > highest))
            los = trace.los_pairs[0] > 0
            bad = outside | ((gap < self._config.separation_min_nm) & both).any(axis=2)
            link |= (bad[:, :, None] & (gap <= s.cluster_radius_nm) & both).any(axis=0) | los
            involved = bad.any(axis=0) | los.any(axis=0) | los.any(axis=1)
            if involved.any():
                at = np.where(bad.any(axis=0), steps + np.argmax(bad, axis=0), steps + record.shape[0])
                first_violation = np.where(involved, np.minimum(first_violation, at), first_violation)
            steps += record.shape[0]
            flown_waypoints = flown_waypoints + (states[:, :, S_X : S_Y + 1] - before)
        link |= link.T
        seeds = np.isfinite(first_violation) & view.flying
        clusters: list[np.ndarray] = []
        unclaimed = seeds.copy()
        while unclaimed.any():
            cluster = np.zeros(n, dtype=bool)
            cluster[int(np.argmax(unclaimed))] = True
            while True:
                grown = cluster | link[cluster].any(axis=0)
                if (grown == cluster).all():
                    break
                cluster = grown
            cluster &= view.flying
            clusters.append(cluster)
            unclaimed &= ~cluster
        clusters.sort(key=lambda c: (float(first_violation[c].min()), int(np.argmax(c))))
        return clusters

    def _fly_alone(self, view: WorldView, waypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``waypoints`` (N, 2) nm flown alone under the prediction, as a candidate is: the
        cluster of its first violation (none when it stays feasible, see
        ``_violation_cluster``), the positions after one period (N, 2) nm and its cost, nm
        (inf when infeasible)."""
        s = self.settings
        assert self._params is not None
        states, flown_waypoints = _candidate_starts(view.state, waypoints[None])
        wind = self._prediction_wind_of_one()
        after_first: np.ndarray | None = None
        for _ in range(s.horizon):
            before = states[:, :, S_X : S_Y + 1].copy()
            trace = _advance_candidates(states, flown_waypoints, wind, s.period_s, self._params, self._start_scratch)
            newly_bad, _ = self._period_verdict(states, trace, np.ones(1, dtype=bool))
            if after_first is None:
                after_first = states[0, :, S_X : S_Y + 1].copy()
            if newly_bad[0]:
                return self._cluster_around(view, states[0], trace), after_first, math.inf
            flown_waypoints = flown_waypoints + (states[:, :, S_X : S_Y + 1] - before)
        assert after_first is not None
        return np.zeros(view.state.shape[0], dtype=bool), after_first, float(self._cost(view.state, states)[0])

    def _whole_first_period(self, view: WorldView, waypoints: np.ndarray) -> np.ndarray:
        """The positions (N, 2) nm after one whole period of ``waypoints`` (N, 2) nm flown
        from ``view`` under the prediction (its wind, its envelope) without stopping at a
        violation: what the "estimated" wind model compares the aircraft's positions with.

        Why re-fly: a candidate's prediction stops at its first violation
        (``constraint_check="every-step"``), so a fallback that breaks a constraint in its
        first period has no prediction of where the period ends, and the rest of the
        period would be read as drift (two aircraft side by side 6 nm apart: a 545-kt
        estimate of a 21-kt wind). Skipping the update instead would keep the old
        estimate (at an episode's start, still air) for another period, in the conflict
        that made every candidate fail. The real aircraft fly the applied waypoints for the
        whole period, so one more world-period of the kernel gives the prediction to
        compare with."""
        assert self._survey_params is not None
        states, flown_waypoints = _candidate_starts(view.state, waypoints[None])
        _advance_candidates(states, flown_waypoints, self._prediction_wind_of_one(), self.settings.period_s,
                            self._survey_params, self._start_scratch)
        return states[0, :, S_X : S_Y + 1].copy()

    def _involved(self, state: np.ndarray, trace: kernel.Trace) -> np.ndarray:
        """(N,) bool: the aircraft of one world (N, N_STATE) that broke a constraint in the
        period ``trace`` (of that world alone) records."""
        config = self._config
        assert config is not None
        if self.settings.constraint_check == "every-step":
            # Only aircraft that flew: an empty stream slot keeps airspeed 0 and its parked
            # position would pull the aircraft around it into the cluster.
            outside = (trace.steps_flown[0] > 0) & ((trace.min_airspeed_kt[0] < config.airspeed_min_kt) | (
                trace.max_airspeed_kt[0] > config.airspeed_max_kt))
            pairs = trace.los_pairs[0] > 0
        else:
            flying = state[:, S_STATUS] == FLYING
            airspeed = state[:, S_AIRSPEED]
            outside = flying & ((airspeed < config.airspeed_min_kt) | (airspeed > config.airspeed_max_kt))
            where = state[:, S_X : S_Y + 1]
            gap2 = ((where[:, None, :] - where[None, :, :]) ** 2).sum(-1)
            pairs = (gap2 < config.separation_min_nm**2) & flying[:, None] & flying[None, :]
            np.fill_diagonal(pairs, False)
        return outside | pairs.any(axis=0) | pairs.any(axis=1)

    def _start_cluster(self, view: WorldView, recovering: np.ndarray) -> np.ndarray | None:
        """``sampling="clusters"``: None (sample every aircraft, as "joint") when the chain's
        start is feasible; otherwise the conflict cluster of its first violation."""
        cluster = self._violation_cluster(view, self._start_waypoints(view))
        return cluster if cluster.any() else None

    def _prediction_wind_of_one(self) -> np.ndarray:
        """The wind (1, 2) kt of a lone prediction: the estimate under "estimated", still air
        otherwise (a "sampled" wind would draw from the candidates' random stream)."""
        if self.settings.wind_model == "estimated":
            return self._wind_estimate_kt[None].copy()
        return np.zeros((1, 2))

    def _update_progress(self, view: WorldView) -> None:
        """The progress rule (``progress_fraction``): an aircraft that closed less than that
        share of a direct flight's progress (at the nominal airspeed, or what was left of its
        distance beyond the arrival tolerance) over the last ``progress_periods`` periods it
        flew whole is held on its recovery waypoint (``_start_directions``) until it stops
        flying; in a traffic stream a slot's next flight starts unheld."""
        s = self.settings
        if s.progress_fraction is None:
            return
        flying = view.flying
        to_dest = view.destinations - view.positions
        distance = np.hypot(to_dest[:, 0], to_dest[:, 1])
        flown_s = view.state[:, S_TIME].copy()
        if self._progress_history:
            _, _, last_flown, last_flying = self._progress_history[-1]
            new_flight = flying & (~last_flying | (flown_s < last_flown))
            self._stalled &= ~new_flight
        self._stalled &= flying
        window_s = s.progress_periods * s.period_s
        for time_s, then_distance, then_flown, then_flying in self._progress_history:
            if not math.isclose(view.time_s - time_s, window_s, abs_tol=1e-6):
                continue
            whole = flying & then_flying & np.isclose(flown_s - then_flown, window_s, atol=1e-6)
            asked = s.progress_fraction * np.minimum(
                AIRSPEED_NOMINAL_KT * window_s / SECONDS_PER_HOUR, np.maximum(then_distance - self._arrival_nm, 0.0))
            stalled = whole & (then_distance - distance < asked)
            self._stalled |= stalled
            self._ever_stalled |= stalled
        self._progress_history.append((view.time_s, distance, flown_s, flying.copy()))
        del self._progress_history[: -s.progress_periods]

    def _prediction_wind(self) -> np.ndarray:
        s = self.settings
        k = s.extractions
        if s.wind_model == "sampled":
            return self._rng.normal(0.0, s.wind_sigma_mps, (k, 2)) * KT_PER_MPS
        if s.wind_model == "estimated":
            return np.repeat(self._wind_estimate_kt[None], k, axis=0)
        return np.zeros((k, 2))

    def _simulate(self, base_state: np.ndarray, proposals: np.ndarray):
        """Costs (K,), survival (K,) and positions after the first period (K, N, 2)."""
        s = self.settings
        assert self._params is not None
        states, waypoints = _candidate_starts(base_state, proposals)
        wind = self._prediction_wind()
        feasible = np.ones(s.extractions, dtype=bool)
        survived = np.zeros(s.extractions, dtype=np.int64)
        after_first = None
        for period in range(s.horizon):
            before = states[:, :, S_X : S_Y + 1].copy()
            trace = kernel.advance(states, waypoints, wind, s.period_s, self._params, scratch=self._scratch)
            newly_bad, flown = self._period_verdict(states, trace, feasible)
            survived += flown
            feasible &= ~newly_bad
            # A world that violated is infeasible already: stop simulating it.
            states[newly_bad, :, S_STATUS] = np.where(
                states[newly_bad, :, S_STATUS] == FLYING, ABSENT, states[newly_bad, :, S_STATUS]
            )
            if after_first is None:
                after_first = states[:, :, S_X : S_Y + 1].copy()
            waypoints = waypoints + (states[:, :, S_X : S_Y + 1] - before)
        cost = self._cost(base_state, states)
        costs = np.where(feasible, cost, np.inf)
        return costs, survived, after_first

    def _period_verdict(
        self, states: np.ndarray, trace: kernel.Trace, feasible: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """After one period of the horizon: the worlds (still feasible) that violated in
        it, and what each world adds to its survival (steps, or sampling instants)."""
        assert self._config is not None
        if self.settings.constraint_check == "every-step":
            return trace.violated & feasible, np.where(feasible, trace.steps_done, 0)
        flying = states[:, :, S_STATUS] == FLYING
        airspeed = states[:, :, S_AIRSPEED]
        outside = flying & ((airspeed < self._config.airspeed_min_kt) | (airspeed > self._config.airspeed_max_kt))
        pos = states[:, :, S_X : S_Y + 1]
        diff = pos[:, :, None, :] - pos[:, None, :, :]
        close = (diff**2).sum(-1) < self._config.separation_min_nm**2
        pair_flying = flying[:, :, None] & flying[:, None, :]
        np.einsum("kii->ki", close)[:] = False
        newly_bad = feasible & (outside.any(axis=1) | (close & pair_flying).any(axis=(1, 2)))
        return newly_bad, feasible & ~newly_bad

    def _cost(self, base_state: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The cost of candidates flown to the horizon's end (feasible or not), nm."""
        cost = self._remaining_distance(states)
        if self.settings.proposal == "homing":
            cost = cost + self._time_to_arrival_nm(base_state, states)
        return cost

    @staticmethod
    def _remaining_distance(states: np.ndarray) -> np.ndarray:
        """Σ_i D(i): remaining distance to destination (0 once arrived), nm, per world."""
        delta = states[:, :, S_X : S_Y + 1] - states[:, :, S_DEST_X : S_DEST_Y + 1]
        distance = np.hypot(delta[..., 0], delta[..., 1])
        present = (states[:, :, S_STATUS] != ARRIVED) & (states[:, :, S_STATUS] != ABSENT)
        return np.where(present, distance, 0.0).sum(axis=1)

    @staticmethod
    def _time_to_arrival_nm(base_state: np.ndarray, states: np.ndarray) -> np.ndarray:
        """Σ_i v_ref·τ_i: the time τ_i each aircraft flew in the horizon (until its arrival,
        or the whole horizon), as distance at the nominal airspeed, nm, per world."""
        flown_s = states[:, :, S_TIME] - base_state[None, :, S_TIME]
        flying0 = base_state[:, S_STATUS] == FLYING
        return np.where(flying0[None], flown_s, 0.0).sum(axis=1) * (AIRSPEED_NOMINAL_KT / SECONDS_PER_HOUR)

    @staticmethod
    def _remaining_distance_of(proposals: np.ndarray, view: WorldView) -> np.ndarray:
        """Fallback tie-break: how far the candidates' waypoints leave the aircraft from home."""
        delta = proposals - view.destinations[None]
        distance = np.hypot(delta[..., 0], delta[..., 1])
        return np.where(view.flying[None], distance, 0.0).sum(axis=1)

    def _update_wind_estimate(self, view: WorldView) -> None:
        if self.settings.wind_model != "estimated" or self._predicted_positions is None:
            return
        if not math.isclose(view.time_s, self._predicted_time_s, abs_tol=1e-6):
            return
        # Only aircraft that flew the whole period were predicted: in a traffic stream an
        # aircraft that entered since has no prediction to compare with, also where it took
        # the slot of one that arrived or left during the period (its time flown restarted).
        whole_period = view.state[:, S_TIME] >= self.settings.period_s - 1e-6
        flying = view.flying & self._predicted_flying & whole_period
        if not flying.any():
            return
        error_nm = view.positions[flying] - self._predicted_positions[flying]
        self._wind_estimate_kt = self._wind_estimate_kt + error_nm.mean(axis=0) / (
            self.settings.period_s / SECONDS_PER_HOUR
        )


def _candidate_starts(base_state: np.ndarray, proposals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The K candidates' states (K, N, N_STATE), each a copy of ``base_state``, and their
    first waypoints (K, N, 2), nm: the proposals for the aircraft flying, the stored
    waypoint for the others (no switch for an aircraft that no longer flies)."""
    states = np.repeat(base_state[None], proposals.shape[0], axis=0)
    waypoints = proposals.copy()
    flying0 = base_state[:, S_STATUS] == FLYING
    waypoints[:, ~flying0] = base_state[None, ~flying0, kernel.S_WP_X : kernel.S_WP_Y + 1]
    return states, waypoints


def _advance_candidates(
    states: np.ndarray, waypoints: np.ndarray, wind_kt: np.ndarray, seconds: float, params: np.ndarray,
    scratch: kernel.KernelScratch, record_every: int = 0,
) -> kernel.Trace:
    """``kernel.advance`` of candidate worlds, a batch of fewer than
    ``_PARALLEL_FROM_WORLDS`` on one thread (the same bits on any number of threads)."""
    threads = numba.get_num_threads()
    if states.shape[0] < _PARALLEL_FROM_WORLDS and threads > 1:
        numba.set_num_threads(1)
        try:
            return kernel.advance(states, waypoints, wind_kt, seconds, params, record_every=record_every,
                                  scratch=scratch)
        finally:
            numba.set_num_threads(threads)
    return kernel.advance(states, waypoints, wind_kt, seconds, params, record_every=record_every, scratch=scratch)


#: ``sampling="clusters"``: how many times one decision may replace the chain's start by a
#: candidate that put its first violation off (see "Dense traffic").
CLUSTER_REPAIRS = 8



class _LazyCandidates:
    """The K candidates of one round, each simulated only as far as it is asked to be.

    Every candidate keeps its own state, waypoints and wind; ``advance`` flies chosen
    candidates one more period of the horizon with exactly the per-period steps of
    ``MCMCMPC._simulate`` (a world flies bit for bit the same alone or in any batch of
    the kernel), so a candidate flown to the horizon's end has the same cost, survival
    and first-period positions as in the exhaustive search. Before that, ``lower_bound``
    bounds its cost from below.
    """

    def __init__(self, mpc: MCMCMPC, base_state: np.ndarray, proposals: np.ndarray, wind_kt: np.ndarray) -> None:
        s = mpc.settings
        k, n = proposals.shape[0], base_state.shape[0]
        self.mpc = mpc
        self.base_state = base_state
        self.states, self.waypoints = _candidate_starts(base_state, proposals)
        self.wind_kt = wind_kt
        self.depth = np.zeros(k, dtype=np.int64)  # periods flown
        self.feasible = np.ones(k, dtype=bool)
        self.survived = np.zeros(k, dtype=np.int64)
        self.after_first = np.zeros((k, n, 2))
        self.costs = np.full(k, np.nan)  # known once done
        self.done = np.zeros(k, dtype=bool)  # flown to the horizon's end, or infeasible
        self.lower = np.zeros(k)  # lower bound of the cost of a candidate not done, nm
        self.estimate = np.zeros(k)  # a guess of that cost (to choose what to fly), nm
        self.world_periods = 0  # candidate-periods flown (diagnostics of the search)
        config = mpc._config
        params = mpc._params
        assert config is not None and params is not None
        if s.constraint_check == "every-step":
            # A feasible candidate flies every step inside the prediction's envelope.
            airspeed_bound = max(abs(config.airspeed_min_kt), abs(config.airspeed_max_kt))
        else:
            airspeed_bound = float(params[nf.P_U_CAP])  # guard 2 of the kernel
        self._speed_bound_kt = airspeed_bound + np.hypot(wind_kt[:, 0], wind_kt[:, 1])
        self._time_cost_kt = AIRSPEED_NOMINAL_KT if s.proposal == "homing" else 0.0
        self._arrival_nm = float(params[nf.P_DELTA])
        self._dt_h = float(params[nf.P_DT]) / SECONDS_PER_HOUR
        # Before anything flies every candidate's state is the base state; under one
        # wind for all (every wind model but "sampled") so is every candidate's bound.
        if (wind_kt == wind_kt[:1]).all():
            self._bound(np.array([0]), base_state[None])
            self.lower[1:] = self.lower[0]
            self.estimate[1:] = self.estimate[0]
        else:
            self._bound(np.arange(k), base_state[None])

    def advance(self, rows: np.ndarray, bound: bool = True) -> None:
        """Fly the candidates ``rows`` (ascending, none of them done) one more period;
        ``bound``: bound the cost of those not done after it (skipped where they will be
        flown on at once)."""
        mpc, s = self.mpc, self.mpc.settings
        assert mpc._params is not None and mpc._config is not None
        if rows.size == 0:
            return
        # A run of consecutive candidates is flown in place (views), any other set as copies.
        consecutive = int(rows[-1]) - int(rows[0]) + 1 == rows.size
        index = slice(int(rows[0]), int(rows[-1]) + 1) if consecutive else rows
        states = self.states[index]
        waypoints = self.waypoints[index]
        feasible = self.feasible[index]
        depth = self.depth[index]
        before = states[:, :, S_X : S_Y + 1].copy()
        trace = _advance_candidates(states, waypoints, self.wind_kt[index], s.period_s, mpc._params, mpc._scratch)
        newly_bad, flown = mpc._period_verdict(states, trace, feasible)
        self.survived[index] += flown
        feasible &= ~newly_bad
        states[newly_bad, :, S_STATUS] = np.where(
            states[newly_bad, :, S_STATUS] == FLYING, ABSENT, states[newly_bad, :, S_STATUS]
        )
        first = depth == 0
        self.after_first[rows[first]] = states[first, :, S_X : S_Y + 1]
        waypoints += states[:, :, S_X : S_Y + 1] - before
        depth += 1
        if not consecutive:
            self.states[rows] = states
            self.waypoints[rows] = waypoints
            self.feasible[rows] = feasible
            self.depth[rows] = depth
        self.world_periods += rows.size
        finished = ~feasible | (depth == s.horizon)
        if finished.any():
            ended = rows[finished]
            cost = mpc._cost(self.base_state, states[finished])
            self.costs[ended] = np.where(feasible[finished], cost, np.inf)
            self.done[ended] = True
        if bound and not finished.all():
            self._bound(rows[~finished])

    def complete(self, rows: np.ndarray) -> None:
        """Fly the candidates ``rows`` (ascending) to the horizon's end (or their first
        violation)."""
        rows = rows[~self.done[rows]]
        while rows.size:
            self.advance(rows, bound=False)
            rows = rows[~self.done[rows]]

    def _bound(self, rows: np.ndarray, states: np.ndarray | None = None) -> None:
        """``lower`` of ``rows``: a cost that no feasible continuation goes below, nm.

        An aircraft still flying is D nm from home with R h of horizon left. Its ground
        speed stays below V = the airspeed bound + |wind|, and its position after any
        time t below V t + (V/2 + V_0) dt from where it is now (the integrator's Euler
        and AB2 steps move x − (h/2) v_prev by at most V per unit of time; V_0 also
        bounds the stored previous velocity). It arrives, leaves, or is still flying at
        the horizon's end after t' ≤ R h; either way its share of the cost is at least
        max(0, d − V t') + c t' with d = D − Δ − slack (c = 454 kt under "homing": the
        time term, 0 under "paper"), whose minimum over [0, R] is taken in closed form.
        Aircraft that no longer fly add what they will add at the end.
        """
        base = self.base_state
        states = self.states[rows] if states is None else states
        status = states[:, :, S_STATUS]
        flying = status == FLYING
        delta = states[:, :, S_X : S_Y + 1] - states[:, :, S_DEST_X : S_DEST_Y + 1]
        distance = np.hypot(delta[..., 0], delta[..., 1])
        present = (status != ARRIVED) & (status != ABSENT)
        frozen = np.where(present & ~flying, distance, 0.0).sum(axis=1)
        flying0 = base[:, S_STATUS] == FLYING
        elapsed_h = np.where(flying0[None], states[:, :, S_TIME] - base[None, :, S_TIME], 0.0) / SECONDS_PER_HOUR
        c = self._time_cost_kt
        speed = self._speed_bound_kt[rows][:, None]
        previous = np.hypot(states[:, :, kernel.S_VX_PREV], states[:, :, kernel.S_VY_PREV])
        slack = self._arrival_nm + (0.5 * speed + np.maximum(speed, previous)) * self._dt_h
        d = np.maximum(distance - slack, 0.0)
        left_h = ((self.mpc.settings.horizon - self.depth[rows]) * self.mpc.settings.period_s / SECONDS_PER_HOUR)[
            :, None
        ]
        reach_h = np.minimum(d / speed, left_h)
        share = np.minimum(
            np.minimum(d, np.maximum(d - speed * left_h, 0.0) + c * left_h), d - speed * reach_h + c * reach_h
        )
        lower = frozen + np.where(flying, share, 0.0).sum(axis=1) + c * elapsed_h.sum(axis=1)
        # Rounding: the bound is compared with a cost summed in another order.
        self.lower[rows] = np.maximum(lower * (1.0 - 1e-9) - 1e-9, 0.0)  # broadcast over rows
        # The guess: the same with every aircraft flying straight home at the nominal
        # airspeed from where it is now.
        nominal = AIRSPEED_NOMINAL_KT
        reach_h = np.minimum(distance / nominal, left_h)
        guess = np.maximum(distance - nominal * left_h, 0.0) + c * reach_h
        self.estimate[rows] = frozen + np.where(flying, guess, 0.0).sum(axis=1) + c * elapsed_h.sum(axis=1)


#: Candidates flown in the first batch of the search for the first feasible one, when
#: the chain's initial state is infeasible (each later batch twice the last): a small
#: batch, as the first feasible candidate is usually among the first few dozen.
_FIRST_FEASIBLE_BATCH = 8

#: Batches of fewer candidates are flown on one thread. Waking numba's thread pool, and
#: its threads spinning after the parallel loop, cost more than they save on a batch of a
#: few hundred candidates while other processes hold the cores (on two shared cores a
#: threshold of 64 made the lazy search's mean decision slower than 256 or one thread).
_PARALLEL_FROM_WORLDS = 256


@njit(cache=True)
def _chain_until_undecided(
    k: int,
    current: int,
    best: int,
    accepted: int,
    done: np.ndarray,
    costs: np.ndarray,
    log_cost: np.ndarray,
    log_lower: np.ndarray,
    log_g: np.ndarray,
    log_u: np.ndarray,
    cost_exponent: float,
    sign: float,
) -> tuple[int, int, int, int]:
    """Run the chain from candidate ``k`` while the state ``current`` is feasible, until
    a candidate that is neither done nor rejected by its cost's lower bound.

    The verdicts of ``metropolis_hastings_best`` with the same operations in the same
    order (IEEE arithmetic, no fast-math), on logarithms taken by its callers as it
    takes them. Returns (that candidate, or K; the state; the best state; moves).
    """
    k_total = done.shape[0]
    while k < k_total:
        if done[k]:
            if not math.isinf(costs[k]):  # an infeasible candidate is rejected
                if accepts(log_acceptance(log_cost[current], log_cost[k], log_g[current], log_g[k], cost_exponent,
                                          sign), log_u[k]):
                    current = k
                    accepted += 1
                    if costs[current] < costs[best] or math.isinf(costs[best]):
                        best = current
            k += 1
            continue
        if not accepts(log_acceptance(log_cost[current], log_lower[k], log_g[current], log_g[k], cost_exponent, sign),
                       log_u[k]):
            k += 1  # rejected whatever its cost: the lower bound gives the largest ρ
            continue
        return k, current, best, accepted
    return k, current, best, accepted


@njit(cache=True)
def _undecided_ahead(
    k: int,
    current: int,
    done: np.ndarray,
    costs: np.ndarray,
    log_cost: np.ndarray,
    log_lower: np.ndarray,
    log_guess: np.ndarray,
    log_g: np.ndarray,
    log_u: np.ndarray,
    cost_exponent: float,
    sign: float,
) -> np.ndarray:
    """The candidates from ``k`` on (k itself first) that the chain will probably find
    undecided: it is run ahead as if every candidate not done were feasible and cost
    its guess. Only a choice of what to fly next; every verdict is taken on true costs.
    """
    k_total = done.shape[0]
    rows = np.empty(k_total - k, dtype=np.int64)
    rows[0] = k
    count = 1
    score = cost_exponent * log_cost[current] + sign * log_g[current]  # the state's
    rise = score - (cost_exponent * log_guess[k] + sign * log_g[k])
    if accepts(rise, log_u[k]):
        score -= rise
    for j in range(k + 1, k_total):
        if done[j]:
            if not math.isinf(costs[j]):
                rise = score - (cost_exponent * log_cost[j] + sign * log_g[j])
                if accepts(rise, log_u[j]):
                    score -= rise
            continue
        upper = score - (cost_exponent * log_lower[j] + sign * log_g[j])
        if not accepts(upper, log_u[j]):
            continue
        rows[count] = j
        count += 1
        rise = score - (cost_exponent * log_guess[j] + sign * log_g[j])
        if accepts(rise, log_u[j]):
            score -= rise
    return rows[:count]


def _load_compiled_chain() -> None:
    """Compile (or load from numba's cache) the lazy chain's helpers, on two candidates."""
    done = np.ones(2, dtype=np.bool_)
    values = np.zeros(2)
    _chain_until_undecided(1, 0, 0, 0, done, values, values, values, values, values, 1.0, 1.0)
    _undecided_ahead(1, 0, ~done, values, values, values, values, values, values, 1.0, 1.0)


def _lazy_chain(
    candidates: _LazyCandidates,
    log_proposal: np.ndarray,
    uniforms: np.ndarray,
    cost_exponent: float,
    acceptance: str,
) -> tuple[int, int, bool]:
    """``metropolis_hastings_best`` over candidates simulated on demand.

    The chain needs a candidate's cost only to decide whether to move to it. While the
    chain sits on an infeasible state it moves to every candidate, whatever its cost:
    the candidates are flown to the end in the chain's order, in batches, until the
    first feasible one. From there on the chain sits on a feasible state, and a
    candidate whose cost's lower bound already gives ρ ≤ u is rejected whatever its
    cost (an infeasible one is rejected too), so it is not flown further. The first
    candidate that is neither is flown a period further and looked at again, and with
    it, in one batch, every later one that the chain, run ahead on guessed costs
    (``_undecided_ahead``), would find undecided too. A candidate the chain moves to has
    always been flown to the end.
    Every verdict is the one ``metropolis_hastings_best`` takes on the full costs, with
    the same arithmetic, so the best state and the number of moves are the same.

    Returns:
        (index of the lowest-cost state the chain visited, number of accepted moves,
        whether any candidate was feasible). When none was, every candidate was flown
        to its end.
    """
    c = candidates
    k_total = log_proposal.shape[0]
    sign = 1.0 if acceptance == "standard" else -1.0
    # math.log of each uniform, as metropolis_hastings_best takes it (np.log may round
    # differently); max(u, 1e-300) is the same double as np.maximum's.
    log_u = np.array(list(map(math.log, np.maximum(uniforms, 1e-300).tolist())))
    c.complete(np.array([0]))
    current = best = 0
    accepted = 0
    k = 1
    costs = c.costs
    if math.isinf(costs[0]):
        # From an infeasible state the chain moves to every candidate (to an infeasible
        # one: no preference; to a feasible one: always), and the last state visited is
        # the best so far, until the first feasible candidate.
        batch = _FIRST_FEASIBLE_BATCH
        while k < k_total:
            rows = np.arange(k, min(k + batch, k_total))
            c.complete(rows)
            feasible = np.flatnonzero(np.isfinite(costs[rows]))
            if feasible.size:
                current = best = int(rows[feasible[0]])
                accepted = current
                k = current + 1
                break
            k = int(rows[-1]) + 1
            batch *= 2
        else:
            return k_total - 1, k_total - 1, False
    while True:  # the current state is feasible from here on
        # Logarithms over the whole array, as metropolis_hastings_best takes them.
        log_cost = np.log(np.maximum(np.where(c.done, costs, 1.0), _COST_FLOOR_NM))
        log_lower = np.log(np.maximum(c.lower, _COST_FLOOR_NM))
        k, current, best, accepted = _chain_until_undecided(
            k, current, best, accepted, c.done, costs, log_cost, log_lower, log_proposal, log_u, cost_exponent, sign
        )
        if k == k_total:
            return best, accepted, True
        log_guess = np.log(np.maximum(c.estimate, _COST_FLOOR_NM))
        c.advance(
            _undecided_ahead(
                k, current, c.done, costs, log_cost, log_lower, log_guess, log_proposal, log_u, cost_exponent, sign
            )
        )
