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
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

if TYPE_CHECKING:  # pragma: no cover - imports for type checkers only
    import zenoh

    from hera.args import ArgsStore
    from hera.keys import Keys
    from hera.store import Store

RESTART_TYPES = ("permanent", "transient", "temporary")


@dataclass(frozen=True, slots=True)
class Reading:
    """Values returned by a measure with an explicit measurement time.

    ``t`` is epoch seconds on the producer's clock; None means "now, when the step began".
    A plain sequence of numbers returned by :meth:`Measure.measure` is the same as
    ``Reading(values)``.
    """

    values: Sequence[float]
    t: float | None = None


@dataclass(frozen=True)
class MeasureSpec:
    """How the runtime runs one measure worker (from class defaults plus the cluster spec).

    - ``name``: publication name, the ``<name>`` of ``hera/<cluster>/data/<name>/<node>``;
    - ``period``: seconds between two deadlines (> 0);
    - ``iterations``: number of steps, or None to run forever;
    - ``sync``: ask the sync service of ``sync_group`` for a slot before each step;
    - ``slot``: seconds a synchronised step needs (the slot length asked for);
    - ``restart``: ``transient`` (the default, as the original's measures: restarted only
      after an abnormal end), ``permanent`` (always restarted) or ``temporary`` (never);
    - ``hang_factor``: a step running longer than ``hang_factor * period`` (and at least
      ``hang_min`` seconds) is reported hung and the worker replaced;
    - ``log``: write the CSV log of this measure's samples.
    """

    name: str
    period: float
    iterations: int | None = None
    sync: bool = False
    sync_group: str | None = None
    slot: float = 0.05
    restart: str = "transient"
    hang_factor: float = 10.0
    hang_min: float = 1.0
    log: bool = False

    def __post_init__(self) -> None:
        from hera.keys import check_chunk

        check_chunk(self.name, "measure name")
        if not (isinstance(self.period, (int, float)) and self.period > 0):
            raise ValueError(f"measure {self.name!r}: period must be > 0 s, got {self.period!r}")
        if self.iterations is not None and (
            not isinstance(self.iterations, int) or self.iterations < 1
        ):
            raise ValueError(
                f"measure {self.name!r}: iterations must be a positive integer or 'forever', "
                f"got {self.iterations!r}"
            )
        if self.restart not in RESTART_TYPES:
            raise ValueError(
                f"measure {self.name!r}: restart must be one of {RESTART_TYPES}, "
                f"got {self.restart!r}"
            )
        if not self.slot > 0:
            raise ValueError(f"measure {self.name!r}: slot must be > 0 s, got {self.slot!r}")
        if not self.hang_factor > 1:
            raise ValueError(f"measure {self.name!r}: hang_factor must be > 1")

    @property
    def group(self) -> str:
        """The sync group: ``sync_group`` if given, else the measure name."""
        return self.sync_group or self.name


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
    - ``grant``: while a synchronised step runs, the grant it runs under, else None;
    - ``seed``: a deterministic seed for this (node, measure), from the spec;
    - ``run_dir``: the run directory (for recordings), or None.
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
    grant: Any = None
    seed: int = 0
    run_dir: str | None = None
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

    ctx: MeasureContext

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        """Prepare the measure from its arguments; raise to refuse them (clear message)."""
        self.ctx = ctx

    def measure(self) -> Sequence[float] | Reading | None:
        """Take one step: return the values to publish, or None for "nothing this time"."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what ``init`` acquired; called when the worker ends or is replaced."""
