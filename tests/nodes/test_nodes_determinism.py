"""Same seed, scenario and measurement times give the same readings; another seed does not."""

from __future__ import annotations

from nodes_helpers import FakeClock, make_ctx

from hera.nodes import boards
from hera.nodes.imu_model import NavModel
from hera.nodes.sim_nav import SimNavBoard
from hera.nodes.sim_sonar import SimMaxSonar
from hera.nodes.sonar_model import SonarModel
from hera.nodes.world import SonarMount, environment, make_scenario
from hera.resources import Resources

WORLD = {"scenario": "train", "epoch": 1000.0}


def _nav(seed: int) -> SimNavBoard:
    return SimNavBoard(
        "n1/nav",
        make_scenario(WORLD),
        environment(WORLD),
        1000.0,
        NavModel(),
        seed,
        FakeClock(start=1000.0, step=0.02),
    )


def test_nav_readings_repeat_for_the_same_seed_and_times() -> None:
    a, b, c = _nav(3), _nav(3), _nav(4)
    ra = [a.read_imu() for _ in range(200)]
    rb = [b.read_imu() for _ in range(200)]
    rc = [c.read_imu() for _ in range(200)]
    assert ra == rb
    assert [s.acc for s in ra] != [s.acc for s in rc]


def test_readings_do_not_depend_on_which_measure_reads_first() -> None:
    a, b = _nav(3), _nav(3)
    a.clock = b.clock = lambda: 1234.5
    acc_a, gyro_a = a.read_acc(), a.read_gyro()
    gyro_b, acc_b = b.read_gyro(), b.read_acc()
    assert (acc_a, gyro_a) == (acc_b, gyro_b)


def test_sonar_readings_repeat_for_the_same_seed_and_times() -> None:
    def run(seed: int) -> list[int]:
        s = SimMaxSonar(
            "n1/sonar",
            "n1/sonar",
            make_scenario(WORLD),
            1000.0,
            SonarMount((0.0, -1.5, 0.0), (0.0, 1.0, 0.0)),
            SonarModel(noise_m=0.03),
            seed,
            clock=FakeClock(start=1000.0, step=0.1),
            block=False,
        )
        return [s.read_range() for _ in range(100)]

    assert run(1) == run(1)
    assert run(1) != run(2)


def test_board_seed_comes_from_ctx_seed_or_the_seed_arg() -> None:
    def bias(seed: int, args: dict) -> tuple:
        return boards.open_nav(make_ctx("nav", WORLD, seed=seed), args).acc_bias

    assert bias(1, {}) == bias(1, {})
    assert bias(1, {}) != bias(2, {})
    assert bias(1, {"seed": 9}) == bias(2, {"seed": 9})
    one = boards.open_nav(make_ctx("nav", WORLD, node="n1"), {})
    two = boards.open_nav(make_ctx("nav", WORLD, node="n2"), {})
    assert one.acc_bias != two.acc_bias  # every node's board is a different board


def test_measures_of_one_node_share_one_board() -> None:
    node = Resources()
    a = boards.open_nav(make_ctx("nav", WORLD, resources=node), {})
    b = boards.open_nav(make_ctx("nav3", WORLD, resources=node), {})
    c = boards.open_nav(make_ctx("mag", WORLD, resources=node), {"board": "nav2"})
    assert a is b and a is not c
    assert boards.open_nav(make_ctx("nav", WORLD), {}) is not a  # another node's board
