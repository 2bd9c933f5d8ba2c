"""Fault tests of the evaluator: SIGKILL a study at several points, damage the last line
of its results file in every way an interruption (or a careless edit) can, resume, and
compare every record and the summary with an uninterrupted run."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from atc_nf_env.cli import main
from atc_nf_env.evaluate import Study, evaluate, read_results, summarize_records

RUNS = 120
ARGS = ["--policy", "nf", "--scenario", "converging-3", "--runs", str(RUNS), "--workers", "1", "--no-progress"]
#: Fields that measure the machine, not the flight.
TIMING_RECORD = {"wall_s", "decision_s_mean", "decision_s_each", "peak_rss_mb", "compile_s"}
TIMING_SUMMARY = {"wall_s_per_run", "decision_s", "peak_rss_mb", "wall_s_per_decision", "policy", "compile_s"}

#: Ways the last line of a results file ends up damaged.
DAMAGE = {
    "cut, no newline": lambda line: line[: len(line) // 2],
    "cut, with newline": lambda line: b'{"seed": 34, "trunc\n',
    "a JSON number": lambda line: b"42\n",
    "JSON null": lambda line: b"null\n",
    "a record without seed": lambda line: json.dumps({"scenario": "converging-3"}).encode() + b"\n",
    "binary garbage": lambda line: b"\x00\xff\xfe garbage",
}


def _flight(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in TIMING_RECORD}


def _outcome(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in TIMING_SUMMARY}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[dict[int, dict], dict]:
    out = tmp_path_factory.mktemp("reference") / "runs.jsonl"
    summary = evaluate(Study(policy="nf", scenario="converging-3"), RUNS, workers=1, out=out, progress=False)
    _, runs = read_results(out)
    return {r["seed"]: _flight(r) for r in runs}, _outcome(summary)


def _kill_when(out: Path, lines: int, resume: bool) -> None:
    """Start `atc-nf evaluate`, SIGKILL it once ``out`` holds ``lines`` lines (or it ends)."""
    command = [sys.executable, "-m", "atc_nf_env.cli", "evaluate", *ARGS, "--out", str(out)]
    process = subprocess.Popen(command + (["--resume"] if resume else []),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 180
    try:
        while time.time() < deadline and process.poll() is None:
            if out.exists() and out.read_bytes().count(b"\n") >= lines:
                break
            time.sleep(0.002)
        else:
            assert process.poll() is not None, "the study neither wrote nor ended within 180 s"
    finally:
        os.kill(process.pid, signal.SIGKILL) if process.poll() is None else None
        process.wait()


def _damage_last_line(path: Path, how) -> None:
    data = path.read_bytes()
    body, _, last = data.rstrip(b"\n").rpartition(b"\n")
    path.write_bytes((body + b"\n" if body else b"") + how(last + b"\n"))


def _resume_and_compare(path: Path, reference, capsys) -> None:
    flights, outcome = reference
    summary_path = path.with_suffix(".summary.json")
    assert main(["evaluate", *ARGS, "--out", str(path), "--resume", "--summary-json", str(summary_path)]) == 0
    capsys.readouterr()
    header, runs = read_results(path)
    assert header is not None and header["policy"] == "nf"
    assert sorted(r["seed"] for r in runs) == list(range(RUNS))  # nothing lost, nothing repeated
    assert {r["seed"]: _flight(r) for r in runs} == flights
    assert _outcome(json.loads(summary_path.read_text())) == outcome
    # The file stays resumable: a second resume runs nothing and changes nothing.
    before = path.read_bytes()
    assert main(["evaluate", *ARGS, "--out", str(path), "--resume"]) == 0
    capsys.readouterr()
    assert path.read_bytes() == before


@pytest.mark.slow  # about 2 minutes; test_evaluate.py kills a study once in the default run
def test_sigkill_at_several_points_then_damage_and_resume(tmp_path, reference, capsys):
    out = tmp_path / "runs.jsonl"
    snapshots = []
    # Kill after the header, early, mid-way and late; each later kill interrupts a resume.
    for index, lines in enumerate((1, 15, 60, 100)):
        _kill_when(out, lines, resume=index > 0)
        snapshot = tmp_path / f"killed{index}.jsonl"
        shutil.copy(out, snapshot)
        snapshots.append(snapshot)
    counts = [len(read_results(s)[1]) for s in snapshots]
    assert sum(0 < count < RUNS for count in counts) >= 2, f"too few kills landed mid-study: {counts}"
    # Resumed as they were left by the kill.
    for snapshot in snapshots:
        copy = tmp_path / f"as-killed-{snapshot.name}"
        shutil.copy(snapshot, copy)
        _resume_and_compare(copy, reference, capsys)
    # And with the last line damaged in every way.
    for snapshot in snapshots:
        for name, how in DAMAGE.items():
            copy = tmp_path / f"{snapshot.stem}-{name.replace(' ', '_').replace(',', '')}.jsonl"
            shutil.copy(snapshot, copy)
            _damage_last_line(copy, how)
            _resume_and_compare(copy, reference, capsys)


def test_a_header_cut_off_while_written_is_rewritten(tmp_path, reference, capsys):
    out = tmp_path / "runs.jsonl"
    out.write_bytes(b'{"type": "header", "policy": ')
    _resume_and_compare(out, reference, capsys)


def test_summary_does_not_depend_on_the_order_runs_finished(reference, tmp_path):
    out = tmp_path / "runs.jsonl"
    evaluate(Study(policy="nf", scenario="converging-3"), 40, workers=1, out=out, progress=False)
    _, runs = read_results(out)
    shuffled = runs[::-1][1::2] + runs[::-1][::2]
    assert summarize_records(shuffled) == summarize_records(runs)


@pytest.mark.parametrize(
    "line, problem",
    [
        (b'{"seed": 1, "trunc\n', "not JSON"),
        (b"42\n", "a JSON int, not an object"),
        (b"null\n", "a JSON NoneType, not an object"),
        (b'{"scenario": "converging-3"}\n', "a run record without"),
    ],
)
def test_a_damaged_line_before_the_last_is_refused_naming_it(tmp_path, line, problem):
    out = tmp_path / "runs.jsonl"
    study = Study(policy="nf", scenario="converging-3")
    evaluate(study, 3, workers=1, out=out, progress=False)
    lines = out.read_bytes().splitlines(keepends=True)
    out.write_bytes(b"".join(lines[:2] + [line] + lines[2:]))
    with pytest.raises(ValueError, match=rf"line 3 is {problem}"):
        evaluate(study, 3, workers=1, out=out, resume=True, progress=False)
    with pytest.raises(ValueError, match=r"line 3 is"):
        read_results(out)


@pytest.mark.parametrize("content", [b"a,b,c\n1,2,3\n", b'{"some": "other"}\n{"seed": 0}\n', b"\x89PNG\r\n\x1a\n\x00\x00"])
def test_a_foreign_file_is_not_taken_for_a_study(tmp_path, content):
    out = tmp_path / "runs.jsonl"
    out.write_bytes(content)
    with pytest.raises(ValueError, match=r"line 1 is .*not a results file of atc-nf evaluate"):
        evaluate(Study(policy="nf", scenario="converging-3"), 2, workers=1, out=out, resume=True, progress=False)
    assert out.read_bytes() == content  # left as it was


def test_resume_from_another_first_seed_is_refused(tmp_path):
    out = tmp_path / "runs.jsonl"
    study = Study(policy="nf", scenario="converging-3")
    evaluate(study, 3, workers=1, out=out, progress=False)
    with pytest.raises(ValueError, match=r"from seed 0, not 5: resuming would mix two ranges"):
        evaluate(study, 3, first_seed=5, workers=1, out=out, resume=True, progress=False)


def test_resume_with_more_or_fewer_runs_covers_exactly_the_seeds_asked(tmp_path):
    out = tmp_path / "runs.jsonl"
    study = Study(policy="nf", scenario="converging-3")
    evaluate(study, 3, workers=1, out=out, progress=False)
    grown = evaluate(study, 5, workers=1, out=out, resume=True, progress=False)
    assert grown["runs"] == 5 and sorted(r["seed"] for r in read_results(out)[1]) == list(range(5))
    shrunk = evaluate(study, 2, workers=1, out=out, resume=True, progress=False)
    assert shrunk == summarize_records([r for r in read_results(out)[1] if r["seed"] < 2])
    assert shrunk["runs"] == 2


def test_without_resume_a_file_holding_anything_is_left_alone(tmp_path):
    out = tmp_path / "runs.jsonl"
    out.write_bytes(b'{"type": "header", "policy": ')
    with pytest.raises(ValueError, match="already holds a study; finish it with --resume"):
        evaluate(Study(policy="nf", scenario="converging-3"), 2, workers=1, out=out, progress=False)
    assert out.read_bytes() == b'{"type": "header", "policy": '


class _Enough(Exception):
    pass


@pytest.mark.parametrize("workers", [1, 2])
def test_an_absurd_number_of_runs_is_planned_lazily(workers):
    from _faults import deadline

    finished = []

    def stop_after_three(record):
        finished.append(record["seed"])
        if len(finished) == 3:
            raise _Enough

    with deadline(120), pytest.raises(_Enough):
        evaluate(Study(policy="nf", scenario="converging-3"), 10**15, workers=workers, progress=False,
                 on_run=stop_after_three)


def test_cli_refuses_seeds_beyond_int64_at_once(capsys):
    assert main(["evaluate", "--runs", "99999999999999999999", "--out", os.devnull, "--no-progress"]) == 2
    assert "seeds run to" in capsys.readouterr().err


_UNGUARDED_SCRIPT = """
from atc_nf_env.evaluate import Study, evaluate
summary = evaluate(Study(policy="nf", scenario="converging-3"), runs=4, workers=2, progress=False)
print("finished", summary["runs"])
"""


def test_a_script_without_the_main_guard_fails_fast_saying_what_to_add(tmp_path):
    script = tmp_path / "study.py"
    script.write_text(_UNGUARDED_SCRIPT)
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                            cwd=tmp_path)
    assert result.returncode != 0
    assert 'if __name__ == "__main__":' in result.stderr
    # Each of the 2 workers dies once; none is restarted.
    assert result.stderr.count("Traceback") <= 3
    assert len(result.stderr.splitlines()) < 150


def test_the_same_script_with_the_guard_runs(tmp_path):
    script = tmp_path / "study.py"
    body = "\n".join("    " + line for line in _UNGUARDED_SCRIPT.strip().splitlines()[1:])
    script.write_text("from atc_nf_env.evaluate import Study, evaluate\n\nif __name__ == \"__main__\":\n" + body + "\n")
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "finished 4" in result.stdout
