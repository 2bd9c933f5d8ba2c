"""Reliability, round 4: results that could silently be wrong or lost.

A resumed study whose header differs from the new one in any run-determining key, in
either direction, is refused; Ctrl-C in ``atc-nf benchmark`` (and ``evaluate``) is one
line; ``read_results`` takes a str; a score card never silently replaces another card
and its folder is checked before anything flies; the benchmark's results files are
labelled so that two models never share one, nor take the MPC reference's.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atc_nf_env import benchmark, cli
from atc_nf_env.evaluate import LABEL_KEYS, Study, differing_header_keys, evaluate, read_results

ROOT = Path(__file__).resolve().parents[1]
#: A short study: 10 minutes of flight per run.
SHORT_S = 600.0


def _env() -> dict[str, str]:
    """The environment of a child Python that imports this checkout first."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


# ------------------------------------------------------------ item 1: resume compares both ways


def _study(**kwargs) -> Study:
    return Study(policy="nf", scenario="converging-3", max_time_s=SHORT_S, **kwargs)


def test_resume_refuses_a_shielded_study_resumed_without_the_shield(tmp_path) -> None:
    out = tmp_path / "m.jsonl"
    evaluate(_study(shield=True), 1, workers=1, out=out, progress=False)
    before = out.read_bytes()
    with pytest.raises(ValueError, match=r"holds a different study \(shield True there, missing here\)"):
        evaluate(_study(), 2, workers=1, out=out, resume=True, progress=False)
    assert out.read_bytes() == before  # nothing appended under the shielded header


def test_resume_refuses_an_unshielded_study_resumed_with_the_shield_and_accepts_the_same_study(tmp_path) -> None:
    out = tmp_path / "m.jsonl"
    evaluate(_study(), 1, workers=1, out=out, progress=False)
    with pytest.raises(ValueError, match=r"holds a different study \(shield missing there, True here\)"):
        evaluate(_study(shield=True), 2, workers=1, out=out, resume=True, progress=False)
    evaluate(_study(), 2, workers=1, out=out, resume=True, progress=False)
    header, runs = read_results(str(out))
    assert "shield" not in header and sorted(r["seed"] for r in runs) == [0, 1]


def test_resume_refuses_a_header_with_a_key_the_new_one_lacks(tmp_path) -> None:
    out = tmp_path / "m.jsonl"
    evaluate(_study(), 1, workers=1, out=out, progress=False)
    header, *runs = out.read_text().splitlines()
    out.write_text("\n".join([json.dumps({**json.loads(header), "future_setting": 3}), *runs]) + "\n")
    with pytest.raises(ValueError, match=r"future_setting 3 there, missing here"):
        evaluate(_study(), 2, workers=1, out=out, resume=True, progress=False)


