"""The application interface: what an application tells the runtime, and nothing more.

An *application* bundles what one use of the framework needs beyond the runtime: its
measures and fusion models, the truth of its simulated world, how to score a run, its plots,
its rows of the live panel of ``hera up``, its view on the web page (:class:`WebPanel`), and
any control verbs it adds. The train ladder is one; a user's own package can be another.
The runtime finds applications through the entry-point group ``hera.apps`` and asks them
through this interface only; it never names one.

Write one by subclassing :class:`Application`: set :attr:`~Application.name` and
:attr:`~Application.measures`, and override the methods that apply (every one is optional,
the defaults say "nothing to add"). Register it in your package's ``pyproject.toml``::

    [project.entry-points."hera.apps"]
    thermo = "mypkg.app:ThermoApp"

The measures themselves stay ``hera.measures`` entry points; :attr:`Application.measures`
names the ones that belong to the application (aliases included or not: the runtime
compares the classes they load). The README's "Write your own application" has a complete
example.

Data the runtime hands an application:

- a :class:`Series`: one model output of a run (times and values per column), read from the
  run's CSV logs or a replay;
- an :class:`Estimate`: the latest estimate of a model on a node (live panel);
- the world table of the spec (``[world]``) for :meth:`Application.truth`, or, for a run
  without one (a real rig), its recordings for :meth:`Application.reference`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from hera.resources import Resources

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np  # imported where used: a node that evaluates nothing never loads it


@dataclass(frozen=True)
class Metric:
    """One column of ``hera eval``'s table: ``key`` in the scores, ``label`` and ``unit``
    for the header (e.g. ``Metric("pos_rmse_cm", "pos RMSE", "cm")``)."""

    key: str
    label: str
    unit: str = ""

    @property
    def header(self) -> str:
        return f"{self.label} {self.unit}".strip()


class Truth(Protocol):
    """The true value of named quantities at any time of a simulated run. A truth may also
    have ``sign_free``: groups of its columns that name one quantity up to its sign (a unit
    quaternion's four: q and -q are one rotation); a display turns such a group of the truth
    to the estimate's side before it differences them (the live view does)."""

    columns: tuple[str, ...]

    def at(self, t: float) -> Mapping[str, float]:
        """The true value of each column at epoch time ``t`` (s); a column may be absent
        when it has no meaning at that time."""
        ...


@dataclass(frozen=True)
class FunctionTruth:
    """A :class:`Truth` from a function of time: ``fn(t) -> {column: value}``;
    ``sign_free`` as :class:`Truth` says."""

    columns: tuple[str, ...]
    fn: Callable[[float], Mapping[str, float]]
    sign_free: tuple[tuple[str, ...], ...] = ()

    def at(self, t: float) -> Mapping[str, float]:
        return self.fn(t)


@dataclass(frozen=True)
class Reference:
    """What a run without a simulated truth is scored against: a :class:`Truth` and one
    sentence saying what it is (``hera eval`` prints it), e.g. "self-consistency: omega
    from lap timing"."""

    truth: Truth
    source: str


class SeriesTruth:
    """A :class:`Truth` from a recorded reference series (times and values per column):
    each column interpolated linearly in time, absent outside the series' time span."""

    def __init__(self, series: Series) -> None:
        if len(series) < 2:
            raise ValueError(f"reference {series.name}_{series.node}: needs two rows or more")
        self.columns = tuple(series.columns)
        self._t = series.t
        self._v = series.values

    def at(self, t: float) -> Mapping[str, float]:
        import numpy as np

        if not self._t[0] <= t <= self._t[-1]:
            return {}
        return {c: float(np.interp(t, self._t, self._v[:, i])) for i, c in enumerate(self.columns)}


@dataclass
class Series:
    """One model output of a run: ``name`` published by ``node``, its ``columns`` (with
    units, e.g. ``"x [m]"``), measurement times ``t`` (epoch s, increasing) and ``values``
    (one row per time). ``measure`` is the measure class that produced it, when known."""

    name: str
    node: str
    columns: tuple[str, ...]
    t: np.ndarray
    values: np.ndarray
    measure: type | None = None

    def __post_init__(self) -> None:
        import numpy as np

        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        values = np.asarray(self.values, dtype=float)
        width = len(self.columns) if not values.size else -1
        self.values = values.reshape(len(self.t), width)

    def __len__(self) -> int:
        return len(self.t)

    def has(self, *columns: str) -> bool:
        return all(c in self.columns for c in columns)

    def column(self, col: str) -> np.ndarray:
        """The values of one column (KeyError naming the columns if absent)."""
        try:
            return self.values[:, self.columns.index(col)]
        except ValueError:
            raise KeyError(
                f"{self.name}_{self.node} has no column {col!r}: {self.columns}"
            ) from None


@dataclass(frozen=True)
class EvalOptions:
    """How ``hera eval`` scores: errors count ``after`` s past a model's first estimate, and
    "settled" errors ``settle`` s past it (what a converged model is judged on)."""

    after: float = 3.0
    settle: float = 10.0


@dataclass(frozen=True)
class Estimate:
    """The latest estimate of model ``name`` on ``node`` at epoch time ``t``: value per
    column. ``measure`` is the measure class of the model."""

    name: str
    node: str
    t: float
    values: Mapping[str, float]
    measure: type | None = None


@dataclass(frozen=True)
class Panel:
    """Rows an application adds to the live view: a ``title``, the column headers and the
    rows (already formatted cells; the runtime aligns them, right-justified but for the
    first column)."""

    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...] = ()


