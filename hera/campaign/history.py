"""What a campaign run recorded, read back for the checkers and the report.

A campaign directory holds:

- ``campaign.json``: the campaign as run (settings, seed, spec source, the times the run
  started, settled, began and ended its schedule, and stopped; the offset between the wall
  clock and the sync clock; the fire logs and their sync groups);
- ``plan.json``: the schedule (:mod:`hera.campaign.plan`); ``faults.jsonl``: what was
  done and when (:mod:`hera.campaign.journal`);
- ``observed/``: the bus as the campaign saw it (:mod:`hera.campaign.recorder`);
- ``audit/fire-<node>-<measure>.log``: the real trigger times of every firing of a
  measure that audits them (a measure declaring a ``fire_log`` argument, e.g. the simulated
  sonar): ``start end node epoch token deadline`` on the sync clock, read onto the wall
  clock through ``clock.csv`` (both clocks sampled together, :mod:`hera.campaign.clockmap`)
  and the journal's pairs;
- ``run/``: the cluster's own run directory (``hera up``: logs, CSVs, persisted state);
- ``final.json``: every node's args and status just before the stop; ``leftovers.json``:
  processes of the run still alive after it stopped; ``launcher.out``: ``hera up``'s output.

:func:`load` reads them into a :class:`History`; every reader is tolerant of what a fault
may leave behind (a torn last line, a node that never logged).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from hera.campaign import clockmap, journal
from hera.campaign.plan import Planned
from hera.campaign.recorder import FOLDER as OBSERVED
from hera.spec import ClusterSpec, load_spec

RUN = "run"
AUDIT = "audit"
META = "campaign.json"
PLAN = "plan.json"
FINAL = "final.json"
LEFTOVERS = "leftovers.json"
LAUNCHER_OUT = "launcher.out"


@dataclass
class Stream:
    """The samples of one (name, node) as recorded: arrival (wall s), run (the producer's
    incarnation, numbered in the order first seen), seq, measurement time t (s, producer's
    clock) and values, in arrival order."""

    name: str
    node: str
    arrival: np.ndarray
    run: np.ndarray
    seq: np.ndarray
    t: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.arrival)

    @property
    def key(self) -> tuple[str, str]:
        return (self.name, self.node)

    def between(self, lo: float, hi: float) -> np.ndarray:
        """Arrival times within [lo, hi)."""
        a = self.arrival
        return a[(a >= lo) & (a < hi)]


@dataclass(frozen=True)
class Firing:
    """One sound: ``start`` to ``end`` (wall s), by ``node``'s ``measure`` of ``group``,
    under grant (``epoch``, ``token``) whose lease ended at ``deadline`` (wall s); the grant
    fields are None for an unsynchronised firing. ``clock_start`` and ``clock_end``: the
    same on the sync clock the fire log was written on (None if unknown). The fire logs of
    one machine share that clock, so firings are ordered there exactly; on the wall clock
    each firing is placed through its own offset, interpolated between samples of the two
    clocks read one after the other, whose jitter (a thread descheduled between the two
    reads) can move two firings a millisecond apart past each other."""

    start: float
    end: float
    node: str
    measure: str
    group: str
    epoch: int | None = None
    token: int | None = None
    deadline: float | None = None
    clock_start: float | None = None
    clock_end: float | None = None


@dataclass(frozen=True)
class LogEvent:
    """A line of a node's log that matters to the checkers: ``kind`` one of ``peer_up``,
    ``peer_down`` (``subject``: the peer), ``crashed``, ``hung``, ``restarted``
    (``subject``: the measure), ``escalated``, ``node_up``, ``crash_node`` (an injected
    exit, 50 ms before the process ends); ``node``: who logged it."""

    t: float
    node: str
    kind: str
    subject: str
    text: str


@dataclass
class FaultRecord:
    """A planned fault and what happened: when it struck (``start``) and was undone
    (``end``), the nodes and pairs it hit, any error."""

    planned: Planned
    start: float | None = None
    end: float | None = None
    nodes: list[str] = field(default_factory=list)
    pairs: list[list[str]] = field(default_factory=list)
    groups: list[list[str]] = field(default_factory=list)
    error: str | None = None
    end_error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    flaps: list[tuple[float, str]] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.planned.name

    @property
    def kind(self) -> str:
        return self.planned.kind

    @property
    def done(self) -> bool:
        return self.start is not None

    def cuts(self) -> list[tuple[float, float]]:
        """The spans a partition was in force: one for a plain partition, one per cut of a
        flapping one (from the journal's ``flap`` events)."""
        if self.start is None:
            return []
        end = self.until or self.start
        if not self.flaps:
            return [(self.start, end)]
        out, cut = [], None
        for t, state in self.flaps:
            if state == "cut":
                cut = t
            elif cut is not None:
                out.append((cut, t))
                cut = None
        if cut is not None:
            out.append((cut, end))
        return out

    @property
    def until(self) -> float | None:
        """When the fault stopped acting (its end, or its start if instantaneous)."""
        if self.start is None:
            return None
        return self.end if self.end is not None else self.start


@dataclass
class History:
    """Everything a campaign run recorded (see the module docstring)."""

    folder: Path
    meta: dict[str, Any]
    spec: ClusterSpec
    plan: list[Planned]
    faults: list[FaultRecord]
    manual: list[dict[str, Any]]
    streams: dict[tuple[str, str], Stream]
    alive: list[tuple[float, str, str]]
    log: list[LogEvent]
    firings: list[Firing]
    args_seen: list[dict[str, Any]]
    final: dict[str, Any]
    persisted: dict[str, dict[str, Any]]
    leftovers: list[dict[str, Any]]
    pauses: list[tuple[float, float, float]] = field(default_factory=list)
    """(wall from, wall to, seconds) the machine stood still (:func:`clockmap.pauses`)."""

    @property
    def run_dir(self) -> Path:
        return self.folder / RUN

    def time(self, key: str) -> float | None:
        return self.meta.get("times", {}).get(key)

    def windows(self, after: float = 0.0) -> list[tuple[float, float]]:
        """The time each fault acted, and each pause of the machine, plus ``after`` s (its
        aftermath), merged."""
        spans = sorted(
            (f.start, (f.until or f.start) + after) for f in self.faults if f.start is not None
        )
        spans += sorted((m["t"], m["t"] + after + m.get("duration", 0.0)) for m in self.manual)
        spans += [(lo, hi + after) for lo, hi, _ in self.pauses]  # the machine stood still
        spans.sort()
        out: list[tuple[float, float]] = []
        for lo, hi in spans:
            if out and lo <= out[-1][1]:
                out[-1] = (out[-1][0], max(out[-1][1], hi))
            else:
                out.append((lo, hi))
        return out

    def baseline(self) -> tuple[float, float] | None:
        """The quiet period before the first fault (settled to schedule start)."""
        lo, hi = self.time("settled"), self.time("schedule_start")
        if lo is None or hi is None or hi <= lo:
            return None
        first = min((f.start for f in self.faults if f.start is not None), default=hi)
        return (lo, min(hi, first))

    def group_of(self) -> dict[str, list[str]]:
        return self.spec.sync_groups()


# -- readers --------------------------------------------------------------------------------


def _json(path: Path, default: Any) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return default


def read_stream(path: Path, name: str, node: str) -> Stream:
    """One ``observed/<name>@<node>.csv`` (a torn or bad row is skipped)."""
    rows = []
    width = None
    for line in path.read_text().splitlines():
        parts = line.split(",")
        try:
            row = [float(x) for x in parts]
        except ValueError:
            continue
        if len(row) < 4:
            continue
        if width is None:
            width = len(row)
        if len(row) == width:
            rows.append(row)
    a = np.array(rows, dtype=float).reshape(len(rows), width or 4)
    return Stream(
        name, node, a[:, 0], a[:, 1].astype(np.int64), a[:, 2].astype(np.int64), a[:, 3], a[:, 4:]
    )


def read_streams(folder: Path) -> dict[tuple[str, str], Stream]:
    out = {}
    for path in sorted((Path(folder) / OBSERVED).glob("*@*.csv")):
        name, _, node = path.stem.partition("@")
        out[(name, node)] = read_stream(path, name, node)
    return out


def read_alive(folder: Path) -> list[tuple[float, str, str]]:
    out = []
    path = Path(folder) / OBSERVED / "alive.csv"
    if path.exists():
        for line in path.read_text().splitlines():
            parts = line.split(",")
            if len(parts) == 3:
                try:
                    out.append((float(parts[0]), parts[1], parts[2]))
                except ValueError:
                    continue
    return out


def read_args_seen(folder: Path) -> list[dict[str, Any]]:
    out = []
    path = Path(folder) / OBSERVED / "args.jsonl"
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
    return out


LINE = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) (\S+) (\S+) (\w+) (.*)$")
PATTERNS = (
    ("peer_up", "hera.peers", re.compile(r"^peer (\S+) up$")),
    ("peer_down", "hera.peers", re.compile(r"^peer (\S+) down$")),
    ("crashed", "hera.worker", re.compile(r"^measure (\S+) crashed: ")),
    ("hung", "hera.supervisor", re.compile(r"^measure (\S+) hung: ")),
    ("restarted", "hera.supervisor", re.compile(r"^restarted (\S+) \(")),
    ("escalated", "hera.node", re.compile(r"^node (\S+) escalates: ")),
    ("node_up", "hera.node", re.compile(r"^node (\S+) up on ")),
    ("crash_node", "hera.control", re.compile(r"^crash of node (\S+) injected$")),
)


