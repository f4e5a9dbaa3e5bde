"""A node's clock skew (hera.wallclock): what it stamps moves, the simulated world does not."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from nodes_helpers import make_ctx

from hera import wallclock
from hera.args import ArgsStore
from hera.nodes.imu_model import NavModel
from hera.nodes.measures.sonar import Sonar
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.world import environment, make_scenario

WORLD = {"scenario": "train", "radius": 0.6, "omega": 0.84, "center": [0.0, 0.0], "epoch": 0.0}


@pytest.fixture
def skew() -> Iterator:
    yield wallclock.set_offset
    wallclock.set_offset(0.0)


def test_the_offset_is_checked_and_read_back(skew):
    assert wallclock.offset() == 0.0
    assert skew(0.25) == 0.0 and wallclock.offset() == 0.25
    with pytest.raises(ValueError, match="clock skew must be a number of seconds"):
        skew(float("nan"))
    with pytest.raises(ValueError, match="within \\+/-3600"):
        skew(7200)
    assert wallclock.offset() == 0.25


def test_a_skewed_nav_board_senses_the_true_world_and_stamps_its_own_clock(skew):
    clock = iter([100.0, 100.0])

    def board() -> SimNavBoard:
        return SimNavBoard(
            "n/nav",
            make_scenario(WORLD),
            environment(WORLD),
            0.0,
            NavModel(),
            7,
            clock=lambda: next(clock),
        )

    true = board().read_imu()
    clock = iter([100.0])
    skew(0.5)
    shifted = board().read_imu()
    assert shifted.t == pytest.approx(true.t + 0.5)
    assert shifted.acc == true.acc and shifted.gyro == true.gyro  # the same world, same noise


def test_a_skewed_sonar_pings_in_true_time_and_stamps_its_own_clock(skew, tmp_path):
    ctx = make_ctx("sonar", {"scenario": "still", "position": [0.0, 2.0, 0.0], "epoch": 0.0})
    m = Sonar()
    m.init(
        {
            "position": [0, 0, 0],
            "direction": [0, 1, 0],
            "ping_ms": 1,
            "fire_log": str(tmp_path / "fire.log"),
        },
        ctx,
    )
    skew(-3.0)
    before = time.time()
    r = m.measure()
    assert r is not None and r.t == pytest.approx(before - 3.0, abs=0.5)
    start, end, node, *grant = (tmp_path / "fire.log").read_text().split()
    assert grant == ["-", "-", "-"]  # not synchronised
    assert float(end) - float(start) == pytest.approx(0.001, abs=2e-6)


def test_args_written_by_a_skewed_node_carry_its_clock(skew):
    store = ArgsStore("n1")
    skew(-10.0)
    store.put("calib/x", 1)
    stamp = store._entries["calib/x"][0]
    assert stamp / 1e9 == pytest.approx(time.time() - 10.0, abs=0.5)


def test_a_node_skewed_past_the_bound_has_its_args_refused_by_the_others(skew):
    """Args stamps are hybrid logical clocks on the node's clock: a writer 2 s ahead is
    further ahead than a receiver on the true clock takes (1 s), and is refused there;
    0.3 s ahead (the nemesis's range) is taken."""
    far, near = ArgsStore("n1"), ArgsStore("n3")  # two writers: a clock never runs back
    receiver = ArgsStore("n2", max_skew_ns=1_000_000_000)
    skew(2.0)
    far.put("calib/far", 1)
    skew(0.3)
    near.put("calib/near", 2)
    skew(0.0)
    receiver._merge("calib/far", *far._entries["calib/far"])
    receiver._merge("calib/near", *near._entries["calib/near"])
    assert receiver.get("calib/near") == 2 and receiver.get("calib/far") is None
    assert receiver.rejected == {"future": 1}
