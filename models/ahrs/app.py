"""The AHRS application (entry point ``attitude3d`` of ``hera.apps``): truth, scores, plots and the
live panel of our AHRS and the thesis's (e11), through :class:`hera.application.Application`.

Truth: the body's orientation in the simulated world (any scenario; the ones of thesis
ch. 7.1.3 are ``still``, ``rotation_slow``, ``rotation_fast`` and ``shaking``). Scores
(``hera eval``), over the estimates from ``after`` s past a model's first one
(:mod:`.scoring` defines the errors):

- ``att_mean_deg`` / ``att_max_deg``: mean and largest attitude error (the angle of
  ``q_est^-1 q_true``);
- ``tilt_mean_deg``: mean tilt error; ``heading_mean_deg`` / ``heading_max_deg``: mean and
  largest absolute heading error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
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
from hera.models.ahrs.measures import Ahrs, AhrsThesis
from hera.models.ahrs.model import QUAT
from hera.models.ahrs.scoring import (
    attitude_error_deg,
    heading_error_deg,
    tilt_error_deg,
    yaw_pitch_roll_deg,
)

LABELS = {Ahrs: "ours", AhrsThesis: "e11"}


@dataclass(frozen=True)
class OrientationTruth(FunctionTruth):
    """An orientation's truth, and where magnetic north lies in the world (rad,
    counter-clockwise about up from the world's x axis): what a compass shows as N."""

    north: float = math.pi / 2


def orientation_truth(world: Mapping[str, Any]) -> OrientationTruth | None:
    """The body's true orientation (qw, qx, qy, qz: body -> world) at any epoch time, or
    None when the world is not one the simulator knows."""
    from hera.nodes.world import environment, epoch_of, make_scenario, state_at

    try:
        scenario, epoch = make_scenario(world), epoch_of(world)
        north = environment(world).mag_north
    except ValueError:
        return None

    def at(t: float) -> dict[str, float]:
        q = state_at(scenario, epoch, t).orientation
        return dict(zip(QUAT, q, strict=True))

    return OrientationTruth(QUAT, at, sign_free=(QUAT,), north=north)


def truth_quats(truth: Truth, times: np.ndarray) -> np.ndarray:
    """The true quaternions (rows) at ``times``."""
    return np.array([[truth.at(float(t))[c] for c in QUAT] for t in times])


def attitude_errors(series: Series, truth: Truth) -> tuple[np.ndarray, ...]:
    """(attitude, tilt, signed heading) errors (deg) of each estimate of ``series``."""
    est = np.column_stack([series.column(c) for c in QUAT])
    true = truth_quats(truth, series.t)
    return (
        attitude_error_deg(est, true),
        tilt_error_deg(est, true),
        heading_error_deg(est, true),
    )


