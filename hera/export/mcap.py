"""Runs as MCAP files (``hera export RUN --mcap OUT.mcap``, ``hera up --mcap OUT.mcap``),
for Foxglove, Lichtblick and the ``mcap`` tools.

Layout of a file:

- one channel per stream, topic ``/<name>/<node>``, message encoding ``json``, with a
  ``jsonschema`` schema named ``hera.<name>``: an object with ``seq`` (integer), ``t``
  (measurement time, epoch s) and one number per column. A field is named after its column
  without the unit (``"omega [rad/s]"`` is ``omega``; the unit is the field's description),
  so Foxglove plots ``/track_gyro/computer.omega``;
- for every stream whose application knows the truth of its columns (a simulated run),
  a channel ``/<name>/<node>/truth`` with the true value of those columns at each sample's
  time (schema ``hera.<name>.truth``);
- every message's log time and publish time are its measurement time (ns since the
  epoch); an export writes them in time order (ties by topic and seq).

:func:`export_run` reads the run's CSV logs (every sample the logging node stored) and
``cluster.json``; :class:`LiveRecorder` subscribes to the bus and writes samples as they
arrive (readers order them by log time).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import re
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from hera.application import Truth
from hera.evaluate import run_spec
from hera.plugins import AppIndex, find_measure
from hera.recordings import measures_dir, read_columns, read_csv, split_stem
from hera.spec import ClusterSpec

PROFILE = ""
LIBRARY = "hera"


def _writer_class() -> Any:
    try:
        from mcap.writer import Writer
    except ImportError:
        raise ImportError(
            "MCAP export needs the mcap package: pip install 'hera-fusion[console]'"
        ) from None
    return Writer


def field_names(columns: Sequence[str]) -> list[str]:
    """JSON field names of columns: the name before its unit, lowercased, other characters
    than letters, digits and '_' replaced by '_'; repeats get _2, _3 ..."""
    out: list[str] = []
    for col in columns:
        base = re.sub(r"[^a-z0-9_]+", "_", col.split("[", 1)[0].strip().lower()).strip("_")
        base = base or "value"
        if base[0].isdigit():
            base = "v" + base
        name, k = base, 2
        while name in out or name in ("seq", "t"):
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


def _unit(column: str) -> str:
    m = re.search(r"\[(.*)\]", column)
    return m.group(1) if m else ""


def json_schema(title: str, columns: Sequence[str], with_seq: bool = True) -> dict[str, Any]:
    """The JSON schema of a stream's messages (see the module docstring)."""
    props: dict[str, Any] = {}
    if with_seq:
        props["seq"] = {"type": "integer", "minimum": 1, "description": "sequence number"}
    props["t"] = {"type": "number", "description": "measurement time [s since the epoch]"}
    for col, name in zip(columns, field_names(columns), strict=True):
        props[name] = {"type": "number", "description": col, "unit": _unit(col)}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }


class Channels:
    """The channels of one MCAP file, registered at a stream's first message."""

    def __init__(self, writer: Any, spec: ClusterSpec, index: AppIndex | None = None) -> None:
        self.writer = writer
        self.spec = spec
        self.index = index or AppIndex()
        self._classes: dict[str, type | None] = {}
        self._truths: dict[str, Truth | None] = {}
        self._schemas: dict[tuple[str, tuple[str, ...]], int] = {}
        self._channels: dict[str, tuple[int, list[str]]] = {}
        self._truth_channels: dict[str, tuple[int, list[str], list[str]] | None] = {}
        self.messages = 0
        self.samples = 0
        self.truth = 0

    def measure_class(self, name: str) -> type | None:
        if name not in self._classes:
            self._classes[name] = None
            for _, m in self.spec.measures():
                if str(m.name) == name:
                    with contextlib.suppress(LookupError, TypeError):
                        self._classes[name] = find_measure(m.use)
                    break
        return self._classes[name]

    def _truth_of(self, cls: type | None) -> Truth | None:
        app = self.index.app_of(cls)
        if app is None:
            return None
        if app.name not in self._truths:
            self._truths[app.name] = app.truth(self.spec.world)
        return self._truths[app.name]

    def _schema(self, title: str, columns: Sequence[str], with_seq: bool = True) -> int:
        key = (title, tuple(columns))
        if key not in self._schemas:
            data = json.dumps(json_schema(title, columns, with_seq)).encode()
            self._schemas[key] = self.writer.register_schema(title, "jsonschema", data)
        return self._schemas[key]

    def write(
        self,
        name: str,
        node: str,
        seq: int,
        t: float,
        values: Sequence[float],
        columns: Sequence[str] | None = None,
    ) -> None:
        """Write one sample of stream ``name/node`` (and its truth, when known)."""
        stream = f"{name}/{node}"
        if stream not in self._channels:
            cls = self.measure_class(name)
            cols = list(columns or getattr(cls, "columns", ()) or ())
            if len(cols) != len(values):
                cols = [f"v{i + 1}" for i in range(len(values))]
            schema = self._schema(f"hera.{name}", cols)
            channel = self.writer.register_channel(
                f"/{stream}", "json", schema, {"name": name, "node": node}
            )
            self._channels[stream] = (channel, field_names(cols))
            self._truth_channels[stream] = self._truth_channel(name, node, cls, cols)
        channel, fields = self._channels[stream]
        stamp = int(round(t * 1e9))
        message = {"seq": seq, "t": t, **dict(zip(fields, values, strict=False))}
        self.writer.add_message(channel, stamp, json.dumps(message).encode(), stamp, seq)
        self.messages += 1
        self.samples += 1
        truth_channel = self._truth_channels[stream]
        if truth_channel is not None:
            tchannel, tcols, tfields = truth_channel
            truth = self._truth_of(self.measure_class(name))
            try:
                at = truth.at(t)
            except Exception:  # outside the simulated world's time
                return
            if all(c in at for c in tcols):
                record = {"t": t, **{f: float(at[c]) for c, f in zip(tcols, tfields, strict=True)}}
                self.writer.add_message(tchannel, stamp, json.dumps(record).encode(), stamp, seq)
                self.messages += 1
                self.truth += 1

    def _truth_channel(
        self, name: str, node: str, cls: type | None, cols: list[str]
    ) -> tuple[int, list[str], list[str]] | None:
        truth = self._truth_of(cls)
        if truth is None:
            return None
        pairs = [(c, f) for c, f in zip(cols, field_names(cols), strict=True) if c in truth.columns]
        if not pairs:
            return None
        tcols = [c for c, _ in pairs]
        schema = self._schema(f"hera.{name}.truth", tcols, with_seq=False)
        channel = self.writer.register_channel(
            f"/{name}/{node}/truth", "json", schema, {"name": name, "node": node, "truth": "1"}
        )
        return channel, tcols, [f for _, f in pairs]

    @property
    def channels(self) -> int:
        return len(self._channels) + sum(1 for c in self._truth_channels.values() if c)


