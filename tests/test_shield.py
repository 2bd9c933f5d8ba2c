"""The safety filter (``atc_nf_env.shield.SafetyFilter``): it removes breaches a policy
would fly, never touches a waypoint set it predicts safe, counts its interventions, refuses
bad arguments and is deterministic per seed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atc_nf_env.cli import main
from atc_nf_env.episode import run_episode
from atc_nf_env.evaluate import Study, evaluate
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.shield import SHIELD_INFO_KEYS, SafetyFilter, summarize_interventions
from atc_nf_env.simulation import WorldView


class AimThrough:
    """Every aircraft aimed at its destination, ``distance_nm`` out (past it on final):
    in the envelope in open traffic, not where the NF's avoidance turns aircraft hard."""

    name = "aim-through"

    def __init__(self, distance_nm: float = 110.0) -> None:
        self.distance_nm = distance_nm
        self.proposals: list[np.ndarray] = []

    def reset(self, scenario, config, seed=None) -> None:
        self.proposals = []

    def act(self, view: WorldView) -> np.ndarray:
        to_dest = view.destinations - view.positions
        distance = np.hypot(to_dest[:, 0], to_dest[:, 1])
        waypoints = view.positions + to_dest * (self.distance_nm / np.maximum(distance, 1e-9))[:, None]
        self.proposals.append(waypoints)
        return waypoints


class Behind(AimThrough):
    """Waypoints 100 nm behind every aircraft: the NF answers with a reverse airspeed."""

    name = "behind"

    def act(self, view: WorldView) -> np.ndarray:
        heading = view.headings
        waypoints = view.positions - 100.0 * np.stack([np.cos(heading), np.sin(heading)], axis=1)
        self.proposals.append(waypoints)
        return waypoints


def test_a_policy_flying_out_of_the_envelope_is_filtered_and_the_episode_stays_inside():
    scenario = make_scenario("converging-4")
    raw = run_episode(Behind(), scenario, seed=0, max_time_s=1800).metrics
    assert raw.worst_excursion_kt > 100  # the policy does breach, far
    shielded = SafetyFilter(Behind(), fallback="least-bad")
    metrics = run_episode(shielded, scenario, seed=0, max_time_s=1800).metrics
    assert metrics.envelope_violation_fraction == 0.0 and metrics.worst_excursion_kt == 0.0
    assert metrics.los_count == 0
    info = shielded.episode_info()
    assert info["shield_decisions"] == 6 and info["shield_filtered"] == 6
    assert info["shield_aircraft_changed"] >= 6


def test_a_breach_on_the_approach_is_removed():
    # Aimed home through the NF's avoidance of converging-3, the airspeed reverses.
    scenario = make_scenario("converging-3")
    raw = run_episode(AimThrough(), scenario, seed=1).metrics
    assert raw.worst_excursion_kt > 0
    shielded = SafetyFilter(AimThrough(), fallback="least-bad")
    metrics = run_episode(shielded, scenario, seed=1).metrics
    assert metrics.success and metrics.worst_excursion_kt == 0.0 and metrics.los_count == 0
    assert shielded.episode_info()["shield_filtered"] >= 1


@pytest.mark.parametrize("scenario_name, seed", [("random-2", 0), ("random-3", 0), ("random-3", 1)])
def test_a_safe_policy_is_never_changed_bit_for_bit(scenario_name, seed):
    scenario = make_scenario(scenario_name, seed=seed)
    plain = run_episode(AimThrough(), scenario, seed=seed, record_every=1)
    inner = AimThrough()
    shielded = SafetyFilter(inner)
    result = run_episode(shielded, scenario, seed=seed, record_every=1)
    assert shielded.episode_info()["shield_filtered"] == 0
    assert np.array_equal(result.waypoints, np.array(inner.proposals))
    assert np.array_equal(result.waypoints, plain.waypoints)
    assert np.array_equal(result.records, plain.records)
    assert result.metrics.flight_time_min == plain.metrics.flight_time_min


def test_the_unchanged_proposal_is_returned_as_is():
    scenario = make_scenario("random-2", seed=0)
    inner = AimThrough()
    shielded = SafetyFilter(inner)
    from atc_nf_env.config import SimConfig
    from atc_nf_env.simulation import Simulation

    shielded.reset(scenario, SimConfig(), 0)
    out = shielded.act(Simulation(scenario).view())
    assert out is inner.proposals[-1]


def test_same_seed_same_filtered_episode():
    scenario = make_scenario("converging-3")
    runs = [run_episode(SafetyFilter(AimThrough(), fallback="least-bad"), scenario, seed=1, record_every=1)
            for _ in range(2)]
    assert np.array_equal(runs[0].waypoints, runs[1].waypoints)
    assert np.array_equal(runs[0].records, runs[1].records)


class NoAlternatives(SafetyFilter):
    """A filter whose every alternative is the unsafe proposal, so that the MPC decides."""

    def _alternatives(self, view, planned, blamed, kind):
        return planned[None].copy(), np.zeros((1, planned.shape[0]), dtype=bool)


def test_with_no_safe_alternative_the_mpc_decides_deterministically_and_is_counted():
    scenario = make_scenario("converging-3")
    results, infos = [], []
    for _ in range(2):
        shielded = NoAlternatives(Behind(), mpc_settings={"extractions": 64})
        results.append(run_episode(shielded, scenario, seed=3, max_time_s=600))
        infos.append(shielded.episode_info())
    assert infos[0]["shield_mpc_fallbacks"] == infos[0]["shield_filtered"] == 2
    assert infos[0] == infos[1]
    assert np.array_equal(results[0].waypoints, results[1].waypoints)
    assert results[0].metrics.worst_excursion_kt == 0.0


