"""Campaign files (declared settings, every problem at once, exit code 2) and schedules
(reproducible from the seed)."""

from __future__ import annotations

import pytest

from hera.campaign.plan import make_plan
from hera.campaign.runner import spec_problems
from hera.campaign.schema import (
    CampaignError,
    campaigns,
    load_campaign,
    parse_campaign,
    resolve_campaign,
)
from hera.cli import main
from hera.examples import resolve_spec
from hera.spec import load_spec

TRAIN = load_spec(resolve_spec("train"))


def test_the_shipped_campaigns_load_and_fit_the_train():
    shipped = campaigns()
    assert {"thesis-ch5", "partitions", "nemesis", "manual"} <= set(shipped)
    for path in shipped.values():
        c = load_campaign(path)
        assert spec_problems(c, TRAIN) == []
        assert spec_problems(c.shortened(), TRAIN) == []


def test_every_problem_of_a_campaign_is_reported_at_once_naming_table_and_key():
    bad = {
        "campaign": {"name": "x", "baseline": 3},
        "faults": [
            {"kind": "crash", "target": "nav_1"},
            {"kind": "partition", "groups": [["a"]], "duration_s": 2},
            {"kind": "meltdown"},
            {"kind": "pause", "target": "nav_1"},
            {"kind": "loss", "target": "nav_1", "duration_s": 2, "loss": 2},
        ],
        "nemesis": {"duration_s": 10, "kinds": {"kill": 1, "explode": 2, "board": 1}},
        "checks": {"skip": ["nothing"], "agreement": {"columns": {"x": -1}}},
        "short": {"faults": ["nope"]},
        "extra": {},
    }
    with pytest.raises(CampaignError) as e:
        parse_campaign(bad, "bad.toml")
    problems = e.value.problems
    expect = [
        "bad.toml: unknown table 'extra'",
        "bad.toml: [campaign]: unknown key 'baseline' (did you mean 'baseline_s'?)",
        "bad.toml: [[faults]] #1: kind 'crash' needs 'measure'",
        "bad.toml: [[faults]] #2: groups needs at least two sides",
        "bad.toml: [[faults]] #3: kind must be one of crash",
        "bad.toml: [[faults]] #4: kind 'pause' needs duration_s > 0",
        "bad.toml: [[faults]] #5: loss must be a number >= 0 and <= 0.95, got 2",
        "bad.toml: [nemesis]: kinds: unknown fault kind 'explode'",
        "bad.toml: [nemesis]: kinds: 'board' is drawn, so give boards",
        "bad.toml: [checks]: skip item 1 must be one of schedule",
        "bad.toml: [checks.agreement]: columns: tolerance of 'x' must be a number > 0",
        "bad.toml: [short]: faults names unknown fault 'nope'",
    ]
    for want in expect:
        assert any(p.startswith(want) for p in problems), (want, problems)


def test_a_campaign_that_does_not_fit_the_spec_is_refused_before_anything_starts(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(
        '[campaign]\nname = "c"\n[[faults]]\nkind = "crash"\ntarget = "nav_1"\n'
        'measure = "sonar"\n[[faults]]\nkind = "kill"\ntarget = "leader:nope"\n'
        '[[faults]]\nkind = "partition"\ngroups = [["nav_9"], ["others"]]\nduration_s = 1\n'
    )
    c = load_campaign(path)
    problems = spec_problems(c, TRAIN)
    assert any("node 'nav_1' has no measure 'sonar'" in p for p in problems)
    assert any("no sync group 'nope'" in p for p in problems)
    assert any("target 'nav_9' is neither a node" in p for p in problems)


def test_network_faults_are_refused_on_a_spec_the_link_proxy_cannot_stand_in(tmp_path):
    """The proxy needs the plain mesh of peers on one host: routers or a client node are
    refused before anything starts, each in a sentence; TLS links pass through it."""
    c = load_campaign(resolve_campaign("partitions"))
    assert spec_problems(c, TRAIN) == []
    routed = load_spec(resolve_spec("two_hosts"))
    assert any("the spec has routers" in p for p in spec_problems(c, routed))
    crash_only = load_campaign(resolve_campaign("thesis-ch5"))
    assert not any("network faults" in p for p in spec_problems(crash_only, routed))
    assert spec_problems(c, TRAIN.with_security(tls=True)) == []


def test_the_command_line_says_what_is_wrong_with_exit_code_2(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text('[campaign]\nname = "c"\n[[faults]]\nkind = "kill"\ntarget = "nobody"\n')
    assert main(["campaign", "train", str(path), "--run-dir", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "hera campaign: " in err and "target 'nobody' is neither a node" in err
    assert not (tmp_path / "r").exists()  # nothing was started, nothing written
    assert main(["campaign", "train", "no-such-campaign"]) == 2
    assert "no shipped campaign of that name" in capsys.readouterr().err


def test_a_nemesis_is_the_same_for_the_same_seed_and_differs_for_another():
    c = load_campaign(campaigns()["nemesis"])
    a, b, other = make_plan(c, TRAIN, 7), make_plan(c, TRAIN, 7), make_plan(c, TRAIN, 8)
    assert a == b
    assert a != other
    assert len(a) > 30  # ten minutes at a fault every ~12 s
    kinds = {p.kind for p in a}
    assert {"kill", "pause", "partition", "loss", "skew"} <= kinds
    for p, q in zip(a, a[1:], strict=False):
        assert q.at >= p.end + 6.0 - 1e-6  # one at a time, each followed by its quiet gap
    assert a[-1].end <= 600.0


def test_nemesis_parameters_stay_within_their_ranges():
    c = load_campaign(campaigns()["nemesis"])
    for seed in range(5):
        for p in make_plan(c, TRAIN, seed):
            if p.kind == "pause":
                assert 1.0 <= p.duration <= 4.0
            if p.kind == "loss":
                assert 0.05 <= p.settings["loss"] <= 0.25
            if p.kind == "skew":
                assert -0.3 <= p.settings["skew_s"] <= 0.3
            if p.kind == "partition":
                sides = p.settings["groups"]
                assert len(sides) == 2 and all(sides)
                assert sorted(n for s in sides for n in s) == sorted(n.name for n in TRAIN.nodes)
            if p.kind in ("crash", "hang"):
                assert f"{p.settings['target']}/{p.settings['measure']}" in c.nemesis["measures"]


def test_a_scripted_schedule_runs_in_order_with_its_gaps():
    c = load_campaign(campaigns()["thesis-ch5"])
    plan = make_plan(c, TRAIN, 1)
    assert [p.name for p in plan] == [f.name for f in c.faults]
    assert plan[0].at == 0.0
    for p, q in zip(plan, plan[1:], strict=False):
        assert q.at == pytest.approx(p.end + c.gap_s)
    short = c.shortened()
    assert [p.name for p in make_plan(short, TRAIN, 1)] == list(c.short["faults"])
    assert short.baseline_s < c.baseline_s


def test_the_readme_campaign_reference_is_generated_from_the_declarations():
    import re
    from pathlib import Path

    from hera.campaign.schema import reference

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    body = re.search(
        r"<!-- campaign-reference[^>]*-->\n(.*?)\n<!-- /campaign-reference -->", readme, re.S
    )
    assert body is not None, "the README lost its campaign reference markers"
    assert body.group(1) == reference(), "put hera.campaign.schema.reference() there"
