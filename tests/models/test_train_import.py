"""`hera import erlang-hera`: logs in the original Erlang Hera layout and conventions,
converted into a run that `hera replay` and `hera eval` take as it is (issue 20).

The synthetic log is written the way the original logged its rig: one CSV per measure,
rows seq,timestamp_ms,values from a negative origin, the train running clockwise about
the board's z (nav [a_y, g_z] with g_z in deg/s as older logs have it, mag a clockwise
heading), sonar [range, x, y], the models' outputs e4 .. e9 and a 3-D model's e13. Its
content comes from a simulated run, so the import is checked against what was written."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from harness import cluster_env

from hera.nodes.offline import simulate
from hera.recordings import read_recordings
from hera.replay import model_args_from_spec, replay
from hera.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]
ORIGIN = 1000.0  # s: the log's timestamps are ms since an origin after the samples


def _write(path: Path, rows) -> None:
    path.write_text(
        "".join(
            f"{q},{(t - ORIGIN) * 1000:.3f},{','.join(repr(v) for v in vals)}\n"
            for q, t, vals in rows
        )
    )


@pytest.fixture(scope="module")
def erlang_logs(tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("erlang")
    spec = load_spec(ROOT / "deploy" / "train.toml")
    sim = simulate(spec, tmp / "sim", 40.0, world={"seed": 4, "epoch": 0.0}, seed=4)
    replay(sim, tmp / "rep", model_args_from_spec(spec))
    src = tmp / "logs"
    src.mkdir()
    rec = read_recordings(sim, known=["nav", "mag", "sonar"])
    nav = [(s.seq, s.t, (-s.values[0], -math.degrees(s.values[1]))) for s in rec if s.name == "nav"]
    _write(src / "nav.csv", nav)
    _write(src / "mag.csv", [(s.seq, s.t, (-s.values[0],)) for s in rec if s.name == "mag"])
    for i in (1, 2):
        rows = [(s.seq, s.t, s.values) for s in rec if s.node == f"sonar_{i}"]
        _write(src / f"sonar{i}.csv", rows)
    models = ["omega_acc", "track_bilat", "track_sonar", "track_gyro", "track_radius", "track_mag"]
    out = read_recordings(tmp / "rep", models, known=models)
    for e, name in zip(("e4", "e5", "e6", "e7", "e8", "e9"), models, strict=True):
        _write(src / f"{e}.csv", [(s.seq, s.t, s.values) for s in out if s.name == name])
    _write(src / "e13.csv", [(1, 1.0, (0.0,) * 9)])
    return src, sim


def hera(*args: str, tmp: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hera", *args],
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_import_converts_the_original_conventions(erlang_logs, tmp_path):
    src, sim = erlang_logs
    out = tmp_path / "run"
    proc = hera("import", "erlang-hera", str(src), str(out), tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "g_z in deg/s: converted" in proc.stdout and "e13.csv" in proc.stdout
    ours = {
        (s.name, s.node, s.seq): s
        for s in read_recordings(sim, ["nav", "mag", "sonar"], known=["nav", "mag", "sonar"])
    }
    got = read_recordings(out, ["nav", "mag", "sonar"], known=["nav", "mag", "sonar"])
    assert len(got) == len(ours)
    for s in got:
        o = ours[(s.name, s.node, s.seq)]
        assert s.t == pytest.approx(o.t - ORIGIN, abs=1e-6)  # the log's own origin, kept
        if s.name == "mag":  # a clockwise heading negated back, wrapped
            assert math.cos(s.values[0] - o.values[0]) == pytest.approx(1.0, abs=1e-9)
        else:  # nav: a_c = -a_y, omega = -g_z in rad/s; sonar as it was
            assert s.values == pytest.approx(o.values, rel=1e-9, abs=1e-12)
    spec = json.loads((out / "cluster.json").read_text())["resolved_spec"]
    assert spec["world"] == {}  # no simulated world: no truth to score against
    beams = spec["nodes"][0]["measures"][3]["args"]["model"]["beams"]
    assert beams["sonar_1"] == pytest.approx([0.3, 1.5])  # towards the track's centre


def test_g_z_already_in_rad_s_is_left_as_it_is(erlang_logs, tmp_path):
    """Newer logs give g_z in rad/s: not converted (the deg/s detection must not fire)."""
    src, sim = erlang_logs
    newer = tmp_path / "newer"
    newer.mkdir()
    for p in src.glob("*.csv"):
        (newer / p.name).write_text(p.read_text())
    rows = [line.split(",") for line in (src / "nav.csv").read_text().splitlines()]
    (newer / "nav.csv").write_text(
        "".join(f"{q},{t},{a},{math.radians(float(g))!r}\n" for q, t, a, g in rows)
    )
    out = tmp_path / "run"
    proc = hera("import", "erlang-hera", str(newer), str(out), tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "deg/s" not in proc.stdout
    ours = {s.seq: s for s in read_recordings(sim, ["nav"], known=["nav", "mag", "sonar"])}
    got = read_recordings(out, ["nav"], known=["nav", "mag", "sonar"])
    assert len(got) == len(ours)
    for s in got:  # omega = -g_z, in rad/s as logged
        assert s.values == pytest.approx(ours[s.seq].values, rel=1e-9, abs=1e-12)


def test_replay_and_eval_of_an_import_score_by_lap_timing_beside_the_original(
    erlang_logs, tmp_path
):
    src, _ = erlang_logs
    run = tmp_path / "run"
    assert hera("import", "erlang-hera", str(src), str(run), tmp=tmp_path).returncode == 0
    proc = hera("replay", str(run), "--out", str(run), tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = hera("eval", str(run), "--json", "--no-plots", tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    rows = {(r["model"], r["node"]): r for r in json.loads(proc.stdout)}
    for node in ("replay", "erlang"):  # ours beside the original's, both scored
        r = rows[("track_gyro", node)]
        assert r["scored_against"].startswith("self-consistency")
        assert "lap timing" in r["scored_against"]
        assert r["omega_settled_rms_pct"] < 0.5, r
        assert r.get("pos_rmse_cm") is None  # lap timing tells omega only
    plots = tmp_path / "plots"
    proc = hera("eval", str(run), "--node", "replay,erlang", "--plots", str(plots), tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "train: scored against self-consistency" in proc.stdout
    assert (plots / "omega.png").stat().st_size > 10_000


def test_bad_logs_are_refused_with_the_file_and_line(erlang_logs, tmp_path):
    src, _ = erlang_logs
    bad = tmp_path / "bad"
    bad.mkdir()
    for p in src.glob("*.csv"):
        (bad / p.name).write_text(p.read_text())
    lines = (bad / "nav.csv").read_text().splitlines()
    lines[2] = "3,12.5,oops,1.0"
    (bad / "nav.csv").write_text("\n".join(lines) + "\n")
    proc = hera("import", "erlang-hera", str(bad), str(tmp_path / "out"), tmp=tmp_path)
    assert proc.returncode == 2 and "nav.csv:3" in proc.stderr, proc.stderr
    proc = hera("import", "no-such-format", str(src), str(tmp_path / "o2"), tmp=tmp_path)
    assert proc.returncode == 2 and "formats: erlang-hera (train)" in proc.stderr
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    proc = hera("import", "erlang-hera", str(src), str(tmp_path / "full"), tmp=tmp_path)
    assert proc.returncode == 2 and "not empty" in proc.stderr
    proc = hera("import", "erlang-hera", str(tmp_path / "full"), str(tmp_path / "o3"), tmp=tmp_path)
    assert proc.returncode == 2 and "not Erlang Hera train logs" in proc.stderr
