"""The ``hera`` command line: run clusters, look at them, score and replay their runs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import logging
import os
import sys
import time

from hera import cliargs, tools
from hera.client import find_run_dir, pid_alive

BENCHES = ("bus", "kalman", "sync", "scale", "console", "tilt", "ahrs")


HELP_EXAMPLES = {
    "up": "hera up train",
    "node": "hera node deploy/train.toml --node sonar_1",
    "router": "hera router deploy/two_hosts.toml --name r_a",
    "status": "hera status nav_1",
    "down": "hera down --cluster train",
    "inject": "hera inject n3 crash obs1\n  hera inject sonar_1 board stuck --board sonar_1/sonar"
    "\n  hera inject nav_1 partition        (a cluster started by hera campaign)",
    "campaign": "hera campaign train thesis-ch5\n  hera campaign train nemesis --seed 7"
    "\n  hera campaign train partitions --short"
    "\n  hera campaign train partitions --short --links netns",
    "measures": "hera measures track_radius",
    "apps": "hera apps",
    "examples": "hera examples",
    "replay": "hera replay hera-run/train --out replayed --models e7,e8 "
    "--set track_radius.radius=0.57",
    "eval": "hera eval hera-run/train",
    "import": "hera import erlang-hera logs/2021-05 imported",
    "bench": "hera bench kalman --quick",
    "cache": "hera cache clean --older-than 30",
    "certs": "hera certs deploy/two_hosts.toml --out certs",
    "start": "start with:\n  hera up train            a cluster, its live view\n"
    "  hera eval hera-run/train score the run",
}
"""Examples shown by ``hera --help`` and each subcommand's help (documentation: they may
name the example specs shipped in ``hera.deploy``)."""


def _command(sub, name: str, summary: str, example: str) -> argparse.ArgumentParser:
    """A subcommand with its one-line summary (``hera --help``) and an example."""
    return sub.add_parser(
        name,
        help=summary,
        description=summary[0].upper() + summary[1:] + ".",
        epilog=f"example:\n  {example}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


VERSIONS_OF = ("eclipse-zenoh", "numpy", "msgpack", "numba")
"""The distributions ``hera --version`` names besides hera's own: what a bug report needs."""


def version_line() -> str:
    """``hera X.Y.Z (Python A.B.C; eclipse-zenoh ..., numpy ..., msgpack ..., numba ...)``,
    read from the installed distributions' metadata (nothing is imported); a distribution
    that is not installed reads "numba none"."""
    from importlib.metadata import PackageNotFoundError, version

    from hera import __version__

    parts = []
    for dist in VERSIONS_OF:
        try:
            parts.append(f"{dist} {version(dist)}")
        except PackageNotFoundError:
            parts.append(f"{dist} none")
    py = ".".join(str(v) for v in sys.version_info[:3])
    return f"hera {__version__} (Python {py}; {', '.join(parts)})"


