"""What of the old code a hot reload's carried-over state holds, moved to the new code.

After ``hera reload`` a fusion measure of the new code takes over the old model's
attributes (:func:`hera.fusion.adopt_model`). Held as they are, parts of them would go on
running the old code: the old model's methods a filter keeps as its ``f`` and ``h``, the
reloaded modules' functions, objects of the reloaded classes (settings, a filter of the
model's own code); and pickle refuses them (the class or function its module names now is
another object), so no checkpoint could be written. :func:`rebind` moves them over;
:func:`superseded` tells an object of a class loaded anew.
"""

from __future__ import annotations

import contextlib
import enum
import sys
import threading
import types
from collections import deque
from collections.abc import Iterator
from typing import Any


def rebind(value: Any, old: Any, new: Any, seen: set[int] | None = None) -> Any:
    """``value`` with every method bound to ``old`` found in it (in dicts, lists, tuples,
    deques and the attributes of objects, in place where they are mutable, the objects of
    :data:`_FOREIGN` libraries left alone) replaced by ``new``'s method of that name, and
    every module-level function its module now names by another, by that one. A
    model's filter keeps the model's own ``f`` and ``h`` (bound methods): carried over as
    they are, they would go on running the old code on the old instance after a reload."""
    seen = set() if seen is None else seen
    if isinstance(value, types.MethodType):
        if value.__self__ is old:
            return getattr(new, value.__func__.__name__, value)
        if value.__self__ is type(old):  # a class method
            return getattr(type(new), value.__func__.__name__, value)
        return value
    if isinstance(value, types.FunctionType):  # a module's function, perhaps loaded anew
        module = sys.modules.get(value.__module__)
        if module is None or value.__globals__ is vars(module):
            return value  # its module was not loaded anew
        now = _named(value)
        return now if isinstance(now, types.FunctionType) else value
    if id(value) in seen or isinstance(value, _OPAQUE):
        return value
    if type(value).__module__.partition(".")[0] in _FOREIGN:
        return value
    seen.add(id(value))
    if isinstance(value, dict):
        for k, v in list(value.items()):
            if (w := rebind(v, old, new, seen)) is not v:
                value[k] = w
    elif isinstance(value, (list, deque)):
        for i, v in enumerate(list(value)):
            if (w := rebind(v, old, new, seen)) is not v:
                value[i] = w
    elif isinstance(value, tuple):
        items = [rebind(v, old, new, seen) for v in value]
        if any(a is not b for a, b in zip(items, value, strict=True)):
            return type(value)(items) if type(value) is tuple else type(value)(*items)
    elif hasattr(value, "__dict__") and not isinstance(value, (type, types.ModuleType)):
        upgrade(value)
        rebind(vars(value), old, new, seen)
    return value


def upgrade(obj: object) -> None:
    """Give ``obj`` the class its module's name gives now, if a hot reload loaded that
    class anew (a part of the old model: its settings, a filter of the model's own code), so
    the new code runs on it and it pickles; left as it is where Python refuses the change
    (another memory layout) and for enum members (compared by identity)."""
    now = _named(type(obj))
    if not isinstance(now, type) or now is type(obj) or isinstance(obj, enum.Enum):
        return
    with contextlib.suppress(TypeError):
        object.__setattr__(obj, "__class__", now)  # past a frozen dataclass's __setattr__


_OPAQUE = (str, bytes, int, float, complex, bool, type(None))
_FOREIGN = frozenset({"numpy", "numba", "llvmlite"})
"""Libraries whose objects :func:`rebind` does not look into (a compiled kernel's
dispatcher holds the compiler's state, and dicts that refuse a key set twice)."""


_reloads_lock = threading.Lock()
_reloads = 0
"""Changes at the start and at the end of every reload (:func:`reloads`)."""
_reloading = 0
"""Reloads under way (each has modules out of ``sys.modules``)."""


@contextlib.contextmanager
def reloading() -> Iterator[None]:
    """Mark the time ``hera reload`` has modules out of ``sys.modules`` (loading their new
    code, or putting the old back): pickle, looking a class up by its module's name then,
    imports the module's source itself and fails if the new code does not load."""
    global _reloads, _reloading
    with _reloads_lock:
        _reloads += 1
        _reloading += 1
    try:
        yield
    finally:
        with _reloads_lock:
            _reloads += 1
            _reloading -= 1


def reloads() -> int:
    """The reload count to give :func:`superseded` (read before the work it may spoil)."""
    return _reloads


def superseded(obj: object, since: int | None = None) -> bool:
    """True if ``obj``'s class is no longer what its module's name gives (``hera reload``
    loaded the module anew), or, given ``since`` (:func:`reloads` read before a pickle
    failed), if a reload was under way at any time since: pickle refuses such an object, and
    the measure holding it is about to be replaced by the new code's (or the reload of code
    that did not load has put the old back), so its checkpoint is skipped, not given up."""
    if since is not None and (_reloading or _reloads != since):
        return True
    cls = type(obj)
    return sys.modules.get(cls.__module__) is not None and _named(cls) is not cls


def _named(thing: Any) -> Any:
    """What the module and qualified name of a class or function ``thing`` give now (None:
    nothing, as for a lambda or a local function)."""
    found: Any = sys.modules.get(thing.__module__)
    for part in thing.__qualname__.split("."):
        found = getattr(found, part, None)
    return found
