"""The core package never imports the packages built on it (``baselines``, ``agents``):
it reaches their policies and commands through entry points (``atc_nf_env.policy``,
``atc_nf_env.cli``), so the core installs, imports and documents on its own."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "atc_nf_env"
UPWARD = ("baselines", "agents")
def _upward_imports(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [f"{path.relative_to(PACKAGE)}:{node.lineno} {name}" for name in names
                  if name.split(".")[0] in UPWARD]
    return found


def test_no_module_of_the_core_imports_baselines_or_agents() -> None:
    sources = sorted(PACKAGE.rglob("*.py"))
    assert len(sources) > 20
    upward = [hit for path in sources for hit in _upward_imports(path)]
    assert upward == []


def test_the_scan_finds_an_upward_import(tmp_path: Path) -> None:
    sample = PACKAGE / "_upward_sample.py"
    try:
        sample.write_text("def f():\n    from baselines.mcmc_mpc import MCMCMPC\n    import agents.policy\n")
        assert _upward_imports(sample) == ["_upward_sample.py:2 baselines.mcmc_mpc", "_upward_sample.py:3 agents.policy"]
    finally:
        sample.unlink()


_BLOCKED_IMPORT = r"""
import importlib, pkgutil, sys

class Blocked:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("baselines", "agents"):
            raise ImportError(f"upward import of {name}")
        return None

sys.meta_path.insert(0, Blocked())
import atc_nf_env
names = [m.name for m in pkgutil.walk_packages(atc_nf_env.__path__, "atc_nf_env.")]
imported = 0
for name in names:
    try:
        importlib.import_module(name)
        imported += 1
    except ModuleNotFoundError as error:  # an integration's optional library (BenchMARL, ...)
        if error.name is None or error.name.split(".")[0] in ("atc_nf_env", "baselines", "agents"):
            raise
from atc_nf_env import cli
try:
    cli.main(["--help"])
except SystemExit as exit_:
    assert exit_.code == 0
print(imported, sorted(m for m in sys.modules if m.split(".")[0] in ("baselines", "agents", "torch")))
"""


def test_every_core_module_and_the_cli_help_import_with_the_upper_packages_blocked() -> None:
    out = subprocess.run([sys.executable, "-c", _BLOCKED_IMPORT], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    count, loaded = out.stdout.strip().splitlines()[-1].split(" ", 1)
    assert int(count) > 20 and loaded == "[]"


def test_cli_help_loads_neither_the_simulator_nor_torch() -> None:
    code = ("import sys\nfrom atc_nf_env import cli\ntry:\n    cli.main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numba', 'torch', 'baselines', 'agents', 'atc_nf_env.kernel') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"
    assert "train" in out.stdout and "fly" in out.stdout
