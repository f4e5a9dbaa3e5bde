"""The 6-DOF IMU application (entry point ``imu6dof`` of ``hera.apps``): truth, scores, plots
and the live panel of the aided e13 and of the same filter without position fixes.

Truth: the body's position and orientation in the simulated world. Scores (``hera eval``),
over the estimates from ``after`` s past a model's first one:

- ``pos_rmse_cm`` / ``pos_max_cm``: RMS and largest distance to the truth;
- ``drift_10s_cm``: how far the position error moves in 10 s (the median over every 10 s
  window of the run of |e(t + 10) - e(t)|, e the error vector): a few cm for the aided
  filter, the inertial drift for the unaided one (an error that grows as t^2 moves more in
  a later window: the median is the run's typical one);
- ``att_mean_deg``: mean attitude error of its AHRS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hera.application import (
    Application,
    Estimate,
    EvalOptions,
    FunctionTruth,
    Metric,
    Panel,
    Series,
    Truth,
    WebPanel,
)
from hera.models.ahrs.app import orientation_truth
from hera.models.ahrs.model import QUAT
from hera.models.ahrs.scoring import attitude_error_deg
from hera.models.imu6dof.measures import Imu6dof, Imu6dofInertial
from hera.models.position3d.app import (
    POS,
    plot_positions,
    position_errors,
    position_panel,
    position_truth,
    position_web_panel,
)

LABELS = {Imu6dof: "e13", Imu6dofInertial: "no sonar"}


def drift_per(series: Series, truth: Truth, window: float, after: float) -> float | None:
    """Median over the windows [t, t + ``window``] (t from ``after`` s past the first
    estimate) of |e(t + window) - e(t)| (m), e the position error vector; None if the run
    is shorter than one window."""
    late = series.t - series.t[0] >= after
    t, e = series.t[late], position_errors(series, truth)[late]
    if not len(t) or t[-1] - t[0] < window:
        return None
    j = np.searchsorted(t, t + window)
    ok = j < len(t)
    return float(np.median(np.linalg.norm(e[j[ok]] - e[ok], axis=1)))


class Imu6dofApp(Application):
    """Position and attitude of a board from its 9-axis IMU and three sonars (thesis ch. 7.3)."""

    name = "imu6dof"
    title = "6-DOF IMU: position from the accelerometer and the AHRS, aided by the sonars (e13)"
    measures = ("imu6dof", "imu6dof_inertial")
    metrics = (
        Metric("pos_rmse_cm", "pos RMSE", "cm"),
        Metric("pos_max_cm", "pos max", "cm"),
        Metric("drift_10s_cm", "drift per 10 s", "cm"),
        Metric("att_mean_deg", "att mean", "deg"),
    )

    def label(self, name: str, measure: type | None) -> str:
        tag = LABELS.get(measure)  # type: ignore[arg-type]
        return f"{name} ({tag})" if tag else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        pos, att = position_truth(world), orientation_truth(world)
        if pos is None or att is None:
            return None
        return FunctionTruth((*POS, *QUAT), lambda t: {**pos.at(t), **att.at(t)}, sign_free=(QUAT,))

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series) or not series.has(*POS):
            return {}
        late = series.t - series.t[0] >= options.after
        if not late.any():
            return {}
        dist = np.linalg.norm(position_errors(series, truth)[late], axis=1)
        drift = drift_per(series, truth, 10.0, options.after)
        out: dict[str, float | None] = {
            "pos_rmse_cm": 100 * float(np.sqrt(np.mean(dist**2))),
            "pos_max_cm": 100 * float(dist.max()),
            "drift_10s_cm": None if drift is None else 100 * drift,
        }
        if series.has(*QUAT):
            est = np.column_stack([series.column(c) for c in QUAT])[late]
            true = np.array([[truth.at(float(t))[c] for c in QUAT] for t in series.t[late]])
            out["att_mean_deg"] = float(attitude_error_deg(est, true).mean())
        return out

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """``position.png`` and ``position_error.png`` (as ``position3d``'s), in a folder
        of their own: ``imu6dof/``."""
        sub = out_dir / "imu6dof"
        sub.mkdir(parents=True, exist_ok=True)
        return plot_positions(self, series, truth, sub)

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        p = position_panel(self, estimates, truth)
        return None if p is None else Panel("6-DOF IMU " + p.title, p.columns, p.rows)

    def web_panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> WebPanel | None:
        return position_web_panel(self, estimates, truth)
