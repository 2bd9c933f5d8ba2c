"""Scenarios: the paper's converging encounters, seeded random ones, dict/JSON input, and
the ValueErrors that reject impossible input (each naming the offending field and value)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atc_nf_env.scenarios import (
    ENCOUNTER_RADIUS_NM,
    WORKSPACE_RADIUS_NM,
    Scenario,
    converging,
    make_scenario,
    random_encounter,
    scenario_from_dict,
    scenario_from_json,
)
from atc_nf_env.units import AIRSPEED_NOMINAL_KT, SEPARATION_MIN_NM


def _pairwise_min(points: np.ndarray) -> float:
    n = points.shape[0]
    diff = points[:, None, :] - points[None, :, :]
    sep = np.hypot(diff[..., 0], diff[..., 1]) + np.diag(np.full(n, np.inf))
    return float(sep.min())


def _unit(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def _assert_same_scenario(a: Scenario, b: Scenario) -> None:
    # Scenario's generated __eq__ compares numpy arrays inside a tuple, so compare fields.
    assert a.name == b.name
    assert a.n_aircraft == b.n_aircraft
    np.testing.assert_allclose(a.start_xy, b.start_xy, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.dest_xy, b.dest_xy, rtol=0, atol=1e-12)
    # Headings pass through degrees and back: equal as directions, to rounding.
    np.testing.assert_allclose(_unit(a.start_heading), _unit(b.start_heading), rtol=0, atol=1e-12)
    np.testing.assert_allclose(_unit(a.dest_heading), _unit(b.dest_heading), rtol=0, atol=1e-12)
    assert a.start_airspeed_kt == b.start_airspeed_kt
    assert a.workspace_radius_nm == b.workspace_radius_nm


def _one_aircraft(**entry_overrides) -> dict:
    entry = {"start": [0.0, 0.0], "destination": [100.0, 0.0]}
    entry.update(entry_overrides)
    return {"aircraft": [entry]}


# --------------------------------------------------------------------------- converging


@pytest.mark.parametrize("n", [3, 4, 6])
def test_converging_geometry(n: int) -> None:
    s = converging(n)
    assert isinstance(s, Scenario)
    assert s.name == f"converging-{n}"
    assert s.n_aircraft == n
    assert s.start_xy.shape == (n, 2) and s.dest_xy.shape == (n, 2)
    assert s.start_heading.shape == (n,) and s.dest_heading.shape == (n,)

    # On the 250 nm circle.
    np.testing.assert_allclose(np.hypot(*s.start_xy.T), ENCOUNTER_RADIUS_NM, rtol=1e-12)
    np.testing.assert_allclose(np.hypot(*s.dest_xy.T), ENCOUNTER_RADIUS_NM, rtol=1e-12)

    # Evenly spaced: consecutive polar angles differ by 2π/n, starting at angle 0.
    angles = np.mod(np.arctan2(s.start_xy[:, 1], s.start_xy[:, 0]), 2 * np.pi)
    np.testing.assert_allclose(np.sort(angles), 2 * np.pi * np.arange(n) / n, atol=1e-12)
    np.testing.assert_allclose(s.start_xy[0], [ENCOUNTER_RADIUS_NM, 0.0], atol=1e-12)
    chord = 2 * ENCOUNTER_RADIUS_NM * math.sin(math.pi / n)
    assert _pairwise_min(s.start_xy) == pytest.approx(chord, rel=1e-12)

    # Headings point at the centre.
    toward_centre = -s.start_xy / np.hypot(*s.start_xy.T)[:, None]
    np.testing.assert_allclose(_unit(s.start_heading), toward_centre, atol=1e-12)
    assert np.all(np.abs(s.start_heading) <= np.pi + 1e-12)

    # Destinations diametrically opposite; arrival headings equal to the start headings.
    np.testing.assert_allclose(s.dest_xy, -s.start_xy, atol=1e-12)
    np.testing.assert_array_equal(s.dest_heading, s.start_heading)

    assert s.start_airspeed_kt == AIRSPEED_NOMINAL_KT
    assert s.workspace_radius_nm == WORKSPACE_RADIUS_NM


def test_converging_custom_radius_and_kwargs() -> None:
    s = converging(4, radius_nm=100.0, workspace_radius_nm=500.0, start_airspeed_kt=400.0)
    np.testing.assert_allclose(np.hypot(*s.start_xy.T), 100.0, rtol=1e-12)
    assert s.workspace_radius_nm == 500.0
    assert s.start_airspeed_kt == 400.0


@pytest.mark.parametrize("n", [0, -1])
def test_converging_rejects_n_below_one(n: int) -> None:
    with pytest.raises(ValueError, match=rf"\bn = {n}\b.*>= 1"):
        converging(n)


def test_converging_rejects_non_integer_n() -> None:
    with pytest.raises(ValueError, match=r"\bn = 3\.0\b"):
        converging(3.0)  # type: ignore[arg-type]


@pytest.mark.parametrize("radius", [0.0, -250.0, float("nan"), float("inf")])
def test_converging_rejects_bad_radius(radius: float) -> None:
    with pytest.raises(ValueError, match=rf"radius_nm = {radius!r}"):
        converging(3, radius_nm=radius)


def test_converging_too_many_aircraft_start_in_conflict() -> None:
    # 400 aircraft on a 250 nm circle are 3.9 nm apart: closer than the 5 nm minimum.
    with pytest.raises(ValueError, match=r"start_xy: aircraft \d+ and \d+ start 3\.\d\d nm apart"):
        converging(400)


def test_converging_outside_the_workspace() -> None:
    with pytest.raises(ValueError, match=r"start_xy\[0\] = \[250\.0, 0\.0\] lies 250\.0 nm"):
        converging(3, workspace_radius_nm=200.0)


# --------------------------------------------------------------------------- random


def test_random_encounter_same_seed_is_identical() -> None:
    a = random_encounter(5, seed=123)
    b = random_encounter(5, seed=123)
    for name in ("start_xy", "start_heading", "dest_xy", "dest_heading"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.metadata == {"seed": 123}
    assert a.name == "random-5"


def test_random_encounter_different_seed_differs() -> None:
    a = random_encounter(5, seed=1)
    b = random_encounter(5, seed=2)
    assert not np.array_equal(a.start_xy, b.start_xy)
    assert not np.array_equal(a.dest_xy, b.dest_xy)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 8),
    seed=st.integers(0, 2**32 - 1),
    min_sep=st.floats(SEPARATION_MIN_NM, 60.0),
)
def test_random_encounter_respects_min_separation(n: int, seed: int, min_sep: float) -> None:
    s = random_encounter(n, seed=seed, min_separation_nm=min_sep)
    assert s.n_aircraft == n
    np.testing.assert_allclose(np.hypot(*s.start_xy.T), ENCOUNTER_RADIUS_NM, rtol=1e-12)
    np.testing.assert_allclose(np.hypot(*s.dest_xy.T), ENCOUNTER_RADIUS_NM, rtol=1e-12)
    if n > 1:
        assert _pairwise_min(s.start_xy) >= min_sep
        assert _pairwise_min(s.dest_xy) >= min_sep
    # Each aircraft heads for its destination, and arrives with that heading.
    bearing = np.arctan2(*(s.dest_xy - s.start_xy)[:, ::-1].T)
    np.testing.assert_allclose(_unit(s.start_heading), _unit(bearing), atol=1e-12)
    np.testing.assert_array_equal(s.dest_heading, s.start_heading)


def test_random_encounter_large_separation() -> None:
    s = random_encounter(4, seed=7, min_separation_nm=200.0)
    assert _pairwise_min(s.start_xy) >= 200.0
    assert _pairwise_min(s.dest_xy) >= 200.0


def test_random_encounter_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match=r"\bn = 0\b"):
        random_encounter(0, seed=0)
    with pytest.raises(ValueError, match=r"radius_nm = -1\.0"):
        random_encounter(3, seed=0, radius_nm=-1.0)
    with pytest.raises(ValueError, match=r"min_separation_nm = 1\.0"):
        random_encounter(3, seed=0, min_separation_nm=1.0)
    with pytest.raises(ValueError, match=r"n = 1000 aircraft"):
        random_encounter(1000, seed=0)


# --------------------------------------------------------------------------- dict / JSON


@pytest.mark.parametrize("make", [lambda: converging(3), lambda: converging(6), lambda: random_encounter(4, seed=9)])
def test_to_dict_round_trip(make) -> None:
    original = make()
    data = original.to_dict()
    assert set(data) == {"name", "workspace_radius_nm", "start_airspeed_kt", "aircraft"}
    assert len(data["aircraft"]) == original.n_aircraft
    # JSON-ready: survives a dump/load unchanged.
    assert json.loads(json.dumps(data)) == data
    _assert_same_scenario(scenario_from_dict(data), original)


def test_to_dict_headings_in_degrees() -> None:
    data = converging(4).to_dict()
    # Aircraft 1 starts at (0, 250) and heads south: -90 degrees.
    assert data["aircraft"][1]["start"] == pytest.approx([0.0, 250.0], abs=1e-9)
    assert data["aircraft"][1]["heading_deg"] == pytest.approx(-90.0)
    assert data["aircraft"][1]["arrival_heading_deg"] == pytest.approx(-90.0)


def test_scenario_from_dict_defaults() -> None:
    s = scenario_from_dict({"aircraft": [{"start": [0, 0], "destination": [0, 100]}]})
    assert s.name == "custom"
    assert s.n_aircraft == 1
    assert s.start_heading[0] == pytest.approx(math.pi / 2)  # bearing to the destination
    assert s.dest_heading[0] == pytest.approx(math.pi / 2)
    assert s.workspace_radius_nm == WORKSPACE_RADIUS_NM
    assert s.start_airspeed_kt == AIRSPEED_NOMINAL_KT


def test_scenario_from_json(tmp_path) -> None:
    original = converging(4)
    path = tmp_path / "four.json"
    path.write_text(json.dumps(original.to_dict()))
    _assert_same_scenario(scenario_from_json(path), original)
    _assert_same_scenario(scenario_from_json(str(path)), original)
    # make_scenario resolves a .json path too.
    _assert_same_scenario(make_scenario(str(path)), original)


def test_scenario_from_json_missing_file(tmp_path) -> None:
    path = tmp_path / "absent.json"
    with pytest.raises(ValueError, match=r"scenario file .*absent\.json.* does not exist"):
        scenario_from_json(path)
    with pytest.raises(ValueError, match=r"absent\.json.* does not exist"):
        make_scenario(str(path))


def test_scenario_from_json_invalid_json(tmp_path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{"aircraft": [')
    with pytest.raises(ValueError, match=r"scenario file .*broken\.json.* is not valid JSON"):
        scenario_from_json(path)


def test_scenario_from_json_not_a_dict(tmp_path) -> None:
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"must be a dict, got list"):
        scenario_from_json(path)


def test_unknown_top_level_key() -> None:
    data = converging(3).to_dict()
    data["wind"] = 3
    with pytest.raises(ValueError, match=r"unknown scenario keys \['wind'\]"):
        scenario_from_dict(data)


def test_unknown_aircraft_key() -> None:
    data = converging(3).to_dict()
    data["aircraft"][2]["altitude_ft"] = 33000
    with pytest.raises(ValueError, match=r"aircraft\[2\]: unknown keys \['altitude_ft'\]"):
        scenario_from_dict(data)


@pytest.mark.parametrize("aircraft", [[], None, "a"])
def test_empty_or_missing_aircraft(aircraft) -> None:
    with pytest.raises(ValueError, match=re.escape(f"aircraft = {aircraft!r}") + r".*n >= 1"):
        scenario_from_dict({"aircraft": aircraft})


def test_missing_aircraft_key() -> None:
    with pytest.raises(ValueError, match=r"aircraft = None"):
        scenario_from_dict({"name": "x"})


@pytest.mark.parametrize(
    "value, shown",
    [([1.0], r"\[1\.0\]"), ("0,0", r"'0,0'"), ([1.0, "2"], r"\[1\.0, '2'\]"), (None, "None")],
)
def test_malformed_point(value, shown) -> None:
    with pytest.raises(ValueError, match=rf"aircraft\[0\]\.start = {shown}: must be \[x, y\]"):
        scenario_from_dict(_one_aircraft(start=value))


def test_start_in_conflict() -> None:
    data = {
        "aircraft": [
            {"start": [0.0, 0.0], "destination": [200.0, 0.0]},
            {"start": [3.0, 4.0 - 1e-3], "destination": [-200.0, 0.0]},  # 4.999 nm away
        ]
    }
    with pytest.raises(ValueError, match=r"start_xy: aircraft 0 and 1 start 5\.00 nm apart, in conflict"):
        scenario_from_dict(data)
    # Exactly 5 nm apart is allowed.
    data["aircraft"][1]["start"] = [3.0, 4.0]
    assert scenario_from_dict(data).n_aircraft == 2


def test_start_in_conflict_clearly() -> None:
    data = {
        "aircraft": [
            {"start": [10.0, 0.0], "destination": [200.0, 0.0]},
            {"start": [12.0, 0.0], "destination": [-200.0, 0.0]},
        ]
    }
    with pytest.raises(ValueError, match=r"start_xy: aircraft 0 and 1 start 2\.00 nm apart"):
        scenario_from_dict(data)


def test_start_outside_workspace() -> None:
    data = _one_aircraft(start=[1600.0, 0.0])
    with pytest.raises(ValueError, match=r"start_xy\[0\] = \[1600\.0, 0\.0\] lies 1600\.0 nm"):
        scenario_from_dict(data)


def test_destination_outside_workspace() -> None:
    data = _one_aircraft(destination=[0.0, -1499.0])  # inside the circle, but not the disk's room
    with pytest.raises(ValueError, match=r"dest_xy\[0\] = \[0\.0, -1499\.0\] lies 1499\.0 nm"):
        scenario_from_dict(data)


def test_outside_a_smaller_workspace() -> None:
    data = _one_aircraft(destination=[300.0, 0.0])
    data["workspace_radius_nm"] = 200.0
    with pytest.raises(ValueError, match=r"dest_xy\[0\] = \[300\.0, 0\.0\]"):
        scenario_from_dict(data)


@pytest.mark.parametrize("radius", [0, -10.0])
def test_workspace_radius_not_positive(radius) -> None:
    data = _one_aircraft()
    data["workspace_radius_nm"] = radius
    with pytest.raises(ValueError, match=rf"workspace_radius_nm = {float(radius)!r}: must be .* > 0"):
        scenario_from_dict(data)


def test_workspace_radius_not_a_number() -> None:
    data = _one_aircraft()
    data["workspace_radius_nm"] = "big"
    with pytest.raises(ValueError, match=r"workspace_radius_nm = 'big': must be a number"):
        scenario_from_dict(data)


def test_nan_coordinates() -> None:
    with pytest.raises(ValueError, match=r"start_xy contains NaN"):
        scenario_from_dict(_one_aircraft(start=[float("nan"), 0.0]))
    with pytest.raises(ValueError, match=r"dest_xy contains NaN"):
        scenario_from_dict(_one_aircraft(destination=[0.0, float("inf")]))
    with pytest.raises(ValueError, match=r"start_heading contains NaN"):
        scenario_from_dict(_one_aircraft(heading_deg=float("nan")))


def test_nan_in_json_file(tmp_path) -> None:
    path = tmp_path / "nan.json"
    path.write_text('{"aircraft": [{"start": [NaN, 0], "destination": [100, 0]}]}')
    with pytest.raises(ValueError, match=r"start_xy contains NaN"):
        scenario_from_json(path)


def test_bad_start_airspeed() -> None:
    data = _one_aircraft()
    data["start_airspeed_kt"] = -1
    with pytest.raises(ValueError, match=r"start_airspeed_kt = -1\.0"):
        scenario_from_dict(data)


def test_scenario_constructor_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match=r"start_xy has shape \(3,\)"):
        Scenario("x", [0.0, 0.0, 0.0], [0.0], [[1.0, 1.0]], [0.0])
    with pytest.raises(ValueError, match=r"dest_xy has shape \(2, 2\); expected \(1, 2\)"):
        Scenario("x", [[0.0, 0.0]], [0.0], [[1.0, 1.0], [2.0, 2.0]], [0.0])
    with pytest.raises(ValueError, match=r"number of aircraft n = 0"):
        Scenario("x", np.zeros((0, 2)), [], np.zeros((0, 2)), [])


# --------------------------------------------------------------------------- make_scenario


@pytest.mark.parametrize("n", [3, 4, 6])
def test_make_scenario_converging_by_name(n: int) -> None:
    _assert_same_scenario(make_scenario(f"converging-{n}"), converging(n))


def test_make_scenario_random_by_name_uses_seed() -> None:
    s = make_scenario("random-4", seed=11)
    _assert_same_scenario(s, random_encounter(4, seed=11))
    assert s.metadata == {"seed": 11}
    # Without a seed: seed 0.
    _assert_same_scenario(make_scenario("random-4"), random_encounter(4, seed=0))


def test_make_scenario_passes_through_scenarios_and_dicts() -> None:
    s = converging(3)
    assert make_scenario(s) is s
    _assert_same_scenario(make_scenario(s.to_dict()), s)


@pytest.mark.parametrize("name", ["converging-0", "random-0", "converging-00"])
def test_make_scenario_zero_aircraft(name: str) -> None:
    with pytest.raises(ValueError, match=rf"scenario '{name}'.*number of aircraft must be >= 1"):
        make_scenario(name)


@pytest.mark.parametrize("name", ["nope", "converging", "converging-x", "converging--3", "diverging-3", ""])
def test_make_scenario_unknown_name(name: str) -> None:
    with pytest.raises(ValueError, match=rf"unknown scenario '{name}'"):
        make_scenario(name)


def test_make_scenario_wrong_type() -> None:
    with pytest.raises(ValueError, match=r"scenario = 42"):
        make_scenario(42)  # type: ignore[arg-type]
