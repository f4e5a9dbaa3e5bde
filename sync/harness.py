"""Test and benchmark harness: real node processes hosting the sync service and firing.

Run one node process with ``python -m hera.sync.harness --node s1 --port 7447 ...``. It
opens a Zenoh peer session on 127.0.0.1, hosts the sync service for its group, runs one
worker thread per measure that fires as often as it may, and appends one line per event to
its log file right away (``os.write`` on an ``O_APPEND`` file, so a SIGKILL loses nothing).
All times are on :data:`CLOCK`, the clock grants' deadlines are on:

- ``F <start> <end> <deadline> <holder> <epoch> <token> <checked>``: a firing; ``start``
  is the clock read at the trigger itself (after any pause between the fit check and the
  trigger), ``end = start + slot`` the end of the sound (a stopped CPU does not prolong
  it), ``deadline`` the end of the grant's lease, ``checked`` the clock read by the fit
  check at the trigger;
- ``E <observed_end> <holder> <token>``: the firing function returned;
- ``G <asked> <granted> <holder> <token>``: ``acquire`` was called and returned a grant;
- ``L <now> <holder> <epoch> <token>``: a grant arrived too late and was given back;
- ``S <now> <holder> <token>``: the worker is about to SIGSTOP its own process while
  holding a grant (``selfstop`` command);
- ``H``/``R <now> <holder> <epoch> <token>``: a release is held back / was sent late;
- ``X <now> <holder>``: the worker of that measure has ended (``remove`` command).

Commands on stdin, one per line: ``add NAME SLOT_MS``, ``remove NAME``, ``selfstop NAME``
(SIGSTOP this process right after NAME's next grant, before its fit check; that worker then
holds until ``go NAME``, to be sent after SIGCONT), ``stall NAME MS EVERY`` (every
EVERY-th firing of NAME pauses MS ms in the measure's code, before the driver),
``stall-trigger NAME MS EVERY`` (the same, inside the driver between its fit check and the
trigger), ``holdrelease NAME`` (after NAME's next firing, hold its release back) and
``release NAME N`` (send the held release N times, 2 ms apart, then go on), ``close``
(close the Zenoh session without exiting: cut off the bus) and ``quit``. The process writes
its status (JSON, ``SyncService.status()`` under ``"sync"``) to ``--status`` every 50 ms.

The firing function is pluggable: ``--fire module:factory`` where ``factory(ctx)`` gets a
dict (node, measure, slot, session, keys) and returns a callable run inside each slot.

:class:`Cluster` starts and controls such processes from a test or benchmark and always
cleans them up; :func:`read_logs` and :func:`check_firings` read and check the logs.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hera import cliargs
from hera.ports import free_ports
from hera.sync import clock as sync_clock

STATUS_EVERY = 0.05
CLOCK = sync_clock.now
"""The clock of every time the harness logs (the clock grants' deadlines are on)."""

# ------------------------------------------------------------------------------------------
# The node process
# ------------------------------------------------------------------------------------------


class _Log:
    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)

    def line(self, *fields: Any) -> None:
        os.write(self.fd, (" ".join(str(f) for f in fields) + "\n").encode())


