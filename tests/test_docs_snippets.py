"""Every code block of the README, agents/README.md and the docs site runs as written.

- ``python`` blocks run as scripts (``__main__``) in an empty folder, so a snippet that
  works only from the repository's root (a relative path) fails here. A block that
  imports a library the test venv lacks (RLlib, TorchRL, BenchMARL: each lives in a venv
  of its own) is skipped, saying which; ``make test-integrations`` runs those blocks in
  their library's venv, with ``ATC_NF_SNIPPETS_OF`` naming the library (then only the
  blocks that name it run, and the test fails if there are none).
- ``bash`` blocks: each command runs in an empty folder in which ``agents/`` and
  ``examples/`` are the repository's (the shipped models' and the examples' relative
  paths are how users run them from a clone); Minari datasets go to a folder inside it. ``atc-nf`` and ``python`` commands run as written, except the ones in SCALED
  (run with fewer runs, each with its reason) and SKIPPED (not run here, each with its
  reason). A command of another kind, or one in neither list that cannot run as
  written, fails the test: a new snippet must be classified.
- ``toml`` blocks are parsed, and an entry-point table must name a group the package
  reads.

Also checks that the model zoo table in agents/README.md is what ``python -m agents.zoo``
generates from the committed summaries.
"""

from __future__ import annotations

