"""The NAV measures: calibration recovers planted errors, is stored and not redone, and the
values match the thesis's layouts on the train."""

from __future__ import annotations

import csv
import json
import math
import statistics
from pathlib import Path

import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx

from hera.args import ArgsStore
from hera.measure import NotReady
from hera.nodes import boards, calibration
from hera.nodes import geometry as gm
from hera.nodes.driver import NavDriver, NavDriverBase
from hera.nodes.imu_model import NavModel
from hera.nodes.measures.nav import Mag, Nav, Nav3
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.truth import truth_at
from hera.nodes.world import environment, make_scenario
from hera.resources import Resources

TRAIN = {"scenario": "train", "epoch": 1000.0}
PLANTED = [0.31, -0.42, 0.17]
IDENTITY = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


def _sim(world: dict, clock=None, **model) -> SimNavBoard:
    return SimNavBoard(
        "n1/nav",
        make_scenario(world),
        environment(world),
        float(world.get("epoch", 0.0)),
        NavModel.from_args(model),
        seed=11,
        clock=clock or FakeClock(start=1000.0),
    )


def test_planted_hard_iron_is_recovered() -> None:
    b = _sim(TRAIN, hard_iron=PLANTED, soft_iron=IDENTITY, tilt_pitch_deg=0.0)
    cal = calibration.calibrate_mag(b, n=20)
    assert cal["bias"] == pytest.approx(PLANTED[:2], abs=0.003)
    cal3 = calibration.calibrate_nav3(b, n_mag=20)
    assert cal3["mag"] == pytest.approx(PLANTED, abs=0.003)


def test_still_calibration_finds_bias_and_tilt() -> None:
    b = _sim(TRAIN, gyro_bias=[1.0, -2.0, 0.5], tilt_pitch_deg=5.0, acc_scale=[0, 0, 0])
    cal = calibration.calibrate_nav(b, n=500)
    assert cal["gyro"] == pytest.approx([1.0, -2.0, 0.5], abs=0.02)
    assert math.degrees(math.asin(cal["sin_tilt"] + b.acc_bias[0])) == pytest.approx(5.0, abs=0.1)


def _train_ctx(
    name: str,
    tmp_path: Path | None = None,
    args: ArgsStore | None = None,
    node: Resources | None = None,
):
    """A context of a measure of node n1 (``node``: its resources, shared by its measures)."""
    return make_ctx(
        name,
        TRAIN,
        args=args,
        run_dir=str(tmp_path) if tmp_path else None,
        period=0.05,
        resources=node,
    )


def _use_clock(ctx, clock: FakeClock) -> None:
    for b in boards_of(ctx).all():
        b.clock = clock


def _fake_board(ctx, args: dict | None = None, start: float = 990.0) -> SimNavBoard:
    """Open the board before the measure does, on a fake clock, so calibration is
    reproducible (its noise is keyed by the reading times)."""
    board = boards.open_nav(ctx, args or {})
    board.clock = FakeClock(start=start, step=0.01)
    return board


def test_nav_on_the_train_measures_centripetal_acc_and_rate(tmp_path) -> None:
    ctx = _train_ctx("nav", tmp_path)
    _fake_board(ctx)
    m = Nav()
    m.init({"truth": True}, ctx)
    assert ctx.args.get("calib/n1/nav")["n"] == 500
    _use_clock(ctx, FakeClock(start=1000.0, step=0.05))
    values = [m.measure().values for _ in range(1500)]
    m.close()
    a_y = statistics.fmean(v[0] for v in values)
    g_z = statistics.fmean(v[1] for v in values)
    assert a_y == pytest.approx(0.6 * 0.84**2, abs=0.1)  # vibrations: sigma 0.9 m/s^2
    assert g_z == pytest.approx(0.84, rel=0.03)  # 1 % scale error at most about 3 sigma
    # the truth file: one row per sample, the train's state and the ideal values
    rows = list(csv.reader((tmp_path / "truth" / "nav_n1.csv").open()))
    side = json.loads((tmp_path / "truth" / "nav_n1.columns.json").read_text())
    assert len(rows) == 1500 and len(rows[0]) == len(side["columns"]) == 2 + 16 + 2
    t = float(rows[10][1]) / 1000.0
    assert [float(x) for x in rows[10][2:5]] == pytest.approx(truth_at(TRAIN, t).position)
    assert float(rows[10][-2]) == pytest.approx(0.6 * 0.84**2)
    assert float(rows[10][-1]) == pytest.approx(0.84)


def test_calibration_is_stored_and_not_redone_after_a_restart() -> None:
    store, node = ArgsStore("n1"), Resources()
    m = Nav()
    m.init({}, _train_ctx("nav", args=store, node=node))
    board = boards.of(node).get("n1/nav")
    reads = board.reads
    again = Nav()  # the supervisor's fresh instance after a crash
    again.init({}, _train_ctx("nav", args=store, node=node))
    assert board.reads == reads  # no new calibration samples
    assert (again.acc0, again.gyro0, again.sin_tilt) == (m.acc0, m.gyro0, m.sin_tilt)
    store.put("calib/n1/nav", {"acc": "garbage"})
    Nav().init({}, _train_ctx("nav", args=store, node=node))
    assert board.reads > reads  # malformed stored calibration: recalibrated
    assert calibration.is_vec(store.get("calib/n1/nav")["acc"])


