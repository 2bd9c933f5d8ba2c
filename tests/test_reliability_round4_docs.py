"""Every docstring the docs site shows is valid reST that renders as text, tables and formulas.

The site (``make docs``) pulls docstrings in through ``sphinx.ext.autodoc`` directives in
the ``{eval-rst}`` blocks of ``docs/*.md`` (and of the files those pages include). This
test finds those directives, takes each docstring as autodoc does (``getdoc``,
``prepare_docstring``, napoleon's Google-style conversion, then ``docs/conf.py``'s own
``autodoc-process-docstring`` handler) and parses it with docutils, without a Sphinx
build. A docstring fails on any docutils warning or error (a malformed table, a broken
list, ``|x|`` read as an undefined substitution, ...), and also where Sphinx would
render it badly without a warning: an indented block that is not a literal block (a
block quote: formula lines run together into one paragraph) and a section title (it
would nest in the page's table of contents; write ``## Heading``, a rubric), and a line
followed by indented lines that is not a Google-style section (a definition list, whose
lines run together too).

The docstrings are collected in a subprocess that imports the code under autodoc's mock
of ``autodoc_mock_imports``, as the build does, so that the mock never leaks into other
tests. ``test_sphinx_build_shows_exactly_these_docstrings`` (slow) builds the site with
warnings as errors and checks that autodoc hands ``docs/conf.py``'s handler exactly the
docstrings this collector checks, line for line.
"""

from __future__ import annotations

import importlib
import inspect
import io
import json
import re
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
EVAL_RST = re.compile(r"^```\{eval-rst\}[ \t]*\n(?P<body>.*?)^```[ \t]*$", re.M | re.S)
INCLUDE = re.compile(r"^```\{include\}\s+(?P<path>\S+)[ \t]*$", re.M)
AUTO_DIRECTIVE = re.compile(r"^\.\. (?P<kind>auto\w+)::\s*(?P<target>\S+)\s*$")
OPTION = re.compile(r"^\s+:(?P<name>[\w-]+):\s*(?P<value>.*?)\s*$")
ANY_AUTO = re.compile(r"\.\. auto\w+::|\{auto\w+\}")
#: The extensions docs/conf.py loads that this test knows: none but autodoc pulls in docstrings.
KNOWN_EXTENSIONS = {"myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.viewcode"}
#: Options of each directive whose effect on what is shown this test reproduces.
KNOWN_OPTIONS = {
    "automodule": {"no-members", "no-index"},
    "autoclass": {"members", "no-index"},
    "autofunction": {"no-index"},
}

# Roles and directives that Sphinx (its Python domain, napoleon's output) adds to reST:
# stand-ins for the docutils parse. A role or directive in neither docutils nor these
# lists fails the test, as Sphinx would warn about it.
SPHINX_ROLES = (
    "class", "func", "meth", "attr", "mod", "data", "obj", "exc", "const", "type",
    "ref", "doc", "term", "any", "envvar", "option", "numref", "download", "keyword",
    "samp", "file", "command", "program", "kbd", "abbr", "dfn", "guilabel", "menuselection",
)
SPHINX_OBJECT_DIRECTIVES = ("attribute", "method", "function", "class", "data", "property", "module", "exception")
SPHINX_BODY_DIRECTIVES = ("versionadded", "versionchanged", "versionremoved", "deprecated", "seealso", "only")
SPHINX_CODE_DIRECTIVES = ("code-block", "sourcecode")


def _page_sources() -> list[tuple[str, str]]:
    """(name, text) of every docs page and of every file a page includes."""
    sources = []
    for page in sorted(DOCS.glob("*.md")):
        text = page.read_text(encoding="utf-8")
        sources.append((page.name, text))
        for match in INCLUDE.finditer(text):
            included = (page.parent / match.group("path")).resolve()
            sources.append((f"{page.name} -> {included.relative_to(ROOT)}", included.read_text(encoding="utf-8")))
    return sources


