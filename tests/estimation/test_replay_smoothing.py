"""``hera.smoothing`` (``hera replay --smooth``) on a small model: which models it takes,
and that each written estimate is its step's smoothed state (the end-to-end check against
the truth of a recorded train run is in tests/models/test_train_cluster.py)."""

from __future__ import annotations

import numpy as np
import pytest

from hera.estimation import (
    KalmanFilter,
    Observations,
    UnscentedKalmanFilter,
    record,
    smooth,
)
from hera.recordings import read_csv
from hera.smoothing import NotSmoothable, SmoothedRun, smoothed_dir


class Walker:
    """A constant-velocity model of one coordinate; outputs [position]."""

    columns = ("p [m]",)

    def __init__(self) -> None:
        self.filter = KalmanFilter(
            [0.0, 0.0], np.eye(2), F=lambda dt: np.array([[1.0, dt], [0.0, 1.0]]), Q=0.01
        )

    def step(self, dt: float, z: float | None) -> None:
        self.filter.predict(dt)
        if z is not None:
            self.filter.update(Observations().add("p", [z], H=[[1.0, 0.0]], R=0.25))

    def estimate_of(self, x: np.ndarray) -> list[float]:
        return [float(x[0])]


def test_each_estimate_is_written_from_its_steps_smoothed_state(tmp_path):
    rng = np.random.default_rng(3)
    model = Walker()
    reference = Walker()
    hist = record(reference.filter)
    run = SmoothedRun(model, "model 'walker'")
    t, marks = 0.0, []
    for k in range(60):
        z = 0.1 * k + rng.normal(scale=0.5) if k % 3 else None  # some steps predict only
        t += 0.1
        for m in (model, reference):
            m.step(0.1, z)
        if k % 2:  # estimates are written at some steps only
            run.mark(t)
            marks.append((t, len(hist) - 1))
    rows = run.write(tmp_path, "walker", "replay", Walker.columns)
    assert rows == len(marks) == 30
    xs = smooth(hist).x
    got = read_csv(smoothed_dir(tmp_path) / "measures" / "walker_replay.csv", "walker", "replay")
    assert [round(r.t, 3) for r in got] == [round(t, 3) for t, _ in marks]
    expected = [xs[k][0] for _, k in marks]
    np.testing.assert_allclose([r.values[0] for r in got], expected, rtol=0, atol=1e-12)
    # the smoother used later samples: the estimates differ from the filtered ones
    filtered = [hist.posts[k][0][0] for _, k in marks]
    assert np.isclose(expected[-1], filtered[-1]) and not np.allclose(expected, filtered)


def test_models_without_a_linear_or_linearised_filter_are_refused_by_name():
    class NoFilter:
        columns = ("v",)

    with pytest.raises(NotSmoothable, match="model 'x' cannot be smoothed: it has no 'filter'"):
        SmoothedRun(NoFilter(), "model 'x'")

    class Unscented(NoFilter):
        filter = UnscentedKalmanFilter([0.0], [[1.0]], f=lambda x, dt, u=None: x, Q=0.1)

        def estimate_of(self, x):
            return list(x)

    with pytest.raises(NotSmoothable, match="its filter is a UnscentedKalmanFilter"):
        SmoothedRun(Unscented(), "model 'u'")
