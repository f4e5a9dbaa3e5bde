"""``hera replay --smooth``: Rauch-Tung-Striebel smoothed estimates of a replayed model.

A model can be smoothed when it offers the two optional members of the ``FusionModel``
protocol (``hera.fusion``): ``filter``, the linear or linearised Kalman filter (KF or EKF of
``hera.estimation``) it steps, and ``estimate_of(x)``, the output columns of a state x (what
``estimate()`` gives for the filter's current state). While the replay runs, every step of
that filter is recorded (``hera.estimation.record``) and each written estimate remembers
its step; afterwards the recorded steps are smoothed backwards (``hera.estimation.smooth``,
using every sample of the run, later ones included) and each estimate is written again from
its step's smoothed state, at the same time, into ``<out>/smoothed/measures/<model>_<node>
.csv``: a run directory of its own, so ``hera eval <out>/smoothed`` scores it like any run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hera.recordings import CsvWriter

__all__ = ["NotSmoothable", "SmoothedRun", "smoothed_dir"]


class NotSmoothable(ValueError):
    """The model offers no linear or linearised filter to smooth (the sentence says why)."""


def smoothed_dir(out: str | Path) -> Path:
    """The run directory the smoothed estimates of a replay into ``out`` are written to."""
    return Path(out) / "smoothed"


class SmoothedRun:
    """Records one model's filter during a replay and writes its smoothed estimates."""

    def __init__(self, model: Any, label: str) -> None:
        from hera.estimation import ExtendedKalmanFilter, KalmanFilter, record

        filt = getattr(model, "filter", None)
        estimate_of = getattr(model, "estimate_of", None)
        if filt is None or not callable(estimate_of):
            raise NotSmoothable(
                f"{label} cannot be smoothed: it has no 'filter' and 'estimate_of(x)' "
                "(see FusionModel in hera.fusion)"
            )
        if not isinstance(filt, KalmanFilter | ExtendedKalmanFilter):
            raise NotSmoothable(
                f"{label} cannot be smoothed: its filter is a {type(filt).__name__}; "
                "RTS smoothing needs a KalmanFilter or an ExtendedKalmanFilter"
            )
        self.label = label
        self.filter = filt
        self.model = model
        self.history = record(filt)
        self.rows: list[tuple[float, int]] = []

    def mark(self, t: float) -> None:
        """An estimate was written at time t from the filter's current step."""
        self.rows.append((t, len(self.history) - 1))

    def write(self, out: str | Path, name: str, node: str, columns: tuple[str, ...]) -> int:
        """Smooth the recorded steps and write one smoothed row per marked estimate to
        ``smoothed_dir(out)``; returns the number of rows."""
        from hera.estimation import smooth

        if self.model.filter is not self.filter:
            raise NotSmoothable(f"{self.label} replaced its filter during the run")
        writer = CsvWriter(smoothed_dir(out), name, node, columns)
        try:
            if self.rows:
                xs = smooth(self.history).x
                for t, k in self.rows:
                    writer.write(t, self.model.estimate_of(xs[k]))
        finally:
            writer.close()
        return writer.seq
