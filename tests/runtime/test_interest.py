"""Stores subscribe by interest: a node takes the names its measures read, a logging node
takes everything (real nodes on loopback)."""

from __future__ import annotations

from harness import wait_for

SPEC = """
[cluster]
name = "interest"
[logging]
node = "logger"
[[nodes]]
name = "counting"
  [[nodes.measures]]
  use = "counter"
  name = "obs1"
  period = 0.2
[[nodes]]
name = "noisy"
  [[nodes.measures]]
  use = "beacon"
  name = "noise"
  period = 0.05
[[nodes]]
name = "quiet"
[[nodes]]
name = "logger"
"""


def held(c, node: str) -> set[str]:
    return {s["name"] for s in c.control(node, "store", {})["samples"]}


def test_each_store_holds_what_its_measures_read(cluster):
    c = cluster(SPEC, name="run")
    wait_for(lambda: held(c, "logger") == {"obs1", "noise"}, 10, "the logger to hold both")
    assert held(c, "counting") == {"obs1"}  # its counter reads obs*, not noise
    assert held(c, "noisy") == set() and held(c, "quiet") == set()
    assert c.status("counting")["store"]["takes"] == ["obs*"]
    assert c.status("logger")["store"]["takes"] is None  # a full mirror
    assert c.status("quiet")["store"]["takes"] == []
    # the counter still counts every observer of the cluster: itself (once it has sent for
    # two of its cycles; a period of 0.2 s keeps "fresh" wider than a loaded machine's jitter)
    wait_for(
        lambda: c.control("counting", "store", {"name": "obs1"})["samples"][0]["values"] == [1.0],
        10,
        "the counter to count itself",
    )