class _Version(argparse.Action):
    """``--version``: print :func:`version_line` and exit 0 (argparse's own action would
    need the line before parsing, which would read the metadata on every command)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the versions and exit")

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        print(version_line())
        parser.exit()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hera",
        description="Hera: distributed, fault-tolerant sensor fusion on Eclipse Zenoh.",
        epilog=HELP_EXAMPLES["start"],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action=_Version)
    sub = p.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    up = _command(
        sub, "up", "start every node of a spec and keep them running", HELP_EXAMPLES["up"]
    )
    up.add_argument("spec", help="cluster spec (TOML file, or an example's name: hera examples)")
    up.add_argument(
        "--duration",
        type=cliargs.positive,
        help="stop after this many seconds of every node up (from the start if a node is "
        "not up within 30 s)",
    )
    up.add_argument(
        "--run-dir",
        help="where logs and recordings go (default: a new hera-run/<cluster>-<time>, "
        "linked from hera-run/<cluster>)",
    )
    up.add_argument("--overwrite", action="store_true", help="replace a previous run in --run-dir")
    up.add_argument(
        "--interval", type=cliargs.positive, default=1.0, help="status refresh period, s"
    )
    up.add_argument(
        "--only",
        help="comma-separated nodes and routers to run on this host (default: all of them)",
    )
    cert_help = "folder made by 'hera certs' (its certificates, or its cluster secret)"
    up.add_argument("--cert", metavar="DIR", help=cert_help + "; overrides [security] certs")
    up.add_argument(
        "--web",
        nargs="?",
        type=cliargs.port,
        const=8765,
        metavar="PORT",
        help="serve the live web view on 127.0.0.1:PORT (default 8765; 0: any free port)",
    )
    up.add_argument("--mcap", metavar="OUT", help="record every sample live to an MCAP file")

    node = _command(
        sub,
        "node",
        "run one node of a spec yourself (hera up does this for you)",
        HELP_EXAMPLES["node"],
    )
    node.add_argument("spec", help="cluster spec (TOML, an example's name, or a cluster.json)")
    node.add_argument("--node", required=True, help="name of the node to run")
    node.add_argument("--run-dir", help="run directory for logs and recordings")
    node.add_argument("--state-dir", help="where the node persists its args (calibrations)")
    node.add_argument("--parent-pid", type=cliargs.count, help="stop when this process is gone")
    node.add_argument("--log-level", type=cliargs.log_level, default="INFO")
    node.add_argument("--cert", metavar="DIR", help=cert_help + "; overrides [security] certs")
    node.add_argument(
        "--check-only",
        action="store_true",
        help="check the whole spec (measures, models, world) as the node would, and exit",
    )
    # hera up checked this spec before it started the node: the node need not load every
    # installed application to check it again (see _checked_apart)
    node.add_argument("--checked", action="store_true", help=argparse.SUPPRESS)

    rt = _command(
        sub,
        "router",
        "run one Zenoh router of a spec (hera up runs the ones it is asked to)",
        HELP_EXAMPLES["router"],
    )
    rt.add_argument("spec", help="cluster spec (TOML, an example's name, or a cluster.json)")
    rt.add_argument("--name", required=True, help="name of the router to run")
    rt.add_argument("--parent-pid", type=cliargs.count, help="stop when this process is gone")
    rt.add_argument("--log-level", type=cliargs.log_level, default="INFO")
    rt.add_argument("--cert", metavar="DIR", help=cert_help + "; overrides [security] certs")

    ce = _command(
        sub,
        "certs",
        "make a cluster CA, a certificate per node, router and operator, and the secret",
        HELP_EXAMPLES["certs"],
    )
    ce.add_argument(
        "spec", help="cluster spec (its nodes' and routers' hosts name the certificates)"
    )
    ce.add_argument("--out", required=True, metavar="DIR", help="folder to write them to")

    st = _command(
        sub,
        "status",
        "show a running cluster (or the details of one node)",
        HELP_EXAMPLES["status"],
    )
    st.add_argument("node", nargs="?", help="a node: every detail of its status")
    st.add_argument("--json", action="store_true", help="print JSON")
    dn = _command(sub, "down", "stop a running cluster", HELP_EXAMPLES["down"])
    inj = _command(sub, "inject", "inject a fault into a running cluster", HELP_EXAMPLES["inject"])
    inj.add_argument("node", help="target node")
    inj.add_argument(
        "fault",
        help="crash | hang | crash_node | stop | start | board | clock | partition | loss | "
        "delay | reset | heal",
    )
    inj.add_argument(
        "measure",
        nargs="?",
        help="the measure (crash, hang, stop, start), the board fault (board: stuck, dropout, "
        "spikes, bias, disconnect, field, clear; the node's 'board' verb lists its boards), or "
        "the value (clock: s, loss: share, delay: ms)",
    )
    inj.add_argument("--board", help="board: the board id, <node>/<board>")
    inj.add_argument(
        "--for", dest="seconds", type=cliargs.positive, help="board: how long it lasts, s"
    )
    inj.add_argument(
        "--param",
        action="append",
        help="board: a fault parameter KEY=VALUE, the value JSON or text (field needs "
        "sensor=S and value=[x,y,z])",
    )
    inj.add_argument("--peers", help="network faults: only the links to these nodes (a,b)")
    inj.add_argument(
        "--jitter", type=cliargs.non_negative, default=0.0, help="delay: +/- this much, ms"
    )
    for s in (st, dn, inj):
        tools.cluster_options(s)

    ms = _command(
        sub, "measures", "list the installed measures, or show one", HELP_EXAMPLES["measures"]
    )
    ms.add_argument("name", nargs="?", help="a measure: show its columns and arguments")
    _command(sub, "apps", "list the installed applications", HELP_EXAMPLES["apps"])
    _command(
        sub, "examples", "list the example specs (hera up NAME runs one)", HELP_EXAMPLES["examples"]
    )

    rp = _command(
        sub,
        "replay",
        "run fusion models offline over recordings",
        HELP_EXAMPLES["replay"],
    )
    rp.add_argument("recordings", help="a run dir or a folder of <name>_<node>.csv files")
    rp.add_argument("--out", required=True, help="where to write <model>_<node>.csv")
    rp.add_argument("--models", help="comma-separated model names or aliases (default: all)")
    rp.add_argument(
        "--spec", help="spec giving the models' settings (default: the recordings' cluster.json)"
    )
    rp.add_argument("--node", type=cliargs.name, default="replay", help="node name of the outputs")
    rp.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="MODEL.SETTING=VALUE",
        help="override a model setting (MODEL.SETTING=VALUE) or the world "
        "(world.KEY=VALUE); repeatable",
    )
    rp.add_argument(
        "--start-like",
        metavar="NODE",
        help="start each model at the first sample NODE's live model fused and write "
        "estimates at the live estimates' instants (to compare a replay with a live node)",
    )
    rp.add_argument(
        "--backend",
        choices=("auto", "numba", "numpy"),
        help="estimation backend of the models (default: the spec's estimation_backend, "
        "as the live nodes ran them)",
    )
    rp.add_argument(
        "--smooth",
        action="store_true",
        help="also write RTS-smoothed estimates of each KF/EKF model to OUT/smoothed "
        "(a run dir: hera eval OUT/smoothed scores them)",
    )

    ev = _command(
        sub, "eval", "score a run through its applications, with plots", HELP_EXAMPLES["eval"]
    )
    ev.add_argument("run_dir")
    ev.add_argument(
        "--settle",
        type=cliargs.non_negative,
        default=10.0,
        help="s after a model's first estimate before settled errors count (default 10)",
    )
    ev.add_argument(
        "--after",
        "--omega-after",
        dest="after",
        type=cliargs.non_negative,
        default=3.0,
        help="s after a model's first estimate before its errors count (default 3)",
    )
    ev.add_argument("--plots", help="folder for the PNG plots (default RUN_DIR/eval)")
    ev.add_argument("--no-plots", action="store_true")
    ev.add_argument(
        "--node",
        help="node(s) whose models are plotted, comma-separated: together (default: the first)",
    )
    ev.add_argument(
        "--reference",
        metavar="FILE",
        help="a recording <name>_<node>.csv (with its .columns.json) to score against when "
        "the run's world has no truth",
    )
    ev.add_argument("--json", action="store_true", help="print JSON")

    cp = _command(
        sub,
        "campaign",
        "run a fault campaign on a cluster, check what happened, write a report",
        HELP_EXAMPLES["campaign"],
    )
    cp.add_argument("spec", help="cluster spec (TOML file, or an example's name)")
    cp.add_argument(
        "campaign", help="campaign file, or a shipped one: thesis-ch5, partitions, nemesis, manual"
    )
    cp.add_argument("--run-dir", help="campaign directory (default: a new hera-run/campaign-*)")
    cp.add_argument(
        "--seed",
        type=cliargs.non_negative_int,
        help="seed of the random choices (default: a new one)",
    )
    cp.add_argument("--short", action="store_true", help="the campaign's short version")
    cp.add_argument(
        "--attach", action="store_true", help="use the running cluster of SPEC (no network faults)"
    )
    cp.add_argument(
        "--links",
        choices=["auto", "proxy", "netns"],
        default="auto",
        help="how network faults cut links: nftables in a network namespace per node (netns: "
        "root, ip and nft needed), the link proxy (proxy), or auto (default): netns where the "
        "machine allows it, the campaign schedules no delay and does not ask for links = true, "
        "else the proxy",
    )
    im = _command(
        sub,
        "import",
        "convert logs of another format into a run directory (hera replay and eval take it)",
        HELP_EXAMPLES["import"],
    )
    im.add_argument("format", help="the logs' format (the installed applications' importers)")
    im.add_argument("src", help="folder of the logs")
    im.add_argument("out", help="the run directory to write (new or empty)")

    tools.add_parsers(sub, _command)

    ca = _command(
        sub, "cache", "show or clean the cache of compiled estimation code", HELP_EXAMPLES["cache"]
    )
    ca.add_argument("action", nargs="?", choices=("list", "clean"), default="list")
    ca.add_argument(
        "--older-than",
        type=cliargs.non_negative,
        default=30.0,
        metavar="DAYS",
        help="clean: also remove what was not used for this many days (default 30); the "
        "kernels of installs that no longer exist go at any age",
    )
    ca.add_argument(
        "--all", action="store_true", help="clean: everything (it compiles again when used)"
    )
    ca.add_argument("--dry-run", action="store_true", help="clean: say what would go; keep it")
    ca.add_argument("--json", action="store_true", help="list: print JSON")

    b = _command(sub, "bench", "run a benchmark: " + ", ".join(BENCHES), HELP_EXAMPLES["bench"])
    b.add_argument("name", choices=BENCHES)
    b.add_argument("rest", nargs=argparse.REMAINDER, help="options of that benchmark")
    return p


STARTERS = ("up", "node", "router", "campaign")  # the commands that start processes


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hera`` console script; returns the exit code (2 for a bad
    command line, spec or input, with one line per problem on stderr)."""
    args = _parser().parse_args(argv)
    try:
        if args.cmd in STARTERS:  # before a run directory or a process is made
            from hera.bus import check_runtime_env

            check_runtime_env()
        return _dispatch(args, argv)
    except BrokenPipeError:  # the reader left (hera measures | head): no error to tell
        # what is still buffered would fail again at exit: send it nowhere (Python's
        # documented way), and exit 1 as a command whose output was cut short
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except (LookupError, ValueError, OSError, ImportError) as e:
        for line in _problem(e).strip().splitlines() or [type(e).__name__]:
            print(f"hera {args.cmd}: {line}", file=sys.stderr)
        return 2


