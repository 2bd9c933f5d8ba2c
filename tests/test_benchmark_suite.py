"""The benchmark suite: disjoint seed splits, per-run safety, a score that ranks safety
first, and score cards from the command line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from atc_nf_env import benchmark
from atc_nf_env.benchmark import SPLITS, TASKS, card_from_records, get_split, get_task, lexicographic_score


def test_the_splits_are_disjoint_and_the_scored_ones_lie_beyond_every_development_seed() -> None:
    ranges = sorted((s.first, s.first + s.size) for s in SPLITS.values())
    assert all(end <= start for (_, end), (start, _) in zip(ranges, ranges[1:]))
    train = SPLITS["train"]
    for name in benchmark.SCORED_SPLITS:
        assert SPLITS[name].first >= train.first + train.size  # beyond 0 … 999 999 999


def test_the_suite_names_its_tasks_and_refuses_others_and_the_train_split() -> None:
    assert {"converging-4", "converging-6", "random-4", "random-6", "random-8"} <= set(TASKS)
    with pytest.raises(ValueError, match="converging-4"):
        get_task("converging-5")
    with pytest.raises(ValueError, match="validation, test"):
        get_split("train")
    with pytest.raises(ValueError, match="10000 seeds"):
        get_split("test").seeds(10_001)


def record(seed: int, *, los: int = 0, outside: float = 0.0, home: bool = True, times=(60.0, 62.0)) -> dict:
    return {"seed": seed, "los_count": los, "envelope_violation_fraction": outside, "success": home,
            "arrived": [home, True], "flight_time_min": list(times), "decisions": 12, "decision_s_mean": 0.002,
            "decision_s_each": [0.002] * 12}


def test_a_card_counts_safety_per_run_not_as_a_share_of_steps() -> None:
    records = [record(1_000_000_000), record(1_000_000_001, outside=1e-4), record(1_000_000_002, los=1)]
    card = card_from_records(TASKS["random-4"], SPLITS["validation"], "x", False, records, None)
    assert (card["runs"], card["runs_safe"], card["runs_with_los"], card["runs_outside_envelope"]) == (3, 1, 1, 1)
    assert card["flight_time_ratio_to_mpc"] is None and card["score"] == lexicographic_score(3, 1, 3, None)


def test_the_flight_ratio_compares_only_aircraft_both_brought_home_on_the_same_seeds() -> None:
    own = [record(5, times=(50.0, 60.0)), record(6, home=False, times=(99.0, 40.0))]
    mpc = [record(5, times=(100.0, 60.0)), record(6, times=(70.0, 80.0)), record(7, times=(1.0, 1.0))]
    card = card_from_records(TASKS["random-4"], SPLITS["validation"], "x", False, own, mpc)
    assert card["flight_time_ratio_to_mpc"] == pytest.approx((50 + 60 + 40) / (100 + 60 + 80))


runs_and_counts = st.integers(1, 2000).flatmap(
    lambda n: st.tuples(st.just(n), st.integers(0, n), st.integers(0, n), st.integers(0, n), st.integers(0, n),
                        st.one_of(st.none(), st.floats(0.01, 100.0)), st.one_of(st.none(), st.floats(0.01, 100.0))))


@given(runs_and_counts)
def test_the_score_orders_safety_first_then_arrivals_then_speed(case) -> None:
    runs, safe_a, safe_b, home_a, home_b, ratio_a, ratio_b = case
    a = lexicographic_score(runs, safe_a, home_a, ratio_a)
    b = lexicographic_score(runs, safe_b, home_b, ratio_b)
    if safe_a != safe_b:
        assert (a > b) == (safe_a > safe_b)
    elif home_a != home_b:
        assert (a > b) == (home_a > home_b)
    assert 0.0 <= a < 1.0 + 2.0 / runs


def test_the_command_writes_a_card_with_the_contract_keys(tmp_path) -> None:
    out = tmp_path / "card.json"
    done = subprocess.run(
        [sys.executable, "-m", "atc_nf_env.benchmark", "--policy", "nf", "--task", "converging-4", "--split",
         "validation", "--runs", "2", "--workers", "1", "--no-progress", "--out", str(out),
         "--results-dir", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    card = json.loads(out.read_text())
    for key in ("task", "split", "runs", "runs_safe", "success_rate", "score"):
        assert key in card
    assert (card["task"], card["split"], card["runs"], card["seeds"]) == ("converging-4", "validation", 2,
                                                                          [1_000_000_000, 1_000_000_001])
    assert card["flight_time_ratio_to_mpc"] is not None  # the MPC flew the same seeds
    assert (tmp_path / "runs" / "converging-4" / "validation" / "mpc.jsonl").exists()
    assert "score" in done.stdout


def test_the_command_refuses_an_unscored_split_before_flying() -> None:
    done = subprocess.run([sys.executable, "-m", "atc_nf_env.benchmark", "--policy", "nf", "--task", "random-4",
                           "--split", "train"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "invalid choice: 'train'" in done.stderr


@pytest.mark.parametrize("command, option", [("benchmark", "--split"), ("dataset", "--dataset-id")])
def test_atc_nf_routes_the_benchmark_and_dataset_commands_to_their_modules(command, option, capsys) -> None:
    from atc_nf_env import cli

    with pytest.raises(SystemExit) as exit_:
        cli.main([command, "--help"])
    assert exit_.value.code == 0 and option in capsys.readouterr().out


# ------------------------------------------------------------------ stream tasks


def test_the_stream_tasks_have_their_own_disjoint_splits_beyond_every_encounter_seed() -> None:
    streams = {name: task for name, task in TASKS.items() if task.is_stream}
    assert set(streams) == {"stream-30", "stream-60", "stream-120"}
    assert all(task.splits is benchmark.STREAM_SPLITS and task.max_time_s == 7200.0 for task in streams.values())
    assert not any(task.is_stream for name, task in TASKS.items() if name not in streams)
    ranges = sorted((s.first, s.first + s.size) for s in benchmark.STREAM_SPLITS.values())
    assert all(end <= start for (_, end), (start, _) in zip(ranges, ranges[1:]))
    last_encounter_seed = max(s.first + s.size for s in SPLITS.values()) - 1
    assert ranges[0][0] > last_encounter_seed
    assert get_split("validation", task="stream-60").first == 4_000_000_000
    assert get_split("validation").first == 1_000_000_000  # the encounter tasks' splits are v0's
    with pytest.raises(ValueError, match="validation, test"):
        get_split("train", task="stream-30")


def stream_record(seed: int, *, los: int = 0, outside: float = 0.0, left: bool = False) -> dict:
    """Two flights home (60 and 80 min, mean delay 10 min), one still airborne."""
    return {"seed": seed, "los_count": los, "envelope_violation_fraction": outside, "success": not left,
            "arrived": [True, True, False], "flight_time_min": [60.0, 80.0, 30.0], "decisions": 24,
            "decision_s_mean": 0.001, "decision_s_each": [0.001] * 24,
            "stream": {"throughput_per_hour": 1.0, "delay_s": {"mean": 600.0, "max": 900.0}, "flight_hours": 2.8,
                       "los_count": los, "max_airborne": 3 + seed % 2, "flights_entered": 3, "flights_completed": 2,
                       "flights_left_workspace": int(left), "entries_held": 0, "airborne_at_end": 1,
                       "entry_delay_s": {"mean": 150.0, "max": 300.0}}}


def test_a_stream_card_carries_the_stream_metrics_and_compares_with_the_direct_flight() -> None:
    records = [stream_record(4_000_000_000), stream_record(4_000_000_001, outside=0.01),
               stream_record(4_000_000_002, los=1, left=True)]
    task, split = TASKS["stream-30"], benchmark.STREAM_SPLITS["validation"]
    card = card_from_records(task, split, "x", False, records, None)
    assert card["flight_time_ratio_to_direct"] == pytest.approx(140.0 / 120.0)  # (60+80) / (60+80−2·10)
    assert "flight_time_ratio_to_mpc" not in card
    assert (card["runs_safe"], card["runs_home"]) == (1, 2)
    assert card["score"] == lexicographic_score(3, 1, 2, 140.0 / 120.0)
    stream = card["stream"]
    assert stream["throughput_per_hour"] == {"min": 1.0, "mean": 1.0, "max": 1.0}
    assert stream["delay_s"] == {"mean": 600.0, "max": 900.0}
    assert (stream["los_count"], stream["runs_outside_envelope"], stream["max_airborne"]) == (1, 1, 4)
    assert stream["los_per_flight_hour"] == pytest.approx(1 / 8.4)
    assert stream["flights_airborne_at_end"] == 3
    with pytest.raises(ValueError, match="direct flight"):
        card_from_records(task, split, "x", False, records, records)
    with pytest.raises(ValueError, match="no stream metrics"):
        card_from_records(task, split, "x", False, [record(4_000_000_000)], None)


@pytest.mark.slow  # two 2-h streams of the suite's task, half a minute
def test_nf_leg_scores_a_stream_task_without_flying_the_mpc(tmp_path) -> None:
    from atc_nf_env.policy import register_policy
    from baselines import NFLeg

    register_policy("nf-leg", NFLeg)  # in this process, whether or not the package is reinstalled
    card = benchmark.score_card("nf-leg", "stream-30", "validation", 2, workers=1, results_dir=tmp_path)
    assert (card["suite_version"], card["task"], card["seeds"]) == ("v1", "stream-30", [4_000_000_000, 4_000_000_001])
    assert sorted(p.name for p in (tmp_path / "stream-30" / "validation").iterdir()) == ["nf-leg.jsonl"]
    stream = card["stream"]
    assert stream["flights_entered"] > 40 and stream["flights_completed"] > 0
    assert stream["max_airborne"] <= 61 and stream["throughput_per_hour"]["mean"] > 0
    assert card["flight_time_ratio_to_direct"] > 1.0
    assert card["runs_outside_envelope"] == stream["runs_outside_envelope"]
    assert "throughput" in benchmark.format_card(card)
