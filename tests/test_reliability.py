"""Bad input refused where it enters; no hang; no NaN counted as a success.

Each test reproduces one way the project once failed (a hang, a NaN arrival, an
out-of-bounds read, a metric over a step never flown) and checks the clear error or
the correct result that replaced it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from atc_nf_env import kernel, nf
from atc_nf_env.calibration import calibrate, check_calibrated
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import S_STATUS, advance
from atc_nf_env.metrics import run_metrics
from atc_nf_env.scenarios import converging, make_scenario
from atc_nf_env.simulation import Simulation, initial_state
from baselines import NFDirect
from _faults import deadline
from atc_nf_env.cli import main

ONE_AIRCRAFT = {"aircraft": [{"start": [0.0, 0.0], "destination": [100.0, 0.0]}]}


# ------------------------------------------------------------ 1. time limits on the grid


@pytest.mark.parametrize("max_time_s", [300.0000005, 1e-9, 60.01 * 60, 2.5, 0.0, -5.0, math.nan, math.inf])
def test_time_limit_off_the_integration_grid_is_refused_before_flying(max_time_s: float) -> None:
    class Counting(NFDirect):
        decisions = 0

        def act(self, view):
            Counting.decisions += 1
            return super().act(view)

    with deadline(60), pytest.raises(ValueError, match=r"max_time_s = .*(whole number of integration steps|> 0)"):
        run_episode(Counting(), converging(4), seed=0, max_time_s=max_time_s)
    assert Counting.decisions == 0


@pytest.mark.parametrize("period_s", [1e-9, 7.0, 0.0])
def test_decision_period_off_the_grid_is_refused(period_s: float) -> None:
    with pytest.raises(ValueError, match=r"period_s = "):
        run_episode(NFDirect(), converging(3), seed=0, period_s=period_s, max_time_s=600.0)


def test_time_limit_not_a_multiple_of_the_period_flies_exactly_to_the_limit() -> None:
    result = run_episode(NFDirect(), converging(4), seed=0, max_time_s=305.0)
    assert result.metrics.sim_time_min == pytest.approx(305.0 / 60.0)
    assert result.metrics.decisions == 2


def test_time_limit_of_a_bool_is_a_type_error() -> None:
    with pytest.raises(TypeError, match=r"max_time_s = True"):
        run_episode(NFDirect(), converging(3), max_time_s=True)  # type: ignore[arg-type]


# ------------------------------------------------------------ 3-4. calibration range, NaN


@pytest.mark.parametrize("radius", [1e200, 3000.0, 3.0e2, 1300.0])
def test_workspace_outside_the_calibrated_range_is_refused_before_flying(radius: float) -> None:
    data = dict(ONE_AIRCRAFT, workspace_radius_nm=radius)
    scenario = make_scenario(data)
    with pytest.raises(ValueError, match=r"workspace_radius_nm = .*calibrate\(workspace_radius_nm=R\)"):
        run_episode(NFDirect(), scenario, seed=0, max_time_s=600.0)


@pytest.mark.parametrize("radius", [1400.0, 1500.0, 1600.0])
def test_workspace_inside_the_calibrated_range_flies(radius: float) -> None:
    result = run_episode(NFDirect(), make_scenario(dict(ONE_AIRCRAFT, workspace_radius_nm=radius)), seed=0,
                         wind_sigma_mps=0.0)
    assert result.metrics.success


@pytest.mark.parametrize("radius, accepted", [(1355.0, False), (1372.0, True), (1673.0, True), (1690.0, False)])
def test_the_calibrated_range_is_the_one_the_refusal_states(radius: float, accepted: bool) -> None:
    # The message (and the README) say "about 1364 to 1681 nm" with the default gains.
    if accepted:
        check_calibrated(SimConfig(), radius)
    else:
        with pytest.raises(ValueError, match=r"they hold from about 1364 to 1681 nm"):
            check_calibrated(SimConfig(), radius)


def test_a_recalibrated_workspace_flies_and_arrives() -> None:
    scenario = converging(4, workspace_radius_nm=3000.0)
    config = calibrate(workspace_radius_nm=3000.0)
    check_calibrated(config, 3000.0)
    result = run_episode(NFDirect(), scenario, seed=0, wind_sigma_mps=0.0, config=config)
    assert result.metrics.success


def test_gains_outside_the_calibrated_range_are_refused() -> None:
    with pytest.raises(ValueError, match=r"k_u = 8071\.47.*cruise at"):
        Simulation(converging(3), config=SimConfig().replace(k_u=SimConfig().k_u / 10))


def test_kernel_never_hands_back_a_non_finite_state_silently() -> None:
    scenario = make_scenario(dict(ONE_AIRCRAFT, workspace_radius_nm=1e200))
    state = initial_state(scenario)
    params = SimConfig().to_params(scenario.workspace_radius_nm)
    with pytest.raises(FloatingPointError, match=r"NaN or inf \(world 0, aircraft 0\)"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params)


def test_arrival_needs_a_finite_position() -> None:
    sim = Simulation(make_scenario(ONE_AIRCRAFT))
    sim.state[0, 0, S_STATUS] = kernel.ARRIVED
    sim.state[0, 0, kernel.S_PATH] = math.nan
    metrics = run_metrics(sim, seed=0, wall_s=0.0, decision_s=[])
    assert metrics.arrived == [False]
    assert not metrics.success


# ------------------------------------------------------------ 5. kernel entry checks


def _world():
    scenario = converging(3)
    return scenario, initial_state(scenario), SimConfig().to_params(scenario.workspace_radius_nm)


@pytest.mark.parametrize("length", [0, 13, nf.N_PARAMS - 1, nf.N_PARAMS + 1])
def test_kernel_refuses_a_params_vector_of_the_wrong_length(length: int) -> None:
    scenario, state, params = _world()
    short = np.resize(params, length)
    before = state.copy()
    with pytest.raises(ValueError, match=rf"params has shape \({length},\).*expected \({nf.N_PARAMS},\) float64"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, short)
    assert np.array_equal(state, before)


@pytest.mark.parametrize("dt", [0.0, -5.0, math.nan])
def test_kernel_refuses_a_step_that_is_not_positive(dt: float) -> None:
    scenario, state, params = _world()
    params[nf.P_DT] = dt
    with pytest.raises(ValueError, match=r"params\[12\] \(dt_s\)|params contains NaN"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params)


def test_kernel_refuses_params_of_another_dtype_and_complex_waypoints() -> None:
    scenario, state, params = _world()
    with pytest.raises(ValueError, match=r"dtype float32"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params.astype(np.float32))
    with pytest.raises(ValueError, match=r"waypoints is complex"):
        advance(state, scenario.dest_xy[None] + 1j, np.zeros((1, 2)), 300.0, params)
    with pytest.raises(ValueError, match=r"record_every = -1"):
        advance(state, scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params, record_every=-1)
    with pytest.raises(ValueError, match=r"C-contiguous"):
        advance(np.asfortranarray(state), scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params)
    with pytest.raises(TypeError, match=r"state is a list"):
        advance(state.tolist(), scenario.dest_xy[None], np.zeros((1, 2)), 300.0, params)


# ------------------------------------------------------------ 7. extremes over flown steps


@pytest.mark.parametrize("start_kt", [0.0, 1e300])
def test_airspeed_extremes_cover_flown_steps_only(start_kt: float) -> None:
    scenario = make_scenario(dict(ONE_AIRCRAFT, start_airspeed_kt=start_kt))
    result = run_episode(NFDirect(), scenario, seed=0, record_every=1)
    flown = result.records[1:, 0, kernel.R_AIRSPEED]  # row 0 is the state before any step
    assert result.metrics.airspeed_max_kt == pytest.approx(float(flown.max()))
    assert result.metrics.airspeed_min_kt == pytest.approx(float(flown.min()))
    assert result.metrics.airspeed_max_kt < SimConfig().airspeed_cap_kt
    assert result.metrics.airspeed_min_kt > 0.0


# ------------------------------------------------------------ 1 and 10 at the command line


@pytest.mark.parametrize("command", ["fly", "evaluate"])
@pytest.mark.parametrize("minutes", ["1e-9", "60.01"])
def test_cli_refuses_a_time_limit_off_the_grid_at_once(command, minutes, capsys, tmp_path) -> None:
    extra = ["--runs", "2", "--workers", "1", "--no-progress"] if command == "evaluate" else []
    with deadline(60):
        code = main([command, "--policy", "nf", "--max-minutes", minutes, *extra])
    assert code == 2
    # In the option's own units: minutes, not the seconds of max_time_s.
    err = capsys.readouterr().err
    assert f"--max-minutes {float(minutes):g}:" in err and "whole integration steps of 5 s (0.08333 min)" in err


@pytest.mark.parametrize("flag", ["--summary-json", "--plots", "--animate"])
def test_cli_fly_refuses_an_unwritable_output_before_flying(flag, tmp_path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    target = blocker / "sub" / ("x.json" if flag != "--plots" else "figs")
    assert main(["fly", "--policy", "nf", flag, str(target)]) == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err


@pytest.mark.parametrize("flag", ["--summary-json", "--out"])
def test_cli_evaluate_refuses_a_directory_as_output_file(flag, tmp_path, capsys) -> None:
    assert main(["evaluate", "--policy", "nf", "--runs", "1", "--workers", "1", "--no-progress",
                 flag, str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_imitate_refuses_bad_expert_settings_before_any_demonstration(tmp_path, capsys) -> None:
    pytest.importorskip("torch")
    from agents import imitate

    code = imitate.main(["--out", str(tmp_path / "im"), "--expert-extractions", "-1"])
    assert code == 2
    assert "extractions" in capsys.readouterr().err
    assert not (tmp_path / "im" / "demos").exists()


# ------------------------------------------------------------ 6. one seed rule


def _envs():
    import gymnasium as gym

    import atc_nf_env  # noqa: F401 - registers the env
    from atc_nf_env.envs.centralized import EncounterEnv

    yield "EncounterEnv", lambda: EncounterEnv(scenario="converging-3")
    yield "parallel_env", lambda: atc_nf_env.parallel_env(scenario="converging-3")
    yield "vector", lambda: gym.make_vec("atc_nf_env/Encounter-v1", num_envs=2, scenario="converging-3")


@pytest.mark.parametrize("seed", [-1, True, 2**63, 2.0, "0", np.int64(-3)])
@pytest.mark.parametrize("env_name", ["EncounterEnv", "parallel_env", "vector"])
def test_every_env_refuses_a_bad_seed_with_one_error(env_name, seed) -> None:
    make = dict(_envs())[env_name]
    env = make()
    with pytest.raises(ValueError, match=r"seed.* must be an integer in \[0, 2\*\*63 - 1\]"):
        env.reset(seed=seed)
    env.close()


@pytest.mark.parametrize("env_name", ["EncounterEnv", "parallel_env"])
def test_every_env_accepts_the_largest_seed_and_numpy_ints(env_name) -> None:
    env = dict(_envs())[env_name]()
    env.reset(seed=2**63 - 1)
    env.reset(seed=np.int64(7))
    env.close()


def test_run_episode_and_scenarios_follow_the_same_seed_rule() -> None:
    for seed in (-1, True, 2**63, 1.5):
        with pytest.raises(ValueError, match=r"seed = .* must be an integer in \[0, 2\*\*63 - 1\]"):
            run_episode(NFDirect(), converging(3), seed=seed, max_time_s=300.0)
        with pytest.raises(ValueError, match=r"seed = .* must be an integer in \[0, 2\*\*63 - 1\]"):
            make_scenario("random-3", seed=seed)


# ------------------------------------------------------------ 10. smaller ones


@pytest.mark.parametrize("scalar", [np.float32(10.0), np.int64(10), np.float64(10.0), np.int32(10)])
def test_numpy_scalars_are_numbers_in_scenario_dicts(scalar) -> None:
    data = {"aircraft": [{"start": [scalar, 0.0], "destination": [100.0, scalar], "heading_deg": scalar}],
            "workspace_radius_nm": np.float32(1500.0)}
    scenario = make_scenario(data)
    assert scenario.start_xy[0, 0] == 10.0 and scenario.dest_xy[0, 1] == 10.0


def test_numpy_bools_are_not_numbers_in_scenario_dicts() -> None:
    with pytest.raises(ValueError, match=r"aircraft\[0\]\.start"):
        make_scenario({"aircraft": [{"start": [np.bool_(True), 0.0], "destination": [100.0, 0.0]}]})


@pytest.mark.parametrize("sigma", [1.7e308, 1e5, -1.0, math.nan])
def test_a_huge_wind_sigma_is_blamed_on_wind_sigma(sigma) -> None:
    from atc_nf_env.evaluate import Study

    with pytest.raises(ValueError, match=r"wind_sigma = "):
        run_episode(NFDirect(), converging(3), seed=0, wind_sigma_mps=sigma, max_time_s=300.0)
    with pytest.raises(ValueError, match=r"wind_sigma = "):
        Study(policy="nf", scenario="converging-3", wind_sigma_mps=sigma)


def test_complex_waypoints_and_actions_are_refused() -> None:
    from atc_nf_env.envs.centralized import EncounterEnv

    class ComplexPolicy(NFDirect):
        def act(self, view):
            return super().act(view) + 1j

    with pytest.raises(ValueError, match=r"complex"):
        run_episode(ComplexPolicy(), converging(3), seed=0, max_time_s=300.0)
    with pytest.raises(ValueError, match=r"complex"):
        Simulation(converging(3)).advance(converging(3).dest_xy + 0j, 300.0)
    env = EncounterEnv(scenario="converging-3")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"complex"):
        env.step(np.zeros((3, 2)) + 0.5j)


def test_scenario_dict_round_trip_has_one_home() -> None:
    from atc_nf_env.scenarios import Scenario

    scenario = make_scenario("random-4", seed=3)
    again = Scenario.from_dict(scenario.to_dict())
    assert np.allclose(again.start_xy, scenario.start_xy) and np.allclose(again.dest_heading, scenario.dest_heading)


def test_cli_reproduce_refuses_a_figures_path_it_cannot_create_before_flying(tmp_path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with deadline(60):
        assert main(["reproduce", "--figures", str(blocker / "figs"), "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert "Not a directory" in err and "Traceback" not in err


def test_an_env_on_a_workspace_outside_the_calibration_refuses_instead_of_returning_nan() -> None:
    from atc_nf_env.envs.centralized import EncounterEnv

    env = EncounterEnv(scenario=dict(ONE_AIRCRAFT, workspace_radius_nm=1e200))
    with pytest.raises(ValueError, match=r"workspace_radius_nm = 1e\+200"):
        env.reset(seed=0)
