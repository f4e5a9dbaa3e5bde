"""What the web view knows of a running cluster, kept up to date in the background.

A :class:`Console` joins the cluster's bus through a :class:`~hera.client.ClusterClient`:

- every sample of ``data/**`` goes into a :class:`~hera.console.buffers.Downsampler` (and
  the latest one per stream is kept for the applications' panels);
- the nodes' liveliness tokens give their up/down events at once (a SIGKILLed node is seen
  down within milliseconds, and up again when its replacement has joined);
- once a second it asks every node's status and reads the launcher's state, which give the
  measures, restarts, rejected inputs, the sync leader and slot holder, and the control
  verbs that changed something (faults injected, measures started, args set, reloads).

:meth:`Console.poll` returns all the page needs in one JSON-able answer. The runtime knows
no application: the truth next to a model's columns and the panels come from the
applications that own the measures (:mod:`hera.application`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import msgpack
import zenoh

from hera.application import Application, Estimate, Truth
from hera.client import ClusterClient
from hera.console.buffers import Downsampler
from hera.fusion import FusionMeasure
from hera.peers import Peers
from hera.plugins import AppIndex, find_measure
from hera.spec import ClusterSpec
from hera.statusview import problem_rows, sync_rows

log = logging.getLogger("hera.console")

STATUS_PERIOD = 1.0
CACHE_S = 0.5
"""Seconds the cluster's and the streams' part of an answer are reused."""
EVENTS = 200
WINDOW_S = 30.0
"""Seconds of history a newly opened page receives."""


def _columns(cls: type | None, n: int) -> list[str]:
    cols = list(getattr(cls, "columns", ()) or ())
    return cols if len(cols) == n else [f"v{i + 1}" for i in range(n)]


class Console:
    """The web view's picture of one cluster (see the module docstring)."""

    def __init__(
        self,
        spec: ClusterSpec,
        run_dir: str | Path | None = None,
        launcher_state: Callable[[], Mapping[str, Any]] | None = None,
        bucket_s: float = 0.1,
        keep_s: float = 60.0,
        index: AppIndex | None = None,
    ) -> None:
        self.spec = spec
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self._launcher_state = launcher_state
        self.buffers = Downsampler(bucket_s, keep_s)
        self.index = index or AppIndex()
        self.classes: dict[str, type] = {}
        for _, m in spec.measures():
            with contextlib.suppress(LookupError, TypeError):
                self.classes.setdefault(str(m.name), find_measure(m.use))
        self.truths: dict[str, Truth | None] = {}
        self.latest: dict[str, tuple[float, tuple[float, ...]]] = {}
        self.rejected = 0
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS)
        self._seen_events: set[tuple[str, float, str]] = set()
        self.status: dict[str, dict[str, Any]] = {}
        self.launcher: dict[str, dict[str, Any]] = {}
        self.started = time.time()
        self._lock = threading.Lock()
        self._cache: dict[str, tuple[float, Any]] = {}
        self._stop = threading.Event()
        self.client = ClusterClient(spec)
        self.peers = Peers(self.client.keys)
        # the nodes up when the view starts come as liveliness history: not "joined" events
        # (they were listed as joining at the view's start); set after the first status
        self._joined_before = True
        self._subs = [
            self.client.subscribe(self.client.keys.data("*", "*"), self._on_sample),
            self.client.subscribe_alive(self._on_alive),
        ]
        self._thread = threading.Thread(target=self._watch, name="console-status", daemon=True)
        self._thread.start()

    # -- bus ------------------------------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: one data sample into the buffers (malformed ones are counted)."""
        key = str(sample.key_expr)
        try:
            *_, name, node = key.rsplit("/", 2)
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            t, values = float(msg["t"]), tuple(float(v) for v in msg["val"])
        except Exception:  # untrusted bytes: the nodes count what they reject
            self.rejected += 1
            return
        stream = f"{name}/{node}"
        self.buffers.add(stream, t, values)
        self.latest[stream] = (t, values)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        before = set(self.peers.up)
        self.peers.on_alive(sample)
        after = set(self.peers.up)
        if self._joined_before:
            return
        for node in sorted(after - before):
            self._event(node, "up", "joined the bus")
        for node in sorted(before - after):
            self._event(node, "down", "left the bus (its liveliness token is gone)")

    def _event(self, node: str, kind: str, text: str, t: float | None = None) -> None:
        with self._lock:
            self.events.append({"t": t or time.time(), "node": node, "kind": kind, "text": text})

    # -- status ---------------------------------------------------------------------------
    def _watch(self) -> None:
        wait = 0.0  # the first status at once, then one a period
        while not self._stop.wait(wait):
            wait = STATUS_PERIOD
            try:
                status = self.client.status(timeout=0.5)
            except Exception as e:  # the view must survive a failing query
                log.warning("status query failed: %s", e)
                status = {}
            launcher = self._read_launcher()
            self.learn_classes(status)
            with self._lock:
                self.status, self.launcher = status, launcher
            self._joined_before = False  # what comes now happens while the view watches
            for node, st in sorted(status.items()):
                for ev in st.get("control_events", ()):
                    key = (node, float(ev.get("t", 0)), str(ev.get("verb")))
                    if key in self._seen_events:
                        continue
                    self._seen_events.add(key)
                    self._event(node, ev.get("verb", "?"), _describe(ev), float(ev.get("t", 0)))

    def learn_classes(self, status: Mapping[str, Mapping[str, Any]]) -> None:
        """Learn the class of each measure the nodes' ``status`` reports that the spec does
        not name (started at run time by ``hera start NODE --use X``), so its outputs get
        their columns, label, truth and panel as the spec's do."""
        for st in status.values():
            for name, m in (st.get("measures") or {}).items():
                use = m.get("use") if isinstance(m, Mapping) else None
                if name not in self.classes and isinstance(use, str):
                    with contextlib.suppress(LookupError, TypeError):
                        self.classes[name] = find_measure(use)

    def _read_launcher(self) -> dict[str, dict[str, Any]]:
        if self._launcher_state is not None:
            return dict(self._launcher_state())
        if self.run_dir is None:
            return {}
        try:
            return json.loads((self.run_dir / "launcher.json").read_text())["nodes"]
        except (OSError, ValueError, KeyError):
            return {}

    # -- the page's answer ----------------------------------------------------------------
    def cluster(self) -> dict[str, Any]:
        """Nodes (state, pid, restarts, measures), sync groups, problems and events."""
        with self._lock:
            status, launcher = dict(self.status), dict(self.launcher)
            events = sorted(self.events, key=lambda e: e["t"])[-50:]
        alive = set(self.peers.up)
        nodes = []
        for n in self.spec.nodes:
            st, la = status.get(n.name), launcher.get(n.name, {})
            if n.name in alive:
                state = "up" if st else "starting"
                if st and st.get("escalated"):
                    state = "escalated"
            else:
                state = la.get("state") if la.get("state") in ("restarting", "failed") else "down"
            measures = (st or {}).get("measures", {})
            nodes.append(
                {
                    "name": n.name,
                    "state": state,
                    "pid": (st or {}).get("pid", la.get("pid")),
                    "restarts": la.get("restarts", 0),
                    "measures": {
                        k: {
                            "state": m.get("state"),
                            "restarts": m.get("restarts", 0),
                            "rate_hz": m.get("rate_hz", 0.0),
                        }
                        for k, m in sorted(measures.items())
                    },
                    "rate_hz": round(sum(m.get("rate_hz", 0.0) for m in measures.values()), 1),
                    "rejected": sum((st or {}).get("rejected", {}).values()),
                    "peers": len([p for p in (st or {}).get("peers", []) if p != n.name]),
                    "rss_mb": (st or {}).get("rss_mb"),
                }
            )
        return {
            "name": self.spec.name,
            "uptime_s": round(time.time() - self.started, 1),
            "nodes": nodes,
            "sync": sync_rows(status),
            "problems": problem_rows(status),
            "events": events,
            "rejected_by_view": self.rejected,
        }

    def streams(self) -> list[dict[str, Any]]:
        """Every stream seen: its columns, whether it is a model's output, its label and
        the columns its application's truth has."""
        out = []
        now_rate = self._rates()
        for stream in self.buffers.streams():
            name, node = stream.split("/", 1)
            cls = self.classes.get(name)
            latest = self.latest.get(stream)
            cols = _columns(cls, len(latest[1]) if latest else 0)
            truth = self._truth_of(cls)
            out.append(
                {
                    "stream": stream,
                    "name": name,
                    "node": node,
                    "columns": cols,
                    "model": bool(cls is not None and issubclass(cls, FusionMeasure)),
                    "label": self.index.label(name, cls),
                    "truth": [c for c in cols if truth is not None and c in truth.columns],
                    "rate_hz": now_rate.get(stream, 0.0),
                }
            )
        return out

    def _rates(self) -> dict[str, float]:
        """Samples per second of each stream over the last 2 s of complete buckets, up to
        now (a stream that stopped falls to 0 within 2 s; it kept its last rate)."""
        out = {}
        span = 2.0
        now = time.time()
        for stream in self.buffers.streams():
            newest = self.buffers.newest(stream)
            if newest is None:
                continue
            end = max(newest, now)  # a sender's clock a little ahead: its newest bucket
            got = self.buffers.since(stream, end - span - self.buffers.bucket_s)
            complete = got[:-1]
            out[stream] = round(sum(p[2] for _, p in complete) / span, 1) if complete else 0.0
        return out

    def _truth_of(self, cls: type | None) -> Truth | None:
        app = self.index.app_of(cls)
        if app is None:
            return None
        if app.name not in self.truths:
            try:
                self.truths[app.name] = app.truth(self.spec.world)
            except Exception as e:  # an application's bug must not take the view down
                log.warning("truth of %s failed: %s", app.name, e)
                self.truths[app.name] = None
        return self.truths[app.name]

    def data(self, streams: Iterable[str], since: float) -> dict[str, Any]:
        """The buckets of ``streams`` from ``since`` (epoch s; the page sends the time of
        the last bucket it holds), with the truth at each bucket's time for the columns
        that have one: ``{stream: {"points": [[index, t, n, means, mins, maxs, truth?],
        ...]}}`` (see :meth:`hera.console.buffers.Bucket.point`)."""
        out = {}
        for stream in streams:
            got = self.buffers.since(stream, since)
            if not got:
                continue
            name = stream.split("/", 1)[0]
            cls = self.classes.get(name)
            truth = self._truth_of(cls)
            points = []
            for i, (bucket, point) in enumerate(got):
                if truth is not None:
                    last = i == len(got) - 1
                    if bucket.truth is None or last:
                        cols = _columns(cls, len(point[3]))
                        values = _truth_at(truth, point[1], cols, point[3])
                        if not last:
                            bucket.truth = values
                    else:
                        values = bucket.truth
                    point.append(values)
                points.append(point)
            out[stream] = {"points": points}
        return out

    def panels(self) -> list[dict[str, Any]]:
        """Each application's web panel for the latest estimates of its measures."""
        by_app: dict[str, tuple[Application, list[Estimate]]] = {}
        for stream, (t, values) in sorted(list(self.latest.items())):
            name, node = stream.split("/", 1)
            cls = self.classes.get(name)
            app = self.index.app_of(cls)
            if app is None:
                continue
            cols = _columns(cls, len(values))
            est = Estimate(name, node, t, dict(zip(cols, values, strict=True)), cls)
            by_app.setdefault(app.name, (app, []))[1].append(est)
        out = []
        for app, estimates in by_app.values():
            try:
                panel = app.web_panel(estimates, self._truth_of(estimates[0].measure))
            except Exception as e:  # an application's bug must not take the view down
                log.warning("web panel of application %s failed", app.name, exc_info=True)
                out.append(
                    {
                        "title": f"{app.name}: panel failed ({type(e).__name__}: {e})",
                        "kind": "error",
                    }
                )
                continue
            if panel is not None:
                out.append({"title": panel.title, "kind": panel.kind, "data": panel.data})
        return out

    def poll(self, streams: Iterable[str], since: float | None) -> dict[str, Any]:
        """All the page needs: cluster, streams, data of ``streams`` since ``since`` (the
        last :data:`WINDOW_S` s when None) and the panels."""
        now = time.time()
        start = now - WINDOW_S if since is None else since
        return {
            "time": now,
            "bucket_s": self.buffers.bucket_s,
            "cluster": self._cached("cluster", CACHE_S, self.cluster),
            "streams": self._cached("streams", CACHE_S, self.streams),
            "data": self.data(streams, start),
            "panels": self._cached("panels", self.buffers.bucket_s, self.panels),
        }

    def _cached(self, key: str, ttl: float, make: Callable[[], Any]) -> Any:
        """``make()``, reused for ``ttl`` s (pages poll more often than these change)."""
        now = time.monotonic()
        held = self._cache.get(key)
        if held is None or now - held[0] > ttl:
            held = self._cache[key] = (now, make())
        return held[1]

    def close(self) -> None:
        """Stop the status thread and leave the bus."""
        self._stop.set()
        self._thread.join(2.0)
        for sub in self._subs:
            with contextlib.suppress(Exception):
                sub.undeclare()
        self.client.close()