def test_an_injected_fallback_policy_decides_as_the_registry_s_mpc_does():
    """``fallback`` takes a policy object or a factory of one; the default ("mpc") is the
    registry's MCMC-MPC, so giving that same policy changes nothing, bit for bit."""
    from atc_nf_env.policy import make_policy

    scenario = make_scenario("converging-3")
    by_name = NoAlternatives(Behind(), mpc_settings={"extractions": 64})
    reference = run_episode(by_name, scenario, seed=3, max_time_s=600)
    for fallback in (make_policy("mpc", extractions=64), lambda: make_policy("mpc", extractions=64)):
        injected = NoAlternatives(Behind(), fallback=fallback)
        result = run_episode(injected, scenario, seed=3, max_time_s=600)
        assert injected.fallback == "policy"
        assert np.array_equal(result.records, reference.records)
        assert np.array_equal(result.waypoints, reference.waypoints)
        assert injected.episode_info()["shield_mpc_fallbacks"] == by_name.episode_info()["shield_mpc_fallbacks"] == 2


def test_a_bad_fallback_is_refused_with_what_is_allowed():
    with pytest.raises(TypeError, match="least-bad.*Policy interface"):
        SafetyFilter(AimThrough(), fallback=42)
    with pytest.raises(TypeError, match="factory returned a int"):
        SafetyFilter(AimThrough(), fallback=lambda: 42)
    with pytest.raises(TypeError, match="neither a SafetyFilter nor the policy filtered"):
        policy = AimThrough()
        SafetyFilter(policy, fallback=policy)
    # Settings of the MPC fallback with another fallback: refused, not silently ignored.
    with pytest.raises(ValueError, match=r"\['extractions'\] apply to fallback='mpc' only"):
        SafetyFilter(AimThrough(), fallback="least-bad", mpc_settings={"extractions": 10})
    with pytest.raises(ValueError, match=r"\['extractions'\] apply to fallback='mpc' only"):
        SafetyFilter(AimThrough(), fallback=AimThrough(), mpc_settings={"extractions": 10})
    # The sampled tier's proposal fields are checked whatever the fallback.
    with pytest.raises(ValueError, match="distance_std_nm"):
        SafetyFilter(AimThrough(), fallback="least-bad", mpc_settings={"distance_std_nm": -1.0})
    SafetyFilter(AimThrough(), fallback="least-bad", mpc_settings={"distance_std_nm": 20.0})  # accepted


def test_the_sampled_tier_s_proposal_defaults_are_the_mpc_s():
    import dataclasses

    from atc_nf_env.proposals import WaypointProposal
    from baselines import MPCSettings

    mpc = MPCSettings()
    for field in dataclasses.fields(WaypointProposal):
        assert getattr(WaypointProposal(), field.name) == getattr(mpc, field.name), field.name


def test_episode_info_keeps_its_keys_and_never_shadows_the_policy_s():
    from baselines import MCMCMPC

    shielded = SafetyFilter(MCMCMPC(extractions=32))
    before = shielded.episode_info()
    run_episode(shielded, make_scenario("converging-3"), seed=0, max_time_s=600)
    after = shielded.episode_info()
    assert set(before) == set(after)
    assert set(SHIELD_INFO_KEYS) <= set(after)
    assert "fallbacks" in after and after["fallbacks"] == MCMCMPC.episode_info(shielded.policy)["fallbacks"]
    assert all(key.startswith("shield_") for key in set(after) - set(shielded.policy.episode_info()))


def test_bad_arguments_are_refused():
    with pytest.raises(TypeError, match="Policy interface"):
        SafetyFilter(object())
    with pytest.raises(TypeError, match="already a SafetyFilter"):
        SafetyFilter(SafetyFilter(AimThrough(), fallback="least-bad"))
    with pytest.raises(ValueError, match="lookahead_periods"):
        SafetyFilter(AimThrough(), lookahead_periods=3)
    with pytest.raises(ValueError, match="fallback"):
        SafetyFilter(AimThrough(), fallback="pray")
    with pytest.raises(ValueError, match="envelope_margin_kt"):
        SafetyFilter(AimThrough(), envelope_margin_kt=float("nan"))
    with pytest.raises(TypeError, match="home_distance_nm"):
        SafetyFilter(AimThrough(), home_distance_nm="far")
    with pytest.raises(TypeError):
        SafetyFilter(AimThrough(), margin=3.0)  # unknown keyword
    with pytest.raises(ValueError, match="unexpected keyword argument 'extractons'"):
        SafetyFilter(AimThrough(), mpc_settings={"extractons": 10})
    with pytest.raises(RuntimeError, match="reset"):
        SafetyFilter(AimThrough(), fallback="least-bad").act(None)


@pytest.mark.parametrize("bad", [np.zeros((2, 2)), np.zeros((3, 2)) + 1j])
def test_a_policy_returning_waypoints_of_the_wrong_shape_or_type_is_refused(bad):
    class Bad(AimThrough):
        def act(self, view):
            return bad

    from atc_nf_env.config import SimConfig
    from atc_nf_env.simulation import Simulation

    scenario = make_scenario("converging-3")
    shielded = SafetyFilter(Bad(), fallback="least-bad")
    shielded.reset(scenario, SimConfig(), 0)
    with pytest.raises(ValueError, match="act returned"):
        shielded.act(Simulation(scenario).view())