def _problem(e: BaseException) -> str:
    """The text of a refused command: an error of the system about a file reads
    "PATH: reason" ("out/o.mcap: Not a directory"), not Python's "[Errno 20] ..."."""
    if isinstance(e, OSError) and e.filename is not None and e.strerror:
        target = f"{e.filename} -> {e.filename2}" if e.filename2 is not None else e.filename
        return f"{target}: {e.strerror}"
    return str(e)


def _dispatch(args: argparse.Namespace, argv: list[str] | None = None) -> int:
    if args.cmd == "node":
        from hera.node import run_node
        from hera.preflight import check_spec

        spec = _load(args.spec, args.cert)
        spec.node(args.node)  # an unknown node is a bad command line, before any logging
        if args.check_only:
            check_spec(spec)
            return 0
        if not args.checked:
            code = _checked_apart(argv if argv is not None else sys.argv[1:])
            if code:
                return code
        spec = _lone_secret(spec, args.run_dir)
        logging.basicConfig(
            level=args.log_level.upper(),
            format=f"%(asctime)s {args.node} %(name)s %(levelname)s %(message)s",
        )
        return run_node(spec, args.node, args.run_dir, args.parent_pid, args.state_dir)
    if args.cmd == "up":
        from hera.examples import resolve_spec
        from hera.launcher import Launcher

        spec = resolve_spec(args.spec)
        only = [x.strip() for x in args.only.split(",") if x.strip()] if args.only else None
        launcher = Launcher(
            spec,
            args.run_dir,
            args.duration,
            interval=args.interval,
            overwrite=args.overwrite,
            only=only,
            cert=args.cert,
            web=args.web,
            mcap=args.mcap,
        )
        return launcher.run()
    if args.cmd == "router":
        from hera.router import run_router

        spec = _load(args.spec, args.cert)
        spec.router(args.name)
        logging.basicConfig(
            level=args.log_level.upper(),
            format=f"%(asctime)s {args.name} %(name)s %(levelname)s %(message)s",
        )
        return run_router(spec, args.name, args.parent_pid)
    if args.cmd == "certs":
        return _certs(args)
    if args.cmd in tools.COMMANDS:
        return tools.run(args)
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
    if args.cmd == "campaign":
        from hera.campaign.runner import CampaignRun

        command = " ".join(["hera", *(argv if argv is not None else sys.argv[1:])])
        run = CampaignRun(
            args.spec, args.campaign, args.run_dir, args.seed, args.short, args.attach,
            links=args.links,
        )  # fmt: skip
        return run.run(command)
    if args.cmd == "import":
        return _import(args)
    if args.cmd == "cache":
        return _cache(args)
    if args.cmd == "bench":
        module = importlib.import_module(f"hera.bench.{args.name}")
        return int(module.main(args.rest) or 0)
    raise AssertionError(args.cmd)


