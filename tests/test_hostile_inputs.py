"""Hypothesis over what a hostile user can pass: env actions, scenario dicts, winds,
seeds, time limits and evaluator files. Every call either gives finite results, or
raises a ValueError/TypeError whose message names the field; none hangs (a deadline
turns a hang into a failure) and no NaN or inf leaves a public function."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _faults import deadline
from atc_nf_env.episode import run_episode
from atc_nf_env.evaluate import Study, evaluate, read_results
from atc_nf_env.scenarios import converging, make_scenario
from baselines import NFDirect

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture],
                    derandomize=True)

floats = st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, -0.0, 1e308, -1e308, 5e-324])
numbers = floats | st.integers(-(2**70), 2**70) | st.booleans()
junk = st.none() | st.text(max_size=5) | st.lists(st.integers(), max_size=3) | st.dictionaries(st.text(max_size=3), st.integers(), max_size=2)
anything = numbers | junk | st.complex_numbers(allow_nan=True, allow_infinity=True)


def assert_finite(value: Any, where: str = "result") -> None:
    """No NaN or inf anywhere in a (nested) result."""
    if isinstance(value, dict):
        for key, item in value.items():
            assert_finite(item, f"{where}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            assert_finite(item, f"{where}[{index}]")
    elif isinstance(value, np.ndarray):
        if value.dtype.kind in "fc":
            assert np.isfinite(value).all(), f"{where} holds NaN or inf"
    elif isinstance(value, (float, np.floating)):
        assert math.isfinite(value), f"{where} = {value}"


def refused_naming(error: Exception, *fields: str) -> None:
    assert isinstance(error, (ValueError, TypeError)), f"{type(error).__name__}: {error}"
    message = str(error)
    assert any(field in message for field in fields), f"the message does not name {fields}: {message}"


# ------------------------------------------------------------ env actions


@pytest.fixture(scope="module")
def env():
    from atc_nf_env.envs.centralized import EncounterEnv

    environment = EncounterEnv(scenario="converging-3", max_episode_minutes=30)
    yield environment
    environment.close()


action_arrays = st.one_of(
    st.lists(st.lists(floats, min_size=2, max_size=2), min_size=3, max_size=3).map(np.array),
    st.lists(st.lists(floats, min_size=1, max_size=3), min_size=1, max_size=4),
    st.lists(st.lists(st.complex_numbers(), min_size=2, max_size=2), min_size=3, max_size=3).map(np.array),
    anything,
)


@SETTINGS
@given(actions=st.lists(action_arrays, min_size=1, max_size=4), seed=st.integers(0, 2**63 - 1))
def test_env_steps_are_finite_or_refused_naming_the_action(env, actions, seed) -> None:
    with deadline(60):
        obs, info = env.reset(seed=seed)
        assert_finite(obs, "observation")
        assert_finite(info, "info")
        for action in actions:
            try:
                obs, reward, terminated, truncated, info = env.step(action)
            except Exception as error:  # noqa: BLE001 - the property is about which errors
                refused_naming(error, "action")
                continue
            assert_finite(obs, "observation")
            assert_finite(reward, "reward")
            assert_finite(info, "info")
            if terminated or truncated:
                env.reset(seed=seed)


# ------------------------------------------------------------ scenario dicts and winds

aircraft = st.fixed_dictionaries(
    {"start": st.lists(numbers, min_size=2, max_size=2) | anything,
     "destination": st.lists(numbers, min_size=2, max_size=2) | anything},
    optional={"heading_deg": numbers | junk, "arrival_heading_deg": numbers | junk, "extra": anything},
)
plausible = st.fixed_dictionaries(
    {"start": st.tuples(st.floats(-300, 300), st.floats(-300, 300)).map(list),
     "destination": st.tuples(st.floats(-300, 300), st.floats(-300, 300)).map(list)},
    optional={"heading_deg": st.floats(-720, 720)},
)
scenario_dicts = st.fixed_dictionaries(
    {"aircraft": st.lists(aircraft | plausible, min_size=0, max_size=3) | anything},
    optional={"workspace_radius_nm": numbers | junk, "start_airspeed_kt": numbers | junk, "name": anything,
              "unknown_key": anything},
)
SCENARIO_FIELDS = ("aircraft", "start", "destination", "heading", "workspace_radius_nm", "start_airspeed_kt",
                   "scenario", "unknown", "dest_xy", "start_xy", "keys")


@SETTINGS
@given(data=scenario_dicts, wind=st.lists(floats, min_size=2, max_size=2) | anything)
def test_scenario_dicts_and_winds_fly_finite_or_are_refused(data, wind) -> None:
    with deadline(60):
        try:
            scenario = make_scenario(data)
        except Exception as error:  # noqa: BLE001
            refused_naming(error, *SCENARIO_FIELDS)
            return
        for name in ("start_xy", "start_heading", "dest_xy", "dest_heading"):
            assert np.isfinite(getattr(scenario, name)).all()
        try:
            result = run_episode(NFDirect(), scenario, seed=0, wind_kt=wind, max_time_s=1800.0)
        except Exception as error:  # noqa: BLE001
            refused_naming(error, "wind_kt", "workspace_radius_nm")
            return
        assert_finite(result.metrics.to_dict(), "metrics")
        assert not result.metrics.success or all(result.metrics.arrived)


@SETTINGS
@given(sigma=numbers | junk, seed=numbers | junk)
def test_wind_sigmas_and_seeds_fly_finite_or_are_refused(sigma, seed) -> None:
    with deadline(60):
        try:
            result = run_episode(NFDirect(), converging(3), seed=seed, wind_sigma_mps=sigma, max_time_s=900.0)
        except Exception as error:  # noqa: BLE001
            refused_naming(error, "wind_sigma", "seed")
            return
        assert_finite(result.metrics.to_dict(), "metrics")


@SETTINGS
@given(seed=numbers | junk)
def test_env_seeds_follow_one_rule(env, seed) -> None:
    import atc_nf_env

    parallel = atc_nf_env.parallel_env(scenario="converging-3")
    outcomes = []
    for reset in (env.reset, parallel.reset):
        try:
            reset(seed=seed)
            outcomes.append("ok")
        except Exception as error:  # noqa: BLE001
            refused_naming(error, "seed")
            outcomes.append(type(error).__name__)
    assert outcomes[0] == outcomes[1], f"the envs disagree on seed {seed!r}: {outcomes}"


# ------------------------------------------------------------ time limits


@SETTINGS
@given(limit=numbers | junk, period=st.sampled_from([300.0, 5.0, 1e-9, 7.0, 0.0]) | floats)
def test_time_limits_end_or_are_refused(limit, period) -> None:
    with deadline(60):
        try:
            result = run_episode(NFDirect(), converging(3), seed=0, max_time_s=limit, period_s=period)
        except Exception as error:  # noqa: BLE001
            refused_naming(error, "max_time_s", "period_s")
            return
        assert result.metrics.sim_time_min * 60.0 <= float(limit) + 1e-6
        assert_finite(result.metrics.to_dict(), "metrics")


# ------------------------------------------------------------ evaluator files

lines = st.one_of(
    st.binary(max_size=40),
    st.sampled_from([b"42", b"null", b"[]", b'"text"', b'{"seed": 1}', b'{"type": "header"}', b"{", b"\xff\xfe"]),
    st.text(max_size=30).map(str.encode),
)


@pytest.fixture(scope="module")
def intact_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("evaluator") / "runs.jsonl"
    evaluate(Study(policy="nf", scenario="converging-3"), 3, workers=1, out=out, progress=False)
    return out.read_bytes()


@SETTINGS
@given(keep=st.integers(0, 4), cut=st.integers(0, 400), tail=st.lists(lines, max_size=3), newline=st.booleans())
def test_evaluator_files_truncated_or_garbled_resume_or_are_refused(tmp_path_factory, intact_file, keep, cut,
                                                                     tail, newline) -> None:
    out = tmp_path_factory.mktemp("case") / "runs.jsonl"
    kept = b"".join(intact_file.splitlines(keepends=True)[:keep])
    content = kept[: max(0, len(kept) - cut)] if cut < 200 else kept
    content += b"\n".join(tail) + (b"\n" if newline and tail else b"")
    out.write_bytes(content)
    with deadline(120):
        try:
            summary = evaluate(Study(policy="nf", scenario="converging-3"), 3, workers=1, out=out, resume=True,
                               progress=False)
        except Exception as error:  # noqa: BLE001
            refused_naming(error, str(out))
            assert out.read_bytes() == content, "a refused file must be left as it was"
            return
    assert_finite(summary, "summary")
    header, runs = read_results(out)  # intact afterwards
    assert header is not None and sorted(r["seed"] for r in runs) == [0, 1, 2]
