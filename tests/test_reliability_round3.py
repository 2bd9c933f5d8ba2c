"""Reliability, round 3: results files that can never mix studies, workers that die with
their parent, one writer per results file, special files, clear errors for foreign model
zips and hostile scenario files, and the smaller traps (numpy scalars, too many workers,
crowded random encounters, absurd headings, a random layout flown with another seed).

Each test reproduces one failure found by a hostile user and checks the clear error or
the correct result that replaced it.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from _faults import deadline

from atc_nf_env import build
from atc_nf_env import evaluate as evaluate_module
from atc_nf_env.episode import LayoutSeedWarning, run_episode
from atc_nf_env.evaluate import Study, evaluate, read_results, run_one
from atc_nf_env.policy import make_policy
from atc_nf_env.scenarios import Scenario, make_scenario, max_random_aircraft, scenario_from_dict
from baselines import NFDirect

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "agents" / "models"
TWO = {"aircraft": [{"start": [-250, 0], "destination": [250, 0]}, {"start": [0, -250], "destination": [0, 250]}]}
THREE = {"aircraft": [*TWO["aircraft"], {"start": [0, 250], "destination": [0, -150]}]}
#: A short study: 10 minutes of flight per run.
SHORT_S = 600.0


def _env() -> dict[str, str]:
    """The environment of a child Python that imports this checkout first."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


# ------------------------------------------------------------ 1. the build fingerprint hashes code


def test_code_digest_ignores_comments_and_docstrings_but_not_code() -> None:
    source = textwrap.dedent('''
        """Module docstring."""
        import math

        def f(x):
            """Docstring."""
            # a comment
            return math.sqrt(x) + 1
        ''')
    same = textwrap.dedent('''
        """Another module docstring, much longer
        and on two lines."""
        import math


        def f(x):   # a new comment
            """Another docstring."""
            "a string used as a comment"
            return math.sqrt(x) + 1  # and another
        ''')
    other = source.replace("+ 1", "+ 2")
    assert build.code_digest(source) == build.code_digest(same)
    assert build.code_digest(source) != build.code_digest(other)
    # A function whose body was only a docstring still does nothing.
    assert build.code_digest('def g():\n    """Doc."""\n') == build.code_digest("def g():\n    pass\n")


def _fingerprint_of_checkout(root: Path) -> str:
    done = subprocess.run(
        [sys.executable, "-c", "from atc_nf_env import build; print(build.fingerprint())"],
        env={**os.environ, "PYTHONPATH": str(root)}, cwd=root, capture_output=True, text=True, timeout=120,
        check=True,
    )
    return done.stdout.strip()


def test_a_comment_or_docstring_edit_keeps_the_fingerprint_and_a_code_edit_changes_it(tmp_path) -> None:
    """On a copy of the checkout: the plug-in packages (baselines, agents) are found by
    their entry points in the copy, without being imported."""
    ignore = shutil.ignore_patterns("__pycache__", "models", "results", "*.md")
    for name in ("atc_nf_env", "baselines", "agents"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=ignore)
    original = _fingerprint_of_checkout(tmp_path)
    assert original == build.fingerprint()  # the copy holds the same code

    kernel = tmp_path / "atc_nf_env" / "kernel.py"
    kernel.write_text('"""A rewritten module docstring."""\n# a new comment\n' + kernel.read_text() + "\n# the end\n")
    agent = tmp_path / "agents" / "policy.py"
    agent.write_text(agent.read_text().replace('"""Metadata assumed for a zip saved without ``atc_nf_meta``."""',
                                               '"""Metadata assumed when a zip has none (a fixed docstring)."""'))
    cli = tmp_path / "atc_nf_env" / "cli.py"
    cli.write_text(cli.read_text() + "\nUNUSED_BY_ANY_RUN = 1\n")  # the command line cannot change a run
    assert _fingerprint_of_checkout(tmp_path) == original

    agent.write_text(agent.read_text().replace('META_KEY = "atc_nf_meta"', 'META_KEY = "atc_nf_meta_2"'))
    assert _fingerprint_of_checkout(tmp_path) != original


