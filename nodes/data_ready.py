"""When a polled chip made its samples: times from the edges of its data-ready flag.

A chip such as the LSM6DSL makes a sample every period of its own oscillator (off from the
nominal rate by a percent or two) and raises a data-ready flag; a driver that reads the
sample when the host's schedule comes round stamps it late by anything up to a period, a
sawtooth as the two clocks slide past each other, and a fusion model then integrates its
gyroscope over the wrong intervals (measured in the tilt application: a chip 1.5 % off took
the tilt RMSE from 0.13-0.19 deg to 0.41-0.81 deg). :class:`DataReadyClock` is what a
driver's polling loop needs to stamp each sample on the chip's own clock:

- a sample seen between a poll that found the flag low and one that found it high, at most
  :data:`EDGE_POLLS` poll intervals apart (an *edge*), was made between the two;
- the chip's clock (when its last sample was made, and its period) is tracked from the
  edges by a two-state Kalman filter, phase += k period over the k periods since the last
  edge (a constant-velocity model: the filter of :mod:`hera.estimation` would do, this one
  is written out for its 2x2 case because it runs in a driver's thread at every sample),
  each edge measuring the phase at its midpoint with the variance of a uniform spread over
  the two polls, ``(high - low)^2 / 12``; the stamp is the filtered phase, kept between the
  two polls (the sample was certainly made there). Raw midpoints jitter by up to half a
  poll, so any one interval between them carries that quantisation (a median of them was
  measured 0.13 ms off at 104 Hz); the filtered stamps follow the chip's period to a small
  fraction of a poll, because the polls, on a grid anchored at the predicted instant, land
  on either side of it and so tell which way the estimate is off;
- an edge that cannot be counted (the prediction for it is not within a period over
  :data:`COUNT_SIGMAS` sigmas), or lies far off the tracked clock (beyond
  :data:`GATE_SIGMAS` sigmas and :data:`RELOCK_POLLS` polls: a reset chip, a long gap)
  starts the tracking again from that edge, the period learnt kept;
- a sample found already there (or after a gap in the polls) is stamped at the chip's
  predicted instant for it (the tracked phase plus whole periods: the latest by then, and
  at least one period after the last sample's), kept after the last poll that saw none and
  the last sample taken; without a prediction that fits, when it was seen, and the next
  sample is then polled for at every poll interval to find its edge;
- the next poll is due two polls before the next predicted instant, so a slow chip costs
  few polls.

Pure: the caller gives every time (seconds of one monotonic clock), so it is tested on an
injected clock; :mod:`hera.nodes.lsm6dsl.i2c` runs it in its sampler thread. For the
bounds to hold, a poll that finds no sample is given the time its read began, and one that
finds a sample the time its read ended.
"""

from __future__ import annotations

import math

PHASE_NOISE_S = 2e-5
"""Process noise of the tracked clock: how far (s, one sigma) a sample's instant wanders
per period beyond the period's own drift (the oscillator's jitter and the host's timing)."""

PERIOD_NOISE = 2e-5
"""How far (as a fraction of the nominal period, one sigma) the period drifts per period
(an oscillator warming up or cooling down)."""

PERIOD_SPREAD = 0.05
"""The chip's period is taken to lie within this fraction of the nominal one (one sigma)
before any edge: the data sheets' oscillator tolerance, with margin."""

READ_JITTER_S = 2e-5
"""Added to an edge's own spread (s, one sigma): the time a read takes on the bus."""

GATE_SIGMAS = 5.0
"""An edge this many sigmas off the tracked clock (and beyond :data:`RELOCK_POLLS`) starts
the tracking again from that edge."""

COUNT_SIGMAS = 8.0
"""An edge corrects the tracked clock only while the prediction for it is within a period
over this many sigmas, so the count of periods since the last edge is certain; else the
tracking starts again from that edge (the period learnt kept)."""

RELOCK_POLLS = 4.0
"""An edge this many poll intervals off the tracked clock starts the tracking again."""

SPREAD = 0.2
"""How far (as a fraction) the learnt period may stray from the nominal one."""

EDGE_POLLS = 2.0
"""A low poll at most this many poll intervals before the high one makes an edge; after a
longer gap (the poller was held up) the sample is stamped as one found already there."""


