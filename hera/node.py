"""One Hera node process: joins the bus, recovers its state, runs its supervised measures.

The parts, one concern each: :mod:`hera.datapath` (publish and store samples),
:mod:`hera.peers` (who is up), :mod:`hera.args` (replicated args), :mod:`hera.control`
(control plane), :mod:`hera.nodestatus` (status reply), node services
(:mod:`hera.services`, e.g. the sync service) and the :class:`~hera.supervisor.Supervisor`
of the measure workers. This module puts them together, in an order that keeps the
guarantees of ARCHITECTURE.md:

1. open the Zenoh session (listen on its own endpoint, connect to every other node);
2. subscribe to the data keys (store + optional CSV log) and answer seq and args queries;
3. recover the args and the latest seqs of this node's measures from live peers, so a
   restarted node continues its seqs and never recalibrates;
4. declare the liveliness token, start the services and the supervised measures, then
   answer the control plane (a node that answers status has all its measures registered).

Exit codes: 0 after a requested stop, 3 when the supervisor's restart intensity is exceeded
(escalation), 70 when a crash is injected, 78 when it cannot start for a cause a restart
will not cure (its port is taken): it logs ``FATAL: <cause>`` first. The launcher restarts a
node that exits non-zero, but 78.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import zenoh

from hera import wallclock
from hera.args import ArgsStore
from hera.beat import Beat
from hera.bus import BusConfig, open_session, with_overrides
from hera.control import EXIT_INJECTED_CRASH, ControlPlane
from hera.csvlog import CsvLog
from hera.datapath import DataPath
from hera.dynamic import restore_measures
from hera.keys import Keys
from hera.measure import MeasureContext, MeasureSpec, runtime_args
from hera.nodestatus import node_status
from hera.peers import Peers
from hera.plugins import find_measure
from hera.reload import freeze_runtime
from hera.resources import Resources
from hera.security.credentials import CredentialsError, secured
from hera.services import NodeService, ServiceContext, ServiceFactory, SlotService
from hera.spec import ClusterSpec
from hera.store import Store
from hera.supervisor import Child, Supervisor
from hera.topology import bus_config
from hera.worker import Worker, wall_grid

freeze_runtime()  # what is loaded now is the runtime's: a hot reload never replaces it
log = logging.getLogger("hera.node")

EXIT_ESCALATED = 3
EXIT_CONFIG = 78
FATAL = "FATAL: "
"""Start of the log line that gives the cause before a node exits EXIT_CONFIG."""
RECOVERY_TIMEOUT = 1.0
ESTIMATION_BACKEND_ENV = "HERA_ESTIMATION_BACKEND"
"""``hera.estimation.backend.ENV_VAR`` (not imported: a node that runs no filter never
loads the estimation package)."""
__all__ = [
    "EXIT_CONFIG",
    "EXIT_ESCALATED",
    "EXIT_INJECTED_CRASH",
    "FATAL",
    "FatalStart",
    "Node",
    "run_node",
]


class FatalStart(RuntimeError):
    """The node cannot start, and restarting it will not help (see the exit codes)."""


class Node:
    """The runtime of one node of a cluster spec.

    ``services`` are the node service factories to start (default: every one registered
    in ``hera.services``, see :func:`hera.plugins.service_factories`).
    """

    def __init__(
        self,
        spec: ClusterSpec,
        name: str,
        run_dir: str | Path | None = None,
        services: Mapping[str, ServiceFactory] | None = None,
        state_dir: str | Path | None = None,
    ) -> None:
        self.spec = spec
        self.decl = spec.node(name)
        self.name = name
        self.keys = Keys(spec.name)
        self.run_dir = Path(run_dir) if run_dir is not None else None
        if state_dir is None and self.run_dir is not None:
            state_dir = self.run_dir / "state"
        self.state_dir = Path(state_dir) / name if state_dir is not None else None
        self.store = Store((n.name for n in spec.nodes), spec.max_names_per_node)
        self.resources = Resources()
        logs = self.run_dir is not None and spec.log_node == name
        self.data = DataPath(
            name,
            self.keys,
            self.store,
            CsvLog(self.run_dir, self._columns(), spec.max_open_logs) if logs else None,
            spec.log_names,
            declared=frozenset((str(m.name), n) for n, m in spec.measures()),
        )
        self.peers = Peers(self.keys)
        self.control = ControlPlane(self)
        self.halt = threading.Event()
        self.exit_code = 0
        self.started_at = time.time()
        self._factories = services
        self.services: dict[str, NodeService] = {}
        self._handles: list[Any] = []
        self.session: zenoh.Session | None = None
        self.supervisor: Supervisor | None = None
        self.args: ArgsStore | None = None
        self.decls: dict[str, MeasureSpec] = {}
        """Every measure the supervisor runs, by name: the spec's and those started at run
        time (:mod:`hera.dynamic`)."""

    # -- life cycle ---------------------------------------------------------------------
    def start(self) -> None:
        """Join the bus, recover state from peers and start the services and measures."""
        self._select_estimation_backend()
        try:
            bus = node_bus(self.spec, self.name)
        except (CredentialsError, ValueError) as e:
            raise FatalStart(str(e)) from None
        me = ", ".join(bus.listen) or "no endpoint (a client)"
        try:
            self.session = s = open_session(bus)
        except zenoh.ZError as e:
            if "Address already in use" in str(e):
                raise FatalStart(f"its port {me} is in use by another process") from None
            raise
        self.data.attach(s)
        if self.spec.node(self.name).store == "all":  # a full mirror, for tools
            self.data.want(None)
        elif self.data.csv is not None:  # the logging node keeps every sender's samples
            self.data.want(self.spec.log_names or None)
        self.args = ArgsStore(
            self.name, s, self.keys, self.state_dir, self.spec.max_clock_skew_ms * 1_000_000
        )
        self.peers.on_up = self.args.on_peer_up  # what was written before a link existed
        self._handles.append(
            s.liveliness().declare_subscriber(
                self.keys.alive_all, self.peers.on_alive, history=True
            )
        )
        self._recover()
        self._handles.append(s.liveliness().declare_token(self.keys.alive(self.name)))
        self._start_services()
        self._beats: dict[tuple[float, float], Beat] = {}
        self._beats_lock = threading.Lock()
        self.supervisor = Supervisor(
            self.spec.intensity,
            self.spec.intensity_period,
            self.spec.strategy,
            on_escalate=self._escalate,
        )
        for m in self.decl.measures:
            self.add_measure(m)
        restore_measures(self)
        # last: a node that answers status has all its measures registered
        self._handles.append(
            s.declare_queryable(self.keys.ctl(self.name, "*"), self.control.on_query, complete=True)
        )
        log.info("node %s up on %s with %d measures", self.name, me, len(self.decl.measures))

    def _select_estimation_backend(self) -> None:
        """Nodes fuse on numpy unless the spec asks for numba ([cluster] estimation_backend).
        The choice applies when a measure makes its first filter: a node that runs none
        never imports numba (about 65 MB) nor loads the kernels (about 80 MB more), nor
        even :mod:`hera.estimation` and numpy (about 15 MB): the choice goes through the
        variable the backend reads at the first filter (:data:`ESTIMATION_BACKEND_ENV`),
        unless the package is loaded already."""
        name = self.spec.estimation_backend
        if name == "numba" and importlib.util.find_spec("numba") is None:
            raise FatalStart("estimation_backend = 'numba' but numba is not installed")
        backend = sys.modules.get("hera.estimation.backend")
        if backend is not None:
            backend.prefer(name)
        else:
            os.environ[ESTIMATION_BACKEND_ENV] = name

    def _remember_incarnation(self) -> None:
        """Read the incarnation of this node's previous process from its state directory
        (the only one whose seqs it will continue) and write this process's own."""
        if self.state_dir is None:
            return
        path = self.state_dir / "incarnation"
        with contextlib.suppress(OSError, ValueError):
            inc, start = path.read_text().split()
            self.data.previous_incarnation, self.data.previous_start = int(inc), float(start)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(f"{self.data.incarnation} {self.started_at!r}\n")
        os.replace(tmp, path)

    def _recover(self) -> None:
        """Wait briefly for live peers, then fetch args and this node's latest seqs."""
        self._remember_incarnation()
        expected = {n.name for n in self.spec.nodes} - {self.name}
        self.peers.wait_for(expected, RECOVERY_TIMEOUT)
        if not self.peers.up:
            return
        got = self.args.recover(timeout=RECOVERY_TIMEOUT)
        self.data.recover_seqs(self.session, RECOVERY_TIMEOUT)
        log.info("recovered %d args and seqs from %s", got, self.peers.names())

    def _start_services(self) -> None:
        if self._factories is None:
            from hera.plugins import service_factories

            self._factories = service_factories()
        ctx = ServiceContext(self.session, self.keys, self.name, self.spec, self.state_dir)
        for name, factory in self._factories.items():
            service = factory(ctx)
            service.start()
            self.services[name] = service

    def _slot_service(self, spec: MeasureSpec) -> SlotService:
        for service in self.services.values():
            if isinstance(service, SlotService):
                return service
        raise RuntimeError(
            f"measure {spec.name!r} is marked sync but no slot service is installed "
            f"(node services: {sorted(self.services) or 'none'})"
        )

    def add_measure(self, decl: MeasureSpec, start: bool = True) -> None:
        """Supervise a measure of this node (started unless ``start`` is False)."""
        cls = find_measure(decl.use)
        spec = decl.resolve(cls)
        args = cls.prepare_args(decl.args)  # refuse bad arguments before the child is added
        self.data.want(cls.reads(args))  # its node takes the samples it reads
        self.supervisor.add(Child(spec.name, self.measure_factory(decl, cls), spec.restart), start)
        self.decls[spec.name] = decl

    def measure_args(self, cls: type, decl: MeasureSpec) -> Mapping[str, Any]:
        """What a measure's ``init`` receives: the spec's arguments merged with the run-time
        ones of the args store (``measure/<node>/<name>/<arg>``); the spec's alone, logged,
        when the merge is refused by the measure's declared arguments."""
        name = str(decl.resolve(cls).name)
        extra = runtime_args(self.args.items(), self.name, name) if self.args else {}
        if extra:
            try:
                return cls.prepare_args({**decl.args, **extra})
            except ValueError as e:
                log.error("measure %s: ignoring its run-time arguments: %s", name, e)
        return cls.prepare_args(decl.args)

    def measure_factory(
        self, decl: MeasureSpec, cls: type, counters: dict[str, float] | None = None
    ) -> Callable[..., Worker]:
        """``make(on_exit, gate=None) -> Worker``: a new worker of measure class ``cls`` for
        ``decl`` (the supervisor calls it at every (re)start; a hot reload with a gate)."""
        spec = decl.resolve(cls)
        counters = {} if counters is None else counters
        slots = self._slot_service(spec) if spec.sync else None

        def make(on_exit, gate: threading.Event | None = None) -> Worker:
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
                seed=spec.seed,
                run_dir=str(self.run_dir) if self.run_dir is not None else None,
                state_dir=str(self.state_dir) if self.state_dir is not None else None,
                resources=self.resources,
                log=logging.getLogger(f"hera.measure.{spec.name}"),
            )
            return Worker(
                cls,
                self.measure_args(cls, decl),
                ctx,
                self.data.publish,
                on_exit,
                slot_runner=slots.slot_runner(spec, ctx) if slots is not None else None,
                halt=self.halt,
                args_source=lambda: self.measure_args(cls, decl),
                gate=gate,
                phase=self._phase_of(spec),
                beat=self._beat_of(spec) if spec.thread == "shared" else None,
            )

        return make

    def _beat_of(self, spec: MeasureSpec) -> Beat:
        """The node's beat of ``spec``'s period and offset (made at first use): the thread
        that steps its shared measures (:mod:`hera.beat`)."""
        period = float(spec.period)
        offset = 0.0 if spec.offset is None else spec.offset
        with self._beats_lock:
            beat = self._beats.get((period, offset))
            if beat is None:
                phase = wall_grid(offset, period, wallclock.now(), time.monotonic())
                beat = Beat(period, phase, name=f"beat-{period:g}s+{offset:g}")
                self._beats[(period, offset)] = beat
            return beat

    def _phase_of(self, spec: MeasureSpec) -> float | None:
        """The grid of a measure's steps (timer coalescing, :mod:`hera.worker`): ``offset``
        (default 0) past each multiple of its period on this node's wall clock, so the
        measures of one period wake together on every node of the cluster; None for sync
        measures (their steps wait for slots and keep their own phase)."""
        if spec.sync:
            return None
        offset = 0.0 if spec.offset is None else spec.offset
        return wall_grid(offset, float(spec.period), wallclock.now(), time.monotonic())

    def _columns(self) -> dict[str, tuple[str, ...]]:
        """Output columns of every measure of the spec (for the CSV sidecars)."""
        cols = {}
        for _, m in self.spec.measures():
            with contextlib.suppress(LookupError, TypeError):
                cols[m.name] = tuple(find_measure(m.use).columns)
        return cols

    def status(self) -> dict[str, Any]:
        """The node's status as a JSON-able dict (see :mod:`hera.nodestatus`)."""
        return node_status(self)

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
        """Stop the measures and services, flush and close the session. Safe to call twice."""
        self.halt.set()
        if self.supervisor is not None:
            self.supervisor.shutdown(self.spec.shutdown_timeout)
        for service in self.services.values():
            with contextlib.suppress(Exception):
                service.close()
        self.resources.close()
        if self.args is not None:
            self.args.close()
        for h in reversed(self._handles):
            with contextlib.suppress(Exception):
                h.undeclare()
        self._handles.clear()
        self.data.close()
        if self.session is not None:
            self.session.close()
            self.session = None
        if self.data.csv is not None:
            self.data.csv.close()

    def _escalate(self, reason: str) -> None:
        log.error("node %s escalates: %s", self.name, reason)
        self.stop(EXIT_ESCALATED)


