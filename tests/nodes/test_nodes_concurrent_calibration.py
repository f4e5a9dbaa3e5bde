"""Measures sharing one board calibrate one at a time: a second calibration must not end
the first one's hold (regression: nav averaged moving-train gyro samples into its bias)."""

from __future__ import annotations

import threading
import time

from hera.nodes import boards
from hera.nodes.nav_measures import Mag, Nav
from nodes_helpers import fresh_boards, make_ctx  # noqa: F401 - fresh_boards is a fixture

TRAIN = {"scenario": "train", "radius": 0.6, "omega": 0.84}


def test_concurrent_nav_and_mag_calibrations_both_see_a_still_board():
    world = {**TRAIN, "epoch": time.time() - 5.0}
    nav, mag = Nav(), Mag()
    errors: list[BaseException] = []
    start = threading.Barrier(2)

    def run(measure, name, period):
        try:
            start.wait()
            measure.init({}, make_ctx(name, world, node="nav_1", period=period))
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
    board = boards.get("nav_1/nav")
    # the calibration found the board's own gyro bias (deg/s), not a share of the motion:
    # a moving-train sample would add about 48 deg/s (0.84 rad/s) to the average
    calib = nav.ctx.args.get("calib/nav_1/nav")
    assert abs(calib["gyro"][2] - board.gyro_bias[2]) < 0.2
    # and after calibration the published angular rate is the train's, within noise
    rates = [nav.measure() for _ in range(200)]
    mean = sum(r.values[1] for r in rates) / len(rates)
    assert abs(mean - 0.84) < 0.03
