"""Where a voter keeps its promise, so that a restart does not make it forget it.

A voter promises at most one candidate per epoch and never goes back to a lower epoch.
Both hold across restarts only if the promise ``(epoch, candidate)`` is on disk before the
vote is answered (as Raft keeps ``currentTerm`` and ``votedFor``). :class:`PromiseFile`
writes it to a temporary file, ``fsync``s it, renames it over the old one and ``fsync``s
the directory: after a crash the file holds the old promise or the new one, never a torn
one. The voter writes only when its promise changes (an election), not on renewals.

File format (JSON): ``{"group": <str>, "epoch": <int >= 0>, "candidate": <str>}``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Protocol


class Promises(Protocol):
    """Durable storage of one voter's promise."""

    def load(self) -> tuple[int, str]:
        """The last promise saved, ``(0, "")`` if none."""
        ...

    def save(self, epoch: int, candidate: str) -> None:
        """Make ``(epoch, candidate)`` durable before returning (raises OSError if not)."""
        ...


class PromiseFile:
    """A voter's promise for ``group`` in the file ``path`` (see the module docstring)."""

    def __init__(self, path: str | os.PathLike[str], group: str) -> None:
        self.path = Path(path)
        self.group = group
        self.writes = 0

    def load(self) -> tuple[int, str]:
        """The promise on disk, ``(0, "")`` if there is no file. ValueError, naming the file
        and what is wrong, if it cannot be read as a promise of this group."""
        try:
            text = self.path.read_text()
        except FileNotFoundError:
            return 0, ""
        try:
            data = json.loads(text)
        except ValueError as e:
            raise ValueError(f"sync promise file {self.path}: not JSON ({e})") from None
        if not isinstance(data, dict):
            raise ValueError(f"sync promise file {self.path}: expected an object")
        epoch, candidate, group = data.get("epoch"), data.get("candidate"), data.get("group")
        if group != self.group:
            raise ValueError(
                f"sync promise file {self.path}: is for group {group!r}, not {self.group!r}"
            )
        if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 0:
            raise ValueError(f"sync promise file {self.path}: epoch {epoch!r} is not an int >= 0")
        if not isinstance(candidate, str):
            raise ValueError(f"sync promise file {self.path}: candidate {candidate!r} is not text")
        return epoch, candidate

    def save(self, epoch: int, candidate: str) -> None:
        """Write the promise durably (temporary file, fsync, rename, fsync of the directory)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        payload = json.dumps({"group": self.group, "epoch": epoch, "candidate": candidate})
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, payload.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, self.path)
        dfd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
        self.writes += 1