LOG_RESOLUTION_S = 0.001  # a log line's stamp is its time cut to the millisecond


def parse_log_line(line: str) -> LogEvent | None:
    """The :class:`LogEvent` of one node log line, or None if it is not one."""
    m = LINE.match(line)
    if m is None:
        return None
    stamp, node, logger, _level, text = m.groups()
    for kind, name, pattern in PATTERNS:
        if logger != name:
            continue
        hit = pattern.match(text)
        if hit:
            t = datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S,%f").timestamp()
            return LogEvent(t, node, kind, hit.group(1), text)
    return None


def read_logs(run_dir: Path) -> list[LogEvent]:
    out = []
    for path in sorted((Path(run_dir) / "logs").glob("*.log")):
        for line in path.read_text(errors="replace").splitlines():
            e = parse_log_line(line)
            if e is not None:
                out.append(e)
    out.sort(key=lambda e: e.t)
    return out


def parse_fire_line(
    line: str, measure: str, group: str, to_wall: Callable[[float], float]
) -> Firing | None:
    """One fire-log line (sync clock) as a :class:`Firing` on the wall clock (``to_wall``:
    :func:`hera.campaign.clockmap.sync_to_wall`)."""
    parts = line.split()
    if len(parts) not in (3, 6):
        return None
    try:
        clock_start, clock_end = float(parts[0]), float(parts[1])
        offset = to_wall(clock_start) - clock_start  # one offset per firing: its length kept
        start, end = clock_start + offset, clock_end + offset
        if len(parts) == 6 and parts[3] != "-":
            epoch, token = int(parts[3]), int(parts[4])
            deadline = float(parts[5]) + offset
        else:
            epoch = token = deadline = None
    except ValueError:
        return None
    return Firing(
        start, end, parts[2], measure, group, epoch, token, deadline, clock_start, clock_end
    )


