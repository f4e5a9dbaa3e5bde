"""``hera campaign SPEC CAMPAIGN``: run a fault campaign on a cluster, judge it, report.

1. Check the spec and the campaign whole (every problem at once, exit 2, nothing started);
   draw the plan from the seed (a new seed is drawn and printed when none is given).
2. Make the campaign directory (layout: :mod:`hera.campaign.history`), fix the ports, point
   every auditing measure's ``fire_log`` into ``audit/``, and, when the campaign has
   network faults, start the link proxy and route the nodes' links through it, or (``--links
   netns``) put every node in a network namespace of its own whose links nftables cuts
   (:mod:`hera.campaign.netns`).
3. Start the cluster (``hera up`` into ``<dir>/run``) and the recorder, wait until every
   stream of the spec flows and every sync group has a leader (at most ``settle_s``).
4. Quiet baseline, the schedule (each fault struck and undone by
   :mod:`hera.campaign.actuators`, journaled), quiet tail.
5. Snapshot every node's args and status, stop the cluster (SIGTERM, then SIGKILL to
   anything of the run still alive, which is recorded as a leftover), stop the proxy or
   remove the namespaces.
6. Run the checkers (:mod:`hera.campaign.checkers`) and write the report
   (:mod:`hera.campaign.report`). Exit code 0 only when every checker passes.

Ctrl-C (or SIGTERM) ends the schedule early: the fault in progress is undone, the cluster
stopped, and the run checked and reported all the same (the report says it was cut short).
With ``--attach`` the campaign works on a cluster that already runs (started with ``hera
up``): it records, strikes and judges, but cannot route links (no network faults) nor audit
firings it did not set up, and leaves the cluster running.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import IO, Any

from hera.campaign import clockmap, history, journal, netns
from hera.campaign.actuators import Injector
from hera.campaign.links import PLAN_FILE, ProxyProcess, node_env, plan_links, write_plan
from hera.campaign.plan import Planned, make_plan
from hera.campaign.recorder import Recorder
from hera.campaign.schema import (
    NETWORK,
    Campaign,
    CampaignError,
    load_campaign,
    resolve_campaign,
)
from hera.campaign.targets import ClusterView
from hera.client import ClusterClient, find_run_dir
from hera.examples import resolve_spec
from hera.launcher import node_command
from hera.plugins import find_measure
from hera.ports import free_ports
from hera.preflight import check_spec
from hera.rundirs import new_run_dir
from hera.security.secret import SECRET_FILE, make_secret
from hera.spec import ClusterSpec, load_spec
from hera.topology import host_of

STOP_TIMEOUT_S = 30.0
LINKS = ("proxy", "netns", "auto")
"""How network faults are made: the link proxy, nftables in a namespace per node, or
nftables where this machine allows it (:func:`hera.campaign.netns.problem`) and the proxy
elsewhere."""


def spec_problems(campaign: Campaign, spec: ClusterSpec) -> list[str]:
    """What in the campaign does not fit the spec (unknown nodes, measures, groups)."""
    names = {n.name for n in spec.nodes}
    groups = spec.sync_groups()
    measures = {(n, m.name) for n, m in spec.measures()}
    out = []

    def target_ok(t: str, where: str, side: bool = False) -> None:
        if t in names or t == "random" or (side and t == "others"):
            return
        role, _, group = t.partition(":")
        if role in ("leader", "follower", "host") and group:
            if group not in groups:
                out.append(
                    f"{where}: no sync group {group!r} in the spec (groups: "
                    f"{', '.join(groups) or 'none'})"
                )
            return
        out.append(
            f"{where}: target {t!r} is neither a node ({', '.join(sorted(names))}) nor "
            "a role (leader:<group>, follower:<group>, host:<group>, random)"
        )

    for i, f in enumerate(campaign.faults, start=1):
        where = f"{campaign.source}: [[faults]] #{i} ({f.name})"
        if f.get("target") is not None:
            target_ok(f.get("target"), where)
        for t in f.get("peers", []):
            target_ok(t, where)
        for side in f.get("groups", []):
            for t in side:
                target_ok(t, where, side=True)
        m = f.get("measure")
        t = f.get("target")
        if m is not None and t in names and (t, m) not in measures:
            out.append(f"{where}: node {t!r} has no measure {m!r}")
        b = f.get("board")
        if b is not None and b.split("/", 1)[0] not in names:
            out.append(f"{where}: board {b!r} is not on a node of the spec (use <node>/<board>)")
    if campaign.nemesis is not None:
        where = f"{campaign.source}: [nemesis]"
        for t in campaign.nemesis.get("targets") or []:
            if t not in names:
                out.append(f"{where}: targets: no node {t!r} in the spec")
        for nm in campaign.nemesis.get("measures") or []:
            node, _, m = nm.partition("/")
            if (node, m) not in measures:
                out.append(f"{where}: measures: no measure {nm!r} (<node>/<measure>) in the spec")
        for b in campaign.nemesis.get("boards") or []:
            if b.split("/", 1)[0] not in names:
                out.append(f"{where}: boards: board {b!r} is not on a node of the spec")
    if campaign.network:
        out.extend(network_problems(campaign, spec))
    return out


def network_problems(campaign: Campaign, spec: ClusterSpec) -> list[str]:
    """Why the link proxy cannot stand between the spec's nodes: it needs the plain full
    mesh of peers on one host (no routers, no client nodes, no endpoints of their own). It
    carries bytes, so TLS links go through it as they are (the nodes dial its ports with
    their own certificates: :func:`hera.node.node_bus`)."""
    where = f"{campaign.source}: network faults (partition, loss, delay, reset)"
    out = []
    if spec.routers:
        out.append(f"{where} need a full mesh of peers; the spec has routers")
    for n in spec.nodes:
        if n.mode != "peer" or n.listen is not None or n.connect is not None:
            out.append(
                f"{where} need every node a peer on its own port; node {n.name!r} sets "
                "mode, listen or connect"
            )
    if spec.spans_hosts():
        out.append(f"{where} need every node on one host; the spec spans several")
    return out


def auditing(spec: ClusterSpec) -> list[tuple[str, str, str]]:
    """(node, measure, sync group) of every measure that can audit its firings (its class
    declares a ``fire_log`` argument)."""
    out = []
    for node, m in spec.measures():
        cls = find_measure(m.use)
        if cls.arguments is not None and "fire_log" in cls.arguments.by_key:
            out.append((node, str(m.name), m.resolve(cls).group))
    return out


def with_fire_logs(spec: ClusterSpec, audit: Path) -> tuple[ClusterSpec, dict[str, dict]]:
    """``spec`` with every auditing measure's ``fire_log`` in ``audit``; the logs' map."""
    logs: dict[str, dict[str, str]] = {}
    targets = {(n, m): g for n, m, g in auditing(spec)}
    nodes = []
    for n in spec.nodes:
        ms = []
        for m in n.measures:
            g = targets.get((n.name, str(m.name)))
            if g is not None:
                fname = f"fire-{n.name}-{m.name}.log"
                logs[fname] = {"node": n.name, "measure": str(m.name), "group": g}
                m = replace(m, args={**m.args, "fire_log": str(audit / fname)})
            ms.append(m)
        nodes.append(replace(n, measures=tuple(ms)))
    return replace(spec, nodes=tuple(nodes)), logs


def _die_with_parent() -> None:
    """In a child before exec (Linux): get SIGTERM when the campaign dies, so that ``hera
    up`` stops its nodes even if the campaign is SIGKILLed (``PR_SET_PDEATHSIG``)."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG


