"""The operator's commands on a running cluster: ``echo``, ``hz``, ``store``, ``args``,
``start``, ``stop``, ``reload`` and ``view``, and ``export`` of a run.

Every command reaches the cluster through one :class:`hera.client.ClusterClient` made by
:func:`connect` (the run directory of a cluster started on this host, or ``--connect``
endpoints from any host), so a new way to reach a cluster is added in one place; the
``hera`` commands ``status``, ``down`` and ``inject`` use it too. Bad input, or a request
a node refuses, gets one sentence and exit code 2; a node that does not answer, exit code 1.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import threading
import time
from typing import Any

from hera import cliargs
from hera.client import ClusterClient, find_run_dir

HELP_EXAMPLES = {
    "echo": "hera echo obs1/n1 --count 5",
    "hz": "hera hz 'obs*' --duration 5",
    "store": "hera store n1",
    "args": "hera args set n1 measure/n1/obs1/prefix '\"x\"'",
    "start": 'hera start n2 --use counter --name extra --args \'{"prefix": "obs"}\'',
    "stop": "hera stop n2 extra",
    "reload": "hera reload mypkg.models",
    "view": "hera view --port 8765",
    "export": "hera export hera-run/observers --mcap run.mcap",
}
COMMANDS = ("echo", "hz", "store", "args", "start", "stop", "reload", "view", "export")


def cluster_options(p: argparse.ArgumentParser, remote: bool = True) -> None:
    """The options that say which cluster a command talks to (see :func:`connect`);
    ``remote``: also ``--connect`` and ``--cert``, to reach it from any host."""
    p.add_argument("--run-dir", help="run directory of the cluster (on this host)")
    p.add_argument("--cluster", help="name of the cluster, if several run")
    if not remote:
        return
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="reach the cluster through this node or router (e.g. tcp/10.0.0.2:7447), "
        "from any host: no run directory needed (repeatable)",
    )
    p.add_argument(
        "--cert",
        metavar="DIR",
        help="with --connect: the operator's credentials, a folder made by 'hera certs' "
        "(default: those of the cluster run from this host)",
    )


def add_parsers(sub: Any, command: Any) -> None:
    """Add this module's subcommands to the ``hera`` parser (``command(sub, name, summary,
    example)`` makes one)."""
    e = command(sub, "echo", "print the samples of a stream as they arrive", HELP_EXAMPLES["echo"])
    e.add_argument("stream", help="NAME or NAME/NODE (wildcards '*' allowed)")
    e.add_argument("--json", action="store_true", help="one JSON object per line")
    e.add_argument("--count", type=cliargs.count, help="stop after this many samples")
    e.add_argument("--duration", type=cliargs.positive, help="stop after this many seconds")
    h = command(sub, "hz", "rate, jitter and gaps of streams", HELP_EXAMPLES["hz"])
    h.add_argument("stream", help="NAME or NAME/NODE (wildcards '*' allowed)")
    h.add_argument("--duration", type=cliargs.positive, help="stop after this many seconds")
    h.add_argument("--every", type=cliargs.positive, default=1.0, help="print every this many s")
    h.add_argument("--json", action="store_true", help="print JSON at the end")
    s = command(sub, "store", "what a node's store holds, with ages", HELP_EXAMPLES["store"])
    s.add_argument("node")
    s.add_argument("name", nargs="?", help="only this name")
    s.add_argument("--json", action="store_true")
    a = command(sub, "args", "read, set or delete replicated args", HELP_EXAMPLES["args"])
    a.add_argument("op", choices=("get", "set", "del"))
    a.add_argument("node", help="the node asked (its replica; '*' for get: every node)")
    a.add_argument("key", nargs="?", help="the key (get without a key: every arg)")
    a.add_argument("value", nargs="?", help="JSON value for set (else taken as a string)")
    st = command(
        sub, "start", "start a stopped measure, or a new one at run time", HELP_EXAMPLES["start"]
    )
    st.add_argument("node")
    st.add_argument("name", nargs="?", help="a stopped measure of the node")
    st.add_argument("--use", help="start a new measure of this kind (kept across restarts)")
    st.add_argument(
        "--name", dest="new_name", metavar="NAME", help="the new measure's name (default: --use)"
    )
    st.add_argument("--args", help="its arguments, a JSON object")
    st.add_argument("--period", type=cliargs.positive, help="its period, s")
    sp = command(
        sub, "stop", "stop a measure (one started at run time is removed)", HELP_EXAMPLES["stop"]
    )
    sp.add_argument("node")
    sp.add_argument("name")
    r = command(sub, "reload", "load new code of a module on every node", HELP_EXAMPLES["reload"])
    r.add_argument("module", help="a module or package whose measures or models changed")
    r.add_argument("--timeout", type=cliargs.positive, default=30.0, help="s to wait for the nodes")
    v = command(sub, "view", "serve the live web view of a running cluster", HELP_EXAMPLES["view"])
    v.add_argument("--port", type=cliargs.port, default=8765, help="port (0: any free one)")
    v.add_argument("--host", default="127.0.0.1", help="address (loopback only)")
    v.add_argument("--duration", type=cliargs.positive, help="stop after this many seconds")
    x = command(
        sub, "export", "write a run as an MCAP file (Foxglove, Lichtblick)", HELP_EXAMPLES["export"]
    )
    x.add_argument("run_dir")
    x.add_argument("--mcap", required=True, metavar="OUT", help="the .mcap file to write")
    for p in (e, h, s, a, st, sp, r):
        cluster_options(p)
    cluster_options(v, remote=False)


def connect(args: argparse.Namespace) -> ClusterClient:
    """The client of the cluster the command line names (:func:`cluster_options`): through
    ``--connect`` endpoints, from any host (no spec then: names are not checked against
    it), or the one registered on this host (``--run-dir``, ``--cluster``, or the only
    one)."""
    if getattr(args, "connect", None):
        return ClusterClient.connect(
            args.connect, args.cluster, credentials=_operator_credentials(args)
        )
    return ClusterClient.from_run_dir(find_run_dir(args.run_dir, args.cluster))


def _operator_credentials(args: argparse.Namespace) -> Any:
    """The operator's credentials of a command run with ``--connect``: from ``--cert DIR``,
    else those of the cluster this host runs (``--run-dir``, ``--cluster`` or the only
    one)."""
    from hera.security.access import OPERATOR
    from hera.security.credentials import for_operator, for_spec
    from hera.spec import load_spec

    if args.cert:
        return for_operator(args.cert, args.connect)
    try:
        run_dir = find_run_dir(args.run_dir, args.cluster)
    except LookupError:
        raise LookupError(
            "--connect needs the operator's credentials: give --cert DIR (a folder made by "
            "'hera certs'), or run it on a host that runs the cluster"
        ) from None
    return for_spec(load_spec(run_dir / "cluster.json"), OPERATOR)


def run(args: argparse.Namespace) -> int:
    """Run one of :data:`COMMANDS`; returns the exit code."""
    if args.cmd == "export":
        return _export(args)
    if args.cmd == "view":
        return _view(args)
    with connect(args) as client:
        return {
            "echo": _echo,
            "hz": _hz,
            "store": _store,
            "args": _args,
            "start": _start,
            "stop": _stop,
            "reload": _reload,
        }[args.cmd](client, args)


def _wait(stop: threading.Event, duration: float | None) -> None:
    """Block until ``stop`` is set, ``duration`` s pass or Ctrl-C."""
    with contextlib.suppress(KeyboardInterrupt):
        stop.wait(duration)


def _echo(client: ClusterClient, args: argparse.Namespace) -> int:
    from hera.watch import (
        decode_sample,
        format_sample,
        stream_columns,
        stream_note,
        stream_selector,
    )

    selector = stream_selector(client.keys, args.stream)
    columns = stream_columns(client.spec)
    note = stream_note(client.spec, args.stream)
    if note:
        print(f"hera echo: {note}", file=sys.stderr, flush=True)
    done = threading.Event()
    lock = threading.Lock()
    seen = [0]

    def on(sample: Any) -> None:
        try:
            s = decode_sample(client.keys, str(sample.key_expr), sample.payload.to_bytes())
        except ValueError as e:
            print(f"rejected: {sample.key_expr}: {e}", file=sys.stderr, flush=True)
            return
        with lock:
            if done.is_set():
                return
            line = json.dumps(s) if args.json else format_sample(s, columns.get(s["name"], ()))
            print(line, flush=True)
            seen[0] += 1
            if args.count is not None and seen[0] >= args.count:
                done.set()

    sub = client.subscribe(selector, on)
    try:
        _wait(done, args.duration)
    finally:
        sub.undeclare()
    if not seen[0]:
        print(f"hera echo: no sample of {args.stream!r} came", file=sys.stderr, flush=True)
        return 1
    return 0


def _hz(client: ClusterClient, args: argparse.Namespace) -> int:
    from hera.watch import RateTable, stream_note, stream_selector

    note = stream_note(client.spec, args.stream)
    if note:
        print(f"hera hz: {note}", file=sys.stderr, flush=True)
    table = RateTable(client.keys)
    sub = client.subscribe(stream_selector(client.keys, args.stream), table.on_sample)
    end = None if args.duration is None else time.monotonic() + args.duration
    try:
        while end is None or time.monotonic() < end:
            left = args.every if end is None else min(args.every, end - time.monotonic())
            time.sleep(max(0.0, left))
            if not args.json:
                print(table.render() + "\n", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
    if args.json:
        print(
            json.dumps(
                {f"{n}/{node}": st.summary() for (n, node), st in sorted(table.streams.items())}
            )
        )
    return 0 if table.streams else 1


def _one(client: ClusterClient, node: str, verb: str, request: dict, timeout: float = 2.0):
    """The reply of one node (its name checked against the spec); None if it is silent."""
    if client.spec is not None:
        client.spec.node(node)  # an unknown node lists the known ones
    reply = client.query(node, verb, request, timeout=timeout).get(node)
    if reply is None:
        print(f"hera {verb}: node {node!r} did not answer", file=sys.stderr)
    return reply


def _refused(cmd: str, reply: dict) -> int:
    print(f"hera {cmd}: {reply.get('error')}", file=sys.stderr)
    return 2 if reply.get("error") else 1


def _store(client: ClusterClient, args: argparse.Namespace) -> int:
    from hera.watch import format_store, stream_columns

    request = {} if args.name is None else {"name": args.name}
    reply = _one(client, args.node, "store", request)
    if reply is None:
        return 1
    if not reply.get("ok"):
        return _refused("store", reply)
    if args.name is not None and not reply["samples"]:
        print(f"hera store: {args.node} holds no sample of {args.name!r}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(reply["samples"], indent=1))
    else:
        print(format_store(reply["samples"], stream_columns(client.spec)))
    return 0


def parse_value(text: str) -> Any:
    """A command-line value: JSON if it parses (numbers, lists, objects, true, "text"),
    else the text itself; ValueError for a text that starts as JSON does ('{', '[' or '"')
    but does not parse: a mistyped object is refused, not stored as a string."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        if text.lstrip()[:1] in ("{", "[", '"'):
            raise ValueError(
                f"value {text!r} is not JSON ({e.msg.removesuffix(' at')} at character "
                f"{e.pos}): fix it, or give "
                "a text that does not start with '{', '[' or '\"'"
            ) from None
        return text


def _args(client: ClusterClient, args: argparse.Namespace) -> int:
    if args.op in ("set", "del") and args.key is None:
        raise ValueError(f"args {args.op} needs a KEY")
    if args.op == "set" and args.value is None:
        raise ValueError("args set needs a VALUE (JSON, or plain text)")
    if args.op == "get" and args.key is None:
        request: dict[str, Any] = {}
    else:
        request = {"op": args.op, "key": args.key}
    if args.op == "set":
        request["value"] = parse_value(args.value)
    if args.node == "*" and args.op == "get":
        replies = client.query("*", "args", request, timeout=2.0)
        for node, reply in sorted(replies.items()):
            shown = reply.get("value", reply.get("args")) if reply.get("ok") else reply["error"]
            print(f"{node}: {json.dumps(shown)}")
        return 0 if replies and all(r.get("ok") for r in replies.values()) else 1
    reply = _one(client, args.node, "args", request)
    if reply is None:
        return 1
    if not reply.get("ok"):
        return _refused("args", reply)
    if args.op == "get" and args.key is None:
        for key, value in sorted(reply["args"].items()):
            print(f"{key} = {json.dumps(value)}")
    elif args.op == "get":
        stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(reply["ts_ns"] / 1e9))
        print(f"{reply['key']} = {json.dumps(reply['value'])}  (set by {reply['origin']} {stamp})")
    else:
        print(json.dumps(reply))
    return 0


def _start(client: ClusterClient, args: argparse.Namespace) -> int:
    if args.use is None:
        if args.name is None:
            raise ValueError("start needs a measure NAME, or --use KIND to start a new one")
        if args.args is not None or args.period is not None or args.new_name is not None:
            raise ValueError("--name, --args and --period go with --use (a new measure)")
        request: dict[str, Any] = {"measure": args.name}
    else:
        if args.name is not None and args.new_name is not None and args.name != args.new_name:
            raise ValueError(f"two names given: {args.name!r} and --name {args.new_name!r}")
        request = {"use": args.use}
        if (args.new_name or args.name) is not None:
            request["name"] = args.new_name or args.name
        if args.period is not None:
            request["period"] = args.period
        if args.args is not None:
            try:
                request["args"] = json.loads(args.args)
            except ValueError as e:
                raise ValueError(f"--args is not JSON ({e}): {args.args!r}") from None
            if not isinstance(request["args"], dict):
                raise ValueError(f"--args must be a JSON object, got {args.args!r}")
    reply = _one(client, args.node, "start", request)
    if reply is None:
        return 1
    if not reply.get("ok"):
        return _refused("start", reply)
    print(json.dumps(reply))
    return 0


def _stop(client: ClusterClient, args: argparse.Namespace) -> int:
    reply = _one(client, args.node, "stop", {"measure": args.name})
    if reply is None:
        return 1
    if not reply.get("ok"):
        return _refused("stop", reply)
    print(json.dumps(reply))
    return 0


def _reload(client: ClusterClient, args: argparse.Namespace) -> int:
    import importlib.util

    try:
        found = importlib.util.find_spec(args.module)
    except (ImportError, ValueError):
        found = None
    if found is None:
        raise ValueError(f"no module called {args.module!r} is installed here")
    replies = client.query("*", "reload", {"module": args.module}, timeout=args.timeout)
    # every node of the spec (a silent one is named); over --connect, those that answered
    nodes = [n.name for n in client.spec.nodes] if client.spec is not None else sorted(replies)
    code = 0
    for node in nodes:
        reply = replies.get(node)
        if reply is None:
            print(f"{node}: did not answer (it loads the new code at its next start)")
            code = 1
        elif not reply.get("ok"):
            print(f"{node}: not reloaded: {reply['error']}")
            code = 1
        elif not reply.get("modules"):
            print(f"{node}: {reply.get('note', 'nothing to reload')}")
        else:
            replaced = ", ".join(
                f"{name} ({'state handed over' if r.get('handover') else 'fresh'}"
                + (
                    f", switched in {r['switch_ms']:.1f} ms"
                    if r.get("switch_ms") is not None
                    else ""
                )
                + ")"
                for name, r in sorted(reply["replaced"].items())
            )
            print(
                f"{node}: reloaded {', '.join(reply['modules'])}; "
                f"replaced {replaced or 'no running measure'}"
            )
    return code


def _view(args: argparse.Namespace) -> int:
    from hera.console.server import serve

    run_dir = find_run_dir(args.run_dir, args.cluster)
    return serve(run_dir, args.host, args.port, args.duration)


def _export(args: argparse.Namespace) -> int:
    from hera.export.mcap import export_run
    from hera.progress import Progress

    with Progress("export") as progress:
        counts = export_run(args.run_dir, args.mcap, progress=progress)
    print(
        f"{args.mcap}: {counts['messages']} messages on {counts['channels']} channels "
        f"({counts['samples']} samples, {counts['truth']} truth)"
    )
    return 0
