"""The world's scenarios: consistent kinematics, shared truth, clear errors."""

from __future__ import annotations

import math

import pytest

from hera.examples import examples
from hera.nodes import geometry as gm
from hera.nodes.app import Simulator
from hera.nodes.lsm6dsl.app import Lsm6dslBoards
from hera.nodes.tof.app import Vl53l1Boards
from hera.nodes.world import SCENARIOS, make_scenario, state_at, truth_at
from hera.spec import load_spec

H = 1e-4


def _fd(f, tau):
    """Central finite difference of a vector function."""
    a, b = f(tau - H), f(tau + H)
    return tuple((y - x) / (2 * H) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("kind", SCENARIOS)
@pytest.mark.parametrize("tau", [0.37, 3.1, 7.77, 13.3])
def test_velocity_acceleration_and_rate_are_derivatives(kind: str, tau: float) -> None:
    sc = make_scenario({"scenario": kind})
    m = sc.motion(tau)
    vel = _fd(lambda s: sc.motion(s).position, tau)
    acc = _fd(lambda s: sc.motion(s).velocity, tau)
    assert vel == pytest.approx(m.velocity, abs=1e-4)
    assert acc == pytest.approx(m.acceleration, abs=1e-3)
    # q_dot = 1/2 q (0, omega_body): recover omega_body from the quaternion's derivative
    qd = _fd(lambda s: sc.motion(s).orientation, tau)
    w = gm.quat_mul(gm.conj(m.orientation), qd)
    assert (2 * w[1], 2 * w[2], 2 * w[3]) == pytest.approx(m.angular_rate, abs=1e-4)
    assert sum(c * c for c in m.orientation) == pytest.approx(1.0)


def test_train_defaults_follow_the_thesis_setup() -> None:
    world = {"scenario": "train", "epoch": 1000.0}
    for t in (1000.0, 1003.3, 1010.0):
        s = truth_at(world, t)
        assert math.hypot(s.position[0], s.position[1]) == pytest.approx(0.6)
        assert math.hypot(*s.velocity[:2]) == pytest.approx(0.6 * 0.84)
        assert s.angular_rate == pytest.approx((0, 0, 0.84))
        # the board's y axis points to the centre: centripetal acceleration r omega^2 on +y
        body = gm.unrotate(s.orientation, s.acceleration)
        assert body == pytest.approx((0.0, 0.6 * 0.84**2, 0.0), abs=1e-12)
    theta = math.atan2(truth_at(world, 1002.0).position[1], truth_at(world, 1002.0).position[0])
    assert theta == pytest.approx(0.84 * 2.0)


def test_every_process_agrees_on_the_truth() -> None:
    world = {"scenario": "target3d", "epoch": 5.0, "amplitude": 0.4}
    sc = make_scenario(world)
    for t in (5.0, 9.9, 17.2, 40.0):
        assert truth_at(world, t) == truth_at(dict(world), t) == state_at(sc, 5.0, t)


def test_target3d_moves_along_one_axis_at_a_time() -> None:
    sc = make_scenario({"scenario": "target3d", "period": 6.0})
    for leg, axis in ((0, 0), (1, 1), (2, 2), (3, 0)):
        p = sc.motion(leg * 6.0 + 3.0).position
        moved = [abs(p[i] - 1.0) > 1e-9 for i in range(3)]
        assert moved == [i == axis for i in range(3)]


def test_rotations_turn_360_degrees() -> None:
    for kind, duration in (("rotation_slow", 12.0), ("rotation_fast", 2.0)):
        sc = make_scenario({"scenario": kind})
        # integrate the rate over one turn (rest 2 s then duration)
        n = 4000
        dt = duration / n
        total = sum(sc.motion(2.0 + (i + 0.5) * dt).angular_rate[2] * dt for i in range(n))
        assert total == pytest.approx(2 * math.pi, rel=1e-4)


def test_bad_worlds_are_refused_clearly() -> None:
    with pytest.raises(ValueError, match="unknown world scenario"):
        make_scenario({"scenario": "boat"})
    with pytest.raises(ValueError, match="radius"):
        make_scenario({"scenario": "train", "radius": -1})
    with pytest.raises(ValueError, match="unknown world keys"):
        make_scenario({"scenario": "train", "radios": 1})
    with pytest.raises(ValueError, match="number"):
        make_scenario({"scenario": "train", "omega": "fast"})


@pytest.mark.parametrize(
    ("app", "example"),
    [(Simulator, "train"), (Vl53l1Boards, "tof_height"), (Lsm6dslBoards, "tilt")],
)
def test_every_simulated_board_application_checks_the_whole_world(app, example) -> None:
    world = load_spec(examples()[example]).world
    assert app().check_world(world) == []
    for bad, says in [
        ({"scenario": "boat"}, "unknown world scenario 'boat'"),
        ({**world, "radios": 1}, "unknown world keys for scenario"),
        ({**world, "altitude": "high"}, "altitude"),
        ({**world, "epoch": "now"}, "epoch"),
    ]:
        problems = app().check_world(bad)
        assert len(problems) == 1 and says in problems[0], (bad, problems)