class Garbage(AimThrough):
    """Proposes, for the aircraft picked by ``pattern`` (one bit each), a waypoint that is
    not a finite point of the workspace; the others aim through their destinations."""

    name = "garbage"

    def __init__(self, pattern: int, value: float) -> None:
        super().__init__()
        self.pattern, self.value = pattern, value

    def act(self, view: WorldView) -> np.ndarray:
        waypoints = super().act(view).copy()
        for i in range(len(waypoints)):
            if self.pattern >> (i + len(self.proposals)) % 6 & 1:
                waypoints[i] = (self.value, -self.value if i % 2 else 0.0)
        return waypoints


@settings(max_examples=8, deadline=None)
@given(pattern=st.integers(1, 63), value=st.sampled_from([np.nan, np.inf, -np.inf, 1e100, -1e308, 5e3]),
       seed=st.integers(0, 50))
def test_waypoints_that_are_no_finite_point_of_the_workspace_are_unsafe_not_an_error(pattern, value, seed):
    """NaN, inf and absurd waypoints are replaced by the homing waypoint, counted, and the
    episode flies home safe: never an exception from the filter or the kernel."""
    shielded = SafetyFilter(Garbage(pattern, value))
    result = run_episode(shielded, make_scenario("converging-4"), seed=seed)
    info = shielded.episode_info()
    assert info["shield_invalid_waypoints"] > 0
    assert np.isfinite(result.waypoints).all()
    m = result.metrics
    assert m.success and m.los_count == 0 and m.envelope_violation_fraction == 0.0


def test_the_mpc_fallback_forgets_the_wind_after_a_prediction_cut_short_in_its_first_period(monkeypatch):
    """A prediction stopped at a breach leaves the aircraft short of where the period
    would have put them: read as drift, that gap once grew the wind estimate to (406, 68)
    kt. The MPC-fallback branch forgets it, as the least-bad branch does."""
    scenario = make_scenario("converging-3")
    from atc_nf_env.config import SimConfig
    from atc_nf_env.simulation import Simulation

    shielded = NoAlternatives(Behind(), mpc_settings={"extractions": 16})
    shielded.reset(scenario, SimConfig(), 0)
    flown = shielded._predict

    def breached_at_once(state, waypoints):
        survived, positions, alive = flown(state, waypoints)
        return np.zeros_like(survived), positions * 0.5, alive

    monkeypatch.setattr(shielded, "_predict", breached_at_once)
    shielded.act(Simulation(scenario).view())
    assert shielded.episode_info()["shield_mpc_fallbacks"] == 1
    assert shielded._memory.timing[0] == 0.0  # nothing remembered to measure drift against


def test_study_and_cli_count_interventions(tmp_path, capsys):
    with pytest.raises(TypeError, match="shield"):
        Study(policy="nf", scenario="converging-3", shield="yes")
    study = Study(policy="nf", scenario="converging-3", max_time_s=600.0, shield=True)
    assert study.header()["shield"] is True
    assert "shield" not in Study(policy="nf", scenario="converging-3").header()
    summary = evaluate(study, 2, workers=1, progress=False)
    shield = summary["shield"]
    assert shield["runs"] == 2 and shield["decisions"] == summary["decisions"] == 4
    assert 0 <= shield["filtered"] <= shield["decisions"]
    assert summary["decision_s"]["p99"] >= summary["decision_s"]["median"] > 0
    out = tmp_path / "fly.json"
    code = main(["fly", "--policy", "nf", "--scenario", "converging-3", "--max-minutes", "10", "--shield",
                 "--summary-json", str(out)])
    assert code == 0
    written = json.loads(out.read_text())
    assert written["shield"]["decisions"] == 2
    assert set(SHIELD_INFO_KEYS) <= set(written["policy_info"])
    assert "safety filter: 2 decisions" in capsys.readouterr().out


def test_summarize_interventions():
    assert summarize_interventions([{}, {"fallbacks": 1}]) is None
    info = dict.fromkeys(SHIELD_INFO_KEYS, 0)
    runs = [{**info, "shield_decisions": 10, "shield_filtered": 2, "shield_mpc_fallbacks": 1}, {**info,
            "shield_decisions": 10}]
    total = summarize_interventions(runs)
    assert total["decisions"] == 20 and total["filtered"] == 2 and total["runs_filtered"] == 1
    assert total["runs_with_mpc_fallback"] == 1 and total["filtered_fraction"] == pytest.approx(0.1)


def test_benchmark_shield_rows(tmp_path):
    pytest.importorskip("stable_baselines3")
    from pathlib import Path

    from agents import benchmark

    model = sorted((Path(__file__).resolve().parents[1] / "agents" / "models").glob("*.zip"))[0]
    results = benchmark.run([str(model)], ["converging-3"], runs=1, mpc_runs=1, out=tmp_path, reuse_mpc=None,
                            workers=1, progress=False, shield=True)
    assert set(results["converging-3"]) == {"nf", "mpc", model.stem, f"{model.stem}+shield"}
    assert results["converging-3"][f"{model.stem}+shield"]["shield"]["runs"] == 1
    assert "shield" not in results["converging-3"][model.stem]
    header, _, *rows = benchmark.table(results).splitlines()
    assert "decision p99" in header and "MPC fallbacks" in header
    assert all(row.count("|") == header.count("|") for row in rows)
    shielded_row = next(row for row in rows if "+shield" in row)
    assert " of " in shielded_row.split("|")[-2]


