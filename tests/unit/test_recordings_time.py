"""A sample's time as a recording keeps it (``recorded_time``) is exactly what ``read_csv``
gives back after ``CsvWriter`` wrote it: the times fusion measures give their models live,
so that ``hera replay`` fuses the very same numbers."""

from __future__ import annotations

import math
import random

from hera.recordings import CsvWriter, read_csv, recorded_time


def test_recorded_time_is_what_a_recording_reads_back(tmp_path):
    rng = random.Random(4)
    times = [1.8e9 + rng.uniform(0, 1e5) for _ in range(2000)] + [0.0, 1e-7, 123.4565]
    w = CsvWriter(tmp_path, "m", "n", ("v [1]",))
    for t in times:
        w.write(t, [1.0])
    w.close()
    back = [s.t for s in read_csv(tmp_path / "measures" / "m_n.csv", "m", "n")]
    assert back == [recorded_time(t) for t in times]  # bit for bit
    assert sum(b != t for b, t in zip(back, times, strict=True)) > 1000  # rounding is real
    # within half a microsecond, give or take the float's own resolution at epoch times
    assert all(abs(b - t) <= 5e-7 + 2 * math.ulp(t) for b, t in zip(back, times, strict=True))
