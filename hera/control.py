"""A node's control plane: queries on ``hera/<cluster>/ctl/<node>/<verb>``, JSON in and out.

Runtime verbs:

- ``status``: the node's status (:mod:`hera.nodestatus`);
- ``start`` / ``stop`` ``{"measure"}``: start or stop one of its measures;
- ``inject`` ``{"fault": "crash" | "hang", "measure"}`` or ``{"fault": "crash_node"}``;
- ``args``: every replicated arg; ``store`` ``{"name"?}``: the samples its store holds;
- ``shutdown``: stop the node (exit 0);
- ``clock`` ``{"skew_s"?}``: set the offset of the node's wall clock (a host's clock skew,
  :mod:`hera.wallclock`); without ``skew_s`` only read it.

Applications add verbs through :meth:`hera.application.Application.verbs` (the simulator's
``board`` verb injects board faults); an unknown verb is looked up among the installed
applications the first time it is asked for. Every reply is ``{"ok": true, ...}`` or
``{"ok": false, "error": "<one sentence>"}``.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from typing import TYPE_CHECKING, Any

import zenoh

from hera import wallclock
from hera.application import VerbContext

if TYPE_CHECKING:  # pragma: no cover
    from hera.node import Node

log = logging.getLogger("hera.control")

EXIT_INJECTED_CRASH = 70
RUNTIME_VERBS = ("status", "start", "stop", "inject", "args", "store", "shutdown", "clock")


class ControlPlane:
    """Answers the control queries of one node."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._app_verbs: dict[str, Any] = {}

    def on_query(self, query: zenoh.Query) -> None:
        """Zenoh queryable callback: parse, run, reply (never raises)."""
        with query:
            verb = str(query.key_expr).rsplit("/", 1)[-1]
            try:
                raw = query.payload.to_bytes() if query.payload is not None else b""
                request = json.loads(raw) if raw else {}
                if not isinstance(request, dict):
                    raise ValueError("a control request must be a JSON object")
                reply = {"ok": True, **self.handle(verb, request)}
            except (ValueError, TypeError, LookupError) as e:
                text = e.args[0] if isinstance(e, KeyError) and e.args else e
                reply = {"ok": False, "error": str(text)}
            except Exception as e:  # a verb's bug must not take the node down
                log.exception("control verb %s failed", verb)
                reply = {"ok": False, "error": f"{verb} failed: {type(e).__name__}: {e}"}
            query.reply(self.node.keys.ctl(self.node.name, verb), json.dumps(reply))

    def handle(self, verb: str, request: dict[str, Any]) -> dict[str, Any]:
        """Run one verb; ValueError (a clear sentence) on a bad request."""
        node = self.node
        if verb == "status":
            return node.status()
        if verb in ("start", "stop"):
            measure = request.get("measure")
            if not isinstance(measure, str):
                raise ValueError(f"{verb} needs a 'measure' name")
            if verb == "start":
                node.supervisor.start_child(measure)
            else:
                node.supervisor.stop_child(measure)
            return {"measure": measure, "state": node.supervisor.children[measure].state}
        if verb == "inject":
            return self._inject(request)
        if verb == "args":
            return {"args": node.args.items()}
        if verb == "store":
            name = request.get("name")
            samples = node.store.snapshot() if name is None else node.store.get(str(name))
            return {
                "samples": [
                    {
                        "name": s.name,
                        "node": s.node,
                        "seq": s.seq,
                        "t": s.t,
                        "age_s": round(s.age(), 4),
                        "values": list(s.values),
                    }
                    for s in samples
                ]
            }
        if verb == "shutdown":
            threading.Timer(0.05, node.stop).start()
            return {"stopping": node.name}
        if verb == "clock":
            if "skew_s" in request:
                before = wallclock.set_offset(request["skew_s"])
                log.warning("clock skew of node %s set to %+.3f s", node.name, wallclock.offset())
                return {"skew_s": wallclock.offset(), "was_s": before}
            return {"skew_s": wallclock.offset()}
        handler = self._app_verb(verb)
        ctx = VerbContext(node.name, node.spec.name, node.spec.world, node.resources)
        return dict(handler(request, ctx))

    def _app_verb(self, verb: str) -> Any:
        if verb not in self._app_verbs:
            from hera.plugins import find_verb, installed_apps

            handler = find_verb(verb)
            if handler is None:
                extra = sorted(v for app in installed_apps() for v in app.verbs())
                raise ValueError(
                    f"unknown control verb {verb!r}: use {', '.join(RUNTIME_VERBS + tuple(extra))}"
                )
            self._app_verbs[verb] = handler
        return self._app_verbs[verb]

    def _inject(self, request: dict[str, Any]) -> dict[str, Any]:
        node = self.node
        fault = request.get("fault")
        if fault == "crash_node":
            log.error("crash of node %s injected", node.name)
            threading.Timer(0.05, os._exit, (EXIT_INJECTED_CRASH,)).start()
            return {"crashing": node.name}
        if fault in ("crash", "hang"):
            measure = request.get("measure")
            if not isinstance(measure, str):
                raise ValueError(f"fault {fault!r} needs a 'measure' name")
            node.supervisor.worker(measure).inject(fault)
            return {"measure": measure, "fault": fault}
        raise ValueError(
            f"unknown fault {fault!r}: use crash, hang or crash_node (board faults: the "
            "'board' verb)"
        )
