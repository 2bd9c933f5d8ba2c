"""The benchmark: a versioned suite of named tasks with seed splits, and score cards.

A *task* is a scenario family flown under the paper's hidden wind (σ = 5.17 m/s) with a
time limit: an *encounter* (converging-N, random-N: every aircraft starts at once and the
episode ends when they are home) or a *traffic stream* (stream-R: R aircraft an hour enter
on the sector's edge for 2 h and leave at their destinations; ``docs/streams.md``). Every
task has three disjoint seed *splits*. The encounter tasks share these:

========== ====================================== ==========================================
split      seeds                                  use
========== ====================================== ==========================================
train      0 … 999 999 999                        training, tuning, any development run
validation 1 000 000 000 … 1 000 009 999          model selection, early stopping
test       2 000 000 000 … 2 000 009 999          the figures you publish; never tune on them
========== ====================================== ==========================================

Every seed fixes the encounter's layout (random families), the hidden wind and the
policy's randomness, so two policies scored on one split face the same encounters.
Seeds 0 … 999 999 999 hold every seed the project's own development used (the safety
filter's tuning on 0 … 999, the agents' training at 10 000 and up, held-out checks at
770 000 and 880 000); the validation and test ranges were touched by none of it.

The stream tasks have splits of their own (``STREAM_SPLITS``), beyond every range above:
train 3 000 000 000 … 3 999 999 999, validation 4 000 000 000 … 4 000 009 999, test
5 000 000 000 … 5 000 009 999. A stream's seed draws its traffic (arrival times, entry
points, destinations) as well as the wind; the streams' development flew seeds below
1 000 000 000, so no seed of any stream split was flown before the tasks were defined.

A *score card* (``score_card``) is one policy on one task and split: runs, runs home
(every aircraft arrived; on a stream: no flight left the workspace, flights still
airborne at the end being neither), runs safe (no loss of separation and no integration
step outside [366, 540] kt — per run, not a share of steps), flight time and its ratio to
a reference on the same seeds, decision time, and one ``score`` that orders policies
safety first (see ``lexicographic_score``). On an encounter the reference is the MPC
flying the same seeds (``flight_time_ratio_to_mpc``); on a stream it is each flight's
direct flight (the straight line at 454 kt without wind; ``flight_time_ratio_to_direct``)
and the card has a ``stream`` block: throughput per hour, delay against the direct
flight, LoS per flight hour, runs outside the envelope, most aircraft airborne at once
(``stream_card_block``).

    python -m atc_nf_env.benchmark --policy nf --task converging-4 --split validation --runs 20 --out card.json
    atc-nf benchmark --policy nf-leg --task stream-30 --split validation --runs 2 --out card.json

The suite is versioned (``SUITE_VERSION``): a change to a task, a split or the score
makes a new version, and every card names the version it was scored on.

- v0: converging-4/6, random-4/6/8.
- v1: adds stream-30, stream-60 and stream-120 (2 h each) with their own splits and the
  stream card. The encounter tasks, their splits and their score are v0's unchanged: a
  v0 card of an encounter task is the v1 card of the same runs but for its version.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from atc_nf_env.episode import MAX_EPISODE_S
from atc_nf_env.policy import policy_file_suffixes
from atc_nf_env.units import AIRSPEED_MAX_KT, AIRSPEED_MIN_KT, WIND_SIGMA_MPS

#: The suite's version: cards of different versions are not comparable.
SUITE_VERSION = "v1"


@dataclass(frozen=True)
class Split:
    """A range of seeds: ``first`` … ``first + size − 1``."""

    name: str
    first: int
    size: int

    def seeds(self, runs: int) -> range:
        """The split's first ``runs`` seeds (ValueError when it has fewer)."""
        if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= self.size:
            raise ValueError(f"runs = {runs!r}: the {self.name} split has {self.size} seeds; give 1 … {self.size}")
        return range(self.first, self.first + runs)


SPLITS: dict[str, Split] = {
    split.name: split
    for split in (
        Split("train", 0, 1_000_000_000),
        Split("validation", 1_000_000_000, 10_000),
        Split("test", 2_000_000_000, 10_000),
    )
}