def test_benchmark_writes_its_table_into_a_marked_section(tmp_path):
    from agents import benchmark

    report = tmp_path / "REPORT.md"
    report.write_text("# Report\n\nprose\n\n<!-- begin study -->\nold\n<!-- end study -->\n")
    argv = ["--baselines", "nf", "--scenarios", "converging-3", "--runs", "1", "--workers", "1", "--out",
            str(tmp_path / "runs"), "--summary", str(tmp_path / "s.json"), "--table", str(tmp_path / "t.md"),
            "--write-section", f"{report}#study", "--no-progress"]
    assert benchmark.main(argv) == 0
    text = report.read_text()
    assert "prose" in text and "old" not in text
    assert "Generated by `python -m agents.benchmark --baselines nf" in text and "| converging-3 | nf | 1 |" in text
    with pytest.raises(SystemExit):
        benchmark.main(["--write-section", str(tmp_path / "missing.md")])


def test_the_alternative_applied_is_the_closest_safe_one_of_the_whole_set():
    """The alternatives are predicted one at a time in the order they would be chosen;
    the one applied must be the one a batch prediction of every alternative ranks first."""
    from atc_nf_env.config import SimConfig
    from atc_nf_env.simulation import Simulation

    scenario = make_scenario("converging-4")
    shielded = SafetyFilter(Behind(), fallback="least-bad")
    shielded.reset(scenario, SimConfig(), 0)
    view = Simulation(scenario).view()
    applied = shielded.act(view)
    proposal = shielded.policy.proposals[-1]
    assert shielded.episode_info()["shield_filtered"] == 1
    blamed = shielded._check(view.state, proposal)[2]
    for kind in ("single", "joint"):
        candidates, changed = shielded._alternatives(view, proposal, blamed, kind)
        safe = shielded._predict(view.state, candidates)[0] == shielded._full_steps()
        if safe.any():
            break
    displacement = np.hypot(*(candidates - proposal[None]).transpose(2, 0, 1)).sum(axis=1)
    best = int(np.lexsort((displacement, changed.sum(axis=1), ~safe))[0])
    assert safe[best]
    assert np.array_equal(applied, np.where(changed[best][:, None], candidates[best], proposal))


class Sideways(AimThrough):
    """Aircraft 0 flies at right angles to its line home (holding off); the rest aim home."""

    name = "sideways"

    def act(self, view: WorldView) -> np.ndarray:
        waypoints = super().act(view)
        to_dest = view.destinations[0] - view.positions[0]
        waypoints[0] = view.positions[0] + 100.0 * np.array([-to_dest[1], to_dest[0]]) / np.hypot(*to_dest)
        return waypoints


def test_the_progress_rule_flies_a_holding_aircraft_home():
    scenario = make_scenario("converging-3")
    plain = SafetyFilter(Sideways(), progress_fraction=None, mpc_settings={"extractions": 64})
    off = run_episode(plain, scenario, seed=0, max_time_s=7200).metrics
    assert not off.arrived[0] and plain.episode_info()["shield_stalled_aircraft"] == 0
    ruled = SafetyFilter(Sideways(), mpc_settings={"extractions": 64})  # the rule is on by default
    on = run_episode(ruled, scenario, seed=0, max_time_s=7200).metrics
    info = ruled.episode_info()
    assert info["shield_stalled_aircraft"] >= 1 and info["shield_homing_decisions"] >= 1
    assert on.success and on.los_count == 0 and on.worst_excursion_kt == 0.0
    with pytest.raises(ValueError, match="progress_periods"):
        SafetyFilter(AimThrough(), progress_periods=0)
    for bad in (float("inf"), -0.1, 1.5):
        with pytest.raises(ValueError, match="progress_fraction"):
            SafetyFilter(AimThrough(), progress_fraction=bad)
    with pytest.raises(TypeError):
        SafetyFilter(AimThrough(), stall_progress_nm=0.0)  # the former rule's setting: unknown now


class SampledOnly(SafetyFilter):
    """A filter whose structured tiers offer only the unsafe proposal: the sampled tier
    (or, failing it, the MPC) must settle every intervention."""

    def _alternatives(self, view, planned, blamed, kind):
        if kind == "sampled":
            return super()._alternatives(view, planned, blamed, kind)
        return planned[None].copy(), np.zeros((1, planned.shape[0]), dtype=bool)


def test_the_sampled_tier_settles_what_the_structured_ones_cannot_and_is_seeded():
    scenario = make_scenario("converging-4")
    runs, infos = [], []
    for _ in range(2):
        shielded = SampledOnly(Behind(), mpc_settings={"extractions": 64})
        runs.append(run_episode(shielded, scenario, seed=5, max_time_s=1800))
        infos.append(shielded.episode_info())
    info = infos[0]
    assert info["shield_filtered"] == 6  # Behind is unsafe at every decision
    assert info["shield_sampled_changes"] + info["shield_mpc_fallbacks"] == 6
    assert info["shield_sampled_changes"] >= 1
    assert runs[0].metrics.worst_excursion_kt == 0.0 and runs[0].metrics.los_count == 0
    assert infos[0] == infos[1] and np.array_equal(runs[0].waypoints, runs[1].waypoints)
    # Another seed draws other sampled sets.
    other = SampledOnly(Behind(), mpc_settings={"extractions": 64})
    assert not np.array_equal(run_episode(other, scenario, seed=6, max_time_s=1800).waypoints, runs[0].waypoints)


