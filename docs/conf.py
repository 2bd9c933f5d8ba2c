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


def process_docstring(app, what, name, obj, options, lines) -> None:
    """Gymnasium's ``## Section`` headings of a docstring as rubrics; the rest is reST as written.

    Nothing else is converted: a docstring that is not valid reST makes the build warn
    (an error under ``-W``), and ``tests/test_reliability_round4_docs.py`` checks every
    docstring the site shows without a build.
    """
    for index, line in enumerate(lines):
        match = _HEADING.match(line)
        if match:
            lines[index] = f"{match.group(1)}.. rubric:: {match.group(2)}"


def setup(app) -> None:
    app.connect("autodoc-process-docstring", process_docstring)