class _Stall:
    """A stall to inject every ``every``-th firing of a measure (``stall`` commands)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.every = 0
        self.count = 0

    def set(self, ms: str, every: str) -> None:
        self.seconds, self.every, self.count = float(ms) / 1000.0, int(every), 0

    def maybe(self) -> float:
        """Sleep if this is the firing to stall; return the seconds stalled."""
        if self.every <= 0:
            return 0.0
        self.count += 1
        if self.count % self.every:
            return 0.0
        time.sleep(self.seconds)
        return self.seconds


class _Worker:
    """One measure firing as often as it may; a SlotClient wrapper for the test hooks.

    A firing runs like a synchronised step of a node: the runtime's wrapper, then the
    measure's own code (where ``stall`` injects a pause), then the driver, which triggers
    (``stall-trigger`` injects a pause just before the trigger). The ``F`` line records the
    clock read at the trigger itself, so the audit sees a late trigger as late.
    """

    def __init__(self, name: str, slot: float, node: Any) -> None:
        self.name = name
        self.slot = slot
        self.node = node
        self.holder = f"{node.node}/{name}"
        self.stop = threading.Event()
        self.selfstop = threading.Event()
        self.go = threading.Event()
        self.stall = _Stall()
        self.stall_trigger = _Stall()
        self.hold_release = threading.Event()
        self.resend = threading.Event()
        self.resend_times = 0
        self.grant: Any = None
        self.fired = 0
        self.fire = node.make_fire(name, slot)
        self.thread = threading.Thread(target=self._run, name=f"worker-{name}", daemon=True)

    # SlotClient protocol, delegating to the node's client
    def acquire(self, group: str, holder: str, duration: float, timeout: float) -> Any:
        t0 = CLOCK()
        g = self.node.client.acquire(group, holder, duration, timeout)
        self.grant = g
        if g is not None:
            self.node.log.line("G", t0, CLOCK(), self.holder, g.token)
        if g is not None and self.selfstop.is_set():
            self.selfstop.clear()
            self.node.log.line("S", CLOCK(), self.holder, g.token)
            os.kill(os.getpid(), signal.SIGSTOP)
            # SIGSTOP lands asynchronously: hold this thread until told to go on (after
            # SIGCONT), so the stop surely falls between the grant and the fit check.
            self.go.wait()
            self.go.clear()
        return g

    def release(self, grant: Any, used: bool) -> None:
        if self.hold_release.is_set() and used:
            # stall before the release (``holdrelease``); ``release N`` then sends it N
            # times, 2 ms apart (a late, duplicated release)
            self.hold_release.clear()
            self.node.log.line("H", CLOCK(), self.holder, grant.epoch, grant.token)
            self.resend.wait()
            for _ in range(self.resend_times):
                self.node.client.release(grant, used)
                time.sleep(0.002)
            self.node.log.line("R", CLOCK(), self.holder, grant.epoch, grant.token)
        self.node.client.release(grant, used)

    def note_late(self, grant: Any) -> None:
        self.node.client.note_late(grant)

    def _fire(self, turn: Any) -> Any:
        """The measure's code, then the driver."""
        self.stall.maybe()  # the measure's own code
        return self._drive(turn)

    def _drive(self, turn: Any) -> Any:
        """The simulated driver: the fit check at the trigger, the trigger, the sound."""
        checked = turn.check_at_trigger().clock  # raises SlotLost if it no longer fits
        self.stall_trigger.maybe()  # outside the guarantee beyond Timing.trigger_pause
        start = CLOCK()  # the trigger
        end = start + self.slot
        g = turn.grant
        self.node.log.line("F", start, end, g.deadline, self.holder, g.epoch, g.token, checked)
        result = self.fire()
        left = end - CLOCK()
        if left > 0:
            time.sleep(left)
        self.node.log.line("E", CLOCK(), self.holder, g.token)
        return result

    def _run(self) -> None:
        from hera.sync.client import run_in_slot

        while not self.stop.is_set():
            fired, _, grant = run_in_slot(
                self, self.node.group, self.holder, self.slot, self._fire, timeout=1.0
            )
            if fired:
                self.fired += 1
            elif grant is not None:
                self.node.log.line("L", CLOCK(), self.holder, grant.epoch, grant.token)
        self.node.log.line("X", CLOCK(), self.holder)


def _no_fire(ctx: dict[str, Any]) -> Callable[[], None]:
    return lambda: None