def read_firings(
    folder: Path, fire_logs: dict[str, dict[str, str]], to_wall: Callable[[float], float]
) -> list[Firing]:
    """Every firing of the audit logs (``fire_logs``: file name -> node, measure, group), on
    the wall clock through ``to_wall``."""
    out = []
    for fname, info in fire_logs.items():
        path = Path(folder) / AUDIT / fname
        if not path.exists():
            continue
        for line in path.read_text().splitlines():
            f = parse_fire_line(line, info["measure"], info["group"], to_wall)
            if f is not None:
                out.append(f)
    out.sort(key=lambda f: f.start)
    return out


def fault_records(plan: Iterable[Planned], events: list[dict[str, Any]]) -> list[FaultRecord]:
    """The planned faults with the journal's start, end and error events."""
    recs = {p.index: FaultRecord(p) for p in plan}
    for e in events:
        r = recs.get(e.get("index", -1))
        if r is None:
            continue
        if e["event"] == "start":
            r.start = e["t"]
            r.nodes = list(e.get("nodes") or [])
            r.pairs = list(e.get("pairs") or [])
            r.groups = list(e.get("groups") or [])
            r.extra.update({k: e[k] for k in ("firing_log",) if k in e})
        elif e["event"] == "end":
            r.end = e["t"]
            r.end_error = e.get("error")
            if "flaps" in e:
                r.extra["flaps"] = e["flaps"]
        elif e["event"] == "error":
            r.error = e.get("error")
        elif e["event"] == "flap":
            r.flaps.append((e["t"], e.get("state")))
    return [recs[i] for i in sorted(recs)]


def read_persisted(state_dir: Path) -> dict[str, dict[str, Any]]:
    """Each node's persisted args (``<state_dir>/<node>/args.msgpack``)."""
    import msgpack

    out = {}
    for path in sorted(Path(state_dir).glob("*/args.msgpack")):
        try:
            out[path.parent.name] = msgpack.unpackb(path.read_bytes(), raw=False)
        except Exception:
            out[path.parent.name] = {}
    return out


def load(folder: str | Path) -> History:
    """Read a campaign directory (see the module docstring); ValueError if it is none."""
    folder = Path(folder)
    meta = _json(folder / META, None)
    if meta is None:
        raise ValueError(f"{folder}: no {META}; is it the directory of a hera campaign?")
    spec = load_spec(folder / "spec.json")
    plan = [Planned.from_dict(d) for d in _json(folder / PLAN, [])]
    events = journal.read(folder)
    manual = [e for e in events if e.get("index") == -1 and e["event"] == "start"]
    anchors = clockmap.read_anchors(folder)
    pairs = anchors + [(e["t"], e["clock"]) for e in events if "t" in e and "clock" in e]
    to_wall = clockmap.sync_to_wall(pairs, float(meta.get("clock_offset", 0.0)))
    return History(
        folder=folder,
        meta=meta,
        spec=spec,
        plan=plan,
        faults=fault_records(plan, events),
        manual=manual,
        streams=read_streams(folder),
        alive=read_alive(folder),
        log=read_logs(folder / RUN),
        firings=read_firings(folder, meta.get("fire_logs", {}), to_wall),
        args_seen=read_args_seen(folder),
        final=_json(folder / FINAL, {}),
        persisted=read_persisted(meta.get("state_dir") or folder / RUN / "state"),
        leftovers=_json(folder / LEFTOVERS, []),
        pauses=clockmap.pauses(anchors),
    )
