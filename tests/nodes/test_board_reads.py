"""A board that stops answering: its measure publishes nothing, counts it, says it in the
log at a slow pace, and reads again each step (``hera.nodes.board_reads``); every board
measure of the project does so, on its simulator's ``disconnect`` fault."""

from __future__ import annotations

import logging

import pytest
from nodes_helpers import FakeClock, make_ctx

from hera.measure import NotReady
from hera.nodes import boards
from hera.nodes.board_reads import WARN_EVERY_S, BoardReads, board_needed
from hera.nodes.driver import BoardDisconnected, NoReading
from hera.nodes.ir.measures import SharpIr, Thermocouple
from hera.nodes.lsm6dsl.measures import Lsm6dsl
from hera.nodes.measures.nav import Mag, Nav, Nav3
from hera.nodes.measures.sonar import Sonar
from hera.nodes.tof.measures import Vl53l1


class Script:
    """A driver read that raises or returns what it is told, one item per call."""

    def __init__(self, *items: object) -> None:
        self.items = list(items)

    def __call__(self) -> object:
        item = self.items.pop(0)
        if isinstance(item, BaseException):
            raise item
        return item


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _reads(caplog) -> tuple[BoardReads, object, Clock]:
    caplog.set_level(logging.INFO, logger="hera.measure")
    ctx = make_ctx("sonar")
    clock = Clock()
    return BoardReads(ctx, clock), ctx, clock


def test_dropouts_and_disconnections_give_none_and_are_counted_apart(caplog) -> None:
    reads, ctx, _ = _reads(caplog)
    unplugged = BoardDisconnected("serial port /dev/ttyUSB0: No such file or directory")
    read = Script(1, NoReading("none"), unplugged, unplugged, 2)
    assert [reads.read(read) for _ in range(5)] == [1, None, None, None, 2]
    assert ctx.counters == {"dropouts": 1, "disconnected": 2}
    assert not reads.away


def test_an_outage_is_warned_once_then_every_few_seconds_and_its_end_is_told(caplog) -> None:
    reads, ctx, clock = _reads(caplog)
    down = BoardDisconnected("board gone")
    read = Script(*[down] * 4, "back")
    reads.read(read)  # the first read of the outage: warned at once
    assert reads.away and ctx.trouble == "board not answering (board gone)"
    clock.t += WARN_EVERY_S - 0.1
    reads.read(read)  # too soon for another line
    clock.t += 0.2
    reads.read(read)  # WARN_EVERY_S after the first: one more
    clock.t += 1.0
    reads.read(read)
    clock.t += 0.5
    assert reads.read(read) == "back" and not reads.away and ctx.trouble is None
    lines = [(r.levelname, r.getMessage()) for r in caplog.records]
    assert lines == [
        ("WARNING", "sonar: board gone (disconnected for 0.0 s; reading again every step)"),
        ("WARNING", "sonar: board gone (disconnected for 5.1 s; reading again every step)"),
        ("INFO", "sonar: the board answers again after 6.6 s away"),
    ]
    assert ctx.counters == {"disconnected": 4}


def test_a_second_outage_is_warned_at_once(caplog) -> None:
    reads, _, clock = _reads(caplog)
    down = BoardDisconnected("board gone")
    read = Script(down, "back", down)
    reads.read(read)
    clock.t += 0.5
    reads.read(read)
    clock.t += 0.5  # within WARN_EVERY_S of the last warning, but a new outage
    reads.read(read)
    assert [r.levelname for r in caplog.records] == ["WARNING", "INFO", "WARNING"]


def test_a_bus_error_the_driver_lets_through_is_a_board_not_answering(caplog) -> None:
    reads, ctx, _ = _reads(caplog)
    eremoteio = OSError(121, "Remote I/O error")  # smbus2 reading an unplugged I2C chip
    read = Script(eremoteio, PermissionError(13, "Permission denied"), 3)
    assert [reads.read(read) for _ in range(3)] == [None, None, 3]
    assert ctx.counters == {"disconnected": 2}
    assert "sonar: [Errno 121] Remote I/O error (disconnected for 0.0 s" in caplog.text


