"""A real board driver's constructor arguments, judged once by the driver's own rules.

A driver class may have a ``check_args(args)`` classmethod: given every argument of its
constructor (the positional-or-keyword ones, defaults filled in), it returns one sentence
per problem. Two callers ask it the same question: the spec check, before any node starts
(:func:`hera.nodes.boards.driver_problems`), and the constructor itself, which
:func:`checked_args` makes refuse what ``check_args`` finds before its body runs. Keyword-only
parameters (test hooks such as the SPI or I2C opener) are not the spec's and are left out.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping
from typing import Any, TypeVar

T = TypeVar("T", bound=type)


def constructor_args(cls: type, *args: Any, **kwargs: Any) -> dict[str, Any]:
    """The values a call ``cls(*args, **kwargs)`` gives ``cls``'s positional-or-keyword
    parameters, defaults filled in; TypeError when the call does not fit the signature."""
    sig = inspect.signature(cls)
    bound = sig.bind(*args, **kwargs)
    bound.apply_defaults()
    return {
        name: value
        for name, value in bound.arguments.items()
        if sig.parameters[name].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD
    }


def checked_args(cls: T) -> T:
    """Class decorator: ``cls``'s constructor raises ValueError, every problem that
    ``cls.check_args`` finds in its arguments joined by "; ", before its own body runs."""
    init = cls.__init__
    check = cls.check_args

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        problems = check(constructor_args(cls, *args, **kwargs))
        if problems:
            raise ValueError("; ".join(problems))
        init(self, *args, **kwargs)

    cls.__init__ = __init__
    return cls


def problems_of(cls: type, kwargs: Mapping[str, Any]) -> list[str]:
    """What ``cls.check_args`` finds in the arguments ``kwargs`` (known, none missing), or
    [] when the class has no ``check_args``."""
    check = getattr(cls, "check_args", None)
    if not callable(check):
        return []
    return list(check(constructor_args(cls, **kwargs)))
