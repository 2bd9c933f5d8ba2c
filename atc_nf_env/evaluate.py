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

import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from atc_nf_env import build, kernel
from atc_nf_env.config import SimConfig
from atc_nf_env.episode import MAX_EPISODE_S, run_episode, warm_up
from atc_nf_env.metrics import RunMetrics, peak_rss_mb, summarize
from atc_nf_env.policy import make_policy  # noqa: F401  (re-exported: the evaluator resolves policies by name)
from atc_nf_env.scenarios import make_scenario
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

    def __post_init__(self) -> None:
        if not (math.isfinite(self.wind_sigma_mps) and self.wind_sigma_mps >= 0):
            raise ValueError(f"wind_sigma = {self.wind_sigma_mps!r} m/s: must be a finite number >= 0")
        # Fail before any worker starts on a bad name or setting.
        make_policy(self.policy, **self.policy_kwargs)
        make_scenario(self.scenario, seed=0)

    def header(self) -> dict[str, Any]:
        return {
            "type": "header",
            "policy": self.policy,
            "scenario": self.scenario,
            "wind_sigma_mps": self.wind_sigma_mps,
            "policy_kwargs": self.policy_kwargs,
            "max_time_s": self.max_time_s,
            "airspeed_every_s": self.airspeed_every_s,
            "config": SimConfig().as_dict(),
            "build": build.fingerprint(),
        }


#: Studies this process has warmed up for (numba compiled or loaded, policy's first call).
_warmed_up: set[str] = set()


def run_one(study: Study, seed: int) -> dict[str, Any]:
    """One run of the study: the metrics dict that goes on one line of the results file.

    The first run of a study in a process first flies an untimed warm-up (``warm_up``)
    and reports its duration as ``compile_s``; later runs in that process report 0.
    """
    policy = make_policy(study.policy, **study.policy_kwargs)
    scenario = make_scenario(study.scenario, seed=seed)
    record_every = 1 if study.airspeed_every_s else 0
    compile_s = 0.0
    key = json.dumps(study.header(), sort_keys=True, default=str)
    if key not in _warmed_up:
        compile_s = warm_up(policy, scenario, seed=seed, wind_sigma_mps=study.wind_sigma_mps,
                            record_every=record_every)
        _warmed_up.add(key)
    result = run_episode(
        policy,
        scenario,
        seed=seed,
        wind_sigma_mps=study.wind_sigma_mps,
        max_time_s=study.max_time_s,
        record_every=record_every,
    )
    record = result.metrics.to_dict()
    if study.airspeed_every_s:
        record.update(_step_trace(result, scenario, study.airspeed_every_s))
        decisions = getattr(policy, "decisions", None) or []
        record["fallback_decisions"] = [k for k, d in enumerate(decisions) if getattr(d, "fallback", False)]
    info = getattr(policy, "episode_info", None)
    record["policy_info"] = info() if callable(info) else {}
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
    flew = result.records[1:, :, kernel.R_FLEW] > 0
    step_start_s = np.arange(speeds.shape[0]) * config.dt_s
    window = np.floor(step_start_s / every_s + 1e-9).astype(np.int64)
    n_windows = int(window[-1]) + 1 if window.size else 0
    bands: list[list[list[float] | None]] = []
    for i in range(speeds.shape[1]):
        rows: list[list[float] | None] = [None] * n_windows
        for w in range(n_windows):
            values = speeds[(window == w) & flew[:, i], i]
            if values.size:
                rows[w] = [round(float(values.min()), 2), round(float(values.mean()), 2),
                           round(float(values.max()), 2)]
        bands.append(rows)
    flown = speeds[flew]
    outside = flew & ((speeds < config.airspeed_min_kt) | (speeds > config.airspeed_max_kt))
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


