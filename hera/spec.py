"""Cluster specs: which nodes run which measures, read from TOML (or a resolved JSON).

A spec (see README "Spec format") has the tables ``[cluster]``, ``[supervisor]``,
``[world]``, ``[defaults]``, ``[logging]``, a list ``[[nodes]]`` and a list
``[[measures]]``. A measure is declared either inside a node (``[[nodes.measures]]``) or at
top level with ``on = ["n1", "n2"]`` or ``on = "*"`` (every node); ``count = N`` declares N
copies whose names replace ``{i}`` by 1..N. Errors name the table and field that is wrong.
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from hera.bus import DEFAULT_LEASE_MS, tcp_endpoint
from hera.keys import check_chunk
from hera.measure import RESTART_TYPES, MeasureSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class SpecError(ValueError):
    """A spec that cannot run; the message names the file, table and field."""


@dataclass(frozen=True)
class MeasureDecl:
    """One measure worker of one node, as declared."""

    use: str
    name: str
    period: float | None = None
    iterations: int | None = None
    sync: bool | None = None
    sync_group: str | None = None
    slot: float | None = None
    restart: str = "transient"
    hang_factor: float = 10.0
    hang_min: float = 1.0
    seed: int = 0
    args: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class NodeDecl:
    """One node process."""

    name: str
    port: int = 0
    measures: tuple[MeasureDecl, ...] = ()
    sync_hosts: tuple[str, ...] = ()


@dataclass(frozen=True)
class ClusterSpec:
    """A whole cluster; ``base_port == 0`` means "pick free ports at launch"."""

    name: str
    nodes: tuple[NodeDecl, ...]
    host: str = "127.0.0.1"
    base_port: int = 0
    lease_ms: int = DEFAULT_LEASE_MS
    sync_lease_ms: int = 300
    estimation_backend: str = "numpy"
    world: dict[str, Any] = field(default_factory=dict)
    intensity: int = 10
    intensity_period: float = 60.0
    strategy: str = "one_for_one"
    shutdown_timeout: float = 2.0
    log_node: str | None = None
    log_names: tuple[str, ...] = ()
    source: str = ""

    def node(self, name: str) -> NodeDecl:
        """The node called ``name``; SpecError listing the known names otherwise."""
        for n in self.nodes:
            if n.name == name:
                return n
        known = ", ".join(n.name for n in self.nodes)
        raise SpecError(f"{self.source}: no node {name!r} in the spec (nodes: {known})")

    def endpoint(self, name: str) -> str:
        """The TCP endpoint node ``name`` listens on."""
        n = self.node(name)
        if not n.port:
            raise SpecError(
                f"{self.source}: node {name!r} has no port; set [cluster] base_port "
                "or start the cluster with 'hera up', which picks free ports"
            )
        return tcp_endpoint(self.host, n.port)

    def sync_groups(self) -> dict[str, list[str]]:
        """Every sync group with the nodes that host its service."""
        groups: dict[str, list[str]] = {}
        for n in self.nodes:
            for g in n.sync_hosts:
                groups.setdefault(g, []).append(n.name)
        return groups

    def with_ports(self, ports: list[int]) -> ClusterSpec:
        """A copy where node i listens on ``ports[i]``."""
        nodes = tuple(replace(n, port=p) for n, p in zip(self.nodes, ports, strict=True))
        return replace(self, nodes=nodes)

    def with_world(self, **values: Any) -> ClusterSpec:
        """A copy with ``values`` added to the world table."""
        return replace(self, world={**self.world, **values})

    def to_json(self) -> str:
        """The resolved spec as JSON (what ``hera up`` hands its nodes)."""
        return json.dumps({"resolved_spec": asdict(self)}, indent=1)


def load_spec(path: str | Path) -> ClusterSpec:
    """Read a TOML spec or a resolved JSON spec written by :meth:`ClusterSpec.to_json`."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SpecError(f"cannot read spec {path}: {e.strerror}") from None
    if path.suffix == ".json":
        try:
            raw = json.loads(text)["resolved_spec"]
            nodes = tuple(
                NodeDecl(
                    n["name"],
                    n["port"],
                    tuple(MeasureDecl(**m) for m in n["measures"]),
                    tuple(n["sync_hosts"]),
                )
                for n in raw.pop("nodes")
            )
            raw["log_names"] = tuple(raw["log_names"])
            return ClusterSpec(nodes=nodes, **raw)
        except (KeyError, TypeError, ValueError) as e:
            raise SpecError(f"{path}: not a resolved spec written by hera up ({e})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: invalid TOML: {e}") from None
    return parse_spec(data, str(path))


_MEASURE_FIELDS = {
    "use",
    "name",
    "period",
    "iterations",
    "sync",
    "sync_group",
    "slot",
    "restart",
    "hang_factor",
    "hang_min",
    "seed",
    "args",
    "on",
    "count",
}


