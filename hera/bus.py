"""Zenoh sessions for Hera nodes and tools: the embedded default is peers on loopback.

Every node process opens exactly one session in peer mode, listens on its own explicit TCP
endpoint and connects to every other node's endpoint, with multicast scouting off. There is
no router and no single point of failure: peers form a full mesh (ZENOH-NOTES "Sessions"),
so any node can die without cutting the others off, and a restarted node reconnects by
itself because it connects out to everyone it knows.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import zenoh

DEFAULT_LEASE_MS = 2000
"""Link lease: a hung or cut-off peer is declared gone after roughly 0.8 x lease.

Measured (ZENOH-NOTES): lease 3000 ms -> 2.4 s, 1000 ms -> 0.8-1.0 s. 2000 ms detects a
SIGSTOPped node in about 1.7 s and gave no false alarm on a healthy loopback; shorter leases
raise false alarms under packet loss. A SIGKILLed node is noticed in milliseconds whatever
the lease, because the kernel closes its sockets.
"""

CONNECT_RETRY = {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}
"""How often a peer or router dials an endpoint again that did not answer, or whose link
was lost: after 0.2 s, then doubling up to every 1 s.

Zenoh's default (1 s doubling to 4 s) was measured to link a peer up to 2.8 s after the
other side began listening (2.2-5.1 s gaps between two opens, one side dialling); with this
setting 0.2-0.8 s. Every link of a starting cluster, of a restarted node's peers and of a
healed partition forms that much sooner, for one failed TCP dial per second to a dead peer.
"""


SHARED_MEMORY = False
"""Zenoh's shared-memory transport, off. On by default in Zenoh, it gives a session that
sends a message of 3 KB or more (``transport_optimization``: a node's status reply, an args
pull) a 16 MB pool in ``/dev/shm`` and makes every router and peer of the host that
forwards from it map that pool. Measured, 32 nodes with 4 streams behind two routers:
17.7 MB of each node's RSS was that pool, 584 MB of ``/dev/shm`` in all, and a router
mapped 459 MB of them (RSS 560-660 MB; 40 MB with the same traffic from sessions that send
no such message). hera's messages are small and its large ones rare, so copying them is
cheaper than the pools. A node turns it on again through the bus overrides file
(:func:`with_overrides`: ``"zenoh": {"transport/shared_memory/enabled": true}``)."""


@dataclass(frozen=True)
class BusConfig:
    """How one process joins the cluster's bus."""

    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    lease_ms: int = DEFAULT_LEASE_MS
    mode: str = "peer"
    extra: dict = field(default_factory=dict)
    dictionary: str | None = field(default=None, repr=False)
    """User/password authentication: the ``user:password`` lines this process checks the
    others against (written to a private file only while the session opens)."""

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "router", "client"):
            raise ValueError(f"bus mode must be peer, router or client, got {self.mode!r}")
        if not 100 <= int(self.lease_ms) <= 600_000:
            raise ValueError(f"lease_ms must be within [100, 600000], got {self.lease_ms!r}")
        for ep in (*self.listen, *self.connect):
            if not isinstance(ep, str) or "/" not in ep:
                raise ValueError(f"endpoint must look like 'tcp/127.0.0.1:7447', got {ep!r}")

    def to_zenoh(self) -> zenoh.Config:
        """Build the zenoh.Config: explicit endpoints, :data:`CONNECT_RETRY`, no multicast
        scouting, our lease, shared memory as :data:`SHARED_MEMORY` says; then ``extra``."""
        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps(self.mode))
        if self.mode != "client":
            cfg.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        cfg.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        cfg.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("transport/link/tx/lease", str(int(self.lease_ms)))
        cfg.insert_json5("transport/link/tx/keep_alive", "4")
        cfg.insert_json5("transport/shared_memory/enabled", json.dumps(SHARED_MEMORY))
        for key, value in self.extra.items():
            cfg.insert_json5(key, json.dumps(value))
        return cfg


OVERRIDES_ENV = "HERA_BUS_OVERRIDES"
"""Environment variable naming a JSON file of per-node bus overrides (see
:func:`with_overrides` and :func:`netns_of`); a fault campaign sets it to route the nodes'
links through its link proxy, or to run each node in a network namespace of its own."""


def netns_of(node: str, environ: Mapping[str, str] = os.environ) -> str | None:
    """The network namespace that node ``node`` runs in, from the overrides file
    (``{"nodes": {"<node>": {"netns": "<name>"}}}``), or None: the launcher starts such a
    node with ``ip netns exec <name>``. ValueError naming the file when it cannot be read."""
    ns = (_overrides_of(node, environ) or {}).get("netns")
    if ns is not None and not isinstance(ns, str):
        path = environ.get(OVERRIDES_ENV)
        raise ValueError(f"bus overrides {path}: node {node!r}: netns must be a name, got {ns!r}")
    return ns


