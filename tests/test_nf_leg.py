"""NFLeg: the NF alone aimed a leg ahead along the line home (policy ``nf-leg``)."""

from __future__ import annotations

import math
import tomllib
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

from atc_nf_env.config import SimConfig
from atc_nf_env.episode import run_episode
from atc_nf_env.scenarios import Scenario, make_scenario
from atc_nf_env.simulation import WorldView, initial_state
from baselines import MPCSettings, NFDirect, NFLeg

ROOT = Path(__file__).resolve().parents[1]


def view_of(aircraft: list[dict]) -> tuple[Scenario, WorldView]:
    scenario = make_scenario({"aircraft": aircraft})
    return scenario, WorldView(0.0, initial_state(scenario)[0], scenario)


def test_the_leg_defaults_to_the_mpc_s_homing_distance_and_turn() -> None:
    policy = NFLeg()
    assert policy.leg_nm == MPCSettings().home_distance_nm
    assert policy.max_turn_rad == MPCSettings().recovery_angle_rad
    assert policy.final_approach == "through"


def test_the_waypoint_is_a_leg_ahead_on_the_line_home_even_past_a_close_destination() -> None:
    scenario, view = view_of([{"start": [-200.0, 0.0], "destination": [200.0, 0.0]},
                              {"start": [0.0, -50.0], "destination": [0.0, 10.0]}])
    policy = NFLeg()
    policy.reset(scenario, SimConfig())
    waypoints = policy.act(view)
    np.testing.assert_allclose(waypoints, [[-70.0, 0.0], [0.0, 80.0]], atol=1e-9)


def test_final_approach_destination_aims_at_the_destination_itself_within_a_leg() -> None:
    scenario, view = view_of([{"start": [-200.0, 0.0], "destination": [200.0, 0.0]},
                              {"start": [0.0, -50.0], "destination": [0.0, 10.0]}])
    policy = NFLeg(final_approach="destination")
    policy.reset(scenario, SimConfig())
    waypoints = policy.act(view)
    np.testing.assert_allclose(waypoints[0], [-70.0, 0.0], atol=1e-9)
    assert waypoints[1].tolist() == view.destinations[1].tolist()  # bit for bit: θ_d is the arrival heading


def test_a_destination_behind_turns_the_leg_at_most_the_turn_limit_from_the_heading() -> None:
    # Heading east (0 rad), destination due west and close: 180° off.
    scenario, view = view_of([{"start": [0.0, 0.0], "destination": [-40.0, -1e-9], "heading_deg": 0.0}])
    for final in ("through", "destination"):
        policy = NFLeg(final_approach=final)
        policy.reset(scenario, SimConfig())
        waypoint = policy.act(view)[0]
        angle = math.atan2(waypoint[1], waypoint[0])
        assert angle == pytest.approx(-math.pi / 3)  # turned 60° toward the destination's side
        assert math.hypot(*waypoint) == pytest.approx(130.0)
    unlimited = NFLeg(max_turn_rad=math.pi)
    unlimited.reset(scenario, SimConfig())
    np.testing.assert_allclose(unlimited.act(view)[0], [-130.0, 0.0], atol=1e-6)


def test_a_leg_point_stays_inside_the_workspace() -> None:
    scenario, view = view_of([{"start": [0.0, 0.0], "destination": [240.0, 0.0]}])
    policy = NFLeg(leg_nm=1000.0)
    policy.reset(scenario, SimConfig())
    assert math.hypot(*policy.act(view)[0]) < scenario.workspace_radius_nm


@pytest.mark.parametrize("settings, message", [
    ({"leg_nm": 0.0}, r"leg_nm = 0.0: must be a number in \(0, 1000\] nm"),
    ({"leg_nm": float("nan")}, r"leg_nm = nan: must be a number in \(0, 1000\]"),
    ({"leg_nm": 1000.5}, r"\(0, 1000\]"),
    ({"leg_nm": True}, r"leg_nm = True"),
    ({"leg_nm": "130"}, r"leg_nm = '130'"),
    ({"max_turn_rad": 0.0}, r"max_turn_rad = 0.0: must be a number in \(0, π\] rad"),
    ({"max_turn_rad": 3.2}, r"\(0, π\]"),
    ({"final_approach": "orbit"}, r"final_approach = 'orbit': allowed: through, destination"),
])
def test_bad_settings_are_refused_naming_the_allowed_range(settings: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        NFLeg(**settings)


def test_an_unknown_setting_is_a_type_error() -> None:
    with pytest.raises(TypeError, match=r"unknown settings \['leg'\]; allowed: leg_nm, max_turn_rad, final_approach"):
        NFLeg(leg=100.0)


def test_the_project_declares_nf_leg_as_a_policy_entry_point() -> None:
    groups = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    value = groups["atc_nf_env.policies"]["nf-leg"]
    assert EntryPoint("nf-leg", value, "atc_nf_env.policies").load() is NFLeg
    assert NFLeg.name == "nf-leg"


def test_on_a_stream_nf_leg_stays_nearer_the_envelope_than_the_nf_aimed_at_the_destination() -> None:
    # Measured, not assumed: the NF aimed 500 nm away spends most steps at the command cap.
    leg = run_episode(NFLeg(), "stream-30-60min", seed=2).metrics
    direct = run_episode(NFDirect(), "stream-30-60min", seed=2).metrics
    assert leg.stream["flights_entered"] == direct.stream["flights_entered"] > 10
    assert leg.los_count == 0
    assert leg.envelope_violation_fraction < 0.1 < direct.envelope_violation_fraction


def test_nf_leg_is_deterministic_bit_for_bit() -> None:
    first = run_episode(NFLeg(), "random-4", seed=3, max_time_s=3600.0)
    second = run_episode(NFLeg(), "random-4", seed=3, max_time_s=3600.0)
    assert np.array_equal(first.waypoints, second.waypoints)
    assert first.metrics.flight_time_min == second.metrics.flight_time_min