def node_bus(spec: ClusterSpec, name: str, environ: Mapping[str, str] = os.environ) -> BusConfig:
    """How node ``name`` joins the bus: its endpoints (:func:`hera.topology.bus_config`), the
    overrides of ``$HERA_BUS_OVERRIDES`` (a campaign's link proxy replaces its connects),
    then its credentials, which make every endpoint a TLS one when the cluster runs TLS.
    CredentialsError or ValueError (the overrides file) naming the cause."""
    return secured(spec, name, with_overrides(bus_config(spec, name), name, environ))


def run_node(
    spec: ClusterSpec,
    name: str,
    run_dir: str | None,
    parent_pid: int | None,
    state_dir: str | None = None,
) -> int:
    """Run one node until SIGTERM/SIGINT, a shutdown request, escalation or the death of
    ``parent_pid``; clean up and return the exit code."""
    node = Node(spec, name, run_dir, state_dir=state_dir)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: node.stop(0))
    try:
        try:
            node.start()
        except FatalStart as e:
            log.error("%s%s", FATAL, e)
            return EXIT_CONFIG
        while not node.halt.wait(0.25):
            if parent_pid is not None and os.getppid() != parent_pid:
                log.error("launcher %d is gone; node %s stops", parent_pid, name)
                node.stop(0)
        return node.exit_code
    finally:
        node.close()