#: The stream tasks' splits: beyond the encounter tasks' and every seed flown before.
STREAM_SPLITS: dict[str, Split] = {
    split.name: split
    for split in (
        Split("train", 3_000_000_000, 1_000_000_000),
        Split("validation", 4_000_000_000, 10_000),
        Split("test", 5_000_000_000, 10_000),
    )
}

#: A stream task's length, s.
STREAM_TASK_S: float = 120.0 * 60.0


@dataclass(frozen=True)
class Task:
    """One benchmark task: a scenario family under the paper's wind, with a time limit and
    its seed splits."""

    name: str
    scenario: str
    wind_sigma_mps: float = WIND_SIGMA_MPS
    #: The episode's time limit, s (the evaluator's default, 4 h; a stream's length).
    max_time_s: float = MAX_EPISODE_S
    description: str = ""
    #: The task's seed splits by name (the encounter tasks': ``SPLITS``).
    splits: Mapping[str, Split] = field(default_factory=lambda: SPLITS, hash=False)

    @property
    def is_stream(self) -> bool:
        """A traffic stream (aircraft entering and leaving), not an encounter."""
        return self.scenario.startswith("stream-")


TASKS: dict[str, Task] = {
    task.name: task
    for task in (
        Task("converging-4", "converging-4", description="the paper's 4-aircraft encounter (Section IV-D.1)"),
        Task("converging-6", "converging-6", description="the paper's 6-aircraft encounter (Section IV-D.2)"),
        Task("random-4", "random-4", description="4 aircraft, random starts and destinations"),
        Task("random-6", "random-6", description="6 aircraft, random starts and destinations"),
        Task("random-8", "random-8", description="8 aircraft, random starts and destinations"),
        *(Task(f"stream-{rate}", f"stream-{rate}", max_time_s=STREAM_TASK_S, splits=STREAM_SPLITS,
               description=f"a traffic stream: {rate} aircraft an hour entering for 2 h")
          for rate in (30, 60, 120)),
    )
}

#: Splits a score card may be computed on (training seeds score nothing).
SCORED_SPLITS: tuple[str, ...] = ("validation", "test")


def get_task(name: str) -> Task:
    """The task called ``name`` (ValueError listing the suite's tasks otherwise)."""
    try:
        return TASKS[name]
    except (KeyError, TypeError):
        raise ValueError(f"task = {name!r}: the {SUITE_VERSION} suite has {', '.join(TASKS)}") from None


def get_split(name: str, *, scored: bool = True, task: Task | str | None = None) -> Split:
    """The split called ``name`` of ``task`` (a task or its name; None: the encounter
    tasks' ``SPLITS``); with ``scored``, only those a card may use."""
    splits = SPLITS if task is None else (get_task(task) if isinstance(task, str) else task).splits
    allowed = SCORED_SPLITS if scored else tuple(splits)
    if name not in allowed:
        raise ValueError(f"split = {name!r}: allowed: {', '.join(allowed)}")
    return splits[name]


def run_is_safe(record: dict[str, Any]) -> bool:
    """No loss of separation and no integration step outside [366, 540] kt in this run."""
    return int(record["los_count"]) == 0 and float(record["envelope_violation_fraction"]) == 0.0


def lexicographic_score(runs: int, runs_safe: int, runs_home: int, flight_time_ratio: float | None) -> float:
    """One number that orders cards of the same task, split and run count
    lexicographically: by ``runs_safe`` first, then by ``runs_home``, then by speed.

        score = runs_safe / runs + runs_home / (runs (runs + 1)) + speed / (runs + 1)²

    with speed = 1 / (1 + ratio) ∈ (0, 1) for the flight-time ratio (0 when unknown): to
    the MPC on the same seeds on an encounter task; on a stream task to the direct flight
    (Σ flight time / Σ direct flight time over the flights that arrived, so the delay
    against the direct flight), where a run is home when no flight left the workspace.
    Throughput, max airborne and LoS per flight hour are on a stream's card but not in its
    score (a LoS already makes its run unsafe). A flight still airborne at the stream's
    end counts in no term: a policy that keeps flights in the air past the end scores its
    speed on the others only, and its throughput on the card shows it. One more safe run always outweighs any number of runs home and any speed,
    and one more run home any speed: the score lies in [0, 1 + 2/runs) and reads, to
    first order, as the share of safe runs.
    """
    speed = 0.0 if flight_time_ratio is None or not math.isfinite(flight_time_ratio) else 1.0 / (1.0 + flight_time_ratio)
    return runs_safe / runs + runs_home / (runs * (runs + 1)) + speed / (runs + 1) ** 2


