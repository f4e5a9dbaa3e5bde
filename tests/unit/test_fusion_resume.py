"""A fusion measure the supervisor restarts resumes its model from the checkpoint of its
previous incarnation (kept in the node's resources), unless the model raised, its settings changed,
the checkpoint is too old, or ``resume_s = 0``; a resumed model never repeats its rows."""

from __future__ import annotations

import dataclasses

import pytest
from nodes_helpers import make_ctx

import hera.fusion as fusion
from hera import checkpoints
from hera.fusion import FusionMeasure
from hera.wire import Message


class Sum:
    """Sums the values of ``a``; raises on a value of -1 (a model that breaks)."""

    inputs = ("a",)
    columns = ("total", "n")

    def __init__(self, scale: float = 1.0) -> None:
        self.scale = scale
        self.total = 0.0
        self.n = 0
        self.t = 0.0
        self._rows: list = []

    def process(self, sample) -> bool:
        if sample.values[0] == -1:
            raise ArithmeticError("the model broke")
        self.total += self.scale * sample.values[0]
        self.n += 1
        self.t = sample.t
        return True

    def estimate(self):
        return (self.t, [self.total, float(self.n)])


class SumMeasure(FusionMeasure):
    name = "sum"
    model_class = Sum
    columns = Sum.columns


class Rows(Sum):
    def process(self, sample) -> bool:
        super().process(sample)
        self._rows.append((sample.t, [self.total, float(self.n)]))
        return True

    def outputs(self):
        out, self._rows = self._rows, []
        return out


class RowsMeasure(SumMeasure):
    model_class = Rows


@pytest.fixture(autouse=True)
def every_step(monkeypatch):
    """A checkpoint at every step that changed the model (not only each second)."""
    monkeypatch.setattr(fusion, "CHECKPOINT_S", 0.0)


def feed(ctx, seq0: int, values: list[float]) -> None:
    for i, v in enumerate(values):
        ctx.store.offer("a", "n2", Message(seq0 + i, 10.0 + 0.1 * (seq0 + i), (v,)))


def start(ctx, cls=SumMeasure, **args) -> FusionMeasure:
    m = cls()
    m.init({"mode": "arrival", "reorder_s": 0.0, **args}, ctx)
    return m


def drain(m: FusionMeasure) -> list:
    return [r for _ in range(3) for r in m.measure() or ()]


def test_a_restarted_measure_resumes_where_it_was():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx)
    feed(ctx, 1, [1.0, 2.0, 3.0])
    drain(m)
    m.close()  # the supervisor drops it (a crash elsewhere than the model, a hang)
    again = start(ctx)
    assert (again.model.total, again.model.n) == (6.0, 3)
    assert again.ctx.counters["resumed"] == 1
    feed(ctx, 4, [4.0])
    drain(again)
    assert (again.model.total, again.model.n) == (10.0, 4)
    assert again.model is not m.model
    again.close()
    third = start(ctx)  # from the newest checkpoint, not the first
    assert (third.model.total, third.model.n) == (10.0, 4)
    third.close()


def test_the_checkpoint_is_a_copy_the_resumed_model_cannot_change():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx)
    feed(ctx, 1, [1.0])
    drain(m)
    a = start(ctx)
    a.model.total = 99.0  # the resumed model runs on, then dies before its next copy
    b = start(ctx)
    assert b.model.total == 1.0


def test_a_model_that_raised_starts_afresh():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx)
    feed(ctx, 1, [1.0, 2.0])
    drain(m)
    feed(ctx, 3, [-1.0])
    with pytest.raises(ArithmeticError):
        drain(m)
    again = start(ctx)
    assert (again.model.total, again.model.n) == (0.0, 0)
    assert "resumed" not in again.ctx.counters


@pytest.mark.parametrize(
    "args",
    [{"model": {"scale": 2.0}}, {"resume_s": 0}, {"resume_s": 1e-9}],
    ids=["settings changed", "resume off", "too old"],
)
def test_it_starts_afresh_when_the_checkpoint_does_not_fit(args):
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx)
    feed(ctx, 1, [1.0, 2.0])
    drain(m)
    again = start(ctx, **args)
    assert (again.model.total, again.model.n) == (0.0, 0)
    if args.get("resume_s") == 0:  # and no checkpoint is kept for later either
        assert ctx.resources.get(fusion.CHECKPOINT_KEY + "sum") is None


def test_a_resumed_model_never_repeats_rows_it_published():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx, RowsMeasure)
    feed(ctx, 1, [1.0, 2.0])
    first = drain(m)
    assert [list(r.values) for r in first] == [[1.0, 1.0], [3.0, 2.0]]
    again = start(ctx, RowsMeasure)
    assert drain(again) == []  # nothing new: nothing out
    feed(ctx, 3, [3.0])
    assert [list(r.values) for r in drain(again)] == [[6.0, 3.0]]


def test_samples_fused_before_the_restart_are_not_fused_again():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx, mode="period")
    feed(ctx, 1, [1.0])
    m.measure()
    again = start(ctx, mode="period")  # the store still holds seq 1: it is not new to it
    again.measure()
    assert (again.model.total, again.model.n) == (1.0, 1)


