"""``hera import erlang-hera SRC OUT``: the logs of the original Erlang Hera train (2021).

That application logged one CSV per measure in ``SRC``: ``nav.csv``, ``mag.csv``,
``sonar1.csv``, ``sonar2.csv`` (``sonar<N>.csv``) and its models' outputs ``e4.csv`` ...
``e13.csv``; rows ``seq,timestamp_ms,values`` (no header), timestamps in ms from an
arbitrary, often negative, origin (kept as they are: the models use only differences).
Its conventions, and what the import makes of them (ours: z up, counter-clockwise
positive, :class:`~hera.models.train.tracker.TrainTracker`):

- ``nav``: [a_y m/s^2, g_z] in the board frame, the train running clockwise about board
  z: written as ``nav`` [a_c, omega] = [-a_y, -g_z]; older logs give g_z in deg/s (values
  around 50 instead of 0.9): detected (a median |g_z| over 10, impossible in rad/s for a toy
  train) and converted;
- ``mag``: [theta_z], a clockwise heading: negated (wrapped to [-pi, pi));
- ``sonar<N>``: [range m, x, y] with the sonar's position: as it is, from node ``sonar_<N>``;
- ``e4`` .. ``e9``: the original models' outputs, in the same frame as the sonars': as the
  outputs of our ladder (``omega_acc`` .. ``track_mag``) from node ``erlang``, beside which
  ``hera replay OUT --out OUT`` writes ours (node ``replay``); ``e10`` .. ``e13`` (the 3-D
  models of thesis ch. 7) are not the train's and are left out.

``OUT/cluster.json`` is a spec of the ladder with the 2021 rig's settings (beams from each
sonar towards the track's centre, 30 deg: readings came from that far off the axis; the
rails' mid radius; a gyroscope scale and an accelerometer gain known to a few per cent); its
world has no scenario, so ``hera eval`` scores against lap timing (:mod:`.laps`).
"""

from __future__ import annotations

import csv
import math
import re
import statistics
from pathlib import Path
from typing import Any

from hera.csvlog import CsvLog
from hera.spec import parse_spec
from hera.store import Sample

E_MODELS = {
    "e4": ("omega_acc", 1),
    "e5": ("track_bilat", 4),
    "e6": ("track_sonar", 4),
    "e7": ("track_gyro", 4),
    "e8": ("track_radius", 5),
    "e9": ("track_mag", 5),
}
"""Original output -> (our model, values per row)."""

COLUMNS = {
    "nav": ("a_y [m/s^2]", "g_z [rad/s]"),
    "mag": ("heading [rad]",),
    "sonar": ("range [m]", "x [m]", "y [m]"),
}
OUT_COLUMNS = {
    1: ("omega [rad/s]",),
    4: ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]"),
    5: ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]", "radius [m]"),
}
DEG_PER_S_ABOVE = 10.0
"""A median |g_z| above this (rad/s) can only be deg/s."""


def read_rows(path: Path, width: int) -> list[tuple[int, float, tuple[float, ...]]]:
    """(seq, t s, the first ``width`` values) of every row of an original log;
    ValueError naming the file, the line and what is wrong."""
    out = []
    with open(path, newline="") as f:
        try:
            rows = list(csv.reader(f))
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a text CSV (a log is seq,timestamp_ms,values)") from None
        for i, row in enumerate(rows, start=1):
            if not row or not "".join(row).strip():
                continue
            try:
                seq, ms = int(row[0]), float(row[1])
                values = tuple(float(v) for v in row[2 : 2 + width])
            except (ValueError, IndexError):
                raise ValueError(
                    f"{path}:{i}: expected seq,timestamp_ms,values: {','.join(row)[:80]!r}"
                ) from None
            if len(values) < width:
                raise ValueError(f"{path}:{i}: expected {width} values, got {len(values)}")
            if not all(math.isfinite(v) for v in (ms, *values)):
                raise ValueError(f"{path}:{i}: a value is not a finite number")
            out.append((seq, ms / 1000.0, values))
    return out


