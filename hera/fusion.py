"""Fusion measures: run a fusion model over the samples in the store, live or in replay.

A *model* is a plain object (see :class:`FusionModel`): it names its ``inputs`` and turns
samples, fed in measurement-time order, into estimates. It never looks at a clock: dt comes
from the samples' measurement times, so the very same model object gives the same output
live and in ``hera replay``.

A :class:`FusionMeasure` runs a model inside a node, in one of two modes (arg ``mode``):

- ``period`` (the original's pattern): each period, the latest sample of each input source
  that is newer than the one used last and younger than ``max_age`` (default 0.5 s);
- ``arrival`` (thesis ch. 8.3): every accepted sample of its inputs is queued as it arrives
  and processed at the next step (the step waits for new data up to one period); when the
  model falls behind and more than ``backlog`` samples of one source wait, only the newest
  of that source are kept. Samples are held back up to ``reorder_s`` (default 0.1 s) and
  released in measurement-time order, so a sample that arrives late (a sonar stamps the
  start of its 49 ms ping) is still fused at its own time: live and ``hera replay`` fuse
  the same sequence. The estimate keeps its true time; it is only published later.
"""

from __future__ import annotations

import heapq
import json
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Protocol

from hera.measure import Measure, MeasureContext, Reading
from hera.recordings import start_marker
from hera.store import Sample, Store


class FusionModel(Protocol):
    """What a fusion model gives."""

    inputs: tuple[str, ...]
    columns: tuple[str, ...]

    def process(self, sample: Sample) -> bool:
        """Fuse one sample (fed in measurement-time order); return whether the estimate
        changed."""

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time in epoch s, values) of the current estimate, or None before the first."""


def time_order(samples: Sequence[Sample]) -> list[Sample]:
    """Samples sorted by measurement time, ties broken by (name, node, seq): deterministic."""
    return sorted(samples, key=lambda s: (s.t, s.name, s.node, s.seq))


class Inbox:
    """Collects every sample of some names accepted by a store (see module docstring)."""

    def __init__(self, store: Store, names: Sequence[str], backlog: int = 64) -> None:
        self._names = frozenset(names)
        self._queues: dict[tuple[str, str], deque[Sample]] = {}
        self._backlog = backlog
        self._cond = threading.Condition()
        self.dropped = 0
        self._store = store
        store.add_listener(self._on_sample)

    def _on_sample(self, s: Sample) -> None:
        if s.name not in self._names:
            return
        with self._cond:
            q = self._queues.get((s.name, s.node))
            if q is None:
                q = self._queues[(s.name, s.node)] = deque()
            q.append(s)
            if len(q) > self._backlog:
                self.dropped += 1
                q.popleft()  # falling behind: keep the newest of this source
            self._cond.notify()

    def drain(self, timeout: float = 0.0) -> list[Sample]:
        """Every queued sample in time order, waiting up to ``timeout`` s for the first."""
        with self._cond:
            if timeout > 0 and not any(self._queues.values()):
                self._cond.wait(timeout)
            out = [s for q in self._queues.values() for s in q]
            for q in self._queues.values():
                q.clear()
        return time_order(out)

    def close(self) -> None:
        self._store.remove_listener(self._on_sample)


class FusionMeasure(Measure):
    """Runs ``model_class(**args["model"])`` as a measure (see module docstring).

    Args: ``mode`` ("period" or "arrival"), ``max_age`` (s, period mode), ``backlog`` and
    ``reorder_s`` (arrival mode), ``model`` (a table of the model's own parameters).
    """

    model_class: ClassVar[type]
    period = 0.05

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        super().init(args, ctx)
        unknown = set(args) - {"mode", "max_age", "backlog", "reorder_s", "model"}
        if unknown:
            raise ValueError(f"{ctx.spec.name}: unknown args {sorted(unknown)}")
        self.mode = args.get("mode", "period")
        if self.mode not in ("period", "arrival"):
            raise ValueError(f"{ctx.spec.name}: mode must be 'period' or 'arrival'")
        self.max_age = float(args.get("max_age", 0.5))
        self.reorder = float(args.get("reorder_s", 0.1))
        if not 0 <= self.reorder <= 5:
            raise ValueError(f"{ctx.spec.name}: reorder_s must be within [0, 5] s")
        self._held: list[tuple[float, str, str, int, Sample]] = []
        self._newest = float("-inf")
        self.model = self.model_class(**dict(args.get("model", {})))
        self.columns = tuple(self.model.columns)
        self._inbox = None
        self._cursor = None
        self._first_t: float | None = None
        if self.mode == "arrival":
            self._inbox = Inbox(ctx.store, self.model.inputs, int(args.get("backlog", 64)))
        else:
            self._cursor = ctx.store.cursor(self.model.inputs)

    def _release(self, arrived: list[Sample]) -> list[Sample]:
        """Hold samples up to ``reorder_s``; return those due, in measurement-time order.

        A sample is due once a sample at least ``reorder_s`` newer has been seen, or once it
        has waited ``reorder_s`` on this node (a silent source never blocks the others).
        """
        for s in arrived:
            heapq.heappush(self._held, (s.t, s.name, s.node, s.seq, s))
            self._newest = max(self._newest, s.t)
        now = time.monotonic()
        due = []
        while self._held:
            t, *_, s = self._held[0]
            if t > self._newest - self.reorder and now - s.arrival < self.reorder:
                break
            due.append(heapq.heappop(self._held)[-1])
        return due

    def measure(self) -> Reading | None:
        if self._inbox is not None:
            samples = self._release(self._inbox.drain(timeout=0.8 * self.ctx.spec.period))
        else:
            samples = time_order(self._cursor.new(max_age=self.max_age))
        changed = False
        for s in samples:
            if self.model.process(s):
                changed = True
                if self._first_t is None:
                    self._first_t = s.t
                    self._record_start(s.t)
        self._report(len(samples))
        est = self.model.estimate() if changed else None
        return None if est is None else Reading(est[1], est[0])

    def _record_start(self, t: float) -> None:
        """Write the first fused sample's time to ``<run>/measures/<name>_<node>.start.json``
        so ``hera replay --start-like <node>`` can start the model exactly there."""
        if self.ctx.run_dir is None:
            return
        path = start_marker(Path(self.ctx.run_dir) / "measures", self.ctx.spec.name, self.ctx.node)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({"first_sample_t": t}))
        except OSError as e:  # a full disk must not stop the fusion
            self.ctx.log.warning("cannot record the model's start: %s", e)

    def _report(self, fused: int) -> None:
        """Status counters: samples fused, dropped (backlog), and the model's own counters
        (integer attributes such as ``late``, ``rejected``)."""
        c = self.ctx.counters
        c["fused"] = c.get("fused", 0) + fused
        if self._inbox is not None:
            c["dropped"] = self._inbox.dropped
        for key in ("late", "out_of_order", "rejected", "beam_edge", "direction_fixes", "misses"):
            value = getattr(self.model, key, None)
            if isinstance(value, int):
                c[key] = value

    def close(self) -> None:
        if self._inbox is not None:
            self._inbox.close()
