"""What a fusion measure publishes: a model's ``outputs()`` rows (a map in tiles) all, in
order; a step's newest estimate (those it replaced counted), or each with ``publish =
"every"``, as ``hera replay`` writes them. The worker publishes every reading of a list a
step returns."""

from __future__ import annotations

from nodes_helpers import make_ctx

from hera.fusion import FusionMeasure, model_outputs
from hera.recordings import CsvWriter, read_csv
from hera.replay import replay
from hera.wire import Message


class Pairs:
    """Each sample of ``a`` makes two rows: (value, 0) and (value, 1) at its time."""

    inputs = ("a",)
    columns = ("value", "part")

    def __init__(self) -> None:
        self._rows: list[tuple[float, list[float]]] = []

    def process(self, sample) -> bool:
        self._rows += [(sample.t, [sample.values[0], 0.0]), (sample.t, [sample.values[0], 1.0])]
        return True

    def estimate(self):
        raise AssertionError("a model with outputs() is never asked for estimate()")

    def outputs(self):
        out, self._rows = self._rows, []
        return out


class PairsMeasure(FusionMeasure):
    name = "pairs"
    model_class = Pairs
    columns = Pairs.columns


class Plain:
    inputs = ("a",)
    columns = ("value",)

    def process(self, sample) -> bool:
        self.last = (sample.t, [sample.values[0]])
        return True

    def estimate(self):
        return self.last


def test_a_model_without_outputs_is_read_through_estimate():
    assert model_outputs(Plain()) is None
    m = Pairs()
    assert model_outputs(m) == []


def test_rows_are_published_all_in_order():
    ctx = make_ctx("pairs", period=0.01)
    m = PairsMeasure()
    m.init({"mode": "arrival", "reorder_s": 0.0}, ctx)
    for seq, (t, v) in enumerate(((10.0, 1.5), (10.1, 2.5)), start=1):
        ctx.store.offer("a", "n2", Message(seq, t, (v,)))
    got = [r for _ in range(3) for r in m.measure() or ()]
    assert [(r.t, list(r.values)) for r in got] == [
        (10.0, [1.5, 0.0]),
        (10.0, [1.5, 1.0]),
        (10.1, [2.5, 0.0]),
        (10.1, [2.5, 1.0]),
    ]
    m.close()


class PlainMeasure(FusionMeasure):
    name = "plain"
    model_class = Plain
    columns = Plain.columns


def _three_samples_then_steps(mode: str, publish: str = "step") -> tuple[list, dict]:
    ctx = make_ctx("plain", period=0.01)
    m = PlainMeasure()
    args = {"mode": mode, "publish": publish}
    m.init({**args, "reorder_s": 0.0} if mode == "arrival" else args, ctx)
    for seq, (t, v) in enumerate(((10.0, 1.5), (10.1, 2.5), (10.2, 3.5)), start=1):
        ctx.store.offer("a", "n2", Message(seq, t, (v,)))
    got = [(r.t, list(r.values)) for _ in range(3) for r in m.measure() or ()]
    m.close()
    return got, dict(ctx.counters)


def test_a_step_publishes_its_newest_estimate_and_counts_those_it_replaced():
    """Three samples arrive before one step: the step's estimate, two superseded."""
    got, counters = _three_samples_then_steps("arrival")
    assert got == [(10.2, [3.5])] and counters["superseded"] == 2


def test_publish_every_gives_each_estimate_of_a_step():
    got, counters = _three_samples_then_steps("arrival", "every")
    assert got == [(10.0, [1.5]), (10.1, [2.5]), (10.2, [3.5])]
    assert counters.get("superseded", 0) == 0


def test_period_mode_publishes_the_estimate_of_the_step():
    got, _ = _three_samples_then_steps("period")
    assert got == [(10.2, [3.5])]


def test_replay_writes_every_row(tmp_path):
    rec = CsvWriter(tmp_path / "rec", "a", "n2", ("v",))
    for t, v in ((10.0, 1.5), (10.1, 2.5), (10.2, 3.5)):
        rec.write(t, [v])
    rec.close()
    counts = replay(tmp_path / "rec", tmp_path / "out", {"pairs": (f"{__name__}:PairsMeasure", {})})
    assert counts == {"pairs": 6}
    rows = read_csv(tmp_path / "out" / "measures" / "pairs_replay.csv", "pairs", "replay")
    assert [r.values for r in rows] == [(v, p) for v in (1.5, 2.5, 3.5) for p in (0.0, 1.0)]
