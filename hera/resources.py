"""Objects the measures of one node share, by key: boards, a simulated medium, a cache.

Each node (and each test) has its own :class:`Resources`, handed to every measure as
``ctx.resources``; nothing is process-global, so two nodes in one process (or two tests)
never see each other's boards. A resource outlives the measures that use it: a restarted
measure finds the same board, with any fault still on. :meth:`Resources.close` closes every
resource that has a ``close()`` method, newest first, when the node stops.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")
log = logging.getLogger("hera.resources")


class Resources:
    """A thread-safe keyed registry of shared objects (see the module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._items: dict[str, Any] = {}

    def get(self, key: str, default: Any = None) -> Any:
        """The resource under ``key``, or ``default``."""
        with self._lock:
            return self._items.get(key, default)

    def put(self, key: str, value: Any) -> Any:
        """Add or replace the resource under ``key``; returns it."""
        with self._lock:
            self._items[key] = value
        return value

    def get_or_create(self, key: str, factory: Callable[[], T]) -> T:
        """The resource under ``key``, made by ``factory()`` on first use (once, even when
        several measures ask at the same time)."""
        with self._lock:
            if key not in self._items:
                self._items[key] = factory()
            return self._items[key]

    def keys(self, prefix: str = "") -> list[str]:
        """The keys held that start with ``prefix``, sorted."""
        with self._lock:
            return sorted(k for k in self._items if k.startswith(prefix))

    @property
    def lock(self) -> threading.RLock:
        """The registry's lock, for callers that must check and create atomically."""
        return self._lock

    def close(self) -> None:
        """Close every resource that has ``close()`` (newest first) and forget them all."""
        with self._lock:
            items = list(self._items.items())
            self._items.clear()
        for key, value in reversed(items):
            close = getattr(value, "close", None)
            if callable(close):
                with contextlib.suppress(Exception):
                    close()
                log.debug("closed resource %s", key)
