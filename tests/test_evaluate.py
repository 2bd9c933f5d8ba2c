"""The Monte Carlo evaluator: results file, resume after an interruption, backends, CLI."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from atc_nf_env.cli import main
from atc_nf_env.evaluate import Study, evaluate, read_results


class Interrupt(Exception):
    pass


def test_resume_after_an_interruption_loses_nothing_and_repeats_nothing(tmp_path):
    out = tmp_path / "runs.jsonl"
    study = Study(policy="nf", scenario="converging-3", wind_sigma_mps=5.17)
    finished = []

    def stop_after_three(record):
        finished.append(record["seed"])
        if len(finished) == 3:
            raise Interrupt

    with pytest.raises(Interrupt):
        evaluate(study, 8, workers=1, out=out, progress=False, on_run=stop_after_three)
    header, runs = read_results(out)
    assert header["policy"] == "nf" and [r["seed"] for r in runs] == finished
    # A line cut off mid-write by a kill is ignored on resume.
    with out.open("a") as handle:
        handle.write('{"seed": 99, "trunc')
    seen = []
    summary = evaluate(study, 8, workers=1, out=out, resume=True, progress=False, on_run=lambda r: seen.append(r["seed"]))
    assert sorted(seen) == sorted(set(range(8)) - set(finished))
    _, runs = read_results(out)
    assert sorted(r["seed"] for r in runs) == list(range(8))
    assert summary["runs"] == 8
    # The same study in one go gives the same results.
    fresh = evaluate(study, 8, workers=1, out=tmp_path / "fresh.jsonl", progress=False)
    for key in ("success_rate", "los_count", "min_separation_nm", "envelope_violation_fraction"):
        assert fresh[key] == summary[key]


def test_a_killed_evaluate_process_resumes(tmp_path):
    out = tmp_path / "runs.jsonl"
    command = [
        sys.executable, "-m", "atc_nf_env.cli", "evaluate", "--policy", "mpc", "--extractions", "100",
        "--scenario", "converging-3", "--runs", "30", "--workers", "1", "--out", str(out), "--no-progress",
    ]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline:
        if out.exists() and len(out.read_text().splitlines()) >= 3:  # header + 2 runs
            break
        time.sleep(0.1)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    _, before = read_results(out)
    assert 2 <= len(before) < 30
    assert main(command[3:] + ["--resume"]) == 0
    _, after = read_results(out)
    seeds = [r["seed"] for r in after]
    assert len(seeds) == len(set(seeds)) == 30
    # Runs finished before the kill are kept as they were.
    assert after[: len(before)] == before


def test_study_errors_name_the_bad_value(tmp_path):
    with pytest.raises(ValueError, match="unknown policy 'greedy'"):
        Study(policy="greedy", scenario="converging-4")
    with pytest.raises(ValueError, match="unknown scenario 'loop-4'"):
        Study(policy="nf", scenario="loop-4")
    with pytest.raises(ValueError, match="wind_sigma"):
        Study(policy="nf", scenario="converging-4", wind_sigma_mps=-1.0)
    with pytest.raises(ValueError, match="extractions"):
        Study(policy="mpc", scenario="converging-4", policy_kwargs={"extractions": 0})
    study = Study(policy="nf", scenario="converging-3")
    with pytest.raises(ValueError, match="runs"):
        evaluate(study, 0, progress=False)
    out = tmp_path / "a.jsonl"
    evaluate(study, 1, workers=1, out=out, progress=False)
    with pytest.raises(ValueError, match="already holds a study"):
        evaluate(study, 2, workers=1, out=out, progress=False)
    other = Study(policy="nf", scenario="converging-4")
    with pytest.raises(ValueError, match="different study"):
        evaluate(other, 2, workers=1, out=out, resume=True, progress=False)


def test_cli_evaluate_writes_the_summary_contract(tmp_path, capsys):
    summary_path = tmp_path / "s.json"
    code = main([
        "evaluate", "--policy", "mpc", "--extractions", "60", "--scenario", "converging-3", "--runs", "3",
        "--workers", "2", "--summary-json", str(summary_path), "--no-progress",
    ])
    assert code == 0
    summary = json.loads(summary_path.read_text())
    for key in ("runs", "success_rate", "los_count", "min_separation_nm", "airspeed_kt",
                "envelope_violation_fraction", "flight_time_min", "wall_s_per_run", "decision_s",
                "peak_rss_mb", "fallbacks"):
        assert key in summary
    assert summary["runs"] == 3
    assert summary["decision_s"]["mean"] > 0
    assert summary["peak_rss_mb"] > 10
    # On the terminal, a table for people, not the JSON.
    out = capsys.readouterr().out
    assert "{" not in out and "None" not in out
    assert "mpc (extractions 60) on converging-3, wind σ 5.17 m/s, seeds 0–2" in out
    home = round(summary["success_rate"] * 3)
    assert f"every aircraft home    {home}/3" in out
    assert f"fallbacks              {summary['fallbacks']} of {summary['decisions']} decisions" in out
    safe = re.search(r"safe runs +(\d)/3 \(no loss of separation, no step outside \[366, 540\] kt\)", out)
    assert safe is not None, out
    unsafe_at_least = max(summary["runs_with_los"], summary["runs_with_envelope_violation"])
    unsafe_at_most = summary["runs_with_los"] + summary["runs_with_envelope_violation"]
    assert 3 - unsafe_at_most <= int(safe.group(1)) <= 3 - unsafe_at_least


def test_cli_rejects_bad_values(capsys):
    assert main(["evaluate", "--policy", "greedy", "--runs", "2", "--no-progress"]) == 2
    assert "greedy" in capsys.readouterr().err
    assert main(["fly", "--policy", "nf", "--extractions", "10"]) == 2
    assert "--extractions" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", "--runs", "0"])
    with pytest.raises(SystemExit):
        main(["evaluate", "--extractions", "0", "--policy", "mpc"])


@pytest.mark.parametrize("name", ["recovery_angle", "approach_angle"])
def test_angle_options_reach_the_mpc_in_radians_and_bad_angles_are_refused(capsys, name):
    import argparse
    import math

    from atc_nf_env.cli import _policy_kwargs

    option = f"--{name.replace('_', '-')}-deg"
    kwargs = _policy_kwargs(argparse.Namespace(policy="mpc", sampling="per-cluster", **{f"{name}_deg": 70.0}))
    assert kwargs == {"sampling": "per-cluster", f"{name}_rad": math.radians(70.0)}
    from baselines import MCMCMPC

    assert getattr(MCMCMPC(**kwargs).settings, f"{name}_rad") == math.radians(70.0)
    for bad in ("90", "0", "-5", "nan", "inf"):
        assert main(["fly", "--policy", "mpc", option, bad]) == 2, bad
        assert option in capsys.readouterr().err, bad
    assert main(["fly", "--policy", "nf", option, "70"]) == 2
    assert f"{option} applies to --policy mpc, or with --shield" in capsys.readouterr().err


def test_ray_backend_on_a_local_cluster():
    pytest.importorskip("ray")
    study = Study(policy="nf", scenario="converging-3", wind_sigma_mps=5.17)
    on_ray = evaluate(study, 3, workers=2, backend="ray", progress=False)
    local = evaluate(study, 3, workers=1, progress=False)
    assert on_ray["runs"] == 3
    for key in ("success_rate", "min_separation_nm", "envelope_violation_fraction"):
        assert on_ray[key] == local[key]