def test_the_compiled_prediction_is_the_kernels_flight_bit_for_bit():
    """``PlanPredictor`` flies the kernel's own compiled world: its verdict, survived steps,
    blame and positions equal two ``kernel.advance`` calls with the homing waypoints."""
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.shield_prediction import NONE_SAFE, PlanPredictor, _homing_waypoints
    from atc_nf_env.simulation import initial_state

    rng = np.random.default_rng(0)
    for name, seed in (("random-5", 2), ("converging-4", 0), ("random-8", 7)):
        scenario = make_scenario(name, seed=seed)
        config = SimConfig()
        params = config.to_params(scenario.workspace_radius_nm, stop_on_violation=True)
        limit = 0.99 * (scenario.workspace_radius_nm - config.aircraft_radius_nm)
        predictor = PlanPredictor(params, 60, 2, 130.0, np.pi / 3, limit)
        state = initial_state(scenario, 1)[0]
        n = state.shape[0]
        to_dest = state[:, kernel.S_DEST_X : kernel.S_DEST_Y + 1] - state[:, :2]
        bearing = np.arctan2(to_dest[:, 1], to_dest[:, 0])
        angles = bearing[None] + rng.uniform(-1.2, 1.2, (12, n))
        distances = rng.uniform(60.0, 160.0, (12, n))
        candidates = np.ascontiguousarray(state[None, :, :2] + distances[..., None]
                                          * np.stack([np.cos(angles), np.sin(angles)], axis=-1))
        wind = rng.normal(0.0, 10.0, 2)
        first = predictor.first_safe(state, candidates, wind)
        for m, candidate in enumerate(candidates):
            world = state[None].copy()
            trace = kernel.advance(world, candidate[None], wind[None], 300.0, params, scratch=kernel.KernelScratch())
            survived = int(trace.steps_done[0]) - 1 if trace.violated[0] else None
            blamed = (trace.violation_steps[0] > 0) | trace.los_pairs[0].any(axis=1)
            after_first = world[0, :, :2].copy()
            if survived is None and (world[0, :, kernel.S_STATUS] == kernel.FLYING).any():
                home = np.empty((n, 2))
                _homing_waypoints(world[0], candidate, 130.0, np.pi / 3, limit, home)
                trace = kernel.advance(world, home[None], wind[None], 300.0, params, scratch=kernel.KernelScratch())
                if trace.violated[0]:
                    survived = 60 + int(trace.steps_done[0]) - 1
                    blamed = (trace.violation_steps[0] > 0) | trace.los_pairs[0].any(axis=1)
            if survived is None:
                assert first == m and predictor.survived[m] == 120
                assert np.array_equal(predictor.positions, after_first)
                break
            assert predictor.survived[m] == survived and np.array_equal(predictor.blamed[m], blamed)
        else:
            assert first == NONE_SAFE
        assert (predictor.survived[first + 1 if first >= 0 else len(candidates):len(candidates)] == -1).all()


def test_the_compiled_prediction_refuses_what_it_cannot_fly():
    """Its compiled flight reads inputs unchecked: every wrong shape, dtype, layout or
    non-finite value is refused with a ValueError naming the input before anything flies."""
    from atc_nf_env.config import SimConfig
    from atc_nf_env.shield_prediction import PlanPredictor
    from atc_nf_env.simulation import initial_state

    scenario = make_scenario("converging-4")
    params = SimConfig().to_params(scenario.workspace_radius_nm, stop_on_violation=True)
    predictor = PlanPredictor(params, 60, 2, 130.0, 1.0, 300.0)
    state = initial_state(scenario, 1)[0]
    good = np.ascontiguousarray(state[None, :, 5:7])
    wind = np.zeros(2)
    assert predictor.first_safe(state, good, wind) in (0, -1)
    nan_wind = np.array([np.nan, 0.0])
    bad_state = state.copy()
    bad_state[1, 0] = np.inf
    for args, match in (
        ((state, good[:, :3].copy(), wind), "candidates has shape"),
        ((state, good.astype(np.float32), wind), "candidates is ndarray"),
        ((state, good[0], wind), "candidates is ndarray"),
        ((state, np.zeros((0, 4, 2)), wind), "candidates has shape"),
        ((state[:, :5].copy(), good, wind), "state has shape"),
        ((state.T, good, wind), "state is ndarray"),
        ((state, good, np.zeros(3)), "wind_kt has shape"),
        ((state, good, nan_wind), "wind_kt contains NaN"),
        ((bad_state, good, wind), "state contains NaN or inf"),
        ((state, good.tolist(), wind), "candidates is list"),
    ):
        with pytest.raises(ValueError, match=match):
            predictor.first_safe(*args)
    with pytest.raises(ValueError, match="stop_on_violation"):
        PlanPredictor(SimConfig().to_params(scenario.workspace_radius_nm), 60, 2, 130.0, 1.0, 300.0)
    for kwargs, match in (({"lookahead_periods": 3}, "lookahead_periods"), ({"period_steps": 0}, "period_steps"),
                          ({"limit_nm": float("nan")}, "limit_nm"), ({"max_turn_rad": -1.0}, "max_turn_rad")):
        settings = {"period_steps": 60, "lookahead_periods": 2, "home_distance_nm": 130.0, "max_turn_rad": 1.0,
                    "limit_nm": 300.0, **kwargs}
        with pytest.raises(ValueError, match=match):
            PlanPredictor(params, **settings)


def test_the_benchmark_tells_breaches_the_filter_gave_up_on_from_those_it_missed(tmp_path):
    """``shield.breached_runs`` over a shielded study's runs (as ``agents.benchmark`` and the
    summaries count them): a run with a breach counts as given up when the filter applied
    a decision it predicted unsafe."""
    from atc_nf_env.evaluate import read_results
    from atc_nf_env.shield import breached_runs

    def breaches_after_unresolved(path):
        return breached_runs(read_results(path)[1])

    path = tmp_path / "runs.jsonl"
    evaluate(Study(policy="nf", scenario="converging-3", max_time_s=600.0, shield=True), 2, out=path, workers=1,
             progress=False)
    lines = path.read_text().splitlines()
    header, runs = lines[0], [json.loads(line) for line in lines[1:]]
    assert breaches_after_unresolved(path)["runs_breached"] == sum(
        r["envelope_violation_fraction"] > 0 or r["los_count"] > 0 for r in runs)
    # Make run 0 a breach with two unresolved decisions, run 1 a breach the filter missed.
    runs[0]["envelope_violation_fraction"], runs[0]["policy_info"]["shield_unresolved"] = 0.01, 2
    runs[1]["los_count"], runs[1]["policy_info"]["shield_unresolved"] = 1, 0
    path.write_text("\n".join([header, *(json.dumps(r) for r in runs)]) + "\n")
    assert breaches_after_unresolved(path) == {
        "runs_breached": 2, "runs_breached_after_unresolved": 1, "unresolved_per_breached_run": [0, 2]}



