"""Write a benchmark's section into BENCHMARKS.md, replacing that section's last version."""

from __future__ import annotations

import platform
from pathlib import Path

import os

from atc_nf_env.experiments.marked_sections import write_marked_section

BENCHMARKS = Path(__file__).resolve().parent.parent / "BENCHMARKS.md"
HEADER = (
    "# Benchmarks\n\nFigures printed by the scripts under `bench/` (each rewrites its own section "
    "with `--write`). Medians over repeats; ratios are from runs side by side.\n"
)


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def write_section(name: str, text: str) -> None:
    """Replace the section delimited by markers named ``name`` (or append it)."""
    write_marked_section(BENCHMARKS, name, text, header=HEADER)


def publish(name: str, text: str, write: bool) -> int:
    """Print a benchmark's section and, with ``write`` (its ``--write``), put it into
    BENCHMARKS.md; the script's exit status (0)."""
    print(text)
    if write:
        write_section(name, text)
    return 0