def _checked_apart(argv: list[str]) -> int:
    """Check a node's spec in a child process (``hera node ... --check-only``): the check
    loads every installed application and its models (about 18 MB, numpy included), which
    the node itself, running only its own measures, never needs. Returns the child's exit
    code; it prints the problems (``hera node: ...``, exit code 2)."""
    import subprocess

    from hera.launcher import node_command

    return subprocess.run(node_command(*argv, "--check-only")).returncode


def _load(spec_arg: str, cert: str | None = None):
    """The spec a command line names (a file, or an example's name), with ``--cert``."""
    from pathlib import Path

    from hera.examples import resolve_spec
    from hera.spec import load_spec

    spec = load_spec(resolve_spec(spec_arg))
    return spec if cert is None else spec.with_security(certs=str(Path(cert).resolve()))


def _lone_secret(spec, run_dir: str | None):
    """A node run by hand with authentication on and no credentials (no ``--cert``, no
    ``[security] certs``, not a ``hera up`` cluster.json) makes its own secret: in its run
    directory, else in a private temporary folder removed at exit. It can join no other
    node, which is what it says in its log."""
    import atexit
    import shutil
    import tempfile
    from pathlib import Path

    from hera.security.secret import SECRET_FILE, make_secret

    if not spec.auth or spec.tls or spec.certs or spec.secret:
        return spec
    if run_dir is not None:
        folder = Path(run_dir)
    else:
        folder = Path(tempfile.mkdtemp(prefix="hera-node-"))
        atexit.register(shutil.rmtree, folder, True)
    path = folder / SECRET_FILE
    if not path.exists():
        make_secret(path)
    logging.getLogger("hera.node").warning(
        "no cluster credentials given: this node made its own secret (%s) and can join no "
        "other node; give --cert DIR (made by 'hera certs') to join a cluster",
        path,
    )
    return spec.with_security(secret=str(path.resolve()))


