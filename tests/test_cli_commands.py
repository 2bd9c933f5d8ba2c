"""The ``atc-nf`` command line as people meet it: the subcommands that come through the
``atc_nf_env.commands`` entry points, a clear message where an extra is missing, and the
study table of ``evaluate``."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, requires

import pytest

from atc_nf_env import cli
from atc_nf_env.evaluate import Study
from atc_nf_env.tables import evaluate_table, run_is_safe


class _EntryPoint:
    """An entry point whose module needs a library that is not installed."""

    def __init__(self, name: str, missing: str) -> None:
        self.name, self.value, self.missing = name, f"somewhere.{name}:main", missing

    def load(self):
        raise ModuleNotFoundError(f"No module named {self.missing!r}", name=self.missing)


def _installed_requirements() -> list[str]:
    try:
        return requires("atc-nf-env") or []
    except PackageNotFoundError:
        pytest.skip("atc-nf-env is not installed (no metadata to read its extras from)")


def test_a_subcommand_without_its_extra_names_the_extra(monkeypatch, capsys) -> None:
    assert any("torch" in r and "extra" in r and "rl" in r for r in _installed_requirements())
    monkeypatch.setattr(cli, "_plugin_commands", lambda: {"train": _EntryPoint("train", "torch")})
    assert cli.main(["train", "--steps", "10"]) == 2
    err = capsys.readouterr().err
    assert "`atc-nf train` needs the rl extra: pip install 'atc-nf-env[rl]'" in err
    assert "Traceback" not in err


def test_a_missing_library_of_no_extra_is_not_disguised(monkeypatch) -> None:
    _installed_requirements()
    monkeypatch.setattr(cli, "_plugin_commands", lambda: {"train": _EntryPoint("train", "no_such_library")})
    with pytest.raises(ModuleNotFoundError, match="no_such_library"):
        cli.main(["train"])


def test_the_extras_are_read_from_the_installed_metadata() -> None:
    _installed_requirements()
    assert cli._extra_providing("stable_baselines3.common") == "rl"
    assert cli._extra_providing("torch") == "rl"
    assert cli._extra_providing("numpy") is None  # a core dependency
    assert cli._extra_providing(None) is None


def test_the_project_s_commands_come_through_entry_points() -> None:
    plugins = cli._plugin_commands()
    assert {"train", "imitate"} <= set(plugins)
    assert plugins["train"].value == "agents.train:main"


def test_a_command_of_the_project_missing_from_the_install_says_how_to_fix_it(monkeypatch, capsys) -> None:
    monkeypatch.setattr(cli, "_plugin_commands", lambda: {})
    assert cli.main(["imitate"]) == 2
    assert "reinstall" in capsys.readouterr().err


def test_the_help_lists_every_command(capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    for command in ("fly", "evaluate", "reproduce", "train", "imitate"):
        assert f"\n    {command}" in text


def _record(seed: int, los: int = 0, outside: float = 0.0) -> dict:
    return {"seed": seed, "los_count": los, "envelope_violation_fraction": outside, "decisions": 10,
            "policy_info": {"start_kept": 7}}


def test_the_study_table_counts_safe_runs_per_run() -> None:
    records = [_record(0), _record(1, los=1), _record(2, outside=0.01), _record(3, los=2, outside=0.5)]
    assert [run_is_safe(r) for r in records] == [True, False, False, False]
    summary = {"runs": 4, "success_rate": 0.75, "success_rate_ci95": [0.3, 0.95],
               "flight_time_min": {"mean": 66.04, "max": 70.26}, "min_separation_nm": {"min": 4.1, "mean": 9.87,
                                                                                      "max": 12.0},
               "airspeed_kt": {"min": 360.4, "max": 541.6}, "decision_s": {"mean": 0.01234, "p99": 0.0456},
               "fallbacks": 2, "decisions": 40}
    study = Study(policy="nf", scenario="converging-3")
    text = evaluate_table(summary, records, study, first_seed=5)
    lines = text.splitlines()
    assert lines[0] == "nf on converging-3, wind σ 5.17 m/s, seeds 5–8"
    assert "  safe runs              1/4 (no loss of separation, no step outside [366, 540] kt)" in lines
    assert "  every aircraft home    3/4 (95 % interval 30.0–95.0 %)" in lines
    assert "  flight time (arrived)  66.0 min mean, 70.3 min max" in lines
    assert "  airspeed range         360–542 kt" in lines
    assert "  decision time          12.3 ms mean, 45.6 ms p99" in lines
    assert "  chain start kept       28 of 40 decisions applied the chain's start unmoved" in lines
