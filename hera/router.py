"""``hera router SPEC --name NAME``: one Zenoh router of a cluster, run from the Python package.

A router is a Zenoh session in router mode (no separate binary): it listens on its
endpoints, connects to the cluster's other routers and routes between hosts and for the
clients attached to it (see :mod:`hera.topology`). It holds no state; ``hera up`` starts the
routers a spec places on this host and restarts one that dies, like a node.
"""

from __future__ import annotations

import logging
import os
import signal
import threading

import zenoh

from hera.bus import open_session
from hera.node import EXIT_CONFIG, FATAL
from hera.security.credentials import CredentialsError, secured
from hera.spec import ClusterSpec
from hera.topology import bus_config

log = logging.getLogger("hera.router")


def run_router(spec: ClusterSpec, name: str, parent_pid: int | None = None) -> int:
    """Run router ``name`` until SIGTERM/SIGINT or the death of ``parent_pid``."""
    spec.router(name)  # SpecError naming the known routers
    try:
        cfg = secured(spec, name, bus_config(spec, name))
    except CredentialsError as e:
        log.error("%s%s", FATAL, e)
        return EXIT_CONFIG
    halt = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: halt.set())
    try:
        session = open_session(cfg)
    except zenoh.ZError as e:
        if "Address already in use" in str(e):
            log.error("%sits port %s is in use by another process", FATAL, ", ".join(cfg.listen))
            return EXIT_CONFIG
        raise
    try:
        log.info("router %s up on %s, connecting to %s", name, cfg.listen, cfg.connect)
        while not halt.wait(0.25):
            if parent_pid is not None and os.getppid() != parent_pid:
                log.error("launcher %d is gone; router %s stops", parent_pid, name)
                break
        return 0
    finally:
        session.close()