def _certs(args: argparse.Namespace) -> int:
    from hera.security.certs import make_certs
    from hera.security.credentials import cert_hosts

    spec = _load(args.spec)
    written = make_certs(args.out, spec.name, cert_hosts(spec))
    print(f"cluster {spec.name}: CA {args.out}/ca.pem (keep ca.key off the cluster's hosts)")
    for path in written:
        print(f"  {path}")
    print(f"  {args.out}/secret (the cluster secret, for links without TLS)")
    return 0


def _cache(args: argparse.Namespace) -> int:
    """``hera cache``: the entries of the estimation cache, or ``clean``: remove some."""
    from hera.estimation import cache
    from hera.estimation.backend import cache_dir

    where = cache_dir()
    spec = importlib.util.find_spec(f"hera.estimation.{cache.KERNELS_SOURCE}")
    here = spec.origin if spec is not None else None
    now = time.time()

    def line(e: cache.Entry) -> str:
        note = " (this install)" if e.current else " (install gone)" if e.gone else ""
        origin = e.origin or "install not recorded"
        size, age = cache.megabytes(e.size), cache.describe_age(e.used, now)
        return f"{e.kind:<8}{size:>9}  {age:<13} {origin}{note}"

    if args.action == "list":
        entries = cache.scan(where, here)
        if args.json:
            keys = ("kind", "name", "origin", "size", "used", "gone", "current")
            rows = [{k: getattr(e, k) for k in keys} for e in entries]
            print(json.dumps({"cache": str(where), "entries": rows}, indent=1))
            return 0
        sets = sum(e.kind == "kernels" for e in entries)
        total = cache.megabytes(sum(e.size for e in entries))
        print(f"{where}: {sets} kernel sets, {len(entries) - sets} compiled models, {total}")
        for e in entries:
            print(line(e))
        return 0
    keep_out = where.is_dir() and not args.dry_run  # a compile waits while we delete
    with cache.locked(where) if keep_out else contextlib.nullcontext():
        entries = cache.scan(where, here)
        chosen = cache.choose(entries, now, args.older_than, args.all)
        verb = "would remove" if args.dry_run else "removed"
        freed = sum(e.size for e in chosen) if args.dry_run else cache.remove(chosen)
        if not args.dry_run:
            cache.remove_orphan_markers(where)
    for e in chosen:
        print(f"{verb}: {line(e)}")
    kept = [e for e in entries if e not in chosen]
    print(
        f"{verb} {_count(len(chosen), 'entry', 'entries')} ({cache.megabytes(freed)}); kept "
        f"{len(kept)} ({cache.megabytes(sum(e.size for e in kept))}) in {where}"
    )
    return 0


