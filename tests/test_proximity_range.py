"""The proximity-range study and the ``paper-nf`` physics it chooses."""

from __future__ import annotations

import json

import numpy as np
import pytest

from atc_nf_env import cli
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.evaluate import Study
from atc_nf_env.experiments import proximity_range
from atc_nf_env.scenarios import converging
from baselines import NFDirect


def test_presets_are_the_defaults_but_for_the_proximity_range():
    assert SimConfig.preset("default") == SimConfig()
    paper = SimConfig.preset("paper-nf")
    assert (paper.sensing_radius_nm, paper.barrier_nm) == (30.0, 15.0)
    assert paper.replace(sensing_radius_nm=12.0, barrier_nm=7.0) == SimConfig()


@pytest.mark.parametrize("name", ["Paper-NF", "", "paper", 3])
def test_an_unknown_preset_is_a_clear_error(name):
    with pytest.raises(ValueError, match="allowed: default, paper-nf"):
        SimConfig.preset(name)
    with pytest.raises(ValueError, match="allowed: default, paper-nf"):
        Study(policy="nf", scenario="converging-4", physics=name)


def test_paper_nf_keeps_the_papers_separation_between_four_aircraft_without_wind():
    m = run_episode(NFDirect(), converging(4), seed=0, wind_sigma_mps=0.0, config=SimConfig.preset("paper-nf")).metrics
    assert all(m.arrived) and m.los_count == 0
    assert 20.0 <= m.min_separation_nm <= 24.0  # paper: 22 nm


def test_cli_fly_with_paper_nf_physics(tmp_path, capsys):
    out = tmp_path / "summary.json"
    args = ["fly", "--policy", "nf", "--scenario", "converging-4", "--wind-sigma", "0", "--physics", "paper-nf",
            "--summary-json", str(out)]
    assert cli.main(args) == 0
    default_out = tmp_path / "default.json"
    assert cli.main(args[:-4] + ["--summary-json", str(default_out)]) == 0
    wide = json.loads(out.read_text())["min_separation_nm"]["min"]
    narrow = json.loads(default_out.read_text())["min_separation_nm"]["min"]
    assert wide > narrow + 5.0


def test_the_study_writes_only_its_marked_section(tmp_path):
    rows = proximity_range.study(0, ranges=((12.0, 7.0), (30.0, 15.0)))
    assert rows[1]["nf4"]["min_separation_nm"] > rows[0]["nf4"]["min_separation_nm"]
    assert np.isfinite(rows[0]["nf6"]["roundabout_radius_nm"])
    page = tmp_path / "REPRODUCTION.md"
    page.write_text("# Title\n\nkept above\n\n<!-- begin proximity-range -->\nold\n<!-- end proximity-range -->\n\nkept below\n")
    proximity_range.write_section(proximity_range.report(rows, 0), page)
    text = page.read_text()
    assert "kept above" in text and "kept below" in text and "old" not in text
    assert text.count("<!-- begin proximity-range -->") == 1
    assert "| 30 / 15 |" in text


def test_the_conclusions_quote_the_rows_they_rest_on():
    rows = proximity_range.study(0, ranges=((12.0, 7.0), (30.0, 15.0)))
    for row, (lo, med) in zip(rows, ((11.25, 12.5), (22.75, 26.25))):
        row["mpc4"] = {"runs": 4, "min_separation_nm": [lo, med, 30.0], "all_home": 4, "runs_with_los": 0,
                       "runs_with_breach": 1, "fallbacks": 2, "feasible_fraction_mean": 0.5}
    text = "\n".join(proximity_range.conclusions(rows))
    assert "11.2 nm at the least and 12.5 nm in the median" in text
    assert "1 with an envelope breach in 4" in text
    assert "its median is 26.2 nm" in text
    assert f"keeps {rows[1]['nf4']['min_separation_nm']:.1f} nm between 4 aircraft" in text
    assert "| 12 / 7 | " in proximity_range.report(rows, 4)
