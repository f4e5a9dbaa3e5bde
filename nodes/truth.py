"""Ground truth: what the world really was at each sample's measurement time.

- :func:`truth_at` (from :mod:`hera.nodes.world`): the true state of any scenario at any
  time, a pure function for scoring code;
- :class:`TruthRecorder`: a measure with the arg ``truth = true`` appends, for every sample,
  a row ``index,timestamp_ms,<16 state values>,<measure-specific truth>`` to
  ``<run_dir>/truth/<name>_<node>.csv`` (no header, flushed per row, the layout of the
  measure logs), with ``<name>_<node>.columns.json`` beside it naming the columns.
  ``timestamp_ms`` is the sample's measurement time (epoch ms), so rows join the measure log
  on the timestamp; ``index`` counts the rows this measure instance wrote (from 1).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from hera.nodes.world import STATE_COLUMNS, State, make_scenario, state_at, truth_at

__all__ = ["STATE_COLUMNS", "TruthRecorder", "make_scenario", "state_at", "truth_at"]


class TruthRecorder:
    """Appends truth rows for one (measure name, node)."""

    def __init__(
        self,
        run_dir: str | Path,
        name: str,
        node: str,
        extra_columns: Sequence[str] = (),
        world: Mapping[str, Any] | None = None,
    ) -> None:
        self.dir = Path(run_dir) / "truth"
        self.dir.mkdir(parents=True, exist_ok=True)
        stem = f"{name}_{node}"
        self.path = self.dir / f"{stem}.csv"
        self.extra = tuple(extra_columns)
        sidecar = {
            "name": name,
            "node": node,
            "columns": ["index", "timestamp [ms since epoch]", *STATE_COLUMNS, *self.extra],
            "format": "no header; index,timestamp_ms,truth... (rows join the measure log on "
            "timestamp_ms)",
            "world": dict(world or {}),
        }
        (self.dir / f"{stem}.columns.json").write_text(json.dumps(sidecar, indent=1))
        self._f: IO[str] | None = open(self.path, "a", buffering=1)  # noqa: SIM115 - kept open
        self._lock = threading.Lock()
        self.rows = 0

    def write(self, state: State, extra: Sequence[float | None] = ()) -> None:
        """Append one row for ``state`` (its ``t`` is the sample's measurement time).
        ``None`` extras are written as empty fields."""
        values = [*state.as_row(), *extra]
        text = ",".join("" if v is None else repr(float(v)) for v in values)
        with self._lock:
            if self._f is None:
                return
            self.rows += 1
            self._f.write(f"{self.rows},{round(state.t * 1000.0, 3)!r},{text}\n")
            self._f.flush()

    def close(self) -> None:
        with self._lock:
            if self._f is not None:
                self._f.close()
                self._f = None


def want_truth(args: Mapping[str, Any], run_dir: str | None) -> bool:
    """True when the args ask for truth (``truth = true``) and there is a run directory."""
    flag = args.get("truth", False)
    if not isinstance(flag, bool):
        raise ValueError(f"arg 'truth' must be true or false, got {flag!r}")
    return flag and run_dir is not None