def _overrides_of(node: str, environ: Mapping[str, str]) -> dict[str, Any] | None:
    """The entry for ``node`` in the overrides file ``$HERA_BUS_OVERRIDES`` names (None: no
    file, or the file does not name it). ValueError naming the file when it cannot be read."""
    path = environ.get(OVERRIDES_ENV)
    if not path:
        return None
    try:
        with open(path) as f:
            mine = json.load(f)["nodes"].get(node)
        if mine is not None and not isinstance(mine, dict):
            raise TypeError(f"node {node!r}: an entry must be a table, got {mine!r}")
        return mine
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"bus overrides {path} ({OVERRIDES_ENV}) cannot be used: {e}") from None


def with_overrides(
    config: BusConfig, node: str, environ: Mapping[str, str] = os.environ
) -> BusConfig:
    """``config`` with the overrides for ``node`` from the file ``$HERA_BUS_OVERRIDES``
    names, if set: ``{"nodes": {"<node>": {"connect": [endpoints], "zenoh": {key: value}}}}``
    (``connect`` replaces the node's connect endpoints, ``zenoh`` adds Zenoh config keys).
    A node the file does not name keeps ``config``. ValueError naming the file otherwise."""
    mine = _overrides_of(node, environ)
    if mine is None:
        return config
    try:
        connect = tuple(mine.get("connect", config.connect))
        extra = {**config.extra, **dict(mine.get("zenoh", {}))}
    except (TypeError, ValueError) as e:
        path = environ.get(OVERRIDES_ENV)
        raise ValueError(f"bus overrides {path} ({OVERRIDES_ENV}) cannot be used: {e}") from None
    return replace(config, connect=connect, extra=extra)


_LOGGING = False
RUNTIME_ENV = "ZENOH_RUNTIME"  # Zenoh's own: its thread pools' settings, read at first open
RUNTIME_EXAMPLE = "(app: (worker_threads: 2))"


def check_runtime_env() -> None:
    """ValueError naming ``ZENOH_RUNTIME`` when it is set but cannot be Zenoh's runtime
    settings (empty, or not one parenthesised list with balanced parentheses): Zenoh would
    panic on it with a Rust backtrace when the first session opens."""
    raw = os.environ.get(RUNTIME_ENV)
    if raw is None:
        return
    text, depth = raw.strip(), 0
    for ch in text:
        depth += (ch == "(") - (ch == ")")
        if depth < 0:
            break
    if not (text.startswith("(") and text.endswith(")") and depth == 0):
        raise ValueError(
            f"environment variable {RUNTIME_ENV}={raw!r} is not Zenoh's runtime settings: "
            f"unset it, or give settings such as {RUNTIME_EXAMPLE!r}"
        )


def _open(cfg: zenoh.Config) -> zenoh.Session:
    """``zenoh.open``; a panic of Zenoh's while ``ZENOH_RUNTIME`` is set becomes a
    ValueError that names it (Zenoh checks that value only here, by panicking)."""
    try:
        return zenoh.open(cfg)
    except BaseException as e:  # pyo3's PanicException derives from BaseException
        raw = os.environ.get(RUNTIME_ENV)
        if type(e).__name__ != "PanicException" or raw is None:
            raise
        first = (str(e).splitlines() or [""])[0][:200]
        raise ValueError(
            f"Zenoh could not start with environment variable {RUNTIME_ENV}={raw!r} "
            f"({first}): unset it, or give settings such as {RUNTIME_EXAMPLE!r}"
        ) from None


def open_session(config: BusConfig) -> zenoh.Session:
    """Open a Zenoh session; the caller must close it (``with`` or ``try/finally``).
    ValueError naming ``ZENOH_RUNTIME`` when that variable is not usable (see
    :func:`check_runtime_env`).

    With ``RUST_LOG`` set (e.g. ``RUST_LOG=zenoh=debug``), Zenoh's own log goes to stderr
    (the node's log file): what its links and routing do, for debugging."""
    global _LOGGING
    check_runtime_env()
    if not _LOGGING and os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")
        _LOGGING = True
    cfg = config.to_zenoh()
    if config.dictionary is None:
        return _open(cfg)
    # Zenoh reads the dictionary when the session opens (verified by a test): it lives in a
    # file only this user can read, removed as soon as the session is open
    with tempfile.TemporaryDirectory(prefix="hera-auth-") as folder:
        path = os.path.join(folder, "dictionary")
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(config.dictionary)
        cfg.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(path))
        return _open(cfg)


def query_all(
    session: zenoh.Session,
    selector: str,
    timeout: float,
    payload: str | bytes | None = None,
    complete: bool = True,
):
    """Ask every queryable matching ``selector`` and yield each successful reply's sample.

    ``complete=True`` asks the queryables that declared themselves complete for the whole
    selector (a node's ``args/**``); ``False`` asks every matching one (``ctl/*/status``
    reaches nodes whose queryable is ``ctl/<node>/*``, which does not include the query).
    Replies are not consolidated: every node answers.
    """
    target = zenoh.QueryTarget.ALL_COMPLETE if complete else zenoh.QueryTarget.ALL
    extra = {} if payload is None else {"payload": payload}
    for reply in session.get(
        selector,
        target=target,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout,
        **extra,
    ):
        if reply.ok is not None:
            yield reply.ok


def tcp_endpoint(host: str, port: int) -> str:
    """Return the Zenoh endpoint string for a TCP address."""
    return f"tcp/{host}:{int(port)}"
