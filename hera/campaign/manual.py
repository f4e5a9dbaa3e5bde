"""``hera inject`` for the faults a campaign makes: board faults, clock skew and the network.

- ``hera inject NODE board FAULT --board ID [--for S] [--param KEY=VALUE ...]``: a board
  fault through the simulator's ``board`` verb (``clear`` removes it);
- ``hera inject NODE clock SECONDS``: the node's clock runs that far off (0: true again);
- ``hera inject NODE partition [--peers A,B]``: cut NODE off from every node (or those);
- ``hera inject NODE loss SHARE``, ``delay MS [--jitter MS]``, ``reset`` on NODE's links
  (to ``--peers`` only, if given); ``hera inject NODE heal`` gives them back (``'*'``: all).

Network faults act on the links of a cluster started by ``hera campaign``: through its link
proxy, or as nftables rules in its nodes' namespaces (``--links netns``; a plain ``hera up``
cluster has neither). On a campaign's cluster every injection is journaled beside the
campaign's own faults, so a person can run a campaign (``deploy/campaigns/manual.toml`` has
no scheduled fault), inject by hand, and get the report and the checkers' verdicts when it
ends.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hera.campaign import journal
from hera.campaign.history import META
from hera.campaign.links import PLAN_FILE, control, cut_pairs, links_of
from hera.campaign.netns import Namespaces
from hera.client import ClusterClient

NETWORK = ("partition", "loss", "delay", "reset", "heal")
FAULTS = ("board", "clock", *NETWORK)


def _number(text: str | None, what: str) -> float:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {text!r}") from None


def _params(items: list[str] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items or []:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ValueError(f"--param takes KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except ValueError:
            out[key] = value
    return out


def campaign_dir(run_dir: Path) -> Path | None:
    """The campaign directory holding cluster run ``run_dir``, if a campaign started it."""
    parent = Path(run_dir).resolve().parent
    return parent if (parent / META).exists() else None


def inject(
    client: ClusterClient,
    run_dir: Path | None,
    node: str,
    fault: str,
    value: str | None,
    board: str | None = None,
    seconds: float | None = None,
    params: list[str] | None = None,
    peers: list[str] | None = None,
    jitter_ms: float = 0.0,
) -> dict[str, Any]:
    """Do one fault by hand through ``client`` (``run_dir``: the cluster's run directory on
    this host, None when reached with ``--connect``: then only board and clock faults);
    the reply to print. ValueError (a sentence) on a bad request, LookupError when the
    node does not answer."""
    folder = campaign_dir(run_dir) if run_dir is not None else None
    if client.spec is not None and node != "*":
        client.spec.node(node)  # an unknown node lists the known ones
    began = journal.now()  # before acting: the cluster may notice within a millisecond
    if fault in NETWORK:
        if client.spec is None:
            raise ValueError("network faults need the cluster's run directory on this host")
        names = [n.name for n in client.spec.nodes]
        reply = _network(folder, names, node, fault, value, peers, jitter_ms)
    elif fault == "board":
        if not board or value is None:
            raise ValueError(
                "board faults need the fault and --board ID, e.g. "
                "'hera inject n1 board stuck --board n1/nav'"
            )
        req: dict[str, Any] = {"board": board, "fault": value, **_params(params)}
        if seconds is not None and value != "clear":
            req["duration"] = seconds
        reply = _ask(client, node, "board", req)
    elif fault == "clock":
        reply = _ask(client, node, "clock", {"skew_s": _number(value, "the clock skew (s)")})
    else:
        raise ValueError(f"unknown fault {fault!r}: use {', '.join(FAULTS)}")
    if folder is not None:
        journal.append(
            folder,
            "start",
            began,
            index=-1,
            name=f"by hand: {fault} {node} {value or ''}".strip(),
            kind=fault,
            nodes=[node],
            duration=seconds or 0.0,
        )
    return reply


def _ask(client: ClusterClient, node: str, verb: str, req: dict[str, Any]) -> dict[str, Any]:
    reply = client.query(node, verb, req, timeout=2.0).get(node)
    if reply is None:
        raise LookupError(f"node {node!r} did not answer")
    return reply


def _network(
    folder: Path | None,
    names: list[str],
    node: str,
    fault: str,
    value: str | None,
    peers: list[str] | None,
    jitter_ms: float,
) -> dict[str, Any]:
    if folder is None or not (folder / PLAN_FILE).exists():
        raise ValueError(
            "network faults need a cluster started by 'hera campaign' (its links run through "
            "the link proxy or its namespaces); this one was started by 'hera up'"
        )
    plan = json.loads((folder / PLAN_FILE).read_text())
    others = [p for p in (peers or names) if p != node]
    for p in others:
        if p not in names:
            raise ValueError(f"--peers names unknown node {p!r}; nodes: {', '.join(names)}")
    pairs = None if node == "*" else links_of(node, others)
    if fault == "heal":
        req: dict[str, Any] = {"op": "clear", **({} if pairs is None else {"pairs": pairs})}
    elif node == "*":
        raise ValueError(f"'*' is for heal only; give the node whose links to {fault}")
    elif fault == "partition":
        req = {"op": "set", "pairs": cut_pairs([[node], others]), "mode": "blackhole"}
    elif fault == "loss":
        req = {"op": "set", "pairs": pairs, "loss": _number(value, "the loss share")}
    elif fault == "delay":
        req = {
            "op": "set",
            "pairs": pairs,
            "delay_ms": _number(value, "the delay (ms)"),
            "jitter_ms": jitter_ms,
        }
    else:
        req = {"op": "set", "pairs": pairs, "mode": "reset"}
    if plan.get("backend") == "netns":  # nftables rules in the nodes' namespaces
        try:
            return Namespaces(plan).command(req)
        except RuntimeError as e:
            raise LookupError(
                f"the campaign's namespaces cannot take the rule ({e}): is it running?"
            ) from None
    try:
        return control(plan["control"], req)
    except OSError as e:
        raise LookupError(
            f"the link proxy does not answer ({e}): is the campaign running?"
        ) from None
