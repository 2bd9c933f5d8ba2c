"""Env IDs whose dynamics are no longer flown: making one raises an error naming the ID
that replaced it and what changed (Gymnasium's convention for an old version, with the
reason; the project's rule: a change of trajectories bumps the env's version)."""

from __future__ import annotations

from typing import Any, NoReturn

from gymnasium.error import DeprecatedEnv


def encounter_v0(*args: Any, **kwargs: Any) -> NoReturn:
    """``atc_nf_env/Encounter-v0``: retired with the kernel's change of integration among
    neighbours."""
    raise DeprecatedEnv(
        "atc_nf_env/Encounter-v0 is retired: its dynamics are no longer flown. Use atc_nf_env/Encounter-v1 (same "
        "arguments; gym.make and gym.make_vec), whose kernel integrates aircraft within the 12-nm sensing radius "
        "differently (theta-dot at its true rate in sub-steps, error control, guard 9 retuned), so every trajectory "
        "with two aircraft that close changed (CHANGELOG.md); a traffic stream has atc_nf_env/Stream-v1 too"
    )


__all__ = ["encounter_v0"]
