"""The link proxy: every link between two nodes passes through it, so a campaign can cut,
slow, lose or reset the links between chosen nodes on one host, without root.

For every ordered pair (A, B) of nodes it listens on a port of its own; node A connects to
B through that port (the bus overrides of :mod:`hera.campaign.links` give each node its
own connect endpoints) and the proxy forwards the bytes both ways to B's real endpoint.
So every TCP connection belongs to one unordered pair {A, B}, and a rule set on the pair
applies to every connection between them, both ways:

- ``pass``: bytes go through (after ``delay_ms`` +/- ``jitter_ms`` and the loss below);
- ``blackhole``: nothing goes through and nothing is closed: the bytes wait in the proxy,
  as unacknowledged segments wait in a sender's buffer, so each side's link lease runs out
  as on a cut cable; a close is held back too, and a new connection is accepted but not
  taken further. On healing, what waited is delivered in order (as TCP retransmits);
- ``reset``: every connection of the pair is closed with a TCP reset, and new ones are
  reset as they come (a "connection refused" for the dialer);
- ``loss`` (0..1): TCP does not lose bytes, it retransmits them: each chunk read is held
  one retransmission timeout (0.2 s, Linux's minimum, doubling while the retry is lost
  again) with probability ``loss``, and the chunks behind it wait for it (head-of-line
  blocking). That is what packet loss does to a Zenoh link.

Order is always kept (a byte stream). Limits: the proxy works on chunks as read (a few
Zenoh batches), not on packets; the dialer of a blackholed pair sees its connect succeed
(the proxy accepts) and its Zenoh handshake time out, where a real partition would let the
SYN time out; timings are those of one Python process (sub-millisecond added latency on
loopback, see the README's campaign section).

Run as a process (``python -m hera.campaign.linkproxy PLAN``); it is controlled through a
Unix socket (JSON lines, :func:`hera.campaign.links.control`) and stops when its parent
process is gone.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import signal
import socket
import struct
import sys
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hera import cliargs

MODES = ("pass", "blackhole", "reset")
RTO_S = 0.2
"""First retransmission timeout (Linux's minimum)."""
RTO_MAX_S = 3.0
HOLD_LIMIT = 4 << 20
"""Bytes a direction may hold before the proxy stops reading from its source (the sender's
buffer is then full, as on a real link)."""


@dataclass
class Rule:
    """What happens to the bytes of one pair of nodes."""

    mode: str = "pass"
    loss: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0

    def check(self) -> Rule:
        """This rule; ValueError naming the bad field otherwise."""
        if self.mode not in MODES:
            raise ValueError(f"link mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"link loss must be within [0, 1), got {self.loss!r}")
        if self.delay_ms < 0 or self.jitter_ms < 0:
            raise ValueError("link delay_ms and jitter_ms must be >= 0")
        return self

    def as_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "loss": self.loss,
            "delay_ms": self.delay_ms,
            "jitter_ms": self.jitter_ms,
        }


def pair_of(a: str, b: str) -> tuple[str, str]:
    """The unordered pair {a, b} as a sorted tuple."""
    return (a, b) if a <= b else (b, a)


@dataclass
class Pair:
    """The rule of one pair of nodes, its open connections and its counters."""

    rule: Rule = field(default_factory=Rule)
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    conns: set[Conn] = field(default_factory=set)
    forwarded: int = 0
    held_chunks: int = 0
    retransmits: int = 0
    resets: int = 0
    accepted: int = 0

    def set(self, rule: Rule) -> None:
        self.rule = rule
        old, self.changed = self.changed, asyncio.Event()
        old.set()  # wake everything waiting on the old rule
        if rule.mode == "reset":
            for c in list(self.conns):
                c.reset()

    @property
    def blocked(self) -> bool:
        return self.rule.mode == "blackhole"


def _rst(writer: asyncio.StreamWriter | None) -> None:
    """Close a connection with a TCP reset (SO_LINGER 0)."""
    if writer is None:
        return
    sock = writer.get_extra_info("socket")
    with contextlib.suppress(OSError):
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()


class Direction:
    """The chunks of one direction of a connection, each with the time it may be
    delivered (non-decreasing: a byte stream keeps its order)."""

    def __init__(self) -> None:
        self.queue: deque[tuple[float, bytes]] = deque()
        self.ready = asyncio.Event()
        self.held = 0
        self.last = 0.0

    def put(self, at: float, data: bytes) -> None:
        self.last = at
        self.queue.append((at, data))
        self.held += len(data)
        self.ready.set()


class Conn:
    """One proxied TCP connection of a pair: the dialer's side and the listener's side,
    and a :class:`Direction` each way."""

    def __init__(self, pair: Pair, rng: random.Random) -> None:
        self.pair = pair
        self.rng = rng
        self.ends: list[asyncio.StreamWriter] = []
        self.tasks: list[asyncio.Task] = []
        self.closed = False

    def reset(self) -> None:
        self.pair.resets += 1
        self.close(rst=True)

    def close(self, rst: bool = False) -> None:
        if self.closed:
            return
        self.closed = True
        self.pair.conns.discard(self)
        for w in self.ends:
            if rst:
                _rst(w)
            else:
                with contextlib.suppress(Exception):
                    w.close()
        for t in self.tasks:
            if t is not asyncio.current_task():
                t.cancel()

    def release_time(self, now: float, last: float) -> float:
        """When a chunk read ``now`` may be delivered under the pair's current rule."""
        r = self.pair.rule
        at = now + r.delay_ms / 1000.0
        if r.jitter_ms:
            at += self.rng.uniform(-r.jitter_ms, r.jitter_ms) / 1000.0
        rto = RTO_S
        while r.loss and self.rng.random() < r.loss:  # emulated retransmission
            at += rto
            rto = min(2 * rto, RTO_MAX_S)
            self.pair.retransmits += 1
        return max(at, last, now)

    async def run(
        self,
        client: tuple[asyncio.StreamReader, asyncio.StreamWriter],
        target: tuple[str, int],
    ) -> None:
        pair = self.pair
        cr, cw = client
        self.ends.append(cw)
        pair.conns.add(self)
        if pair.rule.mode == "reset":
            self.reset()
            return
        up = Direction()
        # read the dialer at once (its bytes wait here while the pair is cut)
        self.tasks.append(asyncio.ensure_future(self._read(cr, up)))
        while pair.blocked and not self.closed:  # a cut link: the SYN goes nowhere
            await pair.changed.wait()
        if self.closed:
            return
        try:
            tr, tw = await asyncio.open_connection(*target)
        except OSError:
            self.close()
            return
        if self.closed:
            _rst(tw)
            return
        self.ends.append(tw)
        with contextlib.suppress(Exception):
            tw.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        down = Direction()
        self.tasks += [
            asyncio.ensure_future(self._write(up, tw)),
            asyncio.ensure_future(self._read(tr, down)),
            asyncio.ensure_future(self._write(down, cw)),
        ]
        await asyncio.gather(*self.tasks, return_exceptions=True)
        self.close()

    async def _read(self, src: asyncio.StreamReader, d: Direction) -> None:
        loop = asyncio.get_running_loop()
        try:
            while not self.closed:
                data = await src.read(65536)
                d.put(self.release_time(loop.time(), d.last), data)
                if not data:
                    return
                while d.held > HOLD_LIMIT and not self.closed:
                    await asyncio.sleep(0.01)  # the sender's buffer is full
        except (ConnectionError, OSError):
            d.put(d.last, b"")

    async def _write(self, d: Direction, dst: asyncio.StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        pair = self.pair
        try:
            while not self.closed:
                while not d.queue:
                    d.ready.clear()
                    await d.ready.wait()
                if pair.blocked:
                    pair.held_chunks += 1
                    await pair.changed.wait()
                    continue
                at, data = d.queue[0]
                wait = at - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                    continue  # the rule may have changed meanwhile
                d.queue.popleft()
                d.held -= len(data)
                if not data:
                    with contextlib.suppress(OSError):
                        dst.write_eof()
                    return
                dst.write(data)
                pair.forwarded += len(data)
                await dst.drain()
        except (ConnectionError, OSError):
            self.close()


class LinkProxy:
    """The proxy of one cluster (see the module docstring)."""

    def __init__(self, links: Iterable[dict[str, Any]], seed: int = 0) -> None:
        self.links = [dict(link) for link in links]
        self.pairs: dict[tuple[str, str], Pair] = {}
        self.rng = random.Random(seed)
        self.servers: list[asyncio.AbstractServer] = []

    def pair(self, a: str, b: str) -> Pair:
        key = pair_of(a, b)
        if key not in self.pairs:
            self.pairs[key] = Pair()
        return self.pairs[key]

    async def start(self, host: str = "127.0.0.1") -> None:
        """Listen on every link's port."""
        for link in self.links:
            pair = self.pair(link["from"], link["to"])
            target = (link.get("target_host", host), int(link["target"]))

            async def accept(r, w, pair=pair, target=target) -> None:
                pair.accepted += 1
                with contextlib.suppress(Exception):
                    w.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                await Conn(pair, self.rng).run((r, w), target)

            self.servers.append(await asyncio.start_server(accept, host, int(link["port"])))

    def command(self, req: dict[str, Any]) -> dict[str, Any]:
        """One control request (JSON): ``{"op": "set", "pairs": [[a, b], ...], "mode",
        "loss", "delay_ms", "jitter_ms"}`` (absent fields: pass, 0), ``{"op": "clear",
        "pairs"?}`` (every pair when absent), ``{"op": "status"}``. ValueError on a bad one."""
        op = req.get("op")
        if op == "status":
            return {"pairs": self.status()}
        if op not in ("set", "clear"):
            raise ValueError(f"link proxy op must be set, clear or status, got {op!r}")
        pairs = req.get("pairs")
        if pairs is None and op == "clear":
            keys = list(self.pairs)
        else:
            if not isinstance(pairs, list) or not all(
                isinstance(p, (list, tuple)) and len(p) == 2 for p in pairs
            ):
                raise ValueError("'pairs' must be a list of [node, node] pairs")
            keys = [pair_of(str(a), str(b)) for a, b in pairs]
            unknown = [k for k in keys if k not in self.pairs]
            if unknown:
                raise ValueError(f"no link between {unknown[0][0]} and {unknown[0][1]}")
        if op == "clear":
            rule = Rule()
        else:
            rule = Rule(
                str(req.get("mode", "pass")),
                float(req.get("loss", 0.0)),
                float(req.get("delay_ms", 0.0)),
                float(req.get("jitter_ms", 0.0)),
            ).check()
        for k in keys:
            self.pairs[k].set(rule)
        return {"pairs": [list(k) for k in keys], "rule": rule.as_dict()}

    def status(self) -> list[dict[str, Any]]:
        return [
            {
                "pair": list(k),
                **p.rule.as_dict(),
                "connections": len(p.conns),
                "accepted": p.accepted,
                "forwarded_bytes": p.forwarded,
                "retransmits": p.retransmits,
                "resets": p.resets,
            }
            for k, p in sorted(self.pairs.items())
        ]

    async def serve_control(self, path: str) -> asyncio.AbstractServer:
        """Answer JSON-line requests on the Unix socket ``path``."""

        async def handle(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            try:
                while line := await r.readline():
                    try:
                        req = json.loads(line)
                        if not isinstance(req, dict):
                            raise ValueError("a request must be a JSON object")
                        reply = {"ok": True, **self.command(req)}
                    except (ValueError, TypeError) as e:
                        reply = {"ok": False, "error": str(e)}
                    w.write((json.dumps(reply) + "\n").encode())
                    await w.drain()
            finally:
                w.close()

        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        return await asyncio.start_unix_server(handle, path)

    def close(self) -> None:
        for s in self.servers:
            s.close()
        for p in self.pairs.values():
            for c in list(p.conns):
                c.close()


async def _main(plan: dict[str, Any], parent: int | None, ready: Path | None) -> None:
    proxy = LinkProxy(plan["links"], int(plan.get("seed", 0)))
    await proxy.start(plan.get("host", "127.0.0.1"))
    control = await proxy.serve_control(plan["control"])
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    if ready is not None:
        ready.write_text(str(os.getpid()))
    try:
        while not stop.is_set():
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.25)
            if parent is not None and os.getppid() != parent:
                break
    finally:
        control.close()
        proxy.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(plan["control"])


def main(argv: list[str] | None = None) -> int:
    """``python -m hera.campaign.linkproxy PLAN [--parent-pid PID] [--ready FILE]``."""
    p = argparse.ArgumentParser(prog="hera-linkproxy")
    p.add_argument("plan", help="the links file (hera.campaign.links)")
    p.add_argument("--parent-pid", type=cliargs.count)
    p.add_argument("--ready", help="file written with the pid once every port listens")
    a = p.parse_args(argv)
    plan = json.loads(Path(a.plan).read_text())
    asyncio.run(_main(plan, a.parent_pid, Path(a.ready) if a.ready else None))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
