"""The MPC's many-run safety claim at a size that fits every CI run: 50 seeded runs each
of the paper's 4- and 6-aircraft encounters under the paper's wind, asserted run by run
(the 1000-run version is ``test_reproduction_slow.py``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from atc_nf_env.config import SimConfig
from atc_nf_env.evaluate import Study, evaluate, read_results

RUNS = 50


@pytest.fixture(scope="module", params=[4, 6], ids=["converging-4", "converging-6"])
def mpc_runs(request, tmp_path_factory) -> list[dict]:
    path = tmp_path_factory.mktemp("safety") / "runs.jsonl"
    evaluate(Study(policy="mpc", scenario=f"converging-{request.param}"), RUNS, workers=2, out=path, progress=False)
    _, records = read_results(path)
    assert sorted(r["seed"] for r in records) == list(range(RUNS))
    return records


def _seeds(records: list[dict], bad) -> list[int]:
    return sorted(r["seed"] for r in records if bad(r))


def test_every_aircraft_arrives_in_every_run(mpc_runs) -> None:
    assert _seeds(mpc_runs, lambda r: not all(r["arrived"])) == []


def test_no_run_loses_separation(mpc_runs) -> None:
    assert _seeds(mpc_runs, lambda r: r["los_count"] > 0) == []
    assert min(r["min_separation_nm"] for r in mpc_runs) >= 5.0


def test_no_integration_step_leaves_the_envelope(mpc_runs) -> None:
    config = SimConfig()
    assert _seeds(mpc_runs, lambda r: r["envelope_violation_fraction"] > 0) == []
    assert min(r["airspeed_min_kt"] for r in mpc_runs) >= config.airspeed_min_kt
    assert max(r["airspeed_max_kt"] for r in mpc_runs) <= config.airspeed_max_kt


def test_no_decision_falls_back(mpc_runs) -> None:
    assert _seeds(mpc_runs, lambda r: r["policy_info"]["fallbacks"] > 0) == []
