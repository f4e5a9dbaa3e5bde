"""The operator's commands reach a cluster through ``--connect``, with no spec at hand: a
real cluster on loopback, the commands given one node's endpoint (the operator's
credentials found on this host, as on a machine that runs the cluster)."""

from __future__ import annotations

import json

from harness import run_hera as hera

from hera.spec import load_spec

SPEC = """
[cluster]
name = "remote"
[[nodes]]
name = "n1"
[[nodes.measures]]
use = "counter"
name = "obs1"
[[nodes]]
name = "n2"
"""


def test_the_operators_commands_work_through_connect(cluster, tmp_path):
    c = cluster(SPEC)
    via = ["--connect", load_spec(c.run_dir / "cluster.json").endpoint("n1")]

    echo = hera(tmp_path, "echo", "obs1/n1", "--count", "2", "--json", *via)
    assert echo.returncode == 0, echo.stderr
    assert [json.loads(line)["node"] for line in echo.stdout.splitlines()] == ["n1", "n1"]
    silent = hera(tmp_path, "echo", "obsx", "--duration", "1", *via)  # no spec: no name check
    assert (silent.returncode, silent.stderr) == (1, "hera echo: no sample of 'obsx' came\n")

    store = hera(tmp_path, "store", "n1", "--json", *via)
    assert store.returncode == 0, store.stderr
    assert isinstance(json.loads(store.stdout), list)

    assert hera(tmp_path, "args", "set", "n1", "note/k", "5", *via).returncode == 0
    got = hera(tmp_path, "args", "get", "n1", "note/k", *via)
    assert got.returncode == 0 and got.stdout.startswith("note/k = 5"), got.stdout + got.stderr

    stop = hera(tmp_path, "stop", "n1", "obs1", *via)
    assert stop.returncode == 0 and json.loads(stop.stdout)["state"] == "stopped", stop.stderr
    start = hera(tmp_path, "start", "n1", "obs1", *via)
    assert start.returncode == 0 and json.loads(start.stdout)["state"] == "running", start.stderr
    refused = hera(tmp_path, "stop", "n1", "nosuch", *via)  # the node still says what is wrong
    assert refused.returncode == 2 and "no measure 'nosuch'" in refused.stderr, refused.stderr
