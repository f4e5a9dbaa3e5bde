"""The ports a launcher picks for its nodes (hera/ports.py): below the kernel's ephemeral
range, so no ``bind(0)`` of another process takes one before its node binds it; a port a
stopped cluster left in TIME_WAIT is free for the next one."""

from __future__ import annotations

import random
import socket
from pathlib import Path

import pytest

from hera.ports import IANA_EPHEMERAL, WINDOW, ephemeral_range, free_ports, port_taken


def test_the_ports_lie_below_the_ephemeral_range_and_are_free():
    low, _ = ephemeral_range()
    ports = free_ports("127.0.0.1", 5)
    assert len(set(ports)) == 5
    assert all(max(1024, low - WINDOW) <= p < low for p in ports), (ports, low)
    held = []
    try:
        for p in ports:  # free: each one binds
            s = socket.socket()
            held.append(s)
            s.bind(("127.0.0.1", p))
    finally:
        for s in held:
            s.close()


def test_no_bind_to_port_zero_takes_a_picked_port():
    """What failed a cluster start in CI: between the pick and the node's bind, another
    process's ``bind(0)`` (a Zenoh session listening on port 0) got a picked port. With
    ports from the ephemeral range, 20 000 such binds hit one of three ports about 5 times."""
    ports = set(free_ports("127.0.0.1", 3))
    for _ in range(20_000):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            assert s.getsockname()[1] not in ports


def test_a_busy_port_is_skipped():
    first = free_ports("127.0.0.1", 1, rng=random.Random(7))[0]
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", first))
        again = free_ports("127.0.0.1", 3, rng=random.Random(7))
    assert first not in again and len(set(again)) == 3


def test_without_room_below_the_range_the_kernel_picks():
    ports = free_ports("127.0.0.1", 4, ephemeral=(1024, 65535))
    low, high = ephemeral_range()
    assert len(set(ports)) == 4 and all(low <= p <= high for p in ports), ports


def test_the_range_is_read_from_the_kernel_file(tmp_path: Path):
    good = tmp_path / "range"
    good.write_text("40000\t50000\n")
    assert ephemeral_range(good) == (40000, 50000)
    bad = tmp_path / "bad"
    bad.write_text("forty\n")
    assert ephemeral_range(bad) == IANA_EPHEMERAL
    assert ephemeral_range(tmp_path / "missing") == IANA_EPHEMERAL


def _time_wait_port() -> int:
    """A loopback port held only by a connection in TIME_WAIT: the server side of an
    accepted connection closes first, then the client and the listener (which binds as
    Zenoh's listeners do, with SO_REUSEADDR, which its connections inherit)."""
    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        client = socket.create_connection(("127.0.0.1", port))
        conn, _ = listener.accept()
        conn.close()  # the side that closes first keeps the TIME_WAIT
        client.recv(1)  # its FIN seen
        client.close()
    return port


def test_a_port_left_in_time_wait_by_a_stopped_cluster_is_free_for_a_server():
    port = _time_wait_port()
    with socket.socket() as plain, pytest.raises(OSError):  # what a plain bind says
        plain.bind(("127.0.0.1", port))
    assert port_taken("127.0.0.1", port) is None
    with socket.socket() as server:  # and a server really listens there
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen()
        # while it listens, the port is taken
        e = port_taken("127.0.0.1", port)
        assert e is not None and e.strerror == "Address already in use"