def _mean_flight_ratio(records: list[dict[str, Any]], reference: list[dict[str, Any]]) -> float | None:
    """Σ policy flight time / Σ reference flight time over the (seed, aircraft) pairs that
    both brought home; None when there is no such pair."""
    by_seed = {int(r["seed"]): r for r in reference}
    own = ref = 0.0
    for record in records:
        other = by_seed.get(int(record["seed"]))
        if other is None:
            continue
        for t, a, t_ref, a_ref in zip(record["flight_time_min"], record["arrived"], other["flight_time_min"],
                                      other["arrived"]):
            if a and a_ref:
                own += t
                ref += t_ref
    return own / ref if ref > 0 else None


def _direct_flight_ratio(records: list[dict[str, Any]]) -> float | None:
    """Σ flight time / Σ direct flight time over every flight of a stream's runs that
    arrived (the direct flight: the straight line at 454 kt without wind, so the delay is
    flight time − direct time); None when no flight arrived."""
    own_s = direct_s = 0.0
    for record in records:
        stream = record["stream"]
        flown_s = 60.0 * sum(t for t, a in zip(record["flight_time_min"], record["arrived"]) if a)
        mean_delay_s = stream["delay_s"]["mean"]
        if mean_delay_s is None:
            continue
        own_s += flown_s
        direct_s += flown_s - mean_delay_s * stream["flights_completed"]
    return own_s / direct_s if direct_s > 0 else None


