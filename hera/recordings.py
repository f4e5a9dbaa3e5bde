"""Recordings in the original Hera CSV layout: read them back as samples, write new ones.

A recording folder holds ``measures/<name>_<node>.csv`` (or the CSVs directly): no header,
rows ``seq,timestamp_ms,v1,v2,...`` with millisecond timestamps from any origin (the
original's monotonic clock, or our epoch milliseconds). Node names may contain ``_``; the
name is everything before the last ``_`` that leaves a known input name, else before the
last ``_``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from hera.store import Sample

SOURCE_FILE = "replay.json"
"""``<out>/replay.json``, written by ``hera replay`` beside its outputs: the recordings it
ran over (``{"recordings": path}``), where ``hera eval`` finds them for a reference."""


class RecordingError(ValueError):
    """A recording that cannot be read; the message names the file and row."""


def measures_dir(folder: str | Path) -> Path:
    """``folder/measures`` if it exists, else ``folder`` itself."""
    folder = Path(folder)
    sub = folder / "measures"
    return sub if sub.is_dir() else folder


def start_marker(folder: str | Path, name: str, node: str) -> Path:
    """``folder/<name>_<node>.start.json``: where a live fusion model records the time of
    the first sample it was given and what keeps a replay from repeating it
    (:class:`LiveStart`; read by ``hera replay --start-like``)."""
    return Path(folder) / f"{name}_{node}.start.json"


@dataclass(frozen=True)
class LiveStart:
    """What a live fusion model records in its start marker (JSON object, these keys):

    - ``first_sample_t``: the measurement time (epoch s) of the first sample it was given;
    - ``late``: samples it was given out of time order (later than its ``reorder_s``),
      ``first_late_t`` the first one's time (or null);
    - ``dropped``: samples its inbox dropped to keep up (``backlog``);
    - ``resumed``: times it resumed from a checkpoint (the samples in between never
      reached it).

    A replay from ``first_sample_t`` gives the live model's very estimates when all three
    counts are 0 and the recordings hold what the model's node received. The counts are
    None in a marker written before they were recorded (unknown).
    """

    first_sample_t: float
    late: int | None = 0
    first_late_t: float | None = None
    dropped: int | None = 0
    resumed: int | None = 0

    @property
    def exact(self) -> bool | None:
        """Whether nothing kept the live model from being replayed exactly (None: unknown)."""
        counts = (self.late, self.dropped, self.resumed)
        if any(c is None for c in counts):
            return None
        return not any(counts)


def write_start(path: str | Path, live: LiveStart) -> None:
    """Write ``live`` to the start marker ``path`` (replaced whole)."""
    Path(path).write_text(json.dumps(dataclasses.asdict(live)))


def read_start(path: str | Path) -> LiveStart:
    """The start marker at ``path``; RecordingError naming the file and key when it is not
    one."""
    try:
        raw = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise RecordingError(f"{path}: not a start marker ({e})") from None
    if not isinstance(raw, dict):
        raise RecordingError(f"{path}: not a start marker (a JSON object is expected)")
    try:
        first = float(raw["first_sample_t"])
    except (KeyError, TypeError, ValueError):
        raise RecordingError(f"{path}: first_sample_t must be a number") from None
    values: dict = {"first_sample_t": first}
    for key in ("late", "dropped", "resumed"):
        v = raw.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
            raise RecordingError(f"{path}: {key} must be an integer >= 0, got {v!r}")
        values[key] = v
    late_t = raw.get("first_late_t")
    if late_t is not None and (isinstance(late_t, bool) or not isinstance(late_t, (int, float))):
        raise RecordingError(f"{path}: first_late_t must be a number or null, got {late_t!r}")
    values["first_late_t"] = None if late_t is None else float(late_t)
    return LiveStart(**values)


def split_stem(stem: str, names: Iterable[str] = ()) -> tuple[str, str]:
    """``(name, node)`` of a file stem ``<name>_<node>`` (see module docstring)."""
    for name in sorted(names, key=len, reverse=True):
        if stem.startswith(name + "_") and len(stem) > len(name) + 1:
            return name, stem[len(name) + 1 :]
    if "_" not in stem:
        raise RecordingError(f"{stem}.csv: expected <name>_<node>.csv")
    name, _, node = stem.rpartition("_")
    return name, node


def read_columns(side: str | Path, keys: Iterable[str] = ("name", "node")) -> dict:
    """A columns sidecar ``<name>_<node>.columns.json``: a JSON object with ``columns``
    (seq, timestamp, then one per value) and the text ``keys``; RecordingError naming the
    file when it is not one."""
    try:
        meta = json.loads(Path(side).read_text())
    except UnicodeDecodeError:
        meta = None
    except ValueError as e:
        raise RecordingError(f"{side}: not a columns sidecar ({e})") from None
    keys = tuple(keys)
    if not (
        isinstance(meta, dict)
        and all(isinstance(meta.get(k), str) for k in keys)
        and isinstance(meta.get("columns"), list)
        and len(meta["columns"]) >= 2
        and all(isinstance(c, str) for c in meta["columns"])
    ):
        raise RecordingError(
            f"{side}: not a columns sidecar (a JSON object with "
            + "".join(f"{k}, " for k in keys)
            + "columns: seq, timestamp, then one per value)"
        )
    return meta


def _width(path: Path) -> int | None:
    """The number of values per row the CSV's columns sidecar names, if it has one."""
    side = path.with_name(path.name.replace(".csv", ".columns.json"))
    try:
        return len(json.loads(side.read_text())["columns"]) - 2
    except (OSError, ValueError, KeyError, TypeError):
        return None


