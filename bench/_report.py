"""Write a benchmark's section into BENCHMARKS.md, replacing that section's last version,
and keep the page laid out by the questions its sections answer.

Each script owns the text between its section's markers; this module owns the rest of
the page: the preamble, the questions (``PAGE``) in order, the contents list, and each
section's place under its question. ``python bench/_report.py`` lays the page out again
without flying anything.
"""

from __future__ import annotations

import os
import platform
import re
import sys
from pathlib import Path

from atc_nf_env.experiments.marked_sections import marked_sections, write_marked_section

BENCHMARKS = Path(__file__).resolve().parent.parent / "BENCHMARKS.md"
HEADER = (
    "# Benchmarks\n\n"
    "Every table below is written by the command it names (`bash bench/regenerate.sh` flies the stale "
    "ones again), with the machine it ran on; a hidden stamp line records the code's behaviour it was "
    "flown with. Medians over repeats; ratios are from runs side by side. This is a 2-core virtual "
    "machine: the same benchmark, run again minutes later, moves by up to ±15 % on a quiet machine and "
    "by several times when other jobs share the cores, so compare figures taken side by side on the "
    "same day.\n"
)

#: The questions the page answers, in order, each with the sections (marker names) that
#: answer it, in order. A section must have a place here before a script writes it.
PAGE: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("How fast is the simulator?", ("kernel", "kernel-scaling", "envs", "compile", "layout-probe")),
    ("How fast beside BlueSky-Gym?", ("bluesky-gym",)),
    ("How fast is the MCMC-MPC and how does it fly dense traffic and streams?",
     ("mpc", "mpc-dense", "mpc-dense-1000", "mpc-streams")),
    ("How fast is the safety filter and what does it keep safe?",
     ("shield", "shield-stall", "shield-stall-mlp", "shield-adversarial", "shielded-streams", "nf-floor")),
    ("How fast are the agents and how do they fare off their training conditions?",
     ("agent-forward", "generalization-grid", "offline-bc")),
    ("How exact is the integration?", ("integration-step", "integration-convergence", "substep-watch")),
)
PLACED = tuple(name for _, names in PAGE for name in names)

_TITLE = re.compile(r"^#{2,3} (?P<title>.+)$", re.M)
_HEADING = re.compile(r"^(#{2,5}) ", re.M)


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def _anchor(heading: str) -> str:
    """The anchor GitHub and MyST give a heading of ASCII words."""
    return "-".join(re.sub(r"[^a-z0-9 -]", "", heading.lower()).split())


def lay_out(text: str) -> str:
    """The page ``text`` laid out by ``PAGE``: the preamble, the contents, each question
    and its sections (their titles one level down); every section's text as written.

    Raises:
        SystemExit: a section of the page has no place in ``PAGE``.
    """
    sections = marked_sections(text)
    unplaced = sorted(set(sections) - set(PLACED))
    if unplaced:
        raise SystemExit(f"bench: BENCHMARKS.md sections {unplaced} have no place in bench/_report.py's PAGE; "
                         "add each under the question it answers")
    contents, body = [], []
    for question, names in PAGE:
        present = [name for name in names if name in sections]
        if not present:
            continue
        titles = []
        body += [f"## {question}", ""]
        for name in present:
            section = sections[name]
            match = _TITLE.search(section)
            if match:
                titles.append(match.group("title"))
                if match.group(0).startswith("## "):  # as its script wrote it: every heading one level down
                    section = _HEADING.sub(lambda m: f"#{m.group(1)} ", section)
            body += [section, ""]
        contents.append(f"- [{question}](#{_anchor(question)}): {'; '.join(titles)}")
    return "\n".join([HEADER, *contents, "", *body]).rstrip() + "\n"


def write_section(name: str, text: str) -> None:
    """Replace the section delimited by markers named ``name`` (or add it) and lay the page out."""
    if name not in PLACED:
        raise SystemExit(f"bench: section {name!r} has no place in bench/_report.py's PAGE")
    write_marked_section(BENCHMARKS, name, text, header=HEADER)
    BENCHMARKS.write_text(lay_out(BENCHMARKS.read_text()))


def publish(name: str, text: str, write: bool) -> int:
    """Print a benchmark's section and, with ``write`` (its ``--write``), put it into
    BENCHMARKS.md; the script's exit status (0)."""
    print(text)
    if write:
        write_section(name, text)
    return 0


if __name__ == "__main__":
    if sys.argv[1:]:
        sys.exit("usage: python bench/_report.py  (lays BENCHMARKS.md out again; takes no arguments)")
    BENCHMARKS.write_text(lay_out(BENCHMARKS.read_text()))