@settings(max_examples=20, deadline=None)
@given(
    scenario=st.sampled_from(["converging-3", "random-4", "random-6"]),
    seed=st.integers(0, 10_000),
    n_candidates=st.integers(1, 6),
    spread=st.floats(0.0, 1.5),
    wind=st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0)),
)
def test_first_safe_of_a_batch_is_the_first_candidate_safe_alone(scenario, seed, n_candidates, spread, wind):
    """Flying candidates in order until the first safe one picks what flying each alone
    would, and reports each flown candidate's survival as it alone would: no state leaks
    from one candidate's flight into the next."""
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.shield_prediction import NONE_SAFE, PlanPredictor
    from atc_nf_env.simulation import initial_state

    sc = make_scenario(scenario, seed=seed)
    params = SimConfig().to_params(sc.workspace_radius_nm, stop_on_violation=True)
    predictor = PlanPredictor(params, 60, 2, 130.0, np.pi / 3, 0.99 * (sc.workspace_radius_nm - 2.5))
    state = initial_state(sc, 1)[0]
    rng = np.random.default_rng(seed)
    to_dest = state[:, kernel.S_DEST_X : kernel.S_DEST_Y + 1] - state[:, :2]
    angles = np.arctan2(to_dest[:, 1], to_dest[:, 0])[None] + rng.uniform(-spread, spread, (n_candidates, len(state)))
    distances = rng.uniform(80.0, 150.0, (n_candidates, len(state)))
    candidates = np.ascontiguousarray(
        state[None, :, :2] + distances[..., None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1))
    wind_kt = np.array(wind)
    first = predictor.first_safe(state, candidates, wind_kt)
    batch_survived, batch_blamed = predictor.survived[:n_candidates].copy(), predictor.blamed[:n_candidates].copy()
    alone = []
    for candidate in candidates:
        index = predictor.first_safe(state, np.ascontiguousarray(candidate[None]), wind_kt)
        alone.append((index == 0, int(predictor.survived[0]), predictor.blamed[0].copy()))
    expected = next((m for m, (safe, _, _) in enumerate(alone) if safe), NONE_SAFE)
    assert first == expected
    for m in range(n_candidates if first == NONE_SAFE else first + 1):
        assert batch_survived[m] == alone[m][1]
        if not alone[m][0]:
            assert np.array_equal(batch_blamed[m], alone[m][2])


def _screen_setup(n_aircraft: int = 3, progress_periods: int = 2):
    from atc_nf_env.config import SimConfig
    from atc_nf_env.kernel import S_TIME
    from atc_nf_env.shield_prediction import DecisionMemory, PlanPredictor
    from atc_nf_env.simulation import initial_state

    scenario = make_scenario(f"converging-{n_aircraft}")
    config = SimConfig()
    params = config.to_params(scenario.workspace_radius_nm, stop_on_violation=True)
    predictor = PlanPredictor(params, 60, 2, 130.0, np.pi / 3, 240.0)
    state = np.ascontiguousarray(initial_state(scenario)[0])
    state[:, S_TIME] = 7200.0  # flown for longer than any window here, as a flight at these times would be
    to_dest = scenario.dest_xy - state[:, :2]
    proposal = state[:, :2] + 100.0 * to_dest / np.hypot(*to_dest.T)[:, None]
    return predictor, DecisionMemory(n_aircraft, progress_periods), state, np.ascontiguousarray(proposal)


def test_the_screen_corrects_the_wind_estimate_by_the_mean_drift_exactly():
    from atc_nf_env.shield_prediction import SCREEN_SAFE

    predictor, memory, state, proposal = _screen_setup()
    memory.wind_kt[:] = (3.0, -1.5)
    drift = np.array([[1.25, -0.5], [0.75, 2.0], [40.0, 40.0]])
    memory.remember(600.0, state[:, :2] - drift, np.array([True, True, False]))  # the third was not flying
    assert predictor.screen(state, proposal, 600.0, 300.0, memory, None) == SCREEN_SAFE
    hours = 300.0 / 3600.0
    expected = np.array([3.0, -1.5]) + np.array([1.25 + 0.75, -0.5 + 2.0]) / 2 / hours
    assert np.array_equal(memory.wind_kt, expected)  # bit for bit: the same operations in the same order
    # A decision at another time than the prediction's leaves the estimate alone.
    before = memory.wind_kt.copy()
    memory.remember(900.0, state[:, :2] - drift, np.ones(3, dtype=bool))
    predictor.screen(state, proposal, 1200.0, 300.0, memory, None)
    assert np.array_equal(memory.wind_kt, before)


