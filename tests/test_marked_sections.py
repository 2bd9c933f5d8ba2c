"""Marked sections: a script rewrites its own section of a shared report and nothing else."""

from __future__ import annotations

from pathlib import Path

from atc_nf_env.experiments.marked_sections import write_marked_section


def test_new_file_starts_with_the_header_and_holds_the_section(tmp_path: Path) -> None:
    report = tmp_path / "REPORT.md"
    write_marked_section(report, "alpha", "first body\n", header="# Report\n")
    assert report.read_text() == "# Report\n\n<!-- begin alpha -->\nfirst body\n<!-- end alpha -->\n"


def test_rewriting_one_section_keeps_the_others_and_the_prose(tmp_path: Path) -> None:
    report = tmp_path / "REPORT.md"
    report.write_text("# Report\n\nhand-written prose\n")
    write_marked_section(report, "alpha", "alpha v1")
    write_marked_section(report, "beta", "beta v1")
    write_marked_section(report, "alpha", "alpha v2")
    text = report.read_text()
    assert "hand-written prose" in text
    assert "alpha v1" not in text
    assert "<!-- begin alpha -->\nalpha v2\n<!-- end alpha -->" in text
    assert "<!-- begin beta -->\nbeta v1\n<!-- end beta -->" in text
    assert text.index("alpha v2") < text.index("beta v1")  # rewritten in place, not moved
