"""Sphinx configuration of the atc-nf-env documentation (Furo theme, MyST Markdown pages).

Build: ``make docs`` (``sphinx-build -W --keep-going -b html docs out/docs``).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # atc_nf_env, baselines and agents from this checkout

project = "atc-nf-env"
author = "the atc-nf-env authors"
copyright = "the atc-nf-env authors, MIT License"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3

html_theme = "furo"
html_title = "atc-nf-env"

# Optional libraries the API reference names but does not need to document.
autodoc_mock_imports = ["torch", "stable_baselines3", "ray", "supersuit", "torchrl", "tensordict", "benchmarl"]
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
napoleon_google_docstring = True
napoleon_numpy_docstring = False

_HEADING = re.compile(r"^(\s*)## (.+?)\s*$")
# Roles and directives of Sphinx (and napoleon's output) that plain docutils does not know.
_SPHINX_ONLY = ("Unknown interpreted text role", "Unknown directive type", "No role entry for", "No directive entry for")

# docutils' own lookups, taken before Sphinx swaps in its domain-aware ones while it reads
# a page: the check below must not run Sphinx's directives (they would register objects).
from docutils.parsers.rst import directives as _directives, roles as _roles  # noqa: E402

_PLAIN_LOOKUPS = (_directives.directive, _roles.role)
# Object directives napoleon writes (Attributes:); their content is checked as a block quote.
_OBJECT_DIRECTIVE = re.compile(r"^(\s*)\.\. (py:)?(attribute|method|function|class|data|property)::.*$")


def _without_object_directives(lines: list[str]) -> list[str]:
    """Each object directive line (and its options) as an empty comment, so that docutils
    parses its content as a block quote instead of skipping an unknown directive."""
    kept: list[str] = []
    in_options = False
    for line in lines:
        match = _OBJECT_DIRECTIVE.match(line)
        if match:
            kept.append(f"{match.group(1)}..")
            in_options = True
        elif in_options and re.match(r"^\s+:[\w-]+:", line):
            continue
        else:
            in_options = False
            kept.append(line)
    return kept


def _rst_problems(text: str) -> list[str]:
    """What plain docutils finds wrong with ``text`` as reST, Sphinx-only markup aside."""
    from docutils import nodes
    from docutils.frontend import get_default_settings
    from docutils.parsers.rst import Parser
    from docutils.utils import new_document

    text = "\n".join(_without_object_directives(text.splitlines()))
    settings = get_default_settings(Parser)
    settings.report_level = 5  # collect, never print
    settings.halt_level = 5
    document = new_document("<docstring>", settings)
    swapped = (_directives.directive, _roles.role)
    _directives.directive, _roles.role = _PLAIN_LOOKUPS
    try:
        Parser().parse(text, document)
    except Exception as error:  # a registered directive that needs more than a bare document
        return [repr(error)]
    finally:
        _directives.directive, _roles.role = swapped
    problems = [
        message.astext() for message in document.findall(nodes.system_message)
        if message["level"] >= 2 and not any(marker in message.astext() for marker in _SPHINX_ONLY)
    ]
    # Resolved only by later transforms, which would then fail: |x|, name_, [1]_.
    for kind in (nodes.substitution_reference, nodes.footnote_reference, nodes.citation_reference):
        problems += [node.astext() for node in document.findall(kind)]
    problems += [node.astext() for node in document.findall(nodes.reference) if "refname" in node]
    return problems


def _docstring_as_rst_or_literal(app, what, name, obj, options, lines) -> None:
    """Render a docstring as reST where it is valid reST, and as preformatted text where not.

    The docstrings are written for readers of the source (plain text with Gymnasium's
    ``## Section`` headings and formulas such as ``|P_i|``); this keeps the site strict
    (warnings are errors) without rewriting them for reST. ``## X`` becomes a rubric.
    """
    converted = []
    for line in lines:
        match = _HEADING.match(line)
        converted.append(f"{match.group(1)}.. rubric:: {match.group(2)}" if match else line)
    if not _rst_problems("\n".join(converted)):
        lines[:] = converted
        return
    body = [f"    {line}" if line.strip() else "" for line in lines]
    lines[:] = ["::", "", *body, ""]


def setup(app) -> None:
    app.connect("autodoc-process-docstring", _docstring_as_rst_or_literal)
