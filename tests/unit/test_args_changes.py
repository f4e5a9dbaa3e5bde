"""Deleting replicated args (tombstones), change listeners, and the worker telling a measure
about changes of its own keys at its next step."""

from __future__ import annotations

import threading
import time

import msgpack
from harness import wait_for

from hera.args import ArgsStore, _pack, _unpack
from hera.measure import Measure, MeasureContext, MeasureSpec, own_keys, runtime_args
from hera.store import Store
from hera.worker import Worker


def test_a_delete_is_a_write_that_wins_by_time_like_any_other():
    a = ArgsStore("a")
    a._merge("k", 10, "a", 1)
    a._merge("k", 20, "b", None, True)  # deleted at 20
    assert a.get("k", "gone") == "gone" and "k" not in a and a.items() == {}
    a._merge("k", 15, "c", 3)  # an older write arriving late does not bring it back
    assert a.get("k") is None and a.entry("k") is None
    a._merge("k", 30, "c", 4)  # a newer one does
    assert a.get("k") == 4 and a.entry("k") == (30, "c", 4)


def test_tombstones_travel_and_persist(tmp_path):
    stamp, origin, value, deleted = _unpack(_pack(7, "n1", None, True))
    assert (stamp, origin, value, deleted) == (7, "n1", None, True)
    assert _unpack(_pack(7, "n1", 5))[3] is False
    a = ArgsStore("a", state_dir=tmp_path)
    a.put("calib/n1/x", 1.5)
    a.delete("calib/n1/x")
    b = ArgsStore("b", state_dir=tmp_path)
    assert "calib/n1/x" not in b and b._entries["calib/n1/x"][3] is True


def test_an_args_file_of_the_previous_layout_still_loads(tmp_path):
    (tmp_path / ArgsStore.FILE).write_bytes(msgpack.packb({"k": [5, "n1", {"v": 1}]}))
    assert ArgsStore("a", state_dir=tmp_path).get("k") == {"v": 1}


def test_listeners_hear_every_change_and_a_failing_one_loses_nothing():
    a = ArgsStore("a")
    heard = []
    a.add_listener(lambda *_: 1 / 0)
    a.add_listener(lambda key, value, deleted: heard.append((key, value, deleted)))
    a.put("x", 1)
    a._merge("x", 1, "z", 0)  # older: no change, nothing heard
    a.delete("x")
    assert heard == [("x", 1, False), ("x", None, True)]
    assert "x" not in a


def test_own_keys_and_runtime_args():
    calib, prefix = own_keys("n1", "nav")
    assert (calib, prefix) == ("calib/n1/nav", "measure/n1/nav/")
    items = {"measure/n1/nav/gain": 2, "measure/n1/navx/gain": 3, "measure/n2/nav/gain": 4}
    assert runtime_args(items, "n1", "nav") == {"gain": 2}


class Probe(Measure):
    """Publishes its ``gain``; records the changes it was told about and each init."""

    period = 0.01
    inits: list[float] = []
    told: list[dict] = []
    applies = False

    def init(self, args, ctx):
        super().init(args, ctx)
        self.gain = args["gain"]
        Probe.inits.append(self.gain)
        self.handed = None

    def measure(self):
        if self.ctx.args.get("self_write") is None:
            self.ctx.args.put("calib/n1/probe", "written by the measure itself")
            self.ctx.args.put("self_write", 1)
        return [self.gain]

    def args_changed(self, changes):
        Probe.told.append(dict(changes))
        return Probe.applies

    def code_change(self, old_version, state):
        self.handed = (old_version, state["gain"])


def worker_of(store: ArgsStore, published: list, args_source=None, gate=None) -> Worker:
    spec = MeasureSpec(use="x", name="probe", period=0.01).resolve(Probe)
    ctx = MeasureContext("n1", "c", spec, Store(), store, None, None)
    return Worker(
        Probe,
        {"gain": 1.0},
        ctx,
        lambda name, reading, grant: published.append(reading.values[0]),
        lambda w, e: None,
        args_source=args_source,
        gate=gate,
    )


def test_the_worker_recreates_the_measure_with_the_runtime_args_at_its_next_step():
    Probe.inits, Probe.told, Probe.applies = [], [], False
    store = ArgsStore("n1")
    published: list[float] = []
    w = worker_of(store, published, lambda: {"gain": store.get("measure/n1/probe/gain", 1.0)})
    w.start()
    try:
        wait_for(lambda: len(published) > 3, 5, "steps")
        assert Probe.told == []  # its own writes are not reported back to it
        store._merge("measure/n1/probe/gain", time.time_ns(), "n2", 2.5)  # from a peer
        store._merge("measure/n1/other/gain", time.time_ns(), "n2", 9.0)  # not its key
        wait_for(lambda: published[-1] == 2.5, 5, "the new gain published")
        assert Probe.told == [{"measure/n1/probe/gain": 2.5}]
        assert Probe.inits == [1.0, 2.5]
    finally:
        w.stop()
        w.thread.join(2)


def test_a_measure_that_applies_a_change_itself_is_not_recreated():
    Probe.inits, Probe.told, Probe.applies = [], [], True
    store = ArgsStore("n1")
    published: list[float] = []
    w = worker_of(store, published)
    w.start()
    try:
        wait_for(lambda: len(published) > 3, 5, "steps")
        store._merge("calib/n1/probe", time.time_ns(), "n2", None, True)  # deleted by a peer
        wait_for(lambda: Probe.told, 5, "the change told")
        assert Probe.told == [{"calib/n1/probe": None}] and Probe.inits == [1.0]
    finally:
        w.stop()
        w.thread.join(2)


def test_a_gated_worker_waits_after_init_and_takes_the_handover():
    Probe.inits, Probe.told, Probe.applies = [], [], False
    published: list[float] = []
    gate = threading.Event()
    w = worker_of(ArgsStore("n1"), published, gate=gate)
    w.start()
    assert w.ready.wait(2) and Probe.inits == [1.0]
    time.sleep(0.05)
    assert published == []  # no step before the gate opens
    w.handover = ("v1", {"gain": 3.0})
    gate.set()
    wait_for(lambda: published, 2, "a first step")
    assert w.measure.handed == ("v1", 3.0)
    w.stop()
    w.thread.join(2)
