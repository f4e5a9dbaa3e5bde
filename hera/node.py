"""One Hera node process: bus session, store, args, liveliness, control plane, measures.

Start-up order matters for the guarantees of ARCHITECTURE.md:

1. open the Zenoh session (listen on its own endpoint, connect to every other node);
2. subscribe to the data keys (store + optional CSV log) and answer seq and args queries;
3. recover the args and the latest seqs of this node's measures from live peers, so a
   restarted node continues its seqs and never recalibrates;
4. declare the liveliness token, start the supervised measures, then answer the control
   plane (a node that answers status has all its measures registered).

Exit codes: 0 after a requested stop, 3 when the supervisor's restart intensity is exceeded
(escalation), 70 when a crash is injected. The launcher restarts a node that exits non-zero.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from hera import wire
from hera.args import ArgsStore
from hera.bus import BusConfig, open_session, query_all, tcp_endpoint
from hera.csvlog import CsvLog
from hera.keys import Keys
from hera.measure import MeasureContext, MeasureSpec, Reading
from hera.plugins import find_measure
from hera.spec import ClusterSpec, MeasureDecl
from hera.store import Store
from hera.supervisor import Child, Supervisor
from hera.worker import Worker

log = logging.getLogger("hera.node")

EXIT_ESCALATED = 3
EXIT_INJECTED_CRASH = 70
RECOVERY_TIMEOUT = 1.0


class Node:
    """The runtime of one node of a cluster spec."""

    def __init__(self, spec: ClusterSpec, name: str, run_dir: str | Path | None = None) -> None:
        self.spec = spec
        self.decl = spec.node(name)
        self.name = name
        self.keys = Keys(spec.name)
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.store = Store()
        self.rejected: dict[str, int] = {}
        self.last_rejection: str | None = None
        self.peers: dict[str, float] = {}
        self.peer_events: deque[tuple[float, str, str]] = deque(maxlen=64)
        self.transit: dict[str, deque[float]] = {}
        self.halt = threading.Event()
        self.exit_code = 0
        self.started_at = time.time()
        self._seq: dict[str, int] = {}
        self._seq_lock = threading.Lock()
        self._publishers: dict[str, Any] = {}
        self._decls: dict[str, MeasureDecl] = {m.name: m for m in self.decl.measures}
        self._handles: list[Any] = []
        self.session: zenoh.Session | None = None
        self.csv: CsvLog | None = None
        self.sync = None
        self.supervisor: Supervisor | None = None
        self.args: ArgsStore | None = None

    # -- life cycle ---------------------------------------------------------------------
    def start(self) -> None:
        """Join the bus, recover state from peers and start the measures."""
        self._select_estimation_backend()
        others = [tcp_endpoint(self.spec.host, n.port) for n in self.spec.nodes if n.port]
        me = self.spec.endpoint(self.name)
        bus = BusConfig(
            listen=(me,), connect=tuple(e for e in others if e != me), lease_ms=self.spec.lease_ms
        )
        self.session = open_session(bus)
        if self.run_dir is not None and self.spec.log_node == self.name:
            self.csv = CsvLog(self.run_dir, self._columns())
        s = self.session
        self._handles.append(s.declare_subscriber(f"{self.keys.prefix}/data/**", self._on_data))
        self._handles.append(
            s.declare_queryable(self.keys.seq("*", "*"), self._on_seq_query, complete=True)
        )
        state_dir = self.run_dir / "state" / self.name if self.run_dir is not None else None
        self.args = ArgsStore(self.name, s, self.keys, state_dir)
        self._handles.append(
            s.liveliness().declare_subscriber(self.keys.alive_all, self._on_alive, history=True)
        )
        self._recover()
        self._handles.append(s.liveliness().declare_token(self.keys.alive(self.name)))
        self._start_sync()
        self.supervisor = Supervisor(
            self.spec.intensity,
            self.spec.intensity_period,
            self.spec.strategy,
            on_escalate=self._escalate,
        )
        for decl in self.decl.measures:
            self._add_child(decl)
        # last: a node that answers status has all its measures registered
        self._handles.append(
            s.declare_queryable(self.keys.ctl(self.name, "*"), self._on_control, complete=True)
        )
        log.info("node %s up on %s with %d measures", self.name, me, len(self.decl.measures))

    def _select_estimation_backend(self) -> None:
        """Nodes fuse on numpy unless the spec asks for numba ([cluster] estimation_backend):
        at sensor rates a numpy step costs well under a millisecond, while numba compiles
        its kernels for seconds at first use. With numba they are compiled (or loaded from
        numba's cache) here, before any measure runs, so no first step stalls."""
        from hera import estimation

        estimation.set_backend(self.spec.estimation_backend)
        spent = estimation.warmup()
        if spent:
            log.info("estimation kernels ready in %.2f s", spent)

    def _recover(self) -> None:
        """Wait briefly for live peers, then fetch args and this node's latest seqs."""
        expected = {n.name for n in self.spec.nodes} - {self.name}
        deadline = time.monotonic() + RECOVERY_TIMEOUT
        # Liveliness history arrives asynchronously after connecting: peers that are up show
        # up within milliseconds on loopback; wait for all of them, at most the timeout.
        while not expected <= set(self.peers) and time.monotonic() < deadline:
            time.sleep(0.005)
        if not self.peers:
            return
        got = self.args.recover(timeout=RECOVERY_TIMEOUT)
        for sample in query_all(self.session, self.keys.seq("*", self.name), RECOVERY_TIMEOUT):
            try:
                seqs = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
                for name, seq in seqs.items():
                    if isinstance(seq, int) and seq > self._seq.get(name, 0):
                        self._seq[name] = seq
            except Exception as e:  # a peer's bad reply must not stop this node's start
                log.warning("ignoring malformed seq reply: %s", e)
        log.info("recovered %d args and seqs %s from %s", got, self._seq, sorted(self.peers))

    def _start_sync(self) -> None:
        try:
            from hera.sync import SyncService
        except ImportError:
            return
        hosts = {g: self.spec.sync_groups()[g] for g in self.decl.sync_hosts}
        state = self.run_dir / "state" / self.name if self.run_dir is not None else None
        self.sync = SyncService(
            self.session, self.keys, self.name, hosts, self.spec.sync_lease_ms, state_dir=state
        )
        self.sync.start()

    def _add_child(self, decl: MeasureDecl, start: bool = True) -> None:
        cls = find_measure(decl.use)
        spec = MeasureSpec(
            name=decl.name,
            period=decl.period if decl.period is not None else cls.period,
            iterations=decl.iterations if decl.iterations is not None else cls.iterations,
            sync=decl.sync if decl.sync is not None else cls.sync,
            sync_group=decl.sync_group,
            slot=decl.slot if decl.slot is not None else cls.slot,
            restart=decl.restart,
            hang_factor=decl.hang_factor,
            hang_min=decl.hang_min,
        )
        args = dict(decl.args)  # the original arguments, reused by every restart
        counters: dict[str, float] = {}

        def make(on_exit) -> Worker:
            ctx = MeasureContext(
                node=self.name,
                cluster=self.spec.name,
                spec=spec,
                store=self.store,
                args=self.args,
                session=self.session,
                keys=self.keys,
                world=self.spec.world,
                counters=counters,
                seed=decl.seed,
                run_dir=str(self.run_dir) if self.run_dir is not None else None,
                log=logging.getLogger(f"hera.measure.{decl.name}"),
            )
            return Worker(
                cls,
                args,
                ctx,
                self.publish,
                on_exit,
                slot_runner=self._slot_runner(spec, ctx) if spec.sync else None,
                halt=self.halt,
            )

        self.supervisor.add(Child(decl.name, make, spec.restart), start=start)

    def _slot_runner(self, spec: MeasureSpec, ctx: MeasureContext):
        if self.sync is None:
            raise RuntimeError(
                f"measure {spec.name!r} is marked sync but the sync service is not available"
            )
        from hera.sync import run_in_slot

        client = self.sync.client()
        holder = f"{self.name}/{spec.name}"

        def in_slot(fn):
            def fire(turn):
                # the measure hands the turn to its driver, which checks it at the trigger
                ctx.grant = turn
                try:
                    return fn()
                finally:
                    ctx.grant = None

            return run_in_slot(client, spec.group, holder, spec.slot, fire, spec.period)

        return in_slot

    def _columns(self) -> dict[str, tuple[str, ...]]:
        cols = {}
        for n in self.spec.nodes:
            for m in n.measures:
                with contextlib.suppress(Exception):
                    cols[m.name] = tuple(find_measure(m.use).columns)
        return cols

    def run(self) -> int:
        """Block until stopped (signal, control plane, escalation); return the exit code."""
        self.halt.wait()
        return self.exit_code

    def stop(self, code: int = 0) -> None:
        """Ask :meth:`run` to return ``code`` (the first reason to stop wins)."""
        if not self.halt.is_set():
            self.exit_code = code
            self.halt.set()

    def close(self) -> None:
        """Stop the measures, flush and close the session. Safe to call twice."""
        self.halt.set()
        if self.supervisor is not None:
            self.supervisor.shutdown(self.spec.shutdown_timeout)
        if self.sync is not None:
            with contextlib.suppress(Exception):
                self.sync.close()
        if self.args is not None:
            self.args.close()
        for h in reversed(self._handles):
            with contextlib.suppress(Exception):
                h.undeclare()
        self._handles.clear()
        for p in self._publishers.values():
            with contextlib.suppress(Exception):
                p.undeclare()
        self._publishers.clear()
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.csv is not None:
            self.csv.close()

    def _escalate(self, reason: str) -> None:
        log.error("node %s escalates: %s", self.name, reason)
        self.stop(EXIT_ESCALATED)

    # -- data path ----------------------------------------------------------------------
    def publish(self, name: str, reading: Reading, grant: Any = None) -> None:
        """Publish one sample of this node's measure ``name`` with the next seq."""
        with self._seq_lock:
            seq = self._seq.get(name, 0) + 1
            try:
                payload = wire.encode(
                    seq, reading.t, reading.values, (grant.epoch, grant.token) if grant else None
                )
            except (wire.WireError, TypeError, ValueError) as e:
                self._reject("invalid_output", f"measure {name} returned unpublishable values: {e}")
                return
            self._seq[name] = seq
            pub = self._publishers.get(name)
            if pub is None:
                pub = self.session.declare_publisher(self.keys.data(name, self.name))
                self._publishers[name] = pub
        pub.put(payload)

    def _on_data(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            name, node = self.keys.parse_data(key)
            msg = wire.decode(sample.payload.to_bytes())
        except wire.WireError as e:
            kind = "oversized" if "too large" in str(e) else "malformed"
            self._reject(kind, f"{key}: {e}")
            return
        except ValueError as e:
            self._reject("bad_key", str(e))
            return
        if not self.store.offer(name, node, msg):
            return
        held = self.store.get_one(name, node)
        # publish-to-store transit on the wall clock (exact on one host; needs NTP across)
        window = self.transit.get(node)
        if window is None:
            window = self.transit[node] = deque(maxlen=4096)
        window.append(held.arrival_wall - held.t)
        if self.csv is not None and (not self.spec.log_names or name in self.spec.log_names):
            self.csv.write(held)

    def _reject(self, kind: str, message: str) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + 1
        self.last_rejection = message
        if self.rejected[kind] <= 3 or self.rejected[kind] % 1000 == 0:
            log.warning("rejected input (%s, %d so far): %s", kind, self.rejected[kind], message)

    def _on_seq_query(self, query: zenoh.Query) -> None:
        with query:
            head = self.keys.seq("", "")
            parts = str(query.key_expr)[len(head) - 1 :].split("/")
            node = parts[-1] if len(parts) == 2 else None
            if node is None or "*" in node:
                return
            seqs = self.store.seqs_of_node(node)
            if node == self.name:
                with self._seq_lock:
                    for k, v in self._seq.items():
                        seqs[k] = max(v, seqs.get(k, 0))
            query.reply(self.keys.seq("all", node), msgpack.packb(seqs))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            node, worker = self.keys.parse_alive(str(sample.key_expr))
        except ValueError:
            return
        if worker is not None:
            return
        now = time.time()
        if sample.kind == zenoh.SampleKind.PUT:
            self.peers[node] = now
            self.peer_events.append((now, node, "up"))
        else:
            self.peers.pop(node, None)
            self.peer_events.append((now, node, "down"))

    # -- control plane ------------------------------------------------------------------
    def _on_control(self, query: zenoh.Query) -> None:
        with query:
            verb = str(query.key_expr).rsplit("/", 1)[-1]
            try:
                raw = query.payload.to_bytes() if query.payload is not None else b""
                request = json.loads(raw) if raw else {}
                if not isinstance(request, dict):
                    raise ValueError("a control request must be a JSON object")
                reply = {"ok": True, **self.control(verb, request)}
            except (ValueError, KeyError, TypeError) as e:
                reply = {"ok": False, "error": str(e)}
            query.reply(self.keys.ctl(self.name, verb), json.dumps(reply))

    def control(self, verb: str, request: dict[str, Any]) -> dict[str, Any]:
        """Run one control verb; raises ValueError with a clear message on a bad request.

        Verbs: ``status``; ``start``/``stop`` {"measure"}; ``inject`` {"fault": "crash" |
        "hang" | "crash_node", "measure"} or {"target": "board", ...} for board faults;
        ``args`` (every replicated arg); ``store`` {"name"?} (held samples); ``shutdown``.
        """
        if verb == "status":
            return self.status()
        if verb in ("start", "stop"):
            measure = request.get("measure")
            if not isinstance(measure, str):
                raise ValueError(f"{verb} needs a 'measure' name")
            if verb == "start":
                self.supervisor.start_child(measure)
            else:
                self.supervisor.stop_child(measure)
            return {"measure": measure, "state": self.supervisor.children[measure].state}
        if verb == "inject":
            return self._inject(request)
        if verb == "args":
            return {"args": self.args.items()}
        if verb == "store":
            name = request.get("name")
            samples = self.store.snapshot() if name is None else self.store.get(str(name))
            return {
                "samples": [
                    {
                        "name": s.name,
                        "node": s.node,
                        "seq": s.seq,
                        "t": s.t,
                        "age_s": round(s.age(), 4),
                        "values": list(s.values),
                    }
                    for s in samples
                ]
            }
        if verb == "shutdown":
            threading.Timer(0.05, self.stop).start()
            return {"stopping": self.name}
        raise ValueError(
            f"unknown control verb {verb!r}: use status, start, stop, inject, args, store, shutdown"
        )

    def _inject(self, request: dict[str, Any]) -> dict[str, Any]:
        if request.get("target") == "board":
            try:
                from hera.nodes.faults import handle_inject
            except ImportError as e:
                raise ValueError(f"board faults are not available: {e}") from None
            return handle_inject(request)
        fault = request.get("fault")
        if fault == "crash_node":
            log.error("crash of node %s injected", self.name)
            threading.Timer(0.05, os._exit, (EXIT_INJECTED_CRASH,)).start()
            return {"crashing": self.name}
        if fault in ("crash", "hang"):
            measure = request.get("measure")
            if not isinstance(measure, str):
                raise ValueError(f"fault {fault!r} needs a 'measure' name")
            self.supervisor.worker(measure).inject(fault)
            return {"measure": measure, "fault": fault}
        raise ValueError(f"unknown fault {fault!r}: use crash, hang, crash_node, or target=board")

    def status(self) -> dict[str, Any]:
        """The node's status as a JSON-able dict (see README "Control plane")."""
        measures = {}
        now = time.monotonic()
        for cid, c in self.supervisor.children.items() if self.supervisor else ():
            w = c.worker
            st = w.stats if w is not None else None
            measures[cid] = {
                "state": c.state,
                "restarts": c.restarts,
                "crashes": c.crashes,
                "hangs": c.hangs,
                "last_error": c.last_error,
                "seq": self._seq.get(cid, 0),
                "steps": st.steps if st else 0,
                "published": st.published if st else 0,
                "empty": st.empty if st else 0,
                "rate_hz": round(st.rate(now), 2) if st else 0.0,
                "jitter_ms": {k: round(v, 3) for k, v in st.jitter_ms().items()} if st else {},
                "overruns": st.overruns if st else 0,
                "skipped_slots": st.skipped_slots if st else 0,
                "counters": dict(w.ctx.counters) if w is not None else {},
                "period_s": w.spec.period if w is not None else None,
                "restart_ms": c.restart_ms,
            }
        out: dict[str, Any] = {
            "node": self.name,
            "cluster": self.spec.name,
            "pid": os.getpid(),
            "uptime_s": round(time.time() - self.started_at, 3),
            "escalated": self.supervisor.escalated if self.supervisor else None,
            "measures": measures,
            "store": {
                "entries": len(self.store.snapshot()),
                "accepted": self.store.accepted,
                "stale": self.store.stale,
            },
            "rejected": dict(self.rejected),
            "last_rejection": self.last_rejection,
            "peers": sorted(self.peers),
            "peer_events": [{"t": t, "node": n, "event": e} for t, n, e in list(self.peer_events)],
            "transit_ms": {n: _percentiles(w) for n, w in list(self.transit.items())},
            "args": len(self.args.items()) if self.args else 0,
            "log_rows": self.csv.rows if self.csv else 0,
        }
        if self.sync is not None:
            with contextlib.suppress(Exception):
                out["sync"] = self.sync.status()
        return out


def _percentiles(window: deque[float]) -> dict[str, float]:
    xs = sorted(window)
    if not xs:
        return {}
    pick = lambda q: round(xs[min(len(xs) - 1, int(q * len(xs)))] * 1e3, 4)  # noqa: E731
    return {"p50": pick(0.5), "p99": pick(0.99), "max": round(xs[-1] * 1e3, 4), "n": len(xs)}


def run_node(spec: ClusterSpec, name: str, run_dir: str | None, parent_pid: int | None) -> int:
    """Run one node until SIGTERM/SIGINT, a shutdown request, escalation or the death of
    ``parent_pid``; clean up and return the exit code."""
    node = Node(spec, name, run_dir)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: node.stop(0))
    try:
        node.start()
        while not node.halt.wait(0.25):
            if parent_pid is not None and os.getppid() != parent_pid:
                log.error("launcher %d is gone; node %s stops", parent_pid, name)
                node.stop(0)
        return node.exit_code
    finally:
        node.close()
