"""The baseline table's plumbing (``agents.baselines_table``) on the quick budget, its
statistics on known numbers, and the training options it relies on (``agents.train``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents import baselines_table as bt  # noqa: E402

# ------------------------------------------------------------------ statistics


@pytest.mark.parametrize("p", [0.6, 0.9, 0.975, 0.995])
def test_t_quantile_matches_the_closed_forms_of_one_and_two_degrees_of_freedom(p: float) -> None:
    assert bt.student_t_quantile(p, 1) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=1e-9)
    assert bt.student_t_quantile(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)), rel=1e-9)
    assert bt.student_t_quantile(1 - p, 7) == pytest.approx(-bt.student_t_quantile(p, 7), rel=1e-9)


def test_t_quantile_tends_to_the_normal_one_and_refuses_bad_input() -> None:
    # Φ⁻¹(0.975) = 1.959963984540054; t's quantile exceeds it by about (z³ + z) / (4 df).
    z = 1.959963984540054
    assert bt.student_t_quantile(0.975, 100_000) == pytest.approx(z + (z**3 + z) / 400_000, rel=1e-7)
    for p, df in ((0.0, 3), (1.0, 3), (0.5, 0), (0.5, 2.5), (0.5, True)):
        with pytest.raises(ValueError):
            bt.student_t_quantile(p, df)


def test_t_interval_on_known_numbers() -> None:
    # 1, 2, 3: mean 2, s = 1, half-width t_{0.975, 2} / sqrt(3) with t_{0.975, 2} = 0.95 / sqrt(0.04875).
    mean, low, high = bt.t_interval([1, 2, 3])
    half = 0.95 / math.sqrt(0.04875) / math.sqrt(3)
    assert (mean, low, high) == pytest.approx((2.0, 2.0 - half, 2.0 + half), rel=1e-9)
    assert bt.t_interval([4, 4, 4]) == (4.0, 4.0, 4.0)
    assert bt.t_interval([7]) == (7.0, None, None)
    with pytest.raises(ValueError):
        bt.t_interval([])
    with pytest.raises(ValueError):
        bt.t_interval([1.0, float("nan")])


def test_count_cells_show_the_interval_clipped_to_what_a_count_can_be() -> None:
    stat = {"values": [0, 0, 3], **bt._interval_dict([0, 0, 3])}
    cell = bt._count_cell(stat, 50)
    assert cell.startswith("1.0 [0.0, ") and cell.endswith("/50 (0, 0, 3)")


# ------------------------------------------------------------------ the command on the quick budget


def _quick_argv(tmp_path: Path) -> list[str]:
    return ["--quick", "--tasks", "converging-4", "--algorithms", "ppo", "--out", str(tmp_path / "out"),
            "--write", "--doc", str(tmp_path / "baselines.md"), "--figures", str(tmp_path / "figures")]


def test_quick_table_writes_its_files_resumes_after_a_kill_and_refuses_another_build(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    real = bt.TRAINERS["ppo"]
    calls: list[int] = []
    killed = {"done": False}

    def ppo_killed_once_at_seed_1(task: str, seed: int, budget: bt.Budget, folder: Path) -> dict:
        calls.append(seed)
        if seed == 1 and not killed["done"]:
            killed["done"] = True
            (folder / "partial.txt").write_text("a training run killed half-way")
            raise KeyboardInterrupt  # what a killed command leaves behind
        return real(task, seed, budget, folder)

    monkeypatch.setitem(bt.TRAINERS, "ppo", ppo_killed_once_at_seed_1)
    out = tmp_path / "out"
    (tmp_path / "baselines.md").write_text("# Baselines\n\nProse kept.\n\n<!-- begin baselines -->\nold\n<!-- end baselines -->\n")

    with pytest.raises(KeyboardInterrupt):
        bt.main(_quick_argv(tmp_path))
    seed0 = out / "train" / "converging-4" / "ppo" / "seed0" / "done.json"
    seed1 = out / "train" / "converging-4" / "ppo" / "seed1"
    assert seed0.is_file() and not (seed1 / "done.json").exists()
    first = seed0.read_text()

    assert bt.main(_quick_argv(tmp_path)) == 0
    assert calls == [0, 1, 1]  # seed 0 trained once; seed 1 trained again from scratch
    assert seed0.read_text() == first and not (seed1 / "partial.txt").exists()

    record = json.loads((out / "table.json").read_text())
    rows = {row["algorithm"]: row for row in record["rows"]}
    assert set(rows) == {"mpc", "nf", "ppo"}
    ppo = rows["ppo"]
    assert ppo["seeds"] == [0, 1]
    cards = [json.loads((out / "cards" / "converging-4" / f"ppo-s{s}.json").read_text()) for s in (0, 1)]
    shielded = [json.loads((out / "cards" / "converging-4" / f"ppo-s{s}+shield.json").read_text()) for s in (0, 1)]
    assert [c["split"] for c in cards + shielded] == ["test"] * 4
    assert all(c["seeds"] == [2_000_000_000, 2_000_000_000] for c in cards)
    assert ppo["alone"]["runs_safe"]["values"] == [c["runs_safe"] for c in cards]
    mean, low, high = bt.t_interval([c["runs_home"] for c in shielded])
    assert ppo["shielded"]["runs_home"]["mean"] == mean and ppo["shielded"]["runs_home"]["ci95"] == [low, high]
    assert all(w > 0 for w in ppo["wall_s_per_seed"])
    assert (tmp_path / "figures" / "baselines_converging-4.png").stat().st_size > 1000
    doc = (tmp_path / "baselines.md").read_text()
    assert "Prose kept." in doc and "old" not in doc
    assert f"build `{record['build']}`" in doc and "| converging-4 | ppo | 2 | 512 frames |" in doc
    assert "![Learning curves on converging-4](figures/baselines_converging-4.png)" in doc

    # Another build: refused, nothing mixed.
    manifest = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**manifest, "build": "0123456789abcdef"}))
    capsys.readouterr()
    assert bt.main(_quick_argv(tmp_path)) == 2
    assert "holds results of build 0123456789abcdef" in capsys.readouterr().err
    (out / "manifest.json").write_text(json.dumps(manifest))
    done = json.loads(seed0.read_text())
    seed0.write_text(json.dumps({**done, "build": "0123456789abcdef"}))
    with pytest.raises(ValueError, match="results of two builds are never mixed"):
        bt.run_unit(bt.Unit("ppo", "converging-4", 0), bt.BUDGETS["quick"], out, manifest["build"])


def test_another_budget_and_bad_names_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    bt.open_folder(out, bt.BUDGETS["quick"], restart=False)
    with pytest.raises(ValueError, match="budget 'quick'"):
        bt.open_folder(out, bt.BUDGETS["default"], restart=False)
    assert bt.main(["--quick", "--algorithms", "ppo,sac", "--out", str(out)]) == 2
    assert "'sac' unknown" in capsys.readouterr().err
    assert bt.main(["--quick", "--tasks", "converging-5", "--out", str(out)]) == 2
    assert "converging-5" in capsys.readouterr().err


# ------------------------------------------------------------------ agents.train's options


def test_envelope_margin_penalty_subtracts_the_margin_term_from_the_env_reward() -> None:
    from agents.train import EnvelopeMarginPenalty
    from atc_nf_env.envs.vector import make_sb3_vec_env

    plain = make_sb3_vec_env(2, mode="shared", scenario="converging-4")
    shaped = EnvelopeMarginPenalty(make_sb3_vec_env(2, mode="shared", scenario="converging-4"), 200.0, 0.5)
    for env in (plain, shaped):
        env.seed(7)
        env.reset()
    actions = np.zeros((8, 2), dtype=np.float32)
    _, r_plain, _, _ = plain.step(actions)
    _, r_shaped, _, _ = shaped.step(actions)
    penalty = r_plain - r_shaped
    # The envelope is 174 kt wide: every flying aircraft is within 87 kt of an edge, so a
    # 200 kt margin costs each between 0.5 · (200 − 87) / 200 and the cap 2 · 0.5.
    assert np.all(penalty >= 0.5 * (200 - 87) / 200 - 1e-6) and np.all(penalty <= 1.0 + 1e-6)


def test_train_refuses_the_margin_penalty_outside_the_native_shared_env() -> None:
    from agents.train import Args, check_args

    with pytest.raises(ValueError, match="--vec native"):
        check_args(Args(mode="shared", vec="supersuit", envelope_margin_kt=30.0, envelope_margin_weight=1.0))
    with pytest.raises(ValueError, match="--eval-every"):
        check_args(Args(vec="native", eval_every=-1))


def test_final_evaluation_prints_runs_safe_and_home_per_run(capsys: pytest.CaptureFixture[str]) -> None:
    from agents.train import safety_report

    report = safety_report("nf", "converging-4", 2, 5.17, label="final evaluation")
    line = capsys.readouterr().out
    per_run = report["per_run"]
    # The per-run counts agree with the evaluator's own summary of the same runs; the NF
    # alone aimed 500 nm away breaks the envelope in every run (the paper's Fig. 3).
    assert per_run["runs"] == report["runs"] == 2 and per_run["seeds"] == [0, 1]
    assert per_run["runs_home"] == round(report["success_rate"] * 2)
    assert per_run["runs_with_los"] == report["runs_with_los"]
    assert per_run["runs_outside_envelope"] == report["runs_with_envelope_violation"] == 2
    assert per_run["runs_safe"] == 0
    assert (f"final evaluation on converging-4, seeds 0..1: 0/2 runs safe (with LoS {per_run['runs_with_los']}, "
            f"outside the envelope 2), {per_run['runs_home']}/2 runs home") in line


def test_torchrl_rows_plug_in_through_agents_marl_torchrl(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A stand-in for agents.marl_torchrl (train -> policy.pt, curve.csv, meta.json; a
    loader): its models are trained per seed, copied under their own names, flown through
    an in-process registration and scored like the others. The stand-in's loader flies
    the NF alone, so its cards must equal the NF's on the same seeds."""
    import sys
    import types

    from baselines import NFDirect

    asked: list[tuple[str, str, int, int]] = []

    def train(algorithm: str, task: str, seed: int, frames: int, out: Path) -> Path:
        asked.append((algorithm, task, seed, frames))
        out.mkdir(parents=True, exist_ok=True)
        (out / "policy.pt").write_bytes(f"weights of {algorithm} seed {seed}".encode())
        (out / "curve.csv").write_text(f"frames,wall_s,mean_return\n{frames // 2},1,{seed}\n{frames},2,{seed + 1}\n")
        (out / "meta.json").write_text(json.dumps({"frames": frames, "wall_s": 1.5}))
        return out / "policy.pt"

    fake = types.ModuleType(bt.TORCHRL_MODULE)
    fake.train = train  # type: ignore[attr-defined]
    fake.TorchRLPolicy = lambda path: NFDirect()  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, bt.TORCHRL_MODULE, fake)
    monkeypatch.setattr(bt, "_torchrl_installed", lambda: True)
    out = tmp_path / "out"
    argv = ["--quick", "--tasks", "converging-4", "--algorithms", "ippo", "--out", str(out)]
    assert bt.main(argv) == 0
    # 512 aircraft decisions on 4 aircraft: 128 world periods, TorchRL's frames.
    assert asked == [("ippo", "converging-4", 0, 128), ("ippo", "converging-4", 1, 128)]
    record = json.loads((out / "table.json").read_text())
    row = next(r for r in record["rows"] if r["algorithm"] == "ippo")
    nf = next(r for r in record["rows"] if r["algorithm"] == "nf")
    assert row["seeds"] == [0, 1] and row["wall_s_per_seed"] == [1.5, 1.5] and row["budget"] == "512 frames"
    for part in ("alone", "shielded"):
        for key in ("runs_safe", "runs_home"):
            assert row[part][key]["values"] == nf[part][key]["values"] * 2
    assert (out / "train" / "converging-4" / "ippo" / "seed1" / "ippo-s1.pt").read_bytes() == b"weights of ippo seed 1"
    assert (out / "figures" / "baselines_converging-4.png").is_file()
