import threading
import time

import pytest
import zenoh
from harness import wait_for

from hera.args import ArgsStore
from hera.bus import BusConfig, open_session, tcp_endpoint
from hera.keys import Keys
from hera.peers import Peers
from hera.ports import free_ports


def test_last_writer_wins_by_timestamp_then_origin():
    a = ArgsStore("a")
    a._merge("k", 10, "a", 1)
    a._merge("k", 5, "z", 2)  # older: ignored
    assert a.get("k") == 1
    a._merge("k", 10, "b", 3)  # same time: the larger origin wins, on every replica
    assert a.get("k") == 3


def test_persisted_and_reloaded(tmp_path):
    a = ArgsStore("a", state_dir=tmp_path)
    a.put("calib/n1/mag", {"bx": 0.1, "by": -0.2})
    b = ArgsStore("a", state_dir=tmp_path)
    assert b.get("calib/n1/mag") == {"bx": 0.1, "by": -0.2}


def test_damaged_file_is_ignored_not_fatal(tmp_path):
    (tmp_path / ArgsStore.FILE).write_bytes(b"\xc1garbage")
    assert ArgsStore("a", state_dir=tmp_path).items() == {}


def test_bad_keys_and_values_are_refused():
    a = ArgsStore("a")
    with pytest.raises(ValueError, match="args key element"):
        a.put("a/*/b", 1)
    with pytest.raises(ValueError, match="cannot be stored"):
        a.put("k", object())


def test_replicates_between_sessions_and_recovers_on_start():
    keys = Keys("argtest")
    p1, p2, p3 = free_ports("127.0.0.1", 3)
    e1, e2 = tcp_endpoint("127.0.0.1", p1), tcp_endpoint("127.0.0.1", p2)
    s1 = open_session(BusConfig(listen=(e1,)))
    s2 = open_session(BusConfig(listen=(e2,), connect=(e1,)))
    a1 = ArgsStore("n1", s1, keys)
    a2 = ArgsStore("n2", s2, keys)
    try:
        time.sleep(0.2)
        a1.put("gain", 2.5)
        wait_for(lambda: a2.get("gain") == 2.5, 5, "replication")
        a2.put("gain", 3.0)
        wait_for(lambda: a1.get("gain") == 3.0, 5, "replication back")
        # a node that starts later gets everything from the live peers
        s3 = open_session(BusConfig(listen=(tcp_endpoint("127.0.0.1", p3),), connect=(e1, e2)))
        a3 = ArgsStore("n3", s3, keys)
        try:
            wait_for(lambda: a3.recover(timeout=1.0) >= 0 and a3.get("gain") == 3.0, 5, "recovery")
        finally:
            a3.close()
            s3.close()
    finally:
        a1.close()
        a2.close()
        s1.close()
        s2.close()


@pytest.mark.parametrize("hooked", [True, False], ids=["peer-up pull", "no pull"])
def test_a_write_made_before_the_link_existed_reaches_the_peer_when_it_comes_up(hooked):
    """Two nodes starting together: n1 writes while no link to n2 exists (its put reaches
    nobody) and n2 never calls recover. With the peer-up hook a node wires (liveliness ->
    Peers.on_up -> ArgsStore.on_peer_up), n2 takes the entry once n1's token reaches it;
    without it, n2 never does (the case the hook is for)."""
    keys = Keys("argup")
    p1, p2 = free_ports("127.0.0.1", 2)
    e1, e2 = tcp_endpoint("127.0.0.1", p1), tcp_endpoint("127.0.0.1", p2)
    s1 = open_session(BusConfig(listen=(e1,)))
    a1 = ArgsStore("n1", s1, keys)
    a1.put("calib/n1/imu", [0.1, 0.2])  # nobody to hear it
    token = s1.liveliness().declare_token(keys.alive("n1"))
    s2 = open_session(BusConfig(listen=(e2,), connect=(e1,)))
    a2 = ArgsStore("n2", s2, keys)
    peers = Peers(keys, on_up=a2.on_peer_up if hooked else None)
    sub = s2.liveliness().declare_subscriber(keys.alive_all, peers.on_alive, history=True)
    try:
        wait_for(lambda: "n1" in peers.up, 5, "n2 to see n1 up")
        if hooked:
            wait_for(lambda: a2.get("calib/n1/imu") == [0.1, 0.2], 5, "the pull on peer-up")
        else:
            # n1 seen up by n2 says nothing of the other direction: n2's subscription may
            # reach n1 later (a put before it reaches nobody; a CI failure). A write made
            # once n1 knows of it (a remote match on n1) does arrive...
            probe = s1.declare_publisher(
                keys.args("other"), allowed_destination=zenoh.Locality.REMOTE
            )
            try:
                wait_for(lambda: probe.matching_status.matching, 5, "n1 to see n2's subscriber")
            finally:
                probe.undeclare()
            a1.put("other", 1)
            wait_for(lambda: a2.get("other") == 1, 5, "a later write")
            assert a2.get("calib/n1/imu") is None  # ...the earlier one never does
    finally:
        sub.undeclare()
        token.undeclare()
        a1.close()
        a2.close()
        s1.close()
        s2.close()


def test_two_threads_saving_at_once_keep_both_keys_on_disk(tmp_path, monkeypatch):
    """A fault campaign found a calibration missing from a node's state file: two measures
    stored theirs at once, and the save holding the older snapshot replaced the newer file.
    The older snapshot is made slow here; both keys must be on disk all the same."""
    import threading
    import time

    import msgpack

    from hera import args as args_module

    real = msgpack.packb

    def slow_when_small(data, **kw):
        if len(data) == 1:
            time.sleep(0.2)  # the first snapshot is written last, in the old code
        return real(data, **kw)

    monkeypatch.setattr(args_module.msgpack, "packb", slow_when_small)
    store = ArgsStore("n1", state_dir=tmp_path)
    first = threading.Thread(target=store.put, args=("calib/n1/nav", 1))
    first.start()
    time.sleep(0.05)
    store.put("calib/n1/mag", 2)
    first.join()
    monkeypatch.setattr(args_module.msgpack, "packb", real)
    assert ArgsStore("n1", state_dir=tmp_path).items() == {"calib/n1/nav": 1, "calib/n1/mag": 2}


class _QuietSession:
    """Stands in for a Zenoh session in a unit test of ArgsStore alone: declares nothing."""

    def declare_subscriber(self, *a, **k):
        return None

    def declare_queryable(self, *a, **k):
        return None


def test_peers_coming_up_together_share_pulls_and_none_is_missed():
    store = ArgsStore("a", _QuietSession(), Keys("c"))
    started, release, calls = threading.Event(), threading.Event(), []

    def recover(timeout: float = 1.0) -> int:
        calls.append(timeout)
        started.set()
        release.wait(5)
        return 0

    store.recover = recover
    store.on_peer_up("a")  # itself: no pull
    store.on_peer_up("b")
    assert started.wait(5)
    for peer in "cdefg":  # they come up while b's pull runs: one more pull, after it
        store.on_peer_up(peer)
    release.set()
    wait_for(lambda: len(calls) == 2 and not store._pulling, 5, "the pulls done")
    assert len(calls) == 2
    store.on_peer_up("h")  # a later peer-up gets a pull of its own
    wait_for(lambda: len(calls) == 3, 5, "h's pull")
