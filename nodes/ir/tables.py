"""Error models from a measure's ``model`` argument: a table of numbers for a dataclass."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import fields, replace
from typing import Any, TypeVar

T = TypeVar("T")


def numbers_into(cls: type[T], table: Any, what: str, non_negative: Iterable[str] = ()) -> T:
    """``cls()`` with the fields ``table`` gives, each a finite number (those named in
    ``non_negative`` also >= 0); ValueError naming ``what``, the field and the value."""
    table = dict(table or {})
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - names)
    if unknown:
        raise ValueError(f"unknown {what} fields {unknown}; known: {', '.join(sorted(names))}")
    for k, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{what} field {k!r} must be a finite number, got {v!r}")
        if k in non_negative and v < 0:
            raise ValueError(f"{what} field {k!r} must be >= 0, got {v!r}")
    return replace(cls(), **{k: float(v) for k, v in table.items()})  # type: ignore[type-var]
