"""CSV logs in the original Hera format, one file per (name, sender node).

``<run-dir>/measures/<name>_<node>.csv``: no header, rows ``seq,timestamp_ms,v1,v2,...``
(timestamp = measurement time, epoch milliseconds). Beside it ``<name>_<node>.columns.json``
names the columns and their units. Each row is flushed as it is written, so a killed process
loses at most the row being written (the next process to log the source cuts that row off
before it appends). At most ``max_open`` files are open at once: the least
recently written is closed (and opened again, appending, when its source writes again), so
no number of sources can exhaust the process's file descriptors.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from pathlib import Path
from typing import IO

from hera.recordings import timestamp_ms
from hera.store import Sample


def cut_partial_row(path: Path) -> None:
    """Drop the last row of ``path`` when it has no line end: the row a killed writer was
    writing. Rows appended after it would otherwise continue it, and the file would hold a
    malformed row in its middle (which readers refuse) instead of one lost row."""
    try:
        f = open(path, "rb+")  # noqa: SIM115 - closed below
    except FileNotFoundError:
        return
    with f:
        end = f.seek(0, 2)
        if end == 0:
            return
        f.seek(end - 1)
        if f.read(1) in (b"\n", b"\r"):
            return
        pos = end
        while pos > 0:
            step = min(4096, pos)
            pos -= step
            f.seek(pos)
            cut = f.read(step).rfind(b"\n")
            if cut >= 0:
                f.truncate(pos + cut + 1)
                return
        f.truncate(0)


class CsvLog:
    """Appends samples to per-(name, node) CSV files under ``<run_dir>/measures``."""

    def __init__(
        self,
        run_dir: str | Path,
        columns: dict[str, tuple[str, ...]] | None = None,
        max_open: int = 64,
    ):
        self.dir = Path(run_dir) / "measures"
        self.dir.mkdir(parents=True, exist_ok=True)
        self._columns = columns or {}
        self._files: OrderedDict[tuple[str, str], IO[str]] = OrderedDict()
        self._known: set[tuple[str, str]] = set()
        self._max_open = max(1, int(max_open))
        self._lock = threading.Lock()
        self.rows = 0
        self.reopened = 0

    def write(self, s: Sample) -> None:
        """Append one row for ``s`` and flush it."""
        with self._lock:
            f = self._files.get((s.name, s.node))
            if f is None:
                f = self._open(s)
            else:
                self._files.move_to_end((s.name, s.node))
            f.write(f"{s.seq},{timestamp_ms(s.t)!r},{','.join(map(repr, s.values))}\n")
            f.flush()
            self.rows += 1

    @property
    def open_files(self) -> int:
        """How many files are open now (at most ``max_open``)."""
        with self._lock:
            return len(self._files)

    def _open(self, s: Sample) -> IO[str]:
        source = (s.name, s.node)
        stem = f"{s.name}_{s.node}"
        while len(self._files) >= self._max_open:
            _, oldest = self._files.popitem(last=False)
            oldest.close()
        if source in self._known:
            self.reopened += 1
        else:
            cols = self._columns.get(s.name) or tuple(f"v{i + 1}" for i in range(len(s.values)))
            sidecar = {
                "name": s.name,
                "node": s.node,
                "columns": ["seq", "timestamp [ms since epoch]", *cols],
                "format": "no header; seq,timestamp_ms,v1,v2,... (original Hera CSV layout)",
            }
            (self.dir / f"{stem}.columns.json").write_text(json.dumps(sidecar, indent=1))
            self._known.add(source)
            cut_partial_row(self.dir / f"{stem}.csv")  # a killed writer's, before this process
        f = open(self.dir / f"{stem}.csv", "a", buffering=1)  # noqa: SIM115 - kept open
        self._files[source] = f
        return f

    def close(self) -> None:
        """Close every file."""
        with self._lock:
            for f in self._files.values():
                f.close()
            self._files.clear()
