"""Benchmark of the sync service (``hera bench sync``): throughput, latency, failover.

Three node processes on loopback host the service for one group (``hera.sync.harness``).

1. One measure alone: grant latency (ask to grant, slot free) p50 and p99.
2. One measure per node, each firing as often as it may: slots per second and the
   hand-over gap between consecutive slots.
3. The leader is SIGKILLed: gap in the slot flow (kill to the next firing); it is
   restarted (a majority must survive the next fault).
4. The new leader is SIGSTOPped: gap in the slot flow; then it is resumed (a zombie).

Every firing interval of the run is checked for overlap. Runs in about 25 s.
"""

from __future__ import annotations

import argparse
import time

from hera import cliargs
from hera.sync.harness import CLOCK, Cluster, check_firings

ORIGINAL_FAILOVER_S = 10.0  # the thesis (ch. 5.3): synchronised measures stop up to ~10 s
HANG_DETECTION_FACTOR = 0.85  # a hung peer is declared gone after ~0.85 x the link lease


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def _gap_after(c: Cluster, t_fault: float, epoch: int, n: int = 20) -> float:
    c.wait_for(f"{n} slots after the fault", lambda: c.count(lambda f: f.epoch > epoch) >= n, 30)
    return min(f.start for f in c.firings() if f.epoch > epoch) - t_fault


def run(slot_ms: float, lease_ms: int, bus_lease_ms: int, steady_s: float) -> dict:
    """Run the scenario; return the figures (seconds, counts)."""
    hosts = ["s1", "s2", "s3"]
    out: dict = {}
    with Cluster(
        hosts, slot_ms=slot_ms, lease_ms=lease_ms, bus_lease_ms=bus_lease_ms,
        measures={"s2": [("m", slot_ms)]},
    ) as c:  # fmt: skip
        c.wait_for("300 uncontended slots", lambda: c.count() >= 300, 30)
        lat = [g - a for a, g, _ in c.logs().acquires]
        out["latency_p50"], out["latency_p99"] = _pct(lat, 0.5), _pct(lat, 0.99)
        c.send("s1", f"add m {slot_ms}")
        c.send("s3", f"add m {slot_ms}")
        c.wait_for("all three firing", lambda: {f.holder for f in c.firings()} >= {
            "s1/m", "s2/m", "s3/m"})  # fmt: skip
        t0 = CLOCK()
        n0 = c.count()
        time.sleep(steady_s)
        t1 = CLOCK()
        fs = [f for f in c.firings() if t0 <= f.start <= t1]
        out["slots_per_s"] = (c.count() - n0) / (t1 - t0)
        gaps = [b.start - a.end for a, b in zip(fs, fs[1:], strict=False)]
        out["handover_p50"], out["handover_p99"] = _pct(gaps, 0.5), _pct(gaps, 0.99)

        leader, epoch = c.wait_for("a leader", c.leader)
        t_kill = CLOCK()
        c.kill(leader)
        out["gap_kill"] = _gap_after(c, t_kill, epoch)

        # restart the killed node, so that a majority survives the next fault
        c.start(leader)
        c.wait_for(
            "the restarted node to follow the leader",
            lambda: (g := c.group_status(leader)) is not None and g["leader"] is not None,
        )
        leader, epoch = c.wait_for("a new leader", c.leader)
        t_stop = CLOCK()
        c.stop(leader)
        out["gap_stop"] = _gap_after(c, t_stop, epoch)
        c.cont(leader)
        n = c.count()
        c.wait_for("slots after the zombie's return", lambda: c.count() >= n + 100, 30)

        check = check_firings(c.firings())
        out["firings"] = check.firings
        out["overlaps"] = len(check.overlaps)
        out["stale_fired"] = len(check.out_of_order)
        out["late_given_back"] = len(c.logs().late)
    out["max_slot"] = lease_ms / 2000.0
    out["hang_detection"] = HANG_DETECTION_FACTOR * bus_lease_ms / 1000.0
    return out


def _table(r: dict, slot_ms: float) -> str:
    ms = 1e3
    kill_target = 0.5 + r["max_slot"]
    stop_target = r["hang_detection"] + 1.0
    rows = [
        ("figure", "measured", "target", "original Hera"),
        ("slot length", f"{slot_ms:.1f} ms", "", ""),
        ("slots per second (3 measures)", f"{r['slots_per_s']:.0f}", "", ""),
        ("grant latency p50 (free slot)", f"{r['latency_p50'] * ms:.2f} ms", "", ""),
        ("grant latency p99 (free slot)", f"{r['latency_p99'] * ms:.2f} ms", "", ""),
        ("hand-over gap p50", f"{r['handover_p50'] * ms:.2f} ms", "", ""),
        ("hand-over gap p99", f"{r['handover_p99'] * ms:.2f} ms", "", ""),
        (
            "slot flow gap, leader SIGKILLed",
            f"{r['gap_kill']:.3f} s",
            f"<= {kill_target:.2f} s",
            f"up to {ORIGINAL_FAILOVER_S:.0f} s",
        ),
        (
            "slot flow gap, leader SIGSTOPped",
            f"{r['gap_stop']:.3f} s",
            f"<= {stop_target:.2f} s",
            f"up to {ORIGINAL_FAILOVER_S:.0f} s",
        ),
        ("firings checked", f"{r['firings']}", "", ""),
        ("overlapping firings", f"{r['overlaps']}", "0", "no mutual exclusion"),
        ("stale grants fired", f"{r['stale_fired']}", "0", ""),
        ("late grants given back", f"{r['late_given_back']}", "", ""),
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    verdict = (
        r["overlaps"] == 0
        and r["stale_fired"] == 0
        and r["gap_kill"] <= kill_target
        and r["gap_stop"] <= stop_target
    )
    lines.append(f"\ntargets {'met' if verdict else 'NOT met'}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """``hera bench sync``: print the table; exit status 1 if a target is missed."""
    p = argparse.ArgumentParser(prog="hera bench sync", description=__doc__.splitlines()[0])
    p.add_argument("--slot-ms", type=cliargs.positive, default=5.0, help="slot of each measure (5)")
    p.add_argument("--lease-ms", type=cliargs.count, default=300, help="leader lease L (300)")
    p.add_argument(
        "--bus-lease-ms", type=cliargs.count, default=2000, help="Zenoh link lease (2000)"
    )
    p.add_argument("--steady-s", type=cliargs.positive, default=5.0, help="steady-state phase (5)")
    a = p.parse_args(argv)
    r = run(a.slot_ms, a.lease_ms, a.bus_lease_ms, a.steady_s)
    print(_table(r, a.slot_ms))
    ok = (
        r["overlaps"] == 0
        and r["stale_fired"] == 0
        and r["gap_kill"] <= 0.5 + r["max_slot"]
        and r["gap_stop"] <= r["hang_detection"] + 1.0
    )
    return 0 if ok else 1


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