def timestamp_ms(t: float) -> float:
    """The ``timestamp_ms`` column of a recording for ``t`` (epoch seconds): milliseconds
    rounded to the microsecond (written with ``repr``, so read back exactly)."""
    return round(t * 1000.0, 3)


def recorded_time(t: float) -> float:
    """``t`` (epoch seconds) as a recording keeps it, so as ``hera replay`` gives it to a
    model: :func:`timestamp_ms` as :func:`read_csv` reads it back (divided by 1000). Fusion
    measures give their models these times live too, so that live and replay fuse the very
    same numbers."""
    return timestamp_ms(t) / 1000.0


def read_csv(path: Path, name: str, node: str) -> list[Sample]:
    """Every row of one CSV as samples (t in seconds); RecordingError naming the file and
    the row on a row that is not ``seq,timestamp_ms,values...``, has another number of
    values than the others (or than its columns sidecar says), or is not text. A last row
    without its line end that is not whole is left out: the row a killed logger was
    writing (see :mod:`hera.csvlog`)."""
    out = []
    width = _width(path)
    try:
        with open(path, newline="") as f:
            text = f.read()
    except UnicodeDecodeError:
        raise RecordingError(
            f"{path}: not a text CSV (a recording is seq,timestamp_ms,...)"
        ) from None
    rows = list(csv.reader(io.StringIO(text)))
    cut = len(rows) if text and not text.endswith(("\n", "\r")) else 0
    for i, row in enumerate(rows, start=1):
        if not row or not "".join(row).strip():
            continue
        try:
            seq, ts = int(row[0]), float(row[1])
            values = tuple(float(v) for v in row[2:])
        except (ValueError, IndexError):
            if i == cut:
                break
            raise RecordingError(
                f"{path}:{i}: expected seq,timestamp_ms,values...: {','.join(row)[:80]!r}"
            ) from None
        if not (math.isfinite(ts) and all(math.isfinite(v) for v in values)):
            raise RecordingError(f"{path}:{i}: non-finite number")
        if width is None:
            width = len(values)
        elif len(values) != width:
            if i == cut:
                break
            raise RecordingError(f"{path}:{i}: {len(values)} values where the rows have {width}")
        out.append(Sample(name, node, seq, ts / 1000.0, 0.0, 0.0, values))
    return out


def read_recordings(
    folder: str | Path, names: Iterable[str] | None = None, known: Iterable[str] = ()
) -> list[Sample]:
    """Every sample of the recordings in ``folder`` whose name is in ``names`` (all if
    None), sorted by (time, name, node, seq)."""
    d = measures_dir(folder)
    files = sorted(d.glob("*.csv"))
    if not files:
        raise RecordingError(f"no <name>_<node>.csv recordings in {d}")
    wanted = None if names is None else set(names)
    out: list[Sample] = []
    for path in files:
        name, node = split_stem(path.stem, [*(wanted or ()), *known])
        if wanted is None or name in wanted:
            out.extend(read_csv(path, name, node))
    out.sort(key=lambda s: (s.t, s.name, s.node, s.seq))
    return out


class CsvWriter:
    """Writes one (name, node) output in the same layout, with a columns sidecar."""

    def __init__(self, folder: str | Path, name: str, node: str, columns: Iterable[str]):
        d = Path(folder) / "measures"
        d.mkdir(parents=True, exist_ok=True)
        self.path = d / f"{name}_{node}.csv"
        (d / f"{name}_{node}.columns.json").write_text(
            json.dumps(
                {"name": name, "node": node, "columns": ["seq", "timestamp [ms]", *columns]},
                indent=1,
            )
        )
        self._f = open(self.path, "w", buffering=1)  # noqa: SIM115 - closed in close()
        self.seq = 0

    def write(self, t: float, values: Iterable[float]) -> None:
        self.seq += 1
        self._f.write(f"{self.seq},{timestamp_ms(t)!r},{','.join(map(repr, values))}\n")

    def close(self) -> None:
        self._f.close()
