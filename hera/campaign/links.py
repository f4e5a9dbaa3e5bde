"""The links of a cluster run behind the link proxy: the plan, the proxy process, its control.

:func:`plan_links` gives every ordered pair of nodes (A, B) a proxy port; node A connects to
B only through it (A's *connect* endpoints are replaced by the bus overrides that
:func:`write_plan` writes, see :func:`hera.bus.with_overrides`), while every node still
listens on its own endpoint, where tools connect directly (the operator's view of the
cluster is never cut). Gossip scouting is off on the nodes, so no node learns another's
real endpoint and dials around the proxy; the mesh is complete without it, since every
node connects to every other one. Zenoh peers do not relay for each other, so a tool
joined to every node does not bridge a partition either (tested).

The plan file (``<campaign dir>/links.json``) is at the same time the nodes' overrides
(key ``nodes``), the proxy's configuration (``links``, ``control``) and how ``hera inject``
finds the proxy of a running campaign (``control``: its Unix socket).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import tempfile
import time
import uuid
from collections.abc import Iterable
from itertools import permutations
from pathlib import Path
from typing import Any, Protocol

from hera.bus import OVERRIDES_ENV, tcp_endpoint
from hera.launcher import code_command
from hera.spec import ClusterSpec

PLAN_FILE = "links.json"
PROXY_MAIN = "from hera.campaign.linkproxy import main; sys.exit(main())"


class Links(Protocol):
    """What cuts a campaign's links: :class:`ProxyProcess` or
    :class:`hera.campaign.netns.Namespaces` (the same control requests)."""

    def command(self, request: dict[str, Any]) -> dict[str, Any]: ...


def plan_links(spec: ClusterSpec, ports: list[int], seed: int = 0) -> dict[str, Any]:
    """The links plan of ``spec`` (every node with its port) with ``ports`` for the
    n (n - 1) ordered pairs, in order. The control socket is a short path in the temporary
    folder (a Unix socket path must stay under 108 bytes)."""
    names = [n.name for n in spec.nodes]
    pairs = list(permutations(names, 2))
    if len(ports) != len(pairs):
        raise ValueError(f"{len(pairs)} proxy ports needed, got {len(ports)}")
    port_of = {n.name: n.port for n in spec.nodes}
    links = [
        {"from": a, "to": b, "port": p, "target": port_of[b]}
        for (a, b), p in zip(pairs, ports, strict=True)
    ]
    nodes = {
        a: {
            "connect": [tcp_endpoint(spec.host, k["port"]) for k in links if k["from"] == a],
            "zenoh": {"scouting/gossip/enabled": False},
        }
        for a in names
    }
    control = str(Path(tempfile.gettempdir()) / f"hera-links-{uuid.uuid4().hex[:12]}.sock")
    return {"host": spec.host, "seed": seed, "nodes": nodes, "links": links, "control": control}


def write_plan(plan: dict[str, Any], folder: Path) -> Path:
    """Write the plan to ``folder/links.json``; return its path."""
    path = Path(folder) / PLAN_FILE
    path.write_text(json.dumps(plan, indent=1))
    return path


def node_env(plan_path: Path, env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for ``hera up`` whose nodes take their links from the plan."""
    out = dict(os.environ if env is None else env)
    out[OVERRIDES_ENV] = str(plan_path)
    return out


def control(socket_path: str, request: dict[str, Any], timeout: float = 2.0) -> dict[str, Any]:
    """Send one request to the link proxy and return its reply; OSError when it does not
    answer, ValueError when it refuses the request (its sentence)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(socket_path)
        s.sendall((json.dumps(request) + "\n").encode())
        buf = b""
        while not buf.endswith(b"\n"):
            chunk = s.recv(65536)
            if not chunk:
                raise OSError("the link proxy closed the connection")
            buf += chunk
    reply = json.loads(buf)
    if not reply.get("ok"):
        raise ValueError(reply.get("error", "the link proxy refused the request"))
    return reply


def cut_pairs(groups: Iterable[Iterable[str]]) -> list[list[str]]:
    """The pairs of nodes a partition into ``groups`` cuts: every pair whose nodes are in
    different groups (a node in no group keeps all its links)."""
    side: dict[str, int] = {}
    for i, g in enumerate(groups):
        for n in g:
            if n in side and side[n] != i:
                raise ValueError(f"node {n!r} is on two sides of the partition")
            side[n] = i
    names = sorted(side)
    return [[a, b] for i, a in enumerate(names) for b in names[i + 1 :] if side[a] != side[b]]


def links_of(node: str, others: Iterable[str]) -> list[list[str]]:
    """The pairs between ``node`` and each of ``others``."""
    return [[node, o] for o in others if o != node]


class ProxyProcess:
    """The link proxy as a child process that stops when this process is gone."""

    def __init__(self, plan_path: Path, log: Path) -> None:
        self.plan_path = Path(plan_path)
        self.plan = json.loads(self.plan_path.read_text())
        self.log = Path(log)
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 10.0) -> None:
        """Start it and wait until every port listens."""
        ready = self.plan_path.with_name("linkproxy.pid")
        ready.unlink(missing_ok=True)
        with open(self.log, "ab") as out:
            self.proc = subprocess.Popen(
                code_command(
                    PROXY_MAIN,
                    str(self.plan_path),
                    "--parent-pid",
                    str(os.getpid()),
                    "--ready",
                    str(ready),
                ),
                stdout=out,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )
        deadline = time.monotonic() + timeout
        while not ready.exists():
            if self.proc.poll() is not None:
                raise RuntimeError(f"the link proxy exited with {self.proc.returncode}: {self.log}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"the link proxy did not start within {timeout:g} s")
            time.sleep(0.02)

    def command(self, request: dict[str, Any]) -> dict[str, Any]:
        return control(self.plan["control"], request)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def stop(self) -> None:
        """Stop it (SIGTERM, then SIGKILL after 3 s)."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(3.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.plan["control"])
