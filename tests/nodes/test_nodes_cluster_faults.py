"""Board faults switched on and off at run time through the control plane of a running
cluster (real `hera up` node processes on 127.0.0.1).

Node n1 runs ``nav`` on a simulated Pmod NAV in the "still" scenario (noise: no two readings
alike) and a counter; n2 runs nothing and only stores what it hears: the test reads nav's
values there through the ``store`` verb. A fault is switched on n1 with the simulator's
``board`` verb; its effect is checked on the samples published after the reply
(seq from n1's status after the reply, plus one: a step may have read the board just before
the fault and published just after the reply).
"""

from __future__ import annotations

from harness import wait_for

SPEC = """
[cluster]
name = "boardfaults"

[world]
scenario = "still"

[[nodes]]
name = "n1"

  [[nodes.measures]]
  use = "nav"
  period = 0.05
  # permanent (the default): a crash would restart it, and a crash loop end the node
  args = { calib_samples = 50 }

  [[nodes.measures]]
  use = "counter"
  name = "beat"
  period = 0.05

[[nodes]]
name = "n2"
store = "all"  # the watcher: its store takes every sample (it reads nothing itself)
"""

N = 6  # samples observed per phase


def _nav(c) -> dict:
    return c.status("n1")["measures"]["nav"]


def _inject(c, **request) -> dict:
    reply = c.control("n1", "board", request)
    assert reply["ok"], reply
    return reply


class NavWatch:
    """nav's samples as n2's store holds them, by seq (polled through the ``store`` verb)."""

    def __init__(self, c) -> None:
        self.c = c
        self.seen: dict[int, tuple[float, ...]] = {}

    def poll(self) -> None:
        reply = self.c.control("n2", "store", {"name": "nav"})
        assert reply["ok"], reply
        for s in reply["samples"]:
            if s["node"] == "n1":
                self.seen[s["seq"]] = tuple(s["values"])

    def after(self, seq: int, n: int, what: str) -> list[tuple[float, ...]]:
        """Wait until n2 has held ``n`` distinct samples with a seq > ``seq``; their values."""

        def enough():
            self.poll()
            got = [v for s, v in sorted(self.seen.items()) if s > seq]
            return got if len(got) >= n else None

        return wait_for(enough, 15, f"{n} nav samples {what} at n2")


