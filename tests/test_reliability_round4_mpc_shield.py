"""Round 4 of the reliability attacks on the MCMC-MPC and the safety filter: the MPC's wind
estimate after a fallback that breaks a constraint in its first period, the filter's
fallback on traffic streams from the command line, the summaries' breach counts, and what
each command takes."""

from __future__ import annotations

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import episode_wind_kt
from atc_nf_env.scenarios import scenario_from_dict
from atc_nf_env.simulation import Simulation
from atc_nf_env.units import WIND_SIGMA_MPS
from baselines import MCMCMPC

#: Two aircraft side by side, 6 nm apart, flying east: every candidate of the first
#: decision breaks a constraint in its first period (the NF pushes them apart).
SIDE_BY_SIDE = {"aircraft": [{"start": [-250, 0], "destination": [250, 0]},
                             {"start": [-250, 6], "destination": [250, 6]}]}
SIDE_BY_SIDE_SEED = 8_100_000_000


def test_wind_estimate_after_a_fallback_breaching_in_its_first_period_is_the_drift_flown():
    """The applied fallback's prediction stops at its breach; the aircraft fly on. The
    estimate after one period must come from a whole period's prediction: within a few kt
    of the true wind (15.8, -14.2) kt, where the stopped prediction gave (545.0, 71.2)."""
    scenario = scenario_from_dict(SIDE_BY_SIDE)
    config = SimConfig()
    true_wind = episode_wind_kt(SIDE_BY_SIDE_SEED, WIND_SIGMA_MPS)
    sim = Simulation(scenario, config, wind_kt=true_wind)
    mpc = MCMCMPC()
    mpc.reset(scenario, config, SIDE_BY_SIDE_SEED)
    waypoints = mpc.act(sim.view())
    first = mpc.decisions[0]
    # The case the test is about: a fallback whose applied candidate breaks in period 1.
    assert first.fallback and first.applied_breach_predicted
    sim.advance(waypoints, mpc.settings.period_s)
    mpc.act(sim.view())
    estimate = np.array(mpc.episode_info()["wind_estimate_kt"])
    assert np.hypot(*(estimate - true_wind)) < 5.0, (estimate, true_wind)


# -- item 18: the filter's fallback on streams, and the MPC's settings for it from the CLI --
def test_the_filter_falls_back_on_the_per_cluster_mpc_on_streams_and_on_the_defaults_elsewhere():
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.shield import STREAM_FALLBACK_MPC_SETTINGS, SafetyFilter

    shielded = SafetyFilter(make_policy("nf-leg"))
    stream = shielded.fallback_for(make_scenario("stream-30", seed=1)).settings
    # What BENCHMARKS' shielded-streams table flew (bench/mpc_dense_study.py "per-cluster").
    assert (stream.sampling, stream.progress_fraction, stream.progress_periods) == ("per-cluster", 0.5, 6)
    assert dict(STREAM_FALLBACK_MPC_SETTINGS) == {"sampling": "per-cluster", "progress_fraction": 0.5,
                                                  "progress_periods": 6}
    converging_4 = make_scenario("converging-4")
    encounter = shielded.fallback_for(converging_4).settings.for_traffic(converging_4)
    assert (encounter.sampling, encounter.progress_fraction) == ("joint", None)
    # The MPC's own default picks its search by the traffic: per cluster above 6 aircraft.
    random_12 = make_scenario("random-12", seed=3)
    dense = shielded.fallback_for(random_12).settings.for_traffic(random_12)
    assert (dense.sampling, dense.progress_fraction, dense.progress_periods) == ("per-cluster", 0.5, 6)
    # Settings given go over either default; the stream's own can be overridden.
    given = SafetyFilter(make_policy("nf"), mpc_settings={"extractions": 200, "sampling": "joint",
                                                            "progress_fraction": None})
    assert given.fallback_for(make_scenario("stream-30", seed=1)).settings.sampling == "joint"
    assert given.fallback_for(make_scenario("stream-30", seed=1)).settings.extractions == 200
    assert SafetyFilter(make_policy("nf"), mpc_settings={"extractions": 200}).fallback_for(
        make_scenario("stream-30", seed=1)).settings.sampling == "per-cluster"
    # reset() flies the fallback of the scenario's kind.
    from atc_nf_env.config import SimConfig

    shielded.reset(make_scenario("stream-30", seed=1), SimConfig(), 1)
    assert shielded._fallback_policy.settings.sampling == "per-cluster"
    shielded.reset(make_scenario("converging-4"), SimConfig(), 1)
    assert shielded._fallback_policy.settings.sampling == "joint"


def test_the_cli_gives_the_mpc_options_to_the_filter_s_fallback(tmp_path):
    """``evaluate --policy nf-leg --shield --extractions 200`` on a stream: the option
    reaches the fallback (the header says so), over the stream's per-cluster default."""
    from atc_nf_env import cli
    from atc_nf_env.evaluate import read_results

    out = tmp_path / "runs.jsonl"
    status = cli.main(["evaluate", "--policy", "nf-leg", "--scenario", "stream-30-60min", "--shield",
                       "--extractions", "200", "--runs", "1", "--workers", "1", "--max-minutes", "10",
                       "--out", str(out), "--no-progress"])
    assert status == 0
    header, runs = read_results(out)
    assert header["shield_kwargs"] == {"mpc_settings": {"extractions": 200}}
    assert len(runs) == 1
    args = cli.build_parser("evaluate").parse_args(
        ["evaluate", "--policy", "nf-leg", "--scenario", "stream-30", "--shield", "--extractions", "200"])
    from atc_nf_env.evaluate import Study
    from atc_nf_env.scenarios import make_scenario

    study = Study(policy="nf-leg", scenario="stream-30", shield=True, shield_kwargs=cli._shield_kwargs(args))
    fallback = study.make_policy().fallback_for(make_scenario("stream-30", seed=0)).settings
    assert (fallback.extractions, fallback.sampling) == (200, "per-cluster")


