"""A fusion measure's checkpoint on disk, so that a node process that restarts resumes its
models (:mod:`hera.fusion` keeps the same checkpoint in memory for a measure the supervisor
restarts within the process).

One file per measure, ``<node state dir>/checkpoints/<measure>.pickle``, replaced
atomically (written beside, then renamed): a pickled dict with ``version`` (1), ``t`` (the
wall clock when taken, s), ``run`` (the cluster run's directory: a state directory outlives
runs, a checkpoint does not), ``settings`` (the model's settings as canonical JSON),
``model`` (a copy of the model), ``fused`` (the last seq fused per (name, node)) and
``first_t``.
The file is this node's own, written by its own process: pickle is fine for it, and a file
from anywhere else must never be put there.
"""

from __future__ import annotations

import contextlib
import os
import pickle
from pathlib import Path
from typing import Any

VERSION = 1
FOLDER = "checkpoints"


def path_of(state_dir: str | Path, measure: str) -> Path:
    return Path(state_dir) / FOLDER / f"{measure}.pickle"


def save(state_dir: str | Path, measure: str, entry: dict[str, Any]) -> None:
    """Write ``entry`` (the fields of the module docstring but ``version``) for ``measure``,
    replacing the previous one at once. Raises what pickling or writing raised."""
    path = path_of(state_dir, measure)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps({"version": VERSION, **entry}, pickle.HIGHEST_PROTOCOL))
    os.replace(tmp, path)


def load(state_dir: str | Path, measure: str) -> dict[str, Any] | None:
    """The checkpoint of ``measure``, or None when there is none, or it cannot be read (a
    model class that changed, a torn file): a measure then starts afresh."""
    try:
        entry = pickle.loads(path_of(state_dir, measure).read_bytes())
    except Exception:  # no file, or whatever unpickling raised: no checkpoint
        return None
    if not isinstance(entry, dict) or entry.get("version") != VERSION:
        return None
    return entry


def forget(state_dir: str | Path, measure: str) -> None:
    """Remove the checkpoint of ``measure`` (its model raised, or checkpoints are off)."""
    with contextlib.suppress(FileNotFoundError):
        path_of(state_dir, measure).unlink()