def stream_card_block(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The ``stream`` block of a stream task's card, from the evaluator's records:
    ``throughput_per_hour`` {min, mean, max} over runs, ``delay_s`` (flight time minus the
    direct flight's, s) {mean over arrived flights, max}, ``los_count`` and
    ``los_per_flight_hour`` (pooled over runs), ``runs_outside_envelope``,
    ``max_airborne`` (over runs) and the flights' counts."""
    from atc_nf_env.metrics import pool_stream_metrics

    missing = [r["seed"] for r in records if not r.get("stream")]
    if missing:
        raise ValueError(f"seeds {missing}: these runs carry no stream metrics (not a stream's runs?)")
    pooled = pool_stream_metrics([r["stream"] for r in records])
    return {
        "throughput_per_hour": pooled["throughput_per_hour"],
        "delay_s": pooled["delay_s"],
        "los_count": pooled["los_count"],
        "los_per_flight_hour": pooled["los_per_flight_hour"],
        "flight_hours": pooled["flight_hours"],
        "runs_outside_envelope": sum(float(r["envelope_violation_fraction"]) > 0 for r in records),
        "max_airborne": pooled["max_airborne"],
        "flights_entered": pooled["flights_entered"],
        "flights_completed": pooled["flights_completed"],
        "flights_left_workspace": pooled["flights_left_workspace"],
        "flights_airborne_at_end": int(sum(r["stream"]["airborne_at_end"] for r in records)),
        "entries_held": pooled["entries_held"],
    }


def card_from_records(task: Task, split: Split, policy: str, shield: bool, records: list[dict[str, Any]],
                      reference: list[dict[str, Any]] | None) -> dict[str, Any]:
    """The score card of finished runs (``evaluate``'s records) on ``split``'s first seeds;
    ``reference``: on an encounter task, the MPC's records on the same seeds (for the
    flight-time ratio); on a stream task it must be None (the reference is each flight's
    direct flight)."""
    if not records:
        raise ValueError("a score card needs at least one run")
    if task.is_stream and reference is not None:
        raise ValueError(f"task {task.name}: a stream's card compares with the direct flight; give reference=None")
    records = sorted(records, key=lambda r: r["seed"])
    runs = len(records)
    safe = [run_is_safe(r) for r in records]
    home = [bool(r["success"]) for r in records]
    flight = [t for r in records for t, a in zip(r["flight_time_min"], r["arrived"]) if a]
    decision_means = [r["decision_s_mean"] for r in records if r["decisions"]]
    latencies = sorted(t for r in records for t in r.get("decision_s_each") or ())
    stream_block = stream_card_block(records) if task.is_stream else None  # refuses runs without stream metrics
    if task.is_stream:
        ratio = _direct_flight_ratio(records)
        ratio_key, reference_name = "flight_time_ratio_to_direct", "the direct flight (straight line at 454 kt)"
    else:
        ratio = _mean_flight_ratio(records, reference) if reference else None
        ratio_key, reference_name = "flight_time_ratio_to_mpc", "the MPC on the same seeds"
    card = {
        "suite_version": SUITE_VERSION,
        "task": task.name,
        "scenario": task.scenario,
        "wind_sigma_mps": task.wind_sigma_mps,
        "split": split.name,
        "seeds": [records[0]["seed"], records[-1]["seed"]],
        "policy": policy,
        "shield": shield,
        "runs": runs,
        "runs_home": sum(home),
        "runs_safe": sum(safe),
        "runs_safe_and_home": sum(s and h for s, h in zip(safe, home)),
        "runs_with_los": sum(int(r["los_count"]) > 0 for r in records),
        "runs_outside_envelope": sum(float(r["envelope_violation_fraction"]) > 0 for r in records),
        "success_rate": sum(home) / runs,
        "safe_rate": sum(safe) / runs,
        "flight_time_min_mean": sum(flight) / len(flight) if flight else None,
        ratio_key: ratio,
        "decision_ms_mean": 1e3 * sum(decision_means) / len(decision_means) if decision_means else None,
        "decision_ms_p99": 1e3 * latencies[min(len(latencies) - 1, math.ceil(0.99 * len(latencies)) - 1)]
        if latencies else None,
        "score": lexicographic_score(runs, sum(safe), sum(home), ratio),
        "score_definition": f"runs_safe/runs + runs_home/(runs(runs+1)) + (1/(1+{ratio_key}))/(runs+1)^2: "
                            f"safety first, then runs home, then speed against {reference_name} "
                            "(atc_nf_env.benchmark.lexicographic_score)",
        "safety_definition": f"a run is safe when no pair came closer than 5 nm and no integration step left "
                             f"[{AIRSPEED_MIN_KT:g}, {AIRSPEED_MAX_KT:g}] kt",
        "home_definition": "no flight left the workspace (flights airborne at the stream's end are neither home "
                           "nor lost)" if task.is_stream else "every aircraft arrived within the time limit",
    }
    if stream_block is not None:
        card["stream"] = stream_block
    return card


def _study_records(policy: str, task: Task, split: Split, runs: int, shield: bool, path: Path | None,
                   workers: int | None, progress: bool, policy_kwargs: dict[str, Any] | None = None
                   ) -> list[dict[str, Any]]:
    from atc_nf_env.evaluate import Study, evaluate, read_results

    study = Study(policy=policy, scenario=task.scenario, wind_sigma_mps=task.wind_sigma_mps,
                  max_time_s=task.max_time_s, shield=shield, policy_kwargs=dict(policy_kwargs or {}))
    records: list[dict[str, Any]] = []
    evaluate(study, runs, first_seed=split.first, workers=workers, out=path, resume=path is not None and path.exists(),
             progress=progress, on_run=None if path is not None else records.append)
    if path is not None:
        _, records = read_results(path)
    wanted = set(split.seeds(runs))
    return [r for r in records if int(r["seed"]) in wanted]


#: How many hex digits of a model file's SHA-256 its results label carries.
LABEL_HASH_DIGITS = 12


def results_label(policy: str, shield: bool = False) -> str:
    """The name of ``policy``'s results file in ``score_card``'s ``results_dir`` (without
    ``.jsonl``): a registered name as given (``mpc``, ``nf``; ``mpc+shield`` inside the
    safety filter), a model file as its stem, ``@`` and the first ``LABEL_HASH_DIGITS`` hex
    digits of its bytes' SHA-256, then its suffix (``policy@3f9c0a1b2d4e.pt``,
    ``policy@3f9c0a1b2d4e+shield.pt``).

    So two different models of one file name (``a/policy.pt``, ``b/policy.pt``) keep two
    files, one model reached by two paths keeps one, and no model file (``mpc.zip``) can
    take the file of a registered name such as the MPC reference's ``mpc``: a file's label
    ends with a model file's suffix, which no policy name does (``make_policy`` reads such
    a name as a file, and ``register_policy`` refuses it).

    Raises:
        ValueError: ``policy`` names a model file that cannot be read.
    """
    from atc_nf_env.evaluate import file_sha256

    suffix = "+shield" if shield else ""
    if Path(policy).suffix.lower().lstrip(".") not in {"zip", *policy_file_suffixes()}:
        return policy + suffix
    try:
        digest = file_sha256(policy)
    except OSError as error:
        raise ValueError(f"policy {policy!r}: cannot read the model file: {error.strerror}") from None
    return f"{Path(policy).stem}@{digest[:LABEL_HASH_DIGITS]}{suffix}{Path(policy).suffix}"


def score_card(policy: str, task: str, split: str, runs: int, *, shield: bool = False, reference: bool = True,
               results_dir: Path | None = None, workers: int | None = None, progress: bool = False,
               policy_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fly ``policy`` (a registered name or a model file) on the first ``runs`` seeds of
    ``split`` of ``task`` and return its score card.

    With ``reference`` the MPC flies the same seeds for the flight-time ratio (its runs
    are kept in ``results_dir`` and reused by later cards of the same task and split);
    a stream task's ratio is to the direct flight, so ``reference`` is ignored there.
    With ``results_dir`` every study's runs go to a resumable results file there
    (``<task>/<split>/<label>.jsonl``, ``results_label``); otherwise they are kept in
    memory only.
    """
    task_ = get_task(task)
    split_ = get_split(split, task=task_)
    split_.seeds(runs)  # a clear error on a bad run count before anything flies

    def path_of(label: str) -> Path | None:
        if results_dir is None:
            return None
        folder = Path(results_dir) / task_.name / split_.name
        folder.mkdir(parents=True, exist_ok=True)
        return folder / f"{label}.jsonl"

    label = results_label(policy, shield) if results_dir is not None else ""
    records = _study_records(policy, task_, split_, runs, shield, path_of(label), workers, progress, policy_kwargs)
    ref = None
    if reference and not task_.is_stream:
        ref = records if policy == "mpc" and not shield and not policy_kwargs else _study_records(
            "mpc", task_, split_, runs, False, path_of("mpc"), workers, progress)
    return card_from_records(task_, split_, policy, shield, records, ref)


def format_card(card: dict[str, Any]) -> str:
    """A short human-readable view of a card."""
    def opt(value: float | None, fmt: str) -> str:
        return "n/a" if value is None else format(value, fmt)

    return "\n".join([
        f"{card['policy']}{' (shielded)' if card['shield'] else ''} on {card['task']} ({card['split']} split, "
        f"seeds {card['seeds'][0]}…{card['seeds'][1]}, suite {card['suite_version']})",
        f"  runs {card['runs']}   home {card['runs_home']}   safe {card['runs_safe']}   "
        f"(with LoS {card['runs_with_los']}, outside the envelope {card['runs_outside_envelope']})",
        f"  flight {opt(card['flight_time_min_mean'], '.1f')} min   "
        + (f"vs direct {opt(card['flight_time_ratio_to_direct'], '.3f')}   " if "stream" in card
           else f"vs MPC {opt(card['flight_time_ratio_to_mpc'], '.3f')}   ")
        + f"decision {opt(card['decision_ms_mean'], '.2f')} ms (p99 {opt(card['decision_ms_p99'], '.2f')})",
        *([_format_stream_block(card["stream"])] if "stream" in card else []),
        f"  score {card['score']:.6f}",
    ])


def _format_stream_block(stream: dict[str, Any]) -> str:
    delay = stream["delay_s"]
    delay_text = "n/a" if delay["mean"] is None else f"{delay['mean']:.0f} s (max {delay['max']:.0f} s)"
    return (f"  throughput {stream['throughput_per_hour']['mean']:.1f} flights/h   delay vs direct {delay_text}   "
            f"LoS {stream['los_count']} ({stream['los_per_flight_hour']:.3f} per flight hour)   "
            f"max airborne {stream['max_airborne']}")


#: What makes two score cards the same card: one policy scored on the same seeds of one
#: task of one suite version (a re-scoring only re-measures its timings).
CARD_IDENTITY_KEYS: tuple[str, ...] = ("suite_version", "task", "split", "policy", "shield", "runs")
#: A larger file is no score card (a card is a few kB), bytes.
MAX_CARD_BYTES = 1 << 20


def check_card_output(path: Path | None, identity: Mapping[str, Any], *, overwrite: bool = False) -> None:
    """Refuse, before anything flies, a card file (``--out``) that cannot be written (a
    missing folder, a directory, no write access) or that would silently replace another
    card: an existing file is replaced only if it holds the card ``identity`` describes
    (``CARD_IDENTITY_KEYS``), or with ``overwrite``.

    Raises:
        ValueError: saying what was wrong and what is allowed.
    """
    from atc_nf_env.cli import _check_output_file

    if path is None:
        return
    _check_output_file(path, "--out")
    if path.exists() and not path.is_file():  # a FIFO would block the read below, a device never end
        raise ValueError(f"--out {path} is not a regular file; give the path of a .json file")
    if overwrite or not path.exists():
        return
    old = None
    if path.stat().st_size <= MAX_CARD_BYTES:
        try:
            old = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            pass
    if not isinstance(old, dict) or "score" not in old:
        raise ValueError(f"--out {path} exists and is not a score card; choose another file, or give --overwrite "
                         "to replace it")
    differing = [key for key in CARD_IDENTITY_KEYS if key not in old or old[key] != identity[key]]
    if differing:
        described = ", ".join(f"{key} {old[key]!r} there, {identity[key]!r} here" if key in old
                              else f"{key} missing there, {identity[key]!r} here" for key in differing)
        raise ValueError(f"--out {path} holds another score card ({described}); choose another file, or give "
                         "--overwrite to replace it")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="atc-nf benchmark",
        description="Score a policy on a task of the benchmark suite (atc_nf_env.benchmark).",
    )
    parser.add_argument("--policy", required=True, help="a registered policy name (nf, mpc, ...) or a model file")
    parser.add_argument("--shield", action="store_true", help="fly the policy inside the safety filter")
    parser.add_argument("--task", required=True, choices=list(TASKS))
    parser.add_argument("--split", required=True, choices=list(SCORED_SPLITS))
    parser.add_argument("--runs", type=int, default=100, help="the split's first RUNS seeds (default 100)")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip the MPC on the same seeds (no flight-time ratio; the score's speed term is 0); "
                             "a stream task compares with the direct flight and never flies the MPC")
    parser.add_argument("--results-dir", type=Path, default=None,
                        help="keep every study's runs here, resumable (default: in memory only)")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None,
                        help="write the card as JSON to this file (its folder must exist); a file there already "
                             "is replaced only if it holds this same card (same suite version, task, split, policy, "
                             "shield and runs), otherwise refused unless --overwrite")
    parser.add_argument("--overwrite", action="store_true",
                        help="let --out replace whatever file is there (another card, or not a card)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    try:
        check_card_output(args.out, {"suite_version": SUITE_VERSION, "task": args.task, "split": args.split,
                                     "policy": args.policy, "shield": args.shield, "runs": args.runs},
                          overwrite=args.overwrite)
        card = score_card(args.policy, args.task, args.split, args.runs, shield=args.shield,
                          reference=not args.no_reference, results_dir=args.results_dir, workers=args.workers,
                          progress=not args.no_progress)
    except ValueError as error:
        print(f"atc-nf benchmark: {error}", file=sys.stderr)
        return 2
    print(format_card(card))
    if args.out is not None:
        args.out.write_text(json.dumps(card, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    from atc_nf_env.cli import main as atc_nf

    sys.exit(atc_nf(["benchmark", *sys.argv[1:]]))  # as `atc-nf benchmark` (one line on Ctrl-C)