def test_mpc_options_without_mpc_or_shield_and_a_stream_fallback_that_cannot_fly_are_one_line_errors(capsys):
    from atc_nf_env import cli

    assert cli.main(["fly", "--policy", "nf", "--extractions", "200"]) == 2
    err = capsys.readouterr().err
    assert "--extractions applies to --policy mpc, or with --shield" in err and len(err.strip().splitlines()) == 1
    # Table I's proposal does not go with the per-cluster search of the stream's fallback.
    for command in ("fly", "evaluate"):
        assert cli.main([command, "--policy", "nf-leg", "--scenario", "stream-30", "--shield",
                         "--proposal", "paper", "--runs" if command == "evaluate" else "--seed", "1"]) == 2
        err = capsys.readouterr().err
        assert "per-cluster" in err and "sampling='joint'" in err and len(err.strip().splitlines()) == 1


# -- item 9: the summaries count the runs that breached inside the filter ----------------
def test_a_shielded_summary_counts_the_runs_that_breached(tmp_path, capsys):
    """``evaluate --shield --summary-json``: the ``shield`` summary has ``runs_breached``,
    as docs/safety_filter.md says. Side by side 6 nm apart, the NF's barrier leaves the
    envelope whatever the filter does."""
    import json

    from atc_nf_env import cli

    scenario = tmp_path / "side.json"
    scenario.write_text(json.dumps(SIDE_BY_SIDE))
    summary_path = tmp_path / "summary.json"
    assert cli.main(["evaluate", "--policy", "nf", "--scenario", str(scenario), "--shield", "--runs", "1",
                     "--workers", "1", "--summary-json", str(summary_path),
                     "--no-progress"]) == 0
    summary = json.loads(summary_path.read_text())
    assert summary["runs_with_envelope_violation"] == 1
    assert summary["shield"]["runs_breached"] == 1
    assert summary["shield"]["runs_breached_after_unresolved"] == 1
    assert summary["shield"]["unresolved_per_breached_run"][0] >= 1


def test_one_step_a_fraction_of_a_knot_outside_counts_as_breached():
    """365.71 kt for one step of a 4-h run is a breach (the predicate of the summary's
    runs_with_envelope_violation), not rounded away; unshielded runs are not counted."""
    from atc_nf_env.shield import breached_runs, summarize_interventions

    info = {"shield_decisions": 48, "shield_filtered": 0, "shield_mpc_fallbacks": 0, "shield_unresolved": 0}
    one_step = {"envelope_violation_fraction": 1 / 2880, "los_count": 0, "policy_info": info}
    clean = {"envelope_violation_fraction": 0.0, "los_count": 0, "policy_info": info}
    los = {"envelope_violation_fraction": 0.0, "los_count": 2, "policy_info": {**info, "shield_unresolved": 3}}
    unshielded = {"envelope_violation_fraction": 0.5, "los_count": 0, "policy_info": {}}
    counts = breached_runs([one_step, clean, los])
    assert counts == {"runs_breached": 2, "runs_breached_after_unresolved": 1, "unresolved_per_breached_run": [0, 3]}
    records = [one_step, clean, los, unshielded]
    summary = summarize_interventions([r["policy_info"] for r in records], records)
    assert summary["runs"] == 3 and summary["runs_breached"] == 2
    assert breached_runs([clean])["unresolved_per_breached_run"] is None


# -- item 19: what docs/evaluation.md says each command takes ----------------------------
def _help(command: str, capsys) -> str:
    import pytest

    from atc_nf_env import cli

    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    return capsys.readouterr().out


def test_the_options_the_docs_say_every_command_takes_are_taken_by_every_command(capsys):
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    every = re.search(r"Every command takes (.*?)[.:]\s", text, re.S)
    assert every, "docs/evaluation.md: the sentence 'Every command takes ...' is gone"
    options = re.findall(r"`(--[a-z-]+)`", every.group(1))
    assert options
    also = re.search(r"`fly` and `evaluate` also take (.*?):\n", text, re.S)
    assert also
    helps = {command: _help(command, capsys) for command in ("fly", "evaluate", "benchmark", "dataset")}
    for command, shown in helps.items():
        for option in options:
            assert option in shown, f"docs say every command takes {option}; atc-nf {command} does not"
    for command in ("fly", "evaluate"):
        for option in re.findall(r"`(--[a-z-]+)`", also.group(1)):
            assert option in helps[command], f"docs say {command} takes {option}"
    # What the docs say instead for the suite's commands.
    assert "--seed" not in helps["benchmark"] and "--seed" not in helps["dataset"]
    assert "--shield" in helps["benchmark"] and "`benchmark --shield`" in text
    assert "--first-seed" in helps["dataset"] and "`--first-seed`" in text
