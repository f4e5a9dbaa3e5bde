"""Cluster specs: which nodes run which measures, read from TOML (or a resolved JSON).

A spec (README "Spec format") has the tables ``[cluster]``, ``[supervisor]``, ``[logging]``,
``[world]``, ``[defaults]``, a list ``[[nodes]]`` and a list ``[[measures]]``. A measure is
declared inside a node (``[[nodes.measures]]``) or at top level with ``on = ["n1", "n2"]``
or ``on = "*"`` (every node); ``count = N`` declares N copies whose names replace ``{i}`` by
1..N.

Every setting is declared once, with its kind, default and meaning: the cluster-wide ones
on :class:`ClusterSpec`, a node's on :class:`NodeSpec`, a measure's on
:class:`hera.measure.MeasureSpec`. Parsing, defaults, the README's reference tables
(:func:`reference`) and the error messages all come from those declarations. Unknown keys
are refused at every level; every problem of a spec is reported at once, one sentence
each, naming the file, the table and the key (:class:`SpecError`).
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from hera.bus import DEFAULT_LEASE_MS, tcp_endpoint
from hera.keys import check_chunk
from hera.measure import MEASURE_TABLE, MeasureSpec, default_name
from hera.schema import (
    ANY,
    REQUIRED,
    STR,
    Kind,
    Setting,
    Table,
    choice,
    either,
    list_of,
    number,
    setting,
    table_of,
    text,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class SpecError(ValueError):
    """A spec that cannot run; one line per problem, each naming file, table and key."""

    def __init__(self, problems: list[str] | str) -> None:
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


def _chunk(what: str):
    def check(value: str) -> None:
        try:
            check_chunk(value, what)
        except ValueError:
            raise ValueError(
                "must use only letters, digits, '_', '.' and '-' (no '/', '*', '$')"
            ) from None

    return check


NAME = text(_chunk("name"), "a name")


def _port_base(v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not (v == 0 or 1024 <= v < 65000):
        raise ValueError("must be 0 (pick free ports) or an integer within [1024, 65000)")
    return v


PORT_BASE = Kind("0 or a port in [1024, 65000)", _port_base)


@dataclass(frozen=True)
class NodeSpec:
    """One node process: a ``[[nodes]]`` entry."""

    name: str = setting(REQUIRED, NAME, "node name, the `<node>` of its keys")
    port: int = setting(
        0,
        number(0, 65535, integer=True),
        "TCP port it listens on (0: `base_port` + its index, or one `hera up` picks)",
    )
    sync_hosts: tuple[str, ...] = setting(
        (), list_of(NAME, "a list of names"), "sync groups this node hosts the leader election of"
    )
    measures: tuple[MeasureSpec, ...] = setting(
        (), ANY, "its measures, each a `[[nodes.measures]]` table (see the measure keys)"
    )


@dataclass(frozen=True)
class ClusterSpec:
    """A whole cluster; ``base_port == 0`` means "pick free ports at launch"."""

    nodes: tuple[NodeSpec, ...]
    name: str = setting(
        REQUIRED, NAME, "cluster name: the key prefix `hera/<name>/`", table="cluster"
    )
    host: str = setting("127.0.0.1", STR, "address every node listens on", table="cluster")
    base_port: int = setting(
        0,
        PORT_BASE,
        "0: `hera up` picks free loopback ports; else node i listens on base + i",
        table="cluster",
    )
    lease_ms: int = setting(
        DEFAULT_LEASE_MS,
        number(100, 600_000, integer=True),
        "Zenoh link lease: a hung or cut-off node is noticed in about 0.85 x lease",
        table="cluster",
    )
    sync_lease_ms: int = setting(
        300,
        number(20, 60_000, integer=True),
        "sync leader lease; the longest sync slot is half of it",
        table="cluster",
    )
    estimation_backend: str = setting(
        "numpy",
        choice("numpy", "numba", "auto"),
        "`numba` compiles the estimation kernels at node start; `auto` uses numba if installed",
        table="cluster",
    )
    strategy: str = setting(
        "one_for_one",
        choice("one_for_one", "one_for_all", "rest_for_one"),
        "OTP restart strategy of each node's supervisor",
        table="supervisor",
    )
    intensity: int = setting(
        10, number(0, integer=True), "at most this many restarts ...", table="supervisor"
    )
    intensity_period: float = setting(
        60.0,
        number(above=0),
        "... within this many seconds; one more and the node exits 3",
        key="period",
        table="supervisor",
    )
    shutdown_timeout: float = setting(
        2.0, number(above=0), "seconds a measure gets to stop", key="shutdown", table="supervisor"
    )
    log_node: str | None = setting(
        None,
        NAME,
        "this node writes `<run-dir>/measures/<name>_<node>.csv` for every sender",
        key="node",
        table="logging",
    )
    log_names: tuple[str, ...] = setting(
        (),
        list_of(NAME, "a list of names"),
        "only these names (default: all)",
        key="names",
        table="logging",
    )
    world: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def node(self, name: str) -> NodeSpec:
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

    def measures(self) -> list[tuple[str, MeasureSpec]]:
        """Every (node name, measure) of the spec, in declaration order."""
        return [(n.name, m) for n in self.nodes for m in n.measures]

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


CLUSTER_TABLE = table_of(ClusterSpec, "[cluster]", table="cluster")
SUPERVISOR_TABLE = table_of(ClusterSpec, "[supervisor]", table="supervisor")
LOGGING_TABLE = table_of(ClusterSpec, "[logging]", table="logging")
NODE_TABLE = table_of(NodeSpec, "[[nodes]]")
DEFAULTS_TABLE = MEASURE_TABLE.without("use", "name")
PLACEMENT = Table(
    "[[measures]]",
    [
        Setting(
            "on",
            either(choice("*"), list_of(NAME, "a list of node names")),
            "*",
            'the nodes: "*" or a list',
        ),
        Setting(
            "count",
            number(1, integer=True),
            1,
            "declare this many copies; `{i}` in the name becomes 1..count",
        ),
    ],
)
TOP_LEVEL = ("cluster", "supervisor", "logging", "world", "defaults", "nodes", "measures")


def reference() -> str:
    """The Markdown reference of every spec table (the README's "Spec reference")."""
    parts = []
    for title, table in (
        ("`[cluster]`", CLUSTER_TABLE),
        ("`[supervisor]`", SUPERVISOR_TABLE),
        ("`[logging]`", LOGGING_TABLE),
        ("`[[nodes]]`", NODE_TABLE),
        ("`[[nodes.measures]]`, `[[measures]]` (and `[defaults]`, all but use and name)", None),
        ("`[[measures]]` only", PLACEMENT),
    ):
        parts.append(f"{title}\n\n{(table or MEASURE_TABLE).markdown()}")
    return "\n\n".join(parts)


def load_spec(path: str | Path) -> ClusterSpec:
    """Read a TOML spec or a resolved JSON spec written by :meth:`ClusterSpec.to_json`."""
    path = Path(path)
    try:
        text_ = path.read_text()
    except OSError as e:
        raise SpecError(f"cannot read spec {path}: {e.strerror}") from None
    except UnicodeDecodeError:
        raise SpecError(f"{path}: not a text file (a spec is TOML)") from None
    if path.suffix == ".json":
        try:
            return from_resolved(json.loads(text_)["resolved_spec"])
        except (KeyError, TypeError, ValueError) as e:
            raise SpecError(f"{path}: not a resolved spec written by hera up ({e})") from None
    try:
        data = tomllib.loads(text_)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: invalid TOML: {e}") from None
    return parse_spec(data, str(path))


def from_resolved(raw: dict[str, Any]) -> ClusterSpec:
    """The spec of a resolved JSON (:meth:`ClusterSpec.to_json`)."""
    raw = dict(raw)
    nodes = tuple(
        NodeSpec(
            n["name"],
            n["port"],
            tuple(n["sync_hosts"]),
            tuple(MeasureSpec(**m) for m in n["measures"]),
        )
        for n in raw.pop("nodes")
    )
    raw["log_names"] = tuple(raw["log_names"])
    return ClusterSpec(nodes=nodes, **raw)


def parse_spec(data: dict[str, Any], source: str = "<spec>") -> ClusterSpec:
    """Validate a spec given as a dict (the parsed TOML) and build a :class:`ClusterSpec`.

    Raises :class:`SpecError` listing every problem found.
    """
    problems: list[str] = []
    where = lambda table: f"{source}: {table}"  # noqa: E731
    for key in data:
        if key not in TOP_LEVEL:
            problems.append(
                f"{source}: unknown table {key!r}; known tables: {', '.join(TOP_LEVEL)}"
            )
    cluster = CLUSTER_TABLE.parse(data.get("cluster"), where("[cluster]"), problems)
    sup = SUPERVISOR_TABLE.parse(data.get("supervisor"), where("[supervisor]"), problems)
    logging_t = LOGGING_TABLE.parse(data.get("logging"), where("[logging]"), problems)
    defaults = DEFAULTS_TABLE.parse(
        data.get("defaults"), where("[defaults]"), problems, defaults=False
    )
    world = data.get("world", {})
    if not isinstance(world, dict):
        problems.append(f"{source}: [world] must be a table")
        world = {}

    node_tables = data.get("nodes", [])
    if not isinstance(node_tables, list) or not node_tables:
        problems.append(f"{source}: [[nodes]]: a spec needs at least one [[nodes]] entry")
        node_tables = []
    nodes: list[dict[str, Any]] = []
    for i, raw in enumerate(node_tables, start=1):
        label = raw.get("name") if isinstance(raw, dict) else None
        here = where(f"[[nodes]] #{i}" + (f" ({label})" if isinstance(label, str) else ""))
        n = NODE_TABLE.parse(raw, here, problems)
        if "name" in n:
            n["_where"], n["_raw_measures"] = here, (raw or {}).get("measures", [])
            nodes.append(n)
    names = [n["name"] for n in nodes]
    for dup in sorted({x for x in names if names.count(x) > 1}):
        problems.append(f"{source}: [[nodes]]: two nodes are called {dup!r}")

    per_node: dict[str, list[MeasureSpec]] = {n: [] for n in names}

    def measures_of(raw: Any, here: str, placement: bool) -> list[MeasureSpec]:
        if not isinstance(raw, dict):
            problems.append(f"{here}: must be a table")
            return []
        own = {k: v for k, v in raw.items() if not (placement and k in PLACEMENT.by_key)}
        settings = MEASURE_TABLE.parse(own, here, problems, defaults=False)
        if placement:
            count = PLACEMENT.parse(
                {k: v for k, v in raw.items() if k == "count"}, here, problems
            ).get("count", 1)
        else:
            count = 1
        merged = {**defaults, **settings}
        if "use" not in merged:
            return []
        base = merged.get("name") or default_name(merged["use"])
        out = []
        for i in range(1, count + 1):
            nm = base.replace("{i}", str(i))
            try:
                out.append(MeasureSpec(**{**merged, "name": nm}))
            except ValueError as e:
                problems.append(f"{here}: {e}")
        return out

    for n in nodes:
        raw_ms = n.pop("_raw_measures")
        here_node = n.pop("_where")
        if not isinstance(raw_ms, list):
            problems.append(f"{here_node}: measures must be a list of [[nodes.measures]] tables")
            continue
        for j, m in enumerate(raw_ms, start=1):
            here = where(f"[[nodes.measures]] #{j} of {n['name']}")
            per_node[n["name"]].extend(measures_of(m, here, placement=False))
    top = data.get("measures", [])
    if not isinstance(top, list):
        problems.append(f"{source}: [[measures]] must be a list of tables")
        top = []
    for j, m in enumerate(top, start=1):
        here = where(f"[[measures]] #{j}")
        on = PLACEMENT.parse(
            {k: v for k, v in (m if isinstance(m, dict) else {}).items() if k == "on"},
            here,
            problems,
        ).get("on", "*")
        targets = names if on == "*" else list(on)
        unknown = [t for t in targets if t not in per_node]
        if unknown:
            problems.append(
                f"{here}: on names unknown node(s) {unknown}; nodes: {', '.join(names)}"
            )
            continue
        for t in targets:
            per_node[t].extend(measures_of(m, here, placement=True))

    built = []
    base_port = cluster.get("base_port", 0)
    for i, n in enumerate(nodes):
        ms = per_node[n["name"]]
        pub = [m.name for m in ms]
        for dup in sorted({x for x in pub if pub.count(x) > 1}):
            problems.append(f"{source}: node {n['name']}: two measures publish as {dup!r}")
        port = n.get("port") or (base_port + i if base_port else 0)
        built.append(NodeSpec(n["name"], port, n.get("sync_hosts", ()), tuple(ms)))
    ports = [n.port for n in built if n.port]
    for dup in sorted({p for p in ports if ports.count(p) > 1}):
        users = [n.name for n in built if n.port == dup]
        problems.append(f"{source}: [[nodes]]: nodes {users} all listen on port {dup}")
    log_node = logging_t.get("log_node")
    if log_node is not None and log_node not in per_node:
        problems.append(f"{source}: [logging]: node {log_node!r} is not a node of the spec")
    if problems:
        raise SpecError(problems)
    return ClusterSpec(
        nodes=tuple(built), world=dict(world), source=source, **cluster, **sup, **logging_t
    )
