"""Synthetic campaign directories: what a run would have recorded, written by hand, so that
each checker can be shown to pass on a clean history and to fail on a planted fault.

Imported by tests as ``campaign_synth`` (pytest puts tests/support on sys.path). The files
are written in the formats the campaign writes (``hera.campaign.history``), and read back
with :func:`hera.campaign.history.load`: the readers are tested along the way. Times are
epoch seconds from :data:`T0`; the sync clock offset is 0 (fire logs hold wall times).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import msgpack

from hera.campaign import history
from hera.campaign.plan import Planned
from hera.campaign.schema import parse_campaign
from hera.spec import parse_spec

T0 = 1_800_000_000.0

SPEC = {
    "cluster": {"name": "synth", "sync_lease_ms": 300},
    "world": {
        "scenario": "train",
        "radius": 0.6,
        "omega": 0.84,
        "center": [0.0, 0.0],
        "epoch": T0 - 100.0,
    },
    "nodes": [
        {"name": "a", "sync_hosts": ["sonar"], "measures": [{"use": "sonar"}]},
        {"name": "b", "sync_hosts": ["sonar"], "measures": [{"use": "sonar"}]},
        {"name": "c", "sync_hosts": ["sonar"]},
    ],
    "measures": [
        {"on": ["b", "c"], "use": "track_gyro", "period": 0.05, "args": {"model": {"radius": 0.6}}},
    ],
}


class Synth:
    """A campaign directory under construction (see the module docstring)."""

    def __init__(
        self,
        folder: Path,
        campaign: dict[str, Any] | None = None,
        spec: dict[str, Any] | None = None,
        settled: float = 10.0,
        schedule: float = 30.0,
        stopped: float = 120.0,
    ) -> None:
        self.dir = Path(folder)
        for sub in ("observed", "audit", "run/logs", "run/state"):
            (self.dir / sub).mkdir(parents=True, exist_ok=True)
        camp = campaign or {
            "campaign": {"name": "synth"},
            "faults": [{"kind": "kill", "target": "a", "name": "kill a"}],
        }
        self.campaign = parse_campaign(camp, "synth.toml")
        self.spec = parse_spec(spec or SPEC, "synth spec").with_ports([7001, 7002, 7003])
        (self.dir / "spec.json").write_text(self.spec.to_json())
        self.times = {
            "started": T0,
            "settled": T0 + settled,
            "schedule_start": T0 + schedule,
            "schedule_end": T0 + stopped - 15,
            "snapshot": T0 + stopped - 2.5,
            "stopped": T0 + stopped,
        }
        self.plan: list[Planned] = []
        self.fire_logs: dict[str, dict[str, str]] = {}
        self.meta: dict[str, Any] = {}
        self.final: dict[str, Any] = {"args": {}, "status": {}}
        self.leftovers: list[dict[str, Any]] = []

    # -- recordings ---------------------------------------------------------------------
    def stream(self, name: str, node: str, times, values=None, seqs=None, runs=None) -> None:
        """Samples of (name, node) arriving at ``T0 + times`` (measurement time = arrival),
        of incarnation ``runs`` (numbers in the order first seen; default all 0)."""
        times = list(times)
        seqs = list(seqs) if seqs is not None else list(range(1, len(times) + 1))
        runs = list(runs) if runs is not None else [0] * len(times)
        rows = []
        for i, t in enumerate(times):
            v = values(T0 + t) if callable(values) else (values[i] if values else [0.0])
            rows.append(f"{T0 + t:.6f},{runs[i]},{seqs[i]},{T0 + t!r},{','.join(map(repr, v))}")
        path = self.dir / "observed" / f"{name}@{node}.csv"
        with open(path, "a") as f:
            f.write("\n".join(rows) + "\n")

    def firings(self, node: str, spans, grants=None, measure: str = "sonar") -> None:
        """Firings of ``node`` over ``spans`` [(start, end)], with optional grants
        [(epoch, token, deadline)] (all times from T0)."""
        fname = f"fire-{node}-{measure}.log"
        self.fire_logs[fname] = {"node": node, "measure": measure, "group": "sonar"}
        lines = []
        for i, (s, e) in enumerate(spans):
            if grants is None:
                g = "- - -"
            else:
                ep, tok, dl = grants[i]
                g = f"{ep} {tok} {T0 + dl:.6f}"
            lines.append(f"{T0 + s:.6f} {T0 + e:.6f} {node} {g}")
        with open(self.dir / "audit" / fname, "a") as f:
            f.write("\n".join(lines) + "\n")

    def log(self, node: str, t: float, logger: str, text: str, level: str = "INFO") -> None:
        """A line of ``node``'s log at ``T0 + t``."""
        when = T0 + t
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(when))
        ms = int((when % 1) * 1000)  # cut, as logging stamps its lines
        with open(self.dir / "run" / "logs" / f"{node}.log", "a") as f:
            f.write(f"{stamp},{ms:03d} {node} {logger} {level} {text}\n")

    def fault(
        self,
        kind: str,
        at: float,
        duration: float = 0.0,
        nodes=(),
        pairs=(),
        groups=(),
        error: str | None = None,
        undone: bool = True,
        **settings: Any,
    ) -> None:
        """A fault planned at ``T0 + at`` (from T0, not from the schedule) and journaled."""
        i = len(self.plan)
        name = settings.pop("name", f"{kind} {i}")
        p = Planned(i, name, kind, at, duration, settings)
        self.plan.append(p)
        events = []
        if error:
            events.append({"event": "error", "index": i, "t": T0 + at, "error": error})
        else:
            events.append(
                {
                    "event": "start",
                    "index": i,
                    "t": T0 + at,
                    "nodes": list(nodes),
                    "pairs": [list(x) for x in pairs],
                    "groups": [list(g) for g in groups],
                }
            )
            if undone and duration:
                events.append({"event": "end", "index": i, "t": T0 + at + duration})
        with open(self.dir / "faults.jsonl", "a") as f:
            for e in events:
                f.write(json.dumps({**e, "clock": e["t"]}) + "\n")

    def args_write(self, t: float, key: str, ts: int, origin: str, value: Any) -> None:
        with open(self.dir / "observed" / "args.jsonl", "a") as f:
            f.write(
                json.dumps({"t": T0 + t, "key": key, "ts": ts, "origin": origin, "value": value})
                + "\n"
            )

    def persist(self, node: str, entries: dict[str, tuple[int, str, Any]]) -> None:
        d = self.dir / "run" / "state" / node
        d.mkdir(parents=True, exist_ok=True)
        (d / "args.msgpack").write_bytes(
            msgpack.packb({k: list(v) for k, v in entries.items()}, use_bin_type=True)
        )

    # -- reading back -------------------------------------------------------------------
    def load(self) -> history.History:
        meta = {
            "campaign": self.campaign.as_dict(),
            "seed": 1,
            "cluster": "synth",
            "times": self.times,
            "clock_offset": 0.0,
            "fire_logs": self.fire_logs,
            **self.meta,
        }
        (self.dir / history.META).write_text(json.dumps(meta))
        (self.dir / history.PLAN).write_text(json.dumps([p.as_dict() for p in self.plan]))
        (self.dir / history.FINAL).write_text(json.dumps(self.final))
        (self.dir / history.LEFTOVERS).write_text(json.dumps(self.leftovers))
        return history.load(self.dir)


def steady(lo: float, hi: float, period: float) -> list[float]:
    """Times from ``lo`` to ``hi`` every ``period`` s."""
    n = int(round((hi - lo) / period))
    return [lo + k * period for k in range(n)]
