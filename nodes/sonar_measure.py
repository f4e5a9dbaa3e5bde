"""The MaxSonar measure of the thesis: ``sonar`` -> ``[range [m], x, y]`` (REFERENCE table).

Publishes nothing ("undefined") when the range exceeds ``max_range``. Synchronised by
default (``sync = true``): the runtime asks the group's sync service for a slot and sets
``ctx.grant`` (the sync turn) while the step runs; the driver checks it at the trigger, and
the ping is announced with that grant. Counters:
``pings``, ``crosstalk`` (readings corrupted by another sonar of the group sounding at the
same time), ``dropouts``.

Args: ``max_range`` (m, default 6.45), ``x``, ``y`` (the two numbers published after the
range; default the sonar's x and y position - the original's 3-D set-up put the distance to
the origin and the direction +1/-1 there), ``position`` [x, y, z] and ``direction``
[x, y, z] (else ``world.sonars.<node>``, else the scenario's placement number ``index``),
``ping_ms`` (49), ``half_angle_deg`` (20), ``model`` (a
:class:`hera.nodes.sonar_model.SonarModel` table), ``board`` (default "sonar"), ``seed``,
``fire_log`` (path: append "start end node" per ping, time.monotonic() seconds),
``air_group`` (default: the sync group), ``crosstalk`` (default true), ``truth`` (bool).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from hera.nodes import boards
from hera.nodes.driver import NoReading
from hera.nodes.sim_sonar import SimMaxSonar
from hera.nodes.sonar_model import INCH
from hera.nodes.truth import TruthRecorder, want_truth
from hera.nodes.world import state_at

from hera.measure import Measure, MeasureContext, Reading

_ARGS = frozenset(
    {
        "max_range",
        "x",
        "y",
        "position",
        "direction",
        "index",
        "ping_ms",
        "half_angle_deg",
        "model",
        "board",
        "seed",
        "fire_log",
        "air_group",
        "crosstalk",
        "truth",
    }
)


def _num(args: Mapping[str, Any], key: str, default: float) -> float:
    v = args.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"sonar arg {key!r} must be a finite number, got {v!r}")
    return float(v)


class Sonar(Measure):
    """A MaxSonar range finder: ``[range [m], x, y]``, range = inches x 0.0254."""

    name = "sonar"
    period = 0.1
    sync = True
    slot = 0.06  # one ping (49 ms) plus margin
    columns = ("range [m]", "x [m]", "y [m]")

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        super().init(args, ctx)
        unknown = set(args) - _ARGS
        if unknown:
            raise ValueError(
                f"measure {ctx.spec.name!r}: unknown args {sorted(unknown)}; known: {sorted(_ARGS)}"
            )
        self.board = boards.open_sonar(ctx, args)
        self.max_range = _num(args, "max_range", 6.45)
        self.sim = self.board if isinstance(self.board, SimMaxSonar) else None
        pos = self.sim.mount.position if self.sim is not None else (0.0, 0.0, 0.0)
        self.x = _num(args, "x", pos[0])
        self.y = _num(args, "y", pos[1])
        self._truth: TruthRecorder | None = None
        if want_truth(args, ctx.run_dir) and self.sim is not None:
            self._truth = TruthRecorder(
                ctx.run_dir,  # type: ignore[arg-type]
                ctx.spec.name,
                ctx.node,
                ("true range [m]", "crosstalk [0/1]"),
                ctx.world,
            )
        elif args.get("truth"):
            ctx.log.warning("truth asked but there is no run directory: not recorded")

    def measure(self) -> Reading | None:
        try:
            # the driver checks the sync turn at its trigger (the simulator also announces
            # the grant with its ping)
            s = self.board.read_sample(self.ctx.grant)
        except NoReading:
            self.ctx.count("dropouts")
            return None
        self.ctx.count("pings")
        if s.crosstalk:
            self.ctx.count("crosstalk")
        if self._truth is not None and self.sim is not None:
            b = self.sim
            self._truth.write(
                state_at(b.scenario, b.epoch, s.t), (b.true_range(s.t), float(s.crosstalk))
            )
        r = s.inches * INCH
        if r > self.max_range:
            return None
        return Reading((r, self.x, self.y), s.t)

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None
