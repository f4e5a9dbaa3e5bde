"""Test harness: real clusters started with ``hera up`` on loopback, always cleaned up.

Imported by tests as ``harness`` (pytest puts tests/support on sys.path).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

SUPPORT = Path(__file__).parent


def wait_for(cond: Callable[[], object], timeout: float, what: str, step: float = 0.02):
    """Poll ``cond`` until it returns something truthy; fail naming ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(step)


def csv_rows(path: Path) -> list[list[str]]:
    """The complete rows of a CSV log a node is still writing (the values of each, split at
    commas; a last line not ended yet is left out; none while the file is not there)."""
    text = path.read_text() if path.exists() else ""
    return [line.split(",") for line in text[: text.rfind("\n") + 1].splitlines()]


def cluster_env(tmp_path: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SUPPORT), env.get("PYTHONPATH")]))
    env["HERA_REGISTRY"] = str(tmp_path / "registry")
    return env


def run_hera(
    tmp_path: Path,
    *args: str,
    cwd: Path | None = None,
    env: dict[str, str] | None = None,
    timeout: float = 60,
) -> subprocess.CompletedProcess:
    """``python -m hera ARGS`` with this test's registry (:func:`cluster_env`, plus ``env``),
    run in ``cwd`` (default ``tmp_path``, so a run directory made by mistake lands there);
    its output captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "hera", *args],
        env={**cluster_env(tmp_path), **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd or tmp_path,
    )


def _descendants(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-eo", "pid=,ppid=,args="], capture_output=True, text=True)
    return [
        int(line.split()[0]) for line in out.stdout.splitlines() if f"--parent-pid {pid}" in line
    ]


class Cluster:
    """A ``hera up`` launcher process and the client to talk to its nodes."""

    def __init__(
        self,
        spec: Path,
        run_dir: Path,
        env: dict[str, str],
        duration: float | None,
        overwrite: bool = False,
        extra: tuple[str, ...] = (),
    ):
        self.run_dir = run_dir
        cmd = [
            sys.executable,
            "-m",
            "hera",
            "up",
            str(spec),
            "--run-dir",
            str(run_dir),
            "--interval",
            "0.5",
        ]
        if duration is not None:
            cmd += ["--duration", str(duration)]
        if overwrite:
            cmd.append("--overwrite")
        cmd += list(extra)
        self.log = run_dir.parent / f"{run_dir.name}-launcher.log"
        self.out = open(run_dir.parent / f"{run_dir.name}-launcher.log", "w")  # noqa: SIM115
        self.proc = subprocess.Popen(cmd, env=env, stdout=self.out, stderr=subprocess.STDOUT)
        self.client = None
        self.stopped = False

    def connect(self, timeout: float = 20.0) -> None:
        from hera.client import ClusterClient

        wait_for(self._mine, timeout, "this launcher's launcher.json")
        self.client = ClusterClient.from_run_dir(self.run_dir)
        names = {node.name for node in self.client.spec.nodes}
        answered: set[str] = set()

        def all_answered() -> bool:  # node by node: one query seldom gets all on a busy machine
            answered.update(self.client.status(0.5))
            return answered >= names

        try:
            wait_for(all_answered, timeout, f"{len(names)} nodes answering")
        except AssertionError as e:
            raise AssertionError(f"{e}; {self.diagnosis(names - answered)}") from None

    def diagnosis(self, silent: set[str]) -> str:
        """What the launcher and the ``silent`` nodes' logs say, for a failure message: a
        cluster that did not come up in CI leaves nothing else behind."""
        parts = [f"never answered: {sorted(silent)}"]
        try:
            parts.append(f"launcher.json: {json.dumps(self.launcher_state())}")
        except (OSError, ValueError, KeyError) as e:
            parts.append(f"launcher.json unreadable ({e})")
        tails = [("launcher", self.log)] + [
            (n, self.run_dir / "logs" / f"{n}.log") for n in sorted(silent)
        ]
        for what, path in tails:
            try:
                lines = path.read_text(errors="replace").splitlines()[-12:]
            except OSError as e:
                lines = [f"unreadable ({e})"]
            parts.append(f"--- {what} log, last lines:\n" + "\n".join(lines))
        return "\n".join(parts)

    def _mine(self) -> bool:
        """Whether launcher.json is this launcher's (a previous run may have left one)."""
        try:
            state = json.loads((self.run_dir / "launcher.json").read_text())
        except (OSError, ValueError):
            return False
        return state.get("launcher_pid") == self.proc.pid

    def operator_bus(self, connect: tuple[str, ...], **kw):
        """A bus configuration joining this cluster as the operator (its credentials and
        access control), for tests that open their own session."""
        from hera.bus import BusConfig
        from hera.security.access import OPERATOR
        from hera.security.credentials import secured

        return secured(self.client.spec, OPERATOR, BusConfig(connect=connect, **kw))

    def reached(self, session, nodes) -> None:
        """Wait until every node of ``nodes`` answers a status query on ``session``: its
        reply comes after its declarations on the same link (declared in one batch when
        the link opened), so a put on ``session`` reaches its subscribers from then on."""
        prefix = f"hera/{self.client.spec.name}/ctl"

        def answered(n):
            return any(r.ok is not None for r in session.get(f"{prefix}/{n}/status", timeout=0.5))

        for n in nodes:
            wait_for(lambda n=n: answered(n), 10, f"{n} to answer the new session")

    def launcher_state(self) -> dict:
        return json.loads((self.run_dir / "launcher.json").read_text())["nodes"]

    def pid(self, node: str) -> int:
        return self.status(node)["pid"]

    def restarted(self, node: str, old_pid: int) -> bool:
        """Whether ``node`` answers with another pid than ``old_pid``, in one query (a node
        going down may answer one query and not the next)."""
        return self.client.status(0.5).get(node, {"pid": old_pid})["pid"] != old_pid

    def status(self, node: str) -> dict:
        return self.client.query(node, "status")[node]

    def control(self, node: str, verb: str, request: dict) -> dict:
        return self.client.query(node, verb, request)[node]

    def stop(self) -> None:
        """Stop the launcher; fail if any of its nodes is still alive. Idempotent."""
        if self.stopped:
            return
        self.stopped = True
        node_pids = _descendants(self.proc.pid)
        if self.client is not None:
            self.client.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        leftovers = []
        for pid in node_pids:
            try:
                os.kill(pid, signal.SIGCONT)
                os.kill(pid, signal.SIGKILL)
                leftovers.append(pid)
            except ProcessLookupError:
                pass
        self.out.close()
        assert not leftovers, f"node processes left behind: {leftovers}"