def test_the_screen_hands_over_an_aircraft_no_closer_to_home_after_the_window():
    from atc_nf_env.kernel import S_DEST_X, S_X
    from atc_nf_env.shield_prediction import SCREEN_HOMED, SCREEN_SAFE

    predictor, memory, state, proposal = _screen_setup(progress_periods=2)
    verdicts = []
    for k in range(3):  # aircraft 0 drifting away from home, the others closing in
        moved = state.copy()
        moved[:, S_X] += 10.0 * k * np.sign(moved[:, S_DEST_X] - moved[:, S_X]) * np.array([-0.1, 1.0, 1.0])
        verdicts.append(predictor.screen(moved, proposal, 300.0 * k, 300.0, memory, 0.0))
    assert verdicts == [SCREEN_SAFE, SCREEN_SAFE, SCREEN_HOMED]
    assert memory.homebound.tolist() == [True, False, False] and memory.counts[1] == 1
    # A gap of more than one period restarts the window: no aircraft is handed over again.
    fresh = _screen_setup(progress_periods=2)[1]
    times = (0.0, 300.0, 900.0, 1200.0)
    assert [predictor.screen(state, proposal, t, 300.0, fresh, 0.0) for t in times][-1] == SCREEN_SAFE
    assert not fresh.homebound.any() and fresh.counts[1] == 0


def test_the_progress_rule_asks_its_share_far_out_and_arrival_close_in():
    """30 nm asked over the window, arrival within 5 nm: far out an aircraft must close
    30 nm (250 → 220 passes, 250 → 225 is handed over); one that started the window within
    30 + 5 nm of home must arrive (20 → 6 nm, still flying, is handed over), while one 40 nm
    out may close its 30 nm (40 → 10 passes)."""
    from atc_nf_env.kernel import S_DEST_X, S_DEST_Y, S_X, S_Y

    predictor, memory, state, proposal = _screen_setup(n_aircraft=4, progress_periods=2)
    start, end = np.array([250.0, 250.0, 20.0, 40.0]), np.array([220.0, 225.0, 6.0, 10.0])
    for k in range(3):
        moved = state.copy()
        moved[:, S_X] = moved[:, S_DEST_X] + start + (end - start) * k / 2
        moved[:, S_Y] = moved[:, S_DEST_Y]
        predictor.screen(moved, proposal, 300.0 * k, 300.0, memory, 30.0, 5.0)
    assert memory.homebound.tolist() == [False, True, True, False] and memory.counts[1] == 2


class _PythonMemory:
    """The filter's wind estimate and progress rule as Python computed them before they moved
    into ``PlanPredictor.screen`` (the reference ``screen`` must match bit for bit), with
    the clean start of a stream slot's new flight."""

    def __init__(self, n: int, progress_periods: int, period_s: float, progress_nm: float,
                 arrival_nm: float = 0.0) -> None:
        self.wind = np.zeros(2)
        self.predicted = None
        self.predicted_flying = None
        self.predicted_time = -1.0
        self.history: list = []
        self.homebound = [False] * n
        self.stalled = 0
        self.progress_periods, self.period_s, self.progress = progress_periods, period_s, progress_nm
        self.arrival = arrival_nm

    def decide(self, state: np.ndarray, time_s: float) -> bool:
        """The old bookkeeping of one decision; returns whether an aircraft is handed over."""
        import math

        from atc_nf_env.kernel import FLYING, S_DEST_X, S_DEST_Y, S_STATUS, S_TIME, S_X, S_Y

        rows = state.tolist()
        flying = [row[S_STATUS] == FLYING for row in rows]
        if self.predicted is not None and abs(time_s - self.predicted_time) <= 1e-6:
            dx = dy = 0.0
            count = 0
            for row, now, predicted, then in zip(rows, flying, self.predicted, self.predicted_flying):
                if now and then and row[S_TIME] >= self.period_s - 1e-6:  # flew the whole period
                    dx += row[S_X] - predicted[0]
                    dy += row[S_Y] - predicted[1]
                    count += 1
            if count:
                self.wind = self.wind + np.array([dx, dy]) / count / (self.period_s / 3600.0)
            self.predicted = None
        for i, row in enumerate(rows):  # a hand-over ends with its flight (a stream reuses the slot)
            if not flying[i] or row[S_TIME] < self.period_s - 1e-6:
                self.homebound[i] = False
        if not any(flying):
            return False
        distances = [math.hypot(r[S_DEST_X] - r[S_X], r[S_DEST_Y] - r[S_Y]) for r in rows]
        if self.history and abs(time_s - self.history[-1][0] - self.period_s) > 1e-6:
            self.history.clear()
        self.history.append((time_s, distances))
        if len(self.history) > self.progress_periods:
            then_time, then = self.history.pop(0)
            for i, (now, before) in enumerate(zip(distances, then)):
                asked = min(self.progress, before - self.arrival)  # arrival asked within the ask of home
                whole = rows[i][S_TIME] >= time_s - then_time - 1e-6  # flew the whole window
                if flying[i] and not self.homebound[i] and whole and now > before - asked:
                    self.homebound[i] = True
                    self.stalled += 1
        return any(bound and flying[i] for i, bound in enumerate(self.homebound))


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(2, 5),
    seed=st.integers(0, 2**31 - 1),
    progress_periods=st.integers(1, 4),
    gaps=st.lists(st.sampled_from([300.0, 300.0, 300.0, 600.0, 450.0]), min_size=3, max_size=9),
    asked=st.sampled_from([(0.0, 0.0), (30.0, 5.0), (60.0, 5.0)]),
)
def test_the_compiled_screen_keeps_the_wind_estimate_and_progress_rule_of_the_python_reference(
    n, seed, progress_periods, gaps, asked
):
    """Random decision sequences (aircraft wandering, arriving, slots taking new flights,
    decisions off the period grid, predictions remembered or not): ``PlanPredictor.screen`` updates the wind estimate
    and hands aircraft over exactly as the filter's former Python did."""
    from atc_nf_env.kernel import ARRIVED, S_STATUS, S_TIME, S_X, S_Y
    from atc_nf_env.shield_prediction import SCREEN_HOMED, SCREEN_NONE_FLYING, SCREEN_SAFE, DecisionMemory

    predictor, _, state, proposal = _screen_setup(n_aircraft=n, progress_periods=progress_periods)
    memory = DecisionMemory(n, progress_periods)
    reference = _PythonMemory(n, progress_periods, 300.0, *asked)
    rng = np.random.default_rng(seed)
    time_s = 0.0
    for gap in gaps:
        state = state.copy()
        state[:, S_X] += rng.normal(0.0, 20.0, n)
        state[:, S_Y] += rng.normal(0.0, 20.0, n)
        state[rng.uniform(size=n) < 0.1, S_STATUS] = ARRIVED
        state[:, S_TIME] += gap
        state[rng.uniform(size=n) < 0.15, S_TIME] = rng.choice([0.0, 150.0, 600.0])  # a stream slot's new flight
        if rng.uniform() < 0.7:  # a prediction remembered for this decision (or another time)
            when = time_s if rng.uniform() < 0.8 else time_s + 1.0
            positions = state[:, S_X : S_Y + 1] + rng.normal(0.0, 2.0, (n, 2))
            alive = rng.uniform(size=n) < 0.9
            memory.remember(when, positions, alive)
            reference.predicted, reference.predicted_flying = positions.tolist(), alive.tolist()
            reference.predicted_time = when
        handed = reference.decide(state, time_s)
        verdict = predictor.screen(np.ascontiguousarray(state), proposal, time_s, 300.0, memory, *asked)
        assert np.array_equal(memory.wind_kt, reference.wind)
        assert memory.homebound.tolist() == reference.homebound and memory.counts[1] == reference.stalled
        assert (verdict == SCREEN_HOMED) == handed
        assert (verdict == SCREEN_NONE_FLYING) == (not (state[:, S_STATUS] == 0.0).any())
        if verdict == SCREEN_SAFE:  # the filter remembered its prediction, as before
            reference.predicted = predictor.positions.tolist()
            reference.predicted_flying = predictor.alive.tolist()
            reference.predicted_time = time_s + 300.0
        time_s += gap


