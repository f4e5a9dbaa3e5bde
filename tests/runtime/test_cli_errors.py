"""Bad specs, arguments and command lines: one clear sentence per problem naming the file,
the table and the key, exit code 2, no traceback, and nothing started."""

from __future__ import annotations

from pathlib import Path

import pytest
from harness import run_hera

ROOT = Path(__file__).resolve().parents[2]
HEAD = '[cluster]\nname = "e"\n[[nodes]]\nname = "a"\n'
TRAIN_MODEL = '[[nodes.measures]]\nuse = "track_radius"\nargs = { model = { %s } }\n'


def hera(tmp_path: Path, *args: str, env: dict[str, str] | None = None):
    return run_hera(tmp_path, *args, cwd=ROOT, env=env)


CASES = [
    (
        HEAD + '[[nodes.measures]]\nuse = "no_such_measure"\n',
        ["measure 'no_such_measure' of node 'a': unknown measure 'no_such_measure'; known "],
    ),
    (
        HEAD + TRAIN_MODEL % "radius_m = 0.6",
        [
            "measure 'track_radius' of node 'a': args: model: unknown setting 'radius_m' (did "
            "you mean 'radius'?); known settings: radius, center,"
        ],
    ),
    (
        HEAD + '[[nodes.measures]]\nuse = "counter"\nargs = { prefxi = "obs" }\n',
        [
            "measure 'counter' of node 'a': args: unknown key 'prefxi' (did you mean "
            "'prefix'?); known keys: prefix, fresh_cycles, min_age_cycles"
        ],
    ),
    (
        HEAD + '[[nodes.measures]]\nuse = "sonar"\n',
        [
            "measure 'sonar' of node 'a': it is synchronised (sync = true) in group 'sonar', "
            "but no node hosts that group: add 'sonar' to some node's sync_hosts"
        ],
    ),
    (
        '[cluster]\nname = "e"\nbase_prot = 7000\n[[nodes]]\nnmae = "a"\n',
        [
            "[cluster]: unknown key 'base_prot' (did you mean 'base_port'?); known keys: name, "
            "host, base_port, lease_ms, sync_lease_ms, multicast_scouting, estimation_backend",
            "[[nodes]] #1: unknown key 'nmae' (did you mean 'name'?); known keys: name, port, "
            "sync_hosts, measures, host, mode, listen, connect, store",
            "[[nodes]] #1: name is required (node name, the `<node>` of its keys)",
        ],
    ),
    (
        "",
        [
            "[cluster]: name is required (cluster name: the key prefix `hera/<name>/`)",
            "[[nodes]]: a spec needs at least one [[nodes]] entry",
        ],
    ),
    (
        HEAD
        + '[[nodes.measures]]\nuse = "track_radius"\nargs = { publish = "every" }\n'
        + '[[nodes.measures]]\nuse = "track_gyro"\nargs = { mode = "arrival", max_age = 1 }\n',
        [
            "measure 'track_radius' of node 'a': args: publish is for arrival mode and does "
            'nothing in period mode (set mode = "arrival" or leave publish out)',
            "measure 'track_gyro' of node 'a': args: max_age is for period mode and does "
            'nothing in arrival mode (set mode = "period" or leave max_age out)',
        ],
    ),
    (
        HEAD
        + '[[nodes.measures]]\nuse = "counter"\noffset = 0.5\n'
        + '[[nodes.measures]]\nuse = "sonar"\noffset = 0.01\n',
        [
            "measure 'counter' of node 'a': offset must be below the period (0.1 s), got 0.5",
            "measure 'sonar' of node 'a': offset is for unsynchronised measures (sync = true)",
        ],
    ),
    (
        HEAD
        + '[[nodes.measures]]\nuse = "lsm6dsl"\nperiod = 0.0384615\nargs = { driver = '
        + '"hera.nodes.lsm6dsl.i2c:I2cLsm6dsl", driver_args = { buss = 1, axes = "y,x,z" } }\n'
        + '[[nodes.measures]]\nuse = "lsm6dsl"\nname = "imu2"\nperiod = 0.0384615\nargs = '
        + '{ board = "imu2", driver = "hera.nodes.lsm6dsl.i2c:I2cLsm6dsl", driver_args = '
        + '{ address = 0x6c, axes = "y,x,z" } }\n'
        + '[[nodes.measures]]\nuse = "sonar"\nsync = false\nargs = { driver = '
        + '"hera.nodes.serial_sonar:SerialMaxSonar" }\n'
        + '[[nodes.measures]]\nuse = "nav"\nargs = { driver = "mydrivers.NavBoard" }\n'
        + '[[nodes.measures]]\nuse = "nav3"\nargs = { board = "nav2", driver = '
        + '"hera.nodes.nav_spi:SpiPmodNav", driver_args = { ag = "spidev0.0", odr_hz = 100 } }\n',
        [
            "measure 'lsm6dsl' of node 'a': args: driver_args: unknown key 'buss' (did you "
            "mean 'bus'?); hera.nodes.lsm6dsl.i2c:I2cLsm6dsl takes bus, address, odr_hz, "
            "acc_range_g, gyro_range_dps, axes, timeout_ms",
            "measure 'lsm6dsl' of node 'a': args: driver_args: axes 'y,x,z' is a mirror image "
            "of the chip's frame (no chip can be mounted so): turn the sign of one more axis",
            "measure 'imu2' of node 'a': args: driver_args: address must be 0x6a or 0x6b (the "
            "chip's two), got 108",
            "measure 'imu2' of node 'a': args: driver_args: axes 'y,x,z' is a mirror image of "
            "the chip's frame (no chip can be mounted so): turn the sign of one more axis",
            "measure 'sonar' of node 'a': args: driver_args: port is required by "
            "hera.nodes.serial_sonar:SerialMaxSonar",
            "measure 'nav' of node 'a': args: driver must be 'package.module:Class', got "
            "'mydrivers.NavBoard'",
            "measure 'nav3' of node 'a': args: driver_args: ag must be a device path, got "
            "'spidev0.0'",
            "measure 'nav3' of node 'a': args: driver_args: odr_hz must be one of (14.9, 59.5, "
            "119.0, 238.0, 476.0, 952.0) (Hz), got 100",
        ],
    ),
    ("[cluster\n", ["invalid TOML: "]),
    (
        HEAD + '[world]\nscenario = "train"\nradius_m = 0.6\n[[nodes.measures]]\nuse = "nav"\n',
        ["[world]: unknown world keys for scenario 'train': ['radius_m']; allowed: "],
    ),
]