WEB_PANEL_KINDS = ("plane", "attitude", "grid")


@dataclass(frozen=True)
class WebPanel:
    """A view an application adds to the live web page (``hera view``, ``hera up --web``):
    data the page draws by ``kind``, the same way for every application. ``data`` is
    JSON-able; lengths in metres, angles in radians:

    - ``"plane"``: a 2-D scene seen from above. ``shapes``: ``{"circle": [cx, cy, r]}`` or
      ``{"line": [[x, y], ...]}``, each with an optional ``"label"``; ``points``:
      ``{"label", "x", "y"}`` with an optional ``"heading"`` (an arrow) and ``"truth":
      true`` (drawn as the reference). The page keeps a short trail per label.
    - ``"attitude"``: ``bodies``: ``{"label", "roll", "pitch", "yaw"}`` (an artificial
      horizon and a compass each), an optional ``"truth": true``; yaw turns
      counter-clockwise about the world's up axis from its x axis, and ``north`` (optional,
      the same convention; default pi/2: north along +y) is where the compass puts N, so its
      needle shows the heading north - yaw, clockwise from north.
    - ``"grid"``: a heat map: ``values`` (rows of numbers, None for unknown; row i spans
      y0 + i cell .. y0 + (i + 1) cell, column j likewise in x), ``origin`` ``[x0, y0]``
      (the lower-left corner of cell [0][0]), ``cell`` (its size), optional ``min``/``max``
      (the colour scale) and ``points`` as for ``plane``.
    """

    title: str
    kind: str
    data: Mapping[str, Any]

    def __post_init__(self) -> None:
        if self.kind not in WEB_PANEL_KINDS:
            raise ValueError(
                f"web panel {self.title!r}: kind must be one of {', '.join(WEB_PANEL_KINDS)}, "
                f"got {self.kind!r}"
            )


@dataclass
class VerbContext:
    """What a control verb of an application may use on the node that runs it."""

    node: str
    cluster: str
    world: Mapping[str, Any]
    resources: Resources
    extra: dict[str, Any] = field(default_factory=dict)


Importer = Callable[[Path, Path], str]
"""``importer(src, out) -> summary``: convert logs in a foreign format found in folder
``src`` into a new run directory ``out`` (recordings, a ``cluster.json``) that ``hera
replay`` and ``hera eval`` take as they are; returns one line saying what was imported.
Raises ValueError with one sentence naming the file and what is wrong."""

Verb = Callable[[Mapping[str, Any], VerbContext], Mapping[str, Any]]
"""A control verb: ``verb(request, ctx) -> reply``; raise ValueError with a clear sentence
for a bad request (the caller receives ``{"ok": false, "error": ...}``)."""


class Application:
    """Base class of applications (see the module docstring). Every method is optional."""

    name: ClassVar[str] = ""
    """The application's name (its ``hera.apps`` entry point)."""
    title: ClassVar[str] = ""
    """One line saying what it is (``hera apps`` prints it)."""
    measures: ClassVar[tuple[str, ...]] = ()
    """Its measures and models, by ``hera.measures`` entry-point name, in the order its
    results are listed (a ladder's order, say)."""
    metrics: ClassVar[tuple[Metric, ...]] = ()
    """The columns it fills in ``hera eval``'s table."""

    def label(self, name: str, measure: type | None) -> str:
        """How a model output called ``name`` (made by class ``measure``) is labelled in
        tables and legends."""
        return name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        """The truth of a run in ``world`` (the spec's ``[world]``), or None when this
        application cannot tell it (no simulated world of its kind)."""
        return None

    def reference(self, recordings: Sequence[Path], world: Mapping[str, Any]) -> Reference | None:
        """What to score a run against when its world has no truth (a real rig, imported
        logs): built from the run's own recordings (folders, the run's first) by
        self-consistency; None when it cannot tell. (``hera eval --reference FILE`` takes
        precedence.)"""
        return None

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> Mapping[str, float | None]:
        """Scores of one of its model outputs, by :attr:`metrics` key (None: not
        applicable)."""
        return {}

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """Write plots of its model outputs into ``out_dir``; return the files written."""
        return []

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        """Its rows of the live view of ``hera up`` for the latest estimates of its models."""
        return None

    def web_panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> WebPanel | None:
        """Its view on the live web page for the latest estimates of its models (a track,
        an attitude, a heat map: see :class:`WebPanel`); the page also plots every stream
        and every model's columns next to the truth without it."""
        return None

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        """Problems with the spec's ``[world]`` table for this application's measures (one
        sentence each; checked before a spec starts, for every application whose measures
        the spec uses)."""
        return []

    def verbs(self) -> Mapping[str, Verb]:
        """Control verbs it adds to every node (``hera/<cluster>/ctl/<node>/<verb>``)."""
        return {}

    def examples(self) -> Mapping[str, Path]:
        """Example specs it ships, by name (``hera examples``, ``hera up NAME``)."""
        return {}

    def importers(self) -> Mapping[str, Importer]:
        """Foreign log formats it can import, by format name (``hera import FORMAT SRC
        OUT``)."""
        return {}