class _Node:
    def __init__(self, args: argparse.Namespace) -> None:
        from hera.bus import BusConfig, open_session, tcp_endpoint
        from hera.keys import Keys
        from hera.sync.service import SyncService

        self.node = args.node
        self.group = args.group
        self.log = _Log(args.log)
        self.status_path = args.status
        peers = tuple(tcp_endpoint("127.0.0.1", int(p)) for p in args.peers.split(",") if p)
        cfg = BusConfig(
            listen=(tcp_endpoint("127.0.0.1", args.port),),
            connect=peers,
            lease_ms=args.bus_lease_ms,
        )
        self.session = open_session(cfg)
        self.keys = Keys(args.cluster)
        hosts = [h for h in args.hosts.split(",") if h]
        host_groups = {args.group: hosts} if args.node in hosts else {}
        self.service = SyncService(
            self.session,
            self.keys,
            args.node,
            host_groups,
            lease_ms=args.lease_ms,
            state_dir=args.state_dir or None,
        )
        self.client = self.service.client()
        self.fire_factory = _no_fire
        if args.fire:
            mod, _, fn = args.fire.partition(":")
            self.fire_factory = getattr(importlib.import_module(mod), fn)
        self.workers: dict[str, _Worker] = {}
        self.closed = False
        self.quit = threading.Event()

    def make_fire(self, name: str, slot: float) -> Callable[[], Any]:
        ctx = {
            "node": self.node,
            "measure": name,
            "slot": slot,
            "session": self.session,
            "keys": self.keys,
        }
        return self.fire_factory(ctx)

    def command(self, line: str) -> None:
        parts = line.split()
        if not parts:
            return
        verb = parts[0]
        if verb == "add" and len(parts) == 3 and parts[1] not in self.workers:
            w = _Worker(parts[1], float(parts[2]) / 1000.0, self)
            self.workers[w.name] = w
            w.thread.start()
        elif verb == "remove" and len(parts) == 2 and parts[1] in self.workers:
            self.workers.pop(parts[1]).stop.set()
        elif verb == "selfstop" and len(parts) == 2 and parts[1] in self.workers:
            self.workers[parts[1]].selfstop.set()
        elif verb == "go" and len(parts) == 2 and parts[1] in self.workers:
            self.workers[parts[1]].go.set()
        elif verb in ("stall", "stall-trigger") and len(parts) == 4 and parts[1] in self.workers:
            w = self.workers[parts[1]]
            (w.stall if verb == "stall" else w.stall_trigger).set(parts[2], parts[3])
        elif verb == "holdrelease" and len(parts) == 2 and parts[1] in self.workers:
            self.workers[parts[1]].hold_release.set()
        elif verb == "release" and len(parts) == 3 and parts[1] in self.workers:
            w = self.workers[parts[1]]
            w.resend_times = int(parts[2])
            w.resend.set()
        elif verb == "close" and not self.closed:
            self.closed = True
            self.session.close()  # cut off the bus; the service's threads live on
        elif verb == "quit":
            self.quit.set()

    def write_status(self) -> None:
        st = {
            "node": self.node,
            "pid": os.getpid(),
            "t": CLOCK(),
            "closed": self.closed,
            "fired": {w.name: w.fired for w in self.workers.values()},
            "sync": self.service.status(),
        }
        tmp = f"{self.status_path}.tmp"
        with open(tmp, "w") as f:
            json.dump(st, f)
        os.replace(tmp, self.status_path)


def _stdin_reader(node: _Node, lines: list[str], lock: threading.Lock) -> None:
    for line in sys.stdin:
        with lock:
            lines.append(line)
    node.quit.set()  # stdin closed: the parent is gone


def main(argv: list[str] | None = None) -> int:
    """Run one harness node process until ``quit`` or the end of stdin."""
    p = argparse.ArgumentParser(prog="python -m hera.sync.harness")
    p.add_argument("--node", required=True)
    p.add_argument("--port", type=cliargs.port, required=True)
    p.add_argument("--peers", default="", help="comma-separated ports of the other nodes")
    p.add_argument("--hosts", default="", help="comma-separated host nodes of the group")
    p.add_argument("--group", default="sonar")
    p.add_argument("--cluster", default="synctest")
    p.add_argument("--measure", action="append", default=[], help="NAME:SLOT_MS")
    p.add_argument("--lease-ms", type=cliargs.count, default=300)
    p.add_argument("--bus-lease-ms", type=cliargs.count, default=2000)
    p.add_argument("--fire", default="", help="module:factory returning the fire callable")
    p.add_argument("--state-dir", default="", help="where the voter keeps its promise")
    p.add_argument("--log", required=True)
    p.add_argument("--status", required=True)
    args = p.parse_args(argv)
    node = _Node(args)
    try:
        node.service.start()
        for m in args.measure:
            name, _, slot_ms = m.partition(":")
            node.command(f"add {name} {slot_ms}")
        lines: list[str] = []
        lock = threading.Lock()
        threading.Thread(target=_stdin_reader, args=(node, lines, lock), daemon=True).start()
        while not node.quit.is_set():
            with lock:
                todo, lines[:] = list(lines), []
            for line in todo:
                node.command(line)
            node.write_status()
            node.quit.wait(STATUS_EVERY)
        for w in node.workers.values():
            w.stop.set()
        for w in node.workers.values():
            w.thread.join(timeout=2.0)
        node.service.close()
        if not node.closed:
            node.session.close()
    finally:
        sys.stdout.flush()
        os._exit(0)  # never hang at exit on a worker stuck in a Zenoh call


