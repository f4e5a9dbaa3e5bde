"""Measures used only by the tests; node processes import them as ``fixture_measures:Class``
(the test harness puts this folder on PYTHONPATH)."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import Any

from hera.measure import Measure, MeasureContext
from hera.schema import Setting, Table, number, text


def _append(path: str | None, line: str) -> None:
    if path:
        with open(path, "a") as f:
            f.write(line + "\n")


class Calibrated(Measure):
    """Calibrates once per cluster: looks in the args store first, else "calibrates" (writes a
    line to ``calib_log``) and stores the result. Publishes ``[calibration, step]``."""

    name = "calibrated"
    period = 0.05

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        super().init(args, ctx)
        key = f"calib/{ctx.node}/{ctx.spec.name}"
        self.calibration = ctx.args.get(key)
        if self.calibration is None:
            self.calibration = float(args["value"])
            _append(args.get("calib_log"), f"{ctx.node} {os.getpid()}")
            ctx.args.put(key, self.calibration)
        self.step = 0

    def measure(self) -> list[float]:
        self.step += 1
        return [self.calibration, float(self.step)]


class Crasher(Measure):
    """Raises at step ``crash_at`` of every instance; logs each init's args to ``init_log``."""

    name = "crasher"
    period = 0.02

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        super().init(args, ctx)
        self.crash_at = int(args.get("crash_at", 3))
        self.steps = 0
        _append(args.get("init_log"), f"{time.monotonic()} {sorted(args.items())}")

    def measure(self) -> list[float]:
        self.steps += 1
        if self.steps >= self.crash_at:
            raise RuntimeError("planned crash")
        return [float(self.steps)]


class Sleeper(Measure):
    """Sleeps ``sleep`` seconds in step ``hang_at`` (a hung sensor read)."""

    name = "sleeper"
    period = 0.02

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        super().init(args, ctx)
        self.hang_at = int(args.get("hang_at", 5))
        self.sleep = float(args.get("sleep", 30))
        self.steps = 0
        _append(args.get("init_log"), str(time.monotonic()))

    def measure(self) -> list[float]:
        self.steps += 1
        if self.steps == self.hang_at:
            time.sleep(self.sleep)
        return [float(self.steps)]


class Tunable(Measure):
    """Publishes ``[gain, step]``: its declared argument ``gain`` (set at run time through
    ``measure/<node>/<name>/gain``); logs each init to ``init_log``."""

    name = "tunable"
    period = 0.05
    arguments = Table(
        "tunable args",
        [Setting("gain", number(), 1.0, "a gain"), Setting("init_log", text(), "", "a file")],
    )

    def init(self, args: Mapping[str, Any], ctx: MeasureContext) -> None:
        args = self.prepare_args(args)
        super().init(args, ctx)
        self.gain = float(args["gain"])
        self.step = 0
        _append(args["init_log"], f"{ctx.node} {self.gain}")

    def measure(self) -> list[float]:
        self.step += 1
        return [self.gain, float(self.step)]
