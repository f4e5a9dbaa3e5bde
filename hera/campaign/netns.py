"""Network faults with nftables: every node of a campaign in a network namespace of its own.

The other way to cut links (:mod:`hera.campaign.linkproxy` is the first): where the machine
allows it (root, ``ip`` and ``nft``, namespaces and nf_tables in the kernel), the campaign
makes one namespace per node, each with its own address on one Linux bridge, and the
launcher starts each node in its namespace (``ip netns exec``, see :func:`hera.bus.netns_of`).
The node listens on its address and dials the other nodes' addresses: their packets cross
the bridge as between hosts on a switch. The root namespace has an address on the bridge
too, so tools (the launcher, the campaign's recorder, ``hera status``) reach every node, and
no rule ever touches them.

Each namespace holds the table ``inet hera`` with, for every other node, an input chain
(packets from it) and an output chain (packets to it). A rule on the pair (a, b) replaces
the contents of those four chains (two in a's namespace, two in b's), so it is stateless:
the campaign and ``hera inject`` apply rules from the plan alone, and a rule set twice is
the same rule.

- ``blackhole``: every packet between the two dropped, both ways. Nothing is closed: TCP
  retransmits into the void, the Zenoh link leases run out as on a cut cable, and after
  the healing TCP's backed-off retransmission (or Zenoh's redial, once the lease closed the
  link) brings the link back.
- ``reset``: a TCP reset answers every segment between the two, both ways (connections
  die at once, new ones are refused); resets themselves pass.
- ``loss``: each packet from the other node dropped with that probability, on arrival (so
  each direction loses that share once); TCP retransmits what is lost.
- ``delay``/``jitter``: not with nftables (it drops or passes; delay needs ``tc netem``):
  refused with a sentence that names the link proxy.
- ``pass``: the chains emptied.

Every namespace, the bridge and their links are removed at :meth:`Namespaces.close`; what a
campaign that was itself SIGKILLed left behind, the next campaign in namespaces removes
(:func:`sweep`: the namespaces' names carry the id of the process that made them).
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import logging
import os
import random
import re
import shutil
import subprocess
from collections.abc import Iterable, Sequence
from typing import Any

from hera.client import pid_alive

log = logging.getLogger("hera.campaign.netns")

TABLE = "hera"
ROOT_OCTET = 254  # the root namespace's address on the bridge: 10.a.b.254
MAX_NODES = 250


def _run(args: Sequence[str], stdin: str | None = None) -> str:
    """Run a command; its stdout. RuntimeError naming the command and its stderr."""
    try:
        p = subprocess.run(
            list(args), input=stdin, capture_output=True, text=True, timeout=15, check=False
        )
    except (OSError, subprocess.TimeoutExpired) as e:
        raise RuntimeError(f"{' '.join(args)}: {e}") from None
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: {p.stderr.strip() or f'exit {p.returncode}'}")
    return p.stdout


def problem() -> str | None:
    """None when this machine can run nodes in namespaces with nftables rules, else why not
    (one sentence)."""
    if os.name != "posix" or os.geteuid() != 0:
        return "network namespaces need root"
    for tool in ("ip", "nft"):
        if shutil.which(tool) is None:
            return f"no '{tool}' command ({'iproute2' if tool == 'ip' else 'nftables'})"
    name = f"hera-probe-{os.getpid()}"
    try:
        _run(["ip", "netns", "add", name])
    except RuntimeError as e:
        return f"cannot make a network namespace: {e}"
    try:
        _run(["ip", "netns", "exec", name, "nft", "-f", "-"], f"add table inet {TABLE}\n")
    except RuntimeError as e:
        return f"nftables does not work in a network namespace: {e}"
    finally:
        with contextlib.suppress(RuntimeError):
            _run(["ip", "netns", "del", name])
    return None


_MINE = re.compile(r"^hera-c(\d+)-([0-9a-f]{6})-(\d+)$")  # maker's pid, tag, node index


def _bridge(tag: str) -> str:
    return f"hb{tag}"


def _outer(tag: str, index: int | str) -> str:
    """The root namespace's end of node ``index``'s veth pair (the plan's ``veth`` + index)."""
    return f"hv{tag}{index}"


def sweep() -> list[str]:
    """Remove the namespaces (and their bridges) that campaigns no longer running left
    behind (a campaign SIGKILLed before it could clean up): those whose name carries the
    id of a process that is gone. Returns the namespaces removed."""
    try:
        listed = _run(["ip", "netns", "list"])
    except RuntimeError:
        return []
    gone, bridges = [], set()
    for line in listed.splitlines():
        name = line.split()[0] if line.split() else ""
        m = _MINE.match(name)
        if m and not pid_alive(int(m.group(1))):
            with contextlib.suppress(RuntimeError):  # the pair first, as in close()
                _run(["ip", "link", "del", _outer(m.group(2), m.group(3))])
            with contextlib.suppress(RuntimeError):
                _run(["ip", "netns", "del", name])
                gone.append(name)
            bridges.add(_bridge(m.group(2)))
    for br in sorted(bridges):
        with contextlib.suppress(RuntimeError):
            _run(["ip", "link", "del", br])
    return gone


def _free_subnet(rng: random.Random) -> str:
    """A 10.a.b.0/24 that no address or route of this host overlaps."""
    taken = []
    for line in _run(["ip", "-o", "-4", "addr", "show"]).splitlines():
        parts = line.split()
        if "inet" in parts:
            taken.append(ipaddress.ip_network(parts[parts.index("inet") + 1], strict=False))
    for line in _run(["ip", "-4", "route", "show"]).splitlines():
        first = line.split()[0]
        if first[0].isdigit():
            taken.append(ipaddress.ip_network(first, strict=False))
    for _ in range(200):
        net = ipaddress.ip_network(f"10.{rng.randrange(200, 250)}.{rng.randrange(256)}.0/24")
        if not any(net.overlaps(t) for t in taken):
            return str(net.network_address).rsplit(".", 1)[0]
    raise RuntimeError("no free 10.x.y.0/24 subnet for the campaign's namespaces")


def _chain(kind: str, peer: int) -> str:
    return f"{kind}_{peer}"


def rule_statements(mode: str, loss: float) -> tuple[list[str], list[str]]:
    """The nft statements of a link rule: (for the input chain, for the output chain)."""
    if mode == "blackhole":
        return ["counter drop"], ["counter drop"]
    if mode == "reset":
        reset = [  # a reset passes (the one the rule made for the other side among them)
            "tcp flags & rst == rst accept",
            "meta l4proto tcp counter reject with tcp reset",
            "counter drop",
        ]
        return reset, list(reset)
    if mode != "pass":
        raise ValueError(f"link mode must be pass, blackhole or reset, got {mode!r}")
    if loss > 0.0:
        share = round(loss * 1_000_000)
        return [f"numgen random mod 1000000 < {share} counter drop"], []
    return [], []


class Namespaces:
    """One network namespace per node on one bridge, and the nftables rules on their links.

    Made from a plan (:meth:`new_plan`'s output) by the campaign (:meth:`create`), or from the
    plan file by ``hera inject`` to set rules on a running campaign (rules need nothing
    else)."""

    def __init__(self, plan: dict[str, Any]) -> None:
        self.plan = plan
        self.nodes: dict[str, dict[str, Any]] = plan["nodes"]
        self.created: list[str] = []
        self.bridge_made = False

    # -- the plan ----------------------------------------------------------------------
    @staticmethod
    def new_plan(names: Sequence[str], seed: int | None = None) -> dict[str, Any]:
        """Namespace, address and index of every node; the bridge and the root's address, on
        a /24 no address or route of this host overlaps (drawn at random unless ``seed`` is
        given). Interface names are short (at most 15 characters); the namespaces' names
        carry this process's id (see :func:`sweep`) and a random tag that the bridge's name
        carries too."""
        if len(names) > MAX_NODES:
            raise ValueError(f"at most {MAX_NODES} nodes in namespaces, the spec has {len(names)}")
        rng = random.Random(seed) if seed is not None else random.SystemRandom()
        tag = f"{rng.randrange(16**6):06x}"
        net = _free_subnet(rng)
        nodes = {
            name: {"netns": f"hera-c{os.getpid()}-{tag}-{i}", "addr": f"{net}.{i}", "index": i}
            for i, name in enumerate(names, start=1)
        }
        return {
            "backend": "netns",
            "bridge": _bridge(tag),
            "veth": _outer(tag, ""),
            "root_addr": f"{net}.{ROOT_OCTET}",
            "nodes": nodes,
        }

    def addr(self, node: str) -> str:
        return self.nodes[node]["addr"]

    def _link(self, n: dict[str, Any]) -> str:
        """The root namespace's end of node ``n``'s veth pair."""
        return f"{self.plan['veth']}{n['index']}"

    # -- making and removing -------------------------------------------------------------
    def create(self) -> None:
        """Make the bridge, every namespace with its link and address, and the empty rule
        chains, after removing what dead campaigns left (:func:`sweep`). Everything made is
        removed if a step fails."""
        swept = sweep()
        if swept:
            log.warning("removed %d network namespaces left by a campaign that died", len(swept))
        p = self.plan
        try:
            _run(["ip", "link", "add", p["bridge"], "type", "bridge"])
            self.bridge_made = True
            _run(["ip", "addr", "add", f"{p['root_addr']}/24", "dev", p["bridge"]])
            _run(["ip", "link", "set", p["bridge"], "up"])
            for name, n in self.nodes.items():
                ns, outer = n["netns"], self._link(n)
                _run(["ip", "netns", "add", ns])
                self.created.append(ns)
                _run(["ip", "-n", ns, "link", "set", "lo", "up"])
                veth = ["type", "veth", "peer", "name", "eth0", "netns", ns]
                _run(["ip", "link", "add", outer, *veth])
                _run(["ip", "link", "set", outer, "master", p["bridge"]])
                _run(["ip", "link", "set", outer, "up"])
                _run(["ip", "-n", ns, "addr", "add", f"{n['addr']}/24", "dev", "eth0"])
                _run(["ip", "-n", ns, "link", "set", "eth0", "up"])
                self._nft(ns, self._table(name))
        except BaseException:
            self.close()
            raise

    def _table(self, node: str) -> str:
        """The ruleset of ``node``'s namespace: a jump per other node, chains empty."""
        lines = [
            f"add table inet {TABLE}",
            f"add chain inet {TABLE} input {{ type filter hook input priority 0; }}",
            f"add chain inet {TABLE} output {{ type filter hook output priority 0; }}",
        ]
        for other, o in self.nodes.items():
            if other == node:
                continue
            i = o["index"]
            lines += [
                f"add chain inet {TABLE} {_chain('in', i)}",
                f"add chain inet {TABLE} {_chain('out', i)}",
                f"add rule inet {TABLE} input ip saddr {o['addr']} jump {_chain('in', i)}",
                f"add rule inet {TABLE} output ip daddr {o['addr']} jump {_chain('out', i)}",
            ]
        return "\n".join(lines) + "\n"

    def close(self) -> None:
        """Remove every link, namespace and the bridge made here; when it returns, their
        names are free again. The processes in the namespaces must be gone first.

        Each veth pair is deleted explicitly, before its namespace: ``ip netns del`` only
        unmounts the namespace, and the kernel tears down its devices (and with them the
        outer end of the pair) later, in its cleanup work, so a plan made again at once
        with the same names found ``File exists``."""
        for n in self.nodes.values():
            if n["netns"] in self.created:
                with contextlib.suppress(RuntimeError):
                    _run(["ip", "link", "del", self._link(n)])
        for ns in self.created:
            with contextlib.suppress(RuntimeError):
                _run(["ip", "netns", "del", ns])
        self.created = []
        if self.bridge_made:
            with contextlib.suppress(RuntimeError):
                _run(["ip", "link", "del", self.plan["bridge"]])
            self.bridge_made = False

    # -- rules -------------------------------------------------------------------------
    @staticmethod
    def _nft(ns: str, script: str) -> str:
        return _run(["ip", "netns", "exec", ns, "nft", "-f", "-"], script)

    def _pairs(self, pairs: Any) -> list[tuple[str, str]]:
        if not isinstance(pairs, list) or not all(
            isinstance(p, (list, tuple)) and len(p) == 2 for p in pairs
        ):
            raise ValueError("'pairs' must be a list of [node, node] pairs")
        out = []
        for a, b in pairs:
            for x in (a, b):
                if x not in self.nodes:
                    known = ", ".join(sorted(self.nodes))
                    raise ValueError(f"no node {x!r} in the namespaces; nodes: {known}")
            if a == b:
                raise ValueError(f"no link between {a} and itself")
            out.append((str(a), str(b)))
        return out

    def _all_pairs(self) -> list[tuple[str, str]]:
        names = list(self.nodes)
        return [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]

    def set_rule(self, pairs: Iterable[tuple[str, str]], mode: str, loss: float = 0.0) -> None:
        """Replace the rule of every pair (both directions, one nft transaction per
        namespace)."""
        into, out = rule_statements(mode, loss)
        scripts: dict[str, list[str]] = {}
        for a, b in pairs:
            for me, peer in ((a, b), (b, a)):
                i = self.nodes[peer]["index"]
                lines = scripts.setdefault(self.nodes[me]["netns"], [])
                for kind, stmts in (("in", into), ("out", out)):
                    lines.append(f"flush chain inet {TABLE} {_chain(kind, i)}")
                    lines += [f"add rule inet {TABLE} {_chain(kind, i)} {s}" for s in stmts]
        for ns, lines in scripts.items():
            self._nft(ns, "\n".join(lines) + "\n")

    def command(self, req: dict[str, Any]) -> dict[str, Any]:
        """The link proxy's control requests (:meth:`hera.campaign.linkproxy.LinkProxy.command`):
        ``{"op": "set", "pairs", "mode", "loss"}``, ``{"op": "clear", "pairs"?}``,
        ``{"op": "status"}``. ValueError naming what is wrong (a delay among them)."""
        op = req.get("op")
        if op == "status":
            return {"pairs": self.status()}
        if op not in ("set", "clear"):
            raise ValueError(f"link op must be set, clear or status, got {op!r}")
        raw = req.get("pairs")
        pairs = self._all_pairs() if raw is None and op == "clear" else self._pairs(raw)
        if op == "clear":
            mode, loss = "pass", 0.0
        else:
            mode = str(req.get("mode", "pass"))
            loss = float(req.get("loss", 0.0))
            if not 0.0 <= loss <= 1.0:
                raise ValueError(f"loss must be a share within [0, 1], got {loss:g}")
            if float(req.get("delay_ms", 0.0)) or float(req.get("jitter_ms", 0.0)):
                raise ValueError(
                    "delay and jitter need the link proxy (nftables drops or passes packets, "
                    "it cannot hold them): run the campaign with --links proxy"
                )
        self.set_rule(pairs, mode, loss)
        return {"pairs": [list(p) for p in pairs], "rule": {"mode": mode, "loss": loss}}

    def status(self) -> list[dict[str, Any]]:
        """Per pair: the packets its current rules (both sides') dropped or answered with a
        reset so far, and how many rules it has (0: it passes)."""
        dropped: dict[tuple[str, str], int] = {}
        rules: dict[tuple[str, str], int] = {}
        index = {n["index"]: name for name, n in self.nodes.items()}
        for me, n in self.nodes.items():
            listed = _run(
                ["ip", "netns", "exec", n["netns"], "nft", "-j", "list", "table", "inet", TABLE]
            )
            listing = json.loads(listed)
            for item in listing.get("nftables", []):
                rule = item.get("rule")
                if not rule or rule.get("chain") in ("input", "output"):
                    continue
                peer = index[int(rule["chain"].split("_", 1)[1])]
                key = tuple(sorted((me, peer)))
                for expr in rule.get("expr", []):
                    if "counter" in expr:
                        dropped[key] = dropped.get(key, 0) + int(expr["counter"]["packets"])
                rules[key] = rules.get(key, 0) + 1
        return [
            {"pair": list(k), "dropped_packets": dropped.get(k, 0), "rules": rules.get(k, 0)}
            for k in self._all_pairs_sorted()
        ]

    def _all_pairs_sorted(self) -> list[tuple[str, str]]:
        return sorted(tuple(sorted(p)) for p in self._all_pairs())