def _ancestors() -> set[int]:
    """This process and its ancestors (whose command lines may name the folder too: a
    shell, ``flock``)."""
    out, pid = set(), os.getpid()
    while pid > 1 and pid not in out:
        out.add(pid)
        try:
            stat = (Path("/proc") / str(pid) / "stat").read_text()
            pid = int(stat.rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return out


def processes_of(folder: Path) -> list[dict[str, Any]]:
    """Processes of hera's own (``python -c "... from hera. ..."``: nodes, the launcher,
    the link proxy) whose command line names ``folder``, this one and its ancestors
    excepted."""
    mark = str(folder)
    mine = _ancestors()
    out = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) in mine:
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if mark in cmd and "from hera." in cmd:  # a node, the launcher, the link proxy
            out.append({"pid": int(proc.name), "cmdline": cmd.strip()[:300]})
    return out


class CampaignRun:
    """One run of a campaign on a cluster (see the module docstring)."""

    def __init__(
        self,
        spec_arg: str,
        campaign_arg: str,
        run_dir: str | None = None,
        seed: int | None = None,
        short: bool = False,
        attach: bool = False,
        out: IO[str] | None = None,
        links: str = "auto",
    ) -> None:
        import sys

        self.out = out or sys.stdout
        self.campaign = load_campaign(resolve_campaign(campaign_arg))
        if short:
            self.campaign = self.campaign.shortened()
        self.attach = attach
        if attach:
            cluster_dir = find_run_dir(None, load_spec(resolve_spec(spec_arg)).name)
            spec = load_spec(cluster_dir / "cluster.json")
            self.cluster_dir = cluster_dir
        else:
            spec = check_spec(load_spec(resolve_spec(spec_arg)))
        problems = spec_problems(self.campaign, spec)
        if attach and self.campaign.network:
            problems.append(
                f"{self.campaign.source}: network faults need a cluster started by the "
                "campaign (its links run through the link proxy); leave out --attach"
            )
        self.links = self._links_backend(links, spec, problems)
        if problems:
            raise CampaignError(problems)
        self.seed = seed if seed is not None else random.SystemRandom().randrange(1, 10**6)
        self.plan = make_plan(self.campaign, spec, self.seed)
        self.spec = spec
        if run_dir is not None:
            folder = Path(run_dir)
            if folder.exists() and any(folder.iterdir()):
                raise CampaignError(
                    [f"run directory {folder} is not empty: give another --run-dir"]
                )
            folder.mkdir(parents=True, exist_ok=True)
            self.folder = folder.resolve()
        else:
            self.folder = new_run_dir(f"campaign-{self.campaign.name}")
        self.stopping = threading.Event()
        self.times: dict[str, float] = {}
        self.proxy: ProxyProcess | None = None
        self.netns: netns.Namespaces | None = None
        self.launcher: subprocess.Popen | None = None
        self.client: ClusterClient | None = None
        self.recorder: Recorder | None = None
        self.fire_logs: dict[str, dict[str, str]] = {}
        self.interrupted = False
        self.holding = False
        self.settle_error: str | None = None
        self.error: str | None = None
        self.state_dir: Path | None = None

    def _links_backend(self, links: str, spec: ClusterSpec, problems: list[str]) -> str:
        """``proxy`` or ``netns`` for ``--links``; a problem added when it cannot be."""
        if links not in LINKS:
            problems.append(f"--links must be one of {', '.join(LINKS)}, got {links!r}")
            return "proxy"
        if not self.campaign.network or links == "proxy":
            return "proxy"
        delays = [f.name for f in self.campaign.faults if f.kind == "delay"]
        if self.campaign.nemesis is not None and self.campaign.nemesis["kinds"].get("delay"):
            delays.append("[nemesis]")
        if links == "auto":  # by-hand faults (links = true) may be delays: the proxy does all
            if delays or self.campaign.links or spec.tls or netns.problem():
                return "proxy"
            return "netns"
        why = netns.problem()
        if spec.tls:
            problems.append(
                f"{spec.source}: [security] tls = true: its certificates name the spec's hosts, "
                "not the namespaces' addresses: use --links proxy"
            )
        if why:
            problems.append(f"--links netns cannot be used on this machine: {why}")
        for name in delays:
            problems.append(
                f"{self.campaign.source}: {name}: delay faults need the link proxy (nftables "
                "drops or passes packets, it cannot hold them): use --links proxy"
            )
        return "netns"

    # -- output -------------------------------------------------------------------------
    def say(self, text: str) -> None:
        print(f"[campaign {time.strftime('%H:%M:%S')}] {text}", file=self.out, flush=True)

    def _mark(self, key: str) -> None:
        self.times[key] = time.time()
        self._write_meta()

    def _write_meta(self) -> None:
        wall, clock = journal.now()
        meta = {
            "campaign": self.campaign.as_dict(),
            "seed": self.seed,
            "command": getattr(self, "command", None),
            "spec_source": self.spec.source,
            "cluster": self.spec.name,
            "attach": self.attach,
            "links": self.links if self.campaign.network else None,
            "times": self.times,
            "clock_offset": self.clock_offset,
            "fire_logs": self.fire_logs,
            "state_dir": str(self.state_dir) if self.state_dir else None,
            "interrupted": self.interrupted,
            "settle_error": self.settle_error,
            "error": self.error,
            "plan_faults": len(self.plan),
        }
        tmp = self.folder / (history.META + ".tmp")
        tmp.write_text(json.dumps(meta, indent=1))
        os.replace(tmp, self.folder / history.META)

    # -- the run ------------------------------------------------------------------------
    def run(self, command: str | None = None) -> int:
        """Run, check, report; return the exit code (0: every checker passed).
        ``command``: the command line, for the report."""
        from hera.campaign import checkers, report

        self.command = command or f"hera campaign {self.spec.source} {self.campaign.source}"
        if "--seed" not in self.command.split():
            self.command += f" --seed {self.seed}"  # the command that repeats this schedule

        wall, clock = journal.now()
        self.clock_offset = wall - clock
        anchors = clockmap.AnchorWriter(self.folder).start()  # the clocks, sampled together
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, self._interrupt)
        try:
            self._prepare()
            self.say(
                f"campaign {self.campaign.name!r} on cluster {self.spec.name!r}, seed "
                f"{self.seed}, {len(self.plan)} faults; directory {self.folder}"
            )
            self._start()
            if self._settle():
                self._wait(self.campaign.baseline_s, "baseline")
                self._schedule()
                if self.campaign.hold_s and not self.stopping.is_set():
                    self.holding = True
                    self._wait(
                        self.campaign.hold_s,
                        "holding: inject faults by hand (hera inject ...); Ctrl-C ends it",
                    )
                    self.holding = False
                    self.stopping.clear()
                if not self.stopping.is_set():
                    self._wait(self.campaign.tail_s, "tail")
            self._snapshot()
        except Exception as e:  # the run broke: stop, then check and report what there is
            self.error = f"{type(e).__name__}: {e}"
            self.say(f"the run broke: {self.error}")
        finally:
            self._stop()
            anchors.stop()
            for sig, h in handlers.items():
                signal.signal(sig, h)
        self.say("checking the run")
        h = history.load(self.folder)
        verdicts = checkers.run_all(h)
        files = report.write(h, verdicts)
        failed = [v.name for v in verdicts if not v.passed]
        self.say(f"report: {files[0]}")
        self.say("every checker passed" if not failed else f"failed: {', '.join(failed)}")
        return 0 if not failed else 1

    def _interrupt(self, *_: object) -> None:
        if self.holding:  # the way a hold ends
            self.stopping.set()
            return
        if not self.stopping.is_set():
            self.interrupted = True
            self.say("interrupted: undoing the fault in progress, stopping, checking")
        self.stopping.set()

    def _wait(self, seconds: float, what: str = "") -> bool:
        """Sleep ``seconds`` unless stopped; True if not stopped."""
        if what:
            self.say(f"{what}: {seconds:g} s")
        return not self.stopping.wait(max(0.0, seconds))

    def _prepare(self) -> None:
        f = self.folder
        (f / history.AUDIT).mkdir(exist_ok=True)
        (f / history.PLAN).write_text(json.dumps([p.as_dict() for p in self.plan], indent=1))
        spec = self.spec
        if not self.attach:
            n = len(spec.nodes)
            pairs = n * (n - 1) if self.campaign.network and self.links == "proxy" else 0
            unported = len(spec.unported())
            ports = free_ports(spec.host, unported + pairs)
            if unported:
                spec = spec.with_ports(ports[:unported])
                ports = ports[unported:]
            if "epoch" not in spec.world:
                spec = spec.with_world(epoch=time.time())
            spec, self.fire_logs = with_fire_logs(spec, f / history.AUDIT)
            if self.campaign.network and self.links == "netns":
                plan = netns.Namespaces.new_plan([n.name for n in spec.nodes])
                write_plan(plan, f)
                self.netns = netns.Namespaces(plan)
                spec = spec.with_hosts({n: self.netns.addr(n) for n in plan["nodes"]})
                if spec.auth and not spec.tls and not spec.certs:
                    # the "hosts" span one machine: they share a secret made here, as the
                    # hosts of a real spec share a 'hera certs' folder
                    make_secret(f / "credentials" / SECRET_FILE)
                    spec = spec.with_security(certs=str(f / "credentials"))
            elif self.campaign.network:
                plan = write_plan(plan_links(spec, ports, self.seed), f)
                self.proxy = ProxyProcess(plan, f / "linkproxy.log")
        self.spec = spec
        (f / "spec.json").write_text(spec.to_json())
        self._write_meta()

    def _start(self) -> None:
        f = self.folder
        env = None
        if self.proxy is not None:
            self.proxy.start()
            env = node_env(self.proxy.plan_path)
            self.say(
                f"link proxy up (pid {self.proxy.pid}): every link between nodes runs through it"
            )
        if self.netns is not None:
            self.netns.create()
            env = node_env(f / PLAN_FILE)
            self.say(
                f"{len(self.netns.nodes)} network namespaces on bridge "
                f"{self.netns.plan['bridge']} ({self.netns.plan['root_addr']}/24): each node "
                "runs in its own, nftables cuts their links"
            )
        if self.attach:
            run_dir = self.cluster_dir
            (f / history.RUN).symlink_to(run_dir)
            # hera up keeps state in the run dir given to it, else beside the runs
            beside = run_dir.parent / f"{self.spec.name}.state"
            self.state_dir = run_dir / "state" if (run_dir / "state").is_dir() else beside
        else:
            run_dir = f / history.RUN
            with open(f / history.LAUNCHER_OUT, "ab") as out:
                self.launcher = subprocess.Popen(
                    node_command(
                        "up", str(f / "spec.json"), "--run-dir", str(run_dir), "--interval", "2"
                    ),
                    stdout=out,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                    env=env,
                    start_new_session=True,
                    preexec_fn=_die_with_parent if os.name == "posix" else None,
                )
            self._wait_listening()
            self._take_credentials(run_dir)
        self._mark("started")
        self.client = ClusterClient(self.spec)
        self.recorder = Recorder(self.client.session, self.client.keys, f)
        self.view = ClusterView(self.client, run_dir)
        self.injector = Injector(
            self.view,
            f,
            self.seed,
            self.proxy or self.netns,
            [f / history.AUDIT / name for name in self.fire_logs],
        )

    def _take_credentials(self, run_dir: Path) -> None:
        """Take the cluster's credentials (the secret ``hera up`` made for this run) from
        the spec it wrote, so the campaign's own session is let in like an operator's."""
        if not (self.spec.auth and not self.spec.tls and not self.spec.certs):
            return
        if not (run_dir / "cluster.json").exists():
            raise RuntimeError(f"hera up wrote no {run_dir / 'cluster.json'}: see its output")
        secret = load_spec(run_dir / "cluster.json").secret
        self.spec = self.spec.with_security(secret=secret)

    def _wait_listening(self, timeout: float = 30.0) -> None:
        """Until every node's port accepts connections (or the launcher died)."""
        import socket

        deadline = time.monotonic() + timeout
        pending = {n.name: (host_of(self.spec, n), n.port) for n in self.spec.nodes}
        while pending and time.monotonic() < deadline and not self.stopping.is_set():
            if self.launcher is not None and self.launcher.poll() is not None:
                return
            for name, where in list(pending.items()):
                with socket.socket() as s:
                    s.settimeout(0.2)
                    if s.connect_ex(where) == 0:
                        del pending[name]
            time.sleep(0.05)

    def _settle(self) -> bool:
        """Wait until every stream of the spec flows and every sync group has a leader."""
        want = {(str(m.name), n) for n, m in self.spec.measures()}
        groups = list(self.spec.sync_groups())
        deadline = time.monotonic() + self.campaign.settle_s
        self.say(f"waiting for {len(want)} streams to flow (at most {self.campaign.settle_s:g} s)")
        missing: set = set(want)
        leaderless: list[str] = list(groups)
        while time.monotonic() < deadline and not self.stopping.is_set():
            if self.launcher is not None and self.launcher.poll() is not None:
                self.settle_error = f"hera up exited with {self.launcher.returncode}"
                break
            counts = dict(self.recorder.counts)
            missing = {k for k in want if counts.get(k, 0) < 2}
            if not missing:
                leaderless = []
                for g in groups:
                    try:
                        self.view.leader(g)
                    except ValueError:
                        leaderless.append(g)
                if not leaderless:
                    self._mark("settled")
                    self.say("settled: every stream flows")
                    return True
            time.sleep(0.25)
        if self.settle_error is None:
            self.settle_error = (
                "the cluster did not settle: "
                + (f"streams without samples: {sorted(missing)}" if missing else "")
                + (f" sync groups without a leader: {leaderless}" if leaderless else "")
            )
        self.say(self.settle_error)
        self._write_meta()
        return False

    def _schedule(self) -> None:
        self._mark("schedule_start")
        t0 = time.monotonic()
        for p in self.plan:
            if not self._wait(t0 + p.at - time.monotonic()):
                break
            self._one(p)
            if self.stopping.is_set():
                break
        self._mark("schedule_end")

    def _one(self, p: Planned) -> None:
        what = " ".join(
            f"{k}={p.settings[k]}"
            for k in ("target", "measure", "board", "fault", "groups")
            if p.settings.get(k) is not None
        )
        act = self.injector.strike(p)
        if act is None:
            err = journal.read(self.folder)[-1].get("error")
            self.say(f"fault {p.index + 1}/{len(self.plan)} {p.name}: FAILED: {err}")
            return
        hit = " | ".join(",".join(g) for g in act.undo.get("groups", ())) or ", ".join(act.nodes)
        self.say(
            f"fault {p.index + 1}/{len(self.plan)} {p.name} ({p.kind} {what}) -> "
            f"{hit or '-'}" + (f" for {p.duration:g} s" if p.duration else "")
        )
        if p.duration or p.kind in NETWORK:
            self.stopping.wait(p.duration)
            self.injector.heal(act)

    def _snapshot(self) -> None:
        if self.client is None:
            return
        self._mark("snapshot")  # the recording is whole up to here
        final: dict[str, Any] = {"args": {}, "status": {}}
        with contextlib.suppress(Exception):
            for node, reply in self.client.query("*", "args", timeout=2.0).items():
                final["args"][node] = reply.get("args", {})
        with contextlib.suppress(Exception):
            final["status"] = self.client.status(timeout=2.0)
        final["launcher"] = self.view.launcher()
        (self.folder / history.FINAL).write_text(json.dumps(final, indent=1, default=str))

    def _stop(self) -> None:
        """Stop everything this run started; record what had to be killed."""
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.recorder.close()
        if self.client is not None:
            with contextlib.suppress(Exception):
                self.client.close()
        if self.launcher is not None:
            if self.launcher.poll() is None:
                self.launcher.terminate()
            try:
                self.launcher.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.say("hera up did not stop in time: killing it")
                self.launcher.kill()
                self.launcher.wait()
        if self.proxy is not None:
            self.proxy.stop()
        self._mark("stopped")
        left: list[dict[str, Any]] = []
        if not self.attach:
            deadline = time.monotonic() + 5.0
            while (left := processes_of(self.folder)) and time.monotonic() < deadline:
                time.sleep(0.1)
            for p in left:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p["pid"], signal.SIGCONT)
                    os.kill(p["pid"], signal.SIGKILL)
            if left:
                self.say(f"{len(left)} processes of the run were still alive: killed them")
        (self.folder / history.LEFTOVERS).write_text(json.dumps(left, indent=1))
        if self.netns is not None:  # its processes are gone: the namespaces can go
            self.netns.close()
