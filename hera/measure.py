"""The ``hera_measure`` behaviour: what a measure module gives and what the runtime promises.

A measure is a class derived from :class:`Measure`. The runtime creates it with no
arguments, calls :meth:`Measure.init` once with the arguments of the cluster spec and a
:class:`MeasureContext`, then calls :meth:`Measure.measure` on an absolute schedule
(deadline k = start + k * period, so the loop never drifts) and publishes what it returns.
Sensor readers, filters and fusion models are all measures.

If a measure raises, it is restarted by its supervisor: a **new** instance gets the very
same arguments it was first created with. A calibration computed during ``init`` should be
stored in the replicated args store (``ctx.args``) and looked up there first, so it is not
redone while the system runs.

Changes at run time (``hera args``, ``hera reload``):

- a measure's own replicated keys are ``calib/<node>/<measure>`` (its calibration) and
  ``measure/<node>/<measure>/<arg>`` (run-time values of its arguments, see
  :func:`own_keys`). When one of them changes, the worker calls
  :meth:`Measure.args_changed` before the measure's next step; by default the measure is
  re-created in place (``close``, a new instance, ``init`` with the spec's arguments and
  the run-time ones), so deleting ``calib/<node>/<measure>`` re-runs a calibration that
  ``init`` does when none is stored, and a changed argument takes effect at once;
- a hot reload (:mod:`hera.reload`) replaces a running measure by one of the new code and
  hands it the old one's attributes through :meth:`Measure.code_change`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from hera.schema import (
    BOOL,
    REQUIRED,
    TABLE,
    Table,
    choice,
    either,
    number,
    setting,
    table_of,
    text,
)

if TYPE_CHECKING:  # pragma: no cover - imports for type checkers only
    import zenoh

    from hera.args import ArgsStore
    from hera.keys import Keys
    from hera.store import Store

from hera.resources import Resources

RESTART_TYPES = ("permanent", "transient", "temporary")
CALIB_PREFIX = "calib"
"""``calib/<node>/<measure>``: where a measure keeps its calibration in the args store."""
ARGS_PREFIX = "measure"
"""``measure/<node>/<measure>/<arg>``: run-time values of a measure's arguments."""


def own_keys(node: str, measure: str) -> tuple[str, str]:
    """The args-store keys a measure follows: its calibration key and the prefix of its
    run-time arguments (``calib/<node>/<measure>``, ``measure/<node>/<measure>/``)."""
    return f"{CALIB_PREFIX}/{node}/{measure}", f"{ARGS_PREFIX}/{node}/{measure}/"


def runtime_args(items: Mapping[str, Any], node: str, measure: str) -> dict[str, Any]:
    """The run-time arguments of ``measure`` on ``node`` among args-store ``items``."""
    prefix = own_keys(node, measure)[1]
    return {k[len(prefix) :]: v for k, v in items.items() if k.startswith(prefix)}


def _measure_ref(use: str) -> None:
    if not use or use.count(":") > 1 or use.startswith(":") or use.endswith(":"):
        raise ValueError("must be an installed measure name or 'package.module:Class'")


def _chunk(what: str):
    def check(value: str) -> None:
        from hera.keys import check_chunk

        try:
            check_chunk(value.replace("{i}", "1"), what)  # {i}: the copy's number (count)
        except ValueError:
            raise ValueError(
                "must use only letters, digits, '_', '.' and '-' (no '/', '*', '$')"
            ) from None

    return check


@dataclass(frozen=True, slots=True)
class Reading:
    """Values returned by a measure with an explicit measurement time.

    ``t`` is epoch seconds on the producer's clock; None means "now, when the step began".
    A plain sequence of numbers returned by :meth:`Measure.measure` is the same as
    ``Reading(values)``.
    """

    values: Sequence[float]
    t: float | None = None


