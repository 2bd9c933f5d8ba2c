"""The behaviour stamp (``atc_nf_env.experiments.behaviour``): a table is flown again only
when a part of what the code flies moved or its command changed, and every part of the
stamp is bit-for-bit reproducible."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from atc_nf_env.experiments import behaviour
from atc_nf_env.experiments.marked_sections import write_marked_section

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def fake_stamp(monkeypatch):
    """Stands in for the probes: {part: value}, changed by the test to move a part."""
    values = {part: f"{part:0<16}"[:16] for part in behaviour.PARTS}
    values[behaviour.BUILD] = "b" * 16

    def table_stamp(parts):
        return {part: values[part] for part in parts}

    monkeypatch.setattr(behaviour, "table_stamp", table_stamp)
    return values


def _script(tmp_path: Path, body: str, name: str = "table_script.py") -> Path:
    script = tmp_path / name
    script.write_text(textwrap.dedent(body))
    return script


def _page(tmp_path: Path) -> Path:
    page = tmp_path / "page.md"
    write_marked_section(page, "alpha", "## Alpha\n\n| a |\n|---|\n| 1 |\n", header="# Page\n")
    write_marked_section(page, "beta", "## Beta\n\nbeta's text\n")
    return page


def test_the_command_is_its_code_and_arguments_not_where_it_writes(tmp_path):
    script = _script(tmp_path, '"""A table."""\nprint(1)\n')
    base = behaviour.command_identity([sys.executable, str(script), "--runs", "20"])
    assert behaviour.command_identity(["python", str(script), "--runs", "20", "--write"]) == base
    assert behaviour.command_identity([str(script), "--no-progress", "--runs", "20"]) == base
    assert behaviour.command_identity([str(script), "--reuse-mpc", "out/x", "--runs", "20"]) == base
    assert behaviour.command_identity([str(script), "--runs", "21"]) != base
    script.write_text('"""Another docstring."""\n# a comment\nprint(1)\n')
    assert behaviour.command_identity([str(script), "--runs", "20"]) == base, "comments and docstrings are not code"
    script.write_text('"""A table."""\nprint(2)\n')
    assert behaviour.command_identity([str(script), "--runs", "20"]) != base
    module = behaviour.command_identity(["python", "-m", "atc_nf_env.experiments.reproduce", "--runs", "5"])
    assert module == behaviour.command_identity(
        [str(ROOT / "atc_nf_env" / "experiments" / "reproduce.py"), "--runs", "5"])
    with pytest.raises(ValueError, match="cannot be found"):
        behaviour.command_identity(["python", "-m", "no_such_module_anywhere"])
    with pytest.raises(ValueError, match="not a file"):
        behaviour.command_identity([str(tmp_path / "missing.py")])


def test_a_stamp_goes_into_its_own_section_once_and_a_rewrite_of_the_section_drops_it(tmp_path, fake_stamp):
    page = _page(tmp_path)
    before = page.read_text()
    script = _script(tmp_path, "print(1)\n")
    line = behaviour.stamp_line(["kernel", "mpc"], [str(script)])
    assert line.startswith("<!-- behaviour stamp: kernel=") and " mpc=" in line and " command=" in line
    behaviour.write_stamp(page, "alpha", line)
    behaviour.write_stamp(page, "alpha", line)
    text = page.read_text()
    assert text.count("behaviour stamp") == 1
    assert behaviour.read_stamp(behaviour.table_text(page, "alpha"))["kernel"] == fake_stamp["kernel"]
    assert behaviour.read_stamp(behaviour.table_text(page, "beta")) is None
    assert text.replace(line + "\n", "").replace("\n\n<!-- end alpha", "\n<!-- end alpha") == before
    write_marked_section(page, "alpha", "## Alpha\n\nflown by hand\n")
    assert behaviour.read_stamp(behaviour.table_text(page, "alpha")) is None
    whole = tmp_path / "table.md"
    whole.write_text("| a |\n|---|\n| 1 |\n")
    behaviour.write_stamp(whole, None, line)
    behaviour.write_stamp(whole, None, line)
    assert whole.read_text() == f"| a |\n|---|\n| 1 |\n\n{line}\n"
    with pytest.raises(ValueError, match="no section 'gamma'"):
        behaviour.write_stamp(page, "gamma", line)


def test_a_table_is_stale_exactly_when_a_part_it_depends_on_or_its_command_moved(tmp_path, fake_stamp):
    page = _page(tmp_path)
    script = _script(tmp_path, "print(1)\n")
    command = [str(script), "--runs", "3"]
    assert "no stamp line" in behaviour.why_stale(page, "alpha", ["kernel"], command)
    assert "no such table" in behaviour.why_stale(page, "gamma", ["kernel"], command)
    assert "no such table" in behaviour.why_stale(tmp_path / "none.md", None, ["kernel"], command)
    behaviour.write_stamp(page, "alpha", behaviour.stamp_line(["kernel", "mpc"], command))
    assert behaviour.why_stale(page, "alpha", ["kernel", "mpc"], command) is None
    fake_stamp["agents"] = "a" * 16
    assert behaviour.why_stale(page, "alpha", ["kernel", "mpc"], command) is None, "a part it does not read"
    flown_with = fake_stamp["mpc"]
    fake_stamp["mpc"] = "1" * 16
    reason = behaviour.why_stale(page, "alpha", ["kernel", "mpc"], command)
    assert "behaviour moved" in reason and "mpc" in reason and "kernel" not in reason
    fake_stamp["mpc"] = flown_with
    assert behaviour.why_stale(page, "alpha", ["kernel", "mpc"], command) is None
    assert "missing" in behaviour.why_stale(page, "alpha", ["kernel", "mpc", "filter"], command)
    assert "command changed" in behaviour.why_stale(page, "alpha", ["kernel", "mpc"], [str(script), "--runs", "4"])
    fake_stamp["kernel"] = behaviour.UNAVAILABLE
    assert "cannot be judged" in behaviour.why_stale(page, "alpha", ["kernel", "mpc"], command)


def test_a_table_flown_on_another_machine_is_flown_again(tmp_path, fake_stamp, monkeypatch):
    page = _page(tmp_path)
    command = [str(_script(tmp_path, "print(1)\n")), "--runs", "3"]
    here = behaviour.machine_identity()
    line = behaviour.stamp_line(["kernel"], command)
    assert f" machine={here} " in line
    behaviour.write_stamp(page, "alpha", line)
    assert behaviour.why_stale(page, "alpha", ["kernel"], command) is None
    monkeypatch.setattr(behaviour, "machine_identity", lambda: "0" * 8)
    assert f"flown on another machine ({here} -> 00000000)" in behaviour.why_stale(page, "alpha", ["kernel"], command)
    # A stamp written before the machine was named is judged by its parts.
    behaviour.write_stamp(page, "alpha", line.replace(f" machine={here}", ""))
    assert behaviour.why_stale(page, "alpha", ["kernel"], command) is None


def test_fly_skips_a_fresh_table_flies_a_stale_one_and_never_stamps_a_failure(tmp_path, fake_stamp, capsys):
    page = _page(tmp_path)
    marker = tmp_path / "flown"
    script = _script(tmp_path, f"""
        import sys
        from pathlib import Path
        from atc_nf_env.experiments.marked_sections import write_marked_section
        Path({str(marker)!r}).write_text(Path({str(marker)!r}).read_text() + "x" if Path({str(marker)!r}).exists() else "x")
        if "--fail" in sys.argv:
            sys.exit(4)
        write_marked_section(Path({str(page)!r}), "alpha", "## Alpha\\n\\nflown\\n")
    """)
    command = [sys.executable, str(script)]
    assert behaviour.fly_table(page, "alpha", ["kernel"], command, force=False) == 0
    assert marker.read_text() == "x" and "flown" in behaviour.table_text(page, "alpha")
    assert behaviour.why_stale(page, "alpha", ["kernel"], command) is None
    assert behaviour.fly_table(page, "alpha", ["kernel"], command, force=False) == 0
    assert marker.read_text() == "x", "a fresh table is not flown again"
    assert "fresh" in capsys.readouterr().out
    assert behaviour.fly_table(page, "alpha", ["kernel"], command, force=True) == 0
    assert marker.read_text() == "xx"
    fake_stamp["kernel"] = "2" * 16
    assert behaviour.fly_table(page, "alpha", ["kernel"], command, force=False) == 0
    assert marker.read_text() == "xxx" and behaviour.why_stale(page, "alpha", ["kernel"], command) is None
    failing = [*command, "--fail"]
    assert behaviour.fly_table(page, "alpha", ["kernel"], failing, force=False) == 4
    assert "command changed" in behaviour.why_stale(page, "alpha", ["kernel"], failing)
    fake_stamp["agents"] = behaviour.UNAVAILABLE
    assert behaviour.fly_table(page, "alpha", ["agents"], command, force=False) == 2
    assert marker.read_text() == "xxxx", "a part that cannot be computed stops it before flying"


def test_the_code_changing_while_a_table_flies_leaves_it_unstamped(tmp_path, fake_stamp, monkeypatch):
    page = _page(tmp_path)
    script = _script(tmp_path, "print('flying')\n")
    calls = []
    real = behaviour.table_stamp

    def moving(parts):
        calls.append(1)
        stamp = real(parts)
        return {k: (v if len(calls) == 1 else "9" * 16) for k, v in stamp.items()}

    monkeypatch.setattr(behaviour, "table_stamp", moving)
    assert behaviour.fly_table(page, "alpha", ["kernel"], [sys.executable, str(script)], force=True) == 3
    assert behaviour.read_stamp(behaviour.table_text(page, "alpha")) is None


def test_unknown_parts_are_refused_naming_the_allowed_ones(tmp_path):
    with pytest.raises(ValueError, match="allowed: kernel, env, stream, mpc, filter, agents"):
        behaviour.compute_stamp(["kernel", "physics"])
    result = subprocess.run([sys.executable, "-m", "atc_nf_env.experiments.behaviour", "check", "BENCHMARKS.md",
                             "kernel", "--parts", "kernel,physics", "--", "bench/bench_kernel.py"],
                            cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 2 and "allowed: kernel, env, stream, mpc, filter, agents, build" in result.stderr


def test_the_kernel_part_is_bit_for_bit_the_same_in_another_process_and_sees_the_law(tmp_path):
    here = behaviour.compute_stamp(["kernel"])["kernel"]
    assert len(here) == 16 and here == behaviour.compute_stamp(["kernel"])["kernel"]
    env = {**os.environ, "ATC_NF_BEHAVIOUR_CACHE": str(tmp_path)}
    out = subprocess.run([sys.executable, "-m", "atc_nf_env.experiments.behaviour", "show", "--parts", "kernel"],
                         cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["kernel", here]
    from atc_nf_env.config import SimConfig

    assert behaviour.kernel_part(SimConfig(k_theta=SimConfig().k_theta * 1.01)) != here


def test_the_stamp_is_cached_per_build_and_recomputed_for_a_part_not_yet_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("ATC_NF_BEHAVIOUR_CACHE", str(tmp_path))
    flown = []
    monkeypatch.setitem(behaviour.PROBES, "kernel", lambda: flown.append("kernel") or "k" * 16)
    monkeypatch.setitem(behaviour.PROBES, "mpc", lambda: flown.append("mpc") or "m" * 16)
    assert behaviour.current_stamp(["kernel"]) == {"kernel": "k" * 16}
    assert behaviour.current_stamp(["mpc", "kernel"]) == {"kernel": "k" * 16, "mpc": "m" * 16}
    assert behaviour.current_stamp(["kernel", "mpc"]) == {"kernel": "k" * 16, "mpc": "m" * 16}
    assert flown == ["kernel", "mpc"]
    (tmp_path / f"{behaviour.cache_key()}.json").write_text("{not json")
    assert behaviour.current_stamp(["kernel"]) == {"kernel": "k" * 16} and flown[-1] == "kernel"


@pytest.mark.slow
def test_every_part_is_bit_for_bit_the_same_in_another_process(tmp_path):
    here = behaviour.compute_stamp()
    env = {**os.environ, "ATC_NF_BEHAVIOUR_CACHE": str(tmp_path)}
    out = subprocess.run([sys.executable, "-m", "atc_nf_env.experiments.behaviour", "show"],
                         cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout
    assert dict(line.split() for line in out.splitlines()) == here


def test_regenerate_fails_before_flying_when_the_venv_lacks_a_library(tmp_path):
    bare = tmp_path / "python"
    # -S: no site-packages, so neither torch nor Stable-Baselines3 nor Minari can be found.
    bare.write_text(f"#!/bin/sh\nexec {sys.executable} -S \"$@\"\n")
    bare.chmod(0o755)
    result = subprocess.run(["bash", "bench/regenerate.sh"], cwd=ROOT, env={**os.environ, "PYTHON": str(bare)},
                            capture_output=True, text=True, timeout=60)
    assert result.returncode != 0
    assert "lacks torch, stable_baselines3, minari" in result.stderr
    assert "[" not in result.stdout, "nothing was checked or flown"
