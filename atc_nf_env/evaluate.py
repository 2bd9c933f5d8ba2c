"""Monte Carlo evaluation of a policy: many seeded episodes, in parallel, resumable.

Every run is one episode with seed s (s = first_seed … first_seed + runs − 1): the seed
fixes the hidden wind and the policy's randomness, so two policies evaluated on the
same seeds face the same winds. Runs go to local worker processes (all cores by
default) or to a Ray cluster (``backend="ray"``, the ``ray`` extra). Each finished run
is appended to a JSON-lines file as soon as it ends, so an interrupted study resumed
with ``resume=True`` loses nothing and repeats nothing.

File format: the first line is a header naming the study (policy, scenario, wind,
settings); every other line is one run's metrics (``RunMetrics.to_dict()``) with the
policy's diagnostics under ``policy_info`` and the worker's peak memory under
``peak_rss_mb`` and, for the process's first run of the study, the untimed warm-up
before it under ``compile_s`` (0 for later runs).
"""

from __future__ import annotations

import itertools
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from atc_nf_env import build, kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import MAX_EPISODE_S, run_episode, warm_up, whole_steps
from atc_nf_env.metrics import RunMetrics, peak_rss_mb, summarize
from atc_nf_env.policy import Policy, make_policy  # (re-exported: the evaluator resolves policies by name)
from atc_nf_env.scenarios import MAX_SEED, make_scenario
from atc_nf_env.shield import SafetyFilter, summarize_interventions
from atc_nf_env.simulation import check_wind_sigma
from atc_nf_env.units import WIND_SIGMA_MPS

BACKENDS = ("local", "ray")


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

    def __post_init__(self) -> None:
        SimConfig.preset(self.physics)  # a clear error on an unknown name
        check_wind_sigma(self.wind_sigma_mps)
        if not isinstance(self.shield, bool):
            raise TypeError(f"shield = {self.shield!r}: must be True or False")
        if not isinstance(self.policy_kwargs, dict):
            raise TypeError(f"policy_kwargs = {self.policy_kwargs!r}: must be a dict of the policy's settings")
        # A time limit off the integration grid is refused here, before any worker starts.
        whole_steps("max_time_s", self.max_time_s, SimConfig.preset(self.physics).dt_s)
        if self.airspeed_every_s is not None:
            whole_steps("airspeed_every_s", self.airspeed_every_s, SimConfig.preset(self.physics).dt_s)
        # Fail before any worker starts on a bad name or setting.
        self.make_policy()
        make_scenario(self.scenario, seed=0)

    def make_policy(self) -> Policy:
        """The study's policy (inside the safety filter when ``shield``)."""
        policy = make_policy(self.policy, **self.policy_kwargs)
        return SafetyFilter(policy) if self.shield else policy

    def header(self) -> dict[str, Any]:
        return {
            "type": "header",
            "policy": self.policy,
            "scenario": self.scenario,
            "wind_sigma_mps": self.wind_sigma_mps,
            "policy_kwargs": self.policy_kwargs,
            "max_time_s": self.max_time_s,
            "airspeed_every_s": self.airspeed_every_s,
            "config": SimConfig.preset(self.physics).as_dict(),
            "build": build.fingerprint(),
            # Only when on: the headers of unshielded studies stay as they were.
            **({"shield": True} if self.shield else {}),
        }


#: Studies this process has warmed up for (numba compiled or loaded, policy's first call).
_warmed_up: set[str] = set()


def run_one(study: Study, seed: int) -> dict[str, Any]:
    """One run of the study: the metrics dict that goes on one line of the results file.

    The first run of a study in a process first flies an untimed warm-up (``warm_up``)
    and reports its duration as ``compile_s``; later runs in that process report 0.
    """
    policy = study.make_policy()
    scenario = make_scenario(study.scenario, seed=seed)
    record_every = 1 if study.airspeed_every_s else 0
    config = SimConfig.preset(study.physics)
    compile_s = 0.0
    key = json.dumps(study.header(), sort_keys=True, default=str)
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


def _worker_init() -> None:
    # Parallelism is across runs: one numba thread per worker avoids oversubscription.
    import numba

    numba.set_num_threads(1)


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
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_init) as pool:
        # Runs are planned lazily, two per worker ahead: memory does not grow with ``runs``.
        pending = {pool.submit(run_one, study, seed) for seed in itertools.islice(seeds, 2 * workers)}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    record = future.result()
                except BrokenProcessPool:
                    for other in pending:
                        other.cancel()
                    if finished == 0:
                        raise RuntimeError(MAIN_GUARD_HINT) from None
                    raise RuntimeError(
                        "a worker process died (killed, or out of memory); the runs finished so far are kept "
                        "in the results file: finish the study with resume"
                    ) from None
                finished += 1
                yield record
            pending |= {pool.submit(run_one, study, seed) for seed in itertools.islice(seeds, len(done))}


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
        _worker_init()
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


def _scan_results(path: Path) -> tuple[dict[str, Any] | None, list[dict[str, Any]], int]:
    """(header, runs, intact_bytes) of a results file; ``intact_bytes`` ends the last intact
    line, so that a last line damaged by an interruption (cut off, with or without its
    newline) can be dropped. A damaged line anywhere else, a file that does not start
    with the header, or a seed written twice raises ValueError."""
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