import functools
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCUMENTS = [ROOT / "README.md", ROOT / "agents" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(?P<info>[^\n]*)\n(?P<body>.*?)^```[ \t]*$", re.M | re.S)
TIMEOUT_S = 600

#: Commands run with fewer runs or scenarios than written: the same code path, a fraction
#: of the time. Written command -> (command run, why).
SCALED: dict[str, tuple[str, str]] = {
    "atc-nf fly --policy nf-leg --scenario stream-30-60min --shield --seed 1 --extractions 500": (
        "atc-nf fly --policy nf-leg --scenario stream-30-20min --shield --seed 1 --extractions 100",
        "an hour of stream inside the filter, its per-cluster MPC fallback included, takes half a minute; 20 min "
        "take the same options through the same fallback"),
    "atc-nf evaluate --policy mpc --scenario converging-4 --runs 1000 --out runs.jsonl": (
        "atc-nf evaluate --policy mpc --scenario converging-4 --runs 2 --workers 1 --out runs.jsonl --no-progress",
        "1000 MPC episodes take minutes; 2 runs in one process go through the same file and summary (the README's "
        "evaluate() snippet runs worker processes)"),
    "atc-nf evaluate --policy mpc --scenario converging-4 --runs 1000 --out runs.jsonl --summary-json summary.json": (
        "atc-nf evaluate --policy mpc --scenario converging-4 --runs 2 --workers 1 --out runs.jsonl"
        " --summary-json summary.json --no-progress",
        "as above"),
    "atc-nf evaluate --policy mpc --scenario converging-4 --runs 1000 --out runs.jsonl --resume": (
        "atc-nf evaluate --policy mpc --scenario converging-4 --runs 3 --workers 1 --out runs.jsonl --resume --no-progress",
        "resumes the scaled study above with one more run"),
    "atc-nf evaluate --policy agents/models/deepsets_mixed.zip --scenario random-6 --runs 300 --shield": (
        "atc-nf evaluate --policy agents/models/deepsets_mixed.zip --scenario random-6 --runs 2 --workers 1 --shield"
        " --no-progress",
        "300 shielded episodes take minutes; 2 runs exercise the model, the filter and the summary"),
    "python -m agents.benchmark --models agents/models/imitation_dagger.zip --runs 300": (
        "python -m agents.benchmark --models agents/models/imitation_dagger.zip --runs 1 --scenarios converging-4"
        " --workers 1 --no-progress",
        "the default flies the NF, the MPC and the model 300 times on three scenarios"),
    "atc-nf dataset --policy mpc --task converging-4 --episodes 24 --dataset-id atc-nf/converging-4/mpc-v0": (
        "atc-nf dataset --policy mpc --task converging-4 --episodes 2 --dataset-id atc-nf/converging-4/mpc-v0"
        " --no-progress",
        "24 MPC episodes take a minute; 2 go through the same recording and Minari writer"),
    "python examples/bc_from_minari.py --dataset-id atc-nf/converging-4/mpc-v0 --out bc_offline.zip": (
        "python examples/bc_from_minari.py --dataset-id atc-nf/converging-4/mpc-v0 --out bc_offline.zip --epochs 2",
        "2 epochs on the 2-episode dataset above write the same kind of model file"),
    "atc-nf benchmark --policy bc_offline.zip --task converging-4 --split validation --runs 50": (
        "atc-nf benchmark --policy bc_offline.zip --task converging-4 --split validation --runs 2 --workers 1"
        " --no-progress",
        "2 validation runs (and the MPC's on the same seeds) give the same card"),
    "atc-nf evaluate --policy mpc --scenario converging-16 --runs 20": (
        "atc-nf evaluate --policy mpc --scenario converging-16 --runs 1 --workers 1 --no-progress",
        "20 dense MPC episodes take most of a minute; 1 goes through the same settings and summary"),
    "atc-nf evaluate --policy mpc --sampling joint --scenario converging-16 --runs 20": (
        "atc-nf evaluate --policy mpc --sampling joint --scenario converging-16 --runs 1 --workers 1 --no-progress",
        "20 dense MPC episodes take most of a minute; 1 goes through the same settings and summary"),
    "python -m agents.zoo --write": (
        "python -m agents.zoo",
        "--write rewrites the committed agents/README.md; test_zoo_table_is_generated checks it instead"),
}

#: Commands not run here. Written command -> why.
SKIPPED: dict[str, str] = {
    "make demo": "builds its own venv; it runs `atc-nf fly --policy mpc --scenario converging-4 --seed 0 --plots "
                 "out/figs`, which the `atc-nf fly` commands here cover",
    "make test": "this test suite",
    "atc-nf reproduce --runs 1000": "the paper's 1000-run study (tens of minutes); tests/test_reproduction.py runs "
                                    "`atc-nf reproduce` end to end with one run per study",
    "bash bench/regenerate.sh studies": "flies every published study again (tens of minutes) and rewrites "
                                        "committed tables",
    "python -m agents.baselines_table --write": "trains and scores every baseline (about half an hour) and "
                                                "rewrites docs/baselines.md; tests/test_baselines_table.py runs it "
                                                "on the quick budget into a temporary folder",
    "python -m agents.cards --summaries agents/results/summary.json,agents/results/deepsets_summary.json,"
    "agents/results/scratch_ppo_summary.json": "rewrites the committed model cards; tests/test_agents.py runs "
                                               "agents.cards into a temporary folder",
}
#: Training commands (minutes to tens of minutes), by prefix; tests/test_agents.py trains
#: and imitates at tiny scale.
SKIPPED_PREFIXES: dict[str, str] = {
    "atc-nf imitate ": "MPC demonstrations and behaviour cloning take minutes; tests/test_agents.py imitates at "
                      "tiny scale",
    "atc-nf train ": "PPO training takes minutes; tests/test_agents.py trains at tiny scale",
}
#: Libraries a python block may need that the test venv does not have.
OPTIONAL_LIBRARIES = ("ray.rllib", "torchrl", "benchmarl")
#: In a library's own venv (``make test-integrations``): run only the blocks naming it.
SNIPPETS_OF = os.environ.get("ATC_NF_SNIPPETS_OF")


def _names(code: str, module: str) -> bool:
    return re.search(rf"\b{re.escape(module)}\b", code) is not None


def code_blocks() -> list[tuple[str, str, str]]:
    """(document:line, language, code) of every fenced block (MyST directives aside)."""
    blocks = []
    for document in DOCUMENTS:
        text = document.read_text()
        for match in FENCE.finditer(text):
            language = match.group("info").strip()
            if language.startswith("{"):  # a MyST directive: toctree, include, eval-rst
                continue
            line = text.count("\n", 0, match.start()) + 1
            blocks.append((f"{document.relative_to(ROOT)}:{line}", language, match.group("body")))
    return blocks