def site_directives() -> list[dict[str, Any]]:
    """The autodoc directives of the site, each as {page, kind, target, members}.

    Fails on what this test cannot reproduce (an unknown directive or option, a directive
    outside an ``{eval-rst}`` block), so that the check always covers exactly what the
    site shows.
    """
    found: list[dict[str, Any]] = []
    for page, text in _page_sources():
        outside = EVAL_RST.sub("", text)
        assert not ANY_AUTO.search(outside), f"{page}: an autodoc directive outside an {{eval-rst}} block"
        for block in EVAL_RST.finditer(text):
            current: dict[str, Any] | None = None
            for line in block.group("body").splitlines():
                directive = AUTO_DIRECTIVE.match(line)
                option = OPTION.match(line)
                if directive:
                    current = {"page": page, "kind": directive.group("kind"), "target": directive.group("target"),
                               "members": None, "options": set()}
                    assert current["kind"] in KNOWN_OPTIONS, f"{page}: {line!r}: a directive this test does not know"
                    found.append(current)
                elif option and current is not None:
                    name = option.group("name")
                    assert name in KNOWN_OPTIONS[current["kind"]], (
                        f"{page}: {current['kind']} {current['target']}: option :{name}: is one this test does not know"
                        " (it may change which docstrings the site shows)")
                    current["options"].add(name)
                    if name == "members":
                        members = [m.strip() for m in option.group("value").split(",") if m.strip()]
                        assert members, f"{page}: {current['target']}: :members: without a list shows every member"
                        current["members"] = members
                elif line.strip():
                    assert not ANY_AUTO.search(line), f"{page}: {line!r}: not an autodoc directive this test reads"
                    current = None
    for directive in found:
        if directive["kind"] == "automodule":
            assert "no-members" in directive["options"], (
                f"{directive['page']}: automodule {directive['target']} without :no-members: shows every member")
        directive["options"] = sorted(directive["options"])
    return found


# --- run in a subprocess: imports under autodoc's mock, as the build does -----------------


