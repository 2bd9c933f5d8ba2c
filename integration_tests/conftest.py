"""Helpers of the integration tests (``make test-integrations``): each test file runs in
the venv of its library, outside the default suite."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def run_example():
    """Run ``examples/NAME`` with this interpreter; returns its stdout (asserting exit 0)."""

    def run(name: str, *args: str, timeout_s: float = 900) -> str:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        done = subprocess.run(
            [sys.executable, str(ROOT / "examples" / name), *args],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout_s,
        )
        assert done.returncode == 0, f"{name} {args} failed:\n{done.stdout[-4000:]}\n{done.stderr[-8000:]}"
        return done.stdout

    return run
