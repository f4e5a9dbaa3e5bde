"""The ``hera`` command line: run clusters, look at them, score and replay their runs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import logging
import sys
import time

from hera.client import ClusterClient, find_run_dir, pid_alive

BENCHES = ("ahrs", "bus", "kalman", "sync")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hera", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    up = sub.add_parser("up", help="start every node of a spec and keep them running")
    up.add_argument("spec", help="cluster spec (TOML file, or an example's name: hera examples)")
    up.add_argument("--duration", type=float, help="stop after this many seconds")
    up.add_argument(
        "--run-dir", help="where logs, state and recordings go (default hera-run/<cluster>)"
    )
    up.add_argument("--interval", type=float, default=1.0, help="status refresh period, s")

    node = sub.add_parser("node", help="run one node of a spec (hera up does this for you)")
    node.add_argument("spec", help="cluster spec (TOML) or resolved cluster.json")
    node.add_argument("--node", required=True, help="name of the node to run")
    node.add_argument("--run-dir", help="run directory for state and logs")
    node.add_argument("--parent-pid", type=int, help="stop when this process is gone")
    node.add_argument("--log-level", default="INFO")

    for name, text in (
        ("status", "show the status of a running cluster"),
        ("down", "stop a running cluster"),
    ):
        s = sub.add_parser(name, help=text)
        s.add_argument("--run-dir", help="run directory of the cluster")
        s.add_argument("--cluster", help="name of the cluster, if several run")
        if name == "status":
            s.add_argument("--json", action="store_true", help="print JSON")

    inj = sub.add_parser("inject", help="inject a fault into a running cluster")
    inj.add_argument("node", help="target node")
    inj.add_argument("fault", help="crash | hang | crash_node | stop | start")
    inj.add_argument("measure", nargs="?", help="target measure (crash, hang, stop, start)")
    inj.add_argument("--run-dir")
    inj.add_argument("--cluster")

    ms = sub.add_parser("measures", help="list the installed measures, or show one")
    ms.add_argument("name", nargs="?", help="a measure: show its columns and arguments")
    sub.add_parser("apps", help="list the installed applications")
    sub.add_parser("examples", help="list the example specs (hera up NAME runs one)")

    rp = sub.add_parser("replay", help="run fusion models offline over recordings")
    rp.add_argument("recordings", help="a run dir or a folder of <name>_<node>.csv files")
    rp.add_argument("--out", required=True, help="where to write <model>_<node>.csv")
    rp.add_argument("--models", help="comma-separated model names (default: the spec's)")
    rp.add_argument(
        "--spec", help="spec giving the models' parameters (default: the recordings' cluster.json)"
    )
    rp.add_argument("--node", default="replay", help="node name of the outputs")
    rp.add_argument(
        "--start-like",
        metavar="NODE",
        help="start each model at the first sample NODE's live model fused and write "
        "estimates at the live estimates' instants (to compare a replay with a live node)",
    )

    ev = sub.add_parser("eval", help="score a run's estimates against the truth")
    ev.add_argument("run_dir")
    ev.add_argument(
        "--settle",
        type=float,
        default=10.0,
        help="s before position/radius errors count (default 10)",
    )
    ev.add_argument(
        "--after",
        "--omega-after",
        dest="after",
        type=float,
        default=3.0,
        help="s after a model's first estimate before its errors count (default 3)",
    )
    ev.add_argument("--plots", help="folder for the PNG plots (default RUN_DIR/eval)")
    ev.add_argument("--no-plots", action="store_true")
    ev.add_argument("--node", help="node whose models are plotted (default: the first)")
    ev.add_argument("--json", action="store_true", help="print JSON")

    b = sub.add_parser("bench", help="run a benchmark: " + ", ".join(BENCHES))
    b.add_argument("name", choices=BENCHES)
    b.add_argument("rest", nargs=argparse.REMAINDER, help="options of that benchmark")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hera`` console script; returns the exit code (2 for a bad
    command line, spec or input, with one line per problem on stderr)."""
    args = _parser().parse_args(argv)
    try:
        return _dispatch(args)
    except (LookupError, ValueError, OSError, ImportError) as e:
        for line in str(e).strip().splitlines() or [type(e).__name__]:
            print(f"hera {args.cmd}: {line}", file=sys.stderr)
        return 2


def _dispatch(args: argparse.Namespace) -> int:
    if args.cmd == "node":
        from hera.node import run_node
        from hera.preflight import check_spec

        spec = check_spec(_load(args.spec))
        spec.node(args.node)  # an unknown node is a bad command line, before any logging
        logging.basicConfig(
            level=args.log_level.upper(),
            format=f"%(asctime)s {args.node} %(name)s %(levelname)s %(message)s",
        )
        return run_node(spec, args.node, args.run_dir, args.parent_pid)
    if args.cmd == "up":
        from hera.examples import resolve_spec
        from hera.launcher import Launcher

        spec = resolve_spec(args.spec)
        return Launcher(spec, args.run_dir, args.duration, interval=args.interval).run()
    if args.cmd == "status":
        return _status(args)
    if args.cmd == "down":
        return _down(args)
    if args.cmd == "inject":
        return _inject(args)
    if args.cmd == "measures":
        return _measures(args)
    if args.cmd == "apps":
        from hera.plugins import installed_apps

        for app in installed_apps():
            print(f"{app.name:<12} {app.title}")
            if app.measures:
                print(f"{'':<12} measures: {', '.join(app.measures)}")
        return 0
    if args.cmd == "examples":
        from hera.examples import describe, examples

        for name, path in examples().items():
            print(f"{name:<14} {describe(path)}")
            print(f"{'':<14} {path}")
        return 0
    if args.cmd == "replay":
        return _replay(args)
    if args.cmd == "eval":
        return _eval(args)
    if args.cmd == "bench":
        module = importlib.import_module(f"hera.bench.{args.name}")
        return int(module.main(args.rest) or 0)
    raise AssertionError(args.cmd)


