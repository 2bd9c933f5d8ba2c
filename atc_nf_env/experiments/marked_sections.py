"""Sections of a Markdown report that one script owns, delimited by HTML-comment markers.

Several scripts write into the same report (REPRODUCTION.md, BENCHMARKS.md); each replaces
only the text between its own ``<!-- begin NAME -->`` and ``<!-- end NAME -->`` markers, so
that rerunning one never erases what another wrote.
"""

from __future__ import annotations

import re
from pathlib import Path

_ANY_SECTION = re.compile(r"<!-- begin (?P<name>[\w.-]+) -->.*?<!-- end (?P=name) -->", re.S)


def marked_sections(text: str) -> dict[str, str]:
    """The ``<!-- begin NAME -->`` … ``<!-- end NAME -->`` sections of a text, markers included, by name."""
    return {m.group("name"): m.group(0) for m in _ANY_SECTION.finditer(text)}


def replace_marked_section(text: str, name: str, body: str) -> str | None:
    """``text`` with section ``name``'s body replaced by ``body``; None if it has no such section."""
    begin, end = f"<!-- begin {name} -->", f"<!-- end {name} -->"
    if begin not in text or end not in text.split(begin, 1)[1]:
        return None
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{begin}\n{body.rstrip()}\n{end}{tail}"


def write_marked_section(path: Path, name: str, text: str, *, header: str = "") -> None:
    """Replace the section ``name`` of the file at ``path`` with ``text`` (or append it).

    Args:
        path: the Markdown file; created (starting with ``header``) if missing.
        name: the section's marker name.
        text: the section's new body (without markers).
        header: the text a new file starts with.
    """
    current = path.read_text() if path.exists() else header
    replaced = replace_marked_section(current, name, text)
    if replaced is None:
        replaced = f"{current.rstrip()}\n\n<!-- begin {name} -->\n{text.rstrip()}\n<!-- end {name} -->\n"
    path.write_text(replaced)
