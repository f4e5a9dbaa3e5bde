"""Who listens where and connects to whom: the Zenoh endpoints of every node and router.

- On one host (the embedded default), nodes are peers on loopback in a full mesh: each
  listens on its own endpoint and connects to every other node's. No router, no single
  point of failure; a restarted node reconnects by itself (it dials out).
- Across hosts, Zenoh routers (``[[routers]]``: sessions in router mode, ``hera router``)
  connect to each other; a peer connects to the routers of its host (else to every router)
  and to the other peers of its host, and finds the peers of other hosts through the
  routers' gossip; a client talks through its router only. Multicast scouting is off unless
  ``[cluster] multicast_scouting`` turns it on. (Peers of one host used to find each other
  by gossip too: in one of nine starts of the four-host test here, and once in CI, two
  peers started side by side never connected and the router did not broker between them,
  so neither saw the other for the whole run. Explicit endpoints are dialled again until
  they answer.)

Every default can be overridden per node or router with ``listen``/``connect``.
"""

from __future__ import annotations

from hera.bus import BusConfig, tcp_endpoint
from hera.spec import ClusterSpec, NodeSpec, RouterSpec


def host_of(spec: ClusterSpec, part: NodeSpec | RouterSpec) -> str:
    """The address of the host a node or router runs on."""
    return part.host or spec.host


def _part(spec: ClusterSpec, name: str) -> NodeSpec | RouterSpec:
    for part in (*spec.nodes, *spec.routers):
        if part.name == name:
            return part
    spec.node(name)  # SpecError naming the known nodes
    raise AssertionError(name)


def listen_endpoints(spec: ClusterSpec, name: str) -> tuple[str, ...]:
    """The endpoints node or router ``name`` listens on (none for a client)."""
    part = _part(spec, name)
    if part.listen is not None:
        return tuple(part.listen)
    if isinstance(part, NodeSpec) and part.mode == "client":
        return ()
    if not part.port:
        raise ValueError(
            f"{spec.source}: {name!r} has no port; set [cluster] base_port or start the "
            "cluster with 'hera up', which picks free ports"
        )
    return (tcp_endpoint(host_of(spec, part), part.port),)


def router_endpoints(spec: ClusterSpec, host: str | None = None) -> tuple[str, ...]:
    """Every router's endpoints (only the routers on ``host`` when given and there are any)."""
    routers = [r for r in spec.routers if host is None or host_of(spec, r) == host]
    if host is not None and not routers:
        routers = list(spec.routers)
    return tuple(e for r in routers for e in listen_endpoints(spec, r.name))


def connect_endpoints(spec: ClusterSpec, name: str) -> tuple[str, ...]:
    """The endpoints node or router ``name`` connects to (see the module docstring)."""
    part = _part(spec, name)
    if part.connect is not None:
        return tuple(part.connect)
    if isinstance(part, RouterSpec):
        return tuple(
            e for r in spec.routers if r.name != name for e in listen_endpoints(spec, r.name)
        )
    if spec.routers:
        host = host_of(spec, part)
        if isinstance(part, NodeSpec) and part.mode == "client":
            return router_endpoints(spec, host)
        # the other peers of this host too: gossip alone can leave two of them unconnected
        # (see the module docstring)
        return router_endpoints(spec, host) + tuple(
            e
            for n in spec.nodes
            if n.name != name and n.mode == "peer" and host_of(spec, n) == host
            if n.port or n.listen
            for e in listen_endpoints(spec, n.name)
        )
    mine = set(listen_endpoints(spec, name))
    return tuple(
        e
        for n in spec.nodes
        if n.name != name and n.mode == "peer" and (n.port or n.listen)
        for e in listen_endpoints(spec, n.name)
        if e not in mine
    )


def bus_config(spec: ClusterSpec, name: str) -> BusConfig:
    """How node or router ``name`` joins the cluster's bus."""
    part = _part(spec, name)
    mode = "router" if isinstance(part, RouterSpec) else part.mode
    return BusConfig(
        listen=listen_endpoints(spec, name),
        connect=connect_endpoints(spec, name),
        lease_ms=spec.lease_ms,
        mode=mode,
        extra={
            "scouting/multicast/enabled": spec.multicast_scouting,
            "scouting/gossip/enabled": True,
            "transport/link/tx/queue/congestion_control/block/wait_before_close": spec.lease_ms
            * 250,
        },
    )


def tool_endpoints(spec: ClusterSpec) -> tuple[str, ...]:
    """Where a tool joins the cluster: the routers if there are any, else every node."""
    if spec.routers:
        return router_endpoints(spec)
    return tuple(e for n in spec.nodes if n.mode == "peer" for e in listen_endpoints(spec, n.name))
