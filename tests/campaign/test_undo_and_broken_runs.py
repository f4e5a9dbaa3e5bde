"""A fault ends when its undoing begins (the journal's stamp), and a campaign whose cluster
never starts is still checked and reported, with the reason, and exits 1."""

from __future__ import annotations

import json
import socket
import time
from types import SimpleNamespace

from campaign_runs import run_campaign

from hera.campaign import journal
from hera.campaign.actuators import Active, Injector
from hera.campaign.plan import Planned


class SlowLinks:
    """Links whose rules take ``delay`` s to apply (as nft in several namespaces does)."""

    def __init__(self, delay: float) -> None:
        self.delay = delay
        self.requests: list[dict] = []

    def command(self, request: dict) -> dict:
        time.sleep(self.delay)
        self.requests.append(request)
        return {}


def test_a_heal_is_journaled_at_the_moment_it_began(tmp_path):
    links = SlowLinks(0.3)
    inj = Injector(view=None, folder=tmp_path, seed=1, links=links)
    act = Active(Planned(0, "cut a", "partition", 0.0, 1.0, {}), pairs=[["a", "b"]])
    before = time.time()
    inj.heal(act)
    after = time.time()
    (end,) = journal.read(tmp_path)
    assert links.requests == [{"op": "clear", "pairs": [["a", "b"]]}]
    assert end["event"] == "end" and after - before >= 0.3
    assert before <= end["t"] <= before + 0.1  # not after the 0.3 s the rule took


def test_a_strike_is_journaled_at_the_moment_it_acted(tmp_path):
    """The start is stamped before the rule goes in, not after: a cluster may notice a
    fault within a millisecond, before a stamp taken after the act (CI once saw every peer
    log a kill 2.7 ms before the kill's journaled start)."""
    links = SlowLinks(0.3)
    spec = SimpleNamespace(nodes=[SimpleNamespace(name="a"), SimpleNamespace(name="b")])
    inj = Injector(view=SimpleNamespace(spec=spec), folder=tmp_path, seed=1, links=links)
    planned = Planned(0, "cut a", "partition", 0.0, 1.0, {"groups": [["a"], ["others"]]})
    before = time.time()
    act = inj.strike(planned)
    after = time.time()
    (start,) = journal.read(tmp_path)
    assert act is not None and act.pairs == [["a", "b"]]
    assert links.requests == [{"op": "set", "pairs": [["a", "b"]], "mode": "blackhole"}]
    assert start["event"] == "start" and after - before >= 0.3
    assert before <= start["t"] <= before + 0.1  # not after the 0.3 s the rule took


def test_a_campaign_whose_cluster_cannot_start_is_reported_not_crashed(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        spec = tmp_path / "busy.toml"
        spec.write_text(
            f'[cluster]\nname = "busy"\nbase_port = {port}\n\n[[nodes]]\nname = "n1"\n\n'
            '[[measures]]\non = ["n1"]\nuse = "counter"\nname = "counter"\nperiod = 0.1\n'
        )
        camp = tmp_path / "c.toml"
        camp.write_text(
            '[campaign]\nname = "c"\nbaseline_s = 1\ntail_s = 1\n\n[[faults]]\n'
            'name = "crash it"\nkind = "crash"\ntarget = "n1"\nmeasure = "counter"\n'
        )
        code, folder, out = run_campaign(tmp_path, str(spec), str(camp), "--seed", "1")
    assert code == 1, out
    assert "Traceback" not in out
    assert "the run broke" in out and "report: " in out
    meta = json.loads((folder / "campaign.json").read_text())
    assert "cluster.json" in meta["error"]  # hera up refused: no cluster to record
    assert (folder / "report.md").exists() and (folder / "report.html").exists()
