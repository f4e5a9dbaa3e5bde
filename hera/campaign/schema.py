"""The campaign file: declared settings (:mod:`hera.schema`), parsed and checked whole.

A campaign file (TOML; ``deploy/campaigns/*.toml`` ship with the package) has:

- ``[campaign]``: its name and timing (baselines, gaps, how long the cluster may take to
  settle);
- ``[[faults]]``: a scripted schedule, run in order, each fault followed by a quiet gap;
- ``[nemesis]``: a randomised schedule (kinds with weights, parameter ranges per kind in
  ``[nemesis.<kind>]``), drawn from the campaign's seed;
- ``[checks]``, ``[checks.estimates]``, ``[checks.agreement]``: the checkers' settings;
- ``[[figures]]``: figures to report beside the thesis's and judge against targets;
- ``[short]``: what ``--short`` changes (a few faults, shorter periods: the tests run it).

Every problem of a file is reported at once, one sentence each naming the file, the table
and the key (:class:`CampaignError`, exit code 2), before anything starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hera.keys import MAX_CHUNK, check_chunk
from hera.schema import (
    BOOL,
    REQUIRED,
    STR,
    TABLE,
    Kind,
    Setting,
    Table,
    choice,
    list_of,
    number,
)
from hera.spec import tomllib

KINDS = (
    "crash",
    "hang",
    "kill",
    "crash_node",
    "pause",
    "board",
    "partition",
    "loss",
    "delay",
    "reset",
    "skew",
)
"""Fault kinds: a measure's ``crash`` or ``hang`` (control plane), a node's ``kill``
(SIGKILL), ``crash_node`` (the node exits on request) or ``pause`` (SIGSTOP for
``duration_s``), a ``board`` fault (the simulator's board verb), the network faults
``partition``, ``loss``, ``delay`` and ``reset`` (link proxy or nftables), and a host's clock
``skew``."""
NETWORK = ("partition", "loss", "delay", "reset")
NEEDS_DURATION = ("pause", "board", "partition", "loss", "delay", "skew")
INSTANT = ("crash", "hang", "kill", "crash_node")
CHECKERS = (
    "schedule",
    "overlaps",
    "stale_firings",
    "sync_partitions",
    "gaps",
    "sequences",
    "args",
    "recovery",
    "estimates",
    "agreement",
    "restarts",
    "figures",
    "leftovers",
)
FIGURES = ("detect", "recover", "flow", "gap", "restart")


class CampaignError(ValueError):
    """A campaign file that cannot run; ``problems`` holds one sentence each."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


NUM = number()
POS = number(minimum=0)
NAMES = list_of(STR, "a list of names")
GROUPS = list_of(list_of(STR, "a list of names"), "a list of lists of names")


def _range(v: Any) -> tuple[float, float]:
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return (float(v), float(v))
    if (
        isinstance(v, (list, tuple))
        and len(v) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        and v[0] <= v[1]
    ):
        return (float(v[0]), float(v[1]))
    raise ValueError("must be a number or [low, high] with low <= high")


RANGE = Kind("a number or [low, high]", _range)

CAMPAIGN_TABLE = Table(
    "[campaign]",
    [
        Setting("name", STR, REQUIRED, "the campaign's name (the run directory's prefix)"),
        Setting("title", STR, "", "one line saying what it does"),
        Setting("baseline_s", POS, 20.0, "quiet time before the first fault, s"),
        Setting("tail_s", POS, 15.0, "quiet time after the last fault, s"),
        Setting("gap_s", POS, 8.0, "quiet time after each scripted fault, s"),
        Setting("settle_s", number(above=0), 60.0, "longest wait for every stream to flow, s"),
        Setting(
            "hold_s",
            POS,
            0.0,
            "after the schedule, keep the cluster up this long (faults by "
            "hand with hera inject; Ctrl-C ends it), s",
        ),
        Setting(
            "links",
            BOOL,
            False,
            "put the link proxy in front of every node even without network faults",
        ),
    ],
)

FAULT_TABLE = Table(
    "[[faults]]",
    [
        Setting("name", STR, None, "a label (default: kind and target)"),
        Setting("kind", choice(*KINDS), REQUIRED, "what to do"),
        Setting(
            "target",
            STR,
            None,
            "a node, `leader:<group>`, `follower:<group>`, `host:<group>`, `random`",
        ),
        Setting("measure", STR, None, "crash, hang: the measure"),
        Setting("board", STR, None, "board: the board id (`<node>/<board>`)"),
        Setting("fault", STR, None, "board: the board fault (stuck, dropout, spikes, ...)"),
        Setting("params", TABLE, {}, "board: the fault's parameters (value, prob, sensor)"),
        Setting("duration_s", POS, 0.0, "how long it lasts, s (0: instantaneous)"),
        Setting("gap_s", POS, None, "quiet time after it, s (default: [campaign] gap_s)"),
        Setting("groups", GROUPS, None, "partition: the sides (nodes or roles; `others`)"),
        Setting("peers", NAMES, None, "loss, delay, reset: only the links to these nodes"),
        Setting("loss", number(0, 0.95), 0.0, "loss: the share of chunks lost once (0..0.95)"),
        Setting("delay_ms", POS, 0.0, "delay: one-way delay, ms"),
        Setting("jitter_ms", POS, 0.0, "delay: +/- this much, ms"),
        Setting("skew_s", number(-3600, 3600), 0.0, "skew: the clock's offset, s"),
        Setting("when", choice("now", "firing"), "now", "`firing`: strike while a slot is held"),
        Setting("flap_on_s", POS, 0.0, "partition: cut this long, then ..."),
        Setting("flap_off_s", POS, 0.0, "... healed this long, repeatedly"),
    ],
)

NEMESIS_TABLE = Table(
    "[nemesis]",
    [
        Setting("duration_s", number(above=0), REQUIRED, "how long faults are drawn, s"),
        Setting("mean_gap_s", number(above=0), 8.0, "mean quiet time between faults, s"),
        Setting("min_gap_s", POS, 3.0, "shortest quiet time between faults, s"),
        Setting("kinds", TABLE, REQUIRED, "fault kind -> weight"),
        Setting("targets", NAMES, None, "nodes a fault may hit (default: every node)"),
        Setting("measures", NAMES, None, "crash, hang: `<node>/<measure>` candidates"),
        Setting("boards", NAMES, None, "board: board ids the faults may hit"),
        Setting("board_faults", NAMES, ["stuck", "dropout", "spikes"], "board: the kinds drawn"),
    ],
)
NEMESIS_KINDS = {
    "pause": ("duration_s",),
    "board": ("duration_s",),
    "partition": ("duration_s",),
    "loss": ("duration_s", "loss"),
    "delay": ("duration_s", "delay_ms", "jitter_ms"),
    "reset": ("duration_s",),
    "skew": ("duration_s", "skew_s"),
    "kill": ("when",),
    "crash": (),
    "hang": (),
    "crash_node": (),
}
"""The keys a ``[nemesis.<kind>]`` table may give (each a number or [low, high])."""

CHECKS_TABLE = Table(
    "[checks]",
    [
        Setting(
            "skip",
            list_of(choice(*CHECKERS), "a list of checker names"),
            [],
            "checkers not to run (they are reported as skipped, never as passed)",
        ),
        Setting(
            "max_gap_periods",
            number(above=1),
            8.0,
            "outside faults, a stream's gap may be this many periods ...",
        ),
        Setting(
            "gap_floor_s",
            POS,
            0.5,
            "... or this long, or 1.5 x its longest baseline gap (3 x for a bursty stream)",
        ),
        Setting("recovery_s", POS, 5.0, "time after a fault before quiet-time checks apply, s"),
        Setting(
            "recover_within_s",
            number(above=0),
            15.0,
            "every fault's streams flow again within this, s",
        ),
        Setting(
            "failover_s",
            number(above=0),
            1.5,
            "a partition's majority side fires again within this, s",
        ),
        Setting(
            "resume_within_s",
            number(above=0),
            2.0,
            "the minority side fires again within this of the healing, s",
        ),
    ],
)
ESTIMATES_TABLE = Table(
    "[checks.estimates]",
    [
        Setting("models", NAMES, [], "models judged (default: none)"),
        Setting("metric", STR, None, "the application's metric judged (default: its first)"),
        Setting("factor", number(above=0), 3.0, "after a fault: error <= factor x baseline ..."),
        Setting("floor", POS, 0.0, "... or this floor (the metric's unit)"),
        Setting("settle_s", POS, 5.0, "time after a fault before its after-window, s"),
        Setting("after_s", number(above=0), 10.0, "length of a fault's after-window, s"),
        Setting("window_s", number(above=0), 2.0, "timeline error window, s"),
    ],
)
AGREEMENT_TABLE = Table(
    "[checks.agreement]",
    [
        Setting("models", NAMES, [], "models compared across the nodes that run them"),
        Setting("columns", TABLE, {}, "column (or `model:column`) -> largest allowed difference"),
        Setting("quantile", number(0.5, 1.0), 0.95, "share of matched estimates that must agree"),
        Setting("settle_s", POS, 10.0, "time after a fault before estimates are compared, s"),
        Setting(
            "max_silence_s",
            number(above=0),
            5.0,
            "longest time one node is silent while another publishes, s",
        ),
    ],
)
FIGURE_TABLE = Table(
    "[[figures]]",
    [
        Setting("label", STR, REQUIRED, "what the figure is"),
        Setting("faults", NAMES, REQUIRED, "the faults it is measured on: kinds or names"),
        Setting("figure", choice(*FIGURES), REQUIRED, "detect, recover, flow, gap or restart"),
        Setting("target_s", number(above=0), None, "the most it may be, s (none: reported)"),
        Setting("thesis", STR, "", "the thesis's figure (chapter 5)"),
    ],
)
SHORT_TABLE = Table(
    "[short]",
    [
        Setting("baseline_s", POS, None, "--short: [campaign] baseline_s"),
        Setting("tail_s", POS, None, "--short: [campaign] tail_s"),
        Setting("gap_s", POS, None, "--short: [campaign] gap_s"),
        Setting("duration_s", number(above=0), None, "--short: [nemesis] duration_s"),
        Setting("faults", NAMES, None, "--short: only these [[faults]] (by name)"),
    ],
)
TOP = ("campaign", "faults", "nemesis", "checks", "figures", "short")


@dataclass(frozen=True)
class Fault:
    """One scripted fault (a ``[[faults]]`` entry), settings by name."""

    kind: str
    name: str
    settings: dict[str, Any] = field(default_factory=dict)

    def get(self, key: str, default: Any = None) -> Any:
        v = self.settings.get(key)
        return default if v is None else v


@dataclass(frozen=True)
class Campaign:
    """A parsed campaign file."""

    source: str
    name: str
    title: str
    baseline_s: float
    tail_s: float
    gap_s: float
    settle_s: float
    hold_s: float
    links: bool
    faults: tuple[Fault, ...]
    nemesis: dict[str, Any] | None
    checks: dict[str, Any]
    estimates: dict[str, Any]
    agreement: dict[str, Any]
    figures: tuple[dict[str, Any], ...]
    short: dict[str, Any]

    def shortened(self) -> Campaign:
        """The ``--short`` version (the ``[short]`` table applied)."""
        s = self.short
        faults = self.faults
        if s.get("faults") is not None:
            keep = set(s["faults"])
            faults = tuple(f for f in faults if f.name in keep)
        nemesis = self.nemesis
        if nemesis is not None and s.get("duration_s") is not None:
            nemesis = {**nemesis, "duration_s": s["duration_s"]}
        pick = lambda k: self.__dict__[k] if s.get(k) is None else s[k]  # noqa: E731
        return replace(
            self,
            baseline_s=pick("baseline_s"),
            tail_s=pick("tail_s"),
            gap_s=pick("gap_s"),
            faults=faults,
            nemesis=nemesis,
        )

    @property
    def network(self) -> bool:
        """Whether the cluster must run behind the link proxy."""
        kinds = {f.kind for f in self.faults}
        if self.nemesis is not None:
            kinds |= {k for k, w in self.nemesis["kinds"].items() if w > 0}
        return self.links or bool(kinds & set(NETWORK))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able (the run directory keeps it)."""
        return {
            "source": self.source,
            "name": self.name,
            "title": self.title,
            "baseline_s": self.baseline_s,
            "tail_s": self.tail_s,
            "gap_s": self.gap_s,
            "settle_s": self.settle_s,
            "hold_s": self.hold_s,
            "links": self.links,
            "faults": [{"kind": f.kind, "name": f.name, **f.settings} for f in self.faults],
            "nemesis": self.nemesis,
            "checks": self.checks,
            "estimates": self.estimates,
            "agreement": self.agreement,
            "figures": list(self.figures),
        }


def _fault_problems(f: dict[str, Any], where: str) -> list[str]:
    """What a ``[[faults]]`` entry of its kind lacks or has too much of."""
    kind = f.get("kind")
    out = []
    need = {
        "crash": ("target", "measure"),
        "hang": ("target", "measure"),
        "kill": ("target",),
        "crash_node": ("target",),
        "pause": ("target",),
        "board": ("board", "fault"),
        "partition": ("groups",),
        "loss": ("target",),
        "delay": ("target",),
        "reset": ("target",),
        "skew": ("target",),
    }.get(kind, ())
    for key in need:
        if f.get(key) is None:
            out.append(f"{where}: kind {kind!r} needs {key!r}")
    if kind in NEEDS_DURATION and not f.get("duration_s"):
        out.append(f"{where}: kind {kind!r} needs duration_s > 0")
    if kind == "loss" and not f.get("loss"):
        out.append(f"{where}: kind 'loss' needs loss > 0")
    if kind == "delay" and not (f.get("delay_ms") or f.get("jitter_ms")):
        out.append(f"{where}: kind 'delay' needs delay_ms or jitter_ms > 0")
    if kind == "skew" and not f.get("skew_s"):
        out.append(f"{where}: kind 'skew' needs skew_s != 0")
    if f.get("when") == "firing" and kind != "kill":
        out.append(f"{where}: when = 'firing' is for kind 'kill' only")
    if bool(f.get("flap_on_s")) != bool(f.get("flap_off_s")):
        out.append(f"{where}: give both flap_on_s and flap_off_s, or neither")
    if (f.get("flap_on_s") or f.get("flap_off_s")) and kind != "partition":
        out.append(f"{where}: flap_on_s/flap_off_s are for kind 'partition' only")
    if f.get("groups") is not None and len(f["groups"]) < 2:
        out.append(f"{where}: groups needs at least two sides")
    return out


def _nemesis(raw: Any, where: str, problems: list[str]) -> dict[str, Any] | None:
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        problems.append(f"{where}: must be a table")
        return None
    plain = {k: v for k, v in raw.items() if k not in NEMESIS_KINDS}
    out = NEMESIS_TABLE.parse(plain, where, problems)
    kinds = out.get("kinds", {})
    for k, w in kinds.items():
        if k not in NEMESIS_KINDS:
            problems.append(f"{where}: kinds: unknown fault kind {k!r}; kinds: {', '.join(KINDS)}")
        elif isinstance(w, bool) or not isinstance(w, (int, float)) or w < 0:
            problems.append(f"{where}: kinds: weight of {k!r} must be a number >= 0, got {w!r}")
    if kinds and not any(isinstance(w, (int, float)) and w > 0 for w in kinds.values()):
        problems.append(f"{where}: kinds: at least one weight must be > 0")
    board_w = kinds.get("board")
    if isinstance(board_w, (int, float)) and board_w > 0 and not out.get("boards"):
        problems.append(f"{where}: kinds: 'board' is drawn, so give boards (board ids)")
    ranges: dict[str, dict[str, Any]] = {}
    for kind, keys in NEMESIS_KINDS.items():
        table = raw.get(kind)
        if table is None:
            continue
        here = f"{where[:-1]}.{kind}]"
        if not isinstance(table, Mapping):
            problems.append(f"{here}: must be a table")
            continue
        settings = [Setting(k, RANGE, None, k) for k in keys if k != "when"]
        if "when" in keys:
            settings.append(Setting("when", choice("now", "firing"), None, "when"))
        ranges[kind] = Table(here, settings).parse(table, here, problems, defaults=False)
    out["ranges"] = ranges
    return out


def parse_campaign(data: Mapping[str, Any], source: str = "<campaign>") -> Campaign:
    """A :class:`Campaign` from a parsed TOML document; :class:`CampaignError` listing
    every problem otherwise."""
    problems: list[str] = []
    for key in data:
        if key not in TOP:
            problems.append(f"{source}: unknown table {key!r}; known tables: {', '.join(TOP)}")
    camp = CAMPAIGN_TABLE.parse(data.get("campaign"), f"{source}: [campaign]", problems)
    if isinstance(camp.get("name"), str):
        try:
            check_chunk(camp["name"], "name")
        except ValueError:
            problems.append(
                f"{source}: [campaign]: name must use only letters, digits, '_', '.' and '-' "
                f"(it names the run directory), at most {MAX_CHUNK} of them, got {camp['name']!r}"
            )
    faults = []
    raw_faults = data.get("faults", [])
    if not isinstance(raw_faults, list):
        problems.append(f"{source}: [[faults]] must be a list of tables")
        raw_faults = []
    names: list[str] = []
    for i, raw in enumerate(raw_faults, start=1):
        label = raw.get("name") if isinstance(raw, Mapping) else None
        where = f"{source}: [[faults]] #{i}" + (f" ({label})" if isinstance(label, str) else "")
        f = FAULT_TABLE.parse(raw, where, problems, defaults=False)
        if "kind" not in f:
            continue
        problems.extend(_fault_problems(f, where))
        name = f.pop("name", None) or f"{f['kind']} {f.get('target') or f.get('board') or ''}"
        name = name.strip()
        if name in names:
            problems.append(f"{where}: two faults are called {name!r}")
        names.append(name)
        faults.append(Fault(f.pop("kind"), name, f))
    nemesis = _nemesis(data.get("nemesis"), f"{source}: [nemesis]", problems)
    if not raw_faults and "nemesis" not in data and not camp.get("hold_s"):
        problems.append(f"{source}: a campaign needs [[faults]], a [nemesis] or hold_s > 0")
    raw_checks = data.get("checks", {})
    if not isinstance(raw_checks, Mapping):
        problems.append(f"{source}: [checks] must be a table")
        raw_checks = {}
    plain = {k: v for k, v in raw_checks.items() if k not in ("estimates", "agreement")}
    checks = CHECKS_TABLE.parse(plain, f"{source}: [checks]", problems)
    estimates = ESTIMATES_TABLE.parse(
        raw_checks.get("estimates"), f"{source}: [checks.estimates]", problems
    )
    agreement = AGREEMENT_TABLE.parse(
        raw_checks.get("agreement"), f"{source}: [checks.agreement]", problems
    )
    for col, tol in agreement.get("columns", {}).items():
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or tol <= 0:
            problems.append(
                f"{source}: [checks.agreement]: columns: tolerance of {col!r} must be a "
                f"number > 0, got {tol!r}"
            )
    figures = []
    raw_figures = data.get("figures", [])
    if not isinstance(raw_figures, list):
        problems.append(f"{source}: [[figures]] must be a list of tables")
        raw_figures = []
    for i, raw in enumerate(raw_figures, start=1):
        figures.append(FIGURE_TABLE.parse(raw, f"{source}: [[figures]] #{i}", problems))
    short = SHORT_TABLE.parse(data.get("short"), f"{source}: [short]", problems, defaults=False)
    unknown = [n for n in short.get("faults") or () if n not in names]
    if unknown:
        problems.append(
            f"{source}: [short]: faults names unknown fault {unknown[0]!r}; faults: "
            + ", ".join(names)
        )
    if problems:
        raise CampaignError(problems)
    return Campaign(
        source=source,
        faults=tuple(faults),
        nemesis=nemesis,
        checks=checks,
        estimates=estimates,
        agreement=agreement,
        figures=tuple(figures),
        short=short,
        **camp,
    )


def load_campaign(path: str | Path) -> Campaign:
    """Read a campaign file; :class:`CampaignError` on any problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise CampaignError([f"cannot read campaign {path}: {e.strerror}"]) from None
    except UnicodeDecodeError:
        raise CampaignError([f"{path}: not a text file (a campaign is TOML)"]) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CampaignError([f"{path}: invalid TOML: {e}"]) from None
    return parse_campaign(data, str(path))


def campaigns() -> dict[str, Path]:
    """The campaigns shipped with the package (``hera.deploy``'s ``campaigns`` folder)."""
    from importlib import resources

    folder = resources.files("hera.deploy") / "campaigns"
    out = {}
    if folder.is_dir():
        for entry in sorted(folder.iterdir(), key=lambda e: e.name):
            if entry.name.endswith(".toml"):
                out[entry.name[: -len(".toml")]] = Path(str(entry))
    return out


def resolve_campaign(arg: str) -> Path:
    """The campaign file ``arg`` names: a path, else a shipped campaign's name."""
    path = Path(arg)
    if path.exists():
        return path
    known = campaigns()
    if arg in known:
        return known[arg]
    raise CampaignError(
        [
            f"no campaign file {arg!r} and no shipped campaign of that name "
            f"(campaigns: {', '.join(known) or 'none'})"
        ]
    )


def reference() -> str:
    """The Markdown reference of every table of a campaign file (README "Fault campaigns")."""
    parts = []
    for title, table in (
        ("`[campaign]`", CAMPAIGN_TABLE),
        ("`[[faults]]`", FAULT_TABLE),
        ("`[nemesis]` (and `[nemesis.<kind>]`: the ranges of a kind's settings)", NEMESIS_TABLE),
        ("`[checks]`", CHECKS_TABLE),
        ("`[checks.estimates]`", ESTIMATES_TABLE),
        ("`[checks.agreement]`", AGREEMENT_TABLE),
        ("`[[figures]]`", FIGURE_TABLE),
        ("`[short]`", SHORT_TABLE),
    ):
        parts.append(f"{title}\n\n{table.markdown()}")
    return "\n\n".join(parts)
