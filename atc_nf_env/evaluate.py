"""Monte Carlo evaluation of a policy: many seeded episodes, in parallel, resumable.

Every run is one episode with seed s (s = first_seed … first_seed + runs − 1): the seed
fixes the hidden wind and the policy's randomness, so two policies evaluated on the
same seeds face the same winds. Runs go to local worker processes (all cores by
default) or to a Ray cluster (``backend="ray"``, the ``ray`` extra). Each finished run
is appended to a JSON-lines file as soon as it ends, so an interrupted study resumed
with ``resume=True`` loses nothing and repeats nothing.

File format: the first line is a header naming the study (policy, scenario, wind,
settings) and identifying what was flown by content (``Study.header``: the scenario as
flown, the model file's bytes, the build fingerprint of the code), so that a resume can
never mix two studies; every other line is one run's metrics (``RunMetrics.to_dict()``) with the
policy's diagnostics under ``policy_info`` and the worker's peak memory under
``peak_rss_mb`` and, for the process's first run of the study, the untimed warm-up
before it under ``compile_s`` (0 for later runs).

One process writes a results file at a time: ``evaluate`` holds an OS lock on it
(``fcntl.flock``) for the whole study and refuses a file another study holds. Worker
processes die with the process that started them (Linux: ``PR_SET_PDEATHSIG``; elsewhere
a watchdog thread), so a killed study leaves no orphan behind.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import signal
import stat
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from atc_nf_env import build, kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import MAX_EPISODE_S, run_episode, warm_up, whole_steps
from atc_nf_env.metrics import RunMetrics, peak_rss_mb, summarize
from atc_nf_env.policy import Policy, make_policy  # (re-exported: the evaluator resolves policies by name)
from atc_nf_env.scenarios import MAX_SEED, Scenario, draws_per_seed, make_scenario
from atc_nf_env.shield import SafetyFilter, summarize_interventions
from atc_nf_env.simulation import check_wind_sigma
from atc_nf_env.units import WIND_SIGMA_MPS

BACKENDS = ("local", "ray")

#: Version of the results header. 2: the header identifies the scenario, the policy and
#: the code by content (``scenario_identity``, ``policy_identity``, ``build``). Files of
#: another version are not resumed.
RESULTS_FORMAT = 2

#: Header keys that only label the study for a reader (the path or name as given): a
#: resume compares the identities instead, so that one file named by a relative or an
#: absolute path is the same study.
LABEL_KEYS = ("policy", "scenario")


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _is_policy_file(spec: str) -> bool:
    """Whether ``make_policy`` reads ``spec`` from a file (its suffix is a registered one)."""
    from atc_nf_env.policy import POLICY_FILE_GROUP, _entry_points

    suffix = Path(spec).suffix.lower().lstrip(".")
    return bool(suffix) and suffix in _entry_points(POLICY_FILE_GROUP)


def _plain(value: Any) -> Any:
    """``json.dumps``'s fallback: numpy scalars and arrays as Python numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} {value!r} is not JSON serializable")


