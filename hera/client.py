"""A tool's view of a running cluster: find it, join its bus, query status, send control.

``hera up`` writes ``<run-dir>/cluster.json`` (the resolved spec: ports, world epoch) and
registers the cluster in a per-user directory (:func:`registry_dir`), one entry per running
launcher (``<cluster>-<pid>.json``), so ``hera status`` and ``hera down`` find every running
cluster from another terminal, two runs of one spec included.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hera.bus import BusConfig, open_session, query_all
from hera.keys import Keys
from hera.spec import ClusterSpec, load_spec


def registry_dir() -> Path:
    """Where running clusters are registered (``$HERA_REGISTRY`` overrides)."""
    env = os.environ.get("HERA_REGISTRY")
    if env:
        return Path(env)
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"hera-{os.getuid()}" / "clusters"


def pid_alive(pid: int) -> bool:
    """Whether a process with ``pid`` exists (and is not a zombie we could reap)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    with contextlib.suppress(OSError), open(f"/proc/{pid}/stat") as f:
        if f.read().rsplit(")", 1)[1].split()[0] == "Z":
            return False
    return True


def running_clusters() -> list[dict[str, Any]]:
    """Registered clusters whose launcher is still alive."""
    out = []
    d = registry_dir()
    for f in sorted(d.glob("*.json")) if d.exists() else ():
        with contextlib.suppress(OSError, ValueError):
            entry = json.loads(f.read_text())
            if pid_alive(int(entry["launcher_pid"])):
                out.append(entry)
    return out


def find_run_dir(run_dir: str | None, cluster: str | None) -> Path:
    """The run directory to talk to: the one given, or the only running cluster (of that
    name); LookupError saying which ones run otherwise."""
    if run_dir:
        return Path(run_dir)
    found = [c for c in running_clusters() if cluster in (None, c["cluster"])]
    if not found:
        raise LookupError(
            "no running cluster found"
            + (f" called {cluster!r}" if cluster else "")
            + "; start one with 'hera up SPEC' or give --run-dir"
        )
    if len(found) > 1:
        where = ", ".join(f"{c['cluster']} in {c['run_dir']}" for c in found)
        pick = "--run-dir DIR" if cluster else "--cluster NAME or --run-dir DIR"
        raise LookupError(f"{len(found)} clusters are running ({where}): pick one with {pick}")
    return Path(found[0]["run_dir"])


class ClusterClient:
    """A peer session joined to a cluster's bus, for status and control queries."""

    def __init__(self, spec: ClusterSpec) -> None:
        self.spec = spec
        self.keys = Keys(spec.name)
        endpoints = tuple(spec.endpoint(n.name) for n in spec.nodes)
        self.session = open_session(
            BusConfig(listen=(f"tcp/{spec.host}:0",), connect=endpoints, lease_ms=spec.lease_ms)
        )

    @classmethod
    def from_run_dir(cls, run_dir: str | Path) -> ClusterClient:
        return cls(load_spec(Path(run_dir) / "cluster.json"))

    def query(
        self, node: str, verb: str, request: dict | None = None, timeout: float = 1.0
    ) -> dict[str, dict[str, Any]]:
        """Send a control query to ``node`` (``*`` for all); replies by node name."""
        out: dict[str, dict[str, Any]] = {}
        replies = query_all(
            self.session,
            self.keys.ctl(node, verb),
            timeout,
            payload=json.dumps(request or {}),
            complete=False,
        )
        for sample in replies:
            with contextlib.suppress(ValueError):
                out[str(sample.key_expr).split("/")[-2]] = json.loads(sample.payload.to_bytes())
        return out

    def subscribe(self, selector: str, callback: Callable[[Any], None]) -> Any:
        """Subscribe to key expression ``selector`` of the cluster's bus (e.g.
        ``self.keys.data("*", "*")``); ``callback(sample)`` runs on Zenoh's threads. Returns
        the subscriber (``undeclare()`` it, or close the client)."""
        return self.session.declare_subscriber(selector, callback)

    def subscribe_alive(self, callback: Callable[[Any], None]) -> Any:
        """Follow the nodes' liveliness tokens (``alive/**``, with the ones already up):
        ``callback(sample)`` with a PUT when a node appears, a DELETE when it is gone."""
        return self.session.liveliness().declare_subscriber(
            self.keys.alive_all, callback, history=True
        )

    def status(self, timeout: float = 1.0) -> dict[str, dict[str, Any]]:
        """Every reachable node's status, by node name."""
        return self.query("*", "status", timeout=timeout)

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> ClusterClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
