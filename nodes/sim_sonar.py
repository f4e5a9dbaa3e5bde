"""A simulated Pmod MAXSONAR: pings the world's target, occupies the air, suffers cross-talk.

It implements :class:`hera.nodes.driver.SonarDriver`. Each reading is one ping that takes
``model.ping_ms`` (the call blocks that long when ``block`` is true, as the real sensor takes
that long per reading). The ping is announced on the group's :class:`~hera.nodes.air.Air`;
if another sonar of the group sounded during it, the reading is corrupted (see
:func:`corrupted_range`) and the sample says ``crosstalk=True``.

``fire_log`` (a path) audits the real trigger times: one line per ping, written at the
trigger, ``start end node epoch token deadline`` with ``start`` the clock reading of the
trigger-time check and ``end = start + ping`` (a stopped process does not prolong a sound)
on the sync clock (:mod:`hera.sync.clock`, one clock for every process of a host), and the
grant it sounded under (``-`` when not synchronised): its epoch, token and lease deadline.
"""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hera import wallclock
from hera.nodes import geometry as gm
from hera.nodes.air import Air, Ping
from hera.nodes.driver import RangeSample
from hera.nodes.fault_model import FaultState
from hera.nodes.noise import KeyedRandom
from hera.nodes.sonar_model import INCH, SonarModel, echo_range, nearest_surface, to_inches
from hera.nodes.world import Motion, Scenario, SonarMount, State, Target, state_at, state_of
from hera.sync import clock as sync_clock


def corrupted_range(
    ping: Ping,
    other: Ping,
    true_m: float | None,
    target_pos: gm.Vec3,
    model: SonarModel,
    rng: random.Random,
) -> float:
    """The range (m) a sonar reports when ``other`` sounded during its ``ping``.

    The receiver takes the first pulse it hears for its echo. The other sonar's pulse,
    reflected by the target, arrives ``dt = other.start - ping.start + path / c`` after our
    ping started (path = other sonar -> target -> us), i.e. a phantom range ``c dt / 2``. If
    that is not shorter than the true range (or is negative: the receiver was blanked), the
    reading is a random early echo, uniform between the minimum range and the true range.
    """
    c = model.speed_of_sound
    path = gm.norm(gm.sub(other.position, target_pos)) + gm.norm(gm.sub(target_pos, ping.position))
    phantom = c * (other.start - ping.start + path / c) / 2.0
    far = true_m if true_m is not None else model.max_in * INCH
    low = model.min_in * INCH
    if low <= phantom < far:
        return phantom
    return rng.uniform(low, max(low, far))


class SimMaxSonar:
    """Simulated MaxSonar at ``mount`` seeing ``scenario``'s target."""

    kind = "maxsonar"
    sensors = {"range": 1}

    def __init__(
        self,
        board_id: str,
        sender: str,
        scenario: Scenario,
        epoch: float,
        mount: SonarMount,
        model: SonarModel,
        seed: int,
        *,
        target: Target | None = None,
        clock: Callable[[], float] = time.time,
        air: Air | None = None,
        block: bool = True,
        fire_log: str | None = None,
        node: str = "",
    ) -> None:
        self.id, self.sender, self.node = board_id, sender, node
        self.scenario, self.epoch, self.mount, self.model = scenario, float(epoch), mount, model
        self.target = target if target is not None else scenario.target
        self.seed = int(seed)
        self.rand = KeyedRandom(self.seed)
        self.clock, self.air, self.block = clock, air, block
        self.fire_log = Path(fire_log) if fire_log else None
        self.half_angle = math.radians(model.half_angle_deg)
        self.faults = FaultState(self.sensors)
        self.pings = 0
        self.crosstalk = 0
        self._lock = threading.Lock()  # one ping at a time per board

    def true_range(self, t: float) -> float | None:
        """The noise-free nearest-surface range (m) at epoch time ``t``, None if unseen."""
        return nearest_surface(self.mount, self.half_angle, self._motion(t), self.target)

    def truth(self, t: float) -> State:
        """The target's true state at epoch time ``t`` (a
        :class:`~hera.nodes.driver.SimulatedSonar`)."""
        return state_at(self.scenario, self.epoch, t)

    def rest_truth(self) -> State:
        """The target's true state in the rest pose."""
        return state_of(self.scenario.rest_motion(), self.epoch)

    def _motion(self, t: float) -> Motion:
        return self.scenario.motion(t - self.epoch)

    def read_range(self) -> int:
        return self.read_sample().inches

    def read_sample(self, grant: Any = None) -> RangeSample:
        """Ping once (blocking ``ping_ms`` if ``block``) and return the reading.

        ``grant``: the sync turn (``hera.sync.client.Turn``) of a synchronised step. Its fit
        check runs right at the trigger, and the ping starts at that same clock reading;
        ``SlotLost`` from it propagates (no ping)."""
        with self._lock:
            ping_s = self.model.ping_ms / 1000.0
            if grant is None:
                t, start = self.clock(), sync_clock.now()
            else:
                trigger = grant.check_at_trigger(self.clock, ping_s)
                t, start = trigger.wall, trigger.clock
            rng = self.rand.rng("range", t)
            self.faults.before_read("range", rng)
            ping = Ping(self.sender, t, t + ping_s, self.mount.position)
            mono0 = time.monotonic()
            self._log_firing(start, start + ping_s, grant)
            if self.air is not None:
                self.air.announce(ping, grant)
            if self.block:
                while (left := mono0 + ping_s - time.monotonic()) > 0:
                    time.sleep(left)
            m = self._motion(t)
            true_m = nearest_surface(self.mount, self.half_angle, m, self.target)
            heard = echo_range(true_m, self._clutter, self.model, rng)
            inches = to_inches(heard, self.model, rng)
            others = self.air.overlapping(ping) if self.air is not None else []
            if others:
                first = min(others, key=lambda p: p.start)
                r = corrupted_range(ping, first, true_m, m.position, self.model, rng)
                inches = to_inches(r, self.model, rng)
                self.crosstalk += 1
            self.pings += 1
            value = self.faults.after_read("range", (float(inches),), rng)[0]
            inches = max(0, round(value))
            # the world is sensed at the true time; the reading is stamped with the node's clock
            return RangeSample(t + wallclock.offset(), inches, bool(others))

    def _clutter(self, u: float) -> float | None:
        """The range of the first clutter echo (far side, multipath) at ``u``, if any."""
        return self.scenario.clutter_range(self.mount, self.half_angle, u)

    def _log_firing(self, start: float, end: float, grant: Any) -> None:
        """Append ``start end node epoch token deadline`` to the fire log (the audit of real
        trigger times; ``-`` for the grant fields of an unsynchronised ping), at the trigger,
        before the ping, so that a process killed while it sounds leaves its line."""
        if self.fire_log is None:
            return
        if grant is None:
            label = "- - -"
        else:
            label = f"{int(grant.epoch)} {int(grant.token)} {float(grant.deadline):.6f}"
        line = f"{start:.6f} {end:.6f} {self.node or self.sender} {label}\n"
        self.fire_log.parent.mkdir(parents=True, exist_ok=True)
        with open(self.fire_log, "a") as f:
            f.write(line)

    def describe(self) -> dict[str, Any]:
        """JSON-able status for ``list_boards``."""
        f = self.faults.current()
        return {
            "board": self.id,
            "kind": self.kind,
            "sensors": sorted(self.sensors),
            "pings": self.pings,
            "crosstalk": self.crosstalk,
            "position": list(self.mount.position),
            "direction": list(self.mount.direction),
            "fault": None if f is None else f.describe(),
        }