# ------------------------------------------------------------------------------------------
# Driving a cluster of harness processes
# ------------------------------------------------------------------------------------------


@dataclass
class Firing:
    """One sound: ``start`` (the trigger) to ``end``, under grant ``(epoch, token)``."""

    start: float
    end: float
    deadline: float
    holder: str
    epoch: int
    token: int
    node: str
    checked: float = float("nan")


@dataclass
class Logs:
    """Everything the node processes logged."""

    firings: list[Firing] = field(default_factory=list)
    late: list[tuple[float, str, int, int]] = field(default_factory=list)
    stops: list[tuple[float, str, int]] = field(default_factory=list)
    exits: dict[str, float] = field(default_factory=dict)
    acquires: list[tuple[float, float, str]] = field(default_factory=list)
    held: list[tuple[float, str, int, int]] = field(default_factory=list)
    resent: list[tuple[float, str, int, int]] = field(default_factory=list)
    lines: dict[str, list[list[str]]] = field(default_factory=dict)


def read_logs(paths: dict[str, Path]) -> Logs:
    """Parse the log files of the nodes (``node -> path``); a torn last line is skipped."""
    out = Logs()
    for node, path in paths.items():
        try:
            text = path.read_text()
        except FileNotFoundError:
            continue
        rows = []
        for raw in text.splitlines():
            f = raw.split()
            try:
                if f[0] == "F" and len(f) == 8:
                    out.firings.append(
                        Firing(
                            float(f[1]),
                            float(f[2]),
                            float(f[3]),
                            f[4],
                            int(f[5]),
                            int(f[6]),
                            node,
                            float(f[7]),
                        )
                    )
                elif f[0] in ("H", "R") and len(f) == 5:
                    rec = (float(f[1]), f[2], int(f[3]), int(f[4]))
                    (out.held if f[0] == "H" else out.resent).append(rec)
                elif f[0] == "L" and len(f) == 5:
                    out.late.append((float(f[1]), f[2], int(f[3]), int(f[4])))
                elif f[0] == "S" and len(f) == 4:
                    out.stops.append((float(f[1]), f[2], int(f[3])))
                elif f[0] == "G" and len(f) == 5:
                    out.acquires.append((float(f[1]), float(f[2]), f[3]))
                elif f[0] == "X" and len(f) == 3:
                    out.exits[f[2]] = float(f[1])
                elif f[0] != "E":
                    continue
            except (IndexError, ValueError):
                continue
            rows.append(f)
        out.lines[node] = rows
    out.firings.sort(key=lambda x: x.start)
    return out


@dataclass
class Check:
    """The verdict on a set of firings."""

    firings: int
    overlaps: list[tuple[Firing, Firing]]
    out_of_order: list[tuple[Firing, Firing]]
    past_deadline: list[Firing]

    @property
    def ok(self) -> bool:
        return not (self.overlaps or self.out_of_order or self.past_deadline)


