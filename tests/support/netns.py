"""Test hosts as Linux network namespaces joined by veth pairs and bridges (root only).

``Hosts`` makes ``h1 .. hN``, each a namespace with its own loopback and one address per
network it is on (10.<a>.<n>.<i>/24 on network n), joined by one Linux bridge per network
in the root namespace. A host on two networks is a gateway between them only for what
listens on both of its addresses (no IP forwarding). :meth:`Hosts.run` starts a command in
a host; :meth:`Hosts.cut` takes a host's link down (as a pulled cable: no FIN, no RST, the
peers notice only when their lease runs out) and :meth:`Hosts.heal` brings it back. Every
namespace, bridge and process is removed at :meth:`Hosts.close`, whatever happened.

Where namespaces cannot be made (not root, no ``ip``), :func:`available` says why, and the
tests are reported as not run, never as passed.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

NODE_MAIN = "import sys; del sys.path[0]; from hera.cli import main; sys.exit(main())"


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=10)


def available() -> str | None:
    """None when network namespaces can be made here, else why not."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "no 'ip' command (iproute2)"
    name = f"hera-probe-{os.getpid()}"
    try:
        _ip("netns", "add", name)
    except (subprocess.CalledProcessError, OSError) as e:
        return f"cannot make a network namespace: {getattr(e, 'stderr', e)}"
    _ip("netns", "del", name)
    return None


class Hosts:
    """Namespaced hosts on one or more networks (see the module docstring)."""

    def __init__(self, networks: Sequence[Sequence[int]], tag: str | None = None) -> None:
        """``networks[k]`` lists the hosts (1-based) on network k."""
        rng = random.SystemRandom()  # not the module's generator, which a test may seed
        self.tag = tag or f"{os.getpid() % 10000}{rng.randrange(100):02d}"
        self.octet = 100 + rng.randrange(100)
        self.hosts = sorted({h for net in networks for h in net})
        self.networks = [list(net) for net in networks]
        self.procs: list[subprocess.Popen] = []
        self.bridges: list[str] = []
        self.links: dict[int, list[str]] = {h: [] for h in self.hosts}
        try:
            for h in self.hosts:
                _ip("netns", "add", self.ns(h))
                _ip("-n", self.ns(h), "link", "set", "lo", "up")
            for k, net in enumerate(self.networks):
                br = f"hb{self.tag}{k}"[:15]
                _ip("link", "add", br, "type", "bridge")
                _ip("link", "set", br, "up")
                self.bridges.append(br)
                for h in net:
                    inner, outer = f"e{k}", f"v{self.tag}{k}{h}"[:15]
                    _ip("link", "add", outer, "type", "veth", "peer", "name", inner)
                    self.links[h].append(outer)
                    _ip("link", "set", inner, "netns", self.ns(h))
                    _ip("link", "set", outer, "master", br)
                    _ip("link", "set", outer, "up")
                    _ip("-n", self.ns(h), "addr", "add", f"{self.addr(h, k)}/24", "dev", inner)
                    _ip("-n", self.ns(h), "link", "set", inner, "up")
        except BaseException:
            self.close()
            raise

    def ns(self, host: int) -> str:
        return f"hera{self.tag}h{host}"

    def addr(self, host: int, network: int = 0) -> str:
        """The address of ``host`` on ``network``."""
        return f"10.{self.octet}.{network}.{host}"

    def run(
        self, host: int, args: Sequence[str], log: Path, env: dict[str, str]
    ) -> subprocess.Popen:
        """Start ``hera ARGS`` in ``host``; its output goes to ``log``."""
        out = open(log, "w")  # noqa: SIM115 - kept by the child
        proc = subprocess.Popen(
            ["ip", "netns", "exec", self.ns(host), sys.executable, "-c", NODE_MAIN, *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        )
        out.close()
        self.procs.append(proc)
        return proc

    def hera(self, host: int, args: Sequence[str], env: dict[str, str], timeout: float = 60):
        """Run ``hera ARGS`` in ``host`` to completion."""
        return subprocess.run(
            ["ip", "netns", "exec", self.ns(host), sys.executable, "-c", NODE_MAIN, *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=timeout,
        )

    def cut(self, host: int) -> None:
        """Take every link of ``host`` down, as a pulled cable."""
        for link in self.links[host]:
            _ip("link", "set", link, "down")

    def heal(self, host: int) -> None:
        for link in self.links[host]:
            _ip("link", "set", link, "up")

    def close(self) -> None:
        """Stop every process started here (TERM, then KILL) and remove the hosts."""
        for p in self.procs:
            if p.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)
        # the pairs first: after 'netns del' the kernel removes a namespace's devices (and
        # the outer ends) only later, and a next Hosts with the same tag would collide
        for link in (li for h in self.hosts for li in self.links[h]):
            subprocess.run(["ip", "link", "del", link], capture_output=True, timeout=10)
        for h in self.hosts:
            subprocess.run(["ip", "netns", "del", self.ns(h)], capture_output=True, timeout=10)
        for br in self.bridges:
            subprocess.run(["ip", "link", "del", br], capture_output=True, timeout=10)
