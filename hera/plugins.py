"""Finding plugins: measures, applications and node services, all through entry points.

- ``hera.measures``: measure classes, by name (or ``package.module:Class`` directly);
- ``hera.apps``: :class:`hera.application.Application` subclasses;
- ``hera.services``: node services (see :mod:`hera.services`), started by every node.

The runtime knows plugins only through these groups: it never imports an application, a
model or the simulator by name.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from functools import cache
from importlib.metadata import entry_points
from typing import Any

from hera.application import Application
from hera.measure import Measure

MEASURES = "hera.measures"
APPS = "hera.apps"
SERVICES = "hera.services"


class UnknownMeasure(LookupError):
    """No measure of that name; the message lists the known ones."""


class PluginError(LookupError):
    """A plugin that is registered but cannot be loaded; the message says which and why."""


def known_measures() -> dict[str, str]:
    """Every measure registered in the ``hera.measures`` entry-point group: name -> target."""
    return {ep.name: ep.value for ep in entry_points(group=MEASURES)}


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
        eps = [ep for ep in entry_points(group=MEASURES) if ep.name == use]
        if not eps:
            from hera.schema import did_you_mean

            known = ", ".join(sorted(known_measures())) or "none installed"
            raise UnknownMeasure(
                f"unknown measure {use!r}{did_you_mean(use, known_measures())}; known "
                f"measures: {known} (or give 'package.module:Class')"
            )
        try:
            target = eps[0].load()
        except Exception as e:
            raise PluginError(f"measure {use!r} ({eps[0].value}) cannot be loaded: {e}") from e
    if not (isinstance(target, type) and issubclass(target, Measure)):
        raise TypeError(f"measure {use!r} is {target!r}, not a subclass of hera.measure.Measure")
    return target


def known_apps() -> dict[str, str]:
    """Every application registered in ``hera.apps``: name -> target."""
    return {ep.name: ep.value for ep in entry_points(group=APPS)}


@cache
def _load_app(name: str, target: str) -> Application:
    ep = next(ep for ep in entry_points(group=APPS) if ep.name == name and ep.value == target)
    try:
        obj = ep.load()
    except Exception as e:
        raise PluginError(f"application {name!r} ({target}) cannot be loaded: {e}") from e
    app = obj() if isinstance(obj, type) else obj
    if not isinstance(app, Application):
        raise PluginError(
            f"application {name!r} ({target}) is {obj!r}, not a hera.application.Application"
        )
    return app


def load_app(name: str) -> Application:
    """The application registered as ``name`` (LookupError listing the known ones)."""
    apps = known_apps()
    if name not in apps:
        known = ", ".join(sorted(apps)) or "none installed"
        raise LookupError(f"unknown application {name!r}; installed applications: {known}")
    return _load_app(name, apps[name])


def installed_apps() -> list[Application]:
    """Every installed application, by name."""
    return [_load_app(n, t) for n, t in sorted(known_apps().items())]


class AppIndex:
    """Which application a measure class belongs to, and its rank within it (the order
    the application lists its measures in)."""

    def __init__(self, apps: Iterable[Application] | None = None) -> None:
        self.apps = list(installed_apps() if apps is None else apps)
        self._of: dict[type, tuple[Application, int]] = {}
        for app in self.apps:
            for rank, use in enumerate(app.measures):
                try:
                    cls = find_measure(use)
                except (LookupError, TypeError) as e:
                    raise PluginError(
                        f"application {app.name!r} lists measure {use!r}, which does not load: {e}"
                    ) from None
                self._of.setdefault(cls, (app, rank))

    def app_of(self, cls: type | None) -> Application | None:
        """The application measure class ``cls`` belongs to, or None."""
        hit = self._of.get(cls) if cls is not None else None
        return hit[0] if hit else None

    def rank(self, cls: type | None) -> tuple[str, int]:
        """A sort key: (application name, position in its list); unknown classes last."""
        hit = self._of.get(cls) if cls is not None else None
        return (hit[0].name, hit[1]) if hit else ("~", 0)

    def label(self, name: str, cls: type | None) -> str:
        """The label its application gives output ``name`` (the name if none)."""
        app = self.app_of(cls)
        return app.label(name, cls) if app is not None else name


def find_verb(verb: str) -> Any:
    """The control verb ``verb`` added by an installed application, or None."""
    for app in installed_apps():
        handler = app.verbs().get(verb)
        if handler is not None:
            return handler
    return None


def service_factories() -> dict[str, Any]:
    """Every registered node service factory (``hera.services``), by name."""
    out = {}
    for ep in entry_points(group=SERVICES):
        try:
            out[ep.name] = ep.load()
        except Exception as e:
            raise PluginError(f"node service {ep.name!r} ({ep.value}) cannot be loaded: {e}") from e
    return out
