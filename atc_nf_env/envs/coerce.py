"""Environment settings given as a dataclass, a dict of its fields, or None."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping, TypeVar

T = TypeVar("T")


def coerce_settings(cls: type[T], value: T | Mapping[str, Any] | None, argument: str) -> T:
    """``cls`` from an instance, a dict of (some of) its fields, or None (the defaults).

    Raises ValueError naming ``argument``, the unknown fields and the allowed ones.
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    allowed = [f.name for f in fields(cls)]  # type: ignore[arg-type]
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(allowed))
        if unknown:
            raise ValueError(f"{argument}: unknown fields {unknown}; allowed: {allowed}")
        return cls(**value)
    raise ValueError(f"{argument} = {value!r}: must be {cls.__name__}(...) or a dict with fields {allowed}")
