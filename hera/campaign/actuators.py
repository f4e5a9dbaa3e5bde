"""Fault actuators: how each kind of fault is done to a running cluster, and undone.

- a measure's ``crash`` / ``hang`` and a node's ``crash_node``: the node's control plane
  (verb ``inject``);
- a node's ``kill`` (SIGKILL) and ``pause`` (SIGSTOP, SIGCONT at the end): signals to the
  node's process (its pid from the launcher); ``kill`` with ``when = "firing"`` strikes
  right after a sonar started to sound (a new line in a fire log), i.e. while its slot is
  held: the worst moment for the sync service;
- ``board`` faults: the simulator's ``board`` control verb (with the fault's duration, so
  the simulator clears it by itself even if the campaign dies; cleared at the end too);
- ``partition``, ``loss``, ``delay``, ``reset``: rules of the link proxy on pairs of
  nodes (:mod:`hera.campaign.linkproxy`), or of nftables in the nodes' namespaces
  (:mod:`hera.campaign.netns`: same requests, no delay);
- ``skew``: the node's ``clock`` control verb (back to 0 at the end).

Every action is journaled (:mod:`hera.campaign.journal`) with the nodes it hit. An action
that cannot be done is journaled as an error and never raises: a campaign goes on.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hera.campaign import journal
from hera.campaign.links import Links, cut_pairs, links_of
from hera.campaign.plan import Planned, fault_rng
from hera.campaign.targets import ClusterView, TargetError, resolve, resolve_groups

FIRING_WAIT_S = 5.0
"""Longest wait for a firing before a ``when = "firing"`` kill strikes anyway."""


class FaultFailed(RuntimeError):
    """A fault that could not be done (the message says why)."""


@dataclass
class Active:
    """A fault that struck and may need undoing."""

    planned: Planned
    nodes: list[str] = field(default_factory=list)
    pairs: list[list[str]] = field(default_factory=list)
    undo: dict[str, Any] = field(default_factory=dict)
    stop: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None
    began: tuple[float, float] | None = None  # the clocks just before it acted

    def acting(self) -> None:
        """Stamp the moment the fault acts: called right before the signal, request or
        rule, after its target was found (and, for a kill at a firing, the firing came).
        The cluster may notice the fault within a millisecond, before a journal line
        written after the act could be stamped."""
        self.began = journal.now()


class Injector:
    """Does and undoes the faults of one campaign (see the module docstring)."""

    def __init__(
        self,
        view: ClusterView,
        folder: Path,
        seed: int,
        links: Links | None = None,
        fire_logs: list[Path] | None = None,
    ) -> None:
        self.view = view
        self.folder = Path(folder)
        self.seed = seed
        self.links = links
        self.fire_logs = list(fire_logs or [])

    # -- helpers ------------------------------------------------------------------------
    def _ask(self, node: str, verb: str, request: dict[str, Any]) -> dict[str, Any]:
        reply = self.view.client.query(node, verb, request, timeout=2.0).get(node)
        if reply is None:
            raise FaultFailed(f"node {node} did not answer {verb}")
        if not reply.get("ok"):
            raise FaultFailed(f"node {node} refused {verb}: {reply.get('error')}")
        return reply

    def _pid(self, node: str) -> int:
        pid = self.view.pid(node)
        if pid is None:
            raise FaultFailed(f"no process of node {node} is known to the launcher")
        return pid

    def _links(self, request: dict[str, Any]) -> dict[str, Any]:
        if self.links is None:
            raise FaultFailed(
                "network faults need the campaign's links: the cluster must be started by the "
                "campaign (not attached to)"
            )
        try:
            return self.links.command(request)
        except (OSError, ValueError, RuntimeError) as e:  # RuntimeError: an nft command
            raise FaultFailed(f"links: {e}") from None

    def _wait_for_firing(self, timeout: float) -> dict[str, Any]:
        """Block until a new line appears in a fire log (a sound just started)."""
        sizes = {p: _size(p) for p in self.fire_logs}
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for p, n in sizes.items():
                if _size(p) > n:
                    return {"firing_log": p.name}
            time.sleep(0.001)
        return {"firing_log": None}

    # -- doing --------------------------------------------------------------------------
    def strike(self, p: Planned) -> Active | None:
        """Do fault ``p``; journal it; None when it could not be done (journaled)."""
        rng = fault_rng(self.seed, p.index)
        act = Active(p)
        try:
            extra = self._strike(p, act, rng) or {}
        except (FaultFailed, TargetError, OSError) as e:
            journal.append(
                self.folder, "error", index=p.index, name=p.name, kind=p.kind, error=str(e)
            )
            return None
        journal.append(
            self.folder,
            "start",
            act.began,
            index=p.index,
            name=p.name,
            kind=p.kind,
            nodes=act.nodes,
            pairs=act.pairs,
            duration=p.duration,
            settings=p.settings,
            **extra,
        )
        return act

    def _strike(self, p: Planned, act: Active, rng: Any) -> dict[str, Any] | None:
        k = p.kind
        if k in ("crash", "hang", "kill", "crash_node", "pause", "skew", "loss", "delay", "reset"):
            act.nodes = [resolve(str(p.get("target")), self.view, rng)]
        node = act.nodes[0] if act.nodes else None
        if k in ("crash", "hang"):
            act.acting()
            self._ask(node, "inject", {"fault": k, "measure": p.get("measure")})
        elif k == "crash_node":
            act.acting()
            self._ask(node, "inject", {"fault": "crash_node"})
        elif k == "kill":
            extra = {}
            if p.get("when") == "firing":
                extra = self._wait_for_firing(FIRING_WAIT_S)
            pid = self._pid(node)
            act.acting()
            os.kill(pid, signal.SIGKILL)
            return extra
        elif k == "pause":
            pid = self._pid(node)
            act.acting()
            os.kill(pid, signal.SIGSTOP)
            act.undo["pid"] = pid
        elif k == "board":
            board = str(p.get("board"))
            node = board.split("/", 1)[0]
            act.nodes = [node]
            req = {"board": board, "fault": p.get("fault"), **p.get("params", {})}
            if p.duration:
                req["duration"] = p.duration
            act.acting()
            self._ask(node, "board", req)
        elif k == "skew":
            act.acting()
            self._ask(node, "clock", {"skew_s": p.get("skew_s")})
        elif k == "partition":
            groups = resolve_groups(p.get("groups"), self.view, rng)
            act.nodes = sorted({n for g in groups for n in g})
            act.pairs = cut_pairs(groups)
            act.undo["groups"] = groups
            act.acting()
            if p.get("flap_on_s"):
                act.thread = threading.Thread(target=self._flap, args=(act,), daemon=True)
                act.thread.start()
            else:
                self._links({"op": "set", "pairs": act.pairs, "mode": "blackhole"})
            return {"groups": groups}
        elif k in ("loss", "delay", "reset"):
            names = [n.name for n in self.view.spec.nodes]
            peers = [resolve(t, self.view, rng) for t in p.get("peers", [])] or names
            act.pairs = links_of(node, peers)
            rule: dict[str, Any] = {"op": "set", "pairs": act.pairs}
            if k == "loss":
                rule["loss"] = p.get("loss")
            elif k == "delay":
                rule.update(delay_ms=p.get("delay_ms", 0.0), jitter_ms=p.get("jitter_ms", 0.0))
            else:
                rule["mode"] = "reset"
            act.acting()
            self._links(rule)
        else:  # pragma: no cover - the schema knows every kind
            raise FaultFailed(f"unknown fault kind {k!r}")
        return None

    def _flap(self, act: Active) -> None:
        """Cut and heal the pairs again and again until the fault ends."""
        p = act.planned
        on, off = float(p.get("flap_on_s")), float(p.get("flap_off_s"))
        flaps = 0
        while not act.stop.is_set():
            try:
                began = journal.now()
                self._links({"op": "set", "pairs": act.pairs, "mode": "blackhole"})
                journal.append(self.folder, "flap", began, index=p.index, state="cut")
                if act.stop.wait(on):
                    break
                began = journal.now()
                self._links({"op": "clear", "pairs": act.pairs})
                journal.append(self.folder, "flap", began, index=p.index, state="healed")
                flaps += 1
            except FaultFailed as e:
                journal.append(self.folder, "error", index=p.index, name=p.name, error=str(e))
                return
            act.stop.wait(off)
        act.undo["flaps"] = flaps

    # -- undoing ------------------------------------------------------------------------
    def heal(self, act: Active) -> None:
        """Undo a fault that lasts (SIGCONT, clear the links, the board, the clock);
        journal the end."""
        p = act.planned
        error = None
        began = journal.now()
        try:
            if act.thread is not None:
                act.stop.set()
                act.thread.join(5.0)
            if p.kind == "pause":
                with contextlib.suppress(ProcessLookupError):
                    os.kill(act.undo["pid"], signal.SIGCONT)
            elif p.kind in ("partition", "loss", "delay", "reset"):
                self._links({"op": "clear", "pairs": act.pairs})
            elif p.kind == "board":
                self._ask(act.nodes[0], "board", {"board": p.get("board"), "fault": "clear"})
            elif p.kind == "skew":
                self._ask(act.nodes[0], "clock", {"skew_s": 0.0})
        except (FaultFailed, OSError) as e:
            error = str(e)
        journal.append(
            self.folder,
            "end",
            began,
            index=p.index,
            name=p.name,
            kind=p.kind,
            nodes=act.nodes,
            error=error,
            **({"flaps": act.undo["flaps"]} if "flaps" in act.undo else {}),
        )


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
