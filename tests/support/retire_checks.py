"""The check of a hot reload's old side, shared by the tests of own-thread and shared
workers: retired, a worker hands over at its next deadline, after its measure closed."""

from __future__ import annotations

import threading
import time


def retire_and_check(w, events: list, done: threading.Event, period: float) -> None:
    """Retire ``w`` (a worker of a measure that logs ``("step", t, deadline)`` and
    ``("close", t)`` in ``events``; ``done`` set when it ends) and check that it handed
    over once, in its own thread, after its close, at the deadline after its last step, which
    it records as the one it gave up."""
    handed: list = []
    w.retire(lambda old: handed.append((old, threading.current_thread(), time.monotonic())))
    assert done.wait(5)
    ((old, thread, t_hand),) = handed
    assert old is w and thread is w.thread  # in the worker's own thread, before its end report
    kinds = [e[0] for e in events]
    assert kinds[-1] == "close" and "close" not in kinds[:-1]  # closed once, no step after
    last_deadline = max(e[2] for e in events if e[0] == "step")
    assert t_hand >= events[-1][1] >= last_deadline + period * 0.99  # at the deadline, not before
    # the deadline it gave up (the next on its grid, unless it woke whole periods late),
    # from which a reload counts its switch time
    k = round((w.retired_deadline - last_deadline) / period)
    assert k >= 1 and abs(w.retired_deadline - last_deadline - k * period) < 1e-6
    assert w.retired_deadline <= w.retired_at <= events[-1][1]  # woke for it, then closed
