"""Every script under ``bench/`` parses: the benchmarks and studies are run by hand or by
``bench/regenerate.sh`` long after a change, so a syntax error would otherwise surface only
there (a quoted section name once left ``bench/bench_kernel.py`` unparsable)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
SCRIPTS = sorted(BENCH.rglob("*.py"))


def test_the_bench_directory_has_scripts() -> None:
    assert len(SCRIPTS) > 10, SCRIPTS


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: str(p.relative_to(BENCH)))
def test_bench_script_parses(path: Path) -> None:
    ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
