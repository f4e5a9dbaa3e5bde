"""A driver's constructor and the spec check judge its arguments by the same check_args."""

from __future__ import annotations

import pytest

from hera.nodes.boards import driver_problems
from hera.nodes.driver_args import checked_args, constructor_args, problems_of


@checked_args
class Probe:
    """A driver whose check_args records what it was given."""

    seen: list[dict] = []

    def __init__(self, device: str = "/dev/x", rate: int = 10, *, opener=None) -> None:
        self.device, self.rate, self.opener = device, rate, opener

    @classmethod
    def check_args(cls, args):
        cls.seen.append(dict(args))
        out = []
        if not str(args["device"]).startswith("/dev/"):
            out.append(f"device must be a path under /dev, got {args['device']!r}")
        if args["rate"] not in (10, 20):
            out.append(f"rate must be 10 or 20, got {args['rate']!r}")
        return out


def test_the_constructor_refuses_every_problem_before_its_body_runs():
    Probe.seen.clear()
    with pytest.raises(ValueError) as e:
        Probe("tty0", 15)
    assert (
        str(e.value)
        == "device must be a path under /dev, got 'tty0'; rate must be 10 or 20, got 15"
    )
    # given every positional-or-keyword argument, defaults filled in, the test hooks left out
    Probe(rate=20, opener=print)
    assert Probe.seen == [{"device": "tty0", "rate": 15}, {"device": "/dev/x", "rate": 20}]


def test_a_good_call_builds_the_driver_as_written():
    p = Probe("/dev/y", opener=len)
    assert (p.device, p.rate, p.opener) == ("/dev/y", 10, len)
    assert list(constructor_args(Probe, "/dev/z")) == ["device", "rate"]


def test_a_call_that_does_not_fit_the_signature_is_a_type_error():
    with pytest.raises(TypeError):
        Probe("/dev/x", 10, 3)


def test_the_spec_check_finds_what_the_constructor_would_refuse():
    assert problems_of(Probe, {"rate": 30}) == ["rate must be 10 or 20, got 30"]
    assert problems_of(object, {}) == []  # no check_args: nothing to ask
    # a real driver, as a spec names it: the spec check and the constructor say the same
    target = "hera.nodes.ir.max31855:Max31855"
    args = {"device": "spidev0.1", "speed_hz": 1_000_000, "mode": 0}
    got = driver_problems({"driver": target, "driver_args": args}, "n1")
    assert got[0] == f"n1: driver_args: unknown key 'mode'; {target} takes device, speed_hz"
    assert len(got) == 2 and got[1].startswith("n1: driver_args: device ")
    from hera.nodes.ir.max31855 import Max31855

    with pytest.raises(ValueError) as e:
        Max31855("spidev0.1")
    assert f"n1: driver_args: {e.value}" == got[1]
