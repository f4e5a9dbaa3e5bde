"""The console's parts one at a time: downsampling, stream statistics, the loopback rule,
web panels, progress, MCAP export of a made-up run, and module reloading."""

from __future__ import annotations

import io
import json
import re
import sys
import time
from types import SimpleNamespace

import jsonschema
import pytest

from hera.application import WebPanel
from hera.console.buffers import Downsampler
from hera.console.server import check_host
from hera.keys import Keys
from hera.progress import Progress
from hera.watch import RateStats, format_sample, stream_selector


def test_a_100_hz_stream_becomes_10_buckets_a_second_with_mean_and_envelope():
    d = Downsampler(bucket_s=0.1, keep_s=2.0)
    for k in range(300):  # 3 s at 100 Hz, a spike at k = 150
        t = 1000.0 + k / 100
        d.add("nav/n1", t, [100.0 if k == 150 else 1.0, float(k)])
    got = [p for _, p in d.since("nav/n1", 0.0)]
    assert len(got) == 20  # only the last 2 s are kept
    index, t, n, means, mins, maxs = got[5]
    assert n == 10 and mins[0] == 1.0 and maxs[0] == 100.0  # the spike survives
    assert means[0] == pytest.approx(10.9) and means[1] == pytest.approx(154.5)
    assert t == pytest.approx(1001.545, abs=1e-6)
    assert [p[0] for _, p in d.since("nav/n1", 1002.85)] == [10028, 10029]
    d.add("nav/n1", 1002.955, [5.0, 0.0])  # late, into its kept bucket
    assert d.since("nav/n1", 1002.9)[0][1][2] == 11
    d.add("nav/n1", 999.0, [5.0, 0.0])  # older than anything kept: dropped
    assert d.since("nav/n1", 0.0)[0][1][0] == 10010


def test_rate_stats_tell_rate_jitter_gaps_and_losses():
    st = RateStats()
    arrival = 0.0
    seq = 0
    for k in range(100):
        seq += 2 if k == 50 else 1  # one sample lost
        arrival += 0.3 if k == 70 else 0.01  # one gap
        st.add(seq, arrival, arrival)
    s = st.summary()
    assert s["count"] == 100 and s["lost"] == 1 and s["gaps"] == 1
    assert s["max_ms"] == pytest.approx(300) and s["min_ms"] == pytest.approx(10)
    assert 1 / s["rate_hz"] == pytest.approx((arrival - 0.01) / 99)
    assert s["jitter_ms"] > 20


def test_stream_arguments():
    keys = Keys("c")
    assert stream_selector(keys, "nav") == "hera/c/data/nav/*"
    assert stream_selector(keys, "nav/n1") == "hera/c/data/nav/n1"
    with pytest.raises(ValueError, match="NAME or NAME/NODE"):
        stream_selector(keys, "a/b/c")
    # shell-like '*' within a name is Zenoh's in-chunk '$*' (a bare '*' inside one is refused
    # by Zenoh: `hera hz 'track_*'` failed with "'*' may only be preceded by '/' or '$'")
    assert stream_selector(keys, "track_*") == "hera/c/data/track_$*/*"
    assert stream_selector(keys, "*_v/comp*") == "hera/c/data/$*_v/comp$*"
    assert stream_selector(keys, "a**b/*") == "hera/c/data/a$*b/*"
    assert stream_selector(keys, "**") == "hera/c/data/*/*"
    for bad in ("nav?", "na$*", "a b", "x#"):
        with pytest.raises(ValueError, match=re.escape(f"invalid stream name {bad!r}")):
            stream_selector(keys, bad)
    with pytest.raises(ValueError, match="invalid node 'n 1'"):
        stream_selector(keys, "nav/n 1")
    line = format_sample({"name": "x", "node": "n", "seq": 3, "t": 0.0, "values": [1.5]}, ["v [m]"])
    assert line.endswith("v [m]=1.5") and "seq=3" in line


