"""Compiled callers never fly a stale copy of what they call (atc_nf_env.compile_cache).

Numba judges a cached function fresh from its own file only; the project stamps each
cached function with the files its module imports as well. The probe: a cached caller in
one module, a cached callee and a constant in another, compiled into an on-disk cache,
then the callee's module edited alone and the caller run again in a fresh process.
"""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numba
import pytest

import atc_nf_env
from atc_nf_env import compile_cache

PACKAGE = Path(atc_nf_env.__file__).resolve().parent

CALLEE = """
from numba import njit
{install}
SCALE = {scale}


@njit(cache=True)
def scaled(x):
    return SCALE * x
"""

CALLER = """
from numba import njit

from atc_nf_env._probe_callee import scaled
{install}

@njit(cache=True)
def twice(x):
    return scaled(x) + scaled(x)
"""

INSTALL = "from atc_nf_env import compile_cache\ncompile_cache.install()\n"


def _fly(root: Path, env: dict[str, str]) -> float:
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import atc_nf_env, atc_nf_env._probe_caller as c; "
            "assert atc_nf_env.__file__.startswith(sys.argv[1]), atc_nf_env.__file__; print(c.twice(1.0))")
    done = subprocess.run([sys.executable, "-c", code, str(root)], capture_output=True, text=True, env=env,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    return float(done.stdout.strip().splitlines()[-1])


def _probe(tmp_path: Path, stamped: bool, cache_dir: Path | None) -> tuple[float, float]:
    """(the caller's result before, after an edit of the callee's module alone)."""
    root = tmp_path / "copy"
    shutil.copytree(PACKAGE, root / "atc_nf_env", ignore=shutil.ignore_patterns("__pycache__"))
    install = INSTALL if stamped else ""
    (root / "atc_nf_env" / "_probe_caller.py").write_text(CALLER.format(install=install))
    callee = root / "atc_nf_env" / "_probe_callee.py"
    callee.write_text(CALLEE.format(install=install, scale="2.0"))
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = str(cache_dir)
    before = _fly(root, env)
    assert _fly(root, env) == before  # the second run loads the cache
    callee.write_text(CALLEE.format(install=install, scale="3.0"))
    return before, _fly(root, env)


def test_numba_alone_flies_a_stale_callee(tmp_path: Path) -> None:
    """The defect the stamp exists for: without it, the caller keeps the old callee."""
    assert _probe(tmp_path, stamped=False, cache_dir=None) == (4.0, 4.0)


@pytest.mark.parametrize("where", ["in-tree", "NUMBA_CACHE_DIR"])
def test_an_edit_of_a_callees_module_alone_recompiles_its_callers(tmp_path: Path, where: str) -> None:
    cache_dir = tmp_path / "numba-cache" if where == "NUMBA_CACHE_DIR" else None
    assert _probe(tmp_path, stamped=True, cache_dir=cache_dir) == (4.0, 6.0)


#: The modules of the project that cache compiled functions on disk.
CACHING_MODULES = ("atc_nf_env.kernel", "atc_nf_env.law", "atc_nf_env.nf", "atc_nf_env.trig", "atc_nf_env.neighbour_grid",
                   "atc_nf_env.shield_prediction", "atc_nf_env.envs.actions", "atc_nf_env.envs.centralized",
                   "atc_nf_env.envs.observations", "atc_nf_env.envs.rewards", "baselines.mcmc_mpc",
                   "agents.compiled_forward")


def test_the_list_holds_every_module_that_caches() -> None:
    roots = {"atc_nf_env": PACKAGE, **{k: v for k, v in compile_cache.package_roots().items()}}
    found = set()
    for name, root in roots.items():
        for path in root.rglob("*.py"):
            if "cache=True" in path.read_text():
                parts = path.relative_to(root.parent).with_suffix("").parts
                found.add(".".join(parts))
    assert found == set(CACHING_MODULES)


def test_every_cached_function_of_the_project_is_stamped_by_its_imports() -> None:
    checked = 0
    for name in CACHING_MODULES:
        module = importlib.import_module(name)
        for value in vars(module).values():
            cache = getattr(value, "_cache", None)
            if isinstance(value, numba.core.registry.CPUDispatcher) and value.__module__ == name \
                    and hasattr(cache, "_impl"):
                assert type(cache._impl.locator).__name__.startswith("DependencyStamped"), (name, value)
                checked += 1
    assert checked >= 50


def test_the_callers_of_the_kernel_depend_on_the_law() -> None:
    names = lambda module: {p.relative_to(PACKAGE.parent).as_posix()  # noqa: E731
                            for p in compile_cache.import_closure(PACKAGE / module)}
    for caller in ("envs/centralized.py", "shield_prediction.py", "kernel.py"):
        assert {"atc_nf_env/kernel.py", "atc_nf_env/nf.py", "atc_nf_env/trig.py",
                "atc_nf_env/neighbour_grid.py"} <= names(caller), caller
    assert "atc_nf_env/config.py" in names("envs/centralized.py")
    assert "atc_nf_env/cli.py" not in names("envs/centralized.py")  # not imported: never inlined


def test_imports_are_read_from_the_text() -> None:
    source = ("import numpy as np\nfrom atc_nf_env import nf, trig as t  # why\nfrom atc_nf_env.kernel import (\n"
              "    A,\n    B,  # note\n)\n    from atc_nf_env.cli import main\n")
    assert compile_cache._imported_modules(source) == {
        "numpy", "atc_nf_env", "atc_nf_env.nf", "atc_nf_env.trig", "atc_nf_env.kernel", "atc_nf_env.kernel.A",
        "atc_nf_env.kernel.B"}