def readings_of(
    result: Sequence[float] | Reading | list[Reading] | None, t: float | None = None
) -> list[Reading]:
    """The readings one step of :meth:`Measure.measure` returned, in order: none for None
    or an empty list, each of a list of :class:`Reading`, else the one (a plain sequence of
    numbers is ``Reading(values, t)``; a reading's ``t`` may be None: "when the step
    began")."""
    if result is None:
        return []
    if isinstance(result, Reading):
        return [result]
    if isinstance(result, list) and (not result or isinstance(result[0], Reading)):
        return list(result)
    return [Reading(result, t)]


class NotReady(Exception):
    """Raised by a measure's ``init`` when something it needs is not there yet (a board that
    does not answer): ``str()`` says what, in a few words.

    Not a crash: the worker keeps the measure waiting, sets its ``trouble`` to that, and calls
    ``init`` again on a fresh instance every :data:`hera.worker.NOT_READY_RETRY_S`, until it
    starts or is stopped. The supervisor's restart intensity is not spent, so a sensor missing
    when its node starts does not crash-loop the node down with its other measures.
    """


class MeasureSpecError(ValueError):
    """A measure's settings break a rule: ``str()`` is "measure 'NAME': SENTENCE";
    ``sentence`` alone, for a caller that names the measure its own way."""

    def __init__(self, where: str, sentence: str) -> None:
        super().__init__(f"{where}: {sentence}")
        self.sentence = sentence


@dataclass(frozen=True)
class MeasureSpec:
    """One measure worker of a node: the spec's ``[[nodes.measures]]``/``[[measures]]`` entry.

    Each field is declared once here (kind, default, meaning); the spec parser, its error
    messages and the README's reference table all come from these declarations
    (:data:`MEASURE_TABLE`). ``None`` means "the measure class's own default":
    :meth:`resolve` fills those in from the class before the worker starts.
    """

    use: str = setting(
        REQUIRED,
        text(_measure_ref, "a measure name"),
        "entry point of group `hera.measures`, or `package.module:Class`",
    )
    name: str | None = setting(
        None,
        text(_chunk("name"), "a name"),
        "publication name, the `<name>` of `data/<name>/<node>` (default: the `use`)",
    )
    period: float | None = setting(
        None, number(above=0), "seconds between deadlines (absolute schedule); default: the class's"
    )
    offset: float | None = setting(
        None,
        number(minimum=0),
        "seconds after each multiple of the period on the wall clock (epoch time) at which the "
        "steps fall (clocks in step: one host, or NTP): measures of one period and offset wake "
        "together on every node, different offsets take turns; default 0 (sync measures: "
        "their slots)",
    )
    thread: str = setting(
        "own",
        choice("own", "shared"),
        "`own`: the measure steps in a thread of its own; `shared`: its node's one thread for "
        "the shared measures of its period and offset steps it with them (one wake for all, "
        "less CPU; a step that blocks holds up the others of that deadline, see hera.beat); "
        "not for sync measures",
    )
    iterations: int | str | None = setting(
        None,
        either(number(minimum=1, integer=True), choice("forever")),
        "number of steps, or `forever`; default: the class's",
    )
    sync: bool | None = setting(
        None, BOOL, "ask the sync service for a slot before each step; default: the class's"
    )
    sync_group: str | None = setting(
        None, text(_chunk("group name"), "a group name"), "sync group (default: the name)"
    )
    slot: float | None = setting(
        None, number(above=0), "seconds a synchronised step needs; default: the class's"
    )
    restart: str = setting(
        "transient",
        choice(*RESTART_TYPES),
        "`permanent` (always restarted), `transient` (after an abnormal end) or `temporary`",
    )
    hang_factor: float = setting(
        10.0, number(above=1), "a step longer than this many periods (and `hang_min`) is hung"
    )
    hang_min: float = setting(1.0, number(minimum=0), "seconds a step may always take")
    seed: int = setting(0, number(integer=True), "deterministic seed of this measure")
    args: dict[str, Any] = setting(
        {}, TABLE, "the measure's arguments, reused verbatim by every restart"
    )

    def __post_init__(self) -> None:
        where = f"measure {self.name or self.use!r}"
        for s in MEASURE_TABLE.settings:
            value = getattr(self, s.target)
            if value is None or value is REQUIRED:
                continue
            try:
                s.kind.convert(value)
            except ValueError as e:
                raise MeasureSpecError(where, f"{s.key} {e}, got {value!r}") from None
        if self.thread == "shared" and self.sync:
            raise MeasureSpecError(
                where, 'thread = "shared" is for unsynchronised measures (sync = true)'
            )
        if self.offset is not None:
            if self.sync:
                raise MeasureSpecError(where, "offset is for unsynchronised measures (sync = true)")
            if self.period is not None and self.offset >= self.period:
                raise MeasureSpecError(
                    where,
                    f"offset must be below the period ({self.period:g} s), got {self.offset!r}",
                )

    @property
    def group(self) -> str:
        """The sync group: ``sync_group`` if given, else the measure name."""
        return self.sync_group or str(self.name)

    @property
    def steps(self) -> int | None:
        """Steps to run, None for ever."""
        return None if self.iterations in (None, "forever") else int(self.iterations)

    def resolve(self, cls: type[Measure]) -> MeasureSpec:
        """A copy with every "class default" filled in from measure class ``cls``."""
        return replace(
            self,
            name=self.name if self.name is not None else default_name(self.use),
            period=self.period if self.period is not None else float(cls.period),
            iterations=(
                self.iterations
                if self.iterations is not None
                else (cls.iterations if cls.iterations is not None else "forever")
            ),
            sync=self.sync if self.sync is not None else bool(cls.sync),
            slot=self.slot if self.slot is not None else float(cls.slot),
        )