@pytest.mark.parametrize(("text", "problems"), CASES)
@pytest.mark.parametrize("command", ["up", "node"])
def test_a_bad_spec_is_refused_before_anything_starts(tmp_path, command, text, problems):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    args = ["--node", "a"] if command == "node" else ["--run-dir", str(tmp_path / "run")]
    out = hera(tmp_path, command, str(spec), *args)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == len(problems), out.stderr
    for line, problem in zip(lines, problems, strict=True):
        assert line.startswith(f"hera {command}: {spec}: ") and problem in line, line
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("command", ["up", "node", "router"])
@pytest.mark.parametrize("value", ["", "  ", "app: (worker_threads: 2)", "(app: (x: 1)"])
def test_an_unusable_zenoh_runtime_variable_is_one_sentence_before_anything_starts(
    tmp_path, command, value
):
    """Zenoh reads ZENOH_RUNTIME when the first session opens and panics on a value it
    cannot parse (a Rust backtrace, a node crash loop): one that cannot be its settings is
    refused first."""
    spec = tmp_path / "ok.toml"
    spec.write_text(HEAD)
    args = {"up": ["--run-dir", str(tmp_path / "run")], "node": ["--node", "a"]}
    out = hera(
        tmp_path,
        command,
        str(spec),
        *args.get(command, ["--name", "r"]),
        env={"ZENOH_RUNTIME": value},
    )
    assert out.returncode == 2, out.stderr
    assert out.stderr == (
        f"hera {command}: environment variable ZENOH_RUNTIME={value!r} is not Zenoh's runtime "
        "settings: unset it, or give settings such as '(app: (worker_threads: 2))'\n"
    )
    assert not (tmp_path / "run").exists()


def test_zenohs_panic_on_its_runtime_variable_names_the_variable(tmp_path):
    """A value shaped like settings but not Zenoh's: Zenoh's panic is turned into one
    sentence naming the variable (its own backtrace goes to stderr before it), exit 2."""
    spec = tmp_path / "ok.toml"
    spec.write_text(HEAD)
    value = "(nonsense: (x: 1))"
    out = hera(
        tmp_path,
        "up",
        str(spec),
        "--run-dir",
        str(tmp_path / "run"),
        env={"ZENOH_RUNTIME": value, "RUST_BACKTRACE": "0"},
    )
    assert out.returncode == 2, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith(
        f"hera up: Zenoh could not start with environment variable ZENOH_RUNTIME={value!r} ("
    ), last
    assert "NoSuchStructField" in last and "Traceback" not in out.stderr
    out = hera(
        tmp_path,
        "up",
        str(spec),
        "--run-dir",
        str(tmp_path / "run2"),
        "--duration",
        "1",
        env={"ZENOH_RUNTIME": "(app: (worker_threads: 1))"},
    )
    assert out.returncode == 0, out.stderr  # a value Zenoh takes runs


