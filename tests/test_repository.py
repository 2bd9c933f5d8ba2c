"""The repository holds the product, not its history: no large files outside the shipped
models, and every benchmark script that the regeneration, the Makefile or a published
table names exists (one-off probes live in git history, not under ``bench/``)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The largest tracked file allowed outside ``agents/models/``, bytes.
MAX_FILE_BYTES = 2_000_000
#: Files that name the bench scripts they run or publish.
REFERRERS = ("bench/regenerate.sh", "Makefile", "REPRODUCTION.md")
BENCH_PATH = re.compile(r"bench/[\w/]+\.(?:py|sh|patch)")


def _tracked_files() -> list[Path]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True, capture_output=True).stdout
    return [ROOT / name for name in names.decode().split("\0") if name]


def test_no_large_file_is_tracked_outside_the_shipped_models() -> None:
    large = [
        (str(path.relative_to(ROOT)), path.stat().st_size)
        for path in _tracked_files()
        if path.is_file() and path.stat().st_size > MAX_FILE_BYTES and "agents/models/" not in path.as_posix()
    ]
    assert large == []


def test_bench_scripts_named_by_the_regeneration_and_the_tables_exist() -> None:
    named = {
        match
        for referrer in REFERRERS
        for match in BENCH_PATH.findall((ROOT / referrer).read_text(encoding="utf-8"))
    }
    for script in (ROOT / "bench").glob("*.py"):  # the scripts' own "Run:" lines and cross-references
        if script.name != "bench_kernel.py":  # its published text is rewritten with the kernel's next figures
            named.update(BENCH_PATH.findall(script.read_text(encoding="utf-8")))
    assert {"bench/bench_mpc.py", "bench/bench_kernel.py"} <= named  # the pattern finds what it should
    missing = sorted(name for name in named if not (ROOT / name).is_file())
    assert missing == []


def test_bench_has_no_one_off_experiments_folder() -> None:
    assert not (ROOT / "bench" / "experiments").exists()