def test_the_fingerprint_covers_agents_envs_shield_and_libraries_without_importing_plugins() -> None:
    names = {f"{p.parent.name}/{p.name}" for p in build.source_files()}
    assert {"atc_nf_env/kernel.py", "envs/observations.py", "envs/actions.py", "atc_nf_env/shield.py",
            "agents/policy.py", "agents/compiled_forward.py", "baselines/mcmc_mpc.py"} <= names
    assert "atc_nf_env/cli.py" not in names
    versions = build.library_versions()
    assert {"python", "numpy", "numba"} <= set(versions)
    pytest.importorskip("torch")
    assert {"torch", "stable-baselines3"} <= set(versions)
    done = subprocess.run(
        [sys.executable, "-c", ("import sys; from atc_nf_env import build; build.fingerprint(); "
                                "print(sorted({'baselines', 'agents', 'torch'} & set(sys.modules)))")],
        env=_env(), capture_output=True, text=True, timeout=120, check=True,
    )
    assert done.stdout.strip() == "[]"


# ------------------------------------------------------------ 1. the header identifies the study by content


def _study(scenario: str, **kwargs) -> Study:
    return Study(policy=kwargs.pop("policy", "nf"), scenario=scenario, max_time_s=SHORT_S, **kwargs)


def test_resume_refuses_a_scenario_file_edited_since(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("s.json").write_text(json.dumps(TWO))
    evaluate(_study("s.json"), 1, workers=1, out=Path("r.jsonl"), progress=False)
    Path("s.json").write_text(json.dumps(THREE))
    with pytest.raises(ValueError, match=r"r\.jsonl holds a different study \(scenario_identity"):
        evaluate(_study("s.json"), 2, workers=1, out=Path("r.jsonl"), resume=True, progress=False)
    _, runs = read_results(Path("r.jsonl"))
    assert [r["seed"] for r in runs] == [0]


def test_resume_accepts_one_scenario_file_by_a_relative_and_an_absolute_path(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("s.json").write_text(json.dumps(TWO))
    evaluate(_study("s.json"), 1, workers=1, out=Path("r.jsonl"), progress=False)
    evaluate(_study(str(tmp_path / "s.json")), 2, workers=1, out=tmp_path / "r.jsonl", resume=True, progress=False)
    _, runs = read_results(tmp_path / "r.jsonl")
    assert sorted(r["seed"] for r in runs) == [0, 1]


def test_the_scenario_identity_is_what_flies_not_where_it_was_read(tmp_path) -> None:
    (tmp_path / "a.json").write_text(json.dumps(dict(TWO, name="first")))
    (tmp_path / "b.json").write_text(json.dumps(dict(TWO, name="second")))
    assert _study(str(tmp_path / "a.json")).scenario_identity() == _study(str(tmp_path / "b.json")).scenario_identity()
    # A random family is not its seed-0 layout flown as a fixed encounter.
    (tmp_path / "r.json").write_text(json.dumps(make_scenario("random-3", seed=0).to_dict()))
    assert _study("random-3").scenario_identity() != _study(str(tmp_path / "r.json")).scenario_identity()


def test_a_file_of_the_old_format_is_refused_saying_why(tmp_path) -> None:
    out = tmp_path / "r.jsonl"
    header = _study("converging-3").header()
    old = {k: v for k, v in header.items() if k not in ("format", "policy_identity", "scenario_identity")}
    out.write_text(json.dumps(old) + "\n")
    with pytest.raises(ValueError, match=r"older atc-nf evaluate .*cannot be resumed"):
        evaluate(_study("converging-3"), 1, workers=1, out=out, resume=True, progress=False)


def _model_or_skip(name: str) -> Path:
    pytest.importorskip("stable_baselines3")
    path = MODELS / name
    if not path.is_file():
        pytest.skip(f"{name} is not shipped in this checkout")
    return path


def test_resume_refuses_a_model_file_replaced_since_and_accepts_it_by_another_path(tmp_path, monkeypatch) -> None:
    scratch, other = _model_or_skip("scratch_ppo.zip"), _model_or_skip("finetuned_ppo.zip")
    monkeypatch.chdir(tmp_path)
    shutil.copy(scratch, "m.zip")
    study = Study(policy="m.zip", scenario="converging-4", max_time_s=SHORT_S)
    assert study.header()["policy_identity"] == f"file sha256:{evaluate_module.file_sha256(scratch)}"
    evaluate(study, 1, workers=1, out=Path("r.jsonl"), progress=False)
    evaluate(Study(policy=str(tmp_path / "m.zip"), scenario="converging-4", max_time_s=SHORT_S), 2, workers=1,
             out=Path("r.jsonl"), resume=True, progress=False)
    shutil.copy(other, "m.zip")
    with pytest.raises(ValueError, match=r"holds a different study \(policy_identity"):
        evaluate(Study(policy="m.zip", scenario="converging-4", max_time_s=SHORT_S), 3, workers=1,
                 out=Path("r.jsonl"), resume=True, progress=False)
    # A study whose model file is replaced while it runs stops instead of mixing models.
    with pytest.raises(ValueError, match=r"m\.zip changed during the study"):
        run_one(study, 5)


# ------------------------------------------------------------ 2. workers die with their parent


def _children(pid: int) -> set[int]:
    """Processes whose parent is ``pid`` (Linux /proc)."""
    found = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(entry))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM", "SIGINT"])
def test_workers_die_with_their_parent_and_resume_is_exact(how, tmp_path) -> None:
    out = tmp_path / "r.jsonl"
    arguments = ["evaluate", "--policy", "nf", "--scenario", "converging-3", "--runs", "100000", "--workers", "2",
                 "--no-progress", "--max-minutes", "60", "--out", str(out)]
    # Ctrl-C as an interactive terminal delivers it: a suite started in the background of a
    # shell inherits SIGINT ignored, and so would the study (as it should, but untestably).
    interactive = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
                   "sys.argv[0] = 'atc-nf'; runpy.run_module('atc_nf_env.cli', run_name='__main__')")
    command = [sys.executable, "-c", interactive, *arguments]
    # stdout is a pipe, as in `atc-nf evaluate ... | cat`: it must close when the study dies.
    process = subprocess.Popen(command, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    closed = threading.Event()
    threading.Thread(target=lambda: (process.stdout.read(), closed.set()), daemon=True).start()
    descendants: set[int] = set()
    try:
        limit = time.time() + 240
        while time.time() < limit and (not out.exists() or out.read_text().count("\n") < 3):
            assert process.poll() is None, "the study ended before it was killed"
            time.sleep(0.2)
        descendants = _children(process.pid)
        descendants |= {c for d in descendants for c in _children(d)}
        assert len(descendants) >= 2, "no worker processes found"
        if how == "SIGINT":  # Ctrl-C reaches the whole foreground group
            os.killpg(process.pid, signal.SIGINT)
        else:
            os.kill(process.pid, getattr(signal, how))
        process.wait(timeout=30)
        limit = time.time() + 10
        while time.time() < limit and any(_alive(pid) for pid in descendants):
            time.sleep(0.1)
        assert not [pid for pid in descendants if _alive(pid)], f"processes outlived their parent ({how})"
        assert closed.wait(5), "stdout stayed open after the study died"
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        for pid in descendants:  # a failed test leaves no orphan behind
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    _, runs = read_results(out)
    wanted = max(r["seed"] for r in runs) + 2
    evaluate(Study(policy="nf", scenario="converging-3", max_time_s=3600.0), wanted, workers=1, out=out,
             resume=True, progress=False)
    _, resumed = read_results(out)
    assert {r["seed"] for r in resumed} >= set(range(wanted))
    reference = tmp_path / "reference.jsonl"
    evaluate(Study(policy="nf", scenario="converging-3", max_time_s=3600.0), wanted, workers=1, out=reference,
             progress=False)
    _, expected = read_results(reference)
    flight = lambda r: {k: v for k, v in r.items() if k not in {"wall_s", "decision_s_mean", "decision_s_each",
                                                                "peak_rss_mb", "compile_s"}}
    by_seed = {r["seed"]: flight(r) for r in resumed}
    assert all(by_seed[r["seed"]] == flight(r) for r in expected)


# ------------------------------------------------------------ 3. one writer per results file


def test_a_second_writer_is_refused_naming_the_file(tmp_path) -> None:
    out = tmp_path / "r.jsonl"
    holder = subprocess.Popen(
        [sys.executable, "-c", ("import sys, time; from pathlib import Path; "
                                "from atc_nf_env.evaluate import ResultsFile; f = ResultsFile(Path(sys.argv[1])); "
                                "print('locked', flush=True); time.sleep(120)"), str(out)],
        env=_env(), stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with deadline(30), pytest.raises(ValueError, match=rf"{out}.* is being written by another study"):
            evaluate(_study("converging-3"), 1, workers=1, out=out, resume=True, progress=False)
        with deadline(30), pytest.raises(ValueError, match=r"being written by another study"):
            evaluate(_study("converging-3"), 1, workers=1, out=out, progress=False)
    finally:
        holder.kill()
        holder.wait()
    evaluate(_study("converging-3"), 1, workers=1, out=out, resume=True, progress=False)  # free again


_RACER = """
import sys, time
from pathlib import Path
from atc_nf_env.evaluate import Study, evaluate
study = Study(policy="nf", scenario="converging-3", max_time_s=600.0)
go = Path(sys.argv[2])
while not go.exists():
    time.sleep(0.001)
try:
    evaluate(study, 2, workers=1, out=Path(sys.argv[1]), progress=False)
except ValueError as error:
    print("refused:", error)
else:
    print("flew")
"""


def test_two_fresh_starts_racing_give_one_study(tmp_path) -> None:
    out, go = tmp_path / "r.jsonl", tmp_path / "go"
    racers = [subprocess.Popen([sys.executable, "-c", _RACER, str(out), str(go)], env=_env(),
                               stdout=subprocess.PIPE, text=True) for _ in range(2)]
    time.sleep(8)  # both have imported and wait for the start
    go.touch()
    said = [racer.communicate(timeout=240)[0].strip() for racer in racers]
    assert sorted(line.split(":")[0] for line in said) == ["flew", "refused"], said
    assert "being written by another study" in said[1] + said[0] or "already holds a study" in said[1] + said[0]
    lines = out.read_text().splitlines()
    assert sum('"type": "header"' in line for line in lines) == 1 and len(lines) == 3


# ------------------------------------------------------------ 4. special files


def _limit_memory() -> None:
    """In the child: at most 4 GiB of address space, so that a build that reads /dev/zero
    fails there instead of taking the machine's memory."""
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux device files")
@pytest.mark.parametrize("special", ["/dev/zero", "/dev/full", "fifo", "directory"])
def test_a_special_results_file_is_refused_before_anything_is_read_or_flown(special, tmp_path) -> None:
    if special == "fifo":
        path = tmp_path / "fifo.jsonl"
        os.mkfifo(path)
    elif special == "directory":
        path = tmp_path / "folder.jsonl"
        path.mkdir()
    else:
        path = Path(special)
        if not path.exists():
            pytest.skip(f"no {special} here")
    for resume in ([], ["--resume"]):
        # In a child with a memory limit and a time limit: what failed here read /dev/zero
        # until the memory ran out, and waited on the FIFO for ever.
        done = subprocess.run(
            [sys.executable, "-m", "atc_nf_env.cli", "evaluate", "--policy", "nf", "--scenario", "converging-3",
             "--runs", "1", "--workers", "1", "--no-progress", "--out", str(path), *resume],
            env=_env(), capture_output=True, text=True, timeout=90, preexec_fn=_limit_memory, check=False,
        )
        assert done.returncode == 2, done.stderr[-2000:]
        assert re.search(rf"error: .*{re.escape(str(path))} is (not a regular file|a directory)", done.stderr), done.stderr
        assert done.stdout == ""  # nothing flown, no summary
    if special in ("fifo", "directory"):
        with deadline(20), pytest.raises(ValueError, match=rf"{re.escape(str(path))} is (not a regular file|a dir)"):
            evaluate(_study("converging-3"), 1, workers=1, out=path, resume=True, progress=False)


def test_a_full_disk_names_the_results_file(tmp_path, monkeypatch) -> None:
    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(evaluate_module.os, "fsync", full)
    out = tmp_path / "r.jsonl"
    with pytest.raises(OSError) as caught:
        evaluate(_study("converging-3"), 1, workers=1, out=out, progress=False)
    assert caught.value.errno == errno.ENOSPC and str(out) in str(caught.value)


# ------------------------------------------------------------ 5. clear errors for foreign models and scenario files


def _sb3_zips(folder: Path) -> dict[str, Path]:
    gym = pytest.importorskip("gymnasium")
    sb3 = pytest.importorskip("stable_baselines3")

    class Tiny(gym.Env):
        observation_space = gym.spaces.Box(-1, 1, (4,), np.float32)

        def __init__(self, action_space):
            self.action_space = action_space

        def reset(self, seed=None, options=None):
            return np.zeros(4, np.float32), {}

        def step(self, action):
            return np.zeros(4, np.float32), 0.0, True, False, {}

    box = gym.spaces.Box(-1, 1, (2,), np.float32)
    paths = {name: folder / f"{name}.zip" for name in ("dqn", "td3", "sac", "ppo_labelled_sac")}
    sb3.DQN("MlpPolicy", Tiny(gym.spaces.Discrete(3))).save(paths["dqn"])
    sb3.TD3("MlpPolicy", Tiny(box)).save(paths["td3"])
    sb3.SAC("MlpPolicy", Tiny(box)).save(paths["sac"])
    ppo = sb3.PPO("MlpPolicy", Tiny(box))
    ppo.atc_nf_meta = {"algo": "sac", "mode": "shared"}
    ppo.save(paths["ppo_labelled_sac"], include=["atc_nf_meta"])
    return paths


def test_foreign_and_mislabelled_model_zips_are_refused_saying_what_they_hold(tmp_path) -> None:
    import zipfile

    paths = _sb3_zips(tmp_path)
    shipped = _model_or_skip("scratch_ppo.zip").read_bytes()
    paths["truncated"] = tmp_path / "truncated.zip"
    paths["truncated"].write_bytes(shipped[: len(shipped) // 2])
    paths["foreign"] = tmp_path / "foreign.zip"
    with zipfile.ZipFile(paths["foreign"], "w") as archive:
        archive.writestr("notes.txt", "not a model")
    paths["text"] = tmp_path / "text.zip"
    paths["text"].write_text("hello")
    said = {"dqn": "another algorithm \\(DQNPolicy", "td3": "another algorithm \\(TD3Policy",
            "sac": "a SAC model \\(SACPolicy\\) and no atc_nf_meta", "ppo_labelled_sac": "says algorithm 'sac', but it "
            "holds a PPO model", "truncated": "without a Stable-Baselines3 'data' entry",
            "foreign": "without a Stable-Baselines3 'data' entry", "text": "not a Stable-Baselines3 model, or a damaged one"}
    for name, path in paths.items():
        with pytest.raises(ValueError, match=rf"{path.name}: .*{said[name]}.*accepted: a PPO model") as caught:
            make_policy(str(path))
        assert isinstance(caught.value, ValueError), name


def test_hostile_scenario_files_are_refused_naming_the_file(tmp_path) -> None:
    big = tmp_path / "big.json"
    big.write_text('{"aircraft": [{"start": [' + "9" * 400 + ', 0], "destination": [100, 0]}]}')
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"name": "caf\xe9", "aircraft": []}')
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    cases = {big: r"too large for a float", deep: r"nested too deeply", latin: r"not UTF-8",
             fifo: r"not a regular file"}
    for path, why in cases.items():
        with deadline(20), pytest.raises(ValueError, match=rf"scenario file '{path}'.*{why}"):
            make_scenario(str(path))
    with pytest.raises(ValueError, match=r"aircraft\[0\]\.start = an integer of about \d+ digits"):
        scenario_from_dict({"aircraft": [{"start": [10**5000, 0], "destination": [1, 0]}]})


# ------------------------------------------------------------ 6. smaller traps


def test_numpy_scalars_in_a_study_and_its_counts(tmp_path) -> None:
    out = tmp_path / "r.jsonl"
    study = Study(policy="nf", scenario="converging-3", wind_sigma_mps=np.float32(5.17), max_time_s=SHORT_S)
    summary = evaluate(study, np.int64(2), first_seed=np.int64(2), workers=1, out=out, progress=False)
    assert summary["runs"] == 2
    header, runs = read_results(out)
    assert header["wind_sigma_mps"] == float(np.float32(5.17)) and sorted(r["seed"] for r in runs) == [2, 3]
    with pytest.raises(TypeError, match=r"runs = (np\.)?True_?: must be an integer"):
        evaluate(study, np.bool_(True), workers=1, progress=False)


def test_never_more_local_workers_than_cpus_or_runs(monkeypatch) -> None:
    seen = []

    class Started(Exception):
        pass

    def runner(study, seeds, workers):
        seen.append(workers)
        raise Started

    monkeypatch.setattr(evaluate_module, "usable_cpus", lambda: 2)
    monkeypatch.setattr(evaluate_module, "_run_local", runner)
    study = _study("converging-3")
    with pytest.warns(UserWarning, match=r"workers = 1000: this process may use 2 CPUs"), pytest.raises(Started):
        evaluate(study, 40, workers=1000, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(Started):
            evaluate(study, 1, workers=2, progress=False)
    assert seen == [2, 1]


def test_every_seed_of_a_crowded_random_family_gives_a_layout_and_old_layouts_stay() -> None:
    for seed in range(12):  # random-18 once failed at seeds 8, 9 and 12
        scenario = make_scenario("random-18", seed=seed)
        assert scenario.n_aircraft == 18
    # Layouts that the generator found before stay: the same draws, so the same coordinates.
    # Compared rounded, not bit for bit: numpy's cos and sin take CPU-dependent SIMD paths
    # (SVML on AVX-512), so the last bits of a layout differ between machines while the draws
    # that pick it do not (random-18 seed 0: the closest spread test is 0.058 nm from 20 nm).
    assert _rounded_layout_sha256(make_scenario("random-6", seed=0)) == LAYOUT_RANDOM_6_SEED_0
    assert _rounded_layout_sha256(make_scenario("random-18", seed=0)) == LAYOUT_RANDOM_18_SEED_0
    limit = max_random_aircraft()
    with pytest.raises(ValueError, match=rf"n = {limit + 1} aircraft .* at most {limit}"):
        make_scenario(f"random-{limit + 1}", seed=5)
    make_scenario("random-20", seed=5)


def _rounded_layout_sha256(scenario: Scenario) -> str:
    """SHA-256 (hex) of the layout rounded to 1e-6 nm and 1e-9 rad: the same on every CPU."""
    rounded = [
        np.round(scenario.start_xy, 6).tolist(),
        np.round(scenario.dest_xy, 6).tolist(),
        np.round(scenario.start_heading, 9).tolist(),
        np.round(scenario.dest_heading, 9).tolist(),
    ]
    return hashlib.sha256(json.dumps(rounded).encode()).hexdigest()


LAYOUT_RANDOM_6_SEED_0 = "622d1f670c5fdaf69e034d6e0fb3a55cbaac7b288ef806a2a36a09bb56f6a127"
LAYOUT_RANDOM_18_SEED_0 = "c83535b3a6743756c2d634c6ec91e4d99b195c3284e167c219de21cb4a6de561"


@pytest.mark.parametrize("degrees", [1e308, -1e50, 360.5, -720.0])
def test_absurd_headings_are_refused_saying_the_range(degrees) -> None:
    aircraft = {"start": [0, 0], "destination": [100, 0], "heading_deg": degrees}
    with pytest.raises(ValueError, match=r"aircraft\[0\]\.heading_deg = .*\[-360, 360\]"):
        scenario_from_dict({"aircraft": [aircraft]})
    with pytest.raises(ValueError, match=r"arrival_heading_deg = .*\[-360, 360\]"):
        scenario_from_dict({"aircraft": [{"start": [0, 0], "destination": [100, 0], "arrival_heading_deg": degrees}]})


def test_headings_within_one_turn_fly_and_radians_beyond_are_refused() -> None:
    for degrees in (360.0, -360.0, 359.9, 0.0):
        scenario_from_dict({"aircraft": [{"start": [0, 0], "destination": [100, 0], "heading_deg": degrees}]})
    with pytest.raises(ValueError, match=r"start_heading\[0\] = .*\[-2\*pi, 2\*pi\]"):
        Scenario("x", [[0.0, 0.0]], [7.0], [[100.0, 0.0]], [0.0])
    with pytest.raises(ValueError, match=r"start_heading contains NaN"):
        scenario_from_dict({"aircraft": [{"start": [0, 0], "destination": [100, 0], "heading_deg": math.nan}]})


def test_run_episode_draws_a_named_random_layout_with_the_run_seed_and_warns_on_a_mismatch() -> None:
    layouts = {s: run_episode(NFDirect(), "random-6", seed=s, max_time_s=300.0, record_every=1).records[0, :, :2]
               .tobytes() for s in (1, 2)}
    assert layouts[1] != layouts[2]
    assert layouts[1] == run_episode(NFDirect(), make_scenario("random-6", seed=1), seed=1, max_time_s=300.0,
                                     record_every=1).records[0, :, :2].tobytes()
    with pytest.warns(LayoutSeedWarning, match=r"'random-6' was drawn with seed 0 and is flown with seed 3"):
        run_episode(NFDirect(), make_scenario("random-6"), seed=3, max_time_s=300.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run_episode(NFDirect(), make_scenario("random-6", seed=3), seed=3, max_time_s=300.0)
        run_episode(NFDirect(), make_scenario("converging-3"), seed=3, max_time_s=300.0)
