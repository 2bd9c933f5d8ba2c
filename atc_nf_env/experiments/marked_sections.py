"""Sections of a Markdown report that one script owns, delimited by HTML-comment markers.

Several scripts write into the same report (REPRODUCTION.md, BENCHMARKS.md); each replaces
only the text between its own ``<!-- begin NAME -->`` and ``<!-- end NAME -->`` markers, so
that rerunning one never erases what another wrote.
"""

from __future__ import annotations

from pathlib import Path


def write_marked_section(path: Path, name: str, text: str, *, header: str = "") -> None:
    """Replace the section ``name`` of the file at ``path`` with ``text`` (or append it).

    Args:
        path: the Markdown file; created (starting with ``header``) if missing.
        name: the section's marker name.
        text: the section's new body (without markers).
        header: the text a new file starts with.
    """
    begin, end = f"<!-- begin {name} -->", f"<!-- end {name} -->"
    current = path.read_text() if path.exists() else header
    block = f"{begin}\n{text.rstrip()}\n{end}"
    if begin in current and end in current:
        head, rest = current.split(begin, 1)
        _, tail = rest.split(end, 1)
        current = head + block + tail
    else:
        current = current.rstrip() + "\n\n" + block + "\n"
    path.write_text(current)
