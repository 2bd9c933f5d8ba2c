"""What a user reads: per-run safety in summaries, warm timings with the warm-up apart,
policies found by name through the registry, and the command line's help and refusals."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from atc_nf_env import evaluate as evaluate_module
from atc_nf_env.cli import main
from atc_nf_env.episode import run_episode, warm_up
from atc_nf_env.evaluate import Study, evaluate, run_one
from atc_nf_env.metrics import RunMetrics, summarize, wilson_interval
from atc_nf_env.policy import available_policies, make_policy, register_policy
from atc_nf_env.scenarios import make_scenario
from baselines import MCMCMPC, NFDirect

# --------------------------------------------------------------------------- per-run safety


def _run(**changes) -> RunMetrics:
    base = RunMetrics(
        scenario="converging-3", seed=0, n_aircraft=2, wind_kt=[0.0, 0.0], arrived=[True, True],
        left_workspace=[False, False], flight_time_min=[60.0, 62.0], path_length_nm=[450.0, 460.0],
        success=True, min_separation_nm=12.0, los_count=0, envelope_violation_fraction=0.0,
        worst_excursion_kt=0.0, airspeed_min_kt=400.0, airspeed_max_kt=480.0, steps_flown=1000,
        sim_time_min=62.0, wall_s=0.5, decisions=13, decision_s_mean=0.03,
    )
    return replace(base, **changes)


def test_summary_counts_safety_per_run() -> None:
    runs = [
        _run(),
        _run(seed=1, envelope_violation_fraction=0.001, worst_excursion_kt=12.5, airspeed_max_kt=552.5),
        _run(seed=2, envelope_violation_fraction=0.02, worst_excursion_kt=960.0, airspeed_max_kt=1500.0,
             airspeed_min_kt=-30.0),
        _run(seed=3, los_count=2, min_separation_nm=3.5, success=False, arrived=[True, False]),
        _run(seed=4, airspeed_min_kt=-1500.0, envelope_violation_fraction=0.01, worst_excursion_kt=1866.0),
    ]
    s = summarize(runs, compile_s=1.25)
    assert s["runs_with_envelope_violation"] == 3
    assert s["runs_at_airspeed_cap"] == 2  # +1500 in one run, -1500 in another
    assert s["worst_envelope_excursion_kt"] == 1866.0
    assert s["runs_with_los"] == 1
    assert s["min_separation_nm"]["min"] == 3.5
    assert s["success_rate"] == 0.8
    low, high = s["success_rate_ci95"]
    assert low < 0.8 < high and s["success_rate_ci95_method"] == "Wilson score"
    assert s["compile_s"] == 1.25
    assert "compile_s" in s["timing_note"] and "warm" in s["timing_note"]


def test_summary_counts_the_cap_of_the_config_it_is_given() -> None:
    runs = [_run(airspeed_max_kt=900.0)]
    assert summarize(runs)["runs_at_airspeed_cap"] == 0
    assert summarize(runs, airspeed_cap_kt=900.0)["runs_at_airspeed_cap"] == 1


@pytest.mark.parametrize(
    "successes, trials, low, high",
    [
        (300, 300, 0.98735, 1.0),  # the "100 %" of 300 runs is at least 98.7 %
        (0, 10, 0.0, 0.27753),
        (5, 10, 0.23659, 0.76341),
        (1, 1, 0.20655, 1.0),
    ],
)
def test_wilson_interval_matches_reference_values(successes, trials, low, high) -> None:
    got = wilson_interval(successes, trials)
    assert got == pytest.approx((low, high), abs=5e-5)


@given(st.integers(1, 100_000).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))))
def test_wilson_interval_holds_the_rate_and_narrows_with_more_runs(counts) -> None:
    successes, trials = counts
    low, high = wilson_interval(successes, trials)
    assert 0.0 <= low <= successes / trials <= high <= 1.0
    assert (low == 0.0) == (successes == 0) and (high == 1.0) == (successes == trials)
    more_low, more_high = wilson_interval(successes * 4, trials * 4)
    assert more_high - more_low <= high - low + 1e-12


@pytest.mark.parametrize("successes, trials", [(3, 2), (-1, 5), (0, 0)])
def test_wilson_interval_rejects_impossible_counts(successes, trials) -> None:
    with pytest.raises(ValueError, match="successes <= trials"):
        wilson_interval(successes, trials)


# --------------------------------------------------------------------------- warm timings


def test_warm_up_changes_no_result() -> None:
    scenario = make_scenario("converging-3")
    cold = run_episode(MCMCMPC(extractions=40), scenario, seed=3)
    policy = MCMCMPC(extractions=40)
    assert warm_up(policy, scenario, seed=3) > 0
    warm = run_episode(policy, scenario, seed=3)
    a, b = cold.metrics.to_dict(), warm.metrics.to_dict()
    for timing in ("wall_s", "decision_s_mean"):
        a.pop(timing), b.pop(timing)
    assert a == b
    np.testing.assert_array_equal(cold.waypoints, warm.waypoints)


def test_evaluator_warms_up_once_per_process_and_reports_it_apart(monkeypatch) -> None:
    monkeypatch.setattr(evaluate_module, "_warmed_up", set())
    study = Study(policy="mpc", scenario="converging-3", policy_kwargs={"extractions": 30})
    first, second = run_one(study, 0), run_one(study, 1)
    assert first["compile_s"] > 0 and second["compile_s"] == 0.0
    summary = evaluate_module.summarize_records([first, second])
    assert summary["compile_s"] == first["compile_s"]
    # An older results file without the field still summarizes.
    old = {k: v for k, v in second.items() if k != "compile_s"}
    assert evaluate_module.summarize_records([old])["compile_s"] is None


# --------------------------------------------------------------------------- the policy registry


class _Straight:
    """A third-party policy: every aircraft aims at its destination (the NF alone)."""

    name = "straight"

    def __init__(self, *, gain: float = 1.0) -> None:
        self.gain = gain

    def reset(self, scenario, config, seed=None) -> None:
        self._destinations = scenario.dest_xy

    def act(self, view) -> np.ndarray:
        return self._destinations.copy()


def test_a_registered_policy_is_found_by_name_and_takes_its_settings() -> None:
    register_policy("straight-for-test", _Straight)
    assert "straight-for-test" in available_policies()
    assert make_policy("straight-for-test", gain=2.0).gain == 2.0
    with pytest.raises(ValueError, match="does not take the settings"):
        make_policy("straight-for-test", horizon=3)
    summary = evaluate(Study(policy="straight-for-test", scenario="converging-3"), 2, workers=1, progress=False)
    assert summary["runs"] == 2
    assert "fallbacks" not in summary  # only policies that can fall back report it


def test_installed_policies_come_from_entry_points() -> None:
    assert {"nf", "mpc"} <= set(available_policies())
    assert isinstance(make_policy("nf"), NFDirect)
    assert isinstance(make_policy("mpc", horizon=2), MCMCMPC)


@pytest.mark.parametrize("name", ["", "a.zip"])
def test_register_policy_rejects_bad_names(name: str) -> None:
    with pytest.raises(ValueError, match="policy name"):
        register_policy(name, _Straight)


def test_unknown_policy_names_the_allowed_ones() -> None:
    with pytest.raises(ValueError, match=r"allowed: .*mpc.*nf.*\.zip"):
        make_policy("greedy")


def test_the_core_package_does_not_import_the_packages_built_on_it() -> None:
    code = (
        "import sys, atc_nf_env.evaluate, atc_nf_env.cli;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('agents', 'baselines')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# --------------------------------------------------------------------------- the command line


@pytest.mark.parametrize("command", ["fly", "evaluate", "reproduce"])
def test_subcommand_help_names_the_subcommand_and_shows_defaults(command, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert text.startswith(f"usage: atc-nf {command}")
    assert "(default: None)" not in text
    if command == "reproduce":
        assert "(default: 1000)" in text
    else:
        assert "(default: mpc)" in text and "(default: 0)" in text and "(default: 240.0)" in text


def test_evaluate_refuses_an_output_in_a_missing_folder(tmp_path, capsys) -> None:
    target = tmp_path / "no" / "such" / "r.jsonl"
    assert main(["evaluate", "--runs", "1", "--out", str(target), "--no-progress"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()


def test_evaluate_refusal_to_overwrite_names_the_flag(tmp_path, capsys) -> None:
    out = tmp_path / "r.jsonl"
    args = ["evaluate", "--policy", "nf", "--scenario", "converging-3", "--runs", "1", "--workers", "1",
            "--out", str(out), "--no-progress"]
    assert main(args) == 0
    capsys.readouterr()
    assert main(args) == 2
    assert "--resume" in capsys.readouterr().err


def test_fly_summary_has_fallbacks_once_and_only_for_the_mpc(tmp_path, capsys) -> None:
    summaries = {}
    for policy in ("nf", "mpc"):
        path = tmp_path / f"{policy}.json"
        extra = ["--extractions", "30"] if policy == "mpc" else []
        assert main(["fly", "--policy", policy, "--scenario", "converging-3", "--max-minutes", "20",
                     "--summary-json", str(path), *extra]) == 0
        summaries[policy] = json.loads(path.read_text())
    assert "fallbacks" not in summaries["nf"]
    assert isinstance(summaries["mpc"]["fallbacks"], int)
    assert "fallbacks" not in summaries["mpc"]["policy_info"]
    for s in summaries.values():
        assert s["compile_s"] > 0 and s["wall_s_per_run"]["mean"] > 0
    assert "warm-up before it (compiling or loading the simulator" in capsys.readouterr().out


def test_bare_fly_flies_the_reference_mpc(capsys, monkeypatch) -> None:
    made = []
    original = make_policy

    def spy(spec, **settings):
        made.append(spec)
        return original(spec, **settings)

    monkeypatch.setattr("atc_nf_env.cli.make_policy", spy)
    assert main(["fly", "--scenario", "converging-3", "--max-minutes", "5", "--extractions", "20"]) == 0
    assert made == ["mpc"]


def test_without_the_package_installed_the_error_says_how_to_install(monkeypatch) -> None:
    import atc_nf_env.policy as policy_module

    monkeypatch.setattr(policy_module, "_entry_points", lambda group: {})
    with pytest.raises(ValueError, match="pip install -e"):
        make_policy("mpc")
