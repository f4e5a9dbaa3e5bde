import threading
import time

from hera.store import Store
from hera.wire import Message


def msg(seq, t=0.0, *values):
    return Message(seq, t, tuple(values))


def test_only_strictly_newer_seq_replaces_the_held_sample():
    s = Store()
    assert s.offer("a", "n1", msg(2, 1.0, 10.0))
    assert not s.offer("a", "n1", msg(2, 1.0, 11.0))  # duplicate
    assert not s.offer("a", "n1", msg(1, 1.0, 12.0))  # reordered, older
    assert s.offer("a", "n1", msg(3, 1.0, 13.0))
    assert s.get_one("a", "n1").values == (13.0,)
    assert (s.accepted, s.stale) == (2, 2)


def test_get_returns_every_node_and_fresh_filters_by_age_and_time():
    s = Store()
    s.offer("a", "n2", msg(1, 100.0, 1.0), arrival=10.0)
    s.offer("a", "n1", msg(1, 200.0, 2.0), arrival=19.0)
    s.offer("b", "n1", msg(1, 200.0, 3.0), arrival=19.0)
    assert [x.node for x in s.get("a")] == ["n1", "n2"]
    assert [x.node for x in s.fresh("a", max_age=5.0, now=20.0)] == ["n1"]
    assert [x.node for x in s.fresh("a", newer_than=150.0, now=20.0)] == ["n1"]
    assert s.fresh("a", max_age=0.5, now=20.0) == []
    assert s.names() == ["a", "b"]
    assert s.seqs_of_node("n1") == {"a": (0, 1), "b": (0, 1)}
    assert s.latest_seq("a", "n3") == 0


def test_samples_holds_the_latest_of_each_source_and_snapshot_sorts_them():
    s = Store()
    s.offer("b", "n1", msg(1, 1.0, 1.0))
    s.offer("a", "n2", msg(1, 1.0, 2.0))
    s.offer("a", "n1", msg(1, 1.0, 3.0))
    s.offer("a", "n1", msg(2, 1.0, 4.0))
    held = {(x.name, x.node, x.values) for x in s.samples()}
    assert held == {("b", "n1", (1.0,)), ("a", "n2", (2.0,)), ("a", "n1", (4.0,))}
    assert len(s.samples()) == 3
    assert [(x.name, x.node) for x in s.snapshot()] == [("a", "n1"), ("a", "n2"), ("b", "n1")]


def test_cursor_returns_each_sample_once():
    s = Store()
    cur = s.cursor(["a"])
    s.offer("a", "n1", msg(1))
    assert [x.seq for x in cur.new()] == [1]
    assert cur.new() == []
    s.offer("a", "n1", msg(2))
    s.offer("a", "n2", msg(1))
    assert sorted((x.node, x.seq) for x in cur.new()) == [("n1", 2), ("n2", 1)]


def test_concurrent_writers_keep_the_highest_seq():
    s = Store()

    def writer(start):
        for seq in range(start, 5000, 4):
            s.offer("a", "n1", msg(seq))

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(1, 5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert s.latest_seq("a", "n1") == 4999


def test_wait_newer_wakes_on_accepted_sample():
    """Woken by the offer, not by its timeout (which returns the same version later): the
    offer notifies only when a thread waits, so the waiter must be seen waiting."""
    s = Store()
    v = s.version
    threading.Timer(0.05, lambda: s.offer("a", "n", msg(1))).start()
    t0 = time.monotonic()
    assert s.wait_newer(v, timeout=60.0) == v + 1
    assert time.monotonic() - t0 < 30.0  # not the timeout's 60 s
