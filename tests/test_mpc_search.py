"""The MPC's lazy search picks what the exhaustive search picks, from the same draws.

``MPCSettings.search = "lazy"`` flies a candidate only as far as the Metropolis-Hastings
chain needs to decide on it, bounding the cost of the rest from below; "exhaustive"
flies all K over the whole horizon. Same seed, same episode, bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import FLYING, S_STATUS
from atc_nf_env.scenarios import converging, random_encounter
from atc_nf_env.simulation import Simulation
from baselines import MCMCMPC, mcmc_mpc
from baselines.mcmc_mpc import _LazyCandidates

CASES = {
    # K = 1000, the paper's: decisions whose initial state is infeasible, chains of many moves.
    "converging-4": (lambda: converging(4), 0, dict(extractions=1000), {}),
    "converging-6": (lambda: converging(6), 1, dict(extractions=1000), {}),
    "random-4": (lambda: random_encounter(4, seed=3), 3, dict(extractions=1000), {}),
    "paper proposal": (lambda: converging(4), 0, dict(extractions=300, proposal="paper"), {}),
    # A narrow envelope: decisions rescued by a wider round, and fallbacks.
    "wider rounds": (
        lambda: converging(4), 2, dict(extractions=100, first_decision_margin_kt=4.0),
        dict(config=SimConfig(airspeed_min_kt=400.0, airspeed_max_kt=470.0), max_time_s=1800.0),
    ),
    "fallbacks": (
        lambda: converging(4), 0, dict(extractions=100),
        dict(config=SimConfig(airspeed_min_kt=430.0, airspeed_max_kt=470.0), max_time_s=1800.0),
    ),
    "sampled wind, table-i, J = 2": (
        lambda: converging(3), 4,
        dict(extractions=200, wind_model="sampled", acceptance="table-i", cost_exponent=2.0), {},
    ),
    "sampling instants": (lambda: converging(3), 1, dict(extractions=200, constraint_check="sampling-instants"), {}),
    "K = 1": (lambda: converging(3), 0, dict(extractions=1), dict(max_time_s=1800.0)),
    "K = 2, horizon 1": (lambda: converging(3), 0, dict(extractions=2, horizon=1), dict(max_time_s=1800.0)),
    "horizon 6": (lambda: converging(3), 2, dict(extractions=100, horizon=6), {}),
    # Conflict clusters (rounds that grow a cluster) and the progress rule.
    "clusters": (
        lambda: converging(6), 1,
        dict(extractions=300, sampling="clusters", progress_fraction=0.9, progress_periods=1), {},
    ),
}


def _fly(case: str, search: str):
    make, seed, settings, run = CASES[case]
    policy = MCMCMPC(search=search, **settings)
    result = run_episode(policy, make(), seed=seed, wind_sigma_mps=5.17, record_every=1, **run)
    return policy, result


@pytest.fixture
def chains(monkeypatch):
    """What every lazy chain of the test saw: (initial state infeasible, index of the
    first feasible candidate or None, candidate-periods flown, moves of the chain, K)."""
    seen = []
    original = mcmc_mpc._lazy_chain

    def spy(candidates, log_proposal, *args):
        best, accepted, any_feasible = original(candidates, log_proposal, *args)
        known = np.flatnonzero(candidates.done & np.isfinite(candidates.costs))
        seen.append(
            (
                bool(np.isinf(candidates.costs[0])),
                int(known[0]) if known.size else None,
                candidates.world_periods,
                accepted,
                log_proposal.shape[0],
            )
        )
        return best, accepted, any_feasible

    monkeypatch.setattr(mcmc_mpc, "_lazy_chain", spy)
    return seen


@pytest.mark.parametrize("case", list(CASES))
def test_lazy_search_flies_the_exhaustive_episode_bit_for_bit(case, chains):
    exhaustive, a = _fly(case, "exhaustive")
    lazy, b = _fly(case, "lazy")
    assert np.array_equal(a.records, b.records)
    assert np.array_equal(a.waypoints, b.waypoints)
    assert len(exhaustive.decisions) == len(lazy.decisions) > 0
    for da, db in zip(exhaustive.decisions, lazy.decisions):
        # The same pick, cost, moves of the chain, rounds and fallback.
        assert dataclasses.replace(da, feasible_fraction=None) == dataclasses.replace(db, feasible_fraction=None)
        # Where the lazy search flew every candidate (no feasible one in the first round),
        # it knows the feasible fraction, and it is the same.
        assert db.feasible_fraction is None or db.feasible_fraction == da.feasible_fraction
    info_a, info_b = exhaustive.episode_info(), lazy.episode_info()
    info_a.pop("feasible_fraction"), info_b.pop("feasible_fraction")
    assert info_a == info_b
    assert lazy.search_world_periods <= exhaustive.search_world_periods
    horizon = lazy.settings.horizon
    if case in ("converging-4", "converging-6"):
        # Most decisions flew only the chain's initial state. Some chains started
        # infeasible, searched for the first feasible candidate in batches (beyond the
        # first batch on converging-6), and then moved many times among candidates flown
        # only as far as the bound needed: far fewer than K · N candidate-periods.
        assert sum(periods == horizon for _, _, periods, _, _ in chains) > len(chains) / 2
        started_infeasible = [c for c in chains if c[0]]
        assert started_infeasible and all(first is not None for _, first, _, _, _ in started_infeasible)
        assert max(moves / k for _, _, _, moves, k in started_infeasible) > 0.05
        assert all(periods < 0.5 * k * horizon for _, _, periods, _, k in started_infeasible)
        if case == "converging-6":
            assert max(first for _, first, _, _, _ in started_infeasible) > mcmc_mpc._FIRST_FEASIBLE_BATCH
        assert lazy.search_world_periods < 0.5 * exhaustive.search_world_periods
    if case == "paper proposal":
        # A chain that moved among candidates flown only in part: the bound-and-refine path.
        assert any(d.chain_acceptance > 0.05 and d.feasible_fraction is None for d in lazy.decisions)
    if case == "wider rounds":
        assert info_b["rescued_by_wider_search"] >= 1 and info_b["fallbacks"] == 0
    if case == "clusters":
        assert info_b["cluster_decisions"] >= 1 and info_b["recovery_decisions"] >= 1
    if case == "fallbacks":
        assert info_b["fallbacks"] >= 1 and info_b["rescued_by_wider_search"] >= 1


@pytest.mark.parametrize(
    "settings",
    [dict(), dict(proposal="paper"), dict(wind_model="sampled"), dict(constraint_check="sampling-instants")],
)
def test_cost_lower_bound_holds_at_every_depth(settings):
    """The bound the lazy search rejects by: never above the cost a feasible candidate ends
    with, at every period of the horizon, over the decisions of a windy episode."""
    views = []

    class Recording(MCMCMPC):
        def act(self, view):
            views.append(view)
            return super().act(view)

    policy = Recording(extractions=300, search="exhaustive", **settings)
    run_episode(policy, converging(4), seed=7, wind_sigma_mps=5.17, max_time_s=2400.0)
    assert len(views) >= 6
    checked = 0
    for view in views:
        proposals, _ = policy._propose(view)
        candidates = _LazyCandidates(policy, view.state, proposals, policy._prediction_wind())
        rows = np.arange(proposals.shape[0])
        bounds = [candidates.lower.copy()]
        for _ in range(policy.settings.horizon):
            live = rows[~candidates.done]
            if live.size == 0:
                break
            candidates.advance(live)
            bounds.append(np.where(candidates.done, np.nan, candidates.lower))
        feasible = np.isfinite(candidates.costs)
        for depth, lower in enumerate(bounds):
            known = feasible & np.isfinite(lower)
            assert (lower[known] <= candidates.costs[known]).all(), (view.time_s, depth)
            checked += int(known.sum())
        # Not a trivial bound: before anything flies it is a sizeable part of the cost
        # (between sampling instants the airspeed is bounded only by the kernel's cap).
        every_step = policy.settings.constraint_check == "every-step"
        if every_step and feasible.any() and (view.state[:, S_STATUS] == FLYING).any():
            assert bounds[0][feasible].min() > 0.3 * candidates.costs[feasible].min()
    assert checked > 1000


def test_lazy_search_does_not_report_a_feasible_fraction_it_did_not_measure():
    scenario = converging(4)
    view = Simulation(scenario).view()
    fractions = {}
    for search in ("lazy", "exhaustive"):
        policy = MCMCMPC(extractions=200, search=search)
        policy.reset(scenario, SimConfig(), seed=0)
        policy.act(view)
        fractions[search] = policy.decisions[0].feasible_fraction
        info = policy.episode_info()["feasible_fraction"]
        assert info["decisions"] == (0 if fractions[search] is None else 1)
    assert fractions["lazy"] is None  # the chain's initial state was feasible: nothing else flew
    assert 0.0 < fractions["exhaustive"] <= 1.0


def test_bad_search_setting_is_a_clear_error():
    with pytest.raises(ValueError, match="search = 'fast'.*lazy, exhaustive"):
        MCMCMPC(search="fast")


def test_cli_search_option_reaches_the_mpc(monkeypatch):
    from atc_nf_env import cli

    made = []
    original = cli.make_policy

    def spy(spec, **settings):
        made.append(settings)
        return original(spec, **settings)

    monkeypatch.setattr("atc_nf_env.cli.make_policy", spy)
    argv = ["fly", "--scenario", "converging-3", "--max-minutes", "5", "--extractions", "20", "--search"]
    assert cli.main(argv + ["exhaustive"]) == 0
    assert made[-1].get("search") == "exhaustive"
    with pytest.raises(SystemExit):
        cli.main(argv + ["fast"])


def test_small_batches_fly_on_one_thread_and_the_thread_count_comes_back(monkeypatch):
    """A batch under ``_PARALLEL_FROM_WORLDS`` candidates flies on one numba thread, a
    larger one on all of them, and the caller's thread count is restored, also when the
    kernel raises."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread here")
    threads = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        scenario = converging(4)
        view = Simulation(scenario).view()
        policy = MCMCMPC(extractions=mcmc_mpc._PARALLEL_FROM_WORLDS + 10)
        policy.reset(scenario, SimConfig(), seed=0)
        proposals, _ = policy._propose(view)
        candidates = _LazyCandidates(policy, view.state, proposals, policy._prediction_wind())
        seen = []
        original = mcmc_mpc.kernel.advance

        def spy(state, *args, **kwargs):
            seen.append((state.shape[0], numba.get_num_threads()))
            return original(state, *args, **kwargs)

        monkeypatch.setattr(mcmc_mpc.kernel, "advance", spy)
        small = np.arange(3, 13)
        candidates.advance(small)
        candidates.advance(np.setdiff1d(np.arange(proposals.shape[0]), small))
        assert seen == [(10, 1), (mcmc_mpc._PARALLEL_FROM_WORLDS, 2)]
        assert numba.get_num_threads() == 2

        def broken(*args, **kwargs):
            raise FloatingPointError("the integration produced NaN")

        monkeypatch.setattr(mcmc_mpc.kernel, "advance", broken)
        with pytest.raises(FloatingPointError):
            candidates.advance(np.arange(20, 25))
        assert numba.get_num_threads() == 2
    finally:
        numba.set_num_threads(threads)
