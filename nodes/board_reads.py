"""What a board measure does when its driver fails: count it, say it once, go on.

Every measure that reads a board through the protocols of :mod:`hera.nodes.driver` makes
its reads through one :class:`BoardReads`. A read gives the driver's sample, or None (the
measure publishes nothing that step) when the driver raises:

- :class:`~hera.nodes.driver.NoReading`, a dropout: counts ``dropouts``;
- :class:`~hera.nodes.driver.BoardDisconnected`, the board unreachable, or any other
  ``OSError`` the driver lets through (a read of an unplugged I2C chip raises
  ``OSError(EREMOTEIO)``; a serial port without permission ``PermissionError``): counts
  ``disconnected``. The first read of an outage is a warning in the node's log, then one
  every :data:`WARN_EVERY_S` while it lasts, and the first sample after it an info line
  saying how long the board was away. While it lasts the measure's ``trouble`` says so
  (``hera status``, the live view's problems line).

The measure keeps running and reads again at its next step; a driver reconnects inside its
read (as :class:`~hera.nodes.serial_sonar.SerialMaxSonar` reopens its port). So a sensor
unplugged for a while neither crash-loops its measure until the supervisor's restart
intensity is spent (which ends the node process and, with it, the node's other measures)
nor needs an operator to start it again: its readings come back by themselves.

At the start, :func:`board_needed` around what a measure's ``init`` does with its board
(open it, calibrate on it) turns a board that does not answer into
:class:`~hera.measure.NotReady`: the measure waits and its ``init`` is tried again every
2 s (:mod:`hera.worker`), so a sensor missing when its node starts does not crash-loop the
node down either.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from hera.measure import MeasureContext, NotReady
from hera.nodes.driver import NoReading

T = TypeVar("T")

WARN_EVERY_S = 5.0
"""Seconds between two warnings of one outage in the node's log."""


class BoardReads:
    """One measure's reads of its board; see the module docstring.

    ``clock``: monotonic seconds, for the pace of the warnings and the length of an outage
    (injected by tests).
    """

    def __init__(self, ctx: MeasureContext, clock: Callable[[], float] = time.monotonic) -> None:
        self.ctx = ctx
        self._clock = clock
        self._away_since: float | None = None  # start of the current outage
        self._warned_at = 0.0

    @property
    def away(self) -> bool:
        """True while the board is unreachable (its last read raised an OSError other than
        NoReading)."""
        return self._away_since is not None

    def read(self, read: Callable[..., T], *args: Any, **kwargs: Any) -> T | None:
        """``read(*args, **kwargs)``'s sample, or None after a dropout or a disconnected
        board (counted and logged as the module docstring says). Other errors propagate: a
        measure that cannot make sense of its board crashes and is restarted."""
        try:
            sample = read(*args, **kwargs)
        except NoReading:
            self.ctx.count("dropouts")
            return None
        except OSError as e:  # BoardDisconnected, or a bus error the driver let through
            self._disconnected(e)
            return None
        if self._away_since is not None:
            self.ctx.log.info(
                "%s: the board answers again after %.1f s away",
                self._name(),
                self._clock() - self._away_since,
            )
            self._away_since = None
            self.ctx.trouble = None
        return sample

    def _disconnected(self, error: OSError) -> None:
        self.ctx.count("disconnected")
        now = self._clock()
        if self._away_since is None:
            self._away_since = now
            self.ctx.trouble = f"board not answering ({error})"
        elif now - self._warned_at < WARN_EVERY_S:
            return
        self._warned_at = now
        self.ctx.log.warning(
            "%s: %s (disconnected for %.1f s; reading again every step)",
            self._name(),
            error,
            now - self._away_since,
        )

    def _name(self) -> str:
        return self.ctx.spec.name or "measure"


@contextlib.contextmanager
def board_needed() -> Iterator[None]:
    """Around a measure's start: a board that does not answer (BoardDisconnected, or another
    OSError but NoReading) raises NotReady instead, so the measure waits for it rather than
    crashing."""
    try:
        yield
    except NoReading:
        raise
    except OSError as e:
        raise NotReady(f"board not answering ({e})") from e