def test_the_command_line_resume_of_the_issue_is_refused_in_one_line(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    common = ["--policy", "nf", "--scenario", "converging-4", "--out", "m.jsonl", "--no-progress", "--workers", "1",
              "--max-minutes", "10"]
    assert cli.main(["evaluate", "--shield", "--runs", "2", *common]) == 0
    capsys.readouterr()
    assert cli.main(["evaluate", "--runs", "4", "--resume", *common]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "holds a different study (shield True there, missing here)" in error
    assert len(read_results("m.jsonl")[1]) == 2


headers = st.dictionaries(st.sampled_from(["format", "policy", "scenario", "shield", "wind_sigma_mps", "build", "x"]),
                          st.one_of(st.none(), st.booleans(), st.integers(-2, 2), st.text(max_size=2)), max_size=7)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(headers, headers)
def test_two_headers_differ_exactly_where_a_key_is_missing_on_one_side_or_its_values_differ(old, new) -> None:
    differing = differing_header_keys(old, new)
    assert set(differing) == set(differing_header_keys(new, old))  # the same both ways
    compared = lambda h: {k: v for k, v in h.items() if k not in LABEL_KEYS}  # noqa: E731
    assert (not differing) == (compared(old) == compared(new))
    for key in differing:
        assert key not in LABEL_KEYS and (key not in old or key not in new or old[key] != new[key])
    # A key missing on one side differs even from a None on the other.
    assert differing_header_keys({"shield": None}, {}) == ["shield"]


def test_the_agents_benchmark_copies_no_mpc_runs_of_a_shielded_study(tmp_path) -> None:
    from agents.benchmark import reuse_mpc_runs

    flown = tmp_path / "flown.jsonl"
    evaluate(_study(), 1, workers=1, out=flown, progress=False)
    run_lines = flown.read_text().splitlines()[1:]
    mpc = Study(policy="mpc", scenario="converging-3")
    for name, extra, copied in (("plain", {}, 1), ("shielded", {"shield": True}, 0)):
        source = tmp_path / name
        source.mkdir()
        (source / "mpc.jsonl").write_text("\n".join([json.dumps({**mpc.header(), **extra}), *run_lines]) + "\n")
        assert reuse_mpc_runs(mpc, 1, source, tmp_path / f"{name}-copy.jsonl") == copied


# ------------------------------------------------------------ item 17: Ctrl-C is one line


@pytest.mark.parametrize("command, target", [("benchmark", "atc_nf_env.benchmark.score_card"),
                                             ("evaluate", "atc_nf_env.evaluate.evaluate")])
def test_ctrl_c_prints_one_line_and_exits_130(command, target, monkeypatch, capsys) -> None:
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(target, interrupted)
    argv = {"benchmark": ["--task", "converging-4", "--split", "validation", "--runs", "1"],
            "evaluate": ["--runs", "1", "--max-minutes", "10"]}[command]
    assert cli.main([command, "--policy", "nf", "--no-progress", *argv]) == cli.INTERRUPTED_STATUS == 130
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith(f"atc-nf {command}: interrupted (Ctrl-C)")


@pytest.mark.slow  # a real benchmark flying until SIGINT, half a minute or more on 2 busy cores
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals a process group")
def test_sigint_in_a_flying_benchmark_is_one_line(tmp_path) -> None:
    runs = tmp_path / "runs"
    # Ctrl-C as an interactive terminal delivers it (a suite started in a shell's background
    # inherits SIGINT ignored).
    interactive = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
                   "sys.argv[0] = 'atc-nf'; runpy.run_module('atc_nf_env.cli', run_name='__main__')")
    command = [sys.executable, "-c", interactive, "benchmark", "--policy", "nf", "--task", "random-4", "--split",
               "validation", "--runs", "10000", "--workers", "2", "--no-progress", "--no-reference",
               "--results-dir", str(runs)]
    process = subprocess.Popen(command, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    results = runs / "random-4" / "validation" / "nf.jsonl"
    try:
        limit = time.time() + 240
        while time.time() < limit and (not results.exists() or results.read_text().count("\n") < 2):
            assert process.poll() is None, "the benchmark ended before it was interrupted"
            time.sleep(0.2)
        os.killpg(process.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
        _, error = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 130, error
    assert error.count("\n") == 1 and error.startswith("atc-nf benchmark: interrupted (Ctrl-C)"), error
    assert len(read_results(results)[1]) >= 1  # the finished runs are kept


# ------------------------------------------------------------ smaller: read_results takes str and PathLike


def test_read_results_takes_a_str_and_a_pathlike_and_refuses_other_types(tmp_path) -> None:
    out = tmp_path / "r.jsonl"
    evaluate(_study(), 1, workers=1, out=out, progress=False)
    assert read_results(str(out)) == read_results(out)
    assert read_results(str(tmp_path / "missing.jsonl")) == (None, [])
    for wrong in (3, None, b"r.jsonl"):
        with pytest.raises(TypeError, match="str or an os.PathLike"):
            read_results(wrong)


# ------------------------------------------------------------ smaller: the card file, checked before flying


def _card(**changes) -> dict:
    card = {"suite_version": benchmark.SUITE_VERSION, "task": "converging-4", "split": "validation", "policy": "nf",
            "shield": False, "runs": 1, "score": 0.5}
    return {**card, **changes}


@pytest.fixture
def scoring(monkeypatch) -> list:
    """``score_card`` replaced by one that records its calls and returns a card at once."""
    calls: list = []

    def score_card(policy, task, split, runs, **kwargs):
        calls.append((policy, task, split, runs))
        return {**_card(policy=policy, task=task, split=split, runs=runs, shield=kwargs["shield"]),
                "seeds": [1, 1], "runs_home": 1, "runs_safe": 1, "runs_with_los": 0, "runs_outside_envelope": 0,
                "flight_time_min_mean": 1.0, "flight_time_ratio_to_mpc": None, "decision_ms_mean": 1.0,
                "decision_ms_p99": 1.0}

    monkeypatch.setattr(benchmark, "score_card", score_card)
    return calls


ARGS = ["--policy", "nf", "--task", "converging-4", "--split", "validation", "--runs", "1"]


@pytest.mark.parametrize("existing, why", [
    (_card(task="converging-6"), "task 'converging-6' there, 'converging-4' here"),
    (_card(runs=100), "runs 100 there, 1 here"),
    (_card(shield=True), "shield True there, False here"),
    ({k: v for k, v in _card().items() if k != "split"}, "split missing there, 'validation' here"),
    ("the only copy of my notes\n", "exists and is not a score card"),
])
def test_the_card_never_silently_replaces_another_file(existing, why, tmp_path, scoring, capsys) -> None:
    out = tmp_path / "card.json"
    text = existing if isinstance(existing, str) else json.dumps(existing)
    out.write_text(text)
    assert benchmark.main([*ARGS, "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert why in error and "--overwrite" in error and error.count("\n") == 1
    assert out.read_text() == text and scoring == []  # refused before anything flew
    assert benchmark.main([*ARGS, "--out", str(out), "--overwrite"]) == 0
    assert json.loads(out.read_text())["task"] == "converging-4"


def test_the_same_card_is_replaced_by_its_rescoring(tmp_path, scoring) -> None:
    out = tmp_path / "card.json"
    assert benchmark.main([*ARGS, "--out", str(out)]) == 0
    assert benchmark.main([*ARGS, "--out", str(out)]) == 0
    assert len(scoring) == 2 and json.loads(out.read_text())["runs"] == 1


def test_a_card_into_a_missing_folder_is_refused_before_anything_flies(tmp_path, scoring, capsys) -> None:
    assert cli.main(["benchmark", *ARGS, "--out", str(tmp_path / "nodir" / "card.json")]) == 2
    error = capsys.readouterr().err
    assert "the folder" in error and "does not exist" in error and scoring == []


# ------------------------------------------------------------ smaller: one results file per model


def test_results_labels_are_unique_per_model_and_never_a_reference_name(tmp_path, monkeypatch) -> None:
    for folder, content in (("a", b"one model"), ("b", b"another model"), ("c", b"one model")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "policy.pt").write_bytes(content)
    (tmp_path / "mpc.zip").write_bytes(b"a model named mpc")
    paths: list[Path] = []
    monkeypatch.setattr(benchmark, "_study_records", lambda policy, task, split, runs, shield, path, *rest:
                        paths.append(path) or [])
    monkeypatch.setattr(benchmark, "card_from_records", lambda *args: {})
    for policy in ("a/policy.pt", "b/policy.pt", "c/policy.pt", "mpc.zip"):
        benchmark.score_card(str(tmp_path / policy), "converging-4", "validation", 1, results_dir=tmp_path / "runs")
    names = [p.name for p in paths]
    # a, b: two models of one name; c: a's bytes; each model flew with the MPC reference after it.
    model_a, mpc, model_b, _, model_c, _, model_mpc, reference = names
    assert mpc == reference == "mpc.jsonl"
    assert len({model_a, model_b, model_mpc, mpc}) == 4 and model_c == model_a
    assert model_a.startswith("policy@") and model_a.endswith(".pt.jsonl") and model_mpc.endswith(".zip.jsonl")
    assert benchmark.results_label(str(tmp_path / "mpc.zip"), shield=True).endswith("+shield.zip")
    assert benchmark.results_label("mpc", shield=True) == "mpc+shield"
    with pytest.raises(ValueError, match="cannot read the model file"):
        benchmark.results_label(str(tmp_path / "missing.pt"))


def test_the_agents_benchmark_refuses_two_studies_of_one_label(tmp_path) -> None:
    from agents import benchmark as agents_benchmark

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for path in (tmp_path / "mpc.zip", tmp_path / "a" / "bc.zip", tmp_path / "b" / "bc.zip"):
        path.write_bytes(b"not flown")
    for models, shared in (([tmp_path / "mpc.zip"], "'mpc'"), ([tmp_path / "a" / "bc.zip", tmp_path / "b" / "bc.zip"],
                                                               "'bc'")):
        with pytest.raises(ValueError, match=f"share the label {shared}"):
            agents_benchmark.run([str(m) for m in models], ["converging-3"], runs=1, mpc_runs=1, out=tmp_path / "o",
                                 reuse_mpc=None, workers=1, progress=False)
    assert not (tmp_path / "o").exists()  # refused before anything flew