def test_the_web_view_serves_loopback_only():
    assert check_host("127.0.0.1") == "127.0.0.1" and check_host("::1") == "::1"
    with pytest.raises(ValueError, match="loopback"):
        check_host("0.0.0.0")
    with pytest.raises(ValueError, match="loopback"):
        check_host("192.168.1.5")


def test_a_web_panel_names_a_kind_the_page_draws():
    WebPanel("t", "plane", {"points": []})
    with pytest.raises(ValueError, match="plane, attitude, grid"):
        WebPanel("t", "sphere", {})


def test_progress_prints_its_end_off_a_terminal_and_nothing_when_silenced(monkeypatch):
    out = io.StringIO()
    with Progress("export", out) as p:
        for i in range(1, 101):
            p(i, 100)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("export:   1% (1/100)")
    assert lines[-1].startswith("export: 100% (100/100) in ")
    monkeypatch.setenv("HERA_PROGRESS", "0")
    quiet = io.StringIO()
    with Progress("export", quiet) as p:
        p(1, 1)
    assert quiet.getvalue() == ""


# -- MCAP ---------------------------------------------------------------------------------
SPEC = """
[cluster]
name = "mini"
[[nodes]]
name = "a"
  [[nodes.measures]]
  use = "counter"
  name = "obs1"
  args = { prefix = "obs" }
"""


def test_an_export_holds_every_sample_in_time_order_and_matches_its_schemas(tmp_path):
    from mcap.reader import make_reader

    from hera.export.mcap import export_run, field_names
    from hera.spec import load_spec

    spec_file = tmp_path / "mini.toml"
    spec_file.write_text(SPEC)
    run = tmp_path / "run"
    (run / "measures").mkdir(parents=True)
    (run / "cluster.json").write_text(load_spec(spec_file).to_json())
    # two streams, interleaved in time, one with a columns sidecar
    (run / "measures" / "obs1_a.csv").write_text("1,1000.5,3\n2,1100.25,4\n3,1200.0,5\n")
    (run / "measures" / "temp_b.csv").write_text("7,1050.0,20.5,1\n8,1150.0,21.5,0\n")
    (run / "measures" / "temp_b.columns.json").write_text(
        json.dumps({"name": "temp", "node": "b", "columns": ["seq", "ts", "T [degC]", "ok"]})
    )
    out = tmp_path / "out.mcap"
    seen = []
    counts = export_run(run, out, progress=lambda done, total: seen.append((done, total)))
    assert counts == {"messages": 5, "channels": 2, "samples": 5, "truth": 0}
    assert seen[-1] == (5, 5)
    with open(out, "rb") as f:
        rows = [
            (channel.topic, json.loads(schema.data), json.loads(msg.data), msg.log_time)
            for schema, channel, msg in make_reader(f).iter_messages()
        ]
    assert [(r[0], r[2]["seq"]) for r in rows] == [
        ("/obs1/a", 1),
        ("/temp/b", 7),
        ("/obs1/a", 2),
        ("/temp/b", 8),
        ("/obs1/a", 3),
    ]
    assert [r[3] for r in rows] == [1000500000, 1050000000, 1100250000, 1150000000, 1200000000]
    for _, schema, record, _ in rows:
        jsonschema.validate(record, schema)
    temp = next(r for r in rows if r[0] == "/temp/b")
    assert temp[2] == {"seq": 7, "t": 1.05, "t_2": 20.5, "ok": 1.0}
    assert temp[1]["properties"]["t_2"]["description"] == "T [degC]"
    # the checker fails on a message its schema does not describe
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**temp[2], "extra": 1}, temp[1])
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**temp[2], "ok": "yes"}, temp[1])
    assert field_names(["omega [rad/s]", "x [m]", "x [cm]", "2nd"]) == ["omega", "x", "x_2", "v2nd"]