def parse_spec(data: dict[str, Any], source: str = "<spec>") -> ClusterSpec:
    """Validate a spec given as a dict (the parsed TOML) and build a :class:`ClusterSpec`."""

    def fail(where: str, msg: str) -> SpecError:
        return SpecError(f"{source}: {where}: {msg}")

    def table(name: str) -> dict[str, Any]:
        value = data.get(name, {})
        if not isinstance(value, dict):
            raise fail(f"[{name}]", "must be a table")
        return value

    unknown = (
        set(data)
        - {"cluster", "supervisor", "world", "defaults", "logging"}
        - {
            "nodes",
            "measures",
        }
    )
    if unknown:
        raise fail("top level", f"unknown table(s) {sorted(unknown)}")
    cluster = table("cluster")
    sup = table("supervisor")
    defaults = table("defaults")
    logging_t = table("logging")
    try:
        name = check_chunk(cluster.get("name", ""), "cluster name")
    except ValueError as e:
        raise fail("[cluster] name", str(e)) from None

    node_tables = data.get("nodes", [])
    if not isinstance(node_tables, list) or not node_tables:
        raise fail("[[nodes]]", "a spec needs at least one [[nodes]] entry")
    node_names: list[str] = []
    for i, n in enumerate(node_tables):
        if not isinstance(n, dict) or "name" not in n:
            raise fail(f"[[nodes]] #{i + 1}", "needs a name")
        try:
            node_names.append(check_chunk(n["name"], "node name"))
        except ValueError as e:
            raise fail(f"[[nodes]] #{i + 1}", str(e)) from None
    dupes = {n for n in node_names if node_names.count(n) > 1}
    if dupes:
        raise fail("[[nodes]]", f"duplicate node name(s) {sorted(dupes)}")

    per_node: dict[str, list[MeasureDecl]] = {n: [] for n in node_names}

    def decls(m: Any, where: str) -> list[MeasureDecl]:
        if not isinstance(m, dict):
            raise fail(where, "must be a table")
        bad = set(m) - _MEASURE_FIELDS
        if bad:
            raise fail(where, f"unknown field(s) {sorted(bad)}")
        merged = {**defaults, **m}
        if "use" not in merged:
            raise fail(where, "needs 'use' (a measure name or module:Class)")
        count = merged.pop("count", 1)
        merged.pop("on", None)
        if not isinstance(count, int) or count < 1:
            raise fail(where, f"count must be a positive integer, got {count!r}")
        iterations = merged.get("iterations")
        if iterations in (None, "forever", "infinity"):
            merged["iterations"] = None
        if merged.get("restart", "transient") not in RESTART_TYPES:
            raise fail(where, f"restart must be one of {RESTART_TYPES}")
        if not isinstance(merged.get("args", {}), dict):
            raise fail(where, "args must be a table")
        base_name = merged.get("name", str(merged["use"]).rsplit(":", 1)[-1].lower())
        out = []
        for i in range(1, count + 1):
            nm = base_name.replace("{i}", str(i)) if count > 1 or "{i}" in base_name else base_name
            try:
                decl = MeasureDecl(**{**merged, "name": nm})
                MeasureSpec(  # validates name, period, iterations, slot, restart, hang factor
                    name=nm,
                    period=1.0 if decl.period is None else decl.period,
                    iterations=decl.iterations,
                    slot=1.0 if decl.slot is None else decl.slot,
                    restart=decl.restart,
                    hang_factor=decl.hang_factor,
                )
                out.append(decl)
            except (TypeError, ValueError) as e:
                raise fail(where, str(e)) from None
        return out

    for n in node_tables:
        for j, m in enumerate(n.get("measures", [])):
            per_node[n["name"]].extend(decls(m, f"[[nodes.measures]] #{j + 1} of {n['name']}"))
    for j, m in enumerate(data.get("measures", [])):
        where = f"[[measures]] #{j + 1}"
        on = m.get("on", "*") if isinstance(m, dict) else None
        targets = node_names if on == "*" else on
        if not isinstance(targets, list) or not all(t in per_node for t in targets):
            raise fail(where, f"'on' must be '*' or a list of node names from {node_names}")
        for t in targets:
            per_node[t].extend(decls(m, where))
    nodes = []
    for n in node_tables:
        ms = per_node[n["name"]]
        names = [m.name for m in ms]
        dupes = {x for x in names if names.count(x) > 1}
        if dupes:
            raise fail(f"node {n['name']}", f"two measures publish as {sorted(dupes)}")
        hosts = n.get("sync_hosts", [])
        if not isinstance(hosts, list):
            raise fail(f"node {n['name']}", "sync_hosts must be a list of group names")
        nodes.append(NodeDecl(n["name"], int(n.get("port", 0)), tuple(ms), tuple(hosts)))

    base_port = cluster.get("base_port", 0)
    if not isinstance(base_port, int) or not (base_port == 0 or 1024 <= base_port < 65000):
        raise fail("[cluster] base_port", "must be 0 (pick free ports) or within [1024, 65000)")
    if base_port:
        nodes = [n if n.port else replace(n, port=base_port + i) for i, n in enumerate(nodes)]
    log_node = logging_t.get("node")
    if log_node is not None and log_node not in per_node:
        raise fail("[logging] node", f"{log_node!r} is not a node of the spec")
    backend = cluster.get("estimation_backend", "numpy")
    if backend not in ("numpy", "numba", "auto"):
        raise fail("[cluster] estimation_backend", "must be numpy, numba or auto")
    strategy = sup.get("strategy", "one_for_one")
    if strategy not in ("one_for_one", "one_for_all", "rest_for_one"):
        raise fail("[supervisor] strategy", "must be one_for_one, one_for_all or rest_for_one")
    try:
        return ClusterSpec(
            name=name,
            nodes=tuple(nodes),
            host=str(cluster.get("host", "127.0.0.1")),
            base_port=base_port,
            lease_ms=int(cluster.get("lease_ms", DEFAULT_LEASE_MS)),
            sync_lease_ms=int(cluster.get("sync_lease_ms", 300)),
            estimation_backend=backend,
            world=dict(table("world")),
            intensity=int(sup.get("intensity", 10)),
            intensity_period=float(sup.get("period", 60.0)),
            strategy=strategy,
            shutdown_timeout=float(sup.get("shutdown", 2.0)),
            log_node=log_node,
            log_names=tuple(logging_t.get("names", ())),
            source=source,
        )
    except (TypeError, ValueError) as e:
        raise fail("[cluster]/[supervisor]", str(e)) from None
