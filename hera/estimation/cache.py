"""What the estimation cache holds, and its cleaning (``hera cache``, ``hera cache clean``).

The cache (:func:`.backend.cache_dir`) holds two kinds of entry:

- **kernel sets**: numba keeps an install's compiled kernels in a folder named after the
  absolute path of the folder that holds ``kernels_numba.py`` (``estimation_<sha1>``): every
  install (a venv, a checkout, a container layer) has its own, about 4 MB. Beside them,
  hera's markers ``hera-kernels-<hash>.done`` say a set is complete (JSON: the kernels'
  source file and names). hera writes ``hera-origin`` into the folder (the install's
  folder) and touches it whenever a process loads the kernels: the set's last use.
- **compiled models** (:mod:`.compiled`): ``models/ekf_step_<hash>.py``, its bytecode in
  ``models/__pycache__`` and its machine code in ``models_<sha1>/``, about 260 KB each; the
  ``.py`` is touched at each load.

numba never deletes anything. hera removes the kernel sets of installs whose folder no
longer exists when a new install compiles its kernels (they can never be loaded again);
``hera cache clean`` removes those, anything else unused for a number of days, or all.
Removing an entry is always safe: what is missing compiles again when next used.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

ORIGIN = "hera-origin"
"""The file in a kernel set's folder naming its install's folder; its mtime: the last use."""
KERNELS_SOURCE = "kernels_numba"
_KERNEL_DIR = re.compile(r"^estimation_[0-9a-f]{40}$")
_MODEL_DIR = re.compile(r"^models_[0-9a-f]{40}$")
_MODEL_FILE = re.compile(r"^(ekf_step_[0-9a-f]+)\.py$")
_MARKER = re.compile(r"^hera-kernels-[0-9a-f]+\.done$")
DAY = 86400.0
LOCK = "hera-kernels.lock"
"""The cache's lock file: held while kernels compile into the cache and while it is
cleaned."""


@contextlib.contextmanager
def locked(cache: Path) -> Iterator[None]:
    """The cache's lock (POSIX ``flock`` on :data:`LOCK`), exclusive between processes; a
    no-op where it cannot be had (no fcntl, a folder we cannot write)."""
    try:
        import fcntl

        f = open(cache / LOCK, "a+b")  # noqa: SIM115 - held for the with block below
    except (ImportError, OSError):
        yield
        return
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def numba_folder(source_file: str | os.PathLike[str]) -> str:
    """The folder numba caches the functions of ``source_file`` in, under its cache
    directory: the source's folder name and the SHA-1 of its absolute path (numba's
    ``get_suitable_cache_subpath``, unchanged since numba 0.49)."""
    folder = os.path.dirname(os.path.abspath(source_file))
    return f"{os.path.basename(folder)}_{hashlib.sha1(folder.encode()).hexdigest()}"


def record_use(cache: Path, source_file: str | os.PathLike[str]) -> None:
    """Note in the kernel set of ``source_file`` (if numba wrote it) that it was loaded now
    and from which install. A read-only cache is left alone."""
    folder = cache / numba_folder(source_file)
    origin = os.path.dirname(os.path.abspath(source_file))
    path = folder / ORIGIN
    with contextlib.suppress(OSError):
        if not folder.is_dir():
            return
        if path.is_file() and path.read_text().strip() == origin:
            os.utime(path)
        else:
            path.write_text(origin + "\n")


def touch(path: Path) -> None:
    """Mark a cached file as used now (nothing when the cache is read-only)."""
    with contextlib.suppress(OSError):
        os.utime(path)


def write_marker(marker: Path, source_file: str, names: Sequence[str]) -> None:
    """Write the marker that says every kernel of ``source_file`` is cached (OSError when
    the cache cannot be written)."""
    body = {"source": os.path.abspath(source_file), "kernels": list(names)}
    marker.write_text(json.dumps(body) + "\n")


@dataclass(frozen=True)
class Entry:
    """One entry of the cache (see the module docstring)."""

    kind: str
    """``"kernels"`` or ``"model"``."""
    name: str
    """Its folder (kernels) or file stem (model) under the cache."""
    origin: str | None
    """The install's folder (kernels) or the model's functions; None when not recorded
    (a kernel set compiled before hera recorded its origin)."""
    size: int
    """Bytes on disk, every file of the entry."""
    used: float
    """Its last use (s since the epoch): the last load recorded, else its newest file."""
    gone: bool
    """A kernel set whose install's folder no longer exists: it can never be loaded."""
    current: bool
    """The kernel set of the install this process runs."""
    paths: tuple[Path, ...]
    """What removing it deletes."""


def _size(paths: Iterable[Path]) -> int:
    total = 0
    for p in paths:
        with contextlib.suppress(OSError):
            if p.is_dir():
                total += sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
            else:
                total += p.stat().st_size
    return total


def _newest(paths: Iterable[Path]) -> float:
    newest = 0.0
    for p in paths:
        with contextlib.suppress(OSError):
            files = [f for f in p.rglob("*") if f.is_file()] if p.is_dir() else [p]
            newest = max([newest, *(f.stat().st_mtime for f in files)])
    return newest


def _markers(cache: Path) -> dict[str, list[Path]]:
    """hera's markers by the numba folder of the source they name ("" for a marker that
    names none: written before markers named their source, or unreadable)."""
    out: dict[str, list[Path]] = {}
    for p in cache.iterdir():
        if not _MARKER.match(p.name):
            continue
        try:
            source = json.loads(p.read_text())["source"]
            key = numba_folder(source)
        except (OSError, ValueError, KeyError, TypeError):
            key = ""
        out.setdefault(key, []).append(p)
    return out


