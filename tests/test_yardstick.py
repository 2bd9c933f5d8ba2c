"""The kernel yardstick of ``bench/bench_kernel.py`` is rebuilt from git history, not
tracked: the rebuilt files are the old ones but for the imports the rewrite names, and
they import nothing of today's package (a benchmark of the old kernel against itself
would read as "no speed-up" and hide a regression)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))
import yardstick  # noqa: E402

HAS_HISTORY = subprocess.run(["git", "-C", str(BENCH.parent), "cat-file", "-e", f"{yardstick.FROZEN_COMMIT}^{{commit}}"],
                             capture_output=True, check=False).returncode == 0


@pytest.mark.skipif(not HAS_HISTORY, reason="a shallow clone or an sdist: no history to rebuild the yardstick from")
@pytest.mark.parametrize("name", sorted(yardstick.FROZEN_FILES))
def test_the_rebuilt_yardstick_is_the_old_file_with_only_its_imports_rewritten(name: str) -> None:
    old = subprocess.run(["git", "-C", str(BENCH.parent), "show", f"{yardstick.FROZEN_COMMIT}:{yardstick.FROZEN_FILES[name]}"],
                         capture_output=True, text=True, check=True).stdout.splitlines()
    rebuilt = yardstick.rebuilt_source(name).splitlines()
    assert rebuilt[0].startswith("# The kernel yardstick"), rebuilt[0]
    assert len(rebuilt) == len(old) + 1
    changed = [(a, b) for a, b in zip(old, rebuilt[1:]) if a != b]
    assert changed == [(a.rstrip("\n"), b.rstrip("\n")) for a, b in yardstick.IMPORT_REWRITES[name]]
    assert not any(line.startswith(("from atc_nf_env", "import atc_nf_env")) for line in rebuilt)


def test_a_missing_commit_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(yardstick, "FROZEN_COMMIT", "0" * 40)
    with pytest.raises(SystemExit, match="kernel yardstick needs atc_nf_env/kernel.py at commit 0000000"):
        yardstick.rebuilt_source("kernel.py")