def test_stuck_then_cleared_then_disconnected_then_bad_requests(cluster):
    c = cluster(SPEC)
    pid = c.pid("n1")
    watch = NavWatch(c)
    free = watch.after(0, N, "before any fault")
    assert len(set(free)) > 1, "nav values should change from sample to sample (noise)"

    # stuck: every sample published after the fault took effect has the same values
    reply = _inject(c, board="n1/nav", fault="stuck")
    assert reply["board"] == "n1/nav" and reply["fault"] == {"fault": "stuck"}
    s0 = _nav(c)["seq"] + 1
    stuck = watch.after(s0, N, "under the stuck fault")
    assert len(set(stuck)) == 1, f"stuck nav values changed: {stuck}"

    # clear: the values change again
    reply = _inject(c, board="n1/nav", fault="clear")
    assert reply == {"ok": True, "board": "n1/nav", "fault": None}
    s1 = _nav(c)["seq"] + 1
    moving = watch.after(s1, N, "after the fault was cleared")
    assert len(set(moving)) > 1, f"nav values still stuck after clear: {moving}"

    # dropout: nav keeps stepping but publishes nothing (empty steps), counted as dropouts
    _inject(c, board="nav", fault="dropout")  # a bare board name: unique in n1
    before = _nav(c)
    m = wait_for(
        lambda: (m := _nav(c))["steps"] >= before["steps"] + N and m, 15, "steps under dropout"
    )
    assert m["seq"] <= before["seq"] + 1 and m["published"] <= before["published"] + 1, m
    assert m["counters"]["dropouts"] >= N, m
    assert m["state"] == "running" and m["crashes"] == 0, m
    _inject(c, board="n1/nav", fault="clear")
    watch.after(_nav(c)["seq"] + 1, 2, "after the dropout was cleared")

    # disconnect: every read raises; nav publishes nothing, counts it and keeps running
    # (no crash, so no restart loop that would spend the node's restart intensity), the node
    # and its other measure go on, and nav publishes again once the board is back
    reply = _inject(c, board="n1/nav", fault="disconnect")
    assert reply["fault"] == {"fault": "disconnect"}
    before = _nav(c)
    m = wait_for(
        lambda: (m := _nav(c))["counters"].get("disconnected", 0) >= N and m,
        15,
        "nav to count disconnected reads",
    )
    assert m["state"] == "running" and m["crashes"] == 0 and m["restarts"] == 0, m
    assert m["trouble"].startswith("board not answering (simulated disconnection"), m
    assert m["seq"] <= before["seq"] + 1, m  # at most one step that read before the fault
    beat = c.status("n1")["measures"]["beat"]["seq"]
    wait_for(lambda: c.status("n1")["measures"]["beat"]["seq"] > beat + N, 15, "beat to go on")
    _inject(c, board="n1/nav", fault="clear")
    back = watch.after(_nav(c)["seq"], N, "after the board was reconnected, without a start")
    assert len(set(back)) > 1
    m = _nav(c)
    assert m["state"] == "running" and m["crashes"] == 0 and m["trouble"] is None, m
    assert c.pid("n1") == pid, "node n1 was restarted"

    # unplugged when nav starts, with no calibration stored: it waits for its board (no
    # crash, so no restarts spent), then calibrates and publishes once the board answers
    assert c.control("n1", "stop", {"measure": "nav"})["ok"]
    assert c.control("n1", "args", {"op": "del", "key": "calib/n1/nav"})["deleted"]
    _inject(c, board="n1/nav", fault="disconnect")
    assert c.control("n1", "start", {"measure": "nav"})["ok"]
    m = wait_for(lambda: (m := _nav(c))["trouble"] and m, 15, "nav to wait for its board")
    assert m["trouble"].startswith("waiting to start: board not answering"), m
    assert m["state"] == "running" and m["crashes"] == 0, m
    _inject(c, board="n1/nav", fault="clear")
    back = watch.after(_nav(c)["seq"], N, "once the board answered at start")
    assert len(set(back)) > 1
    m = _nav(c)
    assert m["trouble"] is None and m["crashes"] == 0, m
    assert c.control("n1", "args", {"op": "get", "key": "calib/n1/nav"})["value"]["n"] == 50
    assert c.pid("n1") == pid

    # bad requests: ok=false and an error naming what was wrong; nothing changes
    def bad(node: str, request: dict, *words: str) -> None:
        reply = c.control(node, "board", request)
        assert reply["ok"] is False, reply
        for w in words:
            assert w in reply["error"], (w, reply["error"])

    bad("n1", {"board": "n1/nav", "fault": "melt"}, "'melt'", "stuck", "disconnect", "clear")
    bad("n1", {"board": "n1/nope", "fault": "stuck"}, "'n1/nope'", "n1/nav")
    bad("n2", {"board": "n1/nav", "fault": "stuck"}, "'n1/nav'")  # n1's board, asked of n2
    bad("n1", {"fault": "stuck"}, "'board'")
    bad("n1", {"board": "n1/nav", "fault": "stuck", "colour": 1}, "'colour'", "value")
    bad("n1", {"board": "n1/nav", "fault": "bias"}, "'value'")
    bad("n1", {"board": "n1/nav", "fault": "dropout", "prob": 2}, "prob", "2")
    bad("n1", {"board": "n1/nav", "fault": "stuck", "sensor": "sonar"}, "'sonar'", "acc")
    bad("n1", {"board": "n1/nav", "fault": "clear", "value": 1}, "'clear'", "value")
    last = _nav(c)["seq"]
    after_bad = watch.after(last, N, "after the bad requests")
    assert len(set(after_bad)) > 1, "a refused request must leave the board fault-free"
    assert c.pid("n1") == pid
