"""Fusion measures: run a fusion model over the samples in the store, live or in replay.

A *model* is a plain object (see :class:`FusionModel`): it names its ``inputs`` and turns
samples, fed in measurement-time order, into estimates. It never looks at a clock: dt comes
from the samples' measurement times, so the very same model object gives the same output
live and in ``hera replay``.

A :class:`FusionMeasure` runs a model inside a node, in one of two modes (arg ``mode``):

- ``period`` (the original's pattern): each period, the latest sample of each input source
  that is newer than the one used last and younger than ``max_age`` (default 0.5 s);
- ``arrival`` (thesis ch. 8.3): every accepted sample of its inputs is queued as it arrives
  and processed at the next step (the step waits for new data up to one period); when the
  model falls behind and more than ``backlog`` samples of one source wait, only the newest
  of that source are kept. Samples are held back up to ``reorder_s`` (default 0.1 s) and
  released in measurement-time order, so a sample that arrives late (a sonar stamps the
  start of its 49 ms ping) is still fused at its own time: live and ``hera replay`` fuse
  the same sequence. The estimate keeps its true time; it is only published later. A step
  publishes its newest estimate (the ones it replaced are counted, ``superseded``: a model
  fusing a 100 Hz IMU need not put 100 estimates a second on the bus), or each of them
  with ``publish = "every"``, as ``hera replay`` writes them.

A measure the supervisor restarts (it crashed, hung, or was stopped and started) resumes its
model from a checkpoint, a copy taken every :data:`CHECKPOINT_S` of the model's state, if
that is at most ``resume_s`` old (default 5 s) and the model's settings are unchanged;
samples that came in between are lost to it, as samples lost on the bus are. A model that
raised starts afresh (its checkpoint is dropped: its state may be what broke it). The
checkpoint is kept in the node's ``ctx.resources`` (in memory) and, where the node has a
state directory, on disk (:mod:`hera.checkpoints`), so a model in a node process that was
killed and restarted resumes too (its age then counted on the wall clock), within the same
run of the cluster (a state directory outlives runs: a new ``hera up`` starts afresh).

Each source's samples are fused at most once (a sample with a seq not above the last fused
one of its (name, node) is skipped), and so is each estimate of a model that runs on several
nodes: the copy another replica publishes is skipped (:class:`Copies`, counted ``copies``),
as ``hera replay`` runs one instance of it. After a hot reload (:mod:`hera.reload`) the new fusion
measure takes over the old one's model state and the samples it held
(:meth:`FusionMeasure.code_change`): a model with its own ``code_change(old_version,
old_model)`` converts the old model's state itself; otherwise, when the model class keeps
its name, the old model's attributes are carried over, with the old model's methods held
in them (a filter's ``f`` and ``h``) bound to the new model and the objects of the reloaded
classes among them given their new class (:mod:`hera.handover`).
"""

from __future__ import annotations

import copy
import dataclasses
import heapq
import inspect
import json
import math
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from hera import checkpoints
from hera.handover import rebind, reloads, superseded
from hera.measure import Measure, MeasureContext, Reading
from hera.recordings import LiveStart, read_start, recorded_time, start_marker, write_start
from hera.schema import TABLE, Setting, Table, choice, did_you_mean, number
from hera.store import Sample, Store

if TYPE_CHECKING:  # pragma: no cover
    from hera.spec import ClusterSpec


