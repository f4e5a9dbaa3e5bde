"""Measures started and stopped at run time (``hera start``, ``hera stop``).

A measure started with ``hera start NODE --use X --name Y [--args JSON]`` is checked like a
spec's (its keys, its arguments, a fusion model's settings), supervised like the others,
and recorded in the replicated args store under ``runtime/<node>/<name>`` (its measure
table), so a restarted node starts it again after it has recovered the args from its peers,
and a restarted cluster from its state directory. ``hera stop NODE NAME`` stops a measure;
one started at run time is also forgotten (its child removed, its key deleted), while a
spec's measure stays stopped until ``hera start NODE NAME`` (or a restart of its node,
which starts what its spec says).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from hera.measure import MEASURE_TABLE, MeasureSpec, default_name
from hera.plugins import find_measure

if TYPE_CHECKING:  # pragma: no cover
    from hera.node import Node

log = logging.getLogger("hera.dynamic")

PREFIX = "runtime"
"""``runtime/<node>/<name>``: the table of a measure started at run time on ``<node>``."""


def runtime_key(node: str, name: str) -> str:
    """The args-store key recording measure ``name`` started at run time on ``node``."""
    return f"{PREFIX}/{node}/{name}"


def measure_decl(table: Any, where: str) -> MeasureSpec:
    """A checked measure declaration from a ``[[nodes.measures]]``-like table; ValueError
    with one sentence per problem (unknown keys, ill-typed values, the measure's
    arguments, a fusion model's settings)."""
    problems: list[str] = []
    settings = MEASURE_TABLE.parse(table, where, problems, defaults=False)
    if problems:
        raise ValueError("; ".join(problems))
    decl = MeasureSpec(**settings)
    try:
        cls = find_measure(decl.use)
    except (LookupError, TypeError) as e:
        raise ValueError(f"{where}: {e}") from None
    problems = cls.check_args(decl.args, f"{where}: args")
    if problems:
        raise ValueError("; ".join(problems))
    return decl


def start_measure(node: Node, table: dict[str, Any]) -> dict[str, Any]:
    """Start a new measure on ``node`` from ``table`` and record it (see the module
    docstring); ValueError when it is refused."""
    name = table.get("name") or (default_name(table["use"]) if table.get("use") else None)
    where = f"measure {name!r} of node {node.name!r}"
    decl = measure_decl(table, where)
    name = str(decl.resolve(find_measure(decl.use)).name)
    if name in node.supervisor.children:
        raise ValueError(
            f"{where}: node {node.name!r} already runs a measure called {name!r}; "
            "pick another --name (or hera stop it first)"
        )
    try:
        node.add_measure(decl)
    except RuntimeError as e:  # e.g. sync = true on a node without a slot service
        raise ValueError(f"{where}: {e}") from None
    node.args.put(runtime_key(node.name, name), _table(decl))
    log.info("measure %s started at run time (%s)", name, decl.use)
    return {"measure": name, "state": node.supervisor.children[name].state, "runtime": True}


def stop_measure(node: Node, name: str) -> dict[str, Any]:
    """Stop measure ``name`` of ``node``; forget it if it was started at run time."""
    key = runtime_key(node.name, name)
    if key in node.args:
        node.supervisor.remove(name)
        node.decls.pop(name, None)
        node.args.delete(key)
        return {"measure": name, "state": "removed"}
    node.supervisor.stop_child(name)
    return {"measure": name, "state": node.supervisor.children[name].state}


def restore_measures(node: Node) -> list[str]:
    """Start the measures recorded for ``node`` under ``runtime/<node>/`` (after the args
    have been recovered); one that no longer loads is logged and left out."""
    started = []
    prefix = f"{PREFIX}/{node.name}/"
    for key, table in sorted(node.args.items().items()):
        if not key.startswith(prefix):
            continue
        name = key[len(prefix) :]
        if name in node.supervisor.children:
            log.error("run-time measure %s clashes with the spec's; not started", name)
            continue
        try:
            node.add_measure(measure_decl(table, f"run-time measure {name!r}"))
            started.append(name)
        except (ValueError, TypeError, LookupError) as e:
            log.error("run-time measure %s not started: %s", name, e)
    if started:
        log.info("restored run-time measures %s", ", ".join(started))
    return started


def _table(decl: MeasureSpec) -> dict[str, Any]:
    """The declaration as the table it came from (the keys that were given)."""
    out = {}
    for s in MEASURE_TABLE.settings:
        value = getattr(decl, s.target)
        if value is not None and value != s.default:
            out[s.key] = value
    return out
