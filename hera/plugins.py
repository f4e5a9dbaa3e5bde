"""Finding measure classes: by entry-point name (group ``hera.measures``) or ``module:Class``."""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from hera.measure import Measure

GROUP = "hera.measures"


class UnknownMeasure(LookupError):
    """No measure of that name; the message lists the known ones."""


def known_measures() -> dict[str, str]:
    """Every measure registered in the ``hera.measures`` entry-point group: name -> target."""
    return {ep.name: ep.value for ep in entry_points(group=GROUP)}


def find_measure(use: str) -> type[Measure]:
    """The measure class named ``use`` (an entry-point name or ``package.module:Class``).

    Raises UnknownMeasure (listing the known names) or TypeError if the target is not a
    Measure subclass.
    """
    if ":" in use:
        module_name, _, attr = use.partition(":")
        try:
            target = getattr(importlib.import_module(module_name), attr)
        except (ImportError, AttributeError) as e:
            raise UnknownMeasure(f"cannot load measure {use!r}: {e}") from None
    else:
        eps = [ep for ep in entry_points(group=GROUP) if ep.name == use]
        if not eps:
            known = ", ".join(sorted(known_measures())) or "none installed"
            raise UnknownMeasure(
                f"unknown measure {use!r}; known measures: {known} (or give 'package.module:Class')"
            )
        target = eps[0].load()
    if not (isinstance(target, type) and issubclass(target, Measure)):
        raise TypeError(f"measure {use!r} is {target!r}, not a subclass of hera.measure.Measure")
    return target
