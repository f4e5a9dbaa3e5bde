"""Backend selection: compiled numba kernels when available, the numpy code otherwise.

``HERA_ESTIMATION_BACKEND`` = ``numpy`` | ``numba`` | ``auto`` (default: numba if it can be
imported, else numpy) is read when the first filter is made; ``set_backend`` switches at
run time, ``prefer`` records a choice to apply then (a node that runs no filter never
imports numba), and ``backend()`` says which one is active. numba is a core dependency on
the platforms it publishes wheels for; without it everything runs on the numpy path, with
the same results (to roundoff) and the same errors.

Compiled once per machine: the first process that selects numba compiles every kernel
(30-60 s on a 2-core machine), printing one line to stderr before and one after, and
numba stores the machine code in :func:`cache_dir` (a per-user directory, so a read-only
site-packages is fine); a marker file there records the complete set, and later processes
load the kernels from the cache in well under a second. Processes that start at the same
time compile once between them (a lock file in the cache directory). ``warmup()`` loads
every kernel up front and returns the time it took.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "BACKENDS",
    "CACHE_ENV",
    "ENV_VAR",
    "active_backend",
    "active_kernels",
    "backend",
    "cache_dir",
    "prefer",
    "set_backend",
    "warmup",
]

ENV_VAR = "HERA_ESTIMATION_BACKEND"
CACHE_ENV = "HERA_CACHE_DIR"
BACKENDS = ("auto", "numba", "numpy")

_UNRESOLVED: Any = object()
_active: Any = _UNRESOLVED  # a _Kernels instance (numba) or None (numpy)
_preferred: str | None = None  # set by prefer(); else the environment variable decides
_kernels: _Kernels | None = None
_lock = threading.RLock()


def cache_dir() -> Path:
    """Where numba keeps the compiled kernels: ``NUMBA_CACHE_DIR`` when the user set it
    (numba's own setting wins), else ``$HERA_CACHE_DIR/numba``, ``$XDG_CACHE_HOME/hera/numba``
    or ``~/.cache/hera/numba``. Never inside the installed package, so a read-only
    site-packages (a system or container install) keeps its cache all the same."""
    numba_dir = os.environ.get("NUMBA_CACHE_DIR")
    if numba_dir:
        return Path(numba_dir)
    base = os.environ.get(CACHE_ENV)
    if base:
        return Path(base) / "numba"
    xdg = os.environ.get("XDG_CACHE_HOME")
    root = Path(xdg) if xdg else Path.home() / ".cache"
    return root / "hera" / "numba"


@contextlib.contextmanager
def _numba_cache_dir(path: Path) -> Iterator[None]:
    """numba's cache directory set to ``path`` while kernels are decorated (numba picks a
    function's cache location then): it applies to our kernels only, not to the user's own
    numba functions, and needs no environment variable set before numba is imported."""
    from numba.core import config

    old = config.CACHE_DIR
    config.CACHE_DIR = str(path)
    try:
        yield
    finally:
        config.CACHE_DIR = old


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` between processes (POSIX ``flock``); a no-op where it
    cannot be had (no fcntl, a directory we cannot write)."""
    try:
        import fcntl

        f = open(path, "a+b")  # noqa: SIM115 - held for the with block below
    except (ImportError, OSError):
        yield
        return
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


class _Kernels:
    """Namespace of compiled kernels; an attribute is compiled (or loaded from the cache)
    on first access and then stored on the instance, so later lookups are plain."""

    def __init__(self) -> None:
        import numba  # noqa: F401 - ImportError: no numba, the numpy path runs

        self.cache = cache_dir()
        with contextlib.suppress(OSError):
            self.cache.mkdir(parents=True, exist_ok=True)
        with _numba_cache_dir(self.cache):
            from . import kernels_numba
        self._mod = kernels_numba

    def __getattr__(self, name: str) -> Any:
        import numba

        sigs = self._mod.SIGNATURES
        if name not in sigs:
            raise AttributeError(name)
        with _lock:
            fn = self.__dict__.get(name)
            if fn is not None:
                return fn
            opts = dict(self._mod.OPTIONS)
            if name in self._mod.NO_NRT:
                opts["_nrt"] = False
            with _numba_cache_dir(self.cache):
                fn = numba.njit(sigs[name], **opts)(getattr(self._mod, name))
            setattr(self, name, fn)
            return fn

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._mod.SIGNATURES)

    def marker(self) -> Path:
        """The file that says every kernel of this source, numba, Python and CPU is in the
        cache (a different one of any of these compiles again, as numba would)."""
        import numba

        h = hashlib.sha256(Path(self._mod.__file__).read_bytes())
        h.update(f"{numba.__version__} {sys.version} {sys.platform}".encode())
        with contextlib.suppress(Exception):  # the CPU numba compiles for (name, features)
            from numba.core.registry import cpu_target

            h.update(repr(cpu_target.target_context.codegen().magic_tuple()).encode())
        return self.cache / f"hera-kernels-{h.hexdigest()[:16]}.done"

    def load_all(self) -> float:
        """Compile or load every kernel; the first time on this machine (no marker) with a
        line on stderr before and after. Returns the seconds spent."""
        t0 = time.perf_counter()
        marker = self.marker()
        if not marker.exists():
            with _file_lock(self.cache / "hera-kernels.lock"):
                if not marker.exists():  # nobody compiled them while we waited
                    self._compile_all(marker)
        for name in self.names:
            getattr(self, name)
        return time.perf_counter() - t0

    def _compile_all(self, marker: Path) -> None:
        names = self.names
        print(
            f"hera.estimation: compiling {len(names)} numba kernels for this machine, once "
            f"(30-60 s; cached in {self.cache}) ...",
            file=sys.stderr,
            flush=True,
        )
        t0 = time.perf_counter()
        for name in names:
            getattr(self, name)
        spent = time.perf_counter() - t0
        try:
            marker.write_text(" ".join(names) + "\n")
            where = f"cached in {self.cache}"
        except OSError as e:
            where = f"not cached: {e}"
        print(
            f"hera.estimation: numba kernels compiled in {spent:.1f} s ({where})",
            file=sys.stderr,
            flush=True,
        )


