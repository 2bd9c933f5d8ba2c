"""The behaviour stamp: what the code flies, hashed, so that a published table is flown
again only when what it shows can change.

The build fingerprint (``atc_nf_env.build``) changes with any edit of the code that flies
a run, a refactor included; it guards ``--resume``, where a run must come from the very
same code. A table needs less: it can change only when what the code *does* changes. The
behaviour stamp is SHA-256 over the outputs of a fixed set of probes, one per part of
the software, each flown with fixed seeds:

- ``kernel``: a batch of mixed encounters (random-4/5/6, converging-6) through
  ``kernel.advance`` under per-world winds, waypoints offset every other period, with and
  without ``stop_on_violation``; the state after every period and every ``Trace`` array.
- ``env``: observations, rewards, terminations and infos of the Gymnasium encounter env
  (random-6) and the PettingZoo parallel env (converging-4) under seeded random actions.
- ``stream``: the same of the PettingZoo stream env on an hour of stream-30, and the
  per-cluster MPC flying an hour of stream-12.
- ``mpc``: the MCMC-MPC's waypoints and run metrics: its defaults on converging-4 (a
  whole episode) and on random-12, Table I's proposal (``proposal="paper"``), the
  per-cluster search with the progress rule on random-12, and a decision with no feasible candidate (two aircraft
  6 nm apart abreast).
- ``filter``: the safety filter's waypoints and counts around a proposer of seeded
  random waypoints (random-6), with the MPC and the least-bad fallback.
- ``agents``: the waypoints of every shipped model (``agents/models``, through the
  registry's file loaders) on three periods of random-6; needs torch and
  Stable-Baselines3 (the part reads ``unavailable`` without them).

Each part is 16 hex digits; the stamp of a table lists the parts it depends on. Equal
parts mean the same numbers bit for bit on this machine; the stamp says nothing about
speed (a table's timings are measured where it is written). Another processor can fly
other bits from the same code (its libm, its vector width), so a table's stamp also names
the machine it was flown on (``machine_identity``), and a table flown elsewhere is flown
again rather than compared.

A stamp is computed once per build fingerprint, probe code and model files, and kept in
``$ATC_NF_BEHAVIOUR_CACHE`` (default ``~/.cache/atc_nf_env/behaviour``): a table writer
asks for it in seconds after the first time.

Run: ``python -m atc_nf_env.experiments.behaviour`` prints the stamp;
``... check FILE [SECTION] --parts P,Q -- COMMAND...`` exits 0 when the table in FILE
(the marked SECTION, or the whole file) carries the stamp COMMAND would write today, 1
when it must be flown again (and says why).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib.util
import json
import os
import re
import sys
import warnings
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: The parts of the stamp, in the order they are printed.
PARTS: tuple[str, ...] = ("kernel", "env", "stream", "mpc", "filter", "agents")

#: The pseudo-part of a table of timings: the build fingerprint (``atc_nf_env.build``).
BUILD = "build"

#: What a part reads when its probe cannot run here (a library missing).
UNAVAILABLE = "unavailable"

#: The line a stamped table carries (an HTML comment: a reader of the page does not see it).
STAMP_PATTERN = re.compile(r"<!-- behaviour stamp: (?P<body>[^>]*) -->")

_PROBE_SEED = 20261207


class _Digest:
    """SHA-256 over arrays (their dtype, shape and bytes) and plain values (as JSON)."""

    def __init__(self) -> None:
        self._hash = hashlib.sha256()

    def add(self, *values: Any) -> None:
        for value in values:
            if isinstance(value, (np.ndarray, np.generic)):
                array = np.ascontiguousarray(value)
                self._hash.update(f"{array.dtype.str}{array.shape}".encode())
                self._hash.update(array.tobytes())
            elif isinstance(value, dict):
                for key in sorted(value, key=str):
                    self._hash.update(str(key).encode() + b"=")
                    self.add(value[key])
            elif isinstance(value, (list, tuple)):
                self._hash.update(b"[")
                for item in value:
                    self.add(item)
                self._hash.update(b"]")
            elif dataclasses.is_dataclass(value) and not isinstance(value, type):
                self.add({f.name: getattr(value, f.name) for f in dataclasses.fields(value)})
            else:
                self._hash.update(repr(value).encode() + b";")

    def hex(self) -> str:
        return self._hash.hexdigest()[:16]


def kernel_part(config: Any = None) -> str:
    """The kernel probe (see the module docstring), flown with ``config`` (a ``SimConfig``;
    None: the defaults)."""
    from atc_nf_env import kernel
    from atc_nf_env.config import SimConfig
    from atc_nf_env.scenarios import make_scenario
    from atc_nf_env.simulation import initial_state

    digest = _Digest()
    for stop_on_violation, record_every in ((False, 2), (True, 1)):
        rng = np.random.default_rng(_PROBE_SEED)
        specs = ("random-4", "random-6", "converging-6", "random-5")
        scenarios = [make_scenario(spec, seed=_PROBE_SEED + b) for b, spec in enumerate(specs)]
        state = np.stack([initial_state(scenario, 1, 6)[0] for scenario in scenarios])
        radius = max(scenario.workspace_radius_nm for scenario in scenarios)
        params = (config or SimConfig()).to_params(radius, stop_on_violation=stop_on_violation)
        wind_kt = rng.normal(0.0, 10.0, (len(scenarios), 2))
        for period in range(24):
            waypoints = state[:, :, kernel.S_DEST_X : kernel.S_DEST_Y + 1].copy()
            if period % 2 == 1:
                waypoints += rng.normal(0.0, 30.0, waypoints.shape)
            trace = kernel.advance(state, waypoints, wind_kt, 300.0, params, record_every=record_every)
            digest.add(state, trace.min_airspeed_kt, trace.max_airspeed_kt, trace.violation_steps,
                       trace.worst_excursion_kt, trace.steps_flown, trace.los_pairs, trace.min_separation_nm,
                       trace.steps_done, trace.violated, trace.record)
            if (state[:, :, kernel.S_STATUS] != kernel.FLYING).all():
                break
    return digest.hex()


def _fly_parallel(env: Any, digest: _Digest, seed: int, steps: int) -> None:
    """Seeded random actions through a PettingZoo parallel env, every output hashed."""
    observations, infos = env.reset(seed=seed)
    digest.add(observations, infos)
    for step in range(steps):
        if not env.agents:
            break
        actions = {}
        for k, agent in enumerate(sorted(env.agents)):
            space = env.action_space(agent)
            space.seed(seed + 1000 * step + k)
            actions[agent] = space.sample()
        digest.add(actions, *env.step(actions))


def env_part() -> str:
    """The environments' probe (see the module docstring)."""
    import gymnasium as gym

    from atc_nf_env.envs.parallel import parallel_env

    digest = _Digest()
    env = gym.make("atc_nf_env/Encounter-v1", scenario="random-6")
    observation, info = env.reset(seed=_PROBE_SEED)
    digest.add(observation, info)
    env.action_space.seed(_PROBE_SEED)
    for _ in range(10):
        result = env.step(env.action_space.sample())
        digest.add(*result)
        if result[2] or result[3]:
            break
    env.close()
    parallel = parallel_env(scenario="converging-4")
    _fly_parallel(parallel, digest, _PROBE_SEED, 10)
    parallel.close()
    return digest.hex()