class FusionModel(Protocol):
    """What a fusion model gives. Optionally, ``counters() -> {name: int}``: its diagnostic
    counters (samples rejected, late, ...), shown in ``hera status`` and written by
    ``hera replay``; ``outputs() -> [(t, values), ...]``: a model that makes several
    rows at a time (a map in tiles) hands every row made since the last call there instead
    of through :meth:`estimate`; a fusion measure publishes them all, in order;
    and, for ``hera replay --smooth`` (``hera.smoothing``), ``filter``: the
    ``KalmanFilter`` or ``ExtendedKalmanFilter`` the model steps (one, for the whole run),
    with ``estimate_of(x) -> list[float]``: the output columns of a state x of that filter
    (what ``estimate`` gives for its current state). A model class may also have a
    classmethod ``check(settings)``: a cheap check of the settings' values, run by the spec
    checks before anything starts (:meth:`FusionMeasure.check_args`)."""

    inputs: tuple[str, ...]
    columns: tuple[str, ...]

    def process(self, sample: Sample) -> bool:
        """Fuse one sample (fed in measurement-time order); return whether the estimate
        changed."""

    def estimate(self) -> tuple[float, list[float]] | None:
        """(time in epoch s, values) of the current estimate, or None before the first."""


def model_counters(model: Any) -> dict[str, int]:
    """The model's diagnostic counters (its ``counters()``), or none."""
    counters = getattr(model, "counters", None)
    return dict(counters()) if callable(counters) else {}


def model_outputs(model: Any) -> list[tuple[float, list[float]]] | None:
    """The rows the model made since the last call (its ``outputs()``), or None when it
    has no ``outputs`` (its :meth:`~FusionModel.estimate` is its output)."""
    drain = getattr(model, "outputs", None)
    return list(drain()) if callable(drain) else None


def adopt_model(new: Any, old: Any) -> bool:
    """Give model ``new`` (new code) the state of model ``old`` (see the module docstring);
    return whether any state was carried over."""
    hook = getattr(new, "code_change", None)
    if callable(hook):
        hook(getattr(type(old), "version", ""), old)
        return True
    if type(new).__qualname__ == type(old).__qualname__:
        vars(new).update(vars(old))
        rebind(vars(new), old, new)
        return True
    return False


def number_problems(model_class: type, settings: Mapping[str, Any]) -> list[str]:
    """``"KEY must be a number, got VALUE"`` for each of ``settings`` that the model's
    ``__init__`` declares a number (annotated ``float`` or ``int``, ``| None`` allowing
    null) and is given something else: caught before a node starts, where the model would
    only say ``could not convert string to float``."""
    params = inspect.signature(model_class).parameters
    out = []
    for key, value in settings.items():
        p = params.get(key)
        note = getattr(p.annotation, "__name__", p.annotation) if p is not None else ""
        kind, _, rest = str(note).replace(" ", "").partition("|")
        if kind not in ("float", "int") or rest not in ("", "None") or (value is None and rest):
            continue
        kinds = (int,) if kind == "int" else (int, float)
        if (
            isinstance(value, bool)
            or not isinstance(value, kinds)
            or (isinstance(value, float) and not math.isfinite(value))
        ):
            what = "an integer" if kind == "int" else "a finite number"
            out.append(f"{key} must be {what}{' or null' if rest else ''}, got {value!r}")
    return out


def model_settings(model_class: type) -> tuple[str, ...] | None:
    """The keyword settings ``model_class`` takes (its ``__init__``'s named parameters), or
    None when it takes any (``**kwargs``)."""
    params = list(inspect.signature(model_class).parameters.values())
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    return tuple(p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))


FUSION_ARGS = Table(
    "fusion args",
    [
        Setting(
            "mode",
            choice("period", "arrival"),
            "period",
            "`period`: the latest new samples each period; `arrival`: every sample, in time order",
        ),
        Setting("max_age", number(above=0), 0.5, "s; period mode takes samples at most this old"),
        Setting("backlog", number(1, integer=True), 64, "arrival mode: samples kept per source"),
        Setting("reorder_s", number(0, 5), 0.1, "arrival mode: s a sample is held for reordering"),
        Setting(
            "publish",
            choice("step", "every"),
            "step",
            "arrival mode: `step`, the newest estimate of each step (those it replaced are "
            "counted, `superseded`); `every`, each estimate, as `hera replay` writes them",
        ),
        Setting(
            "resume_s",
            number(0),
            5.0,
            "a restarted measure resumes its model from a checkpoint at most this old (s; "
            "0: always afresh); a model that raised starts afresh",
        ),
        Setting("model", TABLE, {}, "the model's own settings"),
    ],
)


