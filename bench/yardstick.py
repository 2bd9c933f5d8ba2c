"""The yardstick of ``bench/bench_kernel.py``: the simulator kernel as it was before its
performance work, rebuilt from the repository's history at bench time.

``frozen_kernel()`` writes ``atc_nf_env/kernel.py`` and ``atc_nf_env/nf.py`` of commit
``FROZEN_COMMIT`` (read with ``git show``) into ``bench/.yardstick/<commit>/frozen_kernel/``
with only their imports pointed at that package, and imports the kernel from there.
``advance`` keeps its entry checks: they are part of what a caller pays per call. numba
caches the compiled copy next to those files, apart from the package's cache, so the
copy is written once and compiled once per machine.

Nothing of the old kernel is tracked: the benchmark measures the current kernel against
it side by side, in one run, so that a speed-up is a ratio on one machine under one
load. The parameter vector of ``atc_nf_env.config.SimConfig.to_params`` is passed
truncated to the old ``nf.N_PARAMS`` (parameters added later are appended).
"""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path
from types import ModuleType

#: The commit whose kernel is the yardstick: the last before the kernel's performance work.
FROZEN_COMMIT = "fe97e17ca6718d565f622eb36bbf8ef3e9f3b124"
#: The files of the old kernel, by the name they get in the rebuilt package.
FROZEN_FILES = {"kernel.py": "atc_nf_env/kernel.py", "nf.py": "atc_nf_env/nf.py"}
#: Each old import and what it becomes: the old kernel imports nothing of today's package.
IMPORT_REWRITES = {
    "kernel.py": (
        ("from atc_nf_env import nf\n", "from frozen_kernel import nf\n"),
        ("from atc_nf_env.nf import FAST_MATH_FLAGS\n", "from frozen_kernel.nf import FAST_MATH_FLAGS\n"),
        ("from atc_nf_env.nf import (\n", "from frozen_kernel.nf import (\n"),
        ("from atc_nf_env.units import SECONDS_PER_HOUR\n", "SECONDS_PER_HOUR = 3600.0\n"),
    ),
    "nf.py": (),
}

REPOSITORY = Path(__file__).resolve().parent.parent
YARDSTICK_DIR = Path(__file__).resolve().parent / ".yardstick"


def _old_source(path: str) -> str:
    """The text of ``path`` at ``FROZEN_COMMIT``; SystemExit naming what is missing."""
    try:
        done = subprocess.run(["git", "-C", str(REPOSITORY), "show", f"{FROZEN_COMMIT}:{path}"],
                              capture_output=True, text=True, check=False)
    except FileNotFoundError:
        raise SystemExit("bench: the kernel yardstick is rebuilt from the repository's history, "
                         "and git is not installed") from None
    if done.returncode != 0:
        raise SystemExit(f"bench: the kernel yardstick needs {path} at commit {FROZEN_COMMIT[:7]}, which "
                         f"this checkout lacks ({done.stderr.strip()}); run from a full clone "
                         "(git fetch --unshallow in a shallow one)")
    return done.stdout


def rebuilt_source(name: str) -> str:
    """The yardstick's ``name`` (``kernel.py`` or ``nf.py``): the old file with its imports
    rewritten; SystemExit if an import to rewrite is not where it was."""
    text = _old_source(FROZEN_FILES[name])
    for old, new in IMPORT_REWRITES[name]:
        if text.count(old) != 1:
            raise SystemExit(f"bench: {FROZEN_FILES[name]} at {FROZEN_COMMIT[:7]} does not import {old.strip()!r} "
                             "once; the yardstick's rewrite no longer fits it")
        text = text.replace(old, new)
    if any(line.lstrip().startswith(("from atc_nf_env", "import atc_nf_env")) for line in text.splitlines()):
        raise SystemExit(f"bench: the rebuilt {name} still imports the package; extend IMPORT_REWRITES")
    header = (f"# The kernel yardstick: {FROZEN_FILES[name]} at commit {FROZEN_COMMIT[:7]}, imports rewritten "
              "by bench/yardstick.py. Generated; not tracked.\n")
    return header + text


def frozen_kernel() -> ModuleType:
    """The old kernel module, written from history on first use and imported."""
    root = YARDSTICK_DIR / FROZEN_COMMIT[:12]
    package = root / "frozen_kernel"
    package.mkdir(parents=True, exist_ok=True)
    for name in FROZEN_FILES:
        text = rebuilt_source(name)
        target = package / name
        if not target.exists() or target.read_text() != text:  # an unchanged file keeps numba's cache
            target.write_text(text)
    init = package / "__init__.py"
    if not init.exists():
        init.write_text('"""The kernel yardstick (bench/yardstick.py). Generated; not tracked."""\n')
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module("frozen_kernel.kernel")