def _model_origin(path: Path) -> str | None:
    """The functions a generated step names in its docstring (its "f = mod.fn" lines):
    ``mod: f, F, h, H`` when one module holds them all."""
    try:
        lines = path.read_text().splitlines()[1:8]
    except OSError:
        return None
    names = [ln.split(" = ", 1)[1] for ln in lines if re.match(r"^    [fFhH] = \S+$", ln)]
    if not names:
        return None
    modules = {n.rpartition(".")[0] for n in names}
    if len(modules) == 1:
        return f"{modules.pop()}: " + ", ".join(n.rpartition(".")[2] for n in names)
    return ", ".join(names)


def scan(cache: Path, current_source: str | None = None) -> list[Entry]:
    """Every entry of ``cache``, kernel sets first, then models, newest use first; the
    kernel set of ``current_source`` (this install's ``kernels_numba.py``) is ``current``.
    Folders that are not hera's (the user's own numba caches under ``NUMBA_CACHE_DIR``)
    are not listed."""
    if not cache.is_dir():
        return []
    here = numba_folder(current_source) if current_source else None
    markers = _markers(cache)
    kernels, models = [], []
    for p in sorted(cache.iterdir()):
        if _KERNEL_DIR.match(p.name) and any(p.glob(f"{KERNELS_SOURCE}.*")):
            origin_file = p / ORIGIN
            try:
                origin: str | None = origin_file.read_text().strip() or None
                used = origin_file.stat().st_mtime
            except OSError:
                origin, used = None, _newest([p])
            paths = (p, *markers.get(p.name, []))
            kernels.append(
                Entry(
                    "kernels",
                    p.name,
                    origin,
                    _size(paths),
                    used,
                    origin is not None and not os.path.isdir(origin),
                    p.name == here,
                    paths,
                )
            )
    model_dir = cache / "models"
    numba_dirs = [p for p in cache.iterdir() if _MODEL_DIR.match(p.name)]
    if model_dir.is_dir():
        for p in sorted(model_dir.iterdir()):
            m = _MODEL_FILE.match(p.name)
            if not m:
                continue
            stem = m.group(1)
            paths = (
                p,
                *sorted((model_dir / "__pycache__").glob(f"{stem}.*")),
                *(f for d in numba_dirs for f in sorted(d.glob(f"{stem}.*"))),
            )
            models.append(
                Entry(
                    "model",
                    stem,
                    _model_origin(p),
                    _size(paths),
                    p.stat().st_mtime,
                    False,
                    False,
                    paths,
                )
            )
    kernels.sort(key=lambda e: -e.used)
    models.sort(key=lambda e: -e.used)
    return kernels + models


def orphan_markers(cache: Path) -> list[Path]:
    """Markers whose kernel set is not in the cache (its folder deleted, or a marker that
    names no source): each would make a process believe its kernels are cached."""
    if not cache.is_dir():
        return []
    present = {p.name for p in cache.iterdir() if _KERNEL_DIR.match(p.name)}
    return [m for key, ms in _markers(cache).items() if key not in present for m in ms]


def choose(
    entries: Sequence[Entry], now: float, older_than_days: float | None, everything: bool
) -> list[Entry]:
    """The entries ``hera cache clean`` removes: all of them with ``everything``; else the
    kernel sets of installs that are gone, and every entry but this install's kernels that
    was not used for more than ``older_than_days`` (None: by age, none)."""
    if everything:
        return list(entries)
    out = []
    for e in entries:
        stale = older_than_days is not None and now - e.used > older_than_days * DAY
        if e.gone or (stale and not e.current):
            out.append(e)
    return out


def remove(entries: Iterable[Entry]) -> int:
    """Delete the entries' files and folders; returns the bytes freed, the sizes of the
    entries deleted whole (what could not be deleted is left, silently: a cache entry)."""
    freed = 0
    for e in entries:
        whole = True
        for p in e.paths:
            try:
                if p.is_dir():
                    shutil.rmtree(p)
                else:
                    p.unlink()
            except FileNotFoundError:  # gone already
                continue
            except OSError:  # not ours to delete
                whole = False
        freed += e.size if whole else 0
    return freed


def describe_age(used: float, now: float) -> str:
    """``today``, ``1 day ago``, ``12 days ago``."""
    days = int(max(0.0, now - used) // DAY)
    return "today" if days == 0 else f"{days} day{'s' if days > 1 else ''} ago"


def megabytes(size: int) -> str:
    """``4.3 MB`` (or ``260 KB`` below a megabyte)."""
    return f"{size / 1e6:.1f} MB" if size >= 1e6 else f"{size / 1e3:.0f} KB"


def prune_gone(cache: Path) -> tuple[int, int]:
    """Remove the kernel sets of installs whose folder no longer exists, and orphaned
    markers; returns (sets removed, bytes freed)."""
    gone = [e for e in scan(cache) if e.gone]
    freed = remove(gone)
    remove_orphan_markers(cache)
    return len(gone), freed


def remove_orphan_markers(cache: Path) -> None:
    """Delete the :func:`orphan_markers` (what cannot be deleted stays)."""
    for m in orphan_markers(cache):
        with contextlib.suppress(OSError):
            m.unlink()
