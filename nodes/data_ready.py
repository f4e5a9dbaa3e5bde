"""When a polled chip made its samples: times from the edges of its data-ready flag.

A chip such as the LSM6DSL makes a sample every period of its own oscillator (off from the
nominal rate by a percent or two) and raises a data-ready flag; a driver that reads the
sample when the host's schedule comes round stamps it late by anything up to a period, a
sawtooth as the two clocks slide past each other, and a fusion model then integrates its
gyroscope over the wrong intervals (measured in the tilt application: a chip 1.5 % off took
the tilt RMSE from 0.13-0.19 deg to 0.41-0.81 deg). :class:`DataReadyClock` is what a
driver's polling loop needs to stamp each sample within a poll interval of when it was made:

- a sample seen between a poll that found the flag low and one that found it high, at most
  :data:`EDGE_POLLS` poll intervals apart (an *edge*), was made between the two: stamped at
  their midpoint;
- a sample found already there (or after a gap in the polls) is stamped at the chip's
  predicted instant for it (the last edge plus whole periods: the latest by then, and at
  least one period after the last sample's), kept after the last poll that saw none and the
  last sample taken; without a prediction that fits, when it was seen;
- the chip's period is learnt from the edges (intervals of up to :data:`MAX_PERIODS`
  periods, within :data:`SPREAD` of the nominal one), and the next poll is due a little
  before the next predicted edge, so a slow chip costs few polls.

Pure: the caller gives every time (seconds of one monotonic clock), so it is tested on an
injected clock; :mod:`hera.nodes.lsm6dsl.i2c` runs it in its sampler thread.
"""

from __future__ import annotations

import math

GAIN = 0.1
"""Weight of a new edge interval in the period's estimate."""

MAX_PERIODS = 8
"""Longest edge interval (in periods) that still tells the period."""

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
        self.last_edge: float | None = None
        self._low_at: float | None = None  # a poll since the last sample found no new one
        self._taken_at: float | None = None  # when the last sample was taken
        self._stamp: float | None = None  # when the last sample was made
        self.edges = 0

    def not_ready(self, now: float) -> None:
        """A poll at ``now`` found no new sample."""
        self._low_at = now

    def ready(self, now: float) -> float:
        """A poll at ``now`` found a new sample (which is then taken): when it was made."""
        low, self._low_at = self._low_at, None
        taken, self._taken_at = self._taken_at, now
        stamp = now
        if low is not None and now - low <= EDGE_POLLS * self.poll:
            stamp = 0.5 * (low + now)
            self._learn(stamp)
        elif self.last_edge is not None:
            # The latest predicted instant by now, and not the last sample's own: then it
            # must lie after the last poll that saw none and the last sample taken (within
            # a poll of the estimate's error), else the prediction has gone stale.
            p = self.period
            k = math.floor((now - self.last_edge) / p)
            if self._stamp is not None:
                k = max(k, round((self._stamp - self.last_edge) / p) + 1)
            predicted = self.last_edge + k * p
            after = max(x for x in (taken, low, -math.inf) if x is not None)
            if after - self.poll <= predicted <= now + self.poll:
                stamp = min(max(predicted, after), now)
        self._stamp = stamp
        return stamp

    def _learn(self, edge: float) -> None:
        last, self.last_edge = self.last_edge, edge
        self.edges += 1
        if last is None:
            return
        n = round((edge - last) / self.period)
        if not 1 <= n <= MAX_PERIODS:
            return
        period = self.period + GAIN * ((edge - last) / n - self.period)
        self.period = min(max(period, self.nominal * (1 - SPREAD)), self.nominal * (1 + SPREAD))

    def next_poll(self, now: float) -> float:
        """When to poll next after a poll at ``now``: two poll intervals before the next
        sample is due (a period after the last one's stamp), then every poll interval until
        it comes; every poll interval before the first sample."""
        if self._stamp is not None:
            due = self._stamp + self.period - 2 * self.poll
            if due > now + self.poll:
                return due
        return now + self.poll
