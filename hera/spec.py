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
import math
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from hera.bus import DEFAULT_LEASE_MS
from hera.keys import MAX_CHUNK, check_chunk
from hera.measure import MEASURE_TABLE, MeasureSpec, default_name
from hera.schema import (
    ANY,
    BOOL,
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
                f"must use only letters, digits, '_', '.' and '-' (no '/', '*', '$'), at most "
                f"{MAX_CHUNK} of them"
            ) from None

    return check


NAME = text(_chunk("name"), "a name")


def _endpoint(value: str) -> None:
    proto, _, rest = value.partition("/")
    if proto not in ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream") or ":" not in rest:
        raise ValueError("must be an endpoint like 'tcp/10.0.0.2:7447'")


ENDPOINT = text(_endpoint, "an endpoint like 'tcp/10.0.0.2:7447'")


def _port_base(v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not (v == 0 or 1024 <= v < 65000):
        raise ValueError("must be 0 (pick free ports) or an integer within [1024, 65000)")
    return v


PORT_BASE = Kind("0 or a port in [1024, 65000)", _port_base)

SYNC_LEASE_MS_MIN, SYNC_LEASE_MS_MAX = 20, 1650
"""The range of ``[cluster] sync_lease_ms``. The top is the sync service's clock condition
(``hera.sync.election.Timing``: 2 rho (L + D) / (1 - rho) <= m with its margin m = 50 ms,
drift rho = 1 % and the longest slot lease D = L / 2): a longer leader lease L leaves the
margin too small for the clocks' drift, and the service could not start."""
SLOT_SLACK = 0.25
"""The share of a synchronised step added to the lease it asks for (:func:`slot_lease`)."""
SLOT_SLACK_MIN = 0.005
"""The least slack (s) added to a synchronised step's lease (:func:`slot_lease`)."""


def slot_lease(slot: float) -> float:
    """The sync lease a synchronised step of ``slot`` s asks for: the step plus a slack for
    latency (25 % of the step, at least 5 ms), which absorbs the grant's trip back and the
    scheduling delay before firing. The one formula of the client (``hera.sync``) and of
    the spec check."""
    return slot + max(SLOT_SLACK_MIN, SLOT_SLACK * slot)


def max_slot_lease(sync_lease_ms: int) -> float:
    """The longest slot lease (s) a sync leader grants with ``[cluster] sync_lease_ms``:
    half the leader lease, so a slot fits in a freshly renewed lease."""
    return sync_lease_ms / 2000.0


def longest_slot(max_lease: float) -> float:
    """The longest ``slot`` (s, to 0.1 ms) whose :func:`slot_lease` is at most
    ``max_lease`` s (0 if none is)."""
    if max_lease <= SLOT_SLACK_MIN * (1 + 1 / SLOT_SLACK):  # the slack is its minimum
        slot = max_lease - SLOT_SLACK_MIN
    else:
        slot = max_lease / (1 + SLOT_SLACK)
    shown = round(max(slot, 0.0), 4)
    while shown > 0 and slot_lease(shown) > max_lease:
        shown = round(shown - 1e-4, 4)
    return shown


def slot_problem(slot: float, sync_lease_ms: int) -> str | None:
    """Why a synchronised step of ``slot`` s cannot get a slot with ``[cluster]
    sync_lease_ms`` (one sentence, no subject), or None if it can."""
    lease = slot_lease(slot)
    if lease <= max_slot_lease(sync_lease_ms):
        return None
    longest = longest_slot(max_slot_lease(sync_lease_ms))
    needed = math.ceil(round(lease * 2000.0, 6))
    fix = (
        f"shorten the slot or raise [cluster] sync_lease_ms to {needed} or more"
        if needed <= SYNC_LEASE_MS_MAX
        else "shorten the slot"
    )
    return (
        f"slot {slot:g} s is too long for [cluster] sync_lease_ms = {sync_lease_ms}: its "
        f"lease ({lease:.4g} s: the slot plus {SLOT_SLACK:.0%}, at least "
        f"{SLOT_SLACK_MIN * 1000:g} ms) must fit in half the sync lease, so the longest slot "
        f"is {longest:g} s; {fix}"
    )


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
    host: str | None = setting(
        None, STR, "address of the host it runs on, which it listens on (default: [cluster] host)"
    )
    mode: str = setting(
        "peer",
        choice("peer", "client"),
        "`peer` (listens, meshes with the others) or `client` (talks through a router only)",
    )
    listen: tuple[str, ...] | None = setting(
        None, list_of(ENDPOINT, "a list of endpoints"), "its listen endpoints (default: host:port)"
    )
    connect: tuple[str, ...] | None = setting(
        None,
        list_of(ENDPOINT, "a list of endpoints"),
        "endpoints it connects to (default: the routers of its host, else every router, "
        "else every other node)",
    )
    store: str = setting(
        "interest",
        choice("interest", "all"),
        "what its store takes: `interest` (the names its measures read) or `all` (every "
        "sample of the cluster, for tools; the `[logging]` node takes what it logs too)",
    )


@dataclass(frozen=True)
class RouterSpec:
    """One Zenoh router: a ``[[routers]]`` entry (``hera router SPEC --name NAME``)."""

    name: str = setting(REQUIRED, NAME, "router name")
    host: str | None = setting(
        None, STR, "address of the host it runs on (default: [cluster] host)"
    )
    port: int = setting(
        0, number(0, 65535, integer=True), "TCP port (0: after the nodes' ports, or picked)"
    )
    listen: tuple[str, ...] | None = setting(
        None, list_of(ENDPOINT, "a list of endpoints"), "its listen endpoints (default: host:port)"
    )
    connect: tuple[str, ...] | None = setting(
        None,
        list_of(ENDPOINT, "a list of endpoints"),
        "endpoints it connects to (default: every other router)",
    )


@dataclass(frozen=True)
class ClusterSpec:
    """A whole cluster; ``base_port == 0`` means "pick free ports at launch"."""

    nodes: tuple[NodeSpec, ...]
    routers: tuple[RouterSpec, ...] = ()
    name: str = setting(
        REQUIRED, NAME, "cluster name: the key prefix `hera/<name>/`", table="cluster"
    )
    host: str = setting(
        "127.0.0.1", STR, "address nodes and routers listen on unless they say", table="cluster"
    )
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
        number(SYNC_LEASE_MS_MIN, SYNC_LEASE_MS_MAX, integer=True),
        "sync leader lease; a synchronised measure's slot plus 25 % (at least 5 ms) must "
        "fit in half of it: slot <= 0.12 s at 300",
        table="cluster",
    )
    multicast_scouting: bool = setting(
        False,
        BOOL,
        "let Zenoh find peers by multicast too (off: explicit endpoints and gossip only)",
        table="cluster",
    )
    estimation_backend: str = setting(
        "numpy",
        choice("numpy", "numba", "auto"),
        "`numba`: compiled estimation kernels, loaded when a measure makes its first filter; "
        "`auto` uses numba if installed",
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
        "this node writes `<run-dir>/measures/<name>_<node>.csv` for every source the spec "
        "declares",
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
    auth: bool = setting(
        True,
        BOOL,
        "every link authenticates (user/password from the cluster secret); off only for a "
        "closed lab",
        table="security",
    )
    tls: bool = setting(
        False,
        BOOL,
        "every link is mutual TLS with the certificates of `certs` (plain TCP refused)",
        table="security",
    )
    certs: str | None = setting(
        None,
        STR,
        "folder made by `hera certs`: the certificates (with `tls`) and the cluster secret "
        "shared by every host (default: `hera up` makes a secret in the run directory)",
        table="security",
    )
    access_control: bool = setting(
        True,
        BOOL,
        "with `tls`: Zenoh access control on every node and router (a node writes only its "
        "own keys, only the operator uses the control plane)",
        table="security",
    )
    max_clock_skew_ms: int = setting(
        1000,
        number(1, 3_600_000, integer=True),
        "an args write stamped further ahead of the receiver's clock is refused",
        table="security",
    )
    max_names_per_node: int = setting(
        256,
        number(1, 100_000, integer=True),
        "names a store and the CSV logger take from one node; more are refused",
        table="security",
    )
    max_open_logs: int = setting(
        64,
        number(1, 10_000, integer=True),
        "CSV files the logging node keeps open at once (the least recently used is closed)",
        table="security",
    )
    secret: str | None = None
    """The cluster secret's file (resolved by ``hera up``: ``certs``' or the run's own)."""
    world: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def node(self, name: str) -> NodeSpec:
        """The node called ``name``; SpecError listing the known names otherwise."""
        for n in self.nodes:
            if n.name == name:
                return n
        known = ", ".join(n.name for n in self.nodes)
        raise SpecError(f"{self.source}: no node {name!r} in the spec (nodes: {known})")

    def router(self, name: str) -> RouterSpec:
        """The router called ``name``; SpecError listing the known names otherwise."""
        for r in self.routers:
            if r.name == name:
                return r
        known = ", ".join(r.name for r in self.routers) or "none"
        raise SpecError(f"{self.source}: no router {name!r} in the spec (routers: {known})")

    def endpoint(self, name: str) -> str:
        """The first endpoint node (or router) ``name`` listens on."""
        from hera.topology import listen_endpoints

        eps = listen_endpoints(self, name)
        if not eps:
            raise SpecError(f"{self.source}: {name!r} listens on nothing (a client)")
        return eps[0]

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

    def unported(self) -> list[NodeSpec | RouterSpec]:
        """The nodes (peers) and routers that listen but were given neither a ``port`` nor
        ``listen`` endpoints: :meth:`with_ports` gives them one each. A client listens on
        nothing and needs none."""
        return [
            p
            for p in (*self.nodes, *self.routers)
            if not (p.port or p.listen) and getattr(p, "mode", "peer") != "client"
        ]

    def with_ports(self, ports: list[int]) -> ClusterSpec:
        """A copy where the :meth:`unported` nodes, then routers, listen on ``ports`` in
        order (one port each)."""
        todo = self.unported()
        if len(ports) != len(todo):
            raise ValueError(f"{len(todo)} ports needed, {len(ports)} given")
        given = {id(p): port for p, port in zip(todo, ports, strict=True)}
        nodes = tuple(replace(x, port=given[id(x)]) if id(x) in given else x for x in self.nodes)
        routers = tuple(
            replace(r, port=given[id(r)]) if id(r) in given else r for r in self.routers
        )
        return replace(self, nodes=nodes, routers=routers)

    def with_hosts(self, hosts: dict[str, str]) -> ClusterSpec:
        """A copy where each node named in ``hosts`` runs on the host at that address."""
        unknown = sorted(set(hosts) - {n.name for n in self.nodes})
        if unknown:
            raise ValueError(f"no node {unknown[0]!r} in the spec")
        nodes = tuple(replace(n, host=hosts[n.name]) if n.name in hosts else n for n in self.nodes)
        return replace(self, nodes=nodes)

    def with_security(self, **values: Any) -> ClusterSpec:
        """A copy with the given security settings (``certs``, ``secret``, ``tls`` ...)."""
        return replace(self, **values)

    def spans_hosts(self) -> bool:
        """Whether its nodes and routers run on more than one host."""
        return len({p.host or self.host for p in (*self.nodes, *self.routers)}) > 1

    def with_world(self, **values: Any) -> ClusterSpec:
        """A copy with ``values`` added to the world table."""
        return replace(self, world={**self.world, **values})

    def to_json(self) -> str:
        """The resolved spec as JSON (what ``hera up`` hands its nodes)."""
        return json.dumps({"resolved_spec": asdict(self)}, indent=1)


CLUSTER_TABLE = table_of(ClusterSpec, "[cluster]", table="cluster")
SUPERVISOR_TABLE = table_of(ClusterSpec, "[supervisor]", table="supervisor")
LOGGING_TABLE = table_of(ClusterSpec, "[logging]", table="logging")
SECURITY_TABLE = table_of(ClusterSpec, "[security]", table="security")
NODE_TABLE = table_of(NodeSpec, "[[nodes]]")
ROUTER_TABLE = table_of(RouterSpec, "[[routers]]")
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
TOP_LEVEL = (
    "cluster",
    "supervisor",
    "logging",
    "security",
    "world",
    "defaults",
    "nodes",
    "routers",
    "measures",
)


def reference() -> str:
    """The Markdown reference of every spec table (the README's "Spec reference")."""
    parts = []
    for title, table in (
        ("`[cluster]`", CLUSTER_TABLE),
        ("`[supervisor]`", SUPERVISOR_TABLE),
        ("`[logging]`", LOGGING_TABLE),
        ("`[security]`", SECURITY_TABLE),
        ("`[[nodes]]`", NODE_TABLE),
        ("`[[routers]]`", ROUTER_TABLE),
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
            data = json.loads(text_)
        except ValueError as e:
            raise SpecError(f"{path}: not a resolved spec written by hera up ({e})") from None
        if not isinstance(data, dict) or not isinstance(data.get("resolved_spec"), dict):
            raise SpecError(
                f"{path}: not a resolved spec written by hera up (a JSON object whose "
                "resolved_spec is the spec)"
            )
        try:
            return from_resolved(data["resolved_spec"])
        except (KeyError, TypeError, ValueError) as e:
            why = f"no key {e}" if isinstance(e, KeyError) else str(e)
            raise SpecError(f"{path}: not a resolved spec written by hera up ({why})") from None
    try:
        data = tomllib.loads(text_)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: invalid TOML: {e}") from None
    return parse_spec(data, str(path))


def from_resolved(raw: dict[str, Any]) -> ClusterSpec:
    """The spec of a resolved JSON (:meth:`ClusterSpec.to_json`)."""
    raw = dict(raw)

    def tup(v: Any) -> tuple | None:
        return None if v is None else tuple(v)

    nodes = tuple(
        NodeSpec(
            **{
                **n,
                "sync_hosts": tuple(n["sync_hosts"]),
                "measures": tuple(MeasureSpec(**m) for m in n["measures"]),
                "listen": tup(n.get("listen")),
                "connect": tup(n.get("connect")),
            }
        )
        for n in raw.pop("nodes")
    )
    routers = tuple(
        RouterSpec(**{**r, "listen": tup(r.get("listen")), "connect": tup(r.get("connect"))})
        for r in raw.pop("routers", [])
    )
    raw["log_names"] = tuple(raw["log_names"])
    return ClusterSpec(nodes=nodes, routers=routers, **raw)


def _broken(table: Table, raw: Any, parsed: dict[str, Any]) -> set[str]:
    """The settings of ``table`` that ``raw`` gives but that did not parse (left out of
    ``parsed``); all of them if ``raw`` is not a table."""
    if raw is None:
        return set()
    if not isinstance(raw, dict):
        return {s.target for s in table.settings}
    return {s.target for s in table.settings if s.key in raw and s.target not in parsed}


def _stand_in(
    settings: dict[str, Any], name: str, bad: set[str], built: MeasureSpec | None
) -> MeasureSpec | None:
    """What the plugin checks of a spec with problems check in place of the measure called
    ``name`` of ``settings``: ``built`` (the measure) if all its settings parsed, else one
    without the settings whose checks depend on a broken (``bad``) or conflicting value;
    None if its name or arguments are broken (every check names it, or reads them)."""
    if bad & {"name", "args"}:
        return None
    if built is not None and not bad:
        return built
    keep = {**settings, "name": name}
    if built is None:  # a rule between thread, offset, sync and period broken
        keep.pop("thread", None)
        keep.pop("offset", None)
        if keep.get("sync"):
            keep["sync"] = False
    if bad & {"period", "sync"}:
        keep.pop("offset", None)  # checked against the period and sync
    if bad & {"sync", "sync_group"}:
        keep["sync"] = False  # whether its group is hosted is not known
    try:
        return MeasureSpec(**keep)
    except ValueError:
        return None


def parse_spec(data: dict[str, Any], source: str = "<spec>") -> ClusterSpec:
    """Validate a spec given as a dict (the parsed TOML) and build a :class:`ClusterSpec`.

    Raises :class:`SpecError` listing every problem found: with a problem anywhere, those
    the plugin checks (:func:`hera.preflight.spec_problems`) find in what could be parsed
    too, so that one table's problem hides no other's; only the checks that depend on a
    broken value are skipped.
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
    security = SECURITY_TABLE.parse(data.get("security"), where("[security]"), problems)
    if security.get("certs"):
        security["certs"] = str((Path(source).parent / security["certs"]).resolve())
    defaults = DEFAULTS_TABLE.parse(
        data.get("defaults"), where("[defaults]"), problems, defaults=False
    )
    defaults_bad = _broken(DEFAULTS_TABLE, data.get("defaults"), defaults)
    world = data.get("world", {})
    world_bad = not isinstance(world, dict)
    if world_bad:
        problems.append(f"{source}: [world] must be a table")
        world = {}

    node_tables = data.get("nodes", [])
    if isinstance(node_tables, dict):
        problems.append(
            f"{source}: [nodes] is a table; nodes are a list of tables: write [[nodes]] "
            "(two brackets), one per node"
        )
        node_tables = []
    elif not isinstance(node_tables, list) or not node_tables:
        problems.append(f"{source}: [[nodes]]: a spec needs at least one [[nodes]] entry")
        node_tables = []
    nodes: list[dict[str, Any]] = []
    hosts_known = True  # every node's sync_hosts parsed: whether a group is hosted is known
    for i, raw in enumerate(node_tables, start=1):
        label = raw.get("name") if isinstance(raw, dict) else None
        here = where(f"[[nodes]] #{i}" + (f" ({label})" if isinstance(label, str) else ""))
        n = NODE_TABLE.parse(raw, here, problems)
        hosts_known &= "name" in n and not _broken(NODE_TABLE, raw, n) & {"sync_hosts"}
        if "name" in n:
            n.pop("measures", None)
            n["_where"], n["_raw_measures"] = here, (raw or {}).get("measures", [])
            nodes.append(n)
    names = [n["name"] for n in nodes]
    for dup in sorted({x for x in names if names.count(x) > 1}):
        problems.append(f"{source}: [[nodes]]: two nodes are called {dup!r}")

    per_node: dict[str, list[MeasureSpec]] = {n: [] for n in names}
    # what the plugin checks see of each node's measures when the spec has problems
    checkable: dict[str, list[MeasureSpec]] = {n: [] for n in names}

    def measures_of(raw: Any, here: str, placement: bool, node: str) -> list[MeasureSpec]:
        if not isinstance(raw, dict):
            problems.append(f"{here}: must be a table")
            return []
        own = {k: v for k, v in raw.items() if not (placement and k in PLACEMENT.by_key)}
        settings = MEASURE_TABLE.parse(own, here, problems, defaults=False)
        bad = _broken(MEASURE_TABLE, own, settings) | (defaults_bad - settings.keys())
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
            built: MeasureSpec | None = None
            try:
                built = MeasureSpec(**{**merged, "name": nm})
                out.append(built)
            except ValueError as e:
                problems.append(f"{here}: {e}")
            stand_in = _stand_in(merged, nm, bad, built)
            if stand_in is not None:
                checkable[node].append(stand_in)
        return out

    for n in nodes:
        raw_ms = n.pop("_raw_measures")
        here_node = n.pop("_where")
        if not isinstance(raw_ms, list):
            problems.append(f"{here_node}: measures must be a list of [[nodes.measures]] tables")
            continue
        for j, m in enumerate(raw_ms, start=1):
            here = where(f"[[nodes.measures]] #{j} of {n['name']}")
            per_node[n["name"]].extend(measures_of(m, here, False, n["name"]))
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
            per_node[t].extend(measures_of(m, here, True, t))

    built = []
    base_port = cluster.get("base_port", 0)
    for i, n in enumerate(nodes):
        ms = per_node[n["name"]]
        pub = [m.name for m in ms]
        for dup in sorted({x for x in pub if pub.count(x) > 1}):
            problems.append(f"{source}: node {n['name']}: two measures publish as {dup!r}")
        port = n.get("port") or (base_port + i if base_port else 0)
        fields = {k: v for k, v in n.items() if k not in ("name", "port", "measures")}
        built.append(NodeSpec(n["name"], port, measures=tuple(ms), **fields))
    routers = []
    raw_routers = data.get("routers", [])
    if not isinstance(raw_routers, list):
        problems.append(f"{source}: [[routers]] must be a list of tables")
        raw_routers = []
    for j, raw in enumerate(raw_routers, start=1):
        label = raw.get("name") if isinstance(raw, dict) else None
        here = where(f"[[routers]] #{j}" + (f" ({label})" if isinstance(label, str) else ""))
        r = ROUTER_TABLE.parse(raw, here, problems)
        if "name" in r:
            if not r.get("port") and base_port:
                r["port"] = base_port + len(nodes) + j - 1
            routers.append(RouterSpec(**r))
    every = [n.name for n in built] + [r.name for r in routers]
    for dup in sorted({x for x in every if every.count(x) > 1} - set(names)):
        problems.append(f"{source}: [[routers]]: the name {dup!r} is used twice")
    for dup in sorted({r.name for r in routers} & set(names)):
        problems.append(f"{source}: [[routers]]: {dup!r} is the name of a node too")
    hosts = [
        (x.host or cluster.get("host", "127.0.0.1"), x.port, x.name) for x in [*built, *routers]
    ]
    seen: dict[tuple[str, int], list[str]] = {}
    for host, port, name in hosts:
        if port:
            seen.setdefault((host, port), []).append(name)
    for (host, port), users in sorted(seen.items()):
        if len(users) > 1:
            problems.append(f"{source}: {users} all listen on {host}:{port}")
    spread = {h for h, _, _ in hosts}
    unset = [n for h, p, n in hosts if not p]
    if len(spread) > 1 and unset:
        problems.append(
            f"{source}: the spec spans the hosts {sorted(spread)}, so every node and router "
            f"needs a fixed port: set [cluster] base_port or a port for {unset}"
        )
    for n in built:
        if n.mode == "client" and not routers and n.connect is None:
            problems.append(
                f"{source}: node {n.name!r} is a client, which talks through a router: add a "
                "[[routers]] entry or give it connect endpoints"
            )
    log_node = logging_t.get("log_node")
    if log_node is not None and log_node not in per_node:
        problems.append(f"{source}: [logging]: node {log_node!r} is not a node of the spec")
    if problems:
        # the plugin checks (hera.preflight) of what could be parsed, so that a problem in
        # one table hides none of the others; those depending on a broken value are skipped
        from hera.preflight import spec_problems

        partial = ClusterSpec(
            nodes=tuple(
                NodeSpec(
                    name,
                    sync_hosts=next(n.get("sync_hosts", ()) for n in nodes if n["name"] == name),
                    measures=tuple(
                        m if hosts_known else replace(m, sync=False) for m in checkable[name]
                    ),
                )
                for name in dict.fromkeys(names)
            ),
            world=dict(world),
            source=source,
            # a broken lease checks no slot (the longest lease grants every slot it can)
            sync_lease_ms=cluster.get("sync_lease_ms", SYNC_LEASE_MS_MAX),
        )
        found = spec_problems(partial)
        if world_bad:
            found = [p for p in found if not p.startswith(f"{source}: [world]:")]
        raise SpecError(list(dict.fromkeys([*problems, *found])))
    return ClusterSpec(
        nodes=tuple(built),
        routers=tuple(routers),
        world=dict(world),
        source=source,
        **cluster,
        **sup,
        **logging_t,
        **security,
    )