def test_mag_heading_follows_the_train(tmp_path) -> None:
    ctx = _train_ctx("mag", tmp_path)
    _fake_board(ctx, {"model": {"hard_iron": PLANTED}})
    m = Mag()
    m.init({"model": {"hard_iron": PLANTED}, "truth": True}, ctx)
    # with the 5 deg mounting tilt the vertical field leaks into x: b_x also holds
    # 0.44 sin(5 deg) = 0.038 gauss, constant on a level track, so harmless for the heading
    tilt_leak = 0.44 * math.sin(math.radians(5.0))
    bias = ctx.args.get("calib/n1/mag")["bias"]
    assert bias == pytest.approx([PLANTED[0] + tilt_leak, PLANTED[1]], abs=0.01)
    clock = FakeClock(start=1000.0, step=0.3)
    _use_clock(ctx, clock)
    errors = []
    for _ in range(60):
        h = m.measure().values[0]
        theta = math.atan2(*reversed(truth_at(TRAIN, clock.t).position[:2]))
        errors.append(abs(gm.wrap_angle(h - theta)))
    # the default soft iron (a few %) bends the heading a little; noise 0.003 / 0.205 rad
    assert max(errors) < 0.1
    assert statistics.fmean(errors) < 0.04
    rows = list(csv.reader((tmp_path / "truth" / "mag_n1.csv").open()))
    true_h = float(rows[-1][-1])
    assert abs(gm.wrap_angle(true_h - theta)) < 1e-9


def test_mag_clockwise_gives_the_original_sign() -> None:
    store, node = ArgsStore("n1"), Resources()
    ctx = _train_ctx("mag", args=store, node=node)
    _fake_board(ctx)
    ccw, cw = Mag(), Mag()
    ccw.init({}, _train_ctx("mag", args=store, node=node))
    cw.init({"clockwise": True}, _train_ctx("mag", args=store, node=node))
    _use_clock(ctx, FakeClock(start=1002.0, step=0.0))  # same instant, held
    a, b = ccw.measure().values[0], cw.measure().values[0]
    assert gm.wrap_angle(a + b) == pytest.approx(0.0, abs=0.02)


def test_nav3_layout_units_and_bias_removal() -> None:
    ctx = make_ctx("nav3", {"scenario": "still"})
    _fake_board(ctx, {"model": {"hard_iron": PLANTED, "soft_iron": IDENTITY}})
    m = Nav3()
    m.init({"model": {"hard_iron": PLANTED, "soft_iron": IDENTITY}}, ctx)
    assert len(Nav3.columns) == 9
    vals = [m.measure().values for _ in range(500)]
    mean = [statistics.fmean(v[i] for v in vals) for i in range(9)]
    assert math.sqrt(sum(x * x for x in mean[0:3])) == pytest.approx(9.81, rel=0.05)
    assert mean[2] > 9.0  # flat: z up reads +g
    assert mean[3:6] == pytest.approx([0, 0, 0], abs=0.005)  # rad/s, bias removed
    field = environment({}).field
    mag = mean[6:9]
    assert math.sqrt(sum(x * x for x in mag)) == pytest.approx(gm.norm(field), rel=0.02)


def test_a_real_driver_replaces_the_simulator() -> None:
    class FlatBoard(NavDriverBase):
        def read_acc(self):
            return (0.0, 0.0, 1.0)

        def read_gyro(self):
            return (0.1, 0.2, 0.3)

        def read_mag(self):
            return (0.2, 0.0, -0.4)

        def read_baro(self):
            return 1000.0

    board = FlatBoard()
    assert isinstance(board, NavDriver)
    assert isinstance(_sim({"scenario": "still"}), NavDriver)
    ctx = make_ctx("nav")
    boards_of(ctx).register(board, board_id="n1/nav")
    m = Nav()
    m.init({"calib_samples": 5}, ctx)
    assert m.measure().values == pytest.approx((0.0, 0.0))
    with pytest.raises(ValueError, match="real driver"):
        from hera.nodes import faults

        faults.set_fault(boards_of(ctx), "n1/nav", "stuck")
    # a board that cannot turn itself: the measure waits for a calibration stored by hand
    mag_ctx = make_ctx("mag", resources=ctx.resources)
    with pytest.raises(NotReady) as e:
        Mag().init({}, mag_ctx)
    assert str(e.value) == (
        "no calibration stored at calib/n1/mag, and this board cannot turn itself: calibrate "
        "it by hand, a person turning it (turn=<a function asking them>); store its result "
        "with 'hera args set n1 calib/n1/mag JSON' (README: a real Pmod NAV)"
    )
    mag_ctx.args.put("calib/n1/mag", {"bias": [0.0, 0.0], "offset": 0.0, "n": 10})
    m = Mag()
    m.init({}, mag_ctx)  # then it starts with the stored one


def test_nav_args_are_checked() -> None:
    with pytest.raises(ValueError, match="unknown key 'calib'; known keys: board, .*calib_samples"):
        Nav().init({"calib": 3}, make_ctx("nav"))
    with pytest.raises(ValueError, match="calib_samples must be an integer >= 1, got 0"):
        Nav().init({"calib_samples": 0}, make_ctx("nav"))
    with pytest.raises(ValueError, match="unknown NAV model keys"):
        Nav().init({"model": {"noise": 1}, "board": "b2"}, make_ctx("nav"))
