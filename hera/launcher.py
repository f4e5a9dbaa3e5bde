"""``hera up``: run every node of a spec as its own OS process, and keep them running.

- Free loopback ports are picked when the spec says ``base_port = 0``; the resolved spec
  (ports, world epoch) is written to ``<run-dir>/cluster.json`` and handed to the nodes.
- A node that exits is started again after ``RESTART_DELAY``, with a start limit like
  systemd's (at most ``START_BURST`` starts within ``START_INTERVAL`` s, then it stays
  failed). Each node's output goes to ``<run-dir>/logs/<node>.log``.
- Nodes run in their own sessions (Ctrl-C reaches only the launcher) and watch the
  launcher's pid, so they stop even if the launcher is SIGKILLed.
- SIGINT, SIGTERM, ``hera down`` or the end of ``--duration`` stop everything: SIGTERM to
  each node, SIGKILL after the shutdown timeout, exit 0, nothing left behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from hera.client import ClusterClient, registry_dir
from hera.fusion import spec_models
from hera.panel import estimates_panels, render_panel
from hera.plugins import AppIndex
from hera.preflight import check_spec
from hera.spec import ClusterSpec, load_spec
from hera.statusview import render_status

START_BURST = 5
START_INTERVAL = 10.0
RESTART_DELAY = 0.05


def free_ports(host: str, n: int) -> list[int]:
    """``n`` distinct TCP ports that were free on ``host`` a moment ago."""
    socks, ports = [], []
    try:
        for _ in range(n):
            s = socket.socket()
            s.bind((host, 0))
            socks.append(s)
            ports.append(s.getsockname()[1])
    finally:
        for s in socks:
            s.close()
    return ports


NODE_MAIN = "import sys; del sys.path[0]; from hera.cli import main; sys.exit(main())"
"""What a node process runs: ``hera node ...`` from the *installed* package. ``python -m``
and ``-c`` put the current folder first on ``sys.path``, so from a source checkout they
would import the checkout's ``hera/`` instead; the node drops that entry first."""


def node_command(*args: str) -> list[str]:
    """The command line of a ``hera`` subcommand run in a child process."""
    return [sys.executable, "-c", NODE_MAIN, *args]


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

    def info(self) -> dict[str, Any]:
        return {
            "pid": self.proc.pid if self.proc else None,
            "state": self.state,
            "restarts": self.restarts,
            "last_exit": self.last_exit,
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
    ) -> None:
        spec = check_spec(load_spec(spec_path))
        if spec.base_port == 0 and not all(n.port for n in spec.nodes):
            spec = spec.with_ports(free_ports(spec.host, len(spec.nodes)))
        if "epoch" not in spec.world:
            spec = spec.with_world(epoch=time.time())
        self.spec: ClusterSpec = spec
        self.run_dir = Path(run_dir or Path("hera-run") / spec.name).resolve()
        self.duration = duration
        self.out = out or sys.stdout
        self.interval = interval
        self.nodes = {n.name: NodeProc(n.name) for n in spec.nodes}
        self.models = spec_models(spec)
        self.index = AppIndex()
        self.stopping = threading.Event()
        self._logs: dict[str, IO[bytes]] = {}
        self.registry_file = registry_dir() / f"{spec.name}.json"

    # -- process management -------------------------------------------------------------
    def _spawn(self, np: NodeProc) -> None:
        log = self._logs.get(np.name)
        if log is None:
            log = open(self.run_dir / "logs" / f"{np.name}.log", "ab")  # noqa: SIM115
            self._logs[np.name] = log
        cmd = node_command(
            "node",
            str(self.run_dir / "cluster.json"),
            "--node",
            np.name,
            "--run-dir",
            str(self.run_dir),
            "--parent-pid",
            str(os.getpid()),
        )
        np.proc = subprocess.Popen(
            cmd,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        np.starts.append(time.monotonic())
        np.state = "up"
        np.restart_at = None

    def _check(self, np: NodeProc) -> None:
        now = time.monotonic()
        if np.state == "restarting" and np.restart_at is not None and now >= np.restart_at:
            while np.starts and now - np.starts[0] > START_INTERVAL:
                np.starts.popleft()
            if len(np.starts) >= START_BURST:
                np.state = "failed"
                self._say(
                    f"node {np.name}: start limit hit ({START_BURST} starts within "
                    f"{START_INTERVAL:g} s); not restarting it"
                )
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
        np.state = "restarting"
        np.restart_at = now + RESTART_DELAY
        self._say(f"node {np.name} exited with code {code}; restarting it")

    def _say(self, text: str) -> None:
        print(f"[hera up {time.strftime('%H:%M:%S')}] {text}", file=self.out, flush=True)

    def _write_launcher_state(self) -> None:
        state = {
            "launcher_pid": os.getpid(),
            "nodes": {n: p.info() for n, p in self.nodes.items()},
        }
        tmp = self.run_dir / "launcher.json.tmp"
        tmp.write_text(json.dumps(state))
        os.replace(tmp, self.run_dir / "launcher.json")

    # -- main loop ----------------------------------------------------------------------
    def run(self) -> int:
        """Run until stopped; return 0 after a clean stop."""
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
        try:
            for np in self.nodes.values():
                self._spawn(np)
            self._say(
                f"cluster {self.spec.name!r}: {len(self.nodes)} nodes, run dir {self.run_dir}"
            )
            client = ClusterClient(self.spec)
            started = time.monotonic()
            next_view = started + self.interval
            while not self.stopping.is_set():
                for np in self.nodes.values():
                    self._check(np)
                self._write_launcher_state()
                now = time.monotonic()
                if self.duration is not None and now - started >= self.duration:
                    break
                if now >= next_view:
                    next_view = now + self.interval
                    self._show(client, now - started)
                self.stopping.wait(0.05)
            self._say("stopping")
            return 0
        finally:
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

    def _show(self, client: ClusterClient, uptime: float) -> None:
        try:
            status = client.status(timeout=0.5)
        except Exception as e:  # the view must never take the launcher down
            status = {}
            self._say(f"status query failed: {e}")
        launcher = {n: p.info() for n, p in self.nodes.items()}
        text = render_status(self.spec.name, status, launcher, uptime, str(self.run_dir))
        if self.models and status:
            text += "\n\n" + self._estimates(client, status)
        if self.out.isatty():
            self.out.write("\x1b[H\x1b[2J" + text + "\n")
        else:
            self.out.write(text + "\n")
        self.out.flush()

    def _estimates(self, client: ClusterClient, status: dict) -> str:
        node = self.spec.log_node if self.spec.log_node in status else sorted(status)[0]
        try:
            reply = client.query(node, "store", {}, timeout=0.5).get(node, {})
            samples = reply.get("samples", [])
            panels = estimates_panels(self.models, samples, self.spec.world, self.index)
        except Exception as e:  # the view must never take the launcher down
            return f"estimates: query failed ({e})"
        if not panels:
            return "estimates: none yet (models start when their inputs arrive)"
        return "\n\n".join(render_panel(p) for p in panels)

    def _stop_all(self) -> None:
        procs = [p.proc for p in self.nodes.values() if p.proc is not None]
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
        for np in self.nodes.values():
            np.state = "stopped"
        with contextlib.suppress(OSError):
            self._write_launcher_state()
