"""A node's control plane: queries on ``hera/<cluster>/ctl/<node>/<verb>``, JSON in and out.

Runtime verbs:

- ``status``: the node's status (:mod:`hera.nodestatus`);
- ``start`` / ``stop`` ``{"measure"}``: start or stop one of its measures; ``start`` with a
  measure table (``{"use", "name"?, "args"?, ...}``) starts a new one, ``stop`` of such a
  one forgets it (:mod:`hera.dynamic`);
- ``inject`` ``{"fault": "crash" | "hang", "measure"}`` or ``{"fault": "crash_node"}``;
- ``args``: every replicated arg; ``{"op": "get" | "set" | "del", "key", "value"?}`` reads,
  writes or deletes one (a run-time argument of one of this node's measures,
  ``measure/<node>/<measure>/<arg>``, is checked against the measure's declaration);
- ``store`` ``{"name"?, "names"?}``: the samples its store holds (of one name, of a list of
  names, or all);
- ``reload`` ``{"module"}``: load new code and replace the measures it changes
  (:mod:`hera.reload`);
- ``shutdown``: stop the node (exit 0);
- ``clock`` ``{"skew_s"?}``: set the offset of the node's wall clock (a host's clock skew,
  :mod:`hera.wallclock`); without ``skew_s`` only read it.

Every verb that changes something is remembered (the last :data:`EVENTS` of them, with
their time and outcome) and shown in the node's status (``control_events``).

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
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import zenoh

from hera import dynamic, wallclock
from hera.application import VerbContext
from hera.measure import ARGS_PREFIX

if TYPE_CHECKING:  # pragma: no cover
    from hera.node import Node

log = logging.getLogger("hera.control")

EXIT_INJECTED_CRASH = 70
RUNTIME_VERBS = (
    "status",
    "start",
    "stop",
    "inject",
    "args",
    "store",
    "reload",
    "shutdown",
    "clock",
)
READ_ONLY = frozenset({"status", "store"})
EVENTS = 50


class ControlPlane:
    """Answers the control queries of one node."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._app_verbs: dict[str, Any] = {}
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS)
        """Recent verbs that change something: time, verb, request, ok, error."""

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
            if verb not in READ_ONLY and not (verb == "args" and request.get("op", "get") == "get"):
                self._remember(verb, request, reply)
            query.reply(self.node.keys.ctl(self.node.name, verb), json.dumps(reply))

    def _remember(self, verb: str, request: dict[str, Any], reply: dict[str, Any]) -> None:
        event = {"t": time.time(), "verb": verb, "request": request, "ok": reply.get("ok")}
        if not reply.get("ok"):
            event["error"] = reply.get("error")
        self.events.append(event)

    def handle(self, verb: str, request: dict[str, Any]) -> dict[str, Any]:
        """Run one verb; ValueError (a clear sentence) on a bad request."""
        node = self.node
        if verb == "status":
            return node.status()
        if verb == "start" and "use" in request:
            return dynamic.start_measure(node, request)
        if verb in ("start", "stop"):
            measure = request.get("measure")
            if not isinstance(measure, str):
                raise ValueError(f"{verb} needs a 'measure' name (or, to start a new one, 'use')")
            if verb == "stop":
                return dynamic.stop_measure(node, measure)
            node.supervisor.start_child(measure)
            return {"measure": measure, "state": node.supervisor.children[measure].state}
        if verb == "inject":
            return self._inject(request)
        if verb == "args":
            return self._args(request)
        if verb == "reload":
            module = request.get("module")
            if not isinstance(module, str) or not module:
                raise ValueError("reload needs a 'module' (a module or package name)")
            from hera.reload import reload_code

            return reload_code(node, module)
        if verb == "store":
            name, names = request.get("name"), request.get("names")
            if names is not None:
                if not isinstance(names, list):
                    raise ValueError("store 'names' must be a list of names")
                samples = [s for n in names for s in node.store.get(str(n))]
            else:
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

    def _args(self, request: dict[str, Any]) -> dict[str, Any]:
        """The ``args`` verb: every arg, or get/set/del of one key."""
        store = self.node.args
        op = request.get("op")
        if op is None:
            return {"args": store.items()}
        key = request.get("key")
        if op not in ("get", "set", "del"):
            raise ValueError(f"unknown args op {op!r}: use get, set or del")
        if not isinstance(key, str) or not key:
            raise ValueError(f"args {op} needs a 'key'")
        if op == "get":
            entry = store.entry(key)
            if entry is None:
                raise LookupError(f"no arg {key!r} on node {self.node.name!r}")
            return {"key": key, "value": entry[2], "origin": entry[1], "ts_ns": entry[0]}
        if op == "set":
            if "value" not in request:
                raise ValueError("args set needs a 'value'")
            self._check_measure_arg(key, request["value"])
            store.put(key, request["value"])
            return {"key": key, "value": request["value"]}
        if key not in store:
            raise LookupError(f"no arg {key!r} on node {self.node.name!r}")
        store.delete(key)
        return {"key": key, "deleted": True}

    def _check_measure_arg(self, key: str, value: Any) -> None:
        """Refuse a run-time argument ``measure/<this node>/<measure>/<arg>`` that the
        measure's declared arguments refuse (a clear sentence naming key and value)."""
        node = self.node
        parts = key.split("/")
        if len(parts) != 4 or parts[0] != ARGS_PREFIX or parts[1] != node.name:
            return
        decl = node.decls.get(parts[2])
        if decl is None:
            known = ", ".join(sorted(node.decls)) or "none"
            raise ValueError(f"{key}: node {node.name!r} runs no measure {parts[2]!r} ({known})")
        from hera.plugins import find_measure

        cls = find_measure(decl.use)
        problems = cls.check_args({**decl.args, parts[3]: value}, f"{key} = {value!r}")
        if problems:
            raise ValueError(problems[0])

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
