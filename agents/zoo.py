"""The model zoo table of ``agents/README.md``, generated from the studies under ``agents/results/``.

    python -m agents.zoo            # print the table
    python -m agents.zoo --write    # and write it into agents/README.md (between its zoo markers)

One row per shipped model (``agents/models/*.zip``) and traffic family (the paper's
``converging-N`` encounters, seeded ``random-N`` crossings). Every figure comes from the
summaries that ``python -m agents.benchmark`` wrote (``agents/results/*_summary.json``) and
from the metadata saved inside each zip; nothing is typed by hand. For each scenario the
study with the most runs is used.

A run is *safe* when no pair came closer than 5 nm and no integration step (5 s) left the
airspeed envelope [366, 540] kt. A summary counts the runs with a loss of separation and
the runs outside the envelope separately; where both are non-zero the number of safe runs
is only bounded, and the table says "≤".

Reads only JSON and zip files: no torch, no simulation.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

AGENTS_DIR = Path(__file__).resolve().parent
MODELS_DIR = AGENTS_DIR / "models"
RESULTS_DIR = AGENTS_DIR / "results"
README = AGENTS_DIR / "README.md"
SECTION = "zoo"
SHIELD_SUFFIX = "+shield"
_SCENARIO = re.compile(r"^(converging|random)-(\d+)$")


@dataclass(frozen=True)
class Study:
    """One policy's summary on one scenario, and the conditions that make two comparable."""

    scenario: str
    policy: str
    summary: dict[str, Any]
    source: str

    @property
    def runs(self) -> int:
        return int(self.summary["runs"])

    @property
    def conditions(self) -> tuple:
        study = self.summary.get("study", {})
        return (self.scenario, tuple(study.get("seeds", ())), study.get("wind_sigma_mps"),
                study.get("max_time_s"), study.get("build"))


def load_studies(results_dir: Path = RESULTS_DIR) -> list[Study]:
    """Every (scenario, policy) summary of every ``*_summary.json`` (and ``summary.json``)."""
    studies = []
    for path in sorted(results_dir.glob("*summary.json")):
        data = json.loads(path.read_text())
        for scenario, policies in data.items():
            for policy, summary in policies.items():
                studies.append(Study(scenario, policy, summary, path.name))
    return studies