def _count(n: int, one: str, many: str) -> str:
    """``1 entry``, ``3 entries``."""
    return f"{n} {one if n == 1 else many}"


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
    from hera.client import running_clusters
    from hera.statusview import render_node, render_status

    if not (args.connect or args.run_dir or args.cluster) and len(running_clusters()) > 1:
        print("clusters running (pick one with --cluster NAME or --run-dir DIR):")
        for c in running_clusters():
            print(f"  {c['cluster']:<16} launcher {c['launcher_pid']:<8} {c['run_dir']}")
        return 0
    with tools.connect(args) as client:
        if args.node is not None:
            if client.spec is not None:
                client.spec.node(args.node)  # an unknown node lists the known ones
            reply = client.query(args.node, "status", timeout=1.0).get(args.node)
            if reply is None:
                print(f"hera status: node {args.node!r} did not answer", file=sys.stderr)
                return 1
            print(json.dumps(reply, indent=1) if args.json else render_node(reply))
            return 0
        status = client.status(timeout=1.0)
        launched = client.launched()
        if args.json:
            print(
                json.dumps(
                    {"cluster": client.cluster, "nodes": status, "launcher": launched}, indent=1
                )
            )
        else:
            print(render_status(client.cluster, status, launched))
    return 0 if status else 1


def _down(args: argparse.Namespace) -> int:
    import os
    import signal

    if args.connect:
        return _down_over_the_bus(args)
    run_dir = find_run_dir(args.run_dir, args.cluster)
    pid = _launcher_pid(run_dir / "launcher.json")
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


def _launcher_pid(path) -> int:
    """The launcher's pid its ``launcher.json`` records; ValueError naming the file when it
    is not there or not one."""
    if not path.exists():
        raise ValueError(f"{path}: no such file: is {path.parent} a run directory of 'hera up'?")
    try:
        pid = json.loads(path.read_text())["launcher_pid"]
    except (ValueError, KeyError, TypeError):
        pid = None
    if isinstance(pid, bool) or not isinstance(pid, int) or pid <= 0:
        raise ValueError(f"{path}: not a launcher's record (launcher_pid, written by 'hera up')")
    return pid


