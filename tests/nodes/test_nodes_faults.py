"""Board faults switched on and off at run time through the control-plane entry point."""

from __future__ import annotations

import json
import statistics

import pytest
from hera.nodes import boards, faults
from hera.nodes.driver import BoardDisconnected
from hera.nodes.nav_measures import Nav3
from hera.nodes.sonar_measure import Sonar
from nodes_helpers import (
    FakeClock,
    fresh_boards,  # noqa: F401 - autouse fixture
    make_ctx,
)

WORLD = {"scenario": "still", "position": [0.0, 2.0, 0.0], "epoch": 0.0}


def _nav3(node: str = "n1") -> tuple[Nav3, object]:
    ctx = make_ctx("nav3", WORLD, node=node)
    boards.open_nav(ctx, {}).clock = FakeClock()  # reproducible readings
    m = Nav3()
    m.init({"calib_samples": 20}, ctx)
    return m, ctx


def test_stuck_then_cleared() -> None:
    m, _ = _nav3()
    assert m.measure().values != m.measure().values  # noise: never equal twice
    out = faults.handle_inject({"target": "board", "board": "n1/nav", "fault": "stuck"})
    assert out["ok"] and out["board"] == "n1/nav" and out["fault"]["fault"] == "stuck"
    frozen = [m.measure().values for _ in range(5)]
    assert all(v == frozen[0] for v in frozen)
    faults.handle_inject({"board": "n1/nav", "fault": "clear"})
    assert m.measure().values != m.measure().values


def test_dropout_gives_no_reading_and_is_counted() -> None:
    m, ctx = _nav3()
    faults.handle_inject({"board": "nav", "fault": "dropout"})  # bare name: unique here
    assert [m.measure() for _ in range(5)] == [None] * 5
    assert ctx.counters["dropouts"] == 5
    faults.clear_fault("nav")
    assert m.measure() is not None


def test_disconnect_raises_an_os_error_until_cleared() -> None:
    m, _ = _nav3()
    faults.set_fault("n1/nav", "disconnect")
    with pytest.raises(OSError):
        m.measure()
    with pytest.raises(BoardDisconnected):
        m.measure()
    faults.clear_fault("n1/nav")
    assert m.measure() is not None


def test_bias_and_spikes_on_one_sensor() -> None:
    m, _ = _nav3()
    before = statistics.fmean(m.measure().values[2] for _ in range(200))
    faults.set_fault("n1/nav", "bias", sensor="acc", value=[0.0, 0.0, 0.5])  # g
    after = statistics.fmean(m.measure().values[2] for _ in range(200))
    assert after - before == pytest.approx(0.5 * 9.81, abs=0.05)
    faults.set_fault("n1/nav", "spikes", sensor="gyro", prob=1.0, magnitude=500.0)
    gyro = [max(abs(v) for v in m.measure().values[3:6]) for _ in range(20)]
    assert all(g > 8.0 for g in gyro)  # 500 deg/s = 8.7 rad/s on one axis
    assert all(abs(v) < 1.5 for v in m.measure().values[0:2])  # acc untouched (5 deg tilt)


def test_sonar_faults() -> None:
    ctx = make_ctx("sonar", WORLD)
    s = Sonar()
    s.init({"ping_ms": 1, "position": [0, 0, 0], "direction": [0, 1, 0]}, ctx)
    s.sim.clock = FakeClock()
    faults.set_fault("n1/sonar", "stuck", value=40)
    assert s.measure().values[0] == pytest.approx(40 * 0.0254)
    faults.set_fault("n1/sonar", "bias", value=100)
    assert s.measure().values[0] == pytest.approx(1.95 + 100 * 0.0254, abs=0.06)
    faults.set_fault("n1/sonar", "disconnect")
    with pytest.raises(OSError):
        s.measure()
    faults.clear_fault("n1/sonar")
    assert s.measure().values[0] == pytest.approx(1.95, abs=0.06)


def test_list_boards_is_json_and_shows_the_fault() -> None:
    _nav3("n1")
    _nav3("n2")
    faults.set_fault("n2/nav", "dropout", prob=0.5, duration=60)
    listed = {b["board"]: b for b in faults.list_boards()}
    assert set(listed) == {"n1/nav", "n2/nav"}
    assert listed["n1/nav"]["fault"] is None
    assert listed["n2/nav"]["fault"]["fault"] == "dropout"
    assert listed["n2/nav"]["fault"]["prob"] == 0.5
    json.dumps(listed)


@pytest.mark.parametrize(
    ("request_", "message"),
    [
        ({"board": "n1/nav", "fault": "melt"}, "must be one of"),
        ({"board": "n9/nav", "fault": "stuck"}, "no board"),
        ({"fault": "stuck"}, "needs 'board'"),
        ({"target": "node", "board": "n1/nav", "fault": "stuck"}, "board faults only"),
        ({"board": "n1/nav", "fault": "bias"}, "needs a 'value'"),
        ({"board": "n1/nav", "fault": "dropout", "prob": 2}, r"within \[0, 1\]"),
        ({"board": "n1/nav", "fault": "spikes", "size": 3}, "unknown parameters"),
        ({"board": "n1/nav", "fault": "stuck", "sensor": "range"}, "sensor must be one of"),
        ({"board": "n1/nav", "fault": "bias", "value": [1, 2]}, "one number per axis"),
        ({"board": "n1/nav", "fault": "clear", "prob": 1}, "takes no parameters"),
        ({"board": "nav", "fault": "stuck"}, "ambiguous"),
        ("stuck", "must be a map"),
    ],
)
def test_bad_inject_requests_are_refused_clearly(request_, message) -> None:
    _nav3("n1")
    _nav3("n2")
    with pytest.raises(ValueError, match=message):
        faults.handle_inject(request_)