def test_another_node_never_resumes_this_ones_model():
    ctx = make_ctx("sum", period=0.01)
    m = start(ctx)
    feed(ctx, 1, [1.0])
    drain(m)
    other = start(make_ctx("sum", period=0.01))  # same names, another node's resources
    assert (other.model.total, other.model.n) == (0.0, 0)


# -- across node processes: the checkpoint in the node's state directory -----------------


def on_disk(tmp_path, resources=None):
    """A measure context of node n1 with a state directory; fresh resources and store
    stand for a new node process."""
    return dataclasses.replace(
        make_ctx("sum", period=0.01, resources=resources), state_dir=str(tmp_path)
    )


def feed_from(ctx, node: str, seq0: int, values: list[float]) -> None:
    for i, v in enumerate(values):
        ctx.store.offer("a", node, Message(seq0 + i, 10.0 + 0.1 * (seq0 + i), (v,)))


def test_a_restarted_node_process_resumes_from_its_state_directory(tmp_path):
    ctx = on_disk(tmp_path)
    m = start(ctx)
    feed_from(ctx, "n2", 1, [1.0, 2.0])
    feed_from(ctx, "n1", 1, [3.0])  # this node's own stream
    drain(m)
    assert checkpoints.path_of(tmp_path, "sum").exists()
    again = start(on_disk(tmp_path))  # a new process: nothing in memory, a new store
    assert (again.model.total, again.model.n) == (6.0, 3)
    assert again.ctx.counters["resumed"] == 1
    feed_from(again.ctx, "n2", 2, [20.0])  # n2's seq 2 was fused before: skipped
    feed_from(again.ctx, "n1", 1, [4.0])  # this node numbers afresh: fused
    feed_from(again.ctx, "n2", 3, [5.0])
    drain(again)
    assert (again.model.total, again.model.n) == (15.0, 5)


@pytest.mark.parametrize(
    "args",
    [{"model": {"scale": 2.0}}, {"resume_s": 1e-9}],
    ids=["settings changed", "too old"],
)
def test_a_new_process_starts_afresh_when_the_file_does_not_fit(tmp_path, args):
    ctx = on_disk(tmp_path)
    drain_after(start(ctx), ctx, [1.0, 2.0])
    again = start(on_disk(tmp_path), **args)
    assert (again.model.total, again.model.n) == (0.0, 0)


def drain_after(m, ctx, values):
    feed_from(ctx, "n2", 1, values)
    drain(m)


def test_a_model_that_raised_or_resume_off_leaves_no_file(tmp_path):
    ctx = on_disk(tmp_path)
    m = start(ctx)
    drain_after(m, ctx, [1.0])
    feed_from(ctx, "n2", 2, [-1.0])
    with pytest.raises(ArithmeticError):
        drain(m)
    assert not checkpoints.path_of(tmp_path, "sum").exists()
    assert start(on_disk(tmp_path)).model.n == 0
    ctx = on_disk(tmp_path)
    drain_after(start(ctx), ctx, [1.0])
    assert checkpoints.path_of(tmp_path, "sum").exists()
    start(on_disk(tmp_path), resume_s=0)
    assert not checkpoints.path_of(tmp_path, "sum").exists()


def test_a_new_run_of_the_cluster_starts_afresh(tmp_path):
    """The state directory outlives runs (args, calibrations); a model does not: a new
    ``hera up`` (a new run directory) within resume_s of the last one starts cold."""
    ctx = dataclasses.replace(on_disk(tmp_path), run_dir=str(tmp_path / "run1"))
    drain_after(start(ctx), ctx, [1.0])
    same = dataclasses.replace(on_disk(tmp_path), run_dir=str(tmp_path / "run1"))
    assert start(same).model.n == 1
    other = dataclasses.replace(on_disk(tmp_path), run_dir=str(tmp_path / "run2"))
    assert start(other).model.n == 0


def test_a_torn_file_is_no_checkpoint(tmp_path):
    ctx = on_disk(tmp_path)
    drain_after(start(ctx), ctx, [1.0])
    path = checkpoints.path_of(tmp_path, "sum")
    path.write_bytes(path.read_bytes()[:20])
    again = start(on_disk(tmp_path))
    assert (again.model.total, again.model.n) == (0.0, 0)


class Unpicklable(Sum):
    def __init__(self, scale: float = 1.0) -> None:
        super().__init__(scale)
        self.hook = lambda x: x  # copied by deepcopy, refused by pickle


class UnpicklableMeasure(SumMeasure):
    model_class = Unpicklable


def test_a_model_pickle_refuses_keeps_its_checkpoints_in_memory(tmp_path, caplog):
    resources = make_ctx("sum").resources
    ctx = on_disk(tmp_path, resources)
    m = start(ctx, UnpicklableMeasure)
    drain_after(m, ctx, [1.0, 2.0])
    assert not checkpoints.path_of(tmp_path, "sum").exists()
    assert "no checkpoints of the model on disk" in caplog.text
    again = start(on_disk(tmp_path, resources), UnpicklableMeasure)  # same process
    assert (again.model.total, again.model.n) == (3.0, 2)