def test_an_export_of_a_folder_that_is_no_run_says_so(tmp_path):
    from hera.export.mcap import export_run

    with pytest.raises(ValueError, match="no cluster.json"):
        export_run(tmp_path, tmp_path / "x.mcap")
    with pytest.raises(ValueError) as e:
        export_run(tmp_path / "gone", tmp_path / "x.mcap")
    assert str(e.value) == f"{tmp_path}/gone: no such folder; give a run directory of 'hera up'"
    assert not (tmp_path / "x.mcap").exists()


# -- reloading modules --------------------------------------------------------------------
def test_reload_order_follows_who_refers_to_whom_and_a_failure_restores_everything(
    tmp_path, monkeypatch
):
    from hera import handover, reload

    pkg = tmp_path / "rl_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "core.py").write_text("def value():\n    return 1\n")
    (pkg / "user.py").write_text(
        "from rl_pkg.core import value\n\ndef twice():\n    return 2 * value()\n"
    )
    (tmp_path / "rl_other.py").write_text("from rl_pkg.user import twice\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    reload.freeze_runtime()  # as a node does before loading any measure
    import rl_other  # noqa: F401

    try:
        assert reload.target_modules("rl_pkg.core") == ["rl_pkg.core"]
        assert reload.reload_order(["rl_pkg.core"]) == ["rl_pkg.core", "rl_pkg.user", "rl_other"]
        (pkg / "core.py").write_text("def value():\n    return 5\n")
        old_twice = sys.modules["rl_pkg.user"].twice
        saved = reload.reload_modules(reload.reload_order(["rl_pkg.core"]))
        assert sys.modules["rl_pkg.user"].twice() == 10
        assert sys.modules["rl_pkg"].core is sys.modules["rl_pkg.core"]  # on its package
        assert old_twice() == 2  # code still running from the old module keeps its globals
        reload.restore(saved)
        assert sys.modules["rl_pkg.user"].twice() == 2
        (pkg / "user.py").write_text("raise ImportError('broken on purpose')\n")
        (pkg / "core.py").write_text("def value():\n    return 7\n")
        before = handover.reloads()
        with pytest.raises(reload.ReloadError, match="rl_pkg.user does not load.*broken"):
            reload.reload_modules(reload.reload_order(["rl_pkg.core"]))
        # the modules were out of sys.modules meanwhile: a checkpoint failing then is skipped
        assert handover.reloads() == before + 2
        assert sys.modules["rl_pkg.core"].value() == 1  # restored, not half new
        assert sys.modules["rl_pkg.user"].twice() == 2
        with pytest.raises(ValueError, match="no module called 'rl_nothing'"):
            reload.target_modules("rl_nothing")
        with pytest.raises(ValueError, match="part of the runtime"):
            reload.target_modules("hera.fusion")
    finally:
        for name in ("rl_other", "rl_pkg.user", "rl_pkg.core", "rl_pkg"):
            sys.modules.pop(name, None)


def test_a_fusion_measure_whose_model_refuses_to_start_closes_cleanly(tmp_path):
    # the worker closes a measure whose init failed (to release what it got): CI saw
    # "close() failed: 'Gyro' object has no attribute '_marker_file'" at every retry
    from hera.fusion import FusionMeasure
    from hera.measure import MeasureContext, MeasureSpec
    from hera.store import Store

    class Refusing:
        inputs, columns = ("x",), ("n",)

        def __init__(self):
            raise RuntimeError("no such sensor")

    class Model(FusionMeasure):
        model_class = Refusing

    spec = MeasureSpec(use="x", name="c", period=0.05).resolve(Model)
    ctx = MeasureContext("n1", "c", spec, Store(), None, None, None, run_dir=str(tmp_path))
    m = Model()
    with pytest.raises(RuntimeError, match="no such sensor"):
        m.init({"mode": "arrival"}, ctx)
    m.close()
    assert not (tmp_path / "measures").exists()  # no start marker of a model never started


def test_a_fusion_measure_takes_over_the_old_state_and_fuses_each_sample_once():
    from hera.fusion import FusionMeasure, adopt_model
    from hera.measure import MeasureContext, MeasureSpec
    from hera.store import Store

    class Count:
        inputs = ("x",)
        columns = ("n",)

        def __init__(self):
            self.n, self.t = 0, None

        def process(self, s):
            self.n, self.t = self.n + 1, s.t
            return True

        def estimate(self):
            return (self.t, [float(self.n)])

    class Counting(FusionMeasure):
        model_class = Count

    from hera.wire import Message

    store = Store()
    spec = MeasureSpec(use="x", name="c", period=0.05).resolve(Counting)
    ctx = MeasureContext("n1", "c", spec, store, None, None, None)
    old = Counting()
    old.init({"mode": "period", "max_age": 5.0}, ctx)
    for seq in (1, 2, 3):
        store.offer("x", "a", Message(seq, 100.0 + seq, (1.0,)))
        old.measure()
    assert old.model.n == 3
    new = Counting()
    new.init({"mode": "period", "max_age": 5.0}, ctx)
    new.code_change("", dict(vars(old)))
    assert new.model.n == 3 and new.model is not old.model  # the state, in the new model
    assert new.measure() is None  # sample 3 is in the store, but was fused already
    store.offer("x", "a", Message(4, 104.0, (1.0,)))
    assert [r.values for r in new.measure()] == [[4.0]] and new.model.n == 4

    class Other:
        version = "2"

        def code_change(self, old_version, old_model):
            self.got = (old_version, old_model.n)

    other = Other()
    assert adopt_model(other, old.model) and other.got == ("", 3)
    assert not adopt_model(object.__new__(type("Else", (), {})), old.model)


# -- the view's picture of a cluster -----------------------------------------------------
class FakeSample:
    """What the console's data callback reads of a Zenoh sample."""

    def __init__(self, key: str, payload: bytes) -> None:
        self.key_expr = key
        self.payload = self
        self._bytes = payload

    def to_bytes(self) -> bytes:
        return self._bytes


def test_the_console_joins_model_columns_with_the_truth_and_builds_the_panels():
    from hera.console.state import Console
    from hera.examples import resolve_spec
    from hera.ports import free_ports
    from hera.spec import load_spec
    from hera.wire import encode

    spec = load_spec(resolve_spec("train"))
    spec = spec.with_ports(free_ports("127.0.0.1", len(spec.nodes))).with_world(epoch=1000.0)
    console = Console(spec.with_security(auth=False))  # no cluster here: nothing to join
    try:
        truth = console._truth_of(console.classes["track_gyro"])
        for k in range(50):  # 5 s of a perfect estimate at 10 Hz, then garbage
            t = 1010.05 + k / 10  # mid-bucket
            tr = truth.at(t)
            values = [tr["x [m]"], tr["y [m]"], tr["theta [rad]"], tr["omega [rad/s]"]]
            console._on_sample(
                FakeSample("hera/train/data/track_gyro/computer", encode(k + 1, t, values))
            )
            console._on_sample(
                FakeSample("hera/train/data/nav/nav_1", encode(k + 1, t, [0.4, 0.84]))
            )
        console._on_sample(FakeSample("hera/train/data/nav/nav_1", b"\x00junk"))
        assert console.rejected == 1
        body = console.poll(["track_gyro/computer", "nav/nav_1"], 0.0)
        streams = {s["stream"]: s for s in body["streams"]}
        gyro, nav = streams["track_gyro/computer"], streams["nav/nav_1"]
        assert gyro["model"] and gyro["label"] == "track_gyro (e7)"
        assert gyro["truth"] == ["x [m]", "y [m]", "theta [rad]", "omega [rad/s]"]
        assert not nav["model"] and nav["truth"] == [] and nav["columns"][0].startswith("a_")
        points = body["data"]["track_gyro/computer"]["points"]
        assert len(points) == 50
        for _, _, n, means, _, _, true in points:
            assert n == 1 and means == pytest.approx(true, abs=1e-5)
        assert len(body["data"]["nav/nav_1"]["points"][0]) == 6  # no truth for a sensor
        (panel,) = body["panels"]
        assert panel["kind"] == "plane"
        labels = {p["label"] for p in panel["data"]["points"]}
        assert labels == {"track_gyro (e7) computer", "truth"}
        assert panel["data"]["shapes"][0]["circle"][2] == pytest.approx(0.6)
        assert {n["name"]: n["state"] for n in body["cluster"]["nodes"]} == {
            "nav_1": "down",
            "sonar_1": "down",
            "sonar_2": "down",
            "computer": "down",
        }
        since = points[-2][1]
        again = console.poll(["track_gyro/computer"], since)
        assert [p[0] for p in again["data"]["track_gyro/computer"]["points"]] == [
            points[-2][0],
            points[-1][0],
        ]
    finally:
        console.close()


def test_a_quaternion_truth_is_shown_on_the_estimates_side():
    """q and -q are one attitude: the view differenced them column by column and showed an
    attitude that was right as 'qw -0.75 truth 0.75 err -1.50' (the audit of 2026-12-07)."""
    from hera.console.state import Console
    from hera.examples import resolve_spec
    from hera.ports import free_ports
    from hera.spec import load_spec
    from hera.wire import encode

    spec = load_spec(resolve_spec("ahrs"))
    spec = spec.with_ports(free_ports("127.0.0.1", len(spec.nodes))).with_world(epoch=1000.0)
    console = Console(spec.with_security(auth=False))  # no cluster here: nothing to join
    try:
        truth = console._truth_of(console.classes["attitude_mekf"])
        for k in range(20):  # 2 s at 10 Hz: the true attitude, then its negative
            t = 1010.05 + k / 10
            q = [truth.at(t)[c] for c in ("qw", "qx", "qy", "qz")]
            sign = 1.0 if k < 10 else -1.0
            values = [sign * v for v in q] + [0.0] * 11
            key = "hera/ahrs/data/attitude_mekf/computer"
            console._on_sample(FakeSample(key, encode(k + 1, t, values)))
        points = console.poll(["attitude_mekf/computer"], 0.0)["data"]["attitude_mekf/computer"]
        assert len(points["points"]) == 20
        for _, _, _, means, _, _, true in points["points"]:
            assert true[:4] == pytest.approx(means[:4], abs=1e-5)  # no error either way
        assert points["points"][-1][6][0] * points["points"][0][6][0] < 0  # turned over
    finally:
        console.close()


def test_a_model_started_at_run_time_is_shown_as_the_specs_are():
    """``hera start NODE --use omega_acc --name e4_rt``: the view knew only the spec's
    measures, so e4_rt was no model, had no label, truth or panel (the audit)."""
    from hera.console.state import Console
    from hera.examples import resolve_spec
    from hera.plugins import find_measure
    from hera.ports import free_ports
    from hera.spec import load_spec

    spec = load_spec(resolve_spec("train"))
    spec = spec.with_ports(free_ports("127.0.0.1", len(spec.nodes))).with_world(epoch=1000.0)
    console = Console(spec.with_security(auth=False))  # no cluster here: nothing to join
    try:
        assert "e4_rt" not in console.classes
        nav = console.classes["nav"]
        console.learn_classes(
            {
                "computer": {
                    "measures": {
                        "e4_rt": {"use": "omega_acc", "state": "running"},
                        "lost": {"use": "no_such_measure"},
                        "old": {"state": "running"},  # a node of before: no "use"
                    }
                },
                "nav_1": {"measures": {"nav": {"use": "omega_acc"}}},  # the spec's stands
            }
        )
        # a stream's rate is over the 2 s up to now: one that stopped shows 0, not its last
        now = time.time()
        for k in range(40):  # 4 s at 10 Hz: one stream up to now, one that stopped 5 s ago
            console.buffers.add("nav/nav_1", now - 4.0 + k / 10, [0.0, 0.0])
            console.buffers.add("mag/nav_1", now - 9.0 + k / 10, [0.0])
        rates = console._rates()
        assert rates["nav/nav_1"] == pytest.approx(10.0, abs=1.0) and rates["mag/nav_1"] == 0.0
        assert console.classes["e4_rt"] is find_measure("omega_acc")
        # nodes up before the view started are not "joined" at its start; later ones are
        import zenoh

        def alive(node: str) -> SimpleNamespace:
            return SimpleNamespace(key_expr=f"hera/train/alive/{node}", kind=zenoh.SampleKind.PUT)

        console._joined_before = True  # the liveliness history, before the first status
        console._on_alive(alive("nav_1"))
        deadline = time.monotonic() + 5.0
        while console._joined_before and time.monotonic() < deadline:
            time.sleep(0.01)  # the view's first status (no cluster here: nobody answers)
        console._on_alive(alive("sonar_1"))
        assert [(e["node"], e["text"]) for e in console.events] == [("sonar_1", "joined the bus")]
        assert set(console.peers.up) == {"nav_1", "sonar_1"}
        assert "lost" not in console.classes and "old" not in console.classes
        assert console.classes["nav"] is nav
        assert console.index.label("e4_rt", console.classes["e4_rt"]) == "e4_rt (e4)"
        assert console._truth_of(console.classes["e4_rt"]) is not None
    finally:
        console.close()


def test_the_lazily_loaded_runtime_packages_are_never_reloaded(tmp_path, monkeypatch):
    """A node loads the estimation package and numpy only for a filter: they belong to the
    runtime all the same, loaded or not; a package of the user's does not."""
    from hera import reload

    (tmp_path / "rl_user.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    reload.freeze_runtime()
    for name in ("hera.estimation", "hera.estimation.ekf", "hera.fusion", "numpy.linalg"):
        assert reload.is_runtime(name), name
    with pytest.raises(ValueError, match="part of the runtime"):
        reload.target_modules("hera.estimation.ekf")
    import rl_user  # noqa: F401

    try:
        assert not reload.is_runtime("rl_user")
        assert reload.target_modules("rl_user") == ["rl_user"]
    finally:
        sys.modules.pop("rl_user", None)


def test_hera_view_follows_a_cluster_started_again_in_its_run_directory(tmp_path):
    """``hera view`` joined the endpoints of the cluster.json it found at its start, so a
    cluster started again there (new ports) left it showing 0/4 nodes for good."""
    import threading
    import urllib.request

    from hera.console.server import serve
    from hera.examples import resolve_spec
    from hera.ports import free_ports
    from hera.spec import load_spec

    def write_run(name: str) -> None:
        spec = load_spec(resolve_spec("train")).with_security(auth=False)
        spec = spec.with_ports(free_ports("127.0.0.1", len(spec.nodes)))
        text = spec.to_json().replace('"name": "train"', f'"name": "{name}"', 1)
        (tmp_path / "cluster.json").write_text(text)

    write_run("first")
    port = free_ports("127.0.0.1", 1)[0]
    view = threading.Thread(target=serve, args=(tmp_path, "127.0.0.1", port, 8.0))
    view.start()
    try:

        def shown() -> str | None:
            try:
                url = f"http://127.0.0.1:{port}/api/poll"
                with urllib.request.urlopen(url, timeout=1) as r:
                    return json.loads(r.read())["cluster"]["name"]
            except OSError:
                return None

        deadline = time.monotonic() + 5
        while shown() != "first" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert shown() == "first"
        write_run("second")  # hera up again in the same folder: a new cluster.json
        deadline = time.monotonic() + 5
        while shown() != "second" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert shown() == "second"
    finally:
        view.join(15)
    assert not view.is_alive()