def check_firings(firings: list[Firing], pause: float = 0.0) -> Check:
    """Check mutual exclusion on the real trigger times: no two firings overlap; in start
    order the tokens (audit labels: a sonar cannot check them) strictly increase, so no
    stale grant fired after a newer one; each sound's fit check held (checked + slot within
    the lease) and it ends within its lease plus ``pause`` (s): condition C of
    ``sync/README.md`` tolerates a pause p between the check and the trigger
    (``Timing.trigger_pause``), so a sound may outlive its lease by that much and no more.
    ``pause = 0`` asks for every sound within its lease."""
    fs = sorted(firings, key=lambda x: x.start)
    overlaps, disorder = [], []
    latest: Firing | None = None
    for prev, cur in zip(fs, fs[1:], strict=False):
        if cur.token <= prev.token:
            disorder.append((prev, cur))
    for cur in fs:
        if latest is not None and cur.start < latest.end:
            overlaps.append((latest, cur))
        if latest is None or cur.end > latest.end:
            latest = cur
    past = [
        f for f in fs if f.checked + (f.end - f.start) > f.deadline or f.end > f.deadline + pause
    ]
    return Check(len(fs), overlaps, disorder, past)


class Cluster:
    """Harness node processes on loopback; a context manager that always cleans up.

    ``hosts`` host the service (and fire, one measure each unless ``measures`` says
    otherwise); ``clients`` only fire. Each node keeps its sync state in
    ``state_dir(node)`` (kept across restarts unless wiped). Every process is SIGCONTed then
    SIGKILLed at exit.
    """

    def __init__(
        self,
        hosts: list[str],
        clients: tuple[str, ...] = (),
        slot_ms: float = 5.0,
        lease_ms: int = 300,
        bus_lease_ms: int = 2000,
        group: str = "sonar",
        measures: dict[str, list[tuple[str, float]]] | None = None,
        fire: str = "",
        workdir: str | None = None,
    ) -> None:
        self.hosts = list(hosts)
        self.nodes = [*hosts, *clients]
        self.slot_ms = slot_ms
        self.lease_ms = lease_ms
        self.bus_lease_ms = bus_lease_ms
        self.group = group
        self.fire = fire
        self.measures = measures or {n: [("m", slot_ms)] for n in self.nodes}
        self._tmp = None if workdir else tempfile.TemporaryDirectory(prefix="hera-sync-")
        self.dir = Path(workdir or self._tmp.name)  # type: ignore[union-attr]
        self.ports = dict(zip(self.nodes, free_ports("127.0.0.1", len(self.nodes)), strict=False))
        self.procs: dict[str, subprocess.Popen] = {}
        self.stopped: set[str] = set()
        self._expected_dead: set[str] = set()
        self.cluster = f"t{os.getpid()}x{self.ports[self.nodes[0]]}"

    def log_path(self, node: str) -> Path:
        return self.dir / f"{node}.log"

    def status_path(self, node: str) -> Path:
        return self.dir / f"{node}.status.json"

    def state_dir(self, node: str) -> Path:
        return self.dir / "state" / node

    def start(self, node: str | None = None) -> None:
        """Start every node (or one, e.g. to restart it)."""
        for n in [node] if node else self.nodes:
            self._expected_dead.discard(n)
            peers = ",".join(str(p) for m, p in self.ports.items() if m != n)
            cmd = [
                sys.executable, "-m", "hera.sync.harness",
                "--node", n, "--port", str(self.ports[n]), "--peers", peers,
                "--hosts", ",".join(self.hosts), "--group", self.group,
                "--cluster", self.cluster, "--lease-ms", str(self.lease_ms),
                "--bus-lease-ms", str(self.bus_lease_ms),
                "--log", str(self.log_path(n)), "--status", str(self.status_path(n)),
                "--state-dir", str(self.state_dir(n)),
            ]  # fmt: skip
            for name, slot in self.measures.get(n, []):
                cmd += ["--measure", f"{name}:{slot}"]
            if self.fire:
                cmd += ["--fire", self.fire]
            err = open(self.dir / f"{n}.stderr", "ab")  # noqa: SIM115 - kept by the child
            self.procs[n] = subprocess.Popen(
                cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=err
            )
            err.close()

    def __enter__(self) -> Cluster:
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """SIGCONT then SIGKILL every process started, and reap them."""
        for _n, p in self.procs.items():
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.pid, signal.SIGCONT)
                    os.kill(p.pid, signal.SIGKILL)
        for p in self.procs.values():
            with contextlib.suppress(Exception):
                p.wait(timeout=10)
            if p.stdin:
                with contextlib.suppress(Exception):
                    p.stdin.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # -- control -------------------------------------------------------------------------

    def send(self, node: str, command: str) -> None:
        p = self.procs[node]
        assert p.stdin is not None
        p.stdin.write((command + "\n").encode())
        p.stdin.flush()

    def kill(self, node: str) -> None:
        p = self.procs[node]
        self.expect_dead(node)
        os.kill(p.pid, signal.SIGCONT)
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=10)
        self.stopped.discard(node)

    def restart_hosts(self, wipe: bool = False) -> None:
        """Kill every host process at once, then start them all again (a redeploy, or a
        power blip); ``wipe``: their state directories are lost too."""
        for n in self.hosts:
            if self.procs[n].poll() is None:
                self.kill(n)
        if wipe:
            for n in self.hosts:
                shutil.rmtree(self.state_dir(n), ignore_errors=True)
        for n in self.hosts:
            self.start(n)

    def stop(self, node: str) -> None:
        os.kill(self.procs[node].pid, signal.SIGSTOP)
        self.stopped.add(node)

    def cont(self, node: str) -> None:
        os.kill(self.procs[node].pid, signal.SIGCONT)
        self.stopped.discard(node)

    def is_stopped(self, node: str) -> bool:
        """True once the kernel reports the process stopped (state T)."""
        try:
            stat = Path(f"/proc/{self.procs[node].pid}/stat").read_text()
        except FileNotFoundError:
            return False
        return stat.rsplit(")", 1)[1].split()[0] in ("T", "t")

    # -- observation ---------------------------------------------------------------------

    def status(self, node: str) -> dict[str, Any] | None:
        """The last status written by the node's current process (None before its first)."""
        try:
            st = json.loads(self.status_path(node).read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None
        return st if st.get("pid") == self.procs[node].pid else None

    def group_status(self, node: str) -> dict[str, Any] | None:
        st = self.status(node)
        return st["sync"]["groups"].get(self.group) if st else None

    def leader(self) -> tuple[str, int] | None:
        """(node, epoch) of the granting leader with the highest epoch among the live,
        running processes, by their status files."""
        best = None
        for n in self.hosts:
            if n in self.stopped or self.procs[n].poll() is not None:
                continue
            g = self.group_status(n)
            if g and g["role"] == "leader" and (best is None or g["epoch"] > best[1]):
                best = (n, g["epoch"])
        return best

    def logs(self) -> Logs:
        return read_logs({n: self.log_path(n) for n in self.nodes})

    def firings(self) -> list[Firing]:
        return self.logs().firings

    def count(self, pred: Callable[[Firing], bool] = lambda f: True) -> int:
        return sum(1 for f in self.firings() if pred(f))

    def wait_for(self, what: str, cond: Callable[[], Any], timeout: float = 20.0) -> Any:
        """Poll ``cond`` every 20 ms until it returns a true value; AssertionError naming
        ``what`` (with the stderr of dead nodes) after ``timeout`` s."""
        end = time.monotonic() + timeout
        while True:
            v = cond()
            if v:
                return v
            for n, p in self.procs.items():
                if p.poll() is not None and n not in self._expected_dead:
                    raise AssertionError(f"node {n} exited: {self.stderr(n)}")
            if time.monotonic() > end:
                raise AssertionError(f"timed out waiting for {what}")
            time.sleep(0.02)

    def expect_dead(self, node: str) -> None:
        """Do not fail ``wait_for`` because ``node`` has exited."""
        self._expected_dead.add(node)

    def stderr(self, node: str) -> str:
        try:
            return (self.dir / f"{node}.stderr").read_text()[-2000:]
        except FileNotFoundError:
            return ""


if __name__ == "__main__":
    sys.exit(main())