def rig_spec(sonars: dict[str, tuple[float, float]]) -> dict[str, Any]:
    """The spec (as parsed TOML) of the ladder on the 2021 rig, for sonar nodes at the
    given positions (beams: each towards the track's centre, the origin)."""
    beams = {n: [-x, -y] for n, (x, y) in sonars.items() if math.hypot(x, y) > 0}
    shape = {"target_length": 0.5, "target_radius": 0.05, "beams": beams, "half_angle_deg": 30.0}
    rig = {"acc_gain_var0": 0.04}
    gyro = {"gyro_scale_var0": 2.25e-4}

    def model(use: str, settings: dict[str, Any]) -> dict[str, Any]:
        return {"on": ["computer"], "use": use, "args": {"mode": "arrival", "model": settings}}

    fixed, free = {"radius": 0.5925}, {"radius": 0.57, "radius_var0": 0.0025}
    return {
        "cluster": {"name": "erlang_hera"},
        "world": {},
        "nodes": [{"name": "computer"}],
        "measures": [
            model("omega_acc", {**fixed, **rig}),
            model("bilateration", {"target_radius": 0.05, "beams": beams, "half_angle_deg": 30.0}),
            model("track_bilat", {**fixed, **rig}),
            model("track_sonar", {**fixed, **rig, **shape}),
            model("track_gyro", {**fixed, **rig, **gyro, **shape}),
            model("track_radius", {**free, **rig, **gyro, **shape}),
            model("track_mag", {**free, **rig, **gyro, **shape}),
        ],
    }


def import_erlang(src: Path, out: Path) -> str:
    """Convert the logs in ``src`` into the run directory ``out`` (module docstring);
    return one line saying what was imported."""
    src, out = Path(src), Path(out)
    nav_path = src / "nav.csv"
    sonar_paths = sorted(p for p in src.glob("sonar*.csv") if re.fullmatch(r"sonar\d*", p.stem))
    if not nav_path.exists() or not sonar_paths:
        raise ValueError(f"{src}: not Erlang Hera train logs (expected nav.csv and sonar<N>.csv)")
    out.mkdir(parents=True, exist_ok=True)
    log = CsvLog(out, {**COLUMNS, **{m: OUT_COLUMNS[w] for m, w in E_MODELS.values()}})
    notes = []
    try:
        nav = read_rows(nav_path, 2)
        deg = bool(nav) and statistics.median(abs(v[1]) for _, _, v in nav) > DEG_PER_S_ABOVE
        k = math.pi / 180.0 if deg else 1.0
        for seq, t, (a_y, g_z) in nav:
            log.write(Sample("nav", "nav_1", seq, t, 0.0, 0.0, (-a_y, -g_z * k)))
        notes.append(f"nav {len(nav)}" + (" (g_z in deg/s: converted)" if deg else ""))
        mag_path = src / "mag.csv"
        if mag_path.exists():
            mag = read_rows(mag_path, 1)
            for seq, t, (theta_z,) in mag:
                h = (-theta_z + math.pi) % (2 * math.pi) - math.pi
                log.write(Sample("mag", "nav_1", seq, t, 0.0, 0.0, (h,)))
            notes.append(f"mag {len(mag)}")
        sonars: dict[str, tuple[float, float]] = {}
        for p in sonar_paths:
            node = "sonar_" + (p.stem[5:] or "1")
            rows = read_rows(p, 3)
            for seq, t, v in rows:
                log.write(Sample("sonar", node, seq, t, 0.0, 0.0, v))
            if rows:
                sonars[node] = (
                    statistics.median(v[1] for _, _, v in rows),
                    statistics.median(v[2] for _, _, v in rows),
                )
            notes.append(f"{node} {len(rows)}")
        if not nav and not sonars:
            raise ValueError(f"{src}: nav.csv and the sonar logs hold no rows")
        originals = []
        for e, (name, width) in E_MODELS.items():
            p = src / f"{e}.csv"
            if p.exists():
                for seq, t, v in read_rows(p, width):
                    log.write(Sample(name, "erlang", seq, t, 0.0, 0.0, v))
                originals.append(f"{e} as {name}_erlang")
        skipped = sorted(
            p.name for p in src.glob("e*.csv") if p.stem not in E_MODELS and p.stem[1:].isdigit()
        )
    finally:
        log.close()
    spec = parse_spec(rig_spec(sonars), f"{src} (erlang-hera import)")
    (out / "cluster.json").write_text(spec.to_json())
    return (
        f"imported {', '.join(notes)}; original outputs: {', '.join(originals) or 'none'}"
        + (f"; left out (not the train's): {', '.join(skipped)}" if skipped else "")
        + f" -> {out} (next: hera replay {out} --out {out}; hera eval {out} --node replay,erlang)"
    )
