"""Argument types of the command lines (``hera`` and its benchmarks): numbers with the range
they must lie in, so that a bad value is refused by argparse before anything starts, in one
sentence naming the option and the value, with exit code 2 ("argument --duration: must be a
number > 0, got '-1'"). Every numeric option of the command lines uses one of these (a test
reads the sources for a bare ``type=float`` or ``type=int``)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

_Bad = argparse.ArgumentTypeError


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _Bad(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise _Bad(f"must be a finite number, got {text!r}")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _Bad(f"must be a whole number, got {text!r}") from None


def number(text: str) -> float:
    """A finite number of any sign (a rate that may turn either way)."""
    return _number(text)


def positive(text: str) -> float:
    """A finite number > 0 (a duration, a period, a rate)."""
    value = _number(text)
    if value <= 0:
        raise _Bad(f"must be a number > 0, got {text!r}")
    return value


def non_negative(text: str) -> float:
    """A finite number >= 0 (a delay, a jitter, a settling time)."""
    value = _number(text)
    if value < 0:
        raise _Bad(f"must be a number >= 0, got {text!r}")
    return value


def whole_at_least(minimum: int) -> Callable[[str], int]:
    """A whole number >= ``minimum`` (e.g. node counts a benchmark can lay out)."""

    def kind(text: str) -> int:
        value = _integer(text)
        if value < minimum:
            raise _Bad(f"must be a whole number >= {minimum}, got {text!r}")
        return value

    kind.__doc__ = f"A whole number >= {minimum}."
    return kind


count = whole_at_least(1)
"""A whole number >= 1 (steps, samples, rounds, a process id)."""

non_negative_int = whole_at_least(0)
"""A whole number >= 0 (a seed, a number of injected crashes)."""


def port(text: str) -> int:
    """A TCP port, 0 to 65535 (0: any free port)."""
    value = _integer(text)
    if not 0 <= value <= 65535:
        raise _Bad(f"must be a port from 0 to 65535, got {text!r}")
    return value


def one_of(*allowed: str) -> Callable[[str], str]:
    """One of the words ``allowed``."""

    def kind(text: str) -> str:
        if text not in allowed:
            raise _Bad(f"must be one of {', '.join(allowed)}, got {text!r}")
        return text

    return kind


def name(text: str) -> str:
    """A name as a spec gives one (a node's): a key chunk and a file name part."""
    from hera.keys import MAX_CHUNK, check_chunk

    try:
        return check_chunk(text, "name")
    except ValueError:
        raise _Bad(
            f"must use only letters, digits, '_', '.' and '-' (no '/', '*', '$'), at most "
            f"{MAX_CHUNK} of them, got {text!r}"
        ) from None


LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")


def log_level(text: str) -> str:
    """A logging level, any case (``info``), as the logging module names it (``INFO``)."""
    if text.upper() not in LOG_LEVELS:
        raise _Bad(f"must be one of {', '.join(LOG_LEVELS)}, got {text!r}")
    return text.upper()


def comma_separated(kind: Callable[[str], T]) -> Callable[[str], list[T]]:
    """Comma-separated values of ``kind``, each checked (the first bad one is named)."""

    def many(text: str) -> list[T]:
        return [kind(item.strip()) for item in text.split(",")]

    return many
