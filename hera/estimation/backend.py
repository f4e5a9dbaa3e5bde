"""Backend selection: compiled numba kernels when available, the numpy code otherwise.

``HERA_ESTIMATION_BACKEND`` = ``numpy`` | ``numba`` | ``auto`` (default: numba if it can be
imported, else numpy) is read when the first filter is made; ``set_backend`` switches at
run time, ``prefer`` records a choice to apply then (a node that runs no filter never
imports numba), and ``backend()`` says which one is active. numba is a core dependency on
the platforms it publishes wheels for; without it everything runs on the numpy path, with
the same results (to roundoff) and the same errors.

Compiled once per machine: the first process that selects numba compiles every kernel
(20-50 s on a 2-core machine), printing one line to stderr before and one after, and
numba stores the machine code in :func:`cache_dir` (a per-user directory, so a read-only
site-packages is fine); a marker file there records the complete set, and later processes
load the kernels from the cache in well under a second. Processes that start at the same
time compile once between them (a lock file in the cache directory). The compile is shared
between up to ``HERA_COMPILE_JOBS`` processes (default: the CPU count, at most 4): helper
processes compile their share into the cache and this one loads it from there (45 s in one
process, 21-24 s in two, measured on a 2-vCPU machine); a helper that fails leaves its share
to this process. ``warmup()`` loads every kernel up front and returns the time it took.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from . import cache as _cache

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
JOBS_ENV = "HERA_COMPILE_JOBS"
MAX_JOBS = 4
HELPER_TIMEOUT_S = 900.0
# Seconds each kernel takes to compile (2-vCPU Intel Xeon, numba 0.68, one process, in this
# order; lin_update1's after kf_step's, which compiles the helper they share): only used to
# share the compile fairly between processes (longest first, each to the least loaded); a
# kernel missing here counts as 1 s.
COMPILE_SECONDS = {
    "ekf_step": 17.8,
    "kf_step": 16.6,
    "lin_update1": 5.8,
    "lin_update": 7.0,
    "ukf_update_dev": 3.4,
    "ukf_update": 3.0,
    "kf_predict": 1.9,
    "ekf_predict": 1.5,
    "kf_predict_u": 1.0,
    "ukf_predict": 0.7,
    "ukf_sigmas": 0.4,
    "ukf_predict_dev": 0.4,
}
# Kernels that call one compiled helper with the same argument types (``_update_rows``):
# compiled in one process, the helper is compiled once for them (lin_update1 then takes
# 5.8 s instead of 12.9 s alone).
TOGETHER = (("kf_step", "lin_update1"),)
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


class _Kernels:
    """Namespace of compiled kernels; an attribute is compiled (or loaded from the cache)
    on first access and then stored on the instance, so later lookups are plain."""

    def __init__(self, cache: Path | None = None) -> None:
        import numba  # noqa: F401 - ImportError: no numba, the numpy path runs

        self.cache = cache_dir() if cache is None else cache
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
        cache (a different one of any of these compiles again, as numba would). numba keys
        its cache by the source file's absolute path too (another install or checkout of the
        same version compiles again): so does the marker, or that compile would run silently,
        one kernel after the other, in one process."""
        import numba

        source = os.path.abspath(self._mod.__file__)  # as numba's cache locator takes it
        h = hashlib.sha256(Path(source).read_bytes())
        h.update(source.encode())
        h.update(f"{numba.__version__} {sys.version} {sys.platform}".encode())
        with contextlib.suppress(Exception):  # the CPU numba compiles for (name, features)
            from numba.core.registry import cpu_target

            h.update(repr(cpu_target.target_context.codegen().magic_tuple()).encode())
        return self.cache / f"hera-kernels-{h.hexdigest()[:16]}.done"

    def _cached(self, marker: Path) -> bool:
        """Whether the marker says the kernels are cached and numba's folder for them is
        there (a folder deleted by hand leaves a marker that would lie)."""
        return marker.exists() and (self.cache / _cache.numba_folder(self._mod.__file__)).is_dir()

    def load_all(self) -> float:
        """Compile or load every kernel; the first time on this machine (no marker) with a
        line on stderr before and after. Records the use in the cache (its last use, for
        ``hera cache clean``). Returns the seconds spent."""
        t0 = time.perf_counter()
        marker = self.marker()
        if not self._cached(marker):
            with _cache.locked(self.cache):
                if not self._cached(marker):  # nobody compiled them while we waited
                    self._compile_all(marker)
        for name in self.names:
            getattr(self, name)
        _cache.record_use(self.cache, self._mod.__file__)
        return time.perf_counter() - t0

    def _compile_all(self, marker: Path) -> None:
        names = self.names
        jobs = compile_jobs(len(names))
        shared = f"in {jobs} processes, " if jobs > 1 else ""
        print(
            f"hera.estimation: compiling {len(names)} numba kernels for this machine, once "
            f"({shared}20-50 s; cached in {self.cache}) ...",
            file=sys.stderr,
            flush=True,
        )
        t0 = time.perf_counter()
        failed = compile_shared(
            names,
            jobs,
            lambda name: getattr(self, name),
            lambda share: _spawn_helper(share, self.cache),
        )
        for share, code in failed:
            print(
                f"hera.estimation: a compile helper ended with code {code}; "
                f"compiling {', '.join(share)} here",
                file=sys.stderr,
                flush=True,
            )
        for name in names:  # the helpers' shares load from the cache, a failed one's compile
            getattr(self, name)
        spent = time.perf_counter() - t0
        try:
            _cache.write_marker(marker, self._mod.__file__, names)
            where = f"cached in {self.cache}"
        except OSError as e:
            where = f"not cached: {e}"
        print(
            f"hera.estimation: numba kernels compiled in {spent:.1f} s ({where})",
            file=sys.stderr,
            flush=True,
        )
        count, freed = _cache.prune_gone(self.cache)
        if count:
            print(
                "hera.estimation: removed from the cache the kernels of "
                + (
                    "1 install that no longer exists"
                    if count == 1
                    else f"{count} installs that no longer exist"
                )
                + f" ({_cache.megabytes(freed)})",
                file=sys.stderr,
                flush=True,
            )