def _down_over_the_bus(args: argparse.Namespace) -> int:
    """Stop a cluster from any host: the nodes no launcher runs (started by hand) get
    ``shutdown``, then every launcher on the bus is asked at once to stop what it runs
    (the ones that run routers last: the others' requests travel through them)."""
    with tools.connect(args) as client:
        launchers = client.launchers(timeout=2.0)
        launched = {n for st in launchers.values() for n in st.get("nodes", {})}
        for node in sorted(set(client.status(timeout=1.0)) - launched):
            client.query(node, "shutdown", timeout=1.0)
        order = sorted(launchers, key=lambda lid: bool(launchers[lid].get("routers")))
        pending = [
            (lid, client.session.get(client.keys.launcher(lid, "down"), timeout=3.0))
            for lid in order
        ]  # every request is on its way before the first launcher stops its routers
        stopping = [lid for lid, replies in pending if any(r.ok for r in replies)]
    missing = sorted(set(launchers) - set(stopping))
    if missing:
        print(f"hera down: launchers {missing} did not answer", file=sys.stderr)
        return 1
    print(f"cluster {client.cluster}: {len(stopping)} launchers stopping ({', '.join(stopping)})")
    return 0


def _inject(args: argparse.Namespace) -> int:
    if args.fault in ("board", "clock", "partition", "loss", "delay", "reset", "heal"):
        from hera.campaign.manual import inject

        run_dir = None if args.connect else find_run_dir(args.run_dir, args.cluster)
        peers = args.peers.split(",") if args.peers else None
        with tools.connect(args) as client:
            reply = inject(
                client,
                run_dir,
                args.node,
                args.fault,
                args.measure,
                args.board,
                args.seconds,
                args.param,
                peers,
                args.jitter,
            )
        print(json.dumps(reply))
        return 0 if reply.get("ok") else 1
    if args.fault in ("stop", "start"):
        verb, request = args.fault, {"measure": args.measure}
    else:
        verb, request = "inject", {"fault": args.fault, "measure": args.measure}
    with tools.connect(args) as client:
        if client.spec is not None:
            client.spec.node(args.node)  # an unknown node lists the known ones
        replies = client.query(args.node, verb, request)
    if args.node not in replies:
        print(f"hera inject: node {args.node!r} did not answer", file=sys.stderr)
        return 1
    reply = replies[args.node]
    if not reply.get("ok") and reply.get("error"):  # refused: what was wrong, as stop says
        print(f"hera inject: {args.node}: {reply['error']}", file=sys.stderr)
        return 2
    print(json.dumps(reply))
    return 0 if reply.get("ok") else 1