def default_name(use: str) -> str:
    """The publication name of a measure declared without one: its ``use``, lowercased
    (the class name for ``package.module:Class``)."""
    return use.rsplit(":", 1)[-1].lower()


MEASURE_TABLE = table_of(MeasureSpec, "measure")
"""The declared settings of one measure (see :class:`MeasureSpec`)."""


class SlotGrant(Protocol):
    """A time slot granted by the sync service (see ``hera.sync``)."""

    epoch: int
    token: int
    duration: float


class SlotClient(Protocol):
    """What a synchronised worker needs from the sync service."""

    def acquire(self, group: str, holder: str, duration: float, timeout: float) -> Any:
        """Block until a slot is granted (returns a grant) or ``timeout`` s pass (None)."""

    def release(self, grant: Any, used: bool) -> None:
        """Give the slot back, saying whether it was used."""


@dataclass
class MeasureContext:
    """What the runtime hands a measure: where it runs and the services it may use.

    - ``node``, ``cluster``: names of this node and its cluster;
    - ``spec``: the :class:`MeasureSpec` the worker runs with;
    - ``store``: the node's latest-value store (read other measures' samples);
    - ``args``: the replicated args store (calibrations, shared parameters);
    - ``session``/``keys``: the node's Zenoh session and key builder (for ``sim`` keys);
    - ``world``: the spec's ``[world]`` table (scenario, shared epoch ...), read only;
    - ``counters``: measure-specific counters shown in the node status (e.g. cross-talk);
    - ``trouble``: what is wrong with the measure right now, in a few words (its board does
      not answer), or None; shown in the node status and on the live view's problems line
      while it is set, so a measure that goes on through a fault is still seen;
    - ``grant``: while a synchronised step runs, the grant it runs under, else None;
    - ``seed``: a deterministic seed for this (node, measure), from the spec;
    - ``run_dir``: the run directory (for recordings), or None;
    - ``state_dir``: this node's own state directory (it outlives the node's process: args,
      incarnation, checkpoints), or None;
    - ``resources``: objects the node's measures share (boards, a simulated medium), closed
      with the node; each node (or test) has its own.
    """

    node: str
    cluster: str
    spec: MeasureSpec
    store: Store
    args: ArgsStore
    session: zenoh.Session | None
    keys: Keys
    world: Mapping[str, Any] = field(default_factory=dict)
    counters: MutableMapping[str, float] = field(default_factory=dict)
    trouble: str | None = None
    grant: Any = None
    seed: int = 0
    run_dir: str | None = None
    state_dir: str | None = None
    resources: Resources = field(default_factory=lambda: Resources())
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("hera.measure"))

    def count(self, counter: str, n: float = 1) -> None:
        """Add ``n`` to a measure-specific status counter."""
        self.counters[counter] = self.counters.get(counter, 0) + n


