"""Server-side downsampling of live streams for the web view.

Every stream is reduced to buckets of :attr:`Downsampler.bucket_s` seconds of measurement
time (0.1 s: 10 points a second, whatever the stream's rate), each holding the number of
samples, the mean time, and the mean, minimum and maximum of every column; the last
:attr:`Downsampler.keep_s` seconds are kept. The page asks for the buckets that start at
or after the last one it holds, so a stream at 100 Hz costs it what one at 10 Hz does, and
the envelope (min, max) keeps a spike visible that the mean would hide.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Bucket:
    """The samples of one stream within one bucket of time."""

    index: int
    n: int = 0
    sum_t: float = 0.0
    sums: list[float] = field(default_factory=list)
    mins: list[float] = field(default_factory=list)
    maxs: list[float] = field(default_factory=list)
    truth: list[float | None] | None = None  # filled once the bucket is complete

    def add(self, t: float, values: Sequence[float]) -> None:
        if not self.n or len(values) != len(self.sums):
            self.n, self.sum_t = 0, 0.0
            self.sums = [0.0] * len(values)
            self.mins = [math.inf] * len(values)
            self.maxs = [-math.inf] * len(values)
        self.n += 1
        self.sum_t += t
        for i, v in enumerate(values):
            self.sums[i] += v
            if v < self.mins[i]:
                self.mins[i] = v
            if v > self.maxs[i]:
                self.maxs[i] = v

    @property
    def t(self) -> float:
        """Mean measurement time of its samples (epoch s)."""
        return self.sum_t / self.n

    def point(self) -> list[Any]:
        """``[index, t, n, means, mins, maxs]`` (values rounded to 7 significant digits)."""
        return [
            self.index,
            round(self.t, 4),
            self.n,
            [_r(s / self.n) for s in self.sums],
            [_r(v) for v in self.mins],
            [_r(v) for v in self.maxs],
        ]


def _r(x: float) -> float:
    return float(f"{x:.7g}")


class Downsampler:
    """Buckets of every stream (see the module docstring); thread-safe."""

    def __init__(self, bucket_s: float = 0.1, keep_s: float = 60.0) -> None:
        if bucket_s <= 0 or keep_s < bucket_s:
            raise ValueError("bucket_s must be > 0 and keep_s >= bucket_s")
        self.bucket_s = bucket_s
        self.keep_s = keep_s
        self._keep = int(math.ceil(keep_s / bucket_s))
        self._streams: dict[str, deque[Bucket]] = {}
        self._lock = threading.Lock()
        self.samples = 0

    def add(self, stream: str, t: float, values: Sequence[float]) -> None:
        """Take one sample of ``stream`` (measurement time ``t``, epoch s). A sample older
        than the stream's newest bucket goes into its own bucket if that is still kept,
        else it is dropped."""
        index = math.floor(t / self.bucket_s)
        with self._lock:
            self.samples += 1
            buckets = self._streams.get(stream)
            if buckets is None:
                buckets = self._streams[stream] = deque()
            if not buckets or index > buckets[-1].index:
                buckets.append(Bucket(index))
                while buckets[-1].index - buckets[0].index >= self._keep:
                    buckets.popleft()
                buckets[-1].add(t, values)
                return
            for b in reversed(buckets):  # late sample: its bucket, if kept
                if b.index == index:
                    b.add(t, values)
                    return
                if b.index < index:
                    break

    def streams(self) -> list[str]:
        """The streams seen, sorted."""
        with self._lock:
            return sorted(self._streams)

    def since(self, stream: str, t: float) -> list[tuple[Bucket, list[Any]]]:
        """The buckets of ``stream`` whose start is at or after ``t`` (epoch s), oldest
        first, each with its :meth:`Bucket.point` taken under the lock (the last bucket
        may still grow)."""
        first = math.floor(t / self.bucket_s)
        with self._lock:
            buckets = self._streams.get(stream, ())
            return [(b, b.point()) for b in buckets if b.index >= first]

    def newest(self, stream: str) -> float | None:
        """The mean time of the stream's newest bucket, or None."""
        with self._lock:
            buckets = self._streams.get(stream)
            return buckets[-1].t if buckets else None