BLOCKS = code_blocks()


def _blocks(language: str) -> list:
    return [pytest.param(code, id=where) for where, lang, code in BLOCKS if lang == language]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("MPLBACKEND", "Agg")
    return env


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    # Datasets a snippet records land in its own folder, never in the user's ~/.minari.
    env = {**_env(), "MINARI_DATASETS_PATH": str(cwd / "minari-datasets")}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)


@functools.cache
def _importable(module: str) -> bool:
    return _run([sys.executable, "-c", f"import {module}"], ROOT).returncode == 0


def test_every_block_has_a_language_this_test_runs() -> None:
    assert BLOCKS, "no code blocks found"
    unknown = [(where, lang) for where, lang, _ in BLOCKS if lang not in ("python", "bash", "toml")]
    assert not unknown, f"blocks this test cannot run (give python, bash or toml): {unknown}"


def test_a_library_venv_has_blocks_of_its_library() -> None:
    if SNIPPETS_OF is None:
        pytest.skip("ATC_NF_SNIPPETS_OF is set by make test-integrations only")
    assert SNIPPETS_OF in OPTIONAL_LIBRARIES
    assert any(_names(code, SNIPPETS_OF) for _, lang, code in BLOCKS if lang == "python")


@pytest.mark.parametrize("code", _blocks("python"))
def test_python_block_runs(code: str, tmp_path: Path) -> None:
    if SNIPPETS_OF is not None and not _names(code, SNIPPETS_OF):
        pytest.skip(f"not a block of {SNIPPETS_OF} (ATC_NF_SNIPPETS_OF)")
    # A name anywhere counts: atc_nf_env.integrations.torchrl needs torchrl too.
    missing = [m for m in OPTIONAL_LIBRARIES if _names(code, m) and not _importable(m)]
    if missing:
        pytest.skip(f"needs {', '.join(missing)}, not in this venv (make test-integrations builds its venv)")
    script = tmp_path / "snippet.py"
    script.write_text(code)
    result = _run([sys.executable, str(script)], tmp_path)
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"


