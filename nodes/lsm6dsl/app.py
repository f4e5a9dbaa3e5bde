"""The LSM6DSL boards as an application: the world check and the ``gyro_calibration`` verb.

``hera/<cluster>/ctl/<node>/gyro_calibration`` with a JSON request:

- ``{}``: the gyro calibrations of the node's ``lsm6dsl`` measures (state, bias, progress);
- ``{"measure": "<name>"}``: calibrate that measure's gyroscope now (it refuses to finish
  while the robot moves, and stores the result in the replicated args store).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hera.application import Application, Verb, VerbContext


def gyro_calibration(request: Mapping[str, Any], ctx: VerbContext) -> dict[str, Any]:
    """The ``gyro_calibration`` control verb (see the module docstring); ValueError with a
    clear sentence for a bad request."""
    from hera.nodes.lsm6dsl.measures import CalibrationDesk

    desk = CalibrationDesk.of(ctx.resources)
    req = dict(request)
    if not req:
        return {"calibrations": desk.states()}
    measure = req.pop("measure", None)
    if not isinstance(measure, str) or not measure:
        raise ValueError("a gyro_calibration request needs 'measure': the lsm6dsl measure's name")
    if req:
        raise ValueError(f"gyro_calibration takes only 'measure', got also {sorted(req)}")
    return desk.request(measure)


class Lsm6dslBoards(Application):
    """LSM6DSL accelerometer + gyroscope boards (seed 003)."""

    name = "lsm6dsl"
    title = "simulated LSM6DSL IMUs: gyro calibration on request (verb 'gyro_calibration')"
    measures = ("lsm6dsl",)

    def check_world(self, world: Mapping[str, Any]) -> list[str]:
        """The scenario, its keys and the environment must be ones the simulator knows."""
        from hera.nodes.world import world_problems

        return world_problems(world)

    def verbs(self) -> Mapping[str, Verb]:
        return {"gyro_calibration": gyro_calibration}
