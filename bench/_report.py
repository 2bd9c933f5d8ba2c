"""Write a benchmark's section into BENCHMARKS.md, replacing that section's last version."""

from __future__ import annotations

import platform
from pathlib import Path

import os

BENCHMARKS = Path(__file__).resolve().parent.parent / "BENCHMARKS.md"
HEADER = (
    "# Benchmarks\n\nFigures printed by the scripts under `bench/` (each rewrites its own section "
    "with `--write`). Medians over repeats; ratios are from runs side by side.\n"
)


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def write_section(name: str, text: str) -> None:
    """Replace the section delimited by markers named ``name`` (or append it)."""
    begin, end = f"<!-- begin {name} -->", f"<!-- end {name} -->"
    current = BENCHMARKS.read_text() if BENCHMARKS.exists() else HEADER
    block = f"{begin}\n{text.rstrip()}\n{end}"
    if begin in current and end in current:
        head, rest = current.split(begin, 1)
        _, tail = rest.split(end, 1)
        current = head + block + tail
    else:
        current = current.rstrip() + "\n\n" + block + "\n"
    BENCHMARKS.write_text(current)
