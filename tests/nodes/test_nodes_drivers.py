"""Measures reach boards only through the driver protocols: fake drivers (not simulator
classes) take the simulator's place, registered on the node or named in the spec."""

from __future__ import annotations

import pytest
from fake_drivers import FixedSonar, LevelNav
from nodes_helpers import boards_of, make_ctx

from hera.nodes.driver import NavDriver, SonarDriver
from hera.nodes.measures.nav import Nav
from hera.nodes.measures.sonar import Sonar

WORLD = {"scenario": "train", "epoch": 0.0}


def test_the_fakes_satisfy_the_protocols_and_are_not_simulators():
    assert isinstance(LevelNav(), NavDriver) and isinstance(FixedSonar(), SonarDriver)
    assert not hasattr(LevelNav(), "faults") and not hasattr(FixedSonar(), "truth")


def test_nav_runs_on_a_driver_registered_on_its_node():
    ctx = make_ctx("nav", WORLD)
    board = boards_of(ctx).register(LevelNav(gyro_z=3.0), "n1/nav")
    m = Nav()
    m.init({"calib_samples": 10}, ctx)
    assert board.reads == 20  # calibrated on it: 10 acc + 10 gyro reads
    a_y, g_z = m.measure().values
    assert a_y == pytest.approx(0.0) and g_z == pytest.approx(0.0)  # offset calibrated away


def test_sonar_runs_on_a_driver_named_in_its_args():
    ctx = make_ctx("sonar", WORLD, sync_group="sonar")
    m = Sonar()
    args = {"driver": "fake_drivers:FixedSonar", "driver_args": {"inches": 50}}
    m.init({**args, "position": [1.0, 2.0, 0.0], "direction": [0, 1, 0]}, ctx)
    board = boards_of(ctx).get("n1/sonar")
    assert isinstance(board, FixedSonar) and m.sim is None
    ctx.grant = grant = object()
    assert m.measure().values == pytest.approx((50 * 0.0254, 1.0, 2.0))
    assert board.grants == [grant]  # the driver is handed the grant it runs under
    assert ctx.counters == {"pings": 1}


def test_a_driver_that_is_not_a_board_is_refused():
    with pytest.raises(ValueError, match="does not implement the SonarDriver driver protocol"):
        Sonar().init({"driver": "fake_drivers:LevelNav"}, make_ctx("sonar", WORLD))
    with pytest.raises(ValueError, match="driver 'fake_drivers:Nope' cannot be loaded"):
        Nav().init({"driver": "fake_drivers:Nope"}, make_ctx("nav", WORLD))


def test_a_drivers_arguments_are_checked_against_its_constructor():
    args = {"driver": "fake_drivers:FixedSonar", "driver_args": {"inchs": 50}}
    with pytest.raises(ValueError) as e:
        Sonar().init({**args, "position": [1.0, 2.0, 0.0]}, make_ctx("sonar", WORLD))
    assert str(e.value) == (
        "driver 'fake_drivers:FixedSonar': driver_args: unknown key 'inchs' (did you mean "
        "'inches'?); fake_drivers:FixedSonar takes inches"
    )
    assert Sonar.check_args(args, "here") == [
        "here: driver_args: unknown key 'inchs' (did you mean 'inches'?); "
        "fake_drivers:FixedSonar takes inches"
    ]


def test_the_node_stopping_closes_every_board_that_can_close():
    from hera.nodes.boards import Boards

    class Port(FixedSonar):
        def __init__(self, fails: bool = False) -> None:
            super().__init__()
            self.closed, self.fails = 0, fails

        def close(self) -> None:
            self.closed += 1
            if self.fails:
                raise OSError("the port hung")

    registry = Boards()
    ports = [registry.register(Port(fails=i == 0), f"n1/s{i}") for i in range(3)]
    registry.register(LevelNav(), "n1/nav")  # no close(): left alone
    registry.close()
    assert [p.closed for p in ports] == [1, 1, 1]  # the one that failed did not stop the rest
    assert registry.ids() == []
