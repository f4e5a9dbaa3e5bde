"""Measures sharing one board calibrate one at a time: a second calibration must not end
the first one's hold (regression: nav averaged moving-train gyro samples into its bias)."""

from __future__ import annotations

import threading
import time

from nodes_helpers import boards_of, make_ctx

from hera.nodes.measures.nav import Mag, Nav
from hera.resources import Resources

TRAIN = {"scenario": "train", "radius": 0.6, "omega": 0.84}


def test_concurrent_nav_and_mag_calibrations_both_see_a_still_board():
    world = {**TRAIN, "epoch": time.time() - 5.0}
    nav, mag = Nav(), Mag()
    errors: list[BaseException] = []
    start = threading.Barrier(2)
    node = Resources()  # both measures run on node nav_1 and share its board

    def run(measure, name, period):
        try:
            start.wait()
            measure.init({}, make_ctx(name, world, node="nav_1", period=period, resources=node))
        except BaseException as e:
            errors.append(e)

    threads = [
        threading.Thread(target=run, args=(mag, "mag", 0.1)),
        threading.Thread(target=run, args=(nav, "nav", 0.01)),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors
    board = boards_of(nav.ctx).get("nav_1/nav")
    # the calibration found the board's own gyro bias (deg/s), not a share of the motion:
    # a moving-train sample would add about 48 deg/s (0.84 rad/s) to the average
    calib = nav.ctx.args.get("calib/nav_1/nav")
    assert abs(calib["gyro"][2] - board.gyro_bias[2]) < 0.2
    # and after calibration the published angular rate is the train's, within noise
    rates = [nav.measure() for _ in range(200)]
    mean = sum(r.values[1] for r in rates) / len(rates)
    assert abs(mean - 0.84) < 0.03