def model_meta(path: Path) -> dict[str, Any]:
    """The ``atc_nf_meta`` that ``atc-nf train`` / ``atc-nf imitate`` saved in the zip's ``data``."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    meta = data.get("atc_nf_meta")
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: no atc_nf_meta in the model's data; was it saved by atc-nf train or imitate?")
    return meta


def _family(scenario: str) -> tuple[str, int] | None:
    match = _SCENARIO.match(scenario)
    return (match.group(1), int(match.group(2))) if match else None


def _counts(values: Iterable[int]) -> str:
    """4, 6 / 3–8, 12, 16: runs of consecutive integers joined with an en dash."""
    numbers = sorted(set(values))
    parts: list[str] = []
    start = prev = numbers[0]
    for n in [*numbers[1:], None]:
        if n is not None and n == prev + 1:
            prev = n
            continue
        parts.append(str(start) if start == prev else f"{start}–{prev}" if prev > start + 1 else f"{start}, {prev}")
        if n is not None:
            start = prev = n
    return ", ".join(parts)


def _range(values: list[float], fmt: str, unit: str = "") -> str:
    low, high = min(values), max(values)
    text = fmt.format(low) if fmt.format(low) == fmt.format(high) else f"{fmt.format(low)}–{fmt.format(high)}"
    return f"{text}{unit}"


def trained_on(meta: dict[str, Any]) -> str:
    """How and on what the model was trained, from its saved training command."""
    training = meta.get("training", {})
    argv = shlex.split(training.get("command", ""))
    scenarios: list[str] = []
    for option in ("--episodes", "--scenario"):
        if option in argv:
            value = argv[argv.index(option) + 1]
            scenarios += [item.split(":")[0] for item in value.split(",")]
    families: dict[str, list[int]] = {}
    for scenario in scenarios:
        family = _family(scenario)
        if family:
            families.setdefault(family[0], []).append(family[1])
    where = "; ".join(f"{name} {_counts(ns)}" for name, ns in families.items()) or "?"
    script, stage = training.get("script", ""), training.get("stage", "")
    if script == "atc-nf imitate":
        how = "MPC imitation, DAgger" if stage.startswith("dagger") else "MPC imitation (BC)"
    elif training.get("init_from"):
        how = "PPO fine-tuning of DAgger"
    else:
        how = "PPO from scratch"
    return f"{how}: {where}"


def _safe_runs(summary: dict[str, Any]) -> tuple[int, bool]:
    """(safe runs, exact?): runs with neither a loss of separation nor a step outside the envelope."""
    runs = int(summary["runs"])
    los, envelope = int(summary["runs_with_los"]), int(summary["runs_with_envelope_violation"])
    return runs - max(los, envelope), min(los, envelope) == 0


def _largest(studies: list[Study], policy: str) -> dict[str, Study]:
    """Per scenario, the study of ``policy`` with the most runs (the first file's on a tie)."""
    best: dict[str, Study] = {}
    for study in studies:
        if study.policy == policy and (study.scenario not in best or study.runs > best[study.scenario].runs):
            best[study.scenario] = study
    return best


def _safe_cell(chosen: list[Study]) -> str:
    if not chosen:
        return "not flown"
    safe = sum(_safe_runs(s.summary)[0] for s in chosen)
    exact = all(_safe_runs(s.summary)[1] for s in chosen)
    runs = sum(s.runs for s in chosen)
    verdict = "**yes**" if safe == runs else "no"
    return f"{verdict}: {'' if exact else '≤ '}{safe}/{runs}"


def _mpc_ratio(studies: list[Study], chosen: list[Study]) -> str:
    """Mean flight time over the MPC's on the same scenario, seeds, wind, time limit and build."""
    mpc = {s.conditions: s for s in studies if s.policy == "mpc"}
    ratios = []
    for study in chosen:
        reference = mpc.get(study.conditions)
        mine, theirs = study.summary["flight_time_min"]["mean"], None
        if reference is not None:
            theirs = reference.summary["flight_time_min"]["mean"]
        if mine is not None and theirs:
            ratios.append(mine / theirs)
    return _range(ratios, "{:.2f}", "×") if ratios else "no MPC run"


def _duration(seconds: float) -> str:
    return f"{seconds * 1e6:.0f} µs" if seconds < 1e-3 else f"{seconds * 1e3:.1f} ms"


def _decision_cell(chosen: list[Study]) -> str:
    """The range over scenarios of the mean time of one decision (every aircraft at once)."""
    means = [s.summary["decision_s"]["mean"] for s in chosen if s.summary.get("decision_s")]
    if not means:
        return "–"
    low, high = _duration(min(means)), _duration(max(means))
    return low if low == high else f"{low}–{high}"


def rows(studies: list[Study], models: Sequence[Path]) -> list[list[str]]:
    """The table's rows: model, trained on, traffic, N, safe alone, safe in the filter,
    flight time vs the MPC (alone; in the filter), decision time (alone; in the filter)."""
    table = []
    for path in models:
        name = path.stem
        meta = model_meta(path)
        alone, shielded = _largest(studies, name), _largest(studies, name + SHIELD_SUFFIX)
        for family in ("converging", "random"):
            in_family = [s for s in sorted({*alone, *shielded}) if (_family(s) or ("",))[0] == family]
            if not in_family:
                continue
            mine = [alone[s] for s in in_family if s in alone]
            filtered = [shielded[s] for s in in_family if s in shielded]
            table.append([
                f"`{name}`",
                trained_on(meta),
                family,
                _counts(_family(s)[1] for s in in_family),
                _safe_cell(mine),
                _safe_cell(filtered),
                f"{_mpc_ratio(studies, mine)}; {_mpc_ratio(studies, filtered) if filtered else '–'}",
                f"{_decision_cell(mine)}; {_decision_cell(filtered) if filtered else '–'}",
            ])
    return table


HEADER = ("model", "trained on", "traffic", "N", "safe alone? (runs)", "safe in the filter? (runs)",
          "flight time vs MPC (alone; filter)", "decision time (alone; filter)")


def table(results_dir: Path = RESULTS_DIR, models_dir: Path = MODELS_DIR) -> str:
    """The zoo table in Markdown, with the command that generates it."""
    models = sorted(models_dir.glob("*.zip"))
    if not models:
        raise ValueError(f"no model .zip in {models_dir}")
    lines = ["Generated by `python -m agents.zoo --write` from `agents/results/*_summary.json`.", "",
             "| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(row) + " |" for row in rows(load_studies(results_dir), models)]
    return "\n".join(lines) + "\n"


def write(readme: Path = README, text: str | None = None) -> None:
    """Put the table into ``readme``'s ``<!-- begin zoo -->`` section (which must exist)."""
    from atc_nf_env.experiments.marked_sections import replace_marked_section

    replaced = replace_marked_section(readme.read_text(), SECTION, table() if text is None else text)
    if replaced is None:
        raise ValueError(f"{readme} has no <!-- begin {SECTION} --> ... <!-- end {SECTION} --> section")
    readme.write_text(replaced)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help=f"write the table into {README.name}'s zoo section")
    args = parser.parse_args(argv)
    text = table()
    if args.write:
        write(README, text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
