"""Reliability, round 4: the baseline table never writes a row it could not run, and the
TorchRL learning curves are plotted against frames.

The committed docs/baselines.md said "not run: torchrl is not installed in this
environment" in its IPPO and MAPPO rows while its text discussed their results: a
regeneration in a venv without TorchRL exited 0. And the TorchRL curves were plotted
against the ``batch`` column (0 … 74) under the label "frames", because the axis was
converted only when the curve's first column was named ``frames``.
"""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path

import pytest

from agents import baselines_table as bt

MISSING = "torchrl is not installed in this environment (examples/requirements-torch.txt)"
OLD_DOC = "# Baselines\n\nProse kept.\n\n<!-- begin baselines -->\nold\n<!-- end baselines -->\n"


@pytest.fixture
def no_torchrl(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bt, "torchrl_trainer", lambda: (None, MISSING))

    def never(*args: object, **kwargs: object) -> dict:
        raise AssertionError("a table that cannot run every row trained something")

    for trainer in bt.TRAINERS:
        monkeypatch.setitem(bt.TRAINERS, trainer, never)


def _argv(tmp_path: Path, algorithms: str, *more: str) -> list[str]:
    return ["--quick", "--tasks", "converging-4", "--algorithms", algorithms, "--out", str(tmp_path / "out"), *more]


def _write_args(tmp_path: Path) -> list[str]:
    return ["--write", "--doc", str(tmp_path / "baselines.md"), "--figures", str(tmp_path / "figures")]


@pytest.mark.parametrize("write", [True, False])
def test_a_table_without_torchrl_fails_naming_the_library_and_the_venv(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], no_torchrl: None, write: bool) -> None:
    (tmp_path / "baselines.md").write_text(OLD_DOC)
    argv = _argv(tmp_path, "ppo,ippo,mappo", *(_write_args(tmp_path) if write else []))
    assert bt.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "ippo, mappo need TorchRL" in err and "torchrl is not installed" in err
    assert "make baselines" in err and ".venv-torch" in err
    assert (tmp_path / "baselines.md").read_text() == OLD_DOC  # nothing written, no "not run" row
    assert not (tmp_path / "out").exists()  # failed before training or scoring anything


def test_write_refuses_skip_unavailable(tmp_path: Path, capsys: pytest.CaptureFixture[str], no_torchrl: None) -> None:
    (tmp_path / "baselines.md").write_text(OLD_DOC)
    assert bt.main(_argv(tmp_path, "ppo", "--skip-unavailable", *_write_args(tmp_path))) == 2
    assert "--write with --skip-unavailable" in capsys.readouterr().err
    assert (tmp_path / "baselines.md").read_text() == OLD_DOC


def test_restart_without_torchrl_keeps_the_folder(tmp_path: Path, no_torchrl: None) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "finished.json").write_text("{}")
    assert bt.main(_argv(tmp_path, "mappo", "--restart")) == 2
    assert (out / "finished.json").is_file()  # --restart empties nothing when the command cannot run


def test_skip_unavailable_is_explicit_and_says_so_in_the_row(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_torchrl: None) -> None:
    monkeypatch.setattr(bt, "REFERENCES", ("nf",))  # the NF's single quick run: seconds
    assert bt.unavailable_rows(["ppo", "bc"]) == {}
    with pytest.raises(bt.RowNotRun, match="mappo need TorchRL"):
        bt.unavailable_rows(["ppo", "mappo"])
    assert bt.main(_argv(tmp_path, "mappo", "--skip-unavailable")) == 0
    record = json.loads((tmp_path / "out" / "table.json").read_text())
    (row,) = [r for r in record["rows"] if r["algorithm"] == "mappo"]
    assert row["note"] == f"left out (--skip-unavailable): {MISSING}"