def test_a_binary_or_missing_spec_is_one_sentence(tmp_path):
    blob = tmp_path / "blob.toml"
    blob.write_bytes(b"\x81\x00\xff")
    out = hera(tmp_path, "up", str(blob))
    assert out.returncode == 2
    assert out.stderr == f"hera up: {blob}: not a text file (a spec is TOML)\n"
    out = hera(tmp_path, "up", "nosuch")
    assert out.returncode == 2
    assert out.stderr.startswith("hera up: no spec file 'nosuch' and no example of that name")


def test_replay_resolves_aliases_and_refuses_unknown_settings(tmp_path):
    """``--models e7`` finds the model declared ``use = "track_gyro"`` (its alias)."""
    rec = tmp_path / "rec" / "measures"
    rec.mkdir(parents=True)
    (rec / "nav_n.csv").write_text(
        "".join(f"{i},{1000.0 + 10 * i},0.4,0.84\n" for i in range(1, 200))
    )
    out = hera(tmp_path, "replay", str(rec.parent), "--out", str(tmp_path / "o"), "--spec", "train")
    assert out.returncode == 0, out.stderr
    out = hera(
        tmp_path,
        "replay",
        str(rec.parent),
        "--out",
        str(tmp_path / "o7"),
        "--spec",
        "deploy/train.toml",
        "--models",
        "e7",
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("track_gyro ")  # the spec's model and its settings
    bad = tmp_path / "bad.toml"
    bad.write_text(HEAD + TRAIN_MODEL % "radius_m = 0.6")
    out = hera(
        tmp_path, "replay", str(rec.parent), "--out", str(tmp_path / "x"), "--spec", str(bad)
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "model: unknown setting 'radius_m' (did you mean 'radius'?)" in out.stderr
    out = hera(tmp_path, "replay", str(rec.parent), "--out", str(tmp_path / "y"), "--models", "e77")
    assert out.returncode == 2
    assert out.stderr.startswith("hera replay: unknown measure 'e77' (did you mean 'e7'?)")


def test_an_unknown_control_verb_lists_the_runtime_and_application_verbs():
    from types import SimpleNamespace

    from hera.control import ControlPlane
    from hera.plugins import installed_apps

    plane = ControlPlane(SimpleNamespace(name="a"))
    with pytest.raises(ValueError) as e:
        plane.handle("bored", {})
    apps = sorted(v for app in installed_apps() for v in app.verbs())
    assert "board" in apps  # the simulator's, at least
    from hera.control import RUNTIME_VERBS

    assert str(e.value) == "unknown control verb 'bored': use " + ", ".join((*RUNTIME_VERBS, *apps))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x81\x00\xffbinary", "not a text CSV (a recording is seq,timestamp_ms,...)"),
        (b"1,1000.0,0.4,0.8\n2,1010.0,0.4\n", ":2: 1 values where the rows have 2"),
        (b"1,1000.0,0.4,0.8\nx,1010.0,0.4,0.8\n", ":2: expected seq,timestamp_ms,values..."),
    ],
)
def test_a_bad_recording_names_the_file_and_the_row(tmp_path, content, message):
    rec = tmp_path / "rec" / "measures"
    rec.mkdir(parents=True)
    (rec / "nav_n.csv").write_bytes(content)
    out = hera(tmp_path, "replay", str(rec.parent), "--out", str(tmp_path / "o"), "--spec", "train")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].startswith(f"hera replay: {rec / 'nav_n.csv'}")
    assert message in out.stderr


def test_replay_of_a_folder_that_is_not_there_says_so(tmp_path):
    out = hera(tmp_path, "replay", str(tmp_path / "nope"), "--out", str(tmp_path / "o"))
    assert out.returncode == 2
    assert out.stderr == (
        f"hera replay: {tmp_path / 'nope'}: no such folder: give a run directory of 'hera up' "
        "(or of 'hera import') or a folder of <name>_<node>.csv recordings\n"
    )
    assert not (tmp_path / "o").exists()


def test_an_error_of_the_system_about_a_file_reads_path_then_reason(tmp_path):
    from hera.cli import _problem

    (tmp_path / "file").write_text("x")
    out = hera(tmp_path, "certs", "train", "--out", str(tmp_path / "file" / "certs"))
    assert out.returncode == 2
    assert out.stderr == f"hera certs: {tmp_path}/file/certs: Not a directory\n"
    assert _problem(OSError(2, "No such file or directory", "a", None, "b")) == (
        "a -> b: No such file or directory"
    )
    assert _problem(OSError("no file named")) == "no file named"


def test_a_reader_that_leaves_early_is_no_error(tmp_path):
    """``hera measures | head -1``: the reader closes the pipe before hera is done; hera
    stops quietly (exit 1, as output cut short), not with "[Errno 32] Broken pipe"."""
    import subprocess
    import sys

    from harness import cluster_env

    proc = subprocess.Popen(
        [sys.executable, "-m", "hera", "measures"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=cluster_env(tmp_path),
        cwd=tmp_path,
    )
    proc.stdout.close()  # before hera has imported anything: its first write fails
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert err == "", err