def read_results(path: Path) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """(header, runs) of a results file; a last line damaged by an interruption is ignored.

    Raises:
        ValueError: on a damaged line before the last one, a file that does not start
            with a results header, or a seed written twice.
    """
    if not path.exists():
        return None, []
    header, runs, _ = _scan_results(path)
    return header, runs


def _metrics_from(record: dict[str, Any]) -> RunMetrics:
    names = RunMetrics.__dataclass_fields__
    return RunMetrics(**{key: record[key] for key in names})


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
        workers: processes (local) or CPUs (Ray); all cores by default.
        backend: "local" or "ray".
        out: JSON-lines file that receives every finished run; required for ``resume``.
        resume: keep the runs already in ``out`` and run only the missing seeds.
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
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{name} = {value!r}: must be an integer >= {least}")
        if value < least:
            raise ValueError(f"{name} = {value!r}: must be an integer >= {least}")
    if first_seed + runs > MAX_SEED + 1:
        raise ValueError(
            f"runs = {runs}, first_seed = {first_seed}: seeds run to {first_seed + runs - 1}; every seed must be "
            f"<= {MAX_SEED} (2**63 - 1, the environments' int64 seeds)"
        )
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r}: allowed: {', '.join(BACKENDS)}")
    workers = (os.cpu_count() or 1) if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers = {workers!r}: must be an integer >= 1")
    if resume and out is None:
        raise ValueError("resume needs the results file (out) of the interrupted study")
    _check_not_bootstrapping()

    header = study.header()
    done: dict[int, dict[str, Any]] = {}
    if out is not None:
        out = Path(out)
        if out.is_dir():
            raise ValueError(f"out = {str(out)!r} is a directory; give the path of a .jsonl file")
        out.parent.mkdir(parents=True, exist_ok=True)
        old_header, old_runs, intact = _scan_results(out) if out.exists() else (None, [], 0)
        if out.exists() and out.stat().st_size and not resume:
            raise ValueError(
                f"{out} already holds a study; finish it with --resume (resume=True in Python), or choose another file"
            )
        if old_header is not None and old_header.get("build") != header["build"]:
            raise ValueError(
                f"{out} holds runs of another build ({old_header.get('build')!r}; this one is "
                f"{header['build']!r}): the sources or libraries that fly a run changed since, so its "
                "runs cannot be resumed; fly the study again into a new file"
            )
        if old_header is not None:
            _check_same_study(out, old_header, header, [int(r["seed"]) for r in old_runs], first_seed, runs)
        # Runs beyond this study's seeds (a longer study in the same file) stay in the
        # file but not in this summary, which covers first_seed … first_seed + runs − 1.
        done = {int(r["seed"]): r for r in old_runs if r["seed"] < first_seed + runs}
        if out.exists() and intact < out.stat().st_size:
            _truncate(out, intact)  # a last line damaged by the interruption
        if intact and not out.read_bytes().endswith(b"\n"):
            _append_bytes(out, b"\n")  # an intact last line whose newline the interruption cut
        if old_header is None:
            _append_line(out, header)
    # Planned lazily: a huge ``runs`` costs nothing until its runs finish.
    seeds = (s for s in range(first_seed, first_seed + runs) if s not in done)
    records = list(done.values())
    todo = runs - len(done)

    runner = _run_ray if backend == "ray" else _run_local
    stream: Iterable[dict[str, Any]] = runner(study, seeds, min(workers, todo)) if todo else []
    bar = _progress_bar(total=runs, initial=len(records), enabled=progress)
    try:
        for record in stream:
            if out is not None:
                _append_line(out, record)
            records.append(record)
            if on_run is not None:
                on_run(record)
            bar.update(1)
    finally:
        bar.close()
    return summarize_records(records)


def _check_same_study(
    out: Path, old: dict[str, Any], new: dict[str, Any], seeds: list[int], first_seed: int, runs: int
) -> None:
    """Refuse to resume a file of another study, or of the same study from another first
    seed: one file holds one range of seeds from one first seed, never two ranges."""
    differing = [key for key in new if old.get(key) != new[key]]
    if differing:
        described = ", ".join(f"{key} {old.get(key)!r} there, {new[key]!r} here" for key in differing[:3])
        raise ValueError(f"{out} holds a different study ({described}); cannot resume it")
    if seeds and not first_seed <= min(seeds) < first_seed + runs:
        raise ValueError(
            f"{out} holds the study from seed {min(seeds)}, not {first_seed}: resuming would mix two ranges of "
            "seeds in one file; resume with the --seed the study was started with, or choose another file"
        )


def _append_line(path: Path, record: dict[str, Any]) -> None:
    """Append one JSON line and make it durable before going on (a kill loses at most the
    line being written, which resume drops)."""
    _append_bytes(path, (json.dumps(record, allow_nan=False) + "\n").encode())


def _append_bytes(path: Path, data: bytes) -> None:
    with path.open("ab") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def _truncate(path: Path, size: int) -> None:
    with path.open("r+b") as handle:
        handle.truncate(size)
        handle.flush()
        os.fsync(handle.fileno())


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
    shield = summarize_interventions(infos)
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