ARRIVAL_ONLY = ("backlog", "reorder_s", "publish")
"""Fusion args that only arrival mode reads: refused in period mode rather than ignored."""
PERIOD_ONLY = ("max_age",)
"""Fusion args that only period mode reads: refused in arrival mode rather than ignored."""

CHECKPOINT_S = 1.0
"""How often (s, at most) a fusion measure copies its model's state for a restart."""

CHECKPOINT_KEY = "fusion/checkpoint/"
"""``ctx.resources`` key prefix (+ the measure's name) of a fusion measure's checkpoint:
(monotonic time, the model's settings as JSON, a copy of the model, the seqs fused, the
first fused sample's time)."""


def as_recorded(s: Sample) -> Sample:
    """The sample with its time as a recording keeps it (:func:`hera.recordings.
    recorded_time`, to the microsecond): what a model is given live, as in a replay. Without
    it, a model with a discrete choice (the train's branch grid between two near-equal
    branches) could take another branch live than in the replay of the same run."""
    t = recorded_time(s.t)
    return s if t == s.t else dataclasses.replace(s, t=t)


def time_order(samples: Sequence[Sample]) -> list[Sample]:
    """Samples sorted by measurement time, ties broken by (name, node, seq): deterministic."""
    return sorted(samples, key=lambda s: (s.t, s.name, s.node, s.seq))


class Copies:
    """Recognises the copies of one estimate that replicas of a model publish.

    A model run on several nodes for redundancy (the train's ``bilateration`` on
    ``computer`` and ``nav_1``) publishes each estimate from each of them: the same values
    at the same measurement time. A model fed by it must fuse that estimate once, as
    ``hera replay`` (one instance of the upstream model) does; fusing every copy counts one
    measurement as many times as there are replicas. A sample is a copy when one with the
    same name, measurement time (to the microsecond, as recorded) and values has been seen
    before, from any node. Two sensors' samples are stamped when read and carry noise, so
    they do not meet that test; a sensor of few values (a switch) read at the same
    microsecond by two nodes would, and should then say which it is in its values. The
    last ``memory`` samples of each name are remembered.
    """

    def __init__(self, memory: int = 256) -> None:
        if memory < 1:
            raise ValueError(f"memory must be >= 1, got {memory!r}")
        self._memory = memory
        self._seen: dict[str, tuple[set, deque]] = {}

    def is_copy(self, s: Sample) -> bool:
        """Whether ``s`` repeats a sample seen before; if not, remember it."""
        key = (s.t, s.values)
        entry = self._seen.get(s.name)
        if entry is None:
            entry = self._seen[s.name] = (set(), deque())
        keys, order = entry
        if key in keys:
            return True
        keys.add(key)
        order.append(key)
        if len(order) > self._memory:
            keys.discard(order.popleft())
        return False


class Inbox:
    """Collects every sample of some names accepted by a store (see module docstring)."""

    def __init__(self, store: Store, names: Sequence[str], backlog: int = 64) -> None:
        self._names = frozenset(names)
        self._queues: dict[tuple[str, str], deque[Sample]] = {}
        self._backlog = backlog
        self._cond = threading.Condition()
        self.dropped = 0
        self._store = store
        store.add_listener(self._on_sample)

    def _on_sample(self, s: Sample) -> None:
        if s.name not in self._names:
            return
        with self._cond:
            q = self._queues.get((s.name, s.node))
            if q is None:
                q = self._queues[(s.name, s.node)] = deque()
            q.append(s)
            if len(q) > self._backlog:
                self.dropped += 1
                q.popleft()  # falling behind: keep the newest of this source
            self._cond.notify()

    def drain(self, timeout: float = 0.0) -> list[Sample]:
        """Every queued sample in time order, waiting up to ``timeout`` s for the first."""
        with self._cond:
            if timeout > 0 and not any(self._queues.values()):
                self._cond.wait(timeout)
            out = [s for q in self._queues.values() for s in q]
            for q in self._queues.values():
                q.clear()
        return time_order(out)

    def close(self) -> None:
        self._store.remove_listener(self._on_sample)


