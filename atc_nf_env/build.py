"""A fingerprint of the build that flies a run, so that stored runs are reused only by
the build that made them.

Two builds that differ in any source a run goes through (the kernel, the NF, the
configuration, the scenarios, the episode loop, the metrics, the evaluator, the
baselines) or in the numerical libraries can give different trajectories for the same
seed. Results files record the fingerprint in their header (``evaluate.Study.header``);
a study is resumed only from runs of the same fingerprint.
"""

from __future__ import annotations

import hashlib
import platform
from functools import lru_cache
from pathlib import Path

#: Sources of the ``atc_nf_env`` package that determine a run, relative to the package.
PACKAGE_SOURCES: tuple[str, ...] = (
    "kernel.py",
    "nf.py",
    "trig.py",
    "config.py",
    "units.py",
    "scenarios.py",
    "simulation.py",
    "episode.py",
    "metrics.py",
    "policy.py",
    "evaluate.py",
    "shield.py",
    "shield_prediction.py",
)


def source_files() -> list[Path]:
    """The files hashed into the fingerprint: ``PACKAGE_SOURCES`` and every module of
    ``baselines``."""
    import atc_nf_env
    import baselines

    package = Path(atc_nf_env.__file__).parent
    files = [package / name for name in PACKAGE_SOURCES]
    files += sorted(Path(baselines.__file__).parent.glob("*.py"))
    return files


@lru_cache(maxsize=1)
def fingerprint() -> str:
    """16 hex digits: SHA-256 of the run-determining sources and of the versions of
    Python, NumPy and numba (their code rounds too)."""
    import numba
    import numpy

    digest = hashlib.sha256()
    for path in source_files():
        digest.update(f"{path.parent.name}/{path.name}".encode() + b"\0" + path.read_bytes() + b"\0")
    versions = f"python {platform.python_version()} numpy {numpy.__version__} numba {numba.__version__}"
    digest.update(versions.encode())
    return digest.hexdigest()[:16]
