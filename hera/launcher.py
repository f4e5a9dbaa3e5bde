"""``hera up``: run every node of a spec as its own OS process, and keep them running.

- The spec is checked whole before anything starts (:mod:`hera.preflight`), fixed ports
  included: every problem is reported at once.
- Every run gets its own run directory (:mod:`hera.rundirs`); one given by hand that holds a
  previous run is refused unless asked to overwrite it. Free loopback ports are picked when
  the spec says ``base_port = 0``; the resolved spec (ports, world epoch) is written to
  ``<run-dir>/cluster.json`` and handed to the nodes.
- A node that exits is started again after ``RESTART_DELAY``, with a start limit like
  systemd's (at most ``START_BURST`` starts within ``START_INTERVAL`` s, then it stays
  failed). A node that cannot start for a cause that will not go away (a busy port: it exits
  with :data:`hera.node.EXIT_CONFIG` after logging the cause) is not restarted: the
  launcher prints the cause, stops the cluster and exits 1. Each node's output goes to
  ``<run-dir>/logs/<node>.log``.
- Nodes run in their own sessions (Ctrl-C reaches only the launcher) and watch the
  launcher's pid, so they stop even if the launcher is SIGKILLed.
- SIGINT, SIGTERM, ``hera down`` or the end of ``--duration`` stop everything: SIGTERM to
  each node, SIGKILL after the shutdown timeout, exit 0, nothing left behind. ``--duration``
  counts from when every node answers (all its measures registered) and sees the others
  alive (:func:`not_up`), so a slow start (a loaded machine, a first import, a link Zenoh
  dials again after a failed first try) does not eat the run; a node not up within
  :data:`UP_WAIT_S` does not hold the clock.
- ``web``: serve the live web view (:mod:`hera.console`) on that loopback port while the
  cluster runs; ``mcap``: record every sample to that MCAP file (:mod:`hera.export.mcap`).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from hera.application import Panel
from hera.bus import netns_of
from hera.client import ClusterClient, registry_dir
from hera.fusion import spec_models
from hera.keys import Keys
from hera.node import EXIT_CONFIG, FATAL
from hera.panel import estimates_panels
from hera.plugins import AppIndex
from hera.ports import free_ports, port_taken
from hera.preflight import check_spec
from hera.rundirs import new_run_dir, prepare_run_dir, state_dir
from hera.security.access import OPERATOR
from hera.security.credentials import for_spec
from hera.security.secret import SECRET_FILE, make_secret
from hera.spec import ClusterSpec, SpecError, load_spec
from hera.statusview import render_view

START_BURST = 5
START_INTERVAL = 10.0
RESTART_DELAY = 0.05
UP_POLL_S = 0.25
"""How often (and how long each time) the launcher asks its nodes whether they are up."""
UP_WAIT_S = 30.0
"""``--duration`` counts from when every node is up, or from this long after the start."""


def not_up(local: set[str], status: dict[str, Any]) -> dict[str, str]:
    """Which of the ``local`` nodes are not up yet, given a status query's answers, and why.

    A node is up when it answers (so all its measures are registered) and sees every other
    local node alive (a link to it exists: what they publish reaches each other). A link
    that Zenoh retries after a failed first dial can come seconds after both answer."""
    missing: dict[str, str] = {}
    for node in sorted(local):
        st = status.get(node)
        if st is None:
            missing[node] = "does not answer"
            continue
        unseen = local - set(st.get("peers", ())) - {node}
        if unseen:
            missing[node] = "does not see " + ", ".join(sorted(unseen))
    return missing


def busy_ports(spec: ClusterSpec, local: set[str] | None = None) -> list[str]:
    """One problem per fixed port of the spec's nodes and routers run here (``local``,
    default all) that is already in use on its host."""
    out = []
    for part in (*spec.nodes, *spec.routers):
        if not part.port or (local is not None and part.name not in local):
            continue
        if netns_of(part.name):  # a namespace of its own, made for it: every port is free
            continue
        host = part.host or spec.host
        what = "router" if part in spec.routers else "node"
        e = port_taken(host, part.port)
        if e is not None:
            out.append(
                f"{spec.source}: {what} {part.name!r}: port {part.port} on {host} is not "
                f"free ({e.strerror}): change [cluster] base_port or its port"
            )
    return out


def web_port_problems(port: int, host: str = "127.0.0.1") -> list[str]:
    """The problem with serving the web view on ``host:port``, if any."""
    e = port_taken(host, port)
    if e is not None:
        return [f"--web: port {port} on {host} is not free ({e.strerror}): pick another"]
    return []


def output_file_problems(option: str, path: str | Path) -> list[str]:
    """The problem with writing ``path`` (the file of ``option``), if any: found by opening
    it for appending, which neither truncates a file that is there nor leaves one that was
    not (a read-only or missing folder, a folder in its place)."""
    target = Path(path)
    existed = target.exists()
    try:
        with open(target, "ab"):
            pass
    except OSError as e:
        return [f"{option}: cannot write {target}: {e.strerror or e}"]
    if not existed:
        target.unlink(missing_ok=True)
    return []


def console_dependencies(web: bool, mcap: bool) -> None:
    """ImportError naming the extra to install when the web view or MCAP recording is asked
    for without its packages (checked before any node starts)."""
    import importlib.util

    missing = [m for m, wanted in (("aiohttp", web), ("mcap", mcap)) if wanted]
    missing = [m for m in missing if importlib.util.find_spec(m) is None]
    if missing:
        raise ImportError(
            f"{' and '.join(missing)} not installed: pip install 'hera-fusion[console]'"
        )


def shown_measures(spec: ClusterSpec, index: AppIndex) -> dict[str, type]:
    """The measures whose latest values the live view shows: every measure of an
    application (its panel decides what to show) and every fusion model."""
    from hera.plugins import find_measure

    out = dict(spec_models(spec))
    for _, m in spec.measures():
        cls = find_measure(m.use)
        if index.app_of(cls) is not None:
            out.setdefault(str(m.name), cls)
    return out


def prefer_node(samples: list[dict], node: str) -> list[dict]:
    """One sample per name: ``node``'s own if it has one, else the first node's."""
    best: dict[str, dict] = {}
    for s in sorted(samples, key=lambda s: (s["node"] != node, s["node"])):
        best.setdefault(s["name"], s)
    return list(best.values())


INSTALLED_ONLY = "import sys; del sys.path[0]; "
"""The start of every ``python -c`` program hera runs in a child process: ``python -c``
(and ``-m``) put the current folder first on ``sys.path``, so from a source checkout the
child would import the checkout's ``hera/`` instead of the installed package (which
refuses to load there); the child drops that entry first."""
NODE_MAIN = INSTALLED_ONLY + "from hera.cli import main; sys.exit(main())"
"""What a node process runs: ``hera node ...`` from the *installed* package."""


def code_command(code: str, *args: str) -> list[str]:
    """``python -c CODE ARGS`` with the installed hera (see :data:`INSTALLED_ONLY`)."""
    return [sys.executable, "-c", INSTALLED_ONLY + code, *args]


def node_command(*args: str) -> list[str]:
    """The command line of a ``hera`` subcommand run in a child process."""
    return [sys.executable, "-c", NODE_MAIN, *args]


def module_command(module: str, *args: str) -> list[str]:
    """``python -m MODULE ARGS`` from the installed package, not the working folder's."""
    run = f"import runpy; runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"
    return code_command(run, *args)