class FusionMeasure(Measure):
    """Runs a fusion model as a measure (see module docstring).

    A subclass sets ``model_class`` and, to fix some of the model's settings (a rung of a
    ladder, say), ``model_fixed``. Args (:data:`FUSION_ARGS`): ``mode`` ("period" or
    "arrival"), ``max_age`` (s, period mode), ``backlog`` and ``reorder_s`` (arrival mode),
    ``model`` (a table of the model's own settings: the keyword parameters of
    ``model_class``, less the fixed ones; an unknown one is refused).
    """

    model_class: ClassVar[type]
    model_fixed: ClassVar[Mapping[str, Any]] = {}
    # what close() reads, there before init: the worker closes a measure whose init failed
    _marker_file: Path | None = None
    _inbox: Inbox | None = None
    period = 0.05
    arguments = FUSION_ARGS

    @classmethod
    def settings(cls) -> tuple[str, ...] | None:
        """The model settings a spec may give (None: any)."""
        known = model_settings(cls.model_class)
        return None if known is None else tuple(k for k in known if k not in cls.model_fixed)

    @classmethod
    def check_args(cls, args: Mapping[str, Any], where: str) -> list[str]:
        """The measure's own problems, unknown model settings, and, when the model class
        has ``check(settings)`` (a cheap check of the values, raising ValueError or
        TypeError with one sentence), the settings' values, before anything starts."""
        problems = super().check_args(args, where)
        mode = args.get("mode", "period")
        for key in ARRIVAL_ONLY if mode == "period" else PERIOD_ONLY if mode == "arrival" else ():
            if key in args:
                other = "arrival" if mode == "period" else "period"
                problems.append(
                    f"{where}: {key} is for {other} mode and does nothing in {mode} mode "
                    f'(set mode = "{other}" or leave {key} out)'
                )
        model = args.get("model", {})
        known = cls.settings()
        if isinstance(model, Mapping) and known is not None:
            for key in model:
                if key not in known:
                    problems.append(
                        f"{where}: model: unknown setting {key!r}{did_you_mean(str(key), known)}"
                        f"; known settings: {', '.join(known)}"
                    )
        check = getattr(cls.model_class, "check", None)
        if not problems and isinstance(model, Mapping) and callable(check):
            try:  # the model's own check first: it knows the ranges, not only the kinds
                check({**dict(model), **cls.model_fixed})
            except (TypeError, ValueError) as e:
                problems.append(f"{where}: model: {e}")
        if not problems and isinstance(model, Mapping):
            problems += [f"{where}: model: {p}" for p in number_problems(cls.model_class, model)]
        return problems

    @classmethod
    def reads(cls, args: Mapping[str, Any]) -> tuple[str, ...] | None:
        """The model's inputs (its settings may change them, e.g. a ladder's rung)."""
        model = dict(args.get("model") or {})
        return tuple(cls.make_model(model).inputs)

    @classmethod
    def make_model(cls, settings: Mapping[str, Any], where: str = "model") -> Any:
        """A model with these settings (and the fixed ones); ValueError naming the setting
        that is unknown or refused by the model."""
        problems = cls.check_args({"model": dict(settings)}, where)
        if problems:
            raise ValueError(problems[0])
        try:
            return cls.model_class(**{**dict(settings), **cls.model_fixed})
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where}: {e}") from None

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        self.mode = args["mode"]
        self.max_age = args["max_age"]
        self.reorder = args["reorder_s"]
        self._held: list[tuple[float, str, str, int, Sample]] = []
        self._newest = float("-inf")
        self.model = self.make_model(args["model"], f"measure {ctx.spec.name!r} model")
        self.columns = tuple(self.model.columns)
        self._inbox = None
        self._cursor = None
        self._first_t: float | None = None
        self._key = CHECKPOINT_KEY + ctx.spec.name
        self._settings = json.dumps(args["model"], sort_keys=True, default=str)
        self._checkpointed = time.monotonic()  # the first copy after CHECKPOINT_S
        self._checkpoints = args["resume_s"] > 0
        self._disk = ctx.state_dir is not None  # checkpoints on disk too
        has_outputs = callable(getattr(self.model, "outputs", None))  # its rows go out as made
        self.every = self.mode == "arrival" and args["publish"] == "every" and not has_outputs
        self._fused: dict[tuple[str, str], int] = {}
        self._copies = Copies()
        # what keeps a replay from repeating this model (the start marker, LiveStart)
        self._last_t = float("-inf")  # the newest sample time given to the model
        self._late, self._first_late_t, self._resumed, self._dropped0 = 0, None, 0, 0
        self._marker: LiveStart | None = None  # as last written
        self._marker_at = float("-inf")
        self._marker_file = None  # <run>/measures/<name>_<node>.start.json
        if ctx.run_dir is not None:
            self._marker_file = start_marker(
                Path(ctx.run_dir) / "measures", ctx.spec.name, ctx.node
            )
        if self._checkpoints:
            self._resume(args["resume_s"])
        else:
            self._forget()
        if self.mode == "arrival":
            self._inbox = Inbox(ctx.store, self.model.inputs, args["backlog"])
        else:
            self._cursor = ctx.store.cursor(self.model.inputs)

    def _resume(self, resume_s: float) -> None:
        """Take the model's state from this measure's checkpoint, if there is one at most
        ``resume_s`` old, of a model of the same class and settings."""
        saved = self.ctx.resources.get(self._key)
        where = "its checkpoint"
        if saved is not None:
            at, settings, model, fused, first_t = saved
            age = time.monotonic() - at
            model = copy.deepcopy(model)  # the checkpoint stays as it was, for a next time
        else:  # a new node process: the one its previous process left on disk, if any
            entry = checkpoints.load(self.ctx.state_dir, self.ctx.spec.name) if self._disk else None
            if entry is None or entry.get("run") != self.ctx.run_dir:  # not of an earlier run
                return
            age = time.time() - entry["t"]
            settings, model, first_t = entry["settings"], entry["model"], entry["first_t"]
            # this node's own streams may number afresh in its new process (hera.wire)
            fused = {k: v for k, v in entry["fused"].items() if k[1] != self.ctx.node}
            where = "the checkpoint its node's previous process left"
        if age > resume_s or settings != self._settings or type(model) is not type(self.model):
            return
        self.model = model
        self._fused = dict(fused)
        self._first_t = first_t
        self._carry_marker()
        c = self.ctx.counters
        c["resumed"] = c.get("resumed", 0) + 1
        self.ctx.log.info("resumed the model from %s of %.2f s ago", where, age)

    def _forget(self) -> None:
        """Drop this measure's checkpoints, in memory and on disk."""
        self.ctx.resources.put(self._key, None)
        if self._disk:
            checkpoints.forget(self.ctx.state_dir, self.ctx.spec.name)

    def _checkpoint(self) -> None:
        """Copy the model's state for a restart (at most every CHECKPOINT_S)."""
        now = time.monotonic()
        if now - self._checkpointed < CHECKPOINT_S:
            return
        self._checkpointed = now
        reloads_before = reloads()
        try:
            model = copy.deepcopy(self.model)
        except Exception as e:  # a model holding what cannot be copied: no checkpoints
            self._checkpoints = False
            self.ctx.log.warning("no checkpoints of the model (it cannot be copied: %s)", e)
            return
        saved = (now, self._settings, model, dict(self._fused), self._first_t)
        self.ctx.resources.put(self._key, saved)
        if not self._disk:
            return
        entry = {
            "t": time.time(),
            "run": self.ctx.run_dir,
            "settings": self._settings,
            "model": model,
            "fused": saved[3],
            "first_t": self._first_t,
        }
        try:
            checkpoints.save(self.ctx.state_dir, self.ctx.spec.name, entry)
        except Exception as e:  # cannot be pickled, or the disk refused: in memory only
            # a hot reload loaded its class anew (the old code ends soon), or had its module
            # out of sys.modules meanwhile (pickle imported it itself): skipped, not given up
            if superseded(model, reloads_before):
                return
            self._disk = False
            self.ctx.log.warning(
                "no checkpoints of the model on disk (a node process that restarts starts"
                " it afresh): it cannot be pickled: %s (a lambda or a local function in"
                " the model? a module-level function or a method pickles)",
                e,
            )

    def _release(self, arrived: list[Sample]) -> list[Sample]:
        """Hold samples up to ``reorder_s``; return those due, in measurement-time order.

        A sample is due once a sample at least ``reorder_s`` newer has been seen, or once it
        has waited ``reorder_s`` on this node (a silent source never blocks the others).
        """
        for s in arrived:
            heapq.heappush(self._held, (s.t, s.name, s.node, s.seq, s))
            self._newest = max(self._newest, s.t)
        now = time.monotonic()
        due = []
        while self._held:
            t, *_, s = self._held[0]
            if t > self._newest - self.reorder and now - s.arrival < self.reorder:
                break
            due.append(heapq.heappop(self._held)[-1])
        return due

    def measure(self) -> list[Reading] | None:
        """Fuse the samples due; return the estimates to publish (None: none): the step's
        newest (the others are counted as ``superseded``), or with ``publish = "every"``
        (arrival mode) one per sample that changed it, as ``hera replay`` gives them; a
        model's ``outputs()`` rows, all, when it has them."""
        if self._inbox is not None:
            arrived = self._inbox.drain(timeout=0.8 * self.ctx.spec.period)
            samples = self._release([as_recorded(s) for s in arrived])
        else:
            samples = time_order([as_recorded(s) for s in self._cursor.new(max_age=self.max_age)])
        out: list[Reading] = []
        changed = 0
        for s in samples:
            if s.seq <= self._fused.get((s.name, s.node), 0):
                continue  # already fused (a sample handed over by a hot reload)
            self._fused[(s.name, s.node)] = s.seq
            if self._copies.is_copy(s):  # another replica's copy of an estimate fused
                self.ctx.count("copies")
                continue
            if s.t < self._last_t:  # came after its reorder_s: given out of time order
                self._late += 1
                if self._first_late_t is None:
                    self._first_late_t = s.t
            else:
                self._last_t = s.t
            try:
                fused = self.model.process(s)
            except BaseException:  # its state may be what broke it: a restart starts afresh
                self._forget()
                raise
            if self._first_t is None:  # the first sample it was given, fused or kept
                self._first_t = s.t
                self._write_marker(force=True)  # where hera replay --start-like starts
            if fused:
                changed += 1
                if self.every:  # each estimate, as hera replay gives them
                    est = self.model.estimate()
                    if est is not None:
                        out.append(Reading(est[1], est[0]))
        self._report(len(samples))
        self._write_marker()
        rows = model_outputs(self.model)  # drained before a copy: a resumed model never repeats
        if changed and self._checkpoints:
            self._checkpoint()
        if rows is not None:
            return [Reading(values, t) for t, values in rows] or None
        if not self.every and changed:  # the estimate of the step
            c = self.ctx.counters
            c["superseded"] = c.get("superseded", 0) + changed - 1
            est = self.model.estimate()
            if est is not None:
                out.append(Reading(est[1], est[0]))
        return out or None

    def code_change(self, old_version: str, state: Mapping[str, Any]) -> None:
        """Take over the replaced fusion measure's model state, the samples it held or had
        not drained yet and what it had fused (see the module docstring)."""
        old_model = state.get("model")
        if old_model is not None and not adopt_model(self.model, old_model):
            self.ctx.log.warning(
                "the new model %s cannot take over the state of %s: it starts afresh",
                type(self.model).__qualname__,
                type(old_model).__qualname__,
            )
        self._first_t = state.get("_first_t", self._first_t)
        for key in ("_last_t", "_late", "_first_late_t", "_resumed", "_dropped0", "_marker"):
            if key in state:
                setattr(self, key, state[key])
        self._fused = {**state.get("_fused", {}), **self._fused}
        self._copies = state.get("_copies", self._copies)
        pending = [entry[-1] for entry in state.get("_held", ())]
        old_inbox = state.get("_inbox")
        if old_inbox is not None:
            pending += [as_recorded(s) for s in old_inbox.drain()]
            self._dropped0 += getattr(old_inbox, "dropped", 0)
        if self._inbox is not None:
            for s in pending:
                heapq.heappush(self._held, (s.t, s.name, s.node, s.seq, s))
                self._newest = max(self._newest, s.t)

    def _live_start(self) -> LiveStart | None:
        """The start marker as it stands (:class:`~hera.recordings.LiveStart`): in period
        mode the model is given the newest samples only, which no replay repeats (counts
        unknown)."""
        if self._first_t is None:
            return None
        if self._inbox is None:
            return LiveStart(self._first_t, None, None, None, None)
        return LiveStart(
            self._first_t,
            self._late,
            self._first_late_t,
            self._dropped0 + self._inbox.dropped,
            self._resumed,
        )

    def _write_marker(self, force: bool = False) -> None:
        """Write the start marker when it changed, at most every CHECKPOINT_S (``force``:
        now)."""
        path = self._marker_file
        if path is None:
            return
        live = self._live_start()
        if live is None or live == self._marker:
            return
        now = time.monotonic()
        if not force and now - self._marker_at < CHECKPOINT_S:
            return
        self._marker_at = now
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_start(path, live)
            self._marker = live
        except OSError as e:  # a full disk must not stop the fusion
            self.ctx.log.warning("cannot record the model's start: %s", e)

    def _carry_marker(self) -> None:
        """A model resumed from a checkpoint keeps its start marker, one resume more (the
        samples since the checkpoint never reached it)."""
        path = self._marker_file
        try:
            live = read_start(path) if path is not None and path.exists() else None
        except ValueError:
            live = None
        if live is not None:
            self._late, self._first_late_t = live.late or 0, live.first_late_t
            self._resumed, self._dropped0 = live.resumed or 0, live.dropped or 0
        self._resumed += 1

    def _report(self, fused: int) -> None:
        """Status counters: samples fused, dropped (backlog), and the model's own
        (:func:`model_counters`)."""
        c = self.ctx.counters
        c["fused"] = c.get("fused", 0) + fused
        if self._inbox is not None:
            c["dropped"] = self._inbox.dropped
        c.update(model_counters(self.model))

    def close(self) -> None:
        self._write_marker(force=True)
        if self._inbox is not None:
            self._inbox.close()


def spec_models(spec: ClusterSpec) -> dict[str, type[FusionMeasure]]:
    """Publication name -> measure class of every fusion model of ``spec`` (measures that
    do not load are left out: the spec checks report them)."""
    from hera.plugins import find_measure

    out: dict[str, type[FusionMeasure]] = {}
    for _, m in spec.measures():
        try:
            cls = find_measure(m.use)
        except (LookupError, TypeError):
            continue
        if issubclass(cls, FusionMeasure):
            out.setdefault(str(m.name), cls)
    return out