def test_a_learner_that_trains_no_model_fails_the_table(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(bt, "REFERENCES", ("nf",))
    monkeypatch.setitem(bt.TRAINERS, "ppo", lambda task, seed, budget, folder: {})
    (tmp_path / "baselines.md").write_text(OLD_DOC)
    assert bt.main(_argv(tmp_path, "ppo", *_write_args(tmp_path))) == 2
    assert "ppo on converging-4: no training seed produced a model" in capsys.readouterr().err
    assert (tmp_path / "baselines.md").read_text() == OLD_DOC


# ------------------------------------------------------------------ item 8: the curves' axis

#: agents.marl_torchrl's curve.csv: one row per evaluation point, batch 0 first.
CURVE = ("batch,frames,wall_s,train_return_mean,eval_runs,eval_safe_share,eval_home_share,eval_return_mean\n"
         "0,0,0.5,nan,2,0.0,1.0,-3.0\n"
         "10,2560,10.0,-2.5,2,0.5,1.0,-2.0\n"
         "20,5120,20.0,-1.5,2,1.0,1.0,-1.0\n")
META = {"frames": 5120, "wall_s": 20.0, "ppo": {"num_envs": 8, "steps_per_batch": 32}}


def test_torchrl_curve_is_in_aircraft_decisions_from_the_frames_column(tmp_path: Path) -> None:
    path = tmp_path / "curve.csv"
    path.write_text(CURVE)
    curve = bt.torchrl_curve(path, META, n_aircraft=4)
    assert curve is not None
    assert curve["x"] == [0.0, 2560.0 * 4, 5120.0 * 4]  # not the batches 0, 10, 20
    assert curve["y"][1:] == [-2.5, -1.5]


def test_torchrl_curve_by_batch_counts_the_batch_frames_from_the_config(tmp_path: Path) -> None:
    path = tmp_path / "curve.csv"
    path.write_text("batch,wall_s,train_return_mean\n0,0.5,-3\n10,10,-2.5\n20,20,-1.5\n")
    curve = bt.torchrl_curve(path, META, n_aircraft=4)
    assert curve is not None and curve["x"] == [0.0, 10 * 8 * 32 * 4.0, 20 * 8 * 32 * 4.0]
    with pytest.raises(ValueError, match="no num_envs and steps_per_batch"):
        bt.torchrl_curve(path, {"frames": 5120}, n_aircraft=4)
    path.write_text("step,train_return_mean\n1,2\n")
    with pytest.raises(ValueError, match="no frames or batch column"):
        bt.torchrl_curve(path, META, n_aircraft=4)
    assert bt.torchrl_curve(tmp_path / "absent.csv", META, n_aircraft=4) is None


def test_torchrl_rows_plot_frames_through_the_table(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A stand-in trainer writing marl_torchrl's curve format: the table's recorded curve,
    the one plotted under "frames", ends at the run's frames in aircraft decisions."""
    from baselines import NFDirect

    def train(algorithm: str, task: str, seed: int, frames: int, out: Path) -> Path:
        out.mkdir(parents=True, exist_ok=True)
        (out / "policy.pt").write_bytes(b"weights")
        (out / "curve.csv").write_text(CURVE)
        (out / "meta.json").write_text(json.dumps(META))
        return out / "policy.pt"

    fake = types.ModuleType(bt.TORCHRL_MODULE)
    fake.train = train  # type: ignore[attr-defined]
    fake.TorchRLPolicy = lambda path: NFDirect()  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, bt.TORCHRL_MODULE, fake)
    monkeypatch.setattr(bt, "_torchrl_installed", lambda: True)
    monkeypatch.setattr(bt, "REFERENCES", ("nf",))
    plotted: dict[str, list] = {}
    real_plot = bt.plot_curves

    def plot(task, curves, axes_labels, path):  # type: ignore[no-untyped-def]
        plotted.update(curves=curves["ippo"], label=axes_labels["ippo"][0])
        return real_plot(task, curves, axes_labels, path)

    monkeypatch.setattr(bt, "plot_curves", plot)
    assert bt.main(_argv(tmp_path, "ippo")) == 0
    assert plotted["label"] == "frames"
    assert [c["x"] for c in plotted["curves"]] == [[0.0, 10240.0, 20480.0]] * 2
    done = json.loads((tmp_path / "out" / "train" / "converging-4" / "ippo" / "seed0" / "done.json").read_text())
    assert done["models"]["ippo"]["frames"] == 5120 * 4 == plotted["curves"][0]["x"][-1]
