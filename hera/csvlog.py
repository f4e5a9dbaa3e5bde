"""CSV logs in the original Hera format, one file per (name, sender node).

``<run-dir>/measures/<name>_<node>.csv``: no header, rows ``seq,timestamp_ms,v1,v2,...``
(timestamp = measurement time, epoch milliseconds). Beside it ``<name>_<node>.columns.json``
names the columns and their units. Each row is flushed as it is written, so a killed process
loses at most the row being written.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import IO

from hera.store import Sample


class CsvLog:
    """Appends samples to per-(name, node) CSV files under ``<run_dir>/measures``."""

    def __init__(self, run_dir: str | Path, columns: dict[str, tuple[str, ...]] | None = None):
        self.dir = Path(run_dir) / "measures"
        self.dir.mkdir(parents=True, exist_ok=True)
        self._columns = columns or {}
        self._files: dict[tuple[str, str], IO[str]] = {}
        self._lock = threading.Lock()
        self.rows = 0

    def write(self, s: Sample) -> None:
        """Append one row for ``s`` and flush it."""
        with self._lock:
            f = self._files.get((s.name, s.node))
            if f is None:
                f = self._open(s)
            f.write(f"{s.seq},{round(s.t * 1000.0, 3)!r},{','.join(map(repr, s.values))}\n")
            f.flush()
            self.rows += 1

    def _open(self, s: Sample) -> IO[str]:
        stem = f"{s.name}_{s.node}"
        cols = self._columns.get(s.name) or tuple(f"v{i + 1}" for i in range(len(s.values)))
        sidecar = {
            "name": s.name,
            "node": s.node,
            "columns": ["seq", "timestamp [ms since epoch]", *cols],
            "format": "no header; seq,timestamp_ms,v1,v2,... (original Hera CSV layout)",
        }
        (self.dir / f"{stem}.columns.json").write_text(json.dumps(sidecar, indent=1))
        f = open(self.dir / f"{stem}.csv", "a", buffering=1)  # noqa: SIM115 - kept open
        self._files[(s.name, s.node)] = f
        return f

    def close(self) -> None:
        """Close every file."""
        with self._lock:
            for f in self._files.values():
                f.close()
            self._files.clear()
