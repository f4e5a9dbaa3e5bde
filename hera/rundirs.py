"""Run directories: one per run, never mixed, and where a cluster keeps its state.

- :func:`new_run_dir`: ``hera-run/<cluster>-<YYYYmmdd-HHMMSS>`` (a new folder for every
  ``hera up``), and ``hera-run/<cluster>`` becomes a link to the latest one, so
  ``hera eval hera-run/train`` scores the last run;
- :func:`prepare_run_dir`: a run directory given by hand must be new or empty; one that
  holds a previous run is refused unless ``overwrite`` (then its records are deleted first,
  but not its ``state/``: the nodes' persisted args, which a new run of the cluster keeps);
- :func:`state_dir`: the replicated args each node persists (calibrations) live beside the
  runs, in ``hera-run/<cluster>.state/``, so a new run of the same cluster keeps them; a run
  directory given by hand keeps its state inside it (``<run-dir>/state``).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

BASE = Path("hera-run")
MARK = "cluster.json"
"""A folder holding this file is a run directory (``hera up`` writes it first)."""


class RunDirError(ValueError):
    """A run directory that cannot be used; the message says why and what to do."""


def _make(path: Path, what: str) -> None:
    """``path`` and its parents made (an existing folder is fine); RunDirError naming the
    folder and the system's reason when it cannot be (read-only, not a folder, no space)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunDirError(f"cannot make the {what} {path}: {e.strerror or e}") from None


def new_run_dir(cluster: str, base: Path = BASE, now: float | None = None) -> Path:
    """A new, empty run directory for ``cluster`` under ``base`` (created), and the
    ``<base>/<cluster>`` link pointed at it (left alone if a real folder has that name)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if now is None else now))
    _make(base, "folder of runs")
    run = base / f"{cluster}-{stamp}"
    n = 1
    while True:
        try:
            run.mkdir()
            break
        except FileExistsError:
            n += 1
            run = base / f"{cluster}-{stamp}-{n}"
        except OSError as e:
            raise RunDirError(f"cannot make the run directory {run}: {e.strerror or e}") from None
    latest = base / cluster
    if latest.is_symlink() or not latest.exists():
        tmp = base / f".{cluster}.link-{os.getpid()}"
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(run.name)
        os.replace(tmp, latest)
    return run.resolve()


def prepare_run_dir(path: Path, overwrite: bool = False) -> Path:
    """``path`` made ready for a new run: it must not exist, be empty, or (with
    ``overwrite``) hold a previous run, whose records are deleted (its ``state/`` is
    kept). RunDirError otherwise."""
    path = Path(path)
    if path.is_symlink():
        path = path.resolve()
    if path.exists() and not path.is_dir():
        raise RunDirError(f"run directory {path} is a file")
    if path.exists() and any(path.iterdir()):
        if not (path / MARK).exists():
            raise RunDirError(
                f"run directory {path} is not empty and holds no run: give another --run-dir"
            )
        if not overwrite:
            raise RunDirError(
                f"run directory {path} holds a previous run: give another --run-dir, leave it "
                "out for a new one, or add --overwrite to replace it"
            )
        for entry in path.iterdir():
            if entry.name == "state":
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    _make(path, "run directory")
    return path.resolve()


def state_dir(cluster: str, run_dir: Path, given_run_dir: bool, base: Path = BASE) -> Path:
    """Where the nodes of ``cluster`` persist their state for a run in ``run_dir``."""
    if given_run_dir:
        return (Path(run_dir) / "state").resolve()
    return (base / f"{cluster}.state").resolve()


def folder_problem(path: str | Path) -> str | None:
    """``"PATH: no such folder"`` or ``"PATH: not a folder"`` for a folder argument that is
    not one (a run directory to read), else None."""
    folder = Path(path)
    if folder.is_dir():
        return None
    return f"{path}: {'not a folder' if folder.exists() else 'no such folder'}"
