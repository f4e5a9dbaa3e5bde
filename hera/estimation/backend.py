"""Backend selection: compiled numba kernels when available, the numpy code otherwise.

``HERA_ESTIMATION_BACKEND`` = ``numpy`` | ``numba`` | ``auto`` (default: numba if it can be
imported, else numpy) is read at the first filter step; ``set_backend`` switches at run
time and ``backend()`` says which one is active. numba is an optional dependency
(``hera-fusion[fast]``): without it everything runs on the numpy path, with the same
results (to roundoff) and the same errors.

Kernels are compiled lazily, one by one, at their first use, with ``cache=True`` (numba
stores the machine code next to ``kernels_numba.py`` or under ``NUMBA_CACHE_DIR``, so later
processes load it in milliseconds). ``warmup()`` compiles or loads all of them up front,
e.g. while a node starts, and returns the time it took.
"""

from __future__ import annotations

import os
import time
from typing import Any

__all__ = [
    "BACKENDS",
    "ENV_VAR",
    "active_backend",
    "active_kernels",
    "backend",
    "set_backend",
    "warmup",
]

ENV_VAR = "HERA_ESTIMATION_BACKEND"
BACKENDS = ("auto", "numba", "numpy")

_UNRESOLVED: Any = object()
_active: Any = _UNRESOLVED  # a _Kernels instance (numba) or None (numpy)
_kernels: _Kernels | None = None


class _Kernels:
    """Namespace of compiled kernels; an attribute is compiled (or loaded from the cache)
    on first access and then stored on the instance, so later lookups are plain."""

    def __init__(self) -> None:
        from . import kernels_numba

        self._mod = kernels_numba

    def __getattr__(self, name: str) -> Any:
        import numba

        sigs = self._mod.SIGNATURES
        if name not in sigs:
            raise AttributeError(name)
        # error_model="numpy": a division by zero gives inf/nan (which the kernels test
        # for) instead of a check and a Python exception on every division.
        opts = {"_nrt": False} if name in self._mod.NO_NRT else {}
        fn = numba.njit(sigs[name], cache=True, error_model="numpy", **opts)(
            getattr(self._mod, name)
        )
        setattr(self, name, fn)
        return fn

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._mod.SIGNATURES)


def _numba_kernels() -> _Kernels | None:
    global _kernels
    if _kernels is None:
        try:
            _kernels = _Kernels()
        except ImportError:
            return None
    return _kernels


def set_backend(name: str) -> str:
    """Select ``"numpy"``, ``"numba"`` or ``"auto"``; returns the backend now active.

    Raises ImportError for ``"numba"`` when numba is not installed, ValueError for an
    unknown name.
    """
    global _active
    name = name.strip().lower() or "auto"
    if name not in BACKENDS:
        raise ValueError(f"unknown estimation backend {name!r}; choose one of {BACKENDS}")
    if name == "numpy":
        _active = None
    else:
        k = _numba_kernels()
        if k is None and name == "numba":
            raise ImportError("the numba backend needs numba: pip install 'hera-fusion[fast]'")
        _active = k
    return backend()


def active_kernels() -> Any:
    """The compiled kernel namespace, or None when the numpy path is active. Resolves the
    environment variable on first call."""
    k = _active
    if k is _UNRESOLVED:
        set_backend(os.environ.get(ENV_VAR, "auto"))
        k = _active
    return k


def backend() -> str:
    """Name of the active backend: ``"numba"`` or ``"numpy"``."""
    return "numpy" if active_kernels() is None else "numba"


active_backend = backend  # exported by the package under this name


def warmup() -> float:
    """Compile (or load from the cache) every kernel of the active backend now; returns
    the seconds spent (0.0 on the numpy backend)."""
    k = active_kernels()
    if k is None:
        return 0.0
    t0 = time.perf_counter()
    for name in k.names:
        getattr(k, name)
    return time.perf_counter() - t0