def _load(spec_arg: str):
    """The spec a command line names (a file, or an example's name)."""
    from hera.examples import resolve_spec
    from hera.spec import load_spec

    return load_spec(resolve_spec(spec_arg))


def _measures(args: argparse.Namespace) -> int:
    from hera.plugins import AppIndex, find_measure, known_measures

    if args.name is None:
        for name, target in sorted(known_measures().items()):
            print(f"{name:<16} {target}")
        return 0
    cls = find_measure(args.name)
    app = AppIndex().app_of(cls)
    print(
        f"{args.name}: {cls.__module__}:{cls.__qualname__}"
        + (f" (application {app.name})" if app else "")
    )
    doc = (cls.__doc__ or "").strip().splitlines()
    if doc:
        print(f"  {doc[0]}")
    print(f"  period {cls.period:g} s, sync {'yes' if cls.sync else 'no'}")
    if cls.columns:
        print(f"  columns: {', '.join(cls.columns)}")
    if cls.arguments is None:
        print("  arguments: not declared (the measure checks its own)")
    else:
        print("  arguments:")
        for a in cls.arguments.settings:
            print(f"    {a.key:<16} {a.kind.name:<32} default {a.default_text():<10} {a.doc}")
    settings = getattr(cls, "settings", None)
    if callable(settings) and settings() is not None:
        print(f"  model settings: {', '.join(settings())}")
    return 0


def _status(args: argparse.Namespace) -> int:
    from hera.statusview import render_status

    run_dir = find_run_dir(args.run_dir, args.cluster)
    launcher = {}
    with contextlib.suppress(OSError, ValueError, KeyError):
        launcher = json.loads((run_dir / "launcher.json").read_text())["nodes"]
    with ClusterClient.from_run_dir(run_dir) as client:
        status = client.status(timeout=1.0)
        if args.json:
            print(
                json.dumps(
                    {"cluster": client.spec.name, "nodes": status, "launcher": launcher}, indent=1
                )
            )
        else:
            print(render_status(client.spec.name, status, launcher, run_dir=str(run_dir)))
    return 0 if status else 1


def _down(args: argparse.Namespace) -> int:
    import os
    import signal

    run_dir = find_run_dir(args.run_dir, args.cluster)
    pid = json.loads((run_dir / "launcher.json").read_text())["launcher_pid"]
    if not pid_alive(pid):
        print(f"cluster in {run_dir} is not running")
        return 1
    os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + 20
    while pid_alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    if pid_alive(pid):
        print(f"launcher {pid} did not stop within 20 s", file=sys.stderr)
        return 1
    print(f"cluster in {run_dir} stopped")
    return 0


def _inject(args: argparse.Namespace) -> int:
    run_dir = find_run_dir(args.run_dir, args.cluster)
    if args.fault in ("stop", "start"):
        verb, request = args.fault, {"measure": args.measure}
    else:
        verb, request = "inject", {"fault": args.fault, "measure": args.measure}
    with ClusterClient.from_run_dir(run_dir) as client:
        replies = client.query(args.node, verb, request)
    if args.node not in replies:
        print(f"hera inject: node {args.node!r} did not answer", file=sys.stderr)
        return 1
    reply = replies[args.node]
    print(json.dumps(reply))
    return 0 if reply.get("ok") else 1


def _replay(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hera.replay import model_args_from_spec, pick_models, replay

    if args.spec:
        models = model_args_from_spec(_load(args.spec))
    else:
        spec_path = Path(args.recordings) / "cluster.json"
        models = model_args_from_spec(_load(str(spec_path))) if spec_path.exists() else {}
    wanted = args.models.split(",") if args.models else None
    chosen = pick_models(models, wanted)
    if not chosen:
        raise ValueError("no models to replay: give --models or --spec (or a run dir)")
    like = None
    if args.start_like:
        from hera.replay import live_schedule

        like = live_schedule(args.recordings, args.start_like)
        if not like:
            raise ValueError(f"no live estimates of node {args.start_like!r} in the recordings")
    counts = replay(args.recordings, args.out, chosen, args.node, like)
    for name, n in counts.items():
        print(f"{name:<20} {n:>7} estimates -> {Path(args.out) / 'measures'}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hera.application import EvalOptions
    from hera.evaluate import evaluate, format_table, plot, to_json
    from hera.plugins import AppIndex

    options = EvalOptions(after=args.after, settle=args.settle)
    index = AppIndex()
    results = evaluate(args.run_dir, options, index)
    if not results:
        raise ValueError(f"{args.run_dir}: no model outputs to score (no fusion model logged)")
    if args.json:
        print(json.dumps(to_json(results), indent=1))
    else:
        print(format_table(results))
    if not args.no_plots:
        try:
            out = args.plots or Path(args.run_dir) / "eval"
            files = plot(args.run_dir, out, args.node, options, index)
            if not args.json:
                print("plots: " + (", ".join(str(f) for f in files) or "none"))
        except ImportError as e:
            print(f"plots skipped: {e}", file=sys.stderr)
    return 0