@dataclass(frozen=True)
class Study:
    """What a Monte Carlo study runs: the same for every run but the seed."""

    policy: str
    scenario: str
    wind_sigma_mps: float = WIND_SIGMA_MPS
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    max_time_s: float = MAX_EPISODE_S
    #: Trace every integration step of each run and keep, per window of this many
    #: seconds (for the paper's Figs. 4 and 9), each aircraft's minimum, mean and
    #: maximum airspeed over the steps it flew in the window, as ``airspeed_band_kt``
    #: [aircraft][window] = [min, mean, max] (null where it flew no step); with them
    #: ``airspeed_mean_kt`` (over every step flown), ``distance_short_nm`` (per aircraft,
    #: null if it arrived), ``excursion_decisions`` (decisions whose period has a step
    #: outside the envelope) and ``fallback_decisions`` (the policy's fallbacks, when it
    #: keeps ``decisions`` records with a ``fallback`` flag, as the MPC does).
    airspeed_every_s: float | None = None
    #: Named physics (``SimConfig.preset``): "default" or "paper-nf".
    physics: str = "default"
    #: Fly the policy inside the safety filter (``atc_nf_env.shield.SafetyFilter`` with its
    #: defaults); its counts go to each run's ``policy_info`` and the summary's ``shield``.
    shield: bool = False
    #: Keyword arguments of the safety filter (``shield`` only), e.g. ``{"mpc_settings":
    #: {"extractions": 200}}`` for its MPC fallback; empty: its defaults.
    shield_kwargs: dict[str, Any] = field(default_factory=dict)

    #: The scenario as flown, resolved once here (a file is read once: every run flies what
    #: the header identifies); None for a ``random-N`` name, drawn per run with its seed.
    _fixed_scenario: Scenario | None = field(default=None, init=False, repr=False, compare=False)
    #: SHA-256 of the model file when the policy is read from one.
    _policy_sha256: str | None = field(default=None, init=False, repr=False, compare=False)
    #: ``scenario_identity``'s text, computed once from the draw of seed 0.
    _scenario_identity: str = field(default="", init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        SimConfig.preset(self.physics)  # a clear error on an unknown name
        check_wind_sigma(self.wind_sigma_mps)
        # numpy scalars (np.float32(5.17)) become the Python float of the same value: the
        # same number flies, and the header can be written as JSON.
        for name in ("wind_sigma_mps", "max_time_s", "airspeed_every_s"):
            value = getattr(self, name)
            if isinstance(value, (np.floating, np.integer)) and not isinstance(value, np.bool_):
                object.__setattr__(self, name, value.item())
        if not isinstance(self.shield, bool):
            raise TypeError(f"shield = {self.shield!r}: must be True or False")
        if not isinstance(self.shield_kwargs, dict):
            raise TypeError(f"shield_kwargs = {self.shield_kwargs!r}: must be a dict of SafetyFilter's settings")
        if self.shield_kwargs and not self.shield:
            raise ValueError(f"shield_kwargs = {self.shield_kwargs!r}: set the safety filter's settings with shield=True")
        if not isinstance(self.policy_kwargs, dict):
            raise TypeError(f"policy_kwargs = {self.policy_kwargs!r}: must be a dict of the policy's settings")
        # A time limit off the integration grid is refused here, before any worker starts.
        whole_steps("max_time_s", self.max_time_s, SimConfig.preset(self.physics).dt_s)
        if self.airspeed_every_s is not None:
            whole_steps("airspeed_every_s", self.airspeed_every_s, SimConfig.preset(self.physics).dt_s)
        # Fail before any worker starts on a bad name or setting.
        policy = self.make_policy()
        scenario = make_scenario(self.scenario, seed=0)
        if isinstance(policy, SafetyFilter):
            policy.fallback_for(scenario)  # its fallback's settings on this kind of scenario
        if draws_per_seed(self.scenario):
            identity = f"{self.scenario} per seed, seed 0 sha256:{scenario.content_sha256()}"
        else:
            object.__setattr__(self, "_fixed_scenario", scenario)
            identity = f"fixed sha256:{scenario.content_sha256()}"
        object.__setattr__(self, "_scenario_identity", identity)
        if isinstance(self.policy, str) and _is_policy_file(self.policy):
            object.__setattr__(self, "_policy_sha256", file_sha256(self.policy))

    def scenario_for(self, seed: int) -> Scenario:
        """The scenario that the run with ``seed`` flies."""
        if self._fixed_scenario is not None:
            return self._fixed_scenario
        return make_scenario(self.scenario, seed=seed)

    def scenario_identity(self) -> str:
        """What the study's scenario flies, by content: ``fixed sha256:H`` for one encounter
        (H: ``Scenario.content_sha256``, whether it came from a name, a dict or a file), or
        ``random-N per seed, seed 0 sha256:H`` for a family drawn with each run's seed (the
        generator's code is in the build fingerprint)."""
        return self._scenario_identity

    def policy_identity(self) -> str:
        """What the study's policy is, by content: its name for a named policy (its code is
        in the build fingerprint), or ``file sha256:H`` of a model file's bytes."""
        if self._policy_sha256 is not None:
            return f"file sha256:{self._policy_sha256}"
        return f"name {self.policy}"

    def check_policy_file_unchanged(self) -> None:
        """Raise ValueError if the model file no longer holds the bytes the study started with."""
        if self._policy_sha256 is None:
            return
        path = Path(self.policy)
        try:
            info = path.stat()
        except OSError as error:
            raise ValueError(f"model file {self.policy}: {error.strerror} (it was there when the study started)") from None
        key = (str(path.resolve()), info.st_mtime_ns, info.st_size)
        if _checked_policy_files.get(key) is None:
            _checked_policy_files[key] = file_sha256(path)
        if _checked_policy_files[key] != self._policy_sha256:
            raise ValueError(
                f"model file {self.policy} changed during the study (sha256 {_checked_policy_files[key][:12]}…, "
                f"the study started with {self._policy_sha256[:12]}…); its runs would mix two models"
            )

    def make_policy(self) -> Policy:
        """The study's policy (inside the safety filter when ``shield``)."""
        policy = make_policy(self.policy, **self.policy_kwargs)
        return SafetyFilter(policy, **self.shield_kwargs) if self.shield else policy

    def header(self) -> dict[str, Any]:
        """The results file's first line: what the study is and, by content, what it flies.

        ``policy`` and ``scenario`` label it as given (``LABEL_KEYS``); ``policy_identity``,
        ``scenario_identity`` and ``build`` (``atc_nf_env.build.fingerprint``: the code and
        the numerical libraries) identify it, with every setting below."""
        return {
            "type": "header",
            "format": RESULTS_FORMAT,
            "policy": self.policy,
            "scenario": self.scenario if isinstance(self.scenario, str) else self.scenario_for(0).name,
            "policy_identity": self.policy_identity(),
            "scenario_identity": self.scenario_identity(),
            "wind_sigma_mps": self.wind_sigma_mps,
            "policy_kwargs": self.policy_kwargs,
            "max_time_s": self.max_time_s,
            "airspeed_every_s": self.airspeed_every_s,
            "config": SimConfig.preset(self.physics).as_dict(),
            "build": build.fingerprint(),
            # Only when on: the headers of unshielded studies stay as they were.
            **({"shield": True} if self.shield else {}),
            **({"shield_kwargs": self.shield_kwargs} if self.shield_kwargs else {}),
        }


#: Studies this process has warmed up for (numba compiled or loaded, policy's first call).
_warmed_up: set[str] = set()
#: SHA-256 of model files read by this process, by (resolved path, mtime, size).
_checked_policy_files: dict[tuple[str, int, int], str] = {}


def run_one(study: Study, seed: int) -> dict[str, Any]:
    """One run of the study: the metrics dict that goes on one line of the results file.

    The first run of a study in a process first flies an untimed warm-up (``warm_up``)
    and reports its duration as ``compile_s``; later runs in that process report 0.
    """
    study.check_policy_file_unchanged()
    policy = study.make_policy()
    scenario = study.scenario_for(seed)
    record_every = 1 if study.airspeed_every_s else 0
    config = SimConfig.preset(study.physics)
    compile_s = 0.0
    key = repr(study)
    if key not in _warmed_up:
        compile_s = warm_up(policy, scenario, seed=seed, wind_sigma_mps=study.wind_sigma_mps,
                            config=config, record_every=record_every)
        _warmed_up.add(key)
    result = run_episode(
        policy,
        scenario,
        seed=seed,
        wind_sigma_mps=study.wind_sigma_mps,
        max_time_s=study.max_time_s,
        record_every=record_every,
        config=config,
    )
    record = result.metrics.to_dict()
    if study.airspeed_every_s:
        record.update(_step_trace(result, scenario, study.airspeed_every_s))
        decisions = getattr(policy, "decisions", None) or []
        record["fallback_decisions"] = [k for k, d in enumerate(decisions) if getattr(d, "fallback", False)]
    info = getattr(policy, "episode_info", None)
    record["policy_info"] = info() if callable(info) else {}
    # Every decision's latency (s), for the percentiles of the summary.
    record["decision_s_each"] = [float(t) for t in result.decision_s]
    record["peak_rss_mb"] = peak_rss_mb()
    record["compile_s"] = compile_s
    return record


#: Keys of a run record that only a study with ``airspeed_every_s`` writes.
STEP_TRACE_KEYS = ("airspeed_band_kt", "airspeed_mean_kt", "distance_short_nm", "excursion_decisions",
                   "fallback_decisions")


def _step_trace(result: Any, scenario: Any, every_s: float) -> dict[str, Any]:
    """What a run's every-step record (``record_every=1``) gives the reproduction: airspeed
    bands per window, the mean airspeed, how far short each non-arrival ended, and which
    decision periods had a step outside the envelope."""
    config = SimConfig()
    # Row 0 is the state before the first step; row r > 0 is the state after step r.
    speeds = result.records[1:, :, kernel.R_AIRSPEED]
    # A step flown in sub-steps (kernel guards 8-9) can reach its extremes between its ends.
    lows = result.records[1:, :, kernel.R_AIRSPEED_MIN]
    highs = result.records[1:, :, kernel.R_AIRSPEED_MAX]
    flew = result.records[1:, :, kernel.R_FLEW] > 0
    step_start_s = np.arange(speeds.shape[0]) * config.dt_s
    window = np.floor(step_start_s / every_s + 1e-9).astype(np.int64)
    n_windows = int(window[-1]) + 1 if window.size else 0
    bands: list[list[list[float] | None]] = []
    for i in range(speeds.shape[1]):
        rows: list[list[float] | None] = [None] * n_windows
        for w in range(n_windows):
            in_window = (window == w) & flew[:, i]
            if in_window.any():
                rows[w] = [round(float(lows[in_window, i].min()), 2), round(float(speeds[in_window, i].mean()), 2),
                           round(float(highs[in_window, i].max()), 2)]
        bands.append(rows)
    flown = speeds[flew]
    outside = flew & ((lows < config.airspeed_min_kt) | (highs > config.airspeed_max_kt))
    decision_of_step = np.searchsorted(result.decision_times_s, step_start_s + 1e-9, side="right") - 1
    final = result.records[-1, :, kernel.R_X : kernel.R_Y + 1]
    short = np.hypot(*(final - scenario.dest_xy).T)
    return {
        "airspeed_band_kt": bands,
        "airspeed_mean_kt": float(flown.mean()) if flown.size else None,
        "distance_short_nm": [None if a else round(float(d), 2) for a, d in zip(result.metrics.arrived, short)],
        "excursion_decisions": sorted({int(k) for k in decision_of_step[outside.any(axis=1)]}),
    }


def _worker_init(parent_pid: int | None = None) -> None:
    # Parallelism is across runs: one numba thread per worker avoids oversubscription.
    import numba

    numba.set_num_threads(1)
    if parent_pid is not None:
        # Ctrl-C reaches the terminal's whole process group: the parent alone handles it
        # and stops the workers (``_stop_workers``); an interrupted worker would only turn
        # its run into an error the parent no longer reads.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent(parent_pid)


#: Seconds between two looks of the watchdog thread at the worker's parent.
WATCHDOG_PERIOD_S = 0.5
#: Linux's prctl option that sends the calling process a signal when its parent dies.
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> None:
    """Make this worker process end when ``parent_pid`` (the study's process) ends, however
    it ends (SIGKILL included): a worker holds ~200 MB and the parent's stdout, so an
    orphan would keep memory and keep a ``| cat`` pipeline open for ever.

    On Linux the kernel sends SIGKILL at the parent's death (``PR_SET_PDEATHSIG``, set
    through ``ctypes``); everywhere, a daemon thread looks at ``os.getppid()`` every
    ``WATCHDOG_PERIOD_S`` and ends the process when it is no longer ``parent_pid`` (for
    platforms without prctl, and for a parent that died before prctl was set). The worker
    writes nothing of its own: the parent writes every finished run, so ending it loses
    only the run it was flying."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - a libc without prctl
            pass
    if os.getppid() != parent_pid:
        os._exit(1)  # the parent died before prctl was set

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_PERIOD_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="atc-nf-parent-watchdog", daemon=True).start()


#: Said when a worker process dies before running anything: the usual cause is a script
#: that calls ``evaluate`` at its top level (spawned workers import the main module).
MAIN_GUARD_HINT = (
    "a worker process died before running any episode. If you call evaluate() from a script, put the call "
    'under `if __name__ == "__main__":` (worker processes are spawned and import your main module; without '
    "the guard each of them starts the study again)"
)


def _check_not_bootstrapping() -> None:
    import multiprocessing

    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise RuntimeError("evaluate() called while a worker process was starting: " + MAIN_GUARD_HINT)


def _run_local(study: Study, seeds: Iterator[int], workers: int) -> Iterator[dict[str, Any]]:
    if workers == 1:
        for seed in seeds:
            yield run_one(study, seed)
        return
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    # spawn: numba's threads do not survive a fork safely. A ProcessPoolExecutor (unlike
    # multiprocessing.Pool) never restarts a worker that died: the study fails at once.
    context = mp.get_context("spawn")
    finished = 0
    seeds = iter(seeds)
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_init, initargs=(os.getpid(),))
    pending: set = set()
    try:
        # Runs are planned lazily, two per worker ahead: memory does not grow with ``runs``.
        pending = {pool.submit(run_one, study, seed) for seed in itertools.islice(seeds, 2 * workers)}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    record = future.result()
                except BrokenProcessPool:  # the except below stops the rest
                    if finished == 0:
                        raise RuntimeError(MAIN_GUARD_HINT) from None
                    raise RuntimeError(
                        "a worker process died (killed, or out of memory); the runs finished so far are kept "
                        "in the results file: finish the study with resume"
                    ) from None
                finished += 1
                yield record
            pending |= {pool.submit(run_one, study, seed) for seed in itertools.islice(seeds, len(done))}
    except BaseException:  # Ctrl-C, --max-minutes closing this generator, a failed run
        _stop_workers(pool, pending)
        raise
    pool.shutdown(wait=True)


def _stop_workers(pool: Any, pending: set) -> None:
    """End a local pool at once: its queued runs cancelled, its workers killed (the runs
    they were flying are lost; every finished run is already in the results file).
    ``ProcessPoolExecutor.shutdown`` alone first flies the runs already queued (two per
    worker), minutes in a dense MPC study."""
    for future in pending:
        future.cancel()
    # Python 3.14 has ``kill_workers``; before it the processes are only in ``_processes``.
    kill = getattr(pool, "kill_workers", None)
    if kill is not None:
        kill()
    else:
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            if process.is_alive():
                process.kill()
    pool.shutdown(wait=False, cancel_futures=True)


def _run_ray(study: Study, seeds: Iterator[int], workers: int) -> Iterator[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise ValueError("backend 'ray' needs Ray: pip install 'atc-nf-env[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)

    @ray.remote(num_cpus=1)
    def remote_run(seed: int) -> dict[str, Any]:
        _worker_init()  # Ray's workers belong to Ray, which ends them
        return run_one(study, seed)

    try:
        pending = [remote_run.remote(seed) for seed in itertools.islice(seeds, 2 * workers)]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            pending.extend(remote_run.remote(seed) for seed in itertools.islice(seeds, 1))
            yield ray.get(done[0])
    finally:
        if started_here:
            ray.shutdown()


_RUN_FIELDS = tuple(RunMetrics.__dataclass_fields__)


def _problem_of_run(record: Any) -> str | None:
    """What makes ``record`` not a run record, or None."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    missing = [name for name in _RUN_FIELDS if name not in record]
    if missing:
        return f"a run record without {', '.join(missing[:3])}{' …' if len(missing) > 3 else ''}"
    seed = record["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        return f"a run record with seed {seed!r}"
    return None


def _scan_results(path: Path, data: bytes | None = None) -> tuple[dict[str, Any] | None, list[dict[str, Any]], int]:
    """(header, runs, intact_bytes) of a results file (of its bytes ``data`` when given);
    ``intact_bytes`` ends the last intact line, so that a last line damaged by an
    interruption (cut off, with or without its newline) can be dropped. A damaged line
    anywhere else, a file that does not start with the header, or a seed written twice
    raises ValueError."""
    if data is None:
        _check_regular_file(path)
        data = path.read_bytes()
    lines = data.split(b"\n")
    # The index of the last line holding anything: only that one may be damaged.
    last = max((k for k, line in enumerate(lines) if line.strip()), default=-1)
    header: dict[str, Any] | None = None
    runs: list[dict[str, Any]] = []
    seen: set[int] = set()
    offset = intact = 0
    for number, raw in enumerate(lines):
        end = offset + len(raw) + 1
        if raw.strip():
            problem = None
            try:
                record = json.loads(raw)
            except (json.JSONDecodeError, UnicodeDecodeError):
                problem, record = "not JSON", None
            if problem is None:
                if header is None:
                    if not (isinstance(record, dict) and record.get("type") == "header"):
                        problem = "not the header of an atc-nf evaluate results file"
                else:
                    problem = _problem_of_run(record)
            if problem is not None:
                if number == last:
                    break  # the line being written when the study was interrupted
                raise ValueError(
                    f"{path}: line {number + 1} is {problem}; the file is damaged or not a results file "
                    "of atc-nf evaluate (only its last line may be cut off by an interruption)"
                )
            if header is None:
                header = record
            else:
                if record["seed"] in seen:
                    raise ValueError(f"{path}: line {number + 1} repeats seed {record['seed']}; the file is damaged")
                seen.add(record["seed"])
                runs.append(record)
            intact = min(end, len(data))
        offset = end
    return header, runs, intact


def read_results(path: str | os.PathLike[str]) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """(header, runs) of a results file (a path as ``str`` or ``os.PathLike``); a last line
    damaged by an interruption is ignored; (None, []) when the file does not exist.

    Raises:
        TypeError: ``path`` is not a str or an ``os.PathLike`` of one.
        ValueError: on a damaged line before the last one, a file that does not start
            with a results header, or a seed written twice.
    """
    if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes):
        raise TypeError(f"path = {path!r}: give the results file's path as a str or an os.PathLike (pathlib.Path)")
    path = Path(path)
    if not path.exists():
        return None, []
    header, runs, _ = _scan_results(path)
    return header, runs


def _check_regular_file(path: Path, option: str = "results file") -> None:
    """ValueError unless ``path`` is a regular file or does not exist: a device such as
    /dev/zero would be read for ever, a FIFO would block, /dev/full fails every write."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISDIR(mode):
        raise ValueError(f"{option} {path} is a directory; give the path of a .jsonl file")
    if not stat.S_ISREG(mode):
        raise ValueError(
            f"{option} {path} is not a regular file (a device, FIFO or socket); give the path of a .jsonl file "
            "that is a regular file or does not exist yet"
        )


class ResultsFile:
    """A results file held by one study: opened (created when missing), checked to be a
    regular file, and locked (``fcntl.flock``, exclusive) until ``close``, so that no other
    process writes it meanwhile; every append is made durable before the next (``fsync``).

    Raises:
        ValueError: ``path`` is not a regular file, or another process holds its lock
            (a study writing it now).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        _check_regular_file(path)
        flags = (os.O_RDWR | os.O_CREAT | os.O_APPEND | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
                 | getattr(os, "O_BINARY", 0))
        try:
            # O_NONBLOCK: a FIFO put in its place since the check above is not waited on.
            self.fd = os.open(path, flags, 0o644)
        except OSError as error:
            raise ValueError(f"results file {path}: cannot open it: {error.strerror}") from None
        try:
            if not stat.S_ISREG(os.fstat(self.fd).st_mode):
                raise ValueError(f"results file {path} is not a regular file; give the path of a .jsonl file")
            if hasattr(os, "set_blocking"):
                os.set_blocking(self.fd, True)
            self._lock()
        except BaseException:
            os.close(self.fd)
            raise

    def _lock(self) -> None:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no lock
            return
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ValueError(
                f"results file {self.path} is being written by another study (another process holds its lock): "
                "one study writes a file at a time; wait for it to end, or choose another file"
            ) from None

    def read(self) -> bytes:
        """The file's bytes."""
        size = os.fstat(self.fd).st_size
        os.lseek(self.fd, 0, os.SEEK_SET)  # appends go to the end whatever the offset (O_APPEND)
        chunks, offset = [], 0
        while offset < size:
            chunk = os.read(self.fd, min(size - offset, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            offset += len(chunk)
        return b"".join(chunks)

    def size(self) -> int:
        return os.fstat(self.fd).st_size

    def append(self, data: bytes) -> None:
        """Append ``data`` and make it durable (a kill loses at most the line being written,
        which resume drops). An OSError (a full disk: ENOSPC) names the file."""
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self.fd, view):]
            os.fsync(self.fd)
        except OSError as error:
            raise OSError(error.errno, f"cannot write the results file: {error.strerror}", str(self.path)) from None

    def append_line(self, record: dict[str, Any]) -> None:
        """Append one JSON line (numpy scalars written as Python numbers)."""
        self.append((json.dumps(record, allow_nan=False, default=_plain) + "\n").encode())

    def truncate(self, size: int) -> None:
        try:
            os.ftruncate(self.fd, size)
            os.fsync(self.fd)
        except OSError as error:
            raise OSError(error.errno, f"cannot write the results file: {error.strerror}", str(self.path)) from None

    def close(self) -> None:
        """Release the lock and close the file."""
        if self.fd >= 0:
            os.close(self.fd)  # closing the last descriptor releases the flock
            self.fd = -1


def _metrics_from(record: dict[str, Any]) -> RunMetrics:
    names = RunMetrics.__dataclass_fields__
    # ``stream`` came later: a record written before it (or of an encounter) may lack it.
    return RunMetrics(**{key: record[key] for key in names if key in record or key != "stream"})


def evaluate(
    study: Study,
    runs: int,
    *,
    first_seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    out: Path | None = None,
    resume: bool = False,
    progress: bool = True,
    on_run: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Run (or finish) a study of ``runs`` seeded episodes and return its summary.

    Args:
        study: policy, scenario and wind of the study.
        runs: number of episodes, seeds ``first_seed`` … ``first_seed + runs − 1``.
        workers: processes (local) or CPUs (Ray); all cores by default. The local backend
            starts at most as many processes as there are runs left and as this process
            may use CPUs (``os.sched_getaffinity``): the runs are CPU-bound, so more
            processes only share the CPUs and cost ~200 MB each; a larger ``workers`` is
            lowered with a warning.
        backend: "local" or "ray".
        out: JSON-lines file that receives every finished run; required for ``resume``.
            A regular file or a path that does not exist yet; it is locked for the whole
            study (a second study on it is refused).
        resume: keep the runs already in ``out`` and run only the missing seeds; refused
            unless ``out``'s header identifies the same study by content (same scenario
            as flown, same model bytes, same code and libraries, same settings).
        progress: show a progress bar on stderr.
        on_run: called with each finished run's record (after it is written).

    Returns:
        The summary of DESIGN.md's contract over all the study's runs (``summarize``),
        plus ``decisions``, ``wall_s_per_decision`` and, for policies that report it,
        ``fallbacks`` (MPC decisions with no feasible candidate). Times are warm: every
        worker process warms up before its first timed run, and the longest warm-up is
        ``compile_s``.
    """
    for name, value, least in (("runs", runs, 1), ("first_seed", first_seed, 0)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{name} = {value!r}: must be an integer >= {least}")
        if value < least:
            raise ValueError(f"{name} = {value!r}: must be an integer >= {least}")
    runs, first_seed = int(runs), int(first_seed)
    if first_seed + runs > MAX_SEED + 1:
        raise ValueError(
            f"runs = {runs}, first_seed = {first_seed}: seeds run to {first_seed + runs - 1}; every seed must be "
            f"<= {MAX_SEED} (2**63 - 1, the environments' int64 seeds)"
        )
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r}: allowed: {', '.join(BACKENDS)}")
    asked = workers
    workers = usable_cpus() if workers is None else workers
    if isinstance(workers, (bool, np.bool_)) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers = {workers!r}: must be an integer >= 1")
    workers = int(workers)
    if backend == "local" and workers > usable_cpus():
        warnings.warn(
            f"workers = {asked}: this process may use {usable_cpus()} CPUs; starting at most {usable_cpus()} worker "
            "processes (the runs are CPU-bound: more would share the CPUs and cost ~200 MB each)",
            stacklevel=2,
        )
        workers = usable_cpus()
    if resume and out is None:
        raise ValueError("resume needs the results file (out) of the interrupted study")
    _check_not_bootstrapping()

    header = study.header()
    results: ResultsFile | None = None
    done: dict[int, dict[str, Any]] = {}
    if out is not None:
        out = Path(out)
        _check_regular_file(out)  # before a folder is made or anything read
        out.parent.mkdir(parents=True, exist_ok=True)
        results = ResultsFile(out)  # locked from here to the end of the study
    try:
        if results is not None:
            done = _take_over(results, header, resume, first_seed, runs)
        # Planned lazily: a huge ``runs`` costs nothing until its runs finish.
        seeds = (s for s in range(first_seed, first_seed + runs) if s not in done)
        records = list(done.values())
        todo = runs - len(done)

        runner = _run_ray if backend == "ray" else _run_local
        stream: Iterable[dict[str, Any]] = runner(study, seeds, min(workers, todo)) if todo else []
        bar = _progress_bar(total=runs, initial=len(records), enabled=progress)
        try:
            for record in stream:
                if results is not None:
                    results.append_line(record)
                records.append(record)
                if on_run is not None:
                    on_run(record)
                bar.update(1)
        finally:
            bar.close()
    finally:
        if results is not None:
            results.close()
    return summarize_records(records)


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the OS tells it, else the count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _take_over(results: ResultsFile, header: dict[str, Any], resume: bool, first_seed: int,
               runs: int) -> dict[int, dict[str, Any]]:
    """Check a locked results file against the study and prepare it for appending: its
    runs of this study's seeds, by seed (none for a new file, whose header it writes)."""
    out = results.path
    data = results.read()
    if data and not resume:
        raise ValueError(
            f"{out} already holds a study; finish it with --resume (resume=True in Python), or choose another file"
        )
    old_header, old_runs, intact = _scan_results(out, data)
    if old_header is not None and old_header.get("format") != header["format"]:
        raise ValueError(
            f"{out} was written by an older atc-nf evaluate (results format {old_header.get('format', 1)!r}; this one "
            f"writes {header['format']}), whose header does not identify the scenario and model by content: it "
            "cannot be resumed safely; fly the study again into a new file"
        )
    if old_header is not None and old_header.get("build") != header["build"]:
        raise ValueError(
            f"{out} holds runs of another build ({old_header.get('build')!r}; this one is "
            f"{header['build']!r}): the code or libraries that fly a run changed since, so its "
            "runs cannot be resumed; fly the study again into a new file"
        )
    if old_header is not None:
        _check_same_study(out, old_header, header, [int(r["seed"]) for r in old_runs], first_seed, runs)
    if intact < len(data):
        results.truncate(intact)  # a last line damaged by the interruption
    if intact and not data[:intact].endswith(b"\n"):
        results.append(b"\n")  # an intact last line whose newline the interruption cut
    if old_header is None:
        results.append_line(header)
    # Runs beyond this study's seeds (a longer study in the same file) stay in the
    # file but not in this summary, which covers first_seed … first_seed + runs − 1.
    return {int(r["seed"]): r for r in old_runs if r["seed"] < first_seed + runs}


def differing_header_keys(old: dict[str, Any], new: dict[str, Any],
                          ignore: Iterable[str] = LABEL_KEYS) -> list[str]:
    """The keys on which two results headers differ, looked up in both directions: a key
    that one header has and the other lacks differs whatever its value (a missing
    ``shield`` is an unshielded study, not "any"); ``ignore`` (default ``LABEL_KEYS``, the
    labels) is not compared. New keys first, then those only ``old`` has."""
    skipped = set(ignore)
    keys = [*new, *(key for key in old if key not in new)]
    return [key for key in keys
            if key not in skipped and (key not in old or key not in new or old[key] != new[key])]


def _header_value(header: dict[str, Any], key: str) -> str:
    return repr(header[key]) if key in header else "missing"


def _check_same_study(
    out: Path, old: dict[str, Any], new: dict[str, Any], seeds: list[int], first_seed: int, runs: int
) -> None:
    """Refuse to resume a file of another study, or of the same study from another first
    seed: one file holds one range of seeds from one first seed, never two ranges."""
    differing = differing_header_keys(old, new)
    if differing:
        described = ", ".join(f"{key} {_header_value(old, key)} there, {_header_value(new, key)} here"
                              for key in differing[:3])
        raise ValueError(f"{out} holds a different study ({described}); cannot resume it")
    if seeds and not first_seed <= min(seeds) < first_seed + runs:
        raise ValueError(
            f"{out} holds the study from seed {min(seeds)}, not {first_seed}: resuming would mix two ranges of "
            "seeds in one file; resume with the --seed the study was started with, or choose another file"
        )


def summarize_records(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The study summary from the results file's run records, in seed order: the
    summary does not depend on the order in which workers finished."""
    records = sorted(records, key=lambda r: r["seed"])
    warm_ups = [r["compile_s"] for r in records if r.get("compile_s") is not None]
    summary = summarize(
        [_metrics_from(r) for r in records],
        peak_rss_mb=max((r.get("peak_rss_mb") or 0.0 for r in records), default=None),
        compile_s=max(warm_ups) if warm_ups else None,
    )
    decisions = sum(r["decisions"] for r in records)
    infos = [r.get("policy_info") or {} for r in records]
    if any("fallbacks" in info for info in infos):  # only policies that can fall back report it
        summary["fallbacks"] = int(sum(info.get("fallbacks", 0) for info in infos))
    shield = summarize_interventions(infos, records)
    if shield is not None:
        summary["shield"] = shield
    summary["decisions"] = int(decisions)
    latencies = [t for r in records for t in r.get("decision_s_each") or ()]
    if latencies:  # runs written before the per-decision latencies were kept have none
        summary["decision_s"]["median"] = float(np.median(latencies))
        summary["decision_s"]["p99"] = float(np.percentile(latencies, 99))
        summary["decision_s"]["max"] = float(max(latencies))
    summary["wall_s_per_decision"] = (
        sum(r["decision_s_mean"] * r["decisions"] for r in records) / decisions if decisions else 0.0
    )
    return summary


class _NoBar:
    def update(self, n: int) -> None:
        """Nothing to show."""

    def close(self) -> None:
        """Nothing to close."""


def _progress_bar(total: int, initial: int, enabled: bool):
    if not enabled:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, initial=initial, unit="run", file=sys.stderr, dynamic_ncols=True)