def shell_commands(code: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments and blank lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", code)
    commands = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words:
            commands.append(shlex.join(words))
    return commands


def _normal(command: str) -> str:
    return shlex.join(shlex.split(command))


SCALED_N = {_normal(k): v for k, v in SCALED.items()}
SKIPPED_N = {_normal(k): v for k, v in SKIPPED.items()}
#: Commands that have passed in this test run: a command that two documents show (and that
#: reads nothing its block wrote) runs once.
_PASSED: set[str] = set()


@pytest.mark.parametrize("code", _blocks("bash"))
def test_bash_block_runs(code: str, tmp_path: Path) -> None:
    (tmp_path / "agents").symlink_to(ROOT / "agents")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    ran = []
    for command in shell_commands(code):
        if command in SKIPPED_N or any(command.startswith(p) for p in SKIPPED_PREFIXES):
            continue
        run_as = SCALED_N.get(command, (command, ""))[0]
        if run_as in _PASSED and "--resume" not in run_as:
            ran.append(run_as)
            continue
        words = shlex.split(run_as)
        if words[0] == "atc-nf":
            argv = [sys.executable, "-c", "import sys; from atc_nf_env.cli import main; sys.exit(main())", *words[1:]]
        elif words[0] == "python":
            argv = [sys.executable, *words[1:]]
        else:
            pytest.fail(f"{command!r}: only atc-nf and python commands run here; add it to SKIPPED with a reason")
        result = _run(argv, tmp_path)
        assert result.returncode == 0, (
            f"{run_as!r}: exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
        ran.append(run_as)
        _PASSED.add(run_as)
    if not ran:
        pytest.skip("every command of this block is in SKIPPED: " + "; ".join(shell_commands(code)))


def test_scaled_and_skipped_commands_are_in_the_documents() -> None:
    """No stale entry: each listed command still appears in some block."""
    documented = {c for _, lang, code in BLOCKS if lang == "bash" for c in shell_commands(code)}
    stale = sorted(set(SCALED_N) - documented) + sorted(set(SKIPPED_N) - documented)
    assert not stale, f"listed here but in no document: {stale}"


@pytest.mark.parametrize("code", _blocks("toml"))
def test_toml_block_parses_and_names_a_policy_group(code: str) -> None:
    from atc_nf_env.policy import POLICY_FILE_GROUP, POLICY_GROUP

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        tomllib = pytest.importorskip("tomli")
    data = tomllib.loads(code)
    groups = data.get("project", {}).get("entry-points", {})
    assert groups, "a toml block here declares entry points"
    for group, entries in groups.items():
        assert group in (POLICY_GROUP, POLICY_FILE_GROUP), f"{group!r} is not a group atc_nf_env reads"
        for name, target in entries.items():
            assert re.fullmatch(r"[\w.]+:[\w.]+", target), f"{name} = {target!r}: write 'module:attribute'"


def test_zoo_table_is_generated() -> None:
    """agents/README.md's model table is what `python -m agents.zoo` makes of agents/results/."""
    from agents import zoo
    from atc_nf_env.experiments.marked_sections import marked_sections

    section = marked_sections((ROOT / "agents" / "README.md").read_text())[zoo.SECTION]
    expected = f"<!-- begin {zoo.SECTION} -->\n{zoo.table().rstrip()}\n<!-- end {zoo.SECTION} -->"
    assert section == expected, "agents/README.md's model table is stale: run `python -m agents.zoo --write`"


def _summary(runs: int, los: int, envelope: int, flight: float, decision_s: float, seeds: int) -> dict:
    return {"runs": runs, "runs_with_los": los, "runs_with_envelope_violation": envelope,
            "flight_time_min": {"mean": flight}, "decision_s": {"mean": decision_s},
            "study": {"seeds": [0, seeds - 1], "wind_sigma_mps": 5.17, "max_time_s": 14400.0, "build": "b"}}


def test_zoo_counts_safe_runs_per_family_and_compares_with_the_mpc_on_the_same_seeds(tmp_path: Path) -> None:
    import json
    import shutil

    from agents import zoo

    results, models = tmp_path / "results", tmp_path / "models"
    results.mkdir()
    models.mkdir()
    shutil.copy(ROOT / "agents" / "models" / "finetuned_ppo.zip", models / "finetuned_ppo.zip")
    (results / "a_summary.json").write_text(json.dumps({
        "converging-4": {"mpc": _summary(10, 0, 0, 70.0, 0.01, 10),
                         "finetuned_ppo": _summary(10, 0, 2, 63.0, 30e-6, 10),
                         "finetuned_ppo+shield": _summary(10, 0, 0, 66.5, 90e-6, 10)},
        "random-6": {"finetuned_ppo": _summary(10, 1, 3, 60.0, 40e-6, 10)},
    }))
    # The larger study of a scenario wins; its MPC row is on other seeds, so no ratio there.
    (results / "b_summary.json").write_text(json.dumps({
        "random-6": {"finetuned_ppo": _summary(20, 1, 3, 60.0, 2e-3, 20), "mpc": _summary(10, 0, 0, 50.0, 0.01, 10)},
    }))
    text = zoo.table(results, models)
    converging = next(line for line in text.splitlines() if "| converging |" in line)
    random_row = next(line for line in text.splitlines() if "| random |" in line)
    assert "| PPO fine-tuning of DAgger: converging 4 |" in converging
    assert "| no: 8/10 | **yes**: 10/10 | 0.90×; 0.95× | 30 µs; 90 µs |" in converging
    # Both kinds of breach in one summary: the union is only bounded.
    assert "| 6 | no: ≤ 17/20 | not flown | no MPC run; – | 2.0 ms; – |" in random_row
