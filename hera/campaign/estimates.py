"""Estimate errors of a run through the applications (never naming one).

The fusion models of the spec are found with :func:`hera.fusion.spec_models`; each model's
recorded output becomes a :class:`hera.application.Series`, and its application
(:meth:`Application.truth`, :meth:`Application.score`) tells the error over any window of
measurement time: the campaign cuts the series into windows (the baseline, each fault, the
time after it) and asks the application to score each one, with ``after = settle = 0``
(the windows are already where the campaign wants them).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hera.application import Application, EvalOptions, Series, Truth
from hera.campaign.history import History
from hera.fusion import spec_models
from hera.plugins import AppIndex

WHOLE = EvalOptions(after=0.0, settle=0.0)


@dataclass
class Model:
    """One model output of the run with its application and truth (None when there is
    none: no application, or no truth for this world)."""

    series: Series
    app: Application | None
    truth: Truth | None

    @property
    def key(self) -> tuple[str, str]:
        return (self.series.name, self.series.node)


def models(h: History, names: Iterable[str] | None = None) -> list[Model]:
    """The recorded outputs of the spec's fusion models (of ``names`` only, if given),
    ordered by model and node."""
    classes = spec_models(h.spec)
    wanted = set(classes) if names is None else set(names) & set(classes)
    index = AppIndex()
    truths: dict[str, Truth | None] = {}
    out = []
    for (name, node), s in sorted(h.streams.items()):
        if name not in wanted or not len(s):
            continue
        cls = classes[name]
        app = index.app_of(cls)
        truth = None
        if app is not None:
            if app.name not in truths:
                truths[app.name] = app.truth(h.spec.world)
            truth = truths[app.name]
        order = np.argsort(s.t, kind="stable")
        cols = (
            tuple(cls.columns)
            if cls.columns
            else tuple(f"v{i + 1}" for i in range(s.values.shape[1]))
        )
        if len(cols) != s.values.shape[1]:
            cols = tuple(f"v{i + 1}" for i in range(s.values.shape[1]))
        series = Series(name, node, cols, s.t[order], s.values[order], cls)
        out.append(Model(series, app, truth))
    return out


def window(series: Series, lo: float, hi: float) -> Series:
    """The part of ``series`` with measurement times in [lo, hi)."""
    keep = (series.t >= lo) & (series.t < hi)
    return Series(
        series.name,
        series.node,
        series.columns,
        series.t[keep],
        series.values[keep],
        series.measure,
    )


def metric_of(m: Model, wanted: str | None) -> str | None:
    """The metric judged: ``wanted``, else the application's first one."""
    if m.app is None or not m.app.metrics:
        return None
    keys = [x.key for x in m.app.metrics]
    if wanted is None:
        return keys[0]
    return wanted if wanted in keys else None


def score(m: Model, lo: float, hi: float, metric: str) -> float | None:
    """The application's ``metric`` of ``m`` over [lo, hi) (None: no estimate there, or no
    truth)."""
    if m.app is None or m.truth is None:
        return None
    t = m.series.t
    if int(np.count_nonzero((t >= lo) & (t < hi))) < 3:
        return None
    part = window(m.series, lo, hi)
    value: Any = dict(m.app.score(part, m.truth, WHOLE)).get(metric)
    return None if value is None else float(value)


def timeline(m: Model, metric: str, lo: float, hi: float, step: float) -> tuple[list, list]:
    """``metric`` of ``m`` on consecutive windows of ``step`` s over [lo, hi): the windows'
    middles and values (None where there was nothing to score)."""
    xs, ys = [], []
    t = lo
    while t < hi:
        xs.append(t + step / 2)
        ys.append(score(m, t, t + step, metric))
        t += step
    return xs, ys
