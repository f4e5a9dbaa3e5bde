"""Who a fault hits: node names, and roles resolved on the running cluster.

A target is a node's name, or a role:

- ``leader:<group>``: the current leader of sync group ``<group>`` (asked of its hosts);
- ``follower:<group>``: a host of the group that is not its leader;
- ``host:<group>``: any host of the group;
- ``random``: any node;
- ``others`` (partition sides only): every node no other side names.

Random choices use the fault's own generator (:func:`hera.campaign.plan.fault_rng`).
"""

from __future__ import annotations

import json
import random
from collections import Counter
from pathlib import Path
from typing import Any

from hera.client import ClusterClient
from hera.spec import ClusterSpec

ROLES = ("leader", "follower", "host")


class TargetError(ValueError):
    """A target that names nothing, or a role nobody holds right now."""


class ClusterView:
    """What the campaign asks of the running cluster: statuses, leaders, process ids."""

    def __init__(self, client: ClusterClient, run_dir: Path) -> None:
        self.client = client
        self.spec: ClusterSpec = client.spec
        self.run_dir = Path(run_dir)

    def launcher(self) -> dict[str, Any]:
        """The launcher's view of its nodes (``launcher.json``: pid, state, restarts)."""
        try:
            return json.loads((self.run_dir / "launcher.json").read_text())["nodes"]
        except (OSError, ValueError, KeyError):
            return {}

    def pid(self, node: str) -> int | None:
        return self.launcher().get(node, {}).get("pid")

    def status(self, node: str = "*", timeout: float = 1.0) -> dict[str, dict[str, Any]]:
        return self.client.query(node, "status", timeout=timeout)

    def leader(self, group: str) -> str:
        """The node leading ``group`` now: the host that says it leads (the highest epoch
        if several do), else what most hosts believe; TargetError if there is none."""
        hosts = self.spec.sync_groups().get(group)
        if not hosts:
            raise TargetError(f"no sync group {group!r} in the spec")
        views = []
        for node, st in self.status().items():
            g = (st.get("sync") or {}).get("groups", {}).get(group)
            if g is not None:
                views.append((node, g))
        leading = [(g.get("epoch", 0), node) for node, g in views if g.get("role") == "leader"]
        if leading:
            return max(leading)[1]
        believed = Counter(g.get("leader") for _, g in views if g.get("leader"))
        if believed:
            return believed.most_common(1)[0][0]
        raise TargetError(f"sync group {group!r} has no leader right now")


def resolve(target: str, view: ClusterView, rng: random.Random) -> str:
    """The node ``target`` names now (see the module docstring)."""
    spec = view.spec
    names = [n.name for n in spec.nodes]
    if target in names:
        return target
    if target == "random":
        return rng.choice(names)
    role, _, group = target.partition(":")
    if role not in ROLES or not group:
        raise TargetError(
            f"target {target!r} is neither a node ({', '.join(names)}) nor a role "
            "(leader:<group>, follower:<group>, host:<group>, random)"
        )
    hosts = spec.sync_groups().get(group)
    if not hosts:
        raise TargetError(f"target {target!r}: no sync group {group!r} in the spec")
    if role == "host":
        return rng.choice(hosts)
    leader = view.leader(group)
    if role == "leader":
        return leader
    followers = [h for h in hosts if h != leader]
    if not followers:
        raise TargetError(f"target {target!r}: the group has no host but its leader")
    return rng.choice(followers)


def resolve_groups(
    groups: list[list[str]], view: ClusterView, rng: random.Random
) -> list[list[str]]:
    """The sides of a partition as node names (``others``: every node not named)."""
    names = [n.name for n in view.spec.nodes]
    out: list[list[str]] = []
    rest = None
    for side in groups:
        nodes: list[str] = []
        for t in side:
            if t == "others":
                rest = len(out)
            else:
                nodes.append(resolve(t, view, rng))
        out.append(nodes)
    if rest is not None:
        named = {n for side in out for n in side}
        out[rest] += [n for n in names if n not in named]
    for side in out:
        if not side:
            raise TargetError(f"partition {groups}: a side has no node")
    return [sorted(set(side)) for side in out]
