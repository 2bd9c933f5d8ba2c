"""Numba's on-disk caches of this project, kept consistent across modules.

Numba judges a cached function fresh when the file that defines it is unchanged: a
compiled caller in ``envs/centralized.py`` or ``shield_prediction.py`` that inlines the
kernel's functions (and the constants it reads from ``config.py`` or ``nf.py``, frozen at
compile time) would keep flying the old law after an edit of ``kernel.py`` alone. Here
each cached function of the project's packages is stamped, beside numba's own stamp of its
file, with the code of every project module its file imports, directly or through others
(``import_closure``). An edit of any of them (a comment included) makes the cache stale
and numba compiles again.

``install()`` puts the locators in front of numba's own; ``atc_nf_env``'s ``__init__``
calls it before any compiled module is imported (numba picks a function's locator when
its decorator runs). Nothing changes for functions outside the project's packages.
"""

from __future__ import annotations

import hashlib
import re
from functools import lru_cache
from pathlib import Path
from typing import Any

@lru_cache(maxsize=1)
def package_roots() -> dict[str, Path]:
    """{package name: its directory} of the core and of the packages built on it that
    provide policies (``build.plugin_roots``: found without importing them, as the core
    never imports the packages built on it)."""
    from atc_nf_env.build import plugin_roots

    roots = {"atc_nf_env": Path(__file__).resolve().parent}
    roots.update({name: root for name, root in plugin_roots().items() if root.is_dir()})
    return roots


def _module_file(module: str, roots: dict[str, Path]) -> Path | None:
    """The source file of ``module`` (dotted name) if it is one of the project's modules."""
    top, _, rest = module.partition(".")
    if top not in roots:
        return None
    base = roots[top].joinpath(*rest.split(".")) if rest else roots[top]
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate.resolve()
    return None


#: An import statement at the start of a line (module level, as the project writes them):
#: ``import a.b`` or ``from a.b import c, d`` (names possibly in parentheses over lines).
_IMPORT = re.compile(r"^(?:import\s+([\w.]+)|from\s+([\w.]+)\s+import\s+(\([^)]*\)|[^\n]*))", re.MULTILINE)


def _imported_modules(source: str) -> set[str]:
    """Dotted names of the modules a module imports at its top level (``from a import b``
    gives ``a`` and, in case ``b`` is a submodule, ``a.b``); absolute imports only, as the
    project writes them. Read from the text, not the syntax tree (parsing the kernel would
    cost every process a quarter of a second): an import quoted at the start of a line of
    a docstring counts too, which can only add a dependency, never hide one."""
    names: set[str] = set()
    for plain, module, imported in _IMPORT.findall(source):
        if plain:
            names.add(plain)
            continue
        names.add(module)
        for name in imported.strip("()").replace("\n", ",").split(","):
            name = name.split("#")[0].strip().split(" as ")[0].strip()
            if name.isidentifier():
                names.add(f"{module}.{name}")
    return names


@lru_cache(maxsize=None)
def _parsed(path: Path) -> tuple[str, frozenset[str]]:
    """(SHA-256 of the file's bytes, the modules it imports)."""
    data = path.read_bytes()
    return hashlib.sha256(data).hexdigest(), frozenset(_imported_modules(data.decode("utf-8", "replace")))


def import_closure(path: Path) -> list[Path]:
    """``path`` and every project module it imports, directly or through other project
    modules, sorted."""
    roots = package_roots()
    seen: set[Path] = set()
    todo = [Path(path).resolve()]
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        for module in _parsed(current)[1]:
            found = _module_file(module, roots)
            if found is not None and found not in seen:
                todo.append(found)
    return sorted(seen)


@lru_cache(maxsize=None)
def dependency_stamp(path: Path) -> str:
    """SHA-256 (hex) over the bytes of ``import_closure(path)``: what a compiled function
    defined in ``path`` can have inlined or frozen."""
    roots = package_roots()
    digest = hashlib.sha256()
    for file in import_closure(path):
        root = next((r for r in roots.values() if r in file.parents), file.parent)
        digest.update(f"{file.relative_to(root.parent).as_posix()}\n{_parsed(file)[0]}\n".encode())
    return digest.hexdigest()


def _in_project(py_file: str) -> bool:
    try:
        path = Path(py_file).resolve()
    except (OSError, ValueError):
        return False
    return any(root in path.parents for root in package_roots().values())


def _stamped(locator_class: type) -> type:
    """``locator_class`` (a numba cache locator backed by a source file), for the project's
    files only, with the dependency stamp added to its source stamp."""

    class Stamped(locator_class):  # type: ignore[misc, valid-type]
        def get_source_stamp(self) -> Any:
            return (super().get_source_stamp(), dependency_stamp(Path(self._py_file).resolve()))

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if not _in_project(py_file):
                return None
            return super().from_function(py_func, py_file)

    Stamped.__name__ = Stamped.__qualname__ = f"DependencyStamped{locator_class.__name__}"
    return Stamped


_installed: list[type] = []


def install() -> None:
    """Put the stamped locators (a user-given ``NUMBA_CACHE_DIR`` first, as numba does, then
    the package's ``__pycache__``) in front of numba's own; a second call does nothing."""
    if _installed:
        return
    from numba.core import caching

    def named(name: str) -> Any:  # numba 0.68 dropped the leading underscore of these names
        found = getattr(caching, name, None) or getattr(caching, "_" + name, None)
        if found is None:
            import numba

            raise RuntimeError(f"numba {numba.__version__}: numba.core.caching has no {name}; this package keeps "
                               "its compiled caches consistent through it (tested with numba 0.60-0.68)")
        return found

    stamped = [_stamped(named("UserProvidedCacheLocator")), _stamped(named("InTreeCacheLocator"))]
    named("CacheImpl")._locator_classes[:0] = stamped
    _installed.extend(stamped)


__all__ = ["dependency_stamp", "import_closure", "install", "package_roots"]