def _resolve(target: str) -> Any:
    """The object of a dotted name: the longest importable module prefix, then attributes."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(target)


def _stand_in_role(name, rawtext, text, lineno, inliner, options=None, content=None):  # noqa: ANN001, ANN201
    from docutils import nodes

    return [nodes.literal(rawtext, text)], []


def _register_sphinx_markup() -> None:
    from docutils import nodes
    from docutils.parsers.rst import Directive, directives, roles

    class AnyOptions(dict):
        def __missing__(self, key: str) -> Any:
            return directives.unchanged

    class BodyDirective(Directive):
        has_content = True
        optional_arguments = 1
        final_argument_whitespace = True
        option_spec = AnyOptions()

        def run(self) -> list[Any]:
            container = nodes.container()
            self.state.nested_parse(self.content, self.content_offset, container)
            return [container]

    class CodeDirective(BodyDirective):
        def run(self) -> list[Any]:
            text = "\n".join(self.content)
            return [nodes.literal_block(text, text)]

    for name in SPHINX_ROLES:
        for spelled in (name, f"py:{name}"):
            roles.register_local_role(spelled, _stand_in_role)
    for name in SPHINX_OBJECT_DIRECTIVES:
        directives.register_directive(name, BodyDirective)
        directives.register_directive(f"py:{name}", BodyDirective)
    for name in SPHINX_BODY_DIRECTIVES:
        directives.register_directive(name, BodyDirective)
    for name in SPHINX_CODE_DIRECTIVES:
        directives.register_directive(name, CodeDirective)


def rst_problems(lines: list[str]) -> list[str]:
    """What is wrong with ``lines`` as a docstring on the site (empty: nothing)."""
    from docutils import nodes
    from docutils.core import publish_doctree

    stream = io.StringIO()
    document = publish_doctree(
        "\n".join(lines),
        source_path="<docstring>",
        settings_overrides={"report_level": 2, "halt_level": 5, "warning_stream": stream, "doctitle_xform": False,
                            "file_insertion_enabled": False, "raw_enabled": False},
    )
    problems = [message.strip() for message in re.split(r"\n(?=<docstring>:)", stream.getvalue()) if message.strip()]
    for quote in document.findall(nodes.block_quote):
        problems.append(
            f"<docstring>:{quote.line or '?'}: an indented block that is not a literal block (its lines run together"
            f" into a paragraph; end the line before it with '::'): {quote.astext()[:80]!r}")
    for text in document.findall(nodes.Text):
        if "``" in text and not isinstance(text.parent, (nodes.literal, nodes.literal_block, nodes.system_message)):
            problems.append(
                f"<docstring>:{text.parent.line or '?'}: ``...`` shown with its backquotes (an inline literal needs a"
                f" space or punctuation before and after it): {str(text)[:80]!r}")
    for definitions in document.findall(nodes.definition_list):
        problems.append(
            f"<docstring>:{definitions.line or '?'}: a line followed by indented lines (a definition list, whose"
            " lines run together; a Google-style section header napoleon did not recognize?):"
            f" {definitions.astext()[:80]!r}")
    for section in document.findall(nodes.section):
        problems.append(
            f"<docstring>: a section title ({section[0].astext()!r}): write '## Heading' (a rubric) instead")
    return problems


def docstring_handlers(conf: dict[str, Any]) -> list[Any]:
    """The ``autodoc-process-docstring`` handlers that ``docs/conf.py``'s ``setup`` connects,
    in the order Sphinx calls them (after napoleon's, which is registered first)."""
    connected: list[tuple[int, str, Any]] = []

    class App:
        def connect(self, event: str, handler: Any, priority: int = 500) -> None:
            connected.append((priority, event, handler))

        def __getattr__(self, name: str) -> Any:
            return lambda *args, **kwargs: None

    conf["setup"](App())
    others = {event for _, event, _ in connected if event.startswith("autodoc-") and event != "autodoc-process-docstring"}
    assert not others, f"docs/conf.py connects {sorted(others)}: teach this test what they change"
    return [handler for _, event, handler in sorted(connected, key=lambda c: c[0]) if event == "autodoc-process-docstring"]


def _docstring_lines(what: str, name: str, obj: Any, parent: Any) -> list[str] | None:
    """The docstring as autodoc passes it to ``autodoc-process-docstring`` (before the
    handlers), or None where autodoc shows none."""
    from sphinx.util.docstrings import prepare_docstring
    from sphinx.util.inspect import getdoc

    if what == "module" or what == "class":
        docstring = getdoc(obj)
    else:
        docstring = getdoc(obj, allow_inherited=True, cls=parent, name=name.rsplit(".", 1)[-1])
    if not docstring:
        return None
    return prepare_docstring(docstring, 8)


def collect(directives_: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each docstring the site shows, processed as the build processes it, with its problems."""
    import runpy

    from sphinx.ext.autodoc.mock import mock
    from sphinx.ext.napoleon import Config
    from sphinx.ext.napoleon.docstring import GoogleDocstring

    conf = runpy.run_path(str(DOCS / "conf.py"))
    napoleon = Config(**{key: value for key, value in conf.items() if key.startswith("napoleon_")})
    handlers = docstring_handlers(conf)
    _register_sphinx_markup()
    shown: list[dict[str, Any]] = []
    with mock(conf["autodoc_mock_imports"]):
        for directive in directives_:
            target = directive["target"]
            obj = _resolve(target)
            what = {"automodule": "module", "autoclass": "class", "autofunction": "function"}[directive["kind"]]
            # napoleon reads :no-index: (it marks the attributes it writes); members share the options.
            options = types.SimpleNamespace(no_index="no-index" in directive["options"], noindex=False)
            items = [(what, target, obj, None)]
            for member in directive["members"] or []:
                value = inspect.getattr_static(obj, member)
                kind = "property" if isinstance(value, property) else "method"
                items.append((kind, f"{target}.{member}", getattr(obj, member), obj))
            for kind, name, item, parent in items:
                lines = _docstring_lines(kind, name, item, parent)
                if lines is None:
                    continue
                if napoleon.napoleon_google_docstring:
                    lines = GoogleDocstring(lines, napoleon, None, kind, name, item, options).lines()
                for handler in handlers:
                    handler(None, kind, name, item, options, lines)
                shown.append({"page": directive["page"], "what": kind, "name": name, "lines": lines,
                              "problems": rst_problems(lines)})
    return shown


def _collect_main() -> None:
    print(json.dumps(collect(json.loads(sys.stdin.read()))))


def _collect_in_subprocess(directives_: list[dict[str, Any]]) -> list[dict[str, Any]]:
    code = f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import {Path(__file__).stem} as t; t._collect_main()"
    run = subprocess.run([sys.executable, "-c", code], input=json.dumps(directives_), capture_output=True, text=True,
                         cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr[-4000:]
    return json.loads(run.stdout.splitlines()[-1])


@pytest.fixture(scope="module")
def shown() -> list[dict[str, Any]]:
    return _collect_in_subprocess(site_directives())


def test_conf_loads_no_other_docstring_source() -> None:
    import runpy

    extensions = set(runpy.run_path(str(DOCS / "conf.py"))["extensions"])
    assert extensions <= KNOWN_EXTENSIONS, (
        f"docs/conf.py loads {sorted(extensions - KNOWN_EXTENSIONS)}: teach this test which docstrings they show")


def test_every_docstring_on_the_site_is_valid_rest(shown: list[dict[str, Any]]) -> None:
    names = {entry["name"] for entry in shown}
    # The collector found the site's docstrings (a parser that finds nothing would pass).
    assert {"atc_nf_env.kernel", "atc_nf_env.envs.observations", "baselines.mcmc_mpc",
            "atc_nf_env.envs.centralized.EncounterEnv.reset", "atc_nf_env.config.SimConfig"} <= names
    assert len(shown) >= 80
    failures = [
        f"{entry['page']}: {entry['what']} {entry['name']}:\n    " + "\n    ".join(entry["problems"])
        for entry in shown if entry["problems"]
    ]
    assert not failures, "docstrings the site shows that do not render as reST:\n" + "\n".join(failures)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("Per aircraft:\n\n    x = a + b\n    y = c\n", "indented block"),  # formula lines run together
        ("p_floor: floor on |P_i| in the term.\n", "Undefined substitution"),
        ("====  =====  ====\nidx   name   m\n====  =====  ====\n0     a      x\n1     wind_forward y\n====  =====  ====\n",
         "Malformed table"),  # a cell into the next column's margin
        ("Title\n-----\n\ntext\n", "section title"),
        ("Attributes (beyond Scenario's):\n    a: one, nm.\n    b: two, s.\n", "definition list"),
        ("See :clas:`Foo`.\n", "Unknown interpreted text role"),
        ("Clipped to ±``OBS_LIMIT``.\n", "shown with its backquotes"),
        ("1. a\n2. b\n  c\n", "Enumerated list ends without a blank line"),
    ],
)
def test_the_check_catches_what_renders_badly(text: str, expected: str) -> None:
    _register_sphinx_markup()
    assert any(expected in problem for problem in rst_problems(text.splitlines())), rst_problems(text.splitlines())


def test_the_check_accepts_what_renders_well() -> None:
    _register_sphinx_markup()
    text = ("Per aircraft::\n\n    x = a + b\n    y = c\n\nwith ``|P_i|`` and :class:`Foo`.\n\n"
            ".. rubric:: Heading\n\n.. math::\n\n   r_i = a\n\n:param x: a value, nm.\n")
    assert rst_problems(text.splitlines()) == []


def test_conf_has_no_silent_fallback_for_invalid_docstrings() -> None:
    """An invalid docstring must reach Sphinx as written (its warning fails ``-W``), not be
    turned into a literal block."""
    import runpy

    handlers = docstring_handlers(runpy.run_path(str(DOCS / "conf.py")))
    assert handlers, "docs/conf.py no longer turns '## Heading' into a rubric"
    lines = ["Broken table:", "", "===  ===", "a    b c d e", "===", "", "## Heading", "", "|P_i| text"]
    for handler in handlers:
        handler(None, "module", "m", None, None, lines)
    assert lines == ["Broken table:", "", "===  ===", "a    b c d e", "===", "", ".. rubric:: Heading", "",
                     "|P_i| text"]


def _record_build(out: Path) -> None:
    """Build the site with warnings as errors, recording what autodoc passes to conf.py's handler."""
    from sphinx.application import Sphinx

    records: list[dict[str, Any]] = []

    def record(app, what, name, obj, options, lines) -> None:  # noqa: ANN001
        records.append({"page": app.env.docname, "what": what, "name": name, "lines": list(lines)})

    app = Sphinx(str(DOCS), str(DOCS), str(out / "html"), str(out / "doctrees"), "html",
                 status=None, warningiserror=True, keep_going=True, freshenv=True)
    app.connect("autodoc-process-docstring", record, priority=999)  # after every other handler
    app.build(force_all=True)
    print(json.dumps({"status": app.statuscode, "records": records}))


@pytest.mark.slow
def test_sphinx_build_shows_exactly_these_docstrings(shown: list[dict[str, Any]], tmp_path: Path) -> None:
    code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import {Path(__file__).stem} as t; "
            f"from pathlib import Path; t._record_build(Path({str(tmp_path)!r}))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert run.returncode == 0, run.stderr[-4000:]
    built = json.loads(run.stdout.splitlines()[-1])
    assert built["status"] == 0, run.stderr[-4000:]
    from_build = {(Path(r["page"]).name, r["name"]): r["lines"] for r in built["records"]}
    from_check = {(Path(e["page"].split(" ")[0]).stem, e["name"]): e["lines"] for e in shown}
    assert from_build.keys() == from_check.keys()
    for key, lines in from_build.items():
        assert [line for line in lines if line.strip()] == [line for line in from_check[key] if line.strip()], key