def stream_part() -> str:
    """The traffic streams' probe (see the module docstring)."""
    from atc_nf_env.envs.parallel import parallel_env

    digest = _Digest()
    env = parallel_env(scenario="stream-30-60min")
    _fly_parallel(env, digest, 3_200_000_000 + 7, 12)
    env.close()
    from atc_nf_env.policy import make_policy

    _episode(digest, make_policy("mpc", sampling="per-cluster", progress_fraction=0.5, progress_periods=6),
             "stream-12-60min", 3_200_000_011)
    return digest.hex()


#: The run metrics that are wall-clock times: what the code does is hashed, not how fast.
_WALL_CLOCK = frozenset({"wall_s", "decision_s_mean"})


def _episode(digest: _Digest, policy: Any, scenario: Any, seed: int, **kwargs: Any) -> None:
    from atc_nf_env.episode import run_episode

    result = run_episode(policy, scenario, seed=seed, **kwargs)
    metrics = {k: v for k, v in dataclasses.asdict(result.metrics).items() if k not in _WALL_CLOCK}
    digest.add(metrics, result.waypoints, result.decision_times_s)


def mpc_part() -> str:
    """The MCMC-MPC's probe (see the module docstring)."""
    from atc_nf_env.policy import make_policy
    from atc_nf_env.scenarios import CloseStartWarning

    digest = _Digest()
    _episode(digest, make_policy("mpc"), "converging-4", 2_000_000_017)
    _episode(digest, make_policy("mpc", proposal="paper"), "converging-4", 2_000_000_018, max_time_s=1800.0)
    _episode(digest, make_policy("mpc", sampling="per-cluster", progress_fraction=0.5, progress_periods=6),
             "random-12", 2_000_000_019, max_time_s=1200.0)
    _episode(digest, make_policy("mpc"), "random-12", 2_000_000_020, max_time_s=1200.0)
    abreast = {"name": "abreast-2", "aircraft": [{"start": [-250.0, 0.0], "destination": [250.0, 0.0]},
                                                 {"start": [-250.0, 6.0], "destination": [250.0, 6.0]}]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CloseStartWarning)  # the start is close on purpose
        _episode(digest, make_policy("mpc"), abreast, 8_100_000_000, max_time_s=900.0)
    return digest.hex()


