"""Simulation input checks, the episode runner (determinism, wind seeding), the ``atc-nf``
command line and the metrics summary."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from atc_nf_env.cli import main
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import episode_wind_kt, run_episode
from atc_nf_env.kernel import ARRIVED, FLYING, N_RECORD, S_STATUS
from atc_nf_env.metrics import RunMetrics, summarize
from atc_nf_env.scenarios import make_scenario
from atc_nf_env.simulation import Simulation
from atc_nf_env.units import KT_PER_MPS
from baselines import NFDirect


@pytest.fixture(scope="module")
def calm_pair():
    """Two identical windless runs of NFDirect on converging-3 (compiles the kernel once)."""
    scenario = make_scenario("converging-3")
    runs = [
        run_episode(NFDirect(), scenario, seed=0, wind_sigma_mps=0.0, record_every=1) for _ in range(2)
    ]
    return scenario, runs


# --------------------------------------------------------------------------- Simulation.advance


@pytest.fixture
def sim() -> Simulation:
    return Simulation(make_scenario("converging-3"))


def test_advance_rejects_waypoint_outside_workspace(sim: Simulation) -> None:
    waypoints = sim.scenario.dest_xy.copy()
    waypoints[1] = [0.0, 1600.0]
    with pytest.raises(ValueError, match=r"waypoint of aircraft 1 = \[0\.0, 1600\.0\] lies 1600\.0 nm"):
        sim.advance(waypoints, 300.0)
    # On the workspace limit (radius - aircraft radius) is outside too.
    limit = sim.scenario.workspace_radius_nm - sim.config.aircraft_radius_nm
    waypoints[1] = [limit, 0.0]
    with pytest.raises(ValueError, match=r"waypoint of aircraft 1"):
        sim.advance(waypoints, 300.0)
    # Nothing was flown.
    assert sim.time_s == 0.0
    np.testing.assert_array_equal(sim.state[0, :, 0:2], sim.scenario.start_xy)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_advance_rejects_non_finite_waypoint(sim: Simulation, bad: float) -> None:
    waypoints = sim.scenario.dest_xy.copy()
    waypoints[2, 0] = bad
    with pytest.raises(ValueError, match=r"waypoints contain NaN or inf"):
        sim.advance(waypoints, 300.0)
    assert sim.time_s == 0.0


def re_shape(shape) -> str:
    return str(tuple(shape)).replace("(", r"\(").replace(")", r"\)")


@pytest.mark.parametrize("shape", [(2, 2), (3,), (3, 3), (1, 3, 2)])
def test_advance_rejects_wrong_shape(sim: Simulation, shape) -> None:
    with pytest.raises(ValueError, match=rf"waypoints has shape {re_shape(shape)}; expected \(3, 2\)"):
        sim.advance(np.zeros(shape), 300.0)
    assert sim.time_s == 0.0


def test_advance_flies(sim: Simulation) -> None:
    sim.advance(sim.scenario.dest_xy, 300.0)
    assert sim.time_s == pytest.approx(300.0)
    moved = np.hypot(*(sim.state[0, :, 0:2] - sim.scenario.start_xy).T)
    assert np.all(moved > 10.0)  # ~ 450 kt for 5 min is tens of nm
    assert np.all(sim.status == FLYING)
    assert np.all(sim.state[0, :, S_STATUS] != ARRIVED)


def test_simulation_rejects_bad_wind() -> None:
    with pytest.raises(ValueError, match=r"wind_kt = .*nan"):
        Simulation(make_scenario("converging-3"), wind_kt=(float("nan"), 0.0))
    with pytest.raises(ValueError, match=r"wind_kt"):
        Simulation(make_scenario("converging-3"), wind_kt=(1.0, 2.0, 3.0))


# --------------------------------------------------------------------------- run_episode


def test_calm_converging_3_all_arrive_without_loss(calm_pair) -> None:
    scenario, (result, _) = calm_pair
    m = result.metrics
    assert m.scenario == "converging-3"
    assert m.n_aircraft == 3
    assert m.wind_kt == [0.0, 0.0]
    assert m.arrived == [True, True, True]
    assert m.success
    assert not any(m.left_workspace)
    assert m.los_count == 0
    assert m.min_separation_nm is not None and m.min_separation_nm >= 5.0
    assert all(0 < t < 4 * 60 for t in m.flight_time_min)
    # Each path is at least the 500 nm straight line to the opposite side.
    assert all(p >= 2 * 250.0 - SimConfig().arrival_tolerance_nm - 1e-6 for p in m.path_length_nm)
    assert m.decisions == len(result.waypoints) == len(result.decision_times_s) >= 1
    # NFDirect always asks for the destinations.
    np.testing.assert_array_equal(result.waypoints[0], scenario.dest_xy)
    assert m.steps_flown > 0


def test_calm_episode_records(calm_pair) -> None:
    _, (result, _) = calm_pair
    r = result.records
    assert r.ndim == 3 and r.shape[1:] == (3, N_RECORD)
    assert result.times_s.shape == (r.shape[0],)
    assert np.all(np.diff(result.times_s) > 0)
    assert result.times_s[0] == 0.0
    # The first row is the start, the last is within the arrival tolerance of the destination.
    np.testing.assert_allclose(r[0, :, 0:2], make_scenario("converging-3").start_xy)
    tolerance = SimConfig().arrival_tolerance_nm
    assert np.all(np.hypot(*(r[-1, :, 0:2] - make_scenario("converging-3").dest_xy).T) <= tolerance + 1e-9)


def test_same_seed_bit_identical(calm_pair) -> None:
    _, (a, b) = calm_pair
    assert a.records.size > 0
    assert np.array_equal(a.records, b.records)
    assert np.array_equal(a.times_s, b.times_s)
    assert np.array_equal(a.waypoints, b.waypoints)
    ma, mb = a.metrics.to_dict(), b.metrics.to_dict()
    for timing in ("wall_s", "decision_s_mean"):  # wall-clock, not simulated
        ma.pop(timing), mb.pop(timing)
    assert ma == mb


def test_same_seed_with_wind_identical() -> None:
    scenario = make_scenario("converging-3")
    a = run_episode(NFDirect(), scenario, seed=5, wind_sigma_mps=5.17, max_time_s=600.0, record_every=1)
    b = run_episode(NFDirect(), scenario, seed=5, wind_sigma_mps=5.17, max_time_s=600.0, record_every=1)
    assert a.metrics.wind_kt == b.metrics.wind_kt
    assert np.array_equal(a.records, b.records)


def test_different_seed_different_wind() -> None:
    scenario = make_scenario("converging-3")
    a = run_episode(NFDirect(), scenario, seed=1, wind_sigma_mps=5.17, max_time_s=300.0)
    b = run_episode(NFDirect(), scenario, seed=2, wind_sigma_mps=5.17, max_time_s=300.0)
    assert a.metrics.wind_kt != b.metrics.wind_kt
    assert any(w != 0.0 for w in a.metrics.wind_kt)
    np.testing.assert_array_equal(a.metrics.wind_kt, episode_wind_kt(1, 5.17))
    # Truncated at the time limit: one decision, nobody arrived yet.
    assert a.metrics.sim_time_min == pytest.approx(5.0)
    assert a.metrics.decisions == 1
    assert not a.metrics.success


def test_episode_wind_scales_with_sigma() -> None:
    unit = episode_wind_kt(3, 1.0)
    np.testing.assert_allclose(episode_wind_kt(3, 5.17), 5.17 * unit, rtol=1e-12)
    np.testing.assert_array_equal(episode_wind_kt(3, 0.0), [0.0, 0.0])
    # Components are N(0, σ²) in m/s, converted to kt.
    winds = np.array([episode_wind_kt(s, 5.17) for s in range(400)]) / KT_PER_MPS
    assert np.std(winds) == pytest.approx(5.17, rel=0.15)
    assert abs(np.mean(winds)) < 1.0
    with pytest.raises(ValueError, match=r"wind_sigma = -1"):
        episode_wind_kt(0, -1.0)


def test_explicit_wind_overrides_sampled() -> None:
    result = run_episode(
        NFDirect(), make_scenario("converging-3"), seed=1, wind_kt=np.array([10.0, -5.0]), max_time_s=300.0
    )
    assert result.metrics.wind_kt == [10.0, -5.0]


@pytest.mark.parametrize("kwargs, field", [({"period_s": 0.0}, "period_s"), ({"max_time_s": -1.0}, "max_time_s")])
def test_run_episode_rejects_bad_times(kwargs, field) -> None:
    with pytest.raises(ValueError, match=rf"{field} = "):
        run_episode(NFDirect(), make_scenario("converging-3"), **kwargs)


# --------------------------------------------------------------------------- CLI


def test_cli_fly_writes_summary_and_plots(tmp_path, capsys) -> None:
    summary_path = tmp_path / "s.json"
    figs = tmp_path / "figs"
    code = main(
        [
            "fly",
            "--policy",
            "nf",
            "--scenario",
            "converging-3",
            "--wind-sigma",
            "0",
            "--summary-json",
            str(summary_path),
            "--plots",
            str(figs),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "nf on converging-3, seed 0" in out
    assert re.search(r"^all\s+3/3\s", out, re.MULTILINE)
    for aircraft in range(3):
        assert re.search(rf"^{aircraft}\s+yes\s+\d+\.\d\s+\d+\s", out, re.MULTILINE), out
    # For people: no Python dicts, no None, no 16-digit floats; the JSON went to the file.
    assert "{" not in out and "None" not in out and not re.search(r"\d\.\d{5,}", out)

    summary = json.loads(summary_path.read_text())
    for key in (
        "runs",
        "success_rate",
        "los_count",
        "min_separation_nm",
        "airspeed_kt",
        "envelope_violation_fraction",
        "flight_time_min",
        "wall_s_per_run",
        "decision_s",
        "peak_rss_mb",
    ):
        assert key in summary, key
    assert summary["runs"] == 1
    assert summary["success_rate"] == 1.0
    assert summary["los_count"] == 0
    assert set(summary["min_separation_nm"]) >= {"min", "mean", "max"}
    sep = summary["min_separation_nm"]
    assert sep["min"] == sep["mean"] == sep["max"] >= 5.0
    assert set(summary["airspeed_kt"]) >= {"min", "max"}
    assert summary["airspeed_kt"]["min"] <= summary["airspeed_kt"]["max"]
    assert 0.0 <= summary["envelope_violation_fraction"] <= 1.0
    assert set(summary["flight_time_min"]) >= {"mean", "max"}
    assert 0 < summary["flight_time_min"]["mean"] <= summary["flight_time_min"]["max"]
    assert summary["wall_s_per_run"]["mean"] > 0
    assert summary["decision_s"]["mean"] >= 0
    assert summary["peak_rss_mb"] > 0
    assert summary["policy"] == "nf"
    assert summary["run"]["wind_kt"] == [0.0, 0.0]

    pngs = sorted(figs.glob("*.png"))
    assert len(pngs) == 2
    for png in pngs:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 1000


def test_cli_unknown_scenario(capsys) -> None:
    assert main(["fly", "--scenario", "nope"]) == 2
    captured = capsys.readouterr()
    assert "nope" in captured.err
    assert "error" in captured.err
    assert captured.out == ""


def test_cli_unknown_policy(capsys) -> None:
    assert main(["fly", "--policy", "mystery", "--scenario", "converging-3"]) == 2
    assert "mystery" in capsys.readouterr().err


def test_cli_missing_scenario_file(tmp_path, capsys) -> None:
    path = tmp_path / "gone.json"
    assert main(["fly", "--scenario", str(path)]) == 2
    assert "gone.json" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["-1", "nan", "abc"])
def test_cli_bad_wind_sigma_exits_2(value: str, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["fly", "--wind-sigma", value])
    assert info.value.code == 2
    assert "--wind-sigma" in capsys.readouterr().err


def test_cli_requires_a_command(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main([])
    assert info.value.code == 2


# --------------------------------------------------------------------------- summarize


def _metrics(**overrides) -> RunMetrics:
    base = dict(
        scenario="converging-2",
        seed=0,
        n_aircraft=2,
        wind_kt=[0.0, 0.0],
        arrived=[True, True],
        left_workspace=[False, False],
        flight_time_min=[60.0, 70.0],
        path_length_nm=[500.0, 510.0],
        success=True,
        min_separation_nm=20.0,
        los_count=0,
        envelope_violation_fraction=0.1,
        worst_excursion_kt=10.0,
        airspeed_min_kt=360.0,
        airspeed_max_kt=500.0,
        steps_flown=100,
        sim_time_min=70.0,
        wall_s=1.0,
        decisions=10,
        decision_s_mean=0.002,
    )
    base.update(overrides)
    return RunMetrics(**base)


def test_summarize_two_runs() -> None:
    good = _metrics()
    bad = _metrics(
        seed=1,
        arrived=[True, False],
        flight_time_min=[80.0, 240.0],
        success=False,
        min_separation_nm=3.0,
        los_count=1,
        envelope_violation_fraction=0.5,
        worst_excursion_kt=40.0,
        airspeed_min_kt=300.0,
        airspeed_max_kt=600.0,
        steps_flown=300,
        wall_s=3.0,
        decisions=0,
        decision_s_mean=0.0,
    )
    s = summarize([good, bad], peak_rss_mb=123.0)
    assert s["runs"] == 2
    assert s["success_rate"] == 0.5
    assert s["arrived_fraction"] == 0.75
    assert s["los_count"] == 1
    assert s["runs_with_los"] == 1
    # Pooled over integration steps: (0.1 * 100 + 0.5 * 300) / 400 = 0.4, not the mean 0.3.
    assert s["envelope_violation_fraction"] == pytest.approx(0.4)
    assert s["min_separation_nm"] == {"min": 3.0, "mean": 11.5, "max": 20.0}
    assert s["airspeed_kt"] == {"min": 300.0, "max": 600.0}
    assert s["worst_excursion_kt"] == 40.0
    # Flight times of arrived aircraft only: 60, 70, 80.
    assert s["flight_time_min"]["mean"] == pytest.approx(70.0)
    assert s["flight_time_min"]["max"] == 80.0
    assert s["wall_s_per_run"]["mean"] == pytest.approx(2.0)
    # Runs without decisions do not dilute the decision time.
    assert s["decision_s"]["mean"] == pytest.approx(0.002)
    assert s["peak_rss_mb"] == 123.0
    assert s["scenario"] == "converging-2"
    json.dumps(s)  # JSON-ready


def test_summarize_without_separation_or_arrivals() -> None:
    lone = _metrics(
        n_aircraft=1,
        arrived=[False],
        left_workspace=[False],
        flight_time_min=[10.0],
        path_length_nm=[70.0],
        success=False,
        min_separation_nm=None,
        steps_flown=0,
        envelope_violation_fraction=0.0,
    )
    s = summarize([lone])
    assert s["success_rate"] == 0.0
    assert s["min_separation_nm"] == {"min": None, "mean": None, "max": None}
    assert s["flight_time_min"] == {"mean": None, "max": None}
    assert s["envelope_violation_fraction"] == 0.0
    assert s["peak_rss_mb"] is None


def test_summarize_empty_raises() -> None:
    with pytest.raises(ValueError, match=r"at least one run"):
        summarize([])


def test_summary_of_a_real_run_matches_its_metrics(calm_pair) -> None:
    _, (result, _) = calm_pair
    m = result.metrics
    s = summarize([m, m])
    assert s["success_rate"] == 1.0
    assert s["envelope_violation_fraction"] == pytest.approx(m.envelope_violation_fraction)
    assert s["flight_time_min"]["max"] == max(m.flight_time_min)
    assert math.isfinite(s["airspeed_kt"]["min"])


def test_cli_fly_writes_an_animation(tmp_path) -> None:
    gif = tmp_path / "episode.gif"
    code = main(["fly", "--policy", "nf", "--scenario", "converging-3", "--wind-sigma", "0",
                 "--max-minutes", "20", "--animate", str(gif)])
    assert code == 0
    data = gif.read_bytes()
    assert data[:6] in (b"GIF87a", b"GIF89a")
    from PIL import Image

    with Image.open(gif) as image:
        assert image.n_frames >= 10


def test_cli_fly_refuses_an_animation_format_before_flying(tmp_path, capsys, monkeypatch) -> None:
    import atc_nf_env.episode as episode

    def never(*args, **kwargs):
        raise AssertionError("flew before checking the arguments")

    monkeypatch.setattr(episode, "run_episode", never)
    monkeypatch.setattr(episode, "warm_up", never)
    for name in ("x.mp4", "x.txt", "x"):
        assert main(["fly", "--policy", "nf", "--animate", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert "--animate" in err and "supported: .gif (GIF), .png (animated PNG)" in err, err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("minutes", ["0.1", "7.01"])
def test_cli_refuses_a_time_limit_off_the_step_grid_in_minutes(minutes, capsys) -> None:
    assert main(["fly", "--policy", "nf", "--max-minutes", minutes]) == 2
    err = capsys.readouterr().err
    assert f"--max-minutes {minutes}:" in err and "min" in err and "max_time_s" not in err
    assert "0.1" not in minutes or "e.g. 0.08333 or 0.1667" in err


@pytest.mark.parametrize("minutes", ["0", "-5", "nan", "inf"])
def test_cli_refuses_a_time_limit_that_is_not_positive(minutes, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["fly", "--policy", "nf", "--max-minutes", minutes])
    assert exit_.value.code == 2
    assert "--max-minutes" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".png", ".webp"])
def test_cli_fly_writes_the_other_animation_formats(tmp_path, suffix) -> None:
    from atc_nf_env.rendering import animation_formats

    if suffix not in animation_formats():
        pytest.skip(f"this Pillow writes no {suffix}")
    target = tmp_path / f"episode{suffix}"
    assert main(["fly", "--policy", "nf", "--scenario", "converging-3", "--wind-sigma", "0",
                 "--max-minutes", "20", "--animate", str(target)]) == 0
    from PIL import Image

    with Image.open(target) as image:
        assert image.n_frames >= 10


def test_per_aircraft_closest_approach_matches_the_run_s_minimum(calm_pair) -> None:
    from atc_nf_env.tables import per_aircraft

    _, runs = calm_pair
    result = runs[0]
    closest, low, high = per_aircraft(result)
    m = result.metrics
    # The kernel also looks between a refined step's sub-steps: never above the step ends'.
    assert m.min_separation_nm <= closest.min() + 1e-9
    assert closest.min() == pytest.approx(m.min_separation_nm, abs=0.5)
    assert low.min() == m.airspeed_min_kt and high.max() == m.airspeed_max_kt
    assert (low <= high).all()