class AhrsApp(Application):
    """Attitude and heading of a Pmod NAV (thesis ch. 7.1): ours and the thesis's e11."""

    name = "attitude3d"
    title = "attitude and heading from a 9-axis IMU: ours and the thesis's e11 (ch. 7.1)"
    measures = ("attitude_mekf", "attitude_thesis")
    metrics = (
        Metric("att_mean_deg", "att mean", "deg"),
        Metric("att_max_deg", "att max", "deg"),
        Metric("tilt_mean_deg", "tilt mean", "deg"),
        Metric("heading_mean_deg", "head mean", "deg"),
        Metric("heading_max_deg", "head max", "deg"),
    )

    def label(self, name: str, measure: type | None) -> str:
        tag = LABELS.get(measure)  # type: ignore[arg-type]
        return f"{name} ({tag})" if tag else name

    def truth(self, world: Mapping[str, Any]) -> Truth | None:
        return orientation_truth(world)

    def score(
        self, series: Series, truth: Truth | None, options: EvalOptions
    ) -> dict[str, float | None]:
        if truth is None or not len(series) or not series.has(*QUAT):
            return {}
        late = series.t - series.t[0] >= options.after
        if not late.any():
            return {}
        att, tilt, head = (e[late] for e in attitude_errors(series, truth))
        return {
            "att_mean_deg": float(att.mean()),
            "att_max_deg": float(att.max()),
            "tilt_mean_deg": float(tilt.mean()),
            "heading_mean_deg": float(np.abs(head).mean()),
            "heading_max_deg": float(np.abs(head).max()),
        }

    def plots(
        self,
        series: Sequence[Series],
        truth: Truth | None,
        out_dir: Path,
        options: EvalOptions,
    ) -> list[Path]:
        """``attitude_error.png``: attitude, tilt and heading errors over time of every
        model; ``attitude.png``: yaw, pitch and roll of every model over the truth."""
        from hera.plotting import pyplot

        have = [s for s in series if len(s) and s.has(*QUAT)]
        if truth is None or not have:
            return []
        plt = pyplot()
        t0 = min(float(s.t[0]) for s in have)
        fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
        for s in have:
            att, tilt, head = attitude_errors(s, truth)
            label = self.label(s.name, s.measure)
            for ax, y in zip(axes, (att, tilt, head), strict=True):
                ax.plot(s.t - t0, y, lw=1, label=label)
        for ax, title in zip(
            axes, ("attitude error [deg]", "tilt error [deg]", "heading error [deg]"), strict=True
        ):
            ax.set_ylabel(title)
            ax.grid(alpha=0.3)
        axes[0].set_title(f"attitude errors on node {have[0].node}")
        axes[0].legend(fontsize=8)
        axes[-1].set_xlabel("time since first estimate [s]")
        fig.tight_layout()
        files = [out_dir / "attitude_error.png"]
        fig.savefig(files[0], dpi=100)
        plt.close(fig)

        fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
        ts = np.unique(np.concatenate([s.t for s in have]))[::5]
        true = yaw_pitch_roll_deg(truth_quats(truth, ts))
        for i, (ax, title) in enumerate(zip(axes, ("yaw", "pitch", "roll"), strict=True)):
            ax.plot(ts - t0, true[:, i], color="0.6", lw=3, label="truth")
            for s in have:
                est = yaw_pitch_roll_deg(np.column_stack([s.column(c) for c in QUAT]))
                ax.plot(s.t - t0, est[:, i], lw=1, label=self.label(s.name, s.measure))
            ax.set_ylabel(f"{title} [deg]")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        axes[-1].set_xlabel("time since first estimate [s]")
        fig.tight_layout()
        files.append(out_dir / "attitude.png")
        fig.savefig(files[1], dpi=100)
        plt.close(fig)
        return files

    def panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> Panel | None:
        """One row per model and node: yaw, pitch, roll and the attitude, tilt and heading
        errors against the truth at the estimate's time; then the truth."""
        rows = []
        last = None
        for e in estimates:
            if not all(c in e.values for c in QUAT):
                continue
            q = np.array([[e.values[c] for c in QUAT]])
            ypr = yaw_pitch_roll_deg(q)[0]
            errs = ["", "", ""]
            if truth is not None:
                tq = np.array([[truth.at(e.t)[c] for c in QUAT]])
                errs = [
                    f"{attitude_error_deg(q, tq)[0]:.2f}",
                    f"{tilt_error_deg(q, tq)[0]:.2f}",
                    f"{heading_error_deg(q, tq)[0]:+.2f}",
                ]
                last = tq
            rows.append((self.label(e.name, e.measure), e.node, *(f"{a:+.1f}" for a in ypr), *errs))
        if not rows:
            return None
        if last is not None:
            true = (f"{a:+.1f}" for a in yaw_pitch_roll_deg(last)[0])
            rows.append(("truth", "", *true, "", "", ""))
        cols = ("model", "node", "yaw deg", "pitch deg", "roll deg", "err deg", "tilt err")
        title = "attitude" + (" (truth from the simulated world)" if truth else "")
        return Panel(title, (*cols, "head err"), tuple(rows))

    def web_panel(self, estimates: Sequence[Estimate], truth: Truth | None) -> WebPanel | None:
        """An artificial horizon and a compass per model and node (yaw, pitch, roll in
        radians, ``R = Rz(yaw) Ry(pitch) Rx(roll)``), and the truth at the newest estimate's
        time; the compass's N is the world's magnetic north."""
        bodies = []
        for e in estimates:
            if all(c in e.values for c in QUAT):
                ypr = np.radians(yaw_pitch_roll_deg([[e.values[c] for c in QUAT]])[0])
                bodies.append({"label": f"{self.label(e.name, e.measure)} {e.node}", **_rpy(ypr)})
        if not bodies:
            return None
        if truth is not None:
            tq = [[truth.at(max(e.t for e in estimates))[c] for c in QUAT]]
            ypr = np.radians(yaw_pitch_roll_deg(tq)[0])
            bodies.append({"label": "truth", **_rpy(ypr), "truth": True})
        north = getattr(truth, "north", math.pi / 2)  # +y without a simulated world
        return WebPanel("attitude", "attitude", {"bodies": bodies, "north": north})


def _rpy(ypr: np.ndarray) -> dict[str, float]:
    """A web panel body's angles (rad) from (yaw, pitch, roll)."""
    return {"roll": float(ypr[2]), "pitch": float(ypr[1]), "yaw": float(ypr[0])}
