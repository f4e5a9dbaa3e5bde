"""A live fusion model's start marker (``<run>/measures/<name>_<node>.start.json``) records
where it started and what keeps ``hera replay --start-like`` from repeating it: samples given
out of time order, samples dropped to keep up, resumes from a checkpoint."""

from __future__ import annotations

import json

import pytest
from nodes_helpers import make_ctx

import hera.fusion as fusion
from hera.fusion import FusionMeasure
from hera.recordings import LiveStart, RecordingError, read_start, start_marker, write_start
from hera.replay import why_not_exact
from hera.wire import Message


class Count:
    """Counts the samples of ``a``."""

    inputs = ("a",)
    columns = ("n",)

    def __init__(self) -> None:
        self.n, self.t = 0, 0.0

    def process(self, sample) -> bool:
        self.n, self.t = self.n + 1, sample.t
        return True

    def estimate(self):
        return self.t, [float(self.n)]


class CountMeasure(FusionMeasure):
    name = "sum"
    model_class = Count
    columns = Count.columns


def started(tmp_path, **args):
    ctx = make_ctx("sum", period=0.01, run_dir=str(tmp_path))
    m = CountMeasure()
    m.init({"mode": "arrival", "reorder_s": 0.0, **args}, ctx)
    return ctx, m


def offer(ctx, seq: int, t: float) -> None:
    ctx.store.offer("a", "n2", Message(seq, t, (1.0,)))


def marker(tmp_path) -> LiveStart:
    return read_start(start_marker(tmp_path / "measures", "sum", "n1"))


def test_a_model_given_every_sample_in_order_can_be_replayed_exactly(tmp_path):
    ctx, m = started(tmp_path)
    for seq, t in enumerate((10.0, 10.1, 10.2), start=1):
        offer(ctx, seq, t)
        m.measure()
    m.close()
    assert marker(tmp_path) == LiveStart(10.0, 0, None, 0, 0)
    assert marker(tmp_path).exact is True


def test_a_sample_that_came_after_its_reorder_window_is_recorded(tmp_path):
    ctx, m = started(tmp_path)
    offer(ctx, 1, 10.0)
    offer(ctx, 2, 10.2)
    m.measure()
    offer(ctx, 3, 10.1)  # older than one the model was given already
    m.measure()
    m.close()
    live = marker(tmp_path)
    assert (live.late, live.first_late_t, live.exact) == (1, 10.1, False)
    assert why_not_exact("sum", "n1", live) == (
        "sum: live on n1 it was given 1 sample(s) out of time order, the first 0.100 s after"
        " its start; the replay may differ from there (a larger reorder_s or backlog keeps"
        " every sample in its place)"
    )


def test_samples_dropped_to_keep_up_are_recorded(tmp_path):
    ctx, m = started(tmp_path, backlog=1)
    for seq in range(1, 4):  # three of one source wait: the two oldest are dropped
        offer(ctx, seq, 10.0 + 0.1 * seq)
    m.measure()
    m.close()
    assert (marker(tmp_path).dropped, marker(tmp_path).exact) == (2, False)


def test_a_resumed_model_keeps_its_start_and_counts_the_resume(tmp_path, monkeypatch):
    monkeypatch.setattr(fusion, "CHECKPOINT_S", 0.0)
    ctx, m = started(tmp_path)
    offer(ctx, 1, 10.0)
    m.measure()
    m.close()  # the supervisor restarts it; it resumes from the checkpoint in ctx.resources
    again = CountMeasure()
    again.init({"mode": "arrival", "reorder_s": 0.0}, ctx)
    offer(ctx, 2, 10.3)
    again.measure()
    again.close()
    assert marker(tmp_path) == LiveStart(10.0, 0, None, 0, 1)
    assert "resumed from a checkpoint 1 time(s)" in why_not_exact("sum", "n1", marker(tmp_path))


def test_a_marker_of_an_older_version_says_nothing_of_exactness(tmp_path):
    path = tmp_path / "m.start.json"
    path.write_text(json.dumps({"first_sample_t": 12.5}))
    live = read_start(path)
    assert (live.first_sample_t, live.late, live.exact) == (12.5, None, None)
    assert why_not_exact("sum", "n1", live) is None
    write_start(path, LiveStart(1.0, 0, None, 0, 0))
    assert read_start(path).exact is True


@pytest.mark.parametrize(
    "text, says",
    [
        ("not json", "not a start marker"),
        ("[1, 2]", "a JSON object is expected"),
        ('{"late": 0}', "first_sample_t must be a number"),
        ('{"first_sample_t": 1.0, "late": -1}', "late must be an integer >= 0, got -1"),
        ('{"first_sample_t": 1.0, "dropped": true}', "dropped must be an integer >= 0, got True"),
        ('{"first_sample_t": 1.0, "first_late_t": "x"}', "first_late_t must be a number or null"),
    ],
)
def test_a_bad_marker_is_named_with_what_is_wrong(tmp_path, text, says):
    path = tmp_path / "m.start.json"
    path.write_text(text)
    with pytest.raises(RecordingError, match=str(path)) as e:
        read_start(path)
    assert says in str(e.value)
