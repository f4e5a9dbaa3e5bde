"""Board faults switched on and off at run time through the simulator's ``board`` verb."""

from __future__ import annotations

import json
import statistics

import pytest
from nodes_helpers import FakeClock, boards_of, make_ctx

from hera.application import VerbContext
from hera.nodes import boards, faults
from hera.nodes.driver import BoardDisconnected
from hera.nodes.measures.nav import Nav3
from hera.nodes.measures.sonar import Sonar
from hera.resources import Resources

WORLD = {"scenario": "still", "position": [0.0, 2.0, 0.0], "epoch": 0.0}


def _nav3(resources: Resources | None = None, board: str = "nav") -> tuple[Nav3, object]:
    ctx = make_ctx("nav3", WORLD, resources=resources)
    boards.open_nav(ctx, {"board": board}).clock = FakeClock()  # reproducible readings
    m = Nav3()
    m.init({"calib_samples": 20, "board": board}, ctx)
    return m, ctx


def _verb(ctx, request):
    return faults.board_verb(request, VerbContext("n1", "t", WORLD, ctx.resources))


def test_stuck_then_cleared() -> None:
    m, ctx = _nav3()
    assert m.measure().values != m.measure().values  # noise: never equal twice
    out = _verb(ctx, {"board": "n1/nav", "fault": "stuck"})
    assert out["board"] == "n1/nav" and out["fault"]["fault"] == "stuck"
    frozen = [m.measure().values for _ in range(5)]
    assert all(v == frozen[0] for v in frozen)
    _verb(ctx, {"board": "n1/nav", "fault": "clear"})
    assert m.measure().values != m.measure().values


def test_dropout_gives_no_reading_and_is_counted() -> None:
    m, ctx = _nav3()
    _verb(ctx, {"board": "nav", "fault": "dropout"})  # bare name: unique here
    assert [m.measure() for _ in range(5)] == [None] * 5
    assert ctx.counters["dropouts"] == 5
    faults.clear_fault(boards_of(ctx), "nav")
    assert m.measure() is not None


def test_disconnect_makes_every_read_raise_until_cleared() -> None:
    m, ctx = _nav3()
    faults.set_fault(boards_of(ctx), "n1/nav", "disconnect")
    with pytest.raises(BoardDisconnected):  # an OSError, as an I2C error would be
        m.board.read_imu(mag=True)
    with pytest.raises(OSError):
        m.board.read_acc()
    # the measure publishes nothing and counts it (hera.nodes.board_reads)
    assert [m.measure() for _ in range(2)] == [None, None]
    assert ctx.counters["disconnected"] == 2
    faults.clear_fault(boards_of(ctx), "n1/nav")
    assert m.measure() is not None


def test_bias_and_spikes_on_one_sensor() -> None:
    m, ctx = _nav3()
    before = statistics.fmean(m.measure().values[2] for _ in range(200))
    faults.set_fault(boards_of(ctx), "n1/nav", "bias", sensor="acc", value=[0.0, 0.0, 0.5])  # g
    after = statistics.fmean(m.measure().values[2] for _ in range(200))
    assert after - before == pytest.approx(0.5 * 9.81, abs=0.05)
    faults.set_fault(boards_of(ctx), "n1/nav", "spikes", sensor="gyro", prob=1.0, magnitude=500.0)
    gyro = [max(abs(v) for v in m.measure().values[3:6]) for _ in range(20)]
    assert all(g > 8.0 for g in gyro)  # 500 deg/s = 8.7 rad/s on one axis
    assert all(abs(v) < 1.5 for v in m.measure().values[0:2])  # acc untouched (5 deg tilt)


def test_sonar_faults() -> None:
    ctx = make_ctx("sonar", WORLD)
    s = Sonar()
    s.init({"ping_ms": 1, "position": [0, 0, 0], "direction": [0, 1, 0]}, ctx)
    s.sim.clock = FakeClock()
    b = boards_of(ctx)
    faults.set_fault(b, "n1/sonar", "stuck", value=40)
    assert s.measure().values[0] == pytest.approx(40 * 0.0254)
    faults.set_fault(b, "n1/sonar", "bias", value=100)
    assert s.measure().values[0] == pytest.approx(1.95 + 100 * 0.0254, abs=0.06)
    faults.set_fault(b, "n1/sonar", "disconnect")
    with pytest.raises(BoardDisconnected):
        s.board.read_sample()
    assert s.measure() is None and ctx.counters["disconnected"] == 1
    faults.clear_fault(b, "n1/sonar")
    assert s.measure().values[0] == pytest.approx(1.95, abs=0.06)


def test_list_boards_is_json_and_shows_the_fault() -> None:
    node = Resources()
    _, ctx = _nav3(node)
    _nav3(node, board="nav2")
    _verb(ctx, {"board": "n1/nav2", "fault": "dropout", "prob": 0.5, "duration": 60})
    listed = {b["board"]: b for b in _verb(ctx, {})["boards"]}
    assert set(listed) == {"n1/nav", "n1/nav2"}
    assert listed["n1/nav"]["fault"] is None
    assert listed["n1/nav2"]["fault"]["fault"] == "dropout"
    assert listed["n1/nav2"]["fault"]["prob"] == 0.5
    json.dumps(listed)


def test_nodes_do_not_share_boards() -> None:
    _, one = _nav3()
    _, two = _nav3()
    assert boards_of(one).get("n1/nav") is not boards_of(two).get("n1/nav")


@pytest.mark.parametrize(
    ("request_", "message"),
    [
        ({"board": "n1/nav", "fault": "melt"}, "must be one of"),
        ({"board": "n9/nav", "fault": "stuck"}, "no board"),
        ({"fault": "stuck"}, "needs 'board'"),
        ({"board": "n1/nav", "fault": "bias"}, "needs a 'value'"),
        ({"board": "n1/nav", "fault": "dropout", "prob": 2}, r"within \[0, 1\]"),
        ({"board": "n1/nav", "fault": "spikes", "size": 3}, "unknown parameters"),
        ({"board": "n1/nav", "fault": "stuck", "sensor": "range"}, "sensor must be one of"),
        ({"board": "n1/nav", "fault": "bias", "value": [1, 2]}, "one number per axis"),
        ({"board": "n1/nav", "fault": "clear", "prob": 1}, "takes no parameters"),
    ],
)
def test_bad_board_requests_are_refused_clearly(request_, message) -> None:
    _, ctx = _nav3()
    with pytest.raises(ValueError, match=message):
        _verb(ctx, request_)