def test_errors_that_are_no_os_error_are_not_swallowed(caplog) -> None:
    reads, ctx, _ = _reads(caplog)
    with pytest.raises(ValueError):  # the driver could not make sense of what it read
        reads.read(Script(ValueError("garbled")))
    assert ctx.counters == {} and not reads.away


# -- every board measure, on its simulator ---------------------------------------------------

STILL = {"scenario": "still", "epoch": 0.0}
MEASURES = {
    "nav": (Nav, STILL, {"calib_samples": 5}),
    "mag": (Mag, STILL, {"calib_samples": 5}),
    "nav3": (Nav3, STILL, {"calib_samples": 5}),
    "sonar": (
        Sonar,
        {**STILL, "position": [0.0, 2.0, 0.0]},
        {"ping_ms": 1, "position": [0, 0, 0], "direction": [0, 1, 0]},
    ),
    "vl53l1": (Vl53l1, {"scenario": "desk", "epoch": 0.0}, {}),
    "lsm6dsl": (Lsm6dsl, {"scenario": "balancing", "epoch": 0.0}, {"calibration": "on_request"}),
    "sharp_ir": (SharpIr, {"scenario": "ir_stationary", "epoch": 1000.0}, {"variant": "long"}),
    "thermocouple": (Thermocouple, {"scenario": "ir_plate", "epoch": 1000.0}, {}),
}


@pytest.mark.parametrize("name", sorted(MEASURES))
def test_every_board_measure_goes_on_through_an_unplugged_board(name: str) -> None:
    cls, world, args = MEASURES[name]
    ctx = make_ctx(name, world, period=cls.period)
    m = cls()
    m.init(args, ctx)
    m.board.clock = FakeClock(world["epoch"] + 1.0, cls.period)
    assert m.measure() is not None
    m.board.faults.set("disconnect")  # each read of the board raises BoardDisconnected
    assert [m.measure() for _ in range(3)] == [None] * 3  # the measure does not crash
    assert ctx.counters["disconnected"] == 3
    m.board.faults.clear()
    assert m.measure() is not None  # back at the next step, without a restart
    m.close()


# -- a board that does not answer when its measure starts ------------------------------------


def test_board_needed_turns_a_disconnected_board_into_not_ready() -> None:
    says = r"^board not answering \(I2C bus error\)$"
    with pytest.raises(NotReady, match=says), board_needed():
        raise BoardDisconnected("I2C bus error")
    with pytest.raises(NotReady, match=r"\(\[Errno 121\] Remote I/O error\)$"), board_needed():
        raise OSError(121, "Remote I/O error")
    with pytest.raises(NoReading), board_needed():  # a dropout is no reason to wait
        raise NoReading("none")
    with pytest.raises(ValueError), board_needed():
        raise ValueError("not a board's answer")


@pytest.mark.parametrize("cls", [Nav, Mag, Nav3])
def test_a_nav_measure_waits_for_its_board_to_calibrate_unless_it_has_a_calibration(cls):
    world = {"scenario": "still", "epoch": 0.0}
    ctx = make_ctx(cls.name, world)
    boards.open_nav(ctx, {}).faults.set("disconnect")  # the node's board, unplugged
    with pytest.raises(NotReady, match="board not answering"):
        cls().init({"calib_samples": 5}, ctx)
    boards.of(ctx.resources).get("nav").faults.clear()
    m = cls()
    m.init({"calib_samples": 5}, ctx)  # plugged in: it calibrates (and stores it)
    assert m.measure() is not None
    boards.of(ctx.resources).get("nav").faults.set("disconnect")
    again = cls()
    again.init({"calib_samples": 5}, ctx)  # the stored calibration: no read needed to start
    assert again.measure() is None and ctx.counters["disconnected"] == 1
