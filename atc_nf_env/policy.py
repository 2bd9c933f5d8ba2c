"""The policy interface: what the episode runner and the evaluator need of a policy.

The NF-only baseline, the MCMC-MPC and trained agents all implement it, so they are
evaluated alike. A policy is called every decision period (T = 5 min) with what it
may observe — the aircraft's states, not the wind — and returns one waypoint per
aircraft.

Policies are found by name through one registry (``make_policy``): the entry points of
the ``atc_nf_env.policies`` group (this project declares ``nf``, ``nf-leg`` and ``mpc`` in its
``pyproject.toml``; a third-party package declares its own the same way) and names
registered in-process with ``register_policy``. Saved policies are found by the file's
suffix through the ``atc_nf_env.policy_files`` group (``.zip``: a trained SB3 agent).
The core package never imports the packages built on it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from atc_nf_env.config import SimConfig
from atc_nf_env.scenarios import Scenario
from atc_nf_env.simulation import WorldView


@runtime_checkable
class Policy(Protocol):
    """A waypoint policy.

    Attributes:
        name: a short label used in reports.
    """

    name: str

    def reset(self, scenario: Scenario, config: SimConfig, seed: int | None = None) -> None:
        """Prepare for a new episode of ``scenario`` flown with ``config``."""

    def act(self, view: WorldView) -> np.ndarray:
        """Waypoints (N, 2), nm, for every aircraft (those no longer flying are ignored)."""


#: Entry-point group of policies by name: ``NAME = "module:factory"``, where
#: ``factory(**settings)`` returns a ``Policy``.
POLICY_GROUP = "atc_nf_env.policies"
#: Entry-point group of policies saved to a file, by suffix: ``zip = "module:loader"``,
#: where ``loader(path)`` returns a ``Policy``.
POLICY_FILE_GROUP = "atc_nf_env.policy_files"

_registered: dict[str, Callable[..., Policy]] = {}


def register_policy(name: str, factory: Callable[..., Policy]) -> None:
    """Make ``make_policy(name, **settings)`` call ``factory(**settings)`` in this process.

    Installed packages declare their policies in the ``atc_nf_env.policies`` entry-point
    group instead, which also reaches the evaluator's worker processes.
    """
    if not isinstance(name, str) or not name or name.lower().endswith(tuple(f".{s}" for s in policy_file_suffixes())):
        raise ValueError(f"policy name {name!r}: must be a non-empty string that is not a file name")
    if not callable(factory):
        raise TypeError(f"factory for policy {name!r} must be callable, got {type(factory).__name__}")
    _registered[name] = factory


def _entry_points(group: str) -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=group)}


def policy_file_suffixes() -> list[str]:
    """The suffixes of the policy files that plug-ins register (``zip``, ``pt``, ...), without the dot."""
    return sorted(_entry_points(POLICY_FILE_GROUP))


def available_policies() -> list[str]:
    """Names ``make_policy`` accepts (registered or installed), without loading them."""
    return sorted({*_entry_points(POLICY_GROUP), *_registered})


def make_policy(spec: str, **settings: Any) -> Policy:
    """A policy by name (``nf``: the NF alone, ``mpc``: the MCMC-MPC whose ``settings`` are
    ``MPCSettings`` fields, or any other installed or registered name), or by the path of a
    saved policy whose suffix is registered (``.zip``: a trained Stable-Baselines3 agent,
    ``agents.policy.SB3AgentPolicy``, needs the ``rl`` extra)."""
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"policy {spec!r}: give a policy name or the path of a saved policy")
    suffix = Path(spec).suffix.lower().lstrip(".")
    loaders = _entry_points(POLICY_FILE_GROUP)
    if suffix and suffix in loaders:
        if settings:
            raise ValueError(f"a saved policy ({spec}) takes no settings, got {sorted(settings)}")
        if not Path(spec).is_file():
            raise ValueError(
                f"policy {spec!r}: no such model file; give the path to a .{suffix} saved by `atc-nf train` or "
                "`atc-nf imitate` (shipped models: agents/models/*.zip)"
            )
        return loaders[suffix].load()(spec)
    factory = _registered.get(spec)
    if factory is None:
        installed = _entry_points(POLICY_GROUP)
        if spec not in installed:
            files = ", ".join(f".{s}" for s in sorted(loaders)) or "none installed"
            if not installed and not loaders:
                raise ValueError(
                    f"unknown policy {spec!r}: no policies are installed, because the atc-nf-env package is "
                    "not (run `pip install -e .` in its checkout; policies come from its entry points)"
                )
            raise ValueError(
                f"unknown policy {spec!r}; allowed: {', '.join(available_policies()) or 'none installed'}, or the "
                f"path of a saved policy ({files}; e.g. agents/models/<model>.zip). Packages add policies in the "
                f"{POLICY_GROUP!r} entry-point group."
            )
        factory = installed[spec].load()
    try:
        return factory(**settings)
    except TypeError as error:
        if not settings:
            raise
        raise ValueError(f"policy {spec!r} does not take the settings {sorted(settings)}: {error}") from None