def _truth_at(truth: Truth, t: float, columns: list[str], means: list[float]) -> list[float | None]:
    """The truth at ``t`` in the order of ``columns`` (None where it has none), each of its
    ``sign_free`` groups turned to the side of the estimate's ``means`` (a quaternion and
    its negative are one attitude: their difference column by column is not an error)."""
    try:
        at = truth.at(t)
    except Exception:  # outside the simulated world's time, say
        return [None] * len(columns)
    out = [None if c not in at else float(f"{at[c]:.7g}") for c in columns]
    for group in getattr(truth, "sign_free", ()):
        idx = [columns.index(c) for c in group if c in columns]
        whole = len(idx) == len(group) and all(out[i] is not None for i in idx)
        if whole and sum(means[i] * out[i] for i in idx) < 0.0:  # type: ignore[operator]
            for i in idx:
                out[i] = -out[i]  # type: ignore[operator]
    return out


def _describe(event: Mapping[str, Any]) -> str:
    """One line for a control event: the verb, what it asked and how it went."""
    request = event.get("request") or {}
    what = " ".join(f"{k}={v}" for k, v in sorted(request.items()) if k != "value")
    if "value" in request:
        what += f" value={json.dumps(request['value'])[:40]}"
    outcome = "" if event.get("ok") else f" refused: {event.get('error')}"
    return f"{event.get('verb')} {what}".strip() + outcome
