"""The schedule of a campaign: when each fault starts, how long it lasts, what it hits.

:func:`make_plan` is a pure function of the campaign, the cluster spec and the seed: the
same three always give the same plan (``plan.json`` in the run directory; ``hera campaign
... --seed N`` repeats a run's schedule). Scripted faults run in order, each followed by its
quiet gap; a nemesis draws faults at random (kind by weight, target among the nodes, each
parameter uniformly within its range, the gaps exponentially with the given mean) until its
duration is used up. Faults never overlap: one ends, a quiet gap follows, the next starts.

Targets that depend on the cluster's state (``leader:<group>``, ``follower:<group>``) are
resolved when the fault strikes (:mod:`hera.campaign.targets`), with a random generator
derived from the seed and the fault's index, so that a re-run makes the same choices in the
same situations.
"""

from __future__ import annotations

import random
from dataclasses import asdict, dataclass, field
from typing import Any

from hera.campaign.schema import INSTANT, Campaign
from hera.spec import ClusterSpec


@dataclass(frozen=True)
class Planned:
    """One fault of the schedule: ``at`` s after the schedule starts, lasting ``duration``
    s (0: instantaneous), with its settings (the ``[[faults]]`` keys)."""

    index: int
    name: str
    kind: str
    at: float
    duration: float
    settings: dict[str, Any] = field(default_factory=dict)

    def get(self, key: str, default: Any = None) -> Any:
        v = self.settings.get(key)
        return default if v is None else v

    @property
    def end(self) -> float:
        return self.at + self.duration

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Planned:
        return cls(d["index"], d["name"], d["kind"], d["at"], d["duration"], d["settings"])


def fault_rng(seed: int, index: int) -> random.Random:
    """The random generator of fault ``index``'s run-time choices."""
    return random.Random(f"{seed}/{index}")


def scripted(campaign: Campaign) -> list[Planned]:
    """The ``[[faults]]`` schedule: in order, each followed by its gap."""
    out, t = [], 0.0
    for i, f in enumerate(campaign.faults):
        duration = float(f.get("duration_s", 0.0))
        out.append(Planned(i, f.name, f.kind, round(t, 3), duration, dict(f.settings)))
        t += duration + float(f.get("gap_s", campaign.gap_s))
    return out


def _draw(rng: random.Random, rng_range: tuple[float, float] | Any) -> Any:
    if isinstance(rng_range, tuple):
        lo, hi = rng_range
        return round(rng.uniform(lo, hi), 3)
    return rng_range


DEFAULTS = {
    "pause": {"duration_s": (1.0, 4.0)},
    "board": {"duration_s": (2.0, 6.0)},
    "partition": {"duration_s": (2.0, 8.0)},
    "loss": {"duration_s": (3.0, 10.0), "loss": (0.05, 0.3)},
    "delay": {"duration_s": (3.0, 10.0), "delay_ms": (10.0, 100.0), "jitter_ms": (0.0, 20.0)},
    "reset": {"duration_s": (0.5, 2.0)},
    "skew": {"duration_s": (3.0, 10.0), "skew_s": (-0.5, 0.5)},
    "kill": {"when": "now"},
}
"""Parameter ranges of nemesis faults when ``[nemesis.<kind>]`` does not give them."""


def _partition_groups(rng: random.Random, nodes: list[str]) -> list[list[str]]:
    """A random cut: one node alone against the rest, or two random halves."""
    shuffled = nodes[:]
    rng.shuffle(shuffled)
    if len(nodes) < 4 or rng.random() < 0.5:
        return [[shuffled[0]], sorted(shuffled[1:])]
    k = len(nodes) // 2
    return [sorted(shuffled[:k]), sorted(shuffled[k:])]


def nemesis(campaign: Campaign, spec: ClusterSpec, seed: int) -> list[Planned]:
    """The randomised schedule of ``[nemesis]`` (see the module docstring)."""
    cfg = campaign.nemesis
    assert cfg is not None
    rng = random.Random(seed)
    nodes = list(cfg.get("targets") or [n.name for n in spec.nodes])
    kinds = sorted(k for k, w in cfg["kinds"].items() if w > 0)
    weights = [float(cfg["kinds"][k]) for k in kinds]
    measures = list(cfg.get("measures") or [f"{n}/{m.name}" for n, m in spec.measures()])
    boards = list(cfg.get("boards") or [])
    out: list[Planned] = []
    t = 0.0
    while True:
        mean = cfg["mean_gap_s"]
        gap = max(cfg["min_gap_s"], min(rng.expovariate(1.0 / mean), 3 * mean))
        kind = rng.choices(kinds, weights)[0]
        ranges = {**DEFAULTS.get(kind, {}), **cfg["ranges"].get(kind, {})}
        s: dict[str, Any] = {k: _draw(rng, v) for k, v in ranges.items()}
        duration = 0.0 if kind in INSTANT else float(s.pop("duration_s", 1.0))
        s.pop("duration_s", None)
        target = rng.choice(nodes)
        if kind in ("crash", "hang"):
            node, _, measure = rng.choice(measures).partition("/")
            s.update(target=node, measure=measure)
        elif kind == "board":
            board = rng.choice(boards)  # the schema asks for boards when board is drawn
            s.update(board=board, fault=rng.choice(cfg["board_faults"]))
        elif kind == "partition":
            s["groups"] = _partition_groups(rng, nodes)
        else:
            s["target"] = target
        if t + gap + duration > cfg["duration_s"]:
            break
        t += gap
        what = s.get("target") or s.get("board") or "|".join(",".join(g) for g in s["groups"])
        name = f"#{len(out) + 1} {kind} {what}"
        out.append(Planned(len(out), name, kind, round(t, 3), duration, s))
        t += duration
    return out


def make_plan(campaign: Campaign, spec: ClusterSpec, seed: int) -> list[Planned]:
    """The whole schedule: the scripted faults, then the nemesis's."""
    plan = scripted(campaign)
    if campaign.nemesis is not None:
        start = plan[-1].end + campaign.gap_s if plan else 0.0
        for p in nemesis(campaign, spec, seed):
            plan.append(
                Planned(len(plan), p.name, p.kind, round(start + p.at, 3), p.duration, p.settings)
            )
    return plan