def _open(out: str | Path, part: Path | None = None) -> tuple[Any, IO[bytes]]:
    """A writer started on MCAP file ``out`` (or on ``part``, renamed to ``out`` when done)."""
    Writer = _writer_class()
    path = Path(out)
    if path.parent and not path.parent.exists():
        raise ValueError(f"{out}: folder {path.parent} does not exist")
    if path.is_dir():
        raise ValueError(f"{out}: is a folder; give the name of the .mcap file to write")
    f = open(part or path, "wb")  # noqa: SIM115 - closed by the caller
    writer = Writer(f)
    writer.start(profile=PROFILE, library=LIBRARY)
    return writer, f


def export_run(
    run_dir: str | Path,
    out: str | Path,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, int]:
    """Write every sample of a run's CSV logs (and the truth of its models) to MCAP file
    ``out`` in time order (see the module docstring); return the counts of messages,
    channels, samples and truth messages. ValueError naming the problem for a folder that
    is not a run or has no recordings."""
    run_dir = Path(run_dir)
    spec = run_spec(run_dir)
    folder = measures_dir(run_dir)
    files = sorted(folder.glob("*.csv"))
    if not files:
        raise ValueError(f"{run_dir}: no recordings (measures/<name>_<node>.csv) to export")
    names = [str(m.name) for _, m in spec.measures()]
    rows = []
    columns: dict[str, list[str]] = {}
    for path in files:
        side = path.with_name(path.stem + ".columns.json")
        if side.exists():
            meta = read_columns(side)
            name, node = meta["name"], meta["node"]
            columns[f"{name}/{node}"] = list(meta["columns"][2:])
        else:
            name, node = split_stem(path.stem, names)
        rows.extend(read_csv(path, name, node))
    rows.sort(key=lambda s: (s.t, s.name, s.node, s.seq))
    # written beside, then renamed: an export that fails or is stopped leaves no file cut
    # short, and a file already at ``out`` as it was
    part = Path(out).with_name(f".{Path(out).name}.{os.getpid()}.part")
    writer, f = _open(out, part)
    try:
        channels = Channels(writer, spec)
        for i, s in enumerate(rows):
            channels.write(s.name, s.node, s.seq, s.t, s.values, columns.get(f"{s.name}/{s.node}"))
            if progress is not None and (i % 2000 == 0 or i == len(rows) - 1):
                progress(i + 1, len(rows))
        writer.finish()
        f.close()
        os.replace(part, out)
    finally:
        f.close()
        part.unlink(missing_ok=True)
    return {
        "messages": channels.messages,
        "channels": channels.channels,
        "samples": channels.samples,
        "truth": channels.truth,
    }


class LiveRecorder:
    """Records every sample of a running cluster to an MCAP file (``hera up --mcap``):
    a subscriber queues the samples, a thread writes them; :meth:`close` writes the file's
    summary. Malformed samples are counted in :attr:`rejected` and left out."""

    def __init__(self, spec: ClusterSpec, out: str | Path) -> None:
        from hera.client import ClusterClient

        self.writer, self._file = _open(out)
        self.channels = Channels(self.writer, spec)
        self.rejected = 0
        self.client = ClusterClient(spec)
        self._queue: queue.Queue[tuple[str, bytes] | None] = queue.Queue()
        self._thread = threading.Thread(target=self._write, name="mcap-recorder", daemon=True)
        self._thread.start()
        self._sub = self.client.subscribe(self.client.keys.data("*", "*"), self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        self._queue.put((str(sample.key_expr), sample.payload.to_bytes()))

    def _write(self) -> None:
        from hera.watch import decode_sample

        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                s = decode_sample(self.client.keys, *item)
            except ValueError:
                self.rejected += 1
                continue
            self.channels.write(s["name"], s["node"], s["seq"], s["t"], s["values"])

    def close(self) -> None:
        """Stop recording and finish the file."""
        with contextlib.suppress(Exception):
            self._sub.undeclare()
        self._queue.put(None)
        self._thread.join(10.0)
        try:
            self.writer.finish()
        finally:
            self._file.close()
            self.client.close()
