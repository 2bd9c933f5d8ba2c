"""A fingerprint of the code that flies a run, so that stored runs are reused only by
the code that made them.

Two builds that differ in any module a run goes through (the kernel, the NF, the
configuration, the scenarios, the episode loop, the environments' observations and
actions, the safety filter, the metrics, the evaluator, the policies of the installed
plug-in packages) or in the numerical libraries can give different trajectories for the
same seed. Results files record the fingerprint in their header
(``evaluate.Study.header``); a study is resumed only from runs of the same fingerprint.

What is hashed is the code, not the text: each module's syntax tree without its
docstrings and comments (``code_digest``), so a comment or docstring fix keeps the
fingerprint while any change to what the code does changes it. The modules are every
module of ``atc_nf_env`` except those that cannot change a run (``NOT_RUN_DETERMINING``),
and every module of the packages that provide policies through the entry-point groups
``atc_nf_env.policies`` and ``atc_nf_env.policy_files`` (in this project ``baselines``
and ``agents``). Those packages are located without being imported: the core never
imports the packages built on it.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import platform
from functools import lru_cache
from pathlib import Path

#: Modules of ``atc_nf_env`` (relative to the package) that cannot change a run, left out
#: of the fingerprint: the command line (it only parses options into a ``Study``, whose
#: settings the results header records), plots and animations (drawn from finished runs),
#: and the experiments (reports built on ``evaluate``: a change to how a table is written
#: must not make every stored run stale).
NOT_RUN_DETERMINING: tuple[str, ...] = ("cli.py", "plotting.py", "rendering.py", "experiments")

#: Entry-point groups whose packages provide policies (``atc_nf_env.policy``).
PLUGIN_GROUPS: tuple[str, ...] = ("atc_nf_env.policies", "atc_nf_env.policy_files")

#: Distributions whose versions are hashed when they are installed: their code rounds too
#: (torch and Stable-Baselines3 fly the trained agents).
LIBRARIES: tuple[str, ...] = ("numpy", "numba", "torch", "stable-baselines3")


def _python_files(root: Path) -> list[Path]:
    """Every ``.py`` file under ``root`` (a package directory) or ``root`` itself (a
    module), sorted, without byte-code caches."""
    if root.is_file():
        return [root]
    return sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)


def _package_files() -> list[Path]:
    package = Path(__file__).resolve().parent
    skipped = [package / name for name in NOT_RUN_DETERMINING]
    return [p for p in _python_files(package) if not any(p == s or s in p.parents for s in skipped)]


def plugin_roots() -> dict[str, Path]:
    """{top-level module: its directory (a package) or file (a module)} of every package
    that declares a policy in ``PLUGIN_GROUPS``, found with ``importlib.util.find_spec``,
    which locates a top-level package without executing it."""
    from importlib.metadata import entry_points

    roots: dict[str, Path] = {}
    for group in PLUGIN_GROUPS:
        for point in entry_points(group=group):
            top = point.value.split(":", 1)[0].split(".", 1)[0].strip()
            if not top or top in roots or top == __package__:
                continue
            try:
                spec = importlib.util.find_spec(top)
            except (ImportError, ValueError):
                spec = None
            if spec is None:
                continue  # an entry point of a package that is gone: make_policy reports it
            if spec.submodule_search_locations:
                roots[top] = Path(next(iter(spec.submodule_search_locations))).resolve()
            elif spec.origin and spec.origin.endswith(".py"):
                roots[top] = Path(spec.origin).resolve()
    return dict(sorted(roots.items()))


def plugin_entry_points() -> list[str]:
    """``group name = value`` of every entry point of ``PLUGIN_GROUPS``, sorted: which
    class a policy name resolves to is part of what flies."""
    from importlib.metadata import entry_points

    return sorted(f"{group} {point.name} = {point.value}" for group in PLUGIN_GROUPS
                  for point in entry_points(group=group))


def source_files() -> list[Path]:
    """The modules hashed into the fingerprint: ``atc_nf_env``'s run-determining modules
    and every module of the plug-in packages (``plugin_roots``)."""
    files = _package_files()
    for root in plugin_roots().values():
        files += _python_files(root)
    return files


class _WithoutDocstrings(ast.NodeTransformer):
    """Removes every statement that is only a string literal (docstrings, and strings used
    as comments): it is evaluated and discarded, so it cannot change what the code does."""

    def generic_visit(self, node: ast.AST) -> ast.AST:
        super().generic_visit(node)
        for name in ("body", "orelse", "finalbody"):
            body = getattr(node, name, None)
            if isinstance(body, list) and body and all(isinstance(s, ast.stmt) for s in body):
                kept = [s for s in body
                        if not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant)
                                and isinstance(s.value.value, str))]
                # A body of only a docstring becomes ``pass`` (what the code does is the same).
                setattr(node, name, kept or ([ast.Pass()] if name == "body" else []))
        return node


def code_digest(source: str | bytes, filename: str = "<source>") -> str:
    """SHA-256 (hex) of what ``source`` does: its syntax tree without docstrings and
    comments, without line and column numbers. A comment, a docstring, blank lines or a
    re-wrapped line leave it unchanged; any change to the code changes it.

    Raises:
        SyntaxError: ``source`` is not Python.
    """
    tree = _WithoutDocstrings().visit(ast.parse(source, filename=filename))
    return hashlib.sha256(ast.dump(tree, include_attributes=False).encode()).hexdigest()


def library_versions() -> dict[str, str]:
    """{name: version} of Python and of each of ``LIBRARIES`` that is installed (read from
    the installed metadata, without importing the library)."""
    from importlib.metadata import PackageNotFoundError, version

    versions = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            pass
    return versions


def fingerprint_of(files: list[Path], relative_to: dict[Path, str], extra: list[str]) -> str:
    """16 hex digits: SHA-256 over each file's name (as ``relative_to`` names its root)
    and ``code_digest``, then the ``extra`` lines."""
    digest = hashlib.sha256()
    for path in files:
        root = next(r for r in relative_to if r == path or r in path.parents)
        label = f"{relative_to[root]}/{path.relative_to(root).as_posix()}" if root != path else relative_to[root]
        digest.update(label.encode() + b"\0" + code_digest(path.read_bytes(), str(path)).encode() + b"\0")
    for line in extra:
        digest.update(line.encode() + b"\0")
    return digest.hexdigest()[:16]


@lru_cache(maxsize=1)
def fingerprint() -> str:
    """16 hex digits: SHA-256 of the code of every run-determining module (``source_files``,
    as ``code_digest``), of the plug-in entry points and of the versions of Python, NumPy,
    numba, torch and Stable-Baselines3 (those installed)."""
    package = Path(__file__).resolve().parent
    roots = {package: "atc_nf_env", **{path: name for name, path in plugin_roots().items()}}
    versions = [f"{name} {value}" for name, value in library_versions().items()]
    return fingerprint_of(source_files(), roots, plugin_entry_points() + versions)