def compile_jobs(count: int) -> int:
    """How many processes compile ``count`` kernels: ``HERA_COMPILE_JOBS`` if set (a whole
    number >= 1; ValueError naming the variable otherwise), else the CPU count, at most
    ``MAX_JOBS`` and at most ``count``."""
    raw = os.environ.get(JOBS_ENV, "").strip()
    if raw:
        try:
            jobs = int(raw)
        except ValueError:
            jobs = 0
        if jobs < 1:
            raise ValueError(f"{JOBS_ENV}={raw!r}: expected a whole number of processes >= 1")
    else:
        jobs = min(os.cpu_count() or 1, MAX_JOBS)
    return max(1, min(jobs, count))


def shares(names: Sequence[str], jobs: int) -> list[list[str]]:
    """``names`` split into ``jobs`` shares of about equal compile time: the longest unit
    first, each to the share with the least so far (``COMPILE_SECONDS``); a unit is one
    kernel, or the kernels of a ``TOGETHER`` group, kept in one share. Share 0 is the one
    with the most work, kept by the calling process."""
    units: list[list[str]] = []
    left = list(names)
    for group in TOGETHER:
        unit = [n for n in left if n in group]
        if unit:
            units.append(unit)
            left = [n for n in left if n not in group]
    units += [[n] for n in left]
    out: list[list[str]] = [[] for _ in range(jobs)]
    load = [0.0] * jobs
    for unit in sorted(units, key=lambda u: -unit_seconds(u)):
        i = load.index(min(load))
        out[i] += unit
        load[i] += unit_seconds(unit)
    return [s for _, s in sorted(zip(load, out, strict=True), key=lambda p: -p[0]) if s]


def unit_seconds(names: Sequence[str]) -> float:
    """The compile time of ``names`` in one process, by ``COMPILE_SECONDS``."""
    return sum(COMPILE_SECONDS.get(n, 1.0) for n in names)


def compile_shared(
    names: Sequence[str],
    jobs: int,
    compile_here: Callable[[str], Any],
    spawn: Callable[[list[str]], subprocess.Popen],
) -> list[tuple[list[str], int]]:
    """Compile ``names`` in ``jobs`` processes: ``spawn(share)`` starts a helper for every
    share but the first, ``compile_here(name)`` compiles the first share in this process
    meanwhile; then waits for the helpers (``HELPER_TIMEOUT_S`` each, killed after it).
    Returns (share, exit code) of each helper that did not succeed (its kernels are left to
    the caller); a helper that cannot even be started is one with code -1."""
    parts = shares(names, jobs)
    helpers: list[tuple[list[str], subprocess.Popen | None]] = []
    for share in parts[1:]:
        try:
            helpers.append((share, spawn(share)))
        except OSError:
            helpers.append((share, None))
    failed: list[tuple[list[str], int]] = []
    try:
        for name in parts[0] if parts else []:
            compile_here(name)
    finally:
        for share, proc in helpers:
            if proc is None:
                failed.append((share, -1))
                continue
            try:
                code = proc.wait(HELPER_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = proc.wait()
            if code != 0:
                failed.append((share, code))
    return failed


def _spawn_helper(share: list[str], cache: Path) -> subprocess.Popen:
    """A process that compiles ``share`` into ``cache`` (:func:`_compile_names`), importing
    this very copy of hera (its kernels' source file is numba's cache key): not the working
    folder's (``python -c`` puts it first on the path: run from a source checkout, that
    would import the checkout's ``hera``, which refuses to load beside an install), and the
    folder that holds this ``hera`` goes first on the helper's path unless it is there
    already (an installed package's site-packages is, and keeps its place after the
    standard library)."""
    root = str(Path(__file__).resolve().parents[2])
    code = (
        "import sys; del sys.path[0]; r = sys.argv[1]; r in sys.path or sys.path.insert(0, r); "
        "from hera.estimation.backend import _compile_names; "
        "_compile_names(sys.argv[2], sys.argv[3:])"
    )
    return subprocess.Popen(
        [sys.executable, "-c", code, root, str(cache), *share],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def _compile_names(cache: str, names: Sequence[str]) -> None:
    """A compile helper's work: compile ``names`` into ``cache`` (numba writes the cache)."""
    k = _Kernels(Path(cache))
    for name in names:
        getattr(k, name)


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
