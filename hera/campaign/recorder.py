"""The campaign's own record of the bus: every sample, every args write, every liveliness
change, as an observer joined directly to every node saw them (never through the link
proxy, so a partition between nodes does not hide anything from it).

Unlike the logging node's CSVs (which hold only what its store accepted, and nothing while
it is down), this is the raw history the checkers judge: a duplicate or a seq going back is
recorded as it came. Files under ``<campaign dir>/observed/``:

- ``<name>@<node>.csv``: ``arrival,run,seq,t,v1,v2,...`` (arrival: this process's wall
  clock; run: the producer's incarnation, numbered 0, 1, ... in the order this recorder
  first saw each (a restarted process takes a new incarnation and may start its seqs
  again, :mod:`hera.wire`); t: the sample's measurement time, on its producer's clock);
- ``alive.csv``: ``t,node,up|down`` (liveliness tokens of the nodes, as seen here);
- ``args.jsonl``: ``{"t", "key", "ts", "origin", "value"}`` for every args write;
- ``rejected.txt``: samples that did not decode (each with the reason).

Rows are buffered and flushed every 0.2 s and on :meth:`Recorder.close`.
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
from pathlib import Path
from typing import IO, Any

import msgpack
import zenoh

from hera import wire
from hera.keys import Keys

FOLDER = "observed"


def stream_file(folder: Path, name: str, node: str) -> Path:
    """Where the samples of (name, node) are recorded."""
    return Path(folder) / FOLDER / f"{name}@{node}.csv"


class Recorder:
    """Subscribes to a cluster's data, args and liveliness and writes them down."""

    def __init__(self, session: zenoh.Session, keys: Keys, folder: Path) -> None:
        self.keys = keys
        self.dir = Path(folder) / FOLDER
        self.dir.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._files: dict[tuple[str, str], IO[str]] = {}
        self._runs: dict[tuple[str, str], dict[int, int]] = {}  # incarnation -> its number
        self._alive = open(self.dir / "alive.csv", "a")  # noqa: SIM115 - closed in close()
        self._args = open(self.dir / "args.jsonl", "a")  # noqa: SIM115
        self._rejected = open(self.dir / "rejected.txt", "a")  # noqa: SIM115
        self.samples = 0
        self.rejected = 0
        self.counts: dict[tuple[str, str], int] = {}
        self._closed = False
        self._handles: list[Any] = [
            session.declare_subscriber(f"{keys.prefix}/data/**", self._on_data),
            session.declare_subscriber(keys.args("**"), self._on_args),
            session.liveliness().declare_subscriber(keys.alive_all, self._on_alive, history=True),
        ]
        self._flusher = threading.Thread(target=self._flush_loop, name="recorder", daemon=True)
        self._flusher.start()

    # -- callbacks ------------------------------------------------------------------------
    def _on_data(self, sample: zenoh.Sample) -> None:
        arrival = time.time()
        key = str(sample.key_expr)
        try:
            name, node = self.keys.parse_data(key)
            msg = wire.decode(sample.payload.to_bytes())
        except (wire.WireError, ValueError) as e:
            with self._lock:
                self.rejected += 1
                self._rejected.write(f"{arrival:.6f} {key} {e}\n")
            return
        with self._lock:
            if self._closed:
                return
            runs = self._runs.setdefault((name, node), {})
            run = runs.setdefault(msg.inc, len(runs))
            row = f"{arrival:.6f},{run},{msg.seq},{msg.t!r},{','.join(map(repr, msg.values))}\n"
            f = self._files.get((name, node))
            if f is None:
                f = self._files[(name, node)] = open(stream_file(self.dir.parent, name, node), "a")  # noqa: SIM115
            f.write(row)
            self.samples += 1
            self.counts[(name, node)] = self.counts.get((name, node), 0) + 1

    def _on_args(self, sample: zenoh.Sample) -> None:
        arrival = time.time()
        key = str(sample.key_expr)[len(self.keys.args("")) :]
        try:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            entry = {"t": arrival, "key": key, "ts": msg["ts"], "origin": msg["origin"]}
            entry["value"] = msg["value"]
            line = json.dumps(entry, default=repr) + "\n"
        except Exception as e:
            line = json.dumps({"t": arrival, "key": key, "error": str(e)}) + "\n"
        with self._lock:
            if not self._closed:
                self._args.write(line)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        t = time.time()
        try:
            node, worker = self.keys.parse_alive(str(sample.key_expr))
        except ValueError:
            return
        if worker is not None:
            return
        event = "up" if sample.kind == zenoh.SampleKind.PUT else "down"
        with self._lock:
            if not self._closed:
                self._alive.write(f"{t:.6f},{node},{event}\n")

    # -- files ----------------------------------------------------------------------------
    def flush(self) -> None:
        with self._lock:
            for f in (*self._files.values(), self._alive, self._args, self._rejected):
                with contextlib.suppress(ValueError):
                    f.flush()

    def _flush_loop(self) -> None:
        while not self._closed:
            time.sleep(0.2)
            self.flush()

    def close(self) -> None:
        """Stop recording and close the files (the session stays open)."""
        for h in self._handles:
            with contextlib.suppress(Exception):
                h.undeclare()
        self._handles.clear()
        with self._lock:
            self._closed = True
            for f in (*self._files.values(), self._alive, self._args, self._rejected):
                f.close()
            self._files.clear()