class _RandomWaypoints:
    """A proposer of seeded random waypoints within 150 nm of each aircraft: the filter's
    probe needs a proposer that is often unsafe."""

    name = "random-waypoints"

    def reset(self, scenario: Any, config: Any, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(seed)

    def act(self, view: Any) -> np.ndarray:
        return view.positions + self._rng.uniform(-150.0, 150.0, view.positions.shape)


def filter_part() -> str:
    """The safety filter's probe (see the module docstring)."""
    from atc_nf_env.shield import SafetyFilter

    digest = _Digest()
    for fallback, seed in (("mpc", 2_000_000_021), ("least-bad", 2_000_000_022)):
        shielded = SafetyFilter(_RandomWaypoints(), fallback=fallback)
        _episode(digest, shielded, "random-6", seed, max_time_s=2400.0)
        digest.add(shielded.episode_info())
    return digest.hex()


def model_files() -> list[Path]:
    """The shipped models (``agents/models``), sorted; empty without the agents package."""
    spec = importlib.util.find_spec("agents")
    if spec is None or spec.origin is None:
        return []
    return sorted(p for p in (Path(spec.origin).parent / "models").glob("*") if p.suffix in (".zip", ".pt"))


def agents_part() -> str:
    """The trained agents' probe (see the module docstring)."""
    if importlib.util.find_spec("torch") is None or importlib.util.find_spec("stable_baselines3") is None:
        return UNAVAILABLE
    from atc_nf_env.policy import make_policy

    digest = _Digest()
    for path in model_files():
        digest.add(path.name)
        _episode(digest, make_policy(str(path)), "random-6", 2_000_000_023, max_time_s=900.0)
    return digest.hex()


PROBES: dict[str, Callable[[], str]] = {
    "kernel": kernel_part, "env": env_part, "stream": stream_part, "mpc": mpc_part,
    "filter": filter_part, "agents": agents_part,
}


def machine_identity() -> str:
    """8 hex digits naming this machine as far as the bits of a flight go: the OS, the
    architecture and the processor's model (``/proc/cpuinfo``'s first "model name", or
    ``platform.processor()``); library versions are in the build fingerprint."""
    import platform

    model = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return hashlib.sha256(f"{platform.system()}|{platform.machine()}|{model}".encode()).hexdigest()[:8]


def cache_key() -> str:
    """16 hex digits over what the stamp is a function of on one machine: the build
    fingerprint, this module's code and the shipped models' bytes."""
    from atc_nf_env import build

    digest = hashlib.sha256(build.fingerprint().encode())
    digest.update(build.code_digest(Path(__file__).read_bytes()).encode())
    for path in model_files():
        digest.update(path.name.encode() + hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:16]


def _cache_dir() -> Path:
    return Path(os.environ.get("ATC_NF_BEHAVIOUR_CACHE", Path.home() / ".cache" / "atc_nf_env" / "behaviour"))


def compute_stamp(parts: Iterable[str] = PARTS) -> dict[str, str]:
    """{part: 16 hex digits (or ``UNAVAILABLE``)} of ``parts``, flown now, nothing cached."""
    parts = _checked_parts(parts)
    return {part: PROBES[part]() for part in parts}


def current_stamp(parts: Iterable[str] = PARTS) -> dict[str, str]:
    """The stamp of ``parts`` of the code installed now, from the cache when this build,
    probe code and model files were stamped before (``cache_key``), flown otherwise."""
    parts = _checked_parts(parts)
    path = _cache_dir() / f"{cache_key()}.json"
    try:
        cached = json.loads(path.read_text())
        if not isinstance(cached, dict) or not all(isinstance(v, str) for v in cached.values()):
            cached = {}
    except (OSError, ValueError):
        cached = {}
    missing = [part for part in parts if part not in cached]
    if missing:
        cached.update(compute_stamp(missing))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            partial = path.with_name(f".{path.name}.{os.getpid()}")
            partial.write_text(json.dumps(cached, sort_keys=True))
            partial.replace(path)
        except OSError:
            pass  # an unwritable cache costs the next writer the probes' time, nothing else
    return {part: cached[part] for part in parts}


def _checked_parts(parts: Iterable[str], allowed: Sequence[str] = PARTS) -> list[str]:
    """``parts`` in ``allowed``'s order; ValueError naming the allowed ones otherwise."""
    parts = list(parts)
    unknown = [part for part in parts if part not in allowed]
    if unknown or not parts:
        raise ValueError(f"behaviour parts {unknown or parts!r}: allowed: {', '.join(allowed)} (at least one)")
    return [part for part in allowed if part in parts]


#: The parts a table's stamp may name: the probes' and ``BUILD``.
TABLE_PARTS: tuple[str, ...] = PARTS + (BUILD,)


#: Options of a table's command that do not change what the table holds, each with
#: whether it takes a value: where it is written, progress bars, and the reuse of runs
#: the same build flew (``--reuse-mpc``: the study checks the build).
_NOT_WHAT_A_TABLE_HOLDS: dict[str, bool] = {"--write": False, "--no-progress": False, "--reuse-mpc": True}


def command_identity(argv: Sequence[str]) -> str:
    """16 hex digits over what a table's command is: the code of the script or module it
    runs (``build.code_digest``: comments and docstrings apart) and its arguments, without
    those that do not change what the table holds (``_NOT_WHAT_A_TABLE_HOLDS``).

    ``argv`` is the command as run: ``python SCRIPT ARGS``, ``python -m MODULE ARGS``, or
    ``SCRIPT ARGS``.

    Raises:
        ValueError: the script or module cannot be found.
    """
    from atc_nf_env import build

    words = list(argv)
    if words and Path(words[0]).name.startswith("python"):
        words = words[1:]
    if words[:1] == ["-m"]:
        if len(words) < 2:
            raise ValueError("command '-m' names no module")
        spec = importlib.util.find_spec(words[1])
        if spec is None or spec.origin is None:
            raise ValueError(f"command module {words[1]!r} cannot be found")
        source, args = Path(spec.origin), words[2:]
    else:
        if not words:
            raise ValueError("the command is empty")
        source, args = Path(words[0]), words[1:]
    if not source.is_file():
        raise ValueError(f"command script {str(source)!r} is not a file")
    digest = hashlib.sha256(build.code_digest(source.read_bytes(), str(source)).encode())
    kept, skip_value = [], False
    for arg in args:
        if skip_value:
            skip_value = False
        elif arg in _NOT_WHAT_A_TABLE_HOLDS:
            skip_value = _NOT_WHAT_A_TABLE_HOLDS[arg]
        else:
            kept.append(arg)
    for arg in kept:
        digest.update(arg.encode() + b"\0")
    return digest.hexdigest()[:16]


def stamp_line(parts: Iterable[str], argv: Sequence[str]) -> str:
    """The line a table carries: ``<!-- behaviour stamp: kernel=… mpc=… command=… -->``
    for ``parts`` (``BUILD`` among them: the build fingerprint) and the command ``argv``."""
    stamp = table_stamp(parts)
    return ("<!-- behaviour stamp: " + " ".join(f"{k}={v}" for k, v in stamp.items())
            + f" machine={machine_identity()} command={command_identity(argv)} -->")


def table_stamp(parts: Iterable[str], fresh: bool = False) -> dict[str, str]:
    """{part: value} of ``parts`` for a table: the probes' parts (``current_stamp``, or
    ``compute_stamp`` when ``fresh``) and, where ``BUILD`` is named, the build fingerprint:
    a table of timings is flown again when the code changes, whatever it flies, since speed
    is not in the probes."""
    from atc_nf_env import build

    parts = _checked_parts(parts, TABLE_PARTS)
    probed = [part for part in parts if part != BUILD]
    stamp = (compute_stamp if fresh else current_stamp)(probed) if probed else {}
    if BUILD in parts:
        stamp[BUILD] = build.fingerprint()
    return stamp


def read_stamp(text: str) -> dict[str, str] | None:
    """{part or "command": value} of the stamp line in ``text``; None when it has none."""
    match = STAMP_PATTERN.search(text)
    if match is None:
        return None
    return dict(item.split("=", 1) for item in match.group("body").split() if "=" in item)


def _section_bounds(text: str, section: str) -> tuple[int, int] | None:
    begin, end = f"<!-- begin {section} -->", f"<!-- end {section} -->"
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        return None
    return text.index(begin) + len(begin), text.index(end)


def table_text(path: Path, section: str | None) -> str | None:
    """The text of the marked ``section`` of ``path`` (the whole file when None); None when
    the file or the section does not exist."""
    try:
        text = path.read_text()
    except OSError:
        return None
    if section is None:
        return text
    bounds = _section_bounds(text, section)
    return None if bounds is None else text[bounds[0] : bounds[1]]


def write_stamp(path: Path, section: str | None, line: str) -> None:
    """Put the stamp ``line`` into the table (the end of the marked ``section``, or of the
    whole file), replacing the one it had.

    Raises:
        ValueError: the file or the section does not exist.
    """
    text = table_text(path, None)
    if text is None:
        raise ValueError(f"{path}: no such table")
    start, stop = (0, len(text)) if section is None else (_section_bounds(text, section) or (None, None))
    if start is None:
        raise ValueError(f"{path}: no section {section!r} (one begin and one end marker)")
    body = STAMP_PATTERN.sub("", text[start:stop]).rstrip("\n") + "\n\n" + line + "\n"
    partial = path.with_name(f".{path.name}.{os.getpid()}")
    partial.write_text(text[:start] + body + text[stop:])
    partial.replace(path)


def _where(path: Path, section: str | None) -> str:
    return f"{path}" + (f" [{section}]" if section else "")


def why_stale(path: Path, section: str | None, parts: Iterable[str], argv: Sequence[str]) -> str | None:
    """Why the table must be flown again (None when it is fresh): missing, unstamped, a
    part of the behaviour moved, a part unavailable here, or its command changed."""
    where = _where(path, section)
    _checked_parts(parts, TABLE_PARTS)  # a bad part is an error even for a missing table
    text = table_text(path, section)
    if text is None:
        return f"{where}: no such table"
    stamp = read_stamp(text)
    if stamp is None:
        return f"{where}: flown before the behaviour stamp (no stamp line)"
    here = machine_identity()
    if stamp.get("machine", here) != here:  # a stamp without one predates the key: its parts decide
        return (f"{where}: flown on another machine ({stamp['machine']} -> {here}), whose bits this one "
                "need not reproduce")
    now = table_stamp(parts)
    unavailable = [part for part, value in now.items() if value == UNAVAILABLE]
    if unavailable:
        return f"{where}: the {', '.join(unavailable)} probe cannot run in this venv, so the table cannot be judged"
    moved = [f"{part} {stamp.get(part, 'missing')} -> {value}" for part, value in now.items()
             if stamp.get(part) != value]
    if moved:
        return f"{where}: behaviour moved ({'; '.join(moved)})"
    command = command_identity(argv)
    if stamp.get("command") != command:
        return f"{where}: its command changed ({stamp.get('command', 'missing')} -> {command})"
    return None


def fly_table(path: Path, section: str | None, parts: Sequence[str], argv: Sequence[str], force: bool) -> int:
    """Fly the table's command ``argv`` unless the table is fresh (``why_stale``; ``force``
    flies it anyway), then stamp it; the command's exit status (0 when skipped)."""
    import subprocess

    reason = "flown on request (--force)" if force else why_stale(path, section, parts, argv)
    where = _where(path, section)
    if reason is None:
        print(f"{where}: fresh (behaviour and command unchanged), not flown again", flush=True)
        return 0
    print(reason, flush=True)
    line = stamp_line(parts, argv)  # before flying: a stamp that cannot be made fails first
    if UNAVAILABLE in line:
        print(f"{where}: a part of its stamp cannot be computed in this venv ({line}); not flown", file=sys.stderr)
        return 2
    status = subprocess.call(list(argv))
    if status != 0:
        return status
    if stamp_line(parts, argv) != line:
        print(f"{where}: the code changed while the table flew; not stamped", file=sys.stderr)
        return 3
    write_stamp(path, section, line)
    return 0


def _parts_argument(value: str) -> list[str]:
    try:
        return _checked_parts([part for part in value.split(",") if part], TABLE_PARTS)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r}: allowed: {', '.join(TABLE_PARTS)}, comma-separated") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m atc_nf_env.experiments.behaviour",
                                     description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what")
    show = sub.add_parser("show", help="print the stamp of the code installed now (the default)")
    show.add_argument("--parts", type=_parts_argument, default=list(PARTS))
    show.add_argument("--fresh", action="store_true", help="fly the probes even if this build was stamped before")
    for name, what in (("check", "exit 0 if a table is fresh, 1 if it must be flown again"),
                       ("fly", "fly a table's command unless the table is fresh, then stamp it")):
        command = sub.add_parser(name, help=what)
        command.add_argument("file", type=Path, help="the table's file")
        command.add_argument("section", nargs="?", help="its marked section (none: the whole file)")
        command.add_argument("--parts", type=_parts_argument, default=list(PARTS),
                             help=f"the parts the table depends on: {', '.join(TABLE_PARTS)}")
        if name == "fly":
            command.add_argument("--force", action="store_true", help="fly it even when it is fresh")
        command.epilog = "The table's command follows a lone --, as it is run."
    words = list(sys.argv[1:] if argv is None else argv)
    # The table's command is everything after the first lone "--": it is not parsed here.
    command = words[words.index("--") + 1 :] if "--" in words else []
    args = parser.parse_args(words[: words.index("--")] if "--" in words else words)
    if args.what in ("check", "fly"):
        if not command:
            parser.error(f"{args.what} needs the table's command after --")
        try:
            if args.what == "fly":
                return fly_table(args.file, args.section, args.parts, command, args.force)
            reason = why_stale(args.file, args.section, args.parts, command)
        except ValueError as error:
            parser.error(str(error))
        print(reason or f"{_where(args.file, args.section)}: fresh")
        return 0 if reason is None else 1
    stamp = table_stamp(getattr(args, "parts", list(PARTS)), fresh=getattr(args, "fresh", False))
    for part, value in stamp.items():
        print(f"{part:7s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