def _replay(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hera.plugins import installed_apps
    from hera.replay import (
        apply_overrides,
        model_args_from_spec,
        pick_models,
        replay,
        with_producers,
    )
    from hera.rundirs import folder_problem

    problem = folder_problem(args.recordings)
    if problem:
        raise ValueError(
            f"{problem}: give a run directory of 'hera up' (or of 'hera import') or a folder "
            "of <name>_<node>.csv recordings"
        )
    spec_path = Path(args.recordings) / "cluster.json"
    recorded = _load(str(spec_path)) if spec_path.exists() else None
    spec = _load(args.spec) if args.spec else recorded
    # before any model is made (choosing them makes some): the first filter fixes the backend
    chosen_backend = args.backend or (spec.estimation_backend if spec is not None else None)
    _replay_backend(chosen_backend)
    models = model_args_from_spec(spec) if spec is not None else {}
    wanted = args.models.split(",") if args.models else None
    chosen = with_producers(pick_models(models, wanted), models)
    if not chosen:
        raise ValueError("no models to replay: give --models or --spec (or a run dir)")
    world = None
    if args.overrides:

        def check_world(w):
            return [p for app in installed_apps() for p in app.check_world(w)]

        base = recorded.world if recorded is not None else {}
        chosen, world = apply_overrides(chosen, base, args.overrides, check_world)
        if not any(o.partition("=")[0].startswith("world.") for o in args.overrides):
            world = None
    like = None
    if args.start_like:
        from hera.replay import live_schedule

        like = live_schedule(args.recordings, args.start_like)
        if not like:
            raise ValueError(f"no live estimates of node {args.start_like!r} in the recordings")
    from hera.progress import Progress

    with Progress("replay") as progress:
        if chosen_backend is not None:
            origin = "--backend" if args.backend else "the spec's estimation_backend"
            progress.say(f"estimation backend: {chosen_backend} ({origin})")
        counts = replay(
            args.recordings,
            args.out,
            chosen,
            args.node,
            like,
            progress,
            smooth=args.smooth,
            say=progress.say,
            world=world,
            spec=spec if args.spec else None,
        )
    for name, n in counts.items():
        print(f"{name:<20} {n:>7} estimates -> {Path(args.out) / 'measures'}")
    if args.start_like:
        from hera.replay import (
            live_markers,
            why_inputs_not_exact,
            why_not_exact,
            why_recordings_incomplete,
        )

        for name, live in live_markers(args.recordings, args.start_like).items():
            why = why_not_exact(name, args.start_like, live) if name in counts else None
            if why is not None:
                print(why)
        for why in why_inputs_not_exact(args.recordings, chosen).values():
            print(why)
        for why in why_recordings_incomplete(args.recordings, chosen, like or {}).values():
            print(why)
    return 0


def _replay_backend(name: str | None) -> None:
    """Run the replayed models on ``name`` (``--backend``, else the spec's
    ``estimation_backend``: the live nodes' arithmetic, and no compile on the numpy default);
    None (no spec) keeps the library's default."""
    if name is None:
        return
    if name == "numba":
        import importlib.util

        if importlib.util.find_spec("numba") is None:
            raise ValueError("estimation backend 'numba' asked for, but numba is not installed")
    from hera.estimation import backend

    backend.prefer(name)


def _eval(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hera.application import EvalOptions
    from hera.evaluate import evaluate, format_table, notes, plot, sources, to_json
    from hera.plugins import AppIndex

    options = EvalOptions(after=args.after, settle=args.settle)
    plots = Path(args.plots) if args.plots and not args.no_plots else None
    if plots is not None and plots.exists() and not plots.is_dir():
        raise ValueError(f"--plots {args.plots}: not a folder")
    index = AppIndex()
    from hera.progress import Progress

    with Progress("eval") as progress:
        results = evaluate(args.run_dir, options, index, args.reference, progress)
    if not results:
        raise ValueError(f"{args.run_dir}: no model outputs to score (no fusion model logged)")
    nodes = args.node.split(",") if args.node else None
    have = sorted({r.series.node for r in results})
    unknown = [n for n in nodes or () if n not in have]
    if unknown and not args.no_plots:
        raise ValueError(
            f"--node {','.join(unknown)}: no model outputs of that node in {args.run_dir} "
            f"(nodes: {', '.join(have)})"
        )
    for line in notes(results):
        print(line, file=sys.stderr)
    if args.json:
        print(json.dumps(to_json(results), indent=1))
    else:
        print("\n".join([*sources(results), format_table(results)]))
    if not args.no_plots:
        try:
            out = args.plots or Path(args.run_dir) / "eval"
            files = plot(args.run_dir, out, nodes, options, index, args.reference)
            if not args.json:
                print("plots: " + (", ".join(str(f) for f in files) or "none"))
        except ImportError as e:
            print(f"plots skipped: {e}", file=sys.stderr)
    return 0


def _import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from hera.plugins import installed_apps

    importers = {f: (app, fn) for app in installed_apps() for f, fn in app.importers().items()}
    if args.format not in importers:
        known = ", ".join(f"{f} ({a.name})" for f, (a, _) in sorted(importers.items()))
        raise ValueError(f"unknown log format {args.format!r}; formats: {known or 'none'}")
    src, out = Path(args.src), Path(args.out)
    if not src.is_dir():
        raise ValueError(f"{src}: {'not a folder' if src.exists() else 'no such folder'} of logs")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out}: exists and is not empty; give a new folder")
    made = not out.exists()
    try:
        print(importers[args.format][1](src, out))
    except BaseException:  # refused or stopped: no half-written run directory stays
        import shutil

        if made:
            shutil.rmtree(out, ignore_errors=True)
        elif out.is_dir():
            for entry in out.iterdir():
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
        raise
    return 0
