"""BENCHMARKS.md is laid out by the questions its sections answer (``bench/_report.py``):
the published page is what the layout makes of it, a script's section lands under its
question, and a section without a place is refused, not appended at the end."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
import _report  # noqa: E402

from atc_nf_env.experiments.marked_sections import marked_sections  # noqa: E402


def test_the_published_page_is_laid_out() -> None:
    text = (ROOT / "BENCHMARKS.md").read_text()
    assert _report.lay_out(text) == text


def test_every_table_regenerate_flies_has_a_place_on_the_page() -> None:
    named = set(re.findall(r"BENCHMARKS\.md#([\w.-]+)", (ROOT / "bench" / "regenerate.sh").read_text()))
    assert named and named <= set(_report.PLACED), named - set(_report.PLACED)


def test_a_new_section_lands_under_its_question_with_its_headings_one_level_down() -> None:
    page = _report.lay_out(_report.HEADER + "\n<!-- begin mpc -->\n## MPC timing\n\ntable\n<!-- end mpc -->\n"
                           "\n<!-- begin kernel -->\n## Kernel\n\n### Detail\n<!-- end kernel -->\n")
    assert page.index("## How fast is the simulator?") < page.index("### Kernel") < page.index("#### Detail")
    assert page.index("### Kernel") < page.index("## How fast is the MCMC-MPC") < page.index("### MPC timing")
    assert "- [How fast is the simulator?](#how-fast-is-the-simulator): Kernel" in page
    assert "How exact is the integration" not in page  # a question with no section is left out
    assert _report.lay_out(page) == page
    assert marked_sections(page)["mpc"] == "<!-- begin mpc -->\n### MPC timing\n\ntable\n<!-- end mpc -->"


def test_a_section_without_a_place_is_refused() -> None:
    with pytest.raises(SystemExit, match=r"\['mpc-new-study'\] have no place"):
        _report.lay_out(_report.HEADER + "\n<!-- begin mpc-new-study -->\n## New\n<!-- end mpc-new-study -->\n")