class DataReadyClock:
    """Stamps and poll times for one chip (see the module docstring). ``period_s``: the
    nominal sample period; ``poll_s``: the interval between polls near an edge."""

    def __init__(self, period_s: float, poll_s: float) -> None:
        if not (period_s > 0 and poll_s > 0):
            raise ValueError("period_s and poll_s must be > 0")
        self.nominal = self.period = float(period_s)
        self.poll = float(poll_s)
        self.track: float | None = None  # an instant of the tracked clock (a sample's)
        self._cov = [[0.0, 0.0], [0.0, 0.0]]  # of (track, period), s^2
        self.edges = 0  # edges since the tracking started
        self.relocks = 0  # times the tracking started again from one edge
        self._stamp: float | None = None  # the last sample's stamp
        self._low_at: float | None = None  # a poll since the last sample found no new one
        self._taken_at: float | None = None  # when the last sample was taken
        self._lost = False  # the last sample fitted no prediction: stamped when seen

    def not_ready(self, now: float) -> None:
        """A poll whose read began at ``now`` found no new sample."""
        self._low_at = now

    def ready(self, now: float) -> float:
        """A poll whose read ended at ``now`` found a new sample (which is then taken): when
        the chip made it."""
        low, self._low_at = self._low_at, None
        taken, self._taken_at = self._taken_at, now
        self._lost = False
        if low is not None and now - low <= EDGE_POLLS * self.poll:
            stamp = self._edge(low, now)
        else:
            stamp = self._found(now, max(x for x in (taken, low, -math.inf) if x is not None))
        self._stamp = stamp
        return stamp

    def _edge(self, low: float, high: float) -> float:
        """The stamp of a sample made between ``low`` and ``high``; the tracked clock
        corrected by the edge (Kalman filter, see the module docstring)."""
        mid = 0.5 * (low + high)
        r = (high - low) ** 2 / 12.0 + READ_JITTER_S**2  # uniform over [low, high], s^2
        if self.track is not None:
            k = round((mid - self.track) / self.period)
            if k >= 1 and self._spread(k) <= self.period / COUNT_SIGMAS:
                self._predict(k)
                (p00, p01), (_, p11) = self._cov
                residual, s = mid - self.track, p00 + r
                if abs(residual) <= max(RELOCK_POLLS * self.poll, GATE_SIGMAS * math.sqrt(s)):
                    g0, g1 = p00 / s, p01 / s  # gain, H = [1, 0]
                    self.edges += 1
                    self.track += g0 * residual
                    self.period = min(
                        max(self.period + g1 * residual, self.nominal * (1 - SPREAD)),
                        self.nominal * (1 + SPREAD),
                    )
                    # Joseph form reduced for H = [1, 0]: P - K S K^T
                    self._cov = [
                        [p00 - g0 * g0 * s, p01 - g0 * g1 * s],
                        [p01 - g0 * g1 * s, p11 - g1 * g1 * s],
                    ]
                    # made between the polls: the stamp kept there, the tracked clock not
                    # (moved, it would hide from the period the drift that moved it)
                    return min(max(self.track, low), high)
            self.relocks += 1  # lost: the period learnt stays, the phase starts again
        self.edges += 1
        self.track = mid
        p11 = self._cov[1][1] if self.edges > 1 else (PERIOD_SPREAD * self.nominal) ** 2
        self._cov = [[r, 0.0], [0.0, p11]]
        return mid

    def _predicted_cov(self, k: int) -> list[list[float]]:
        """The covariance of the tracked clock ``k`` periods on: F P F^T + k Q with
        F = [[1, k], [0, 1]]."""
        (p00, p01), (_, p11) = self._cov
        q0, q1 = k * PHASE_NOISE_S**2, k * (PERIOD_NOISE * self.nominal) ** 2
        return [
            [p00 + 2 * k * p01 + k * k * p11 + q0, p01 + k * p11],
            [p01 + k * p11, p11 + q1],
        ]

    def _spread(self, k: int) -> float:
        """One sigma (s) of the tracked clock's prediction ``k`` periods on."""
        return math.sqrt(self._predicted_cov(k)[0][0])

    def _predict(self, k: int) -> None:
        """The tracked clock ``k`` periods on: phase += k period."""
        self._cov = self._predicted_cov(k)
        self.track += k * self.period

    def _found(self, now: float, after: float) -> float:
        """The stamp of a sample found already there at ``now``, made after ``after`` (the
        last poll that saw none, or the last sample taken): its predicted instant if that
        fits, else ``now``."""
        if self.track is None:
            return now
        # The latest predicted instant by now, and not the last sample's own: then it must
        # lie after ``after`` (within a poll of the estimate's error), else the prediction
        # has gone stale.
        p = self.period
        k = max(math.floor((now - self.track) / p), self._next_k())
        predicted = self.track + k * p
        if not after - self.poll <= predicted <= now + self.poll:
            self._lost = True
            return now
        return min(max(predicted, after), now)

    def _next_k(self) -> int:
        """How many periods after the tracked instant the next sample is due."""
        if self._stamp is None or self.track is None:
            return 1
        return round((self._stamp - self.track) / self.period) + 1

    def next_poll(self, now: float) -> float:
        """When to poll next after a poll at ``now``: two poll intervals before the next
        predicted instant, then on a grid of poll intervals anchored at that instant, so
        one poll falls on it and the edge tells which way the tracked clock is off; every
        poll interval before the first sample and after one that fitted no prediction (so
        the next sample is caught at its edge)."""
        if self.track is None or self._lost:
            return now + self.poll
        due = self.track + self._next_k() * self.period
        if now < due - 3 * self.poll:
            return due - 2 * self.poll
        # the first grid point at least half a poll on (a late poll skips the one it nears)
        return due + self.poll * math.floor((now - due) / self.poll + 1.5)