class Measure:
    """Base class of the ``hera_measure`` behaviour.

    Class attributes give the defaults of the spec; the cluster spec may override them.
    ``columns`` names the values (with units in brackets, e.g. ``"range [m]"``), for the
    CSV sidecar and the status screen.
    """

    name: ClassVar[str] = ""
    period: ClassVar[float] = 0.1
    iterations: ClassVar[int | None] = None
    sync: ClassVar[bool] = False
    slot: ClassVar[float] = 0.05
    columns: ClassVar[tuple[str, ...]] = ()
    inputs: ClassVar[tuple[str, ...] | None] = None
    """The publication names this measure reads from the store (``"prefix*"``: every name
    starting with prefix; ``"name/node"``: one sender's only); ``()`` for none. None (the
    default): it may read anything, and its node takes every sample of the cluster. See
    :meth:`reads`."""
    version: ClassVar[str] = ""
    """The version of this measure's code, handed to :meth:`code_change` of its successor
    after a hot reload."""
    arguments: ClassVar[Table | None] = None
    """The ``args`` this measure takes (a :class:`hera.schema.Table`). When declared, a spec
    giving an unknown or ill-typed argument is refused before any node starts, and
    :meth:`init` receives the arguments converted, with the defaults filled in."""

    ctx: MeasureContext

    @classmethod
    def reads(cls, args: Mapping[str, Any]) -> tuple[str, ...] | None:
        """The names this measure, with these ``args``, reads from the store (see
        :attr:`inputs`, which it returns unless overridden): its node subscribes to those
        only, so a store holds what its measures need and no more."""
        return cls.inputs

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        """Every problem with ``args`` (one sentence each, starting with ``where``); empty
        when they are fine or the measure declares no :attr:`arguments`."""
        problems: list[str] = []
        if cls.arguments is not None:
            cls.arguments.parse(args, where, problems)
        return problems

    @classmethod
    def prepare_args(cls, args: Mapping[str, Any]) -> Mapping[str, Any]:
        """What :meth:`init` receives: ``args`` converted and completed with the declared
        defaults (raises :class:`hera.schema.SchemaError`), or ``args`` as given when the
        measure declares no :attr:`arguments`."""
        if cls.arguments is None:
            return args
        return cls.arguments.parse(args, f"measure {cls.__name__} args")

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        """Prepare the measure from its arguments; raise to refuse them (clear message), or
        :class:`NotReady` to be tried again later."""
        self.ctx = ctx

    def measure(self) -> Sequence[float] | Reading | list[Reading] | None:
        """Take one step: return the values to publish, a list of :class:`Reading` (several
        samples made in one step, published in that order), or None for "nothing this
        time"."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what ``init`` acquired; called when the worker ends or is replaced."""

    def args_changed(self, changes: Mapping[str, Any]) -> bool:
        """Some of this measure's own args-store keys changed (see the module docstring):
        ``changes`` maps each key to its new value (None when deleted). Called by the
        worker before the next step, on the worker's thread. Return True when the measure
        has applied the change itself; the default returns False and the worker re-creates
        the measure in place from its spec arguments merged with the run-time ones."""
        return False

    def code_change(self, old_version: str, state: Mapping[str, Any]) -> None:
        """After a hot reload, on the new code's instance (``init`` done, before its first
        step): ``state`` is the replaced instance's attributes (its ``vars()``),
        ``old_version`` its class's :attr:`version`. Adopt what applies; raising rolls the
        reload back. The default keeps the fresh state, as after a restart."""