def _run_local(study: Study, seeds: list[int], workers: int) -> Iterator[dict[str, Any]]:
    if workers == 1:
        for seed in seeds:
            yield run_one(study, seed)
        return
    import multiprocessing as mp
    from functools import partial

    context = mp.get_context("spawn")  # numba's threads do not survive a fork safely
    with context.Pool(workers, initializer=_worker_init) as pool:
        yield from pool.imap_unordered(partial(run_one, study), seeds)


def _run_ray(study: Study, seeds: list[int], workers: int) -> Iterator[dict[str, Any]]:
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
        pending = [remote_run.remote(seed) for seed in seeds]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
    finally:
        if started_here:
            ray.shutdown()


def read_results(path: Path) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """(header, runs) of a results file; a last line cut off by an interruption is ignored."""
    if not path.exists():
        return None, []
    header, runs = None, []
    lines = path.read_text().splitlines()
    for number, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines) - 1:
                break  # the run being written when the study was interrupted
            raise ValueError(f"{path}: line {number + 1} is not JSON; the file is damaged") from None
        if record.get("type") == "header":
            header = record
        else:
            runs.append(record)
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
    if not isinstance(runs, int) or runs < 1:
        raise ValueError(f"runs = {runs!r}: must be an integer >= 1")
    if not isinstance(first_seed, int) or first_seed < 0:
        raise ValueError(f"first_seed = {first_seed!r}: must be an integer >= 0")
    if backend not in BACKENDS:
        raise ValueError(f"backend = {backend!r}: allowed: {', '.join(BACKENDS)}")
    workers = workers or os.cpu_count() or 1
    if workers < 1:
        raise ValueError(f"workers = {workers!r}: must be >= 1")
    if resume and out is None:
        raise ValueError("resume needs the results file (out) of the interrupted study")

    header = study.header()
    done: dict[int, dict[str, Any]] = {}
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        old_header, old_runs = read_results(out)
        if old_runs or old_header:
            if not resume:
                raise ValueError(
                    f"{out} already holds a study; finish it with --resume (resume=True in Python), "
                    "or choose another file"
                )
            if old_header is not None and old_header.get("build") != header["build"]:
                raise ValueError(
                    f"{out} holds runs of another build ({old_header.get('build')!r}; this one is "
                    f"{header['build']!r}): the sources or libraries that fly a run changed since, so its "
                    "runs cannot be resumed; fly the study again into a new file"
                )
            if old_header is not None and {k: old_header.get(k) for k in header} != header:
                raise ValueError(
                    f"{out} holds a different study ({old_header.get('policy')!r} on "
                    f"{old_header.get('scenario')!r}, wind {old_header.get('wind_sigma_mps')}); cannot resume it"
                )
            done = {int(r["seed"]): r for r in old_runs}
            _truncate_partial_line(out)
        if old_header is None:
            with out.open("a") as handle:
                handle.write(json.dumps(header) + "\n")
    seeds = [s for s in range(first_seed, first_seed + runs) if s not in done]
    records = [done[s] for s in range(first_seed, first_seed + runs) if s in done]

    runner = _run_ray if backend == "ray" else _run_local
    stream: Iterable[dict[str, Any]] = runner(study, seeds, min(workers, max(len(seeds), 1))) if seeds else []
    bar = _progress_bar(total=runs, initial=len(records), enabled=progress)
    try:
        for record in stream:
            if out is not None:
                with out.open("a") as handle:
                    handle.write(json.dumps(record) + "\n")
                    handle.flush()
                    os.fsync(handle.fileno())
            records.append(record)
            if on_run is not None:
                on_run(record)
            bar.update(1)
    finally:
        bar.close()
    return summarize_records(records)


def summarize_records(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The study summary from the results file's run records."""
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
    summary["decisions"] = int(decisions)
    summary["wall_s_per_decision"] = (
        sum(r["decision_s_mean"] * r["decisions"] for r in records) / decisions if decisions else 0.0
    )
    return summary


def _truncate_partial_line(path: Path) -> None:
    """Drop a last line cut off by an interruption, so that appends start on a fresh line."""
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        path.write_bytes(data[: data.rfind(b"\n") + 1])


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
