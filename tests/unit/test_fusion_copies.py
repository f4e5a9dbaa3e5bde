"""A model that runs on several nodes publishes each estimate from each of them: a model fed
by it fuses that estimate once, live as in ``hera replay`` (the live e5 of the train fused
every bilateration fix twice, once per node, and differed from its replay)."""

from __future__ import annotations

import pytest
from nodes_helpers import make_ctx

from hera.fusion import Copies, FusionMeasure
from hera.recordings import CsvWriter
from hera.replay import replay
from hera.store import Sample
from hera.wire import Message


def sample(node: str, t: float, values: tuple[float, ...], name: str = "fix") -> Sample:
    return Sample(name, node, 1, t, 0.0, 0.0, values)


def test_a_copy_from_another_node_is_recognised():
    c = Copies()
    assert not c.is_copy(sample("computer", 10.0, (0.1, -0.6)))
    assert c.is_copy(sample("nav_1", 10.0, (0.1, -0.6)))
    assert c.is_copy(sample("computer", 10.0, (0.1, -0.6)))


@pytest.mark.parametrize(
    "other",
    [
        sample("nav_1", 10.0, (0.1, -0.61)),  # other values at the same time: another reading
        sample("nav_1", 10.000001, (0.1, -0.6)),  # the same values a microsecond later
        sample("nav_1", 10.0, (0.1, -0.6), name="sonar"),  # another stream
    ],
)
def test_a_sample_that_differs_in_name_time_or_values_is_no_copy(other):
    c = Copies()
    assert not c.is_copy(sample("computer", 10.0, (0.1, -0.6)))
    assert not c.is_copy(other)


def test_only_the_last_samples_of_a_name_are_remembered():
    c = Copies(memory=3)
    first = sample("a", 1.0, (1.0,))
    assert not c.is_copy(first)
    for k in range(2, 5):
        assert not c.is_copy(sample("a", float(k), (1.0,)))
        assert not c.is_copy(sample("a", float(k), (1.0,), name="other"))  # its own memory
    assert not c.is_copy(first)  # pushed out by three newer ones of its name
    with pytest.raises(ValueError, match="memory must be >= 1, got 0"):
        Copies(memory=0)


class Collect:
    """Keeps what it is given."""

    inputs = ("fix",)
    columns = ("x",)

    def __init__(self) -> None:
        self.given: list[tuple[str, float, tuple]] = []

    def process(self, s) -> bool:
        self.given.append((s.node, s.t, s.values))
        return True

    def estimate(self):
        return self.given[-1][1], [self.given[-1][2][0]]


class CollectMeasure(FusionMeasure):
    name = "collect"
    model_class = Collect
    columns = Collect.columns


def test_a_fusion_measure_fuses_each_estimate_of_two_replicas_once():
    ctx = make_ctx("collect", period=0.01)
    m = CollectMeasure()
    m.init({"mode": "arrival", "reorder_s": 0.0}, ctx)
    for node in ("computer", "nav_1"):  # each replica's two fixes, the same ones
        for seq, (t, x) in enumerate(((10.0, 0.0), (10.4, 0.4)), start=1):
            ctx.store.offer("fix", node, Message(seq, t, (x, -0.6)))
    ctx.store.offer("fix", "nav_1", Message(3, 10.8, (0.9, -0.6)))  # only nav_1 has this one
    for _ in range(3):
        m.measure()
    assert [(t, v) for _, t, v in m.model.given] == [
        (10.0, (0.0, -0.6)),
        (10.4, (0.4, -0.6)),
        (10.8, (0.9, -0.6)),
    ]
    assert ctx.counters["copies"] == 2 and ctx.counters["fused"] == 5
    m.close()


def test_replay_fuses_the_recorded_estimates_of_two_replicas_once(tmp_path):
    for node in ("computer", "nav_1"):
        rec = CsvWriter(tmp_path / "rec", "fix", node, ("x", "y"))
        for t, x in ((10.0, 0.0), (10.4, 0.4)):
            rec.write(t, [x, -0.6])
        rec.close()
    counts = replay(tmp_path / "rec", tmp_path / "out", {"c": (f"{__name__}:CollectMeasure", {})})
    assert counts == {"c": 2}
