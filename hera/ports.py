"""Free TCP ports for the nodes and routers a launcher starts, picked where no other process
can take them before the node binds.

A launcher picks its nodes' ports, writes them to the spec every process reads, and only
then do the nodes start and bind them, about a second later. A port picked with ``bind(0)``
comes from the kernel's ephemeral range, the same range every other ``bind(0)`` (a Zenoh
session listening on port 0: the launcher's own, a tool's) and every outgoing connection
draws from: in that second one of them can take the port, and the node then fails to start
("its port is in use"). Measured on Linux: a ``bind(0)`` got one of three ports released a
moment before 14 times in 60 000. Ports picked just below the ephemeral range are never
handed out by the kernel, so only a process that names that very port can take it.
"""

from __future__ import annotations

import os
import random
import socket
from pathlib import Path

LINUX_RANGE_FILE = Path("/proc/sys/net/ipv4/ip_local_port_range")
IANA_EPHEMERAL = (49152, 65535)
"""The ephemeral range of systems without :data:`LINUX_RANGE_FILE` (macOS, BSDs)."""

WINDOW = 10_000
"""How many ports below the ephemeral range the pick draws from (never below 1024)."""


def ephemeral_range(path: Path = LINUX_RANGE_FILE) -> tuple[int, int]:
    """The ports (first, last) the kernel hands out to ``bind(0)`` and outgoing connections:
    Linux's ``ip_local_port_range``, or :data:`IANA_EPHEMERAL` where that file is missing or
    unreadable."""
    try:
        low, high = (int(x) for x in path.read_text().split())
    except (OSError, ValueError):
        return IANA_EPHEMERAL
    return low, high


def free_ports(
    host: str,
    n: int,
    ephemeral: tuple[int, int] | None = None,
    rng: random.Random | None = None,
) -> list[int]:
    """``n`` distinct TCP ports that were free on ``host`` a moment ago, drawn at random from
    the :data:`WINDOW` ports below the ephemeral range (``ephemeral``, read from the kernel
    when None), so that no ``bind(0)`` nor outgoing connection can take them before their
    node binds them. Where that window is too small (a system whose ephemeral range starts
    near 1024), the rest come from ``bind(0)`` as before."""
    low, _ = ephemeral if ephemeral is not None else ephemeral_range()
    first = max(1024, low - WINDOW)
    candidates = list(range(first, low))
    (rng or random.SystemRandom()).shuffle(candidates)
    socks: list[socket.socket] = []
    ports: list[int] = []
    try:
        for port in candidates:
            if len(ports) == n:
                break
            s = socket.socket()
            try:
                s.bind((host, port))
            except OSError:  # in use (or reserved): try the next one
                s.close()
                continue
            socks.append(s)
            ports.append(port)
        while len(ports) < n:
            s = socket.socket()
            socks.append(s)
            s.bind((host, 0))
            ports.append(s.getsockname()[1])
    finally:
        for s in socks:
            s.close()
    return ports


def port_taken(host: str, port: int) -> OSError | None:
    """Why a server could not listen on ``host:port`` now, or None when it can. The port is
    bound as a server binds it: with ``SO_REUSEADDR``, as Zenoh's and aiohttp's listeners
    do, so a port held only by connections in TIME_WAIT (a cluster just stopped: about a
    minute on Linux) is free, and one another process listens on is not."""
    with socket.socket() as s:
        if os.name != "nt":  # on Windows it would let a port be taken from its listener
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            return e
    return None