def _numba_kernels() -> _Kernels | None:
    """The compiled kernels, every one loaded (compiled the first time on this machine), or
    None when numba cannot be imported."""
    global _kernels
    with _lock:
        if _kernels is None:
            try:
                k = _Kernels()
            except ImportError:
                return None
            k.load_all()
            _kernels = k
    return _kernels


def _check_name(name: str) -> str:
    name = name.strip().lower() or "auto"
    if name not in BACKENDS:
        raise ValueError(f"unknown estimation backend {name!r}; choose one of {BACKENDS}")
    return name


def set_backend(name: str) -> str:
    """Select ``"numpy"``, ``"numba"`` or ``"auto"`` now; returns the backend now active.

    Raises ImportError for ``"numba"`` when numba is not installed, ValueError for an
    unknown name.
    """
    global _active
    name = _check_name(name)
    if name == "numpy":
        _active = None
    else:
        k = _numba_kernels()
        if k is None and name == "numba":
            raise ImportError("the numba backend needs numba: pip install numba")
        _active = k
    return backend()


def prefer(name: str) -> None:
    """Select ``name`` (as ``set_backend``) when the first filter is made, not now: nothing
    is imported or compiled for a process that never makes one (once a filter exists, the
    choice applies at once). ValueError for an unknown name."""
    global _preferred
    name = _check_name(name)
    with _lock:
        _preferred = name
        if _active is not _UNRESOLVED:  # a filter exists already: the choice applies now
            set_backend(name)


def active_kernels() -> Any:
    """The compiled kernel namespace, or None when the numpy path is active. Resolves the
    preferred backend (``prefer``, else the environment variable) on first call."""
    k = _active
    if k is _UNRESOLVED:
        with _lock:
            if _active is _UNRESOLVED:
                set_backend(_preferred or os.environ.get(ENV_VAR, "auto"))
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
    return k.load_all()
