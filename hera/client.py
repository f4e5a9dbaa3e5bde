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
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hera.bus import BusConfig, open_session, query_all
from hera.keys import Keys
from hera.security.access import OPERATOR
from hera.security.credentials import Credentials, secured
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


def _open_retrying(cfg: BusConfig, retry_s: float) -> Any:
    """Open a session; a client that finds no router retries for ``retry_s`` seconds."""
    deadline = time.monotonic() + retry_s
    while True:
        try:
            return open_session(cfg)
        except Exception:
            if cfg.mode != "client" or time.monotonic() >= deadline:
                raise
            time.sleep(0.1)


class ClusterClient:
    """A session joined to a cluster's bus, for status and control queries.

    Made from the cluster's spec (a peer meshing with its nodes, through its routers if it
    has any: what ``hera up`` and tools on the same host use), or with :meth:`connect` from
    just an endpoint (a client of one node or router: a tool on any host, no run
    directory needed).
    """

    def __init__(
        self,
        spec: ClusterSpec | None,
        session: Any = None,
        cluster: str = "",
        host: str | None = None,
        retry_s: float = 0.0,
    ) -> None:
        """``host``: the address this tool runs on, to join through that host's routers;
        ``retry_s``: how long to keep trying when no router answers yet (a launcher that has
        just started its routers)."""
        self.spec = spec
        self.cluster = spec.name if spec is not None else cluster
        self.keys = Keys(self.cluster)
        if session is None:
            from hera.topology import router_endpoints, tool_endpoints

            assert spec is not None
            if spec.routers:  # a client of the routers (of this host, when it has some)
                cfg = BusConfig(
                    listen=(),
                    connect=router_endpoints(spec, host),
                    lease_ms=spec.lease_ms,
                    mode="client",
                )
            else:  # a peer of the nodes' full mesh
                cfg = BusConfig(
                    listen=(f"tcp/{spec.host}:0",),
                    connect=tool_endpoints(spec),
                    lease_ms=spec.lease_ms,
                )
            session = _open_retrying(secured(spec, OPERATOR, cfg), retry_s)
        self.session = session

    @classmethod
    def from_run_dir(cls, run_dir: str | Path) -> ClusterClient:
        return cls(load_spec(Path(run_dir) / "cluster.json"))

    @classmethod
    def connect(
        cls,
        endpoints: list[str],
        cluster: str | None = None,
        timeout: float = 2.0,
        credentials: Credentials | None = None,
    ) -> ClusterClient:
        """A client session to one of ``endpoints`` (a node or router of the cluster),
        authenticated with ``credentials`` (the operator's, see
        :func:`hera.security.credentials.for_operator`); the cluster is found on the bus when
        ``cluster`` is not given and only one answers. LookupError when nothing answers
        (wrong credentials included) or several clusters do."""
        cfg = BusConfig(listen=(), connect=tuple(endpoints), mode="client")
        if credentials is not None:
            cfg = credentials.secure(cfg)
        try:
            session = open_session(cfg)
        except Exception as e:
            raise LookupError(
                f"cannot join the bus at {', '.join(endpoints)}: nothing listens there, or it "
                f"refused these credentials ({str(e).split(' at ')[0]})"
            ) from None
        try:
            if cluster is None:
                found = set()
                for sample in query_all(session, "hera/*/ctl/*/status", timeout, complete=False):
                    found.add(str(sample.key_expr).split("/")[1])
                if not found:
                    raise LookupError(f"no cluster answers at {', '.join(endpoints)}")
                if len(found) > 1:
                    raise LookupError(
                        f"several clusters answer at {', '.join(endpoints)} "
                        f"({', '.join(sorted(found))}): pick one with --cluster NAME"
                    )
                cluster = found.pop()
            return cls(None, session, cluster)
        except BaseException:
            session.close()
            raise

    def launchers(self, timeout: float = 1.0) -> dict[str, dict[str, Any]]:
        """The state of every launcher running processes of the cluster, by launcher id."""
        out = {}
        for sample in query_all(
            self.session, self.keys.launcher("*", "status"), timeout, complete=False
        ):
            with contextlib.suppress(ValueError):
                reply = json.loads(sample.payload.to_bytes())
                out[str(sample.key_expr).split("/")[-2]] = reply
        return out

    def launched(self, timeout: float = 1.0) -> dict[str, dict[str, Any]]:
        """What the launchers say of each node (pid, state, restarts), by node name."""
        out: dict[str, dict[str, Any]] = {}
        for state in self.launchers(timeout).values():
            out.update(state.get("nodes", {}))
        return out

    def query(
        self, node: str, verb: str, request: dict | None = None, timeout: float = 1.0
    ) -> dict[str, dict[str, Any]]:
        """Send a control query to ``node`` (``*`` for all); replies by node name.

        One named node is asked again while its query ends with no reply before
        ``timeout``: Zenoh ends a query at once when no queryable matches it, which is what a
        session just opened sees until the node's declarations reach it (a tool's first
        query, or a node just restarted). A query the node received is never sent twice: it
        answers every query, so such a query ends with its reply or at the timeout."""
        deadline = time.monotonic() + timeout
        while True:
            left = max(0.05, deadline - time.monotonic())
            out = self._ask(node, verb, request, left)
            if "*" in node or out or time.monotonic() >= deadline - 0.05:
                return out
            time.sleep(0.02)  # the node's declarations are on their way

    def _ask(
        self, node: str, verb: str, request: dict | None, timeout: float
    ) -> dict[str, dict[str, Any]]:
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