def test_reset_loads_every_compiled_entry_of_a_change():
    """The first decision the filter changes runs no numba cache load (about 25 ms, once
    inside a timed run): ``reset`` has loaded the alternatives and their prediction. In a
    fresh interpreter, where nothing was loaded before."""
    import subprocess
    import sys

    code = (
        "from atc_nf_env import shield_prediction as sp\n"
        "from atc_nf_env.config import SimConfig\n"
        "from atc_nf_env.policy import make_policy\n"
        "from atc_nf_env.scenarios import make_scenario\n"
        "from atc_nf_env.shield import SafetyFilter\n"
        "assert not sp._first_safe.signatures\n"
        "SafetyFilter(make_policy('nf'), fallback='least-bad').reset(make_scenario('converging-4'), SimConfig(), 0)\n"
        "print(len(sp._first_safe.signatures), len(sp._structured_alternatives.signatures))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    first_safe, alternatives = (int(x) for x in out.stdout.split())
    assert first_safe >= 1 and alternatives >= 1


def test_a_slot_that_takes_a_new_flight_starts_with_a_clean_memory() -> None:
    """In a traffic stream a slot emptied by an arrival takes the next flight (time flown 0):
    the progress rule's hand-over ends with the old flight, the new one is judged only over
    a window it flew whole, and its position is never read as the old one's drift (wind)."""
    from atc_nf_env.config import SimConfig
    from atc_nf_env.kernel import S_TIME, S_X
    from atc_nf_env.shield_prediction import SCREEN_HOMED, DecisionMemory, PlanPredictor
    from atc_nf_env.simulation import initial_state

    scenario = make_scenario("converging-4")
    params = SimConfig().to_params(scenario.workspace_radius_nm, stop_on_violation=True)
    predictor = PlanPredictor(params, 60, 2, 130.0, 1.0, 300.0)
    state = np.ascontiguousarray(initial_state(scenario, 1)[0])
    proposal = np.ascontiguousarray(state[:, 8:10])  # aim home
    periods = 3
    for new_flight in (False, True):
        memory = DecisionMemory(4, periods)
        old = state.copy()
        old[:, S_TIME] = 3600.0
        # A full window in which slot 0 made no progress, and a prediction of where it would be.
        for row in range(periods):
            memory.history_time[row] = 2700.0 + 300.0 * row
            memory.distances[row] = np.hypot(*(old[:, 8:10] - old[:, 0:2]).T)
        memory.counts[0] = periods
        memory.predicted[:] = old[:, 0:2]
        memory.predicted_alive[:] = True
        memory.timing[:] = (1.0, 3600.0)
        now = old.copy()
        if new_flight:
            now[0, S_TIME] = 0.0  # slot 0: a flight that entered at this instant, 300 nm away
            now[0, S_X] += 300.0
        verdict = predictor.screen(now, proposal, 3600.0, 300.0, memory, 20.0, 5.0)
        assert verdict == SCREEN_HOMED and memory.homebound[1:].all()  # the others made no progress
        assert memory.homebound[0] == (not new_flight)
        assert np.array_equal(memory.wind_kt, np.zeros(2))  # the others flew where predicted
    # A slot handed over keeps its hand-over while its flight flies, and loses it with the flight.
    memory.homebound[:] = True
    now[0, S_TIME] = 0.0
    predictor.screen(now, proposal, 3900.0, 300.0, memory, 20.0, 5.0)
    assert not memory.homebound[0] and memory.homebound[1:].all()