@dataclass
class NodeProc:
    """One node process under the launcher's care."""

    name: str
    proc: subprocess.Popen | None = None
    starts: deque = field(default_factory=deque)
    restarts: int = 0
    state: str = "starting"  # up | restarting | failed | stopped
    last_exit: int | None = None
    restart_at: float | None = None
    started_at: float = 0.0

    def info(self) -> dict[str, Any]:
        return {
            "pid": self.proc.pid if self.proc else None,
            "state": self.state,
            "restarts": self.restarts,
            "last_exit": self.last_exit,
            "age_s": round(time.monotonic() - self.started_at, 3),
        }


class Launcher:
    """Starts a cluster and supervises its node processes (see module docstring)."""

    def __init__(
        self,
        spec_path: str | Path,
        run_dir: str | Path | None = None,
        duration: float | None = None,
        out: IO[str] | None = None,
        interval: float = 1.0,
        overwrite: bool = False,
        only: Sequence[str] | None = None,
        cert: str | Path | None = None,
        web: int | None = None,
        mcap: str | Path | None = None,
    ) -> None:
        spec = check_spec(load_spec(spec_path))
        if cert is not None:
            spec = spec.with_security(certs=str(Path(cert).resolve()))
        if spec.spans_hosts() and (spec.auth or spec.tls) and not spec.certs:
            raise SpecError(
                f"{spec.source}: [security]: the spec spans several hosts, which must share "
                "their credentials: make them with 'hera certs SPEC --out DIR', copy DIR to "
                "every host and give --cert DIR (or [security] certs = DIR)"
            )
        names = [n.name for n in spec.nodes] + [r.name for r in spec.routers]
        if only is not None:
            unknown = [x for x in only if x not in names]
            if unknown:
                raise SpecError(
                    f"{spec.source}: --only names {unknown}, which are not nodes or routers of "
                    f"the spec ({', '.join(names)})"
                )
        self.local = set(names if only is None else only)
        busy = busy_ports(spec, self.local)
        if web:
            busy += web_port_problems(web)
        if mcap is not None:
            busy += output_file_problems("--mcap", mcap)
        if web is not None or mcap is not None:
            console_dependencies(web is not None, mcap is not None)
        if busy:
            raise SpecError(busy)
        unset = spec.unported()
        if spec.base_port == 0 and unset:
            spec = spec.with_ports(free_ports(spec.host, len(unset)))
        if "epoch" not in spec.world:
            spec = spec.with_world(epoch=time.time())
        # credentials given (certs) are checked before a run directory is made: a refused
        # start leaves no empty run behind (nor hera-run/<cluster> pointing at one)
        makes_secret = spec.auth and not spec.tls and not spec.certs
        if not makes_secret:
            for name in self.local | {OPERATOR}:
                for_spec(spec, name)
        self.spec: ClusterSpec = spec
        self.link: Path | None = None
        if run_dir is None:
            self.run_dir = new_run_dir(spec.name)
            link = self.run_dir.parent / spec.name
            self.link = link if link.is_symlink() else None
        else:
            self.run_dir = prepare_run_dir(Path(run_dir), overwrite)
        self.state_dir = state_dir(spec.name, self.run_dir, run_dir is not None)
        if makes_secret:
            spec = spec.with_security(secret=str(make_secret(self.run_dir / SECRET_FILE)))
            for name in self.local | {OPERATOR}:
                for_spec(spec, name)  # CredentialsError now rather than in every node
        self.spec = spec
        self.duration = duration
        self.out = out or sys.stdout
        self.interval = interval
        self.routers = {r.name: NodeProc(r.name) for r in spec.routers if r.name in self.local}
        self.nodes = {n.name: NodeProc(n.name) for n in spec.nodes if n.name in self.local}
        self.id = f"{socket.gethostname()}-{os.getpid()}".replace("/", "_")
        self.shown = shown_measures(spec, AppIndex())
        self.index = AppIndex()
        self.stopping = threading.Event()
        self.failed: str | None = None
        self._written: tuple[list, float] = ([], 0.0)
        self._logs: dict[str, IO[bytes]] = {}
        self.web, self.mcap = web, mcap
        self.registry_file = registry_dir() / f"{spec.name}-{os.getpid()}.json"

    # -- process management -------------------------------------------------------------
    def host(self) -> str | None:
        """The address of the host this launcher runs on (that of its nodes and routers)."""
        for part in (*self.spec.routers, *self.spec.nodes):
            if part.name in self.local:
                return part.host or self.spec.host
        return None

    def _procs(self) -> list[NodeProc]:
        """Every process this launcher runs: the routers first, then the nodes."""
        return [*self.routers.values(), *self.nodes.values()]

    def _spawn(self, np: NodeProc) -> None:
        log = self._logs.get(np.name)
        if log is None:
            log = open(self.run_dir / "logs" / f"{np.name}.log", "ab")  # noqa: SIM115
            self._logs[np.name] = log
        spec_file = str(self.run_dir / "cluster.json")
        parent = ("--parent-pid", str(os.getpid()))
        if np.name in self.routers:
            cmd = node_command("router", spec_file, "--name", np.name, *parent)
        else:
            cmd = node_command(
                "node",
                spec_file,
                "--node",
                np.name,
                "--run-dir",
                str(self.run_dir),
                "--state-dir",
                str(self.state_dir),
                "--checked",  # the launcher checked the spec before it started any process
                *parent,
            )
        ns = netns_of(np.name)
        if ns is not None:  # a fault campaign's node in its own network namespace
            cmd = ["ip", "netns", "exec", ns, *cmd]
        np.proc = subprocess.Popen(
            cmd,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        np.starts.append(time.monotonic())
        np.started_at = time.monotonic()
        np.state = "up"
        np.restart_at = None

    def _check(self, np: NodeProc) -> None:
        now = time.monotonic()
        if np.state == "restarting" and np.restart_at is not None and now >= np.restart_at:
            while np.starts and now - np.starts[0] > START_INTERVAL:
                np.starts.popleft()
            if len(np.starts) >= START_BURST:
                np.state = "failed"
                last = self._last_line(np.name)
                self._say(
                    f"node {np.name}: start limit hit ({START_BURST} starts within "
                    f"{START_INTERVAL:g} s); not restarting it"
                    + (f" (its log ends: {last})" if last else "")
                )
                if all(p.state == "failed" for p in self.nodes.values()):
                    # nothing of this launcher's runs any more: waiting would show an empty
                    # cluster until Ctrl-C
                    self.failed = "every node failed" + (
                        f" (node {np.name}'s log ends: {last})" if last else ""
                    )
                    self.stopping.set()
                return
            np.restarts += 1
            self._spawn(np)
            return
        if np.proc is None or np.state != "up":
            return
        code = np.proc.poll()
        if code is None:
            return
        np.last_exit = code
        if code == EXIT_CONFIG:
            np.state = "failed"
            cause = self._fatal_cause(np.name) or "see its log"
            self._say(f"node {np.name} cannot start: {cause}; stopping the cluster")
            self.failed = f"node {np.name} cannot start: {cause}"
            self.stopping.set()
            return
        np.state = "restarting"
        np.restart_at = now + RESTART_DELAY
        self._say(f"node {np.name} exited with code {code}; restarting it")

    def _last_line(self, node: str) -> str | None:
        """The last line a node wrote to its log (its exception, when it died of one)."""
        try:
            lines = (self.run_dir / "logs" / f"{node}.log").read_text(errors="replace")
        except OSError:
            return None
        found = [ln.strip() for ln in lines.splitlines() if ln.strip()]
        return found[-1][:300] if found else None

    def _fatal_cause(self, node: str) -> str | None:
        """The cause a node logged before it exited EXIT_CONFIG (its last FATAL line)."""
        try:
            lines = (self.run_dir / "logs" / f"{node}.log").read_text(errors="replace")
        except OSError:
            return None
        found = [ln.split(FATAL, 1)[1].strip() for ln in lines.splitlines() if FATAL in ln]
        return found[-1] if found else None

    def _say(self, text: str) -> None:
        print(f"[hera up {time.strftime('%H:%M:%S')}] {text}", file=self.out, flush=True)

    def state(self) -> dict[str, Any]:
        """This launcher's state: its id, host, pid, run dir, nodes and routers."""
        return {
            "launcher": self.id,
            "host": socket.gethostname(),
            "launcher_pid": os.getpid(),
            "run_dir": str(self.run_dir),
            "nodes": {n: p.info() for n, p in self.nodes.items()},
            "routers": {n: p.info() for n, p in self.routers.items()},
        }

    def _on_query(self, query: Any) -> None:
        """``hera/<cluster>/launcher/<id>/<verb>``: ``status`` (its state) or ``down`` (stop
        the processes it runs), so tools reach launchers over the bus from any host."""
        with query:
            verb = str(query.key_expr).rsplit("/", 1)[-1]
            if verb == "down":
                reply = {"ok": True, "stopping": sorted(self.nodes) + sorted(self.routers)}
            elif verb == "status":
                reply = {"ok": True, **self.state()}
            else:
                reply = {"ok": False, "error": f"unknown launcher verb {verb!r}: status, down"}
            query.reply(Keys(self.spec.name).launcher(self.id, verb), json.dumps(reply))
        if verb == "down":  # after the reply: stopping ends with this launcher's routers,
            self.stopping.set()  # which may be the reply's way back to the tool

    def _write_launcher_state(self, force: bool = False) -> None:
        """Write ``launcher.json`` when a process changed (pid, state, restarts) or once a
        second, not at every turn of the loop."""
        key = [(p.proc.pid if p.proc else None, p.state, p.restarts) for p in self._procs()]
        now = time.monotonic()
        if not force and key == self._written[0] and now - self._written[1] < 1.0:
            return
        self._written = (key, now)
        tmp = self.run_dir / "launcher.json.tmp"
        tmp.write_text(json.dumps(self.state()))
        os.replace(tmp, self.run_dir / "launcher.json")

    # -- main loop ----------------------------------------------------------------------
    def run(self) -> int:
        """Run until stopped; return 0 after a clean stop, 1 when a node could not start."""
        (self.run_dir / "logs").mkdir(parents=True, exist_ok=True)
        (self.run_dir / "cluster.json").write_text(self.spec.to_json())
        self.registry_file.parent.mkdir(parents=True, exist_ok=True)
        self.registry_file.write_text(
            json.dumps(
                {
                    "cluster": self.spec.name,
                    "run_dir": str(self.run_dir),
                    "launcher_pid": os.getpid(),
                }
            )
        )
        handlers = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, lambda *_: self.stopping.set())
        client = None
        extras: list[Any] = []
        try:
            for np in self._procs():
                self._spawn(np)
            routers = f" and {len(self.routers)} routers" if self.routers else ""
            self._say(
                f"cluster {self.spec.name!r}: {len(self.nodes)} nodes{routers}, run dir "
                f"{self.run_dir}"
            )
            client = ClusterClient(self.spec, host=self.host(), retry_s=15.0)
            client.session.declare_queryable(
                Keys(self.spec.name).launcher(self.id, "*"), self._on_query, complete=True
            )
            extras = self._start_extras()
            started = time.monotonic()
            counting: float | None = None  # when the --duration clock started
            next_poll, next_view = started, started + self.interval
            while not self.stopping.is_set():
                for np in self._procs():
                    self._check(np)
                self._write_launcher_state()
                now = time.monotonic()
                if counting is None and now >= next_poll:
                    next_poll = now + UP_POLL_S
                    counting = self._all_up(client, now - started)
                if None not in (counting, self.duration) and now - counting >= self.duration:
                    break
                if now >= next_view:
                    next_view = now + self.interval
                    self._show(client, now - started)
                self.stopping.wait(0.05)
            self._say("stopping")
            return 1 if self.failed else 0
        finally:
            for extra in reversed(extras):
                try:
                    extra.close()
                except Exception as e:  # closing the view or the recorder must not stop the stop
                    self._say(f"closing {type(extra).__name__} failed: {e}")
            if client is not None:
                with contextlib.suppress(Exception):
                    client.close()
            self._stop_all()
            for sig, h in handlers.items():
                signal.signal(sig, h)
            with contextlib.suppress(OSError):
                self.registry_file.unlink()
            for f in self._logs.values():
                f.close()
            self._say(self._next_steps())

    def _start_extras(self) -> list[Any]:
        """The web view and the live MCAP recorder, when asked for (closed at the end)."""
        extras: list[Any] = []
        if self.mcap is not None:
            from hera.export.mcap import LiveRecorder

            extras.append(LiveRecorder(self.spec, self.mcap))
            self._say(f"recording every sample to {self.mcap}")
        if self.web is not None:
            from hera.console.server import ConsoleServer
            from hera.console.state import Console

            console = Console(
                self.spec,
                self.run_dir,
                launcher_state=lambda: {n: p.info() for n, p in self.nodes.items()},
            )
            extras.append(console)
            server = ConsoleServer(console, "127.0.0.1", self.web)
            url = server.start()
            extras.append(server)
            self._say(f"web view on {url}")
        return extras

    def _next_steps(self) -> str:
        """Where the run is and what to run next (printed when the cluster has stopped)."""

        def short(path: Path) -> str:
            rel = os.path.relpath(path)
            return str(path) if rel.startswith("..") else rel

        run = short(self.run_dir)
        if self.failed:
            return f"stopped: {self.failed}; logs in {run}/logs"
        text = f"stopped; the run is in {run}"
        if spec_models(self.spec):
            name = short(self.link) if self.link is not None else run
            text += f"; next: hera eval {name}"
        return text

    def _all_up(self, client: ClusterClient, waited: float) -> float | None:
        """When every node of this launcher is up (see :func:`not_up`), or :data:`UP_WAIT_S`
        has passed: the monotonic time the run's ``--duration`` counts from, said on the
        terminal; None while still waiting."""
        local = set(self.nodes)
        if local:
            try:
                missing = not_up(local, client.status(timeout=UP_POLL_S))
            except Exception:  # a query that fails now is asked again at the next poll
                missing = {n: "does not answer" for n in local}
            if missing and waited < UP_WAIT_S:
                return None
            if missing:
                why = "; ".join(f"{n} {w}" for n, w in sorted(missing.items()))
                self._say(f"not up after {UP_WAIT_S:.0f} s: {why}; the run counts from now")
            else:
                runs = "" if self.duration is None else f"; running {self.duration:g} s"
                self._say(f"all {len(local)} nodes up in {waited:.1f} s{runs}")
        return time.monotonic()

    def _show(self, client: ClusterClient, uptime: float) -> None:
        try:
            status = client.status(timeout=0.5)
        except Exception as e:  # the view must never take the launcher down
            status = {}
            self._say(f"status query failed: {e}")
        launcher = {n: p.info() for n, p in self.nodes.items()}
        panels = self._panels(client, status)
        tty = self.out.isatty()
        width, height = shutil.get_terminal_size((120, 40)) if tty else (120, 10_000)
        text = render_view(
            self.spec.name,
            status,
            launcher,
            uptime=uptime,
            run_dir=os.path.relpath(self.run_dir),
            panels=panels,
            width=width,
            height=height - 1,
            routers={n: p.info() for n, p in self.routers.items()},
        )
        self.out.write(("\x1b[H\x1b[2J" if tty else "") + text + "\n")
        self.out.flush()

    def _panels(self, client: ClusterClient, status: dict) -> list[Panel]:
        """The applications' panels, from what the nodes' stores hold of the measures shown
        (the logging node's samples first)."""
        if not self.shown or not status:
            return []
        node = self.spec.log_node if self.spec.log_node in status else sorted(status)[0]
        try:
            request = {"names": sorted(self.shown)}
            replies = client.query("*", "store", request, timeout=0.5)
            held = [s for r in replies.values() for s in r.get("samples", [])]
            samples = prefer_node(held, node)
            return estimates_panels(self.shown, samples, self.spec.world, self.index)
        except Exception as e:  # the view must never take the launcher down
            return [Panel(f"estimates: query failed ({e})", ("",))]

    def _stop_all(self) -> None:
        """Stop the nodes (SIGTERM, SIGKILL after the shutdown timeout), then the routers,
        which carry the others' traffic until then."""
        for group in (self.nodes.values(), self.routers.values()):
            procs = [p.proc for p in group if p.proc is not None]
            for p in procs:
                if p.poll() is None:
                    with contextlib.suppress(ProcessLookupError):
                        p.send_signal(signal.SIGCONT)
                        p.terminate()
            deadline = time.monotonic() + self.spec.shutdown_timeout + 3.0
            for p in procs:
                try:
                    p.wait(max(0.05, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        for np in self._procs():
            np.state = "stopped"
        with contextlib.suppress(OSError):
            self._write_launcher_state(force=True)
