"""The reproduction's machinery: build fingerprints, every-step airspeed bands, derived
report cells, marked sections, and the README's summary equal to REPRODUCTION.md's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from atc_nf_env import build
from atc_nf_env.evaluate import Study, evaluate, read_results, run_one
from atc_nf_env.experiments import reproduce
from atc_nf_env.experiments.marked_sections import marked_sections, replace_marked_section

ROOT = Path(__file__).resolve().parents[1]


def test_fingerprint_is_stable_and_covers_the_kernel_and_baselines() -> None:
    names = {f"{p.parent.name}/{p.name}" for p in build.source_files()}
    assert {"atc_nf_env/kernel.py", "atc_nf_env/nf.py", "atc_nf_env/config.py", "atc_nf_env/scenarios.py",
            "baselines/mcmc_mpc.py"} <= names
    assert all(p.is_file() for p in build.source_files())
    assert build.fingerprint() == build.fingerprint()
    assert len(build.fingerprint()) == 16 and int(build.fingerprint(), 16) >= 0
    assert Study(policy="nf", scenario="converging-3").header()["build"] == build.fingerprint()


def _file_of_another_build(path: Path, study: Study) -> None:
    header = study.header() | {"build": "0" * 16}
    record = run_one(study, 0)
    path.write_text(json.dumps(header) + "\n" + json.dumps(record) + "\n")


def test_evaluator_refuses_to_resume_runs_of_another_build(tmp_path: Path) -> None:
    study = Study(policy="nf", scenario="converging-3", wind_sigma_mps=0.0)
    path = tmp_path / "runs.jsonl"
    _file_of_another_build(path, study)
    with pytest.raises(ValueError, match="another build"):
        evaluate(study, 2, out=path, resume=True, workers=1, progress=False)


def test_reproduction_flies_again_a_study_of_another_build(tmp_path: Path, capsys) -> None:
    study = Study(policy="nf", scenario="converging-3", wind_sigma_mps=0.0, airspeed_every_s=60.0)
    path = tmp_path / "runs.jsonl"
    _file_of_another_build(path, study)
    _, records, reused = reproduce.fly_study(study, 1, path, workers=1, progress=False)
    assert reused == 0 and len(records) == 1
    assert "not reused" in capsys.readouterr().err
    header, runs = read_results(path)
    assert header["build"] == build.fingerprint() and len(runs) == 1
    # The same build's runs are reused.
    _, records, reused = reproduce.fly_study(study, 1, path, workers=1, progress=False)
    assert reused == 1 and records[0]["seed"] == 0


def test_bands_hold_the_extremes_of_every_integration_step() -> None:
    # The NF alone without wind: the approach slows to a few kt and the saddle saturates
    # the command, both far outside the envelope and within a minute.
    study = Study(policy="nf", scenario="converging-4", wind_sigma_mps=0.0, airspeed_every_s=60.0)
    record = run_one(study, 0)
    bands = record["airspeed_band_kt"]
    lows = [w[0] for aircraft in bands for w in aircraft if w is not None]
    highs = [w[2] for aircraft in bands for w in aircraft if w is not None]
    assert min(lows) == pytest.approx(record["airspeed_min_kt"], abs=0.01)
    assert max(highs) == pytest.approx(record["airspeed_max_kt"], abs=0.01)
    assert all(record["arrived"]) and record["distance_short_nm"] == [None] * 4
    assert record["fallback_decisions"] == []
    assert bool(record["excursion_decisions"]) == (record["envelope_violation_fraction"] > 0)
    assert all(0 <= k < record["decisions"] for k in record["excursion_decisions"])
    minutes, mean, low, high = reproduce.airspeed_bands([record, record])
    assert np.nanmin(low) == pytest.approx(min(lows)) and np.nanmax(high) == pytest.approx(max(highs))
    assert np.all((low <= mean + 1e-9) | np.isnan(mean)) and np.all((mean <= high + 1e-9) | np.isnan(mean))
    bottom, top = reproduce.band_axis_limits(low, high)
    assert bottom < np.nanmin(low) and top > np.nanmax(high)


def test_band_axis_never_hides_an_excursion() -> None:
    low = np.array([[400.0], [-471.0]])
    high = np.array([[500.0], [520.0]])
    bottom, top = reproduce.band_axis_limits(low, high)
    assert bottom < -471 and top > 540


def _record(seed: int, **changes) -> dict:
    record = {
        "seed": seed, "n_aircraft": 2, "arrived": [True, True], "left_workspace": [False, False],
        "distance_short_nm": [None, None], "success": True, "los_count": 0,
        "envelope_violation_fraction": 0.0, "steps_flown": 100, "worst_excursion_kt": 0.0,
        "airspeed_min_kt": 400.0, "airspeed_max_kt": 500.0, "airspeed_mean_kt": 450.0,
        "excursion_decisions": [], "fallback_decisions": [], "decisions": 10, "flight_time_min": [60.0, 70.0],
    }
    return record | changes


def test_report_cells_are_counted_from_the_runs() -> None:
    records = [
        _record(0),
        _record(1, arrived=[True, False], success=False, distance_short_nm=[None, 21.0], flight_time_min=[60, 240]),
        _record(2, arrived=[False, True], success=False, left_workspace=[True, False], distance_short_nm=[300, None]),
        _record(3, envelope_violation_fraction=0.02, worst_excursion_kt=837.0, airspeed_min_kt=-471.0,
                excursion_decisions=[4], fallback_decisions=[3, 4]),
        _record(4, envelope_violation_fraction=0.01, worst_excursion_kt=2.0, excursion_decisions=[5],
                los_count=1),
    ]
    s = reproduce.run_safety(records)
    assert (s["runs_all_home"], s["aircraft_not_home"], s["aircraft_at_time_limit"], s["aircraft_left_workspace"]) \
        == (3, 2, 1, 1)
    assert s["distance_short_nm"]["median"] == 21.0
    assert (s["runs_outside_envelope"], s["runs_outside_envelope_after_a_fallback"],
            s["runs_outside_envelope_without_a_fallback"]) == (2, 1, 1)
    assert (s["steps_outside_envelope"], s["worst_excursion_kt"], s["airspeed_min_kt"]) == (3, 837.0, -471.0)
    assert (s["runs_with_los"], s["fallbacks"], s["runs_with_a_fallback"]) == (1, 2, 1)
    assert s["flight_time_all_home_min"] == 65.0
    note = reproduce.arrival_note(s)
    assert "2 aircraft not home in 2 runs" in note and "median 21.0 nm" in note and "1 aircraft left" in note
    assert "in 1 run a step outside falls in the period of a fallback" in reproduce.envelope_note(s)
    assert reproduce.arrival_note(reproduce.run_safety([_record(0)])) == ""


def test_marked_blocks_survive_and_the_readme_block_is_replaced(tmp_path: Path) -> None:
    text = "head\n<!-- begin proximity-range -->\n| a | b |\n<!-- end proximity-range -->\ntail\n"
    assert marked_sections(text) == {
        "proximity-range": "<!-- begin proximity-range -->\n| a | b |\n<!-- end proximity-range -->"}
    readme = tmp_path / "README.md"
    readme.write_text("x\n<!-- begin reproduction-summary -->\nold\n<!-- end reproduction-summary -->\ny\n")
    assert reproduce.update_readme(readme, "new figures")
    assert readme.read_text() == "x\n<!-- begin reproduction-summary -->\nnew figures\n" \
                                 "<!-- end reproduction-summary -->\ny\n"
    assert not reproduce.update_readme(tmp_path / "missing.md", "z")



def test_mpc_rows_quote_the_runs_and_the_papers_figures() -> None:
    records = [_record(0), _record(1, arrived=[True, False], success=False, distance_short_nm=[None, 21.0])]
    summary = {"min_separation_nm": {"min": 11.0, "mean": 12.0, "max": 13.0},
               "flight_time_min": {"mean": 66.0, "max": 70.0}, "wall_s_per_run": {"mean": 1.5},
               "peak_rss_mb": 200.0, "success_rate_ci95": [0.1, 0.9]}
    rows = {claim.split(": ", 1)[1]: (paper, ours, note) for claim, paper, ours, note in
            reproduce.mpc_rows("converging-4", summary, reproduce.run_safety(records))}
    assert rows["runs where every aircraft arrives"][:2] == ("1000/1000", "1/2 (95 % interval 10.0 - 90.0 %)")
    assert rows["runs with a loss of separation (< 5 nm)"][1] == "0/2"
    assert rows["runs with an integration step outside [366, 540] kt"][1:] == ("0/2", "checked at every integration step")
    random_rows = reproduce.mpc_rows("random-6", summary, reproduce.run_safety(records))
    assert all(paper == "-" for _, paper, _, _ in random_rows)


def test_reproduce_end_to_end_keeps_marked_sections_and_fills_the_readme(tmp_path: Path) -> None:
    report, readme = tmp_path / "REPRODUCTION.md", tmp_path / "README.md"
    kept = "<!-- begin proximity-range -->\n| range | separation |\n<!-- end proximity-range -->"
    report.write_text(f"# old table\n\n| stale | 921/1000 |\n\n{kept}\n")
    readme.write_text("# x\n\n<!-- begin reproduction-summary -->\nstale\n<!-- end reproduction-summary -->\n")
    assert reproduce.main(["--runs", "1", "--nf-wind-runs", "1", "--workers", "1", "--no-progress",
                           "--out", str(tmp_path / "out"), "--figures", str(tmp_path / "fig"),
                           "--report", str(report), "--readme", str(readme)]) == 0
    text = report.read_text()
    assert "921/1000" not in text and text.count(kept) == 1
    assert "atc-nf reproduce --runs 1 --nf-wind-runs 1" in text and build.fingerprint() in text
    for scenario in reproduce.MPC_STUDIES:
        assert f"| {scenario}, MPC under wind: runs where every aircraft arrives |" in text
    summary = text.split("## In short\n\n", 1)[1].split("\n\n", 1)[0]
    assert f"<!-- begin reproduction-summary -->\n{summary}\n<!-- end reproduction-summary -->" in readme.read_text()
    assert {p.name for p in (tmp_path / "fig").iterdir()} >= {
        "mpc_converging4_airspeed_bands.png", "mpc_converging6_airspeed_bands.png"}


def test_a_section_is_replaced_only_between_its_own_markers() -> None:
    text = "<!-- end a -->\n<!-- begin b -->\nkeep\n<!-- end b -->\n"
    assert replace_marked_section(text, "a", "new") is None  # an end marker alone is no section
    assert replace_marked_section("no markers", "a", "new") is None
    assert replace_marked_section(text, "b", "new\n") == "<!-- end a -->\n<!-- begin b -->\nnew\n<!-- end b -->\n"
