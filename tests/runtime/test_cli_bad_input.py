"""Bad input to the commands that read runs, recordings, logs and credentials: one sentence
naming the file, option or key, exit code 2, and nothing half-written or replaced (the cases
of test_cli_errors.py, which covers bad specs, are not repeated here)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from harness import run_hera

ROOT = Path(__file__).resolve().parents[2]
HEAD = '[cluster]\nname = "e"\n[[nodes]]\nname = "a"\n'


def hera(tmp_path: Path, *args: str, env: dict[str, str] | None = None):
    return run_hera(tmp_path, *args, cwd=ROOT, env=env)


def fake_run(tmp_path: Path) -> Path:
    """A run directory of the train as ``hera up`` leaves one: its cluster.json, an IMU
    recording and one model output (with their columns sidecars)."""
    from hera.spec import load_spec

    run = tmp_path / "run"
    (run / "measures").mkdir(parents=True)
    spec = load_spec(ROOT / "deploy" / "train.toml").with_world(epoch=1000.0)
    (run / "cluster.json").write_text(spec.to_json())
    t0 = 1_000_000.0
    (run / "measures" / "nav_nav_1.csv").write_text(
        "".join(f"{i},{t0 + 10 * i},0.4,0.84\n" for i in range(1, 300))
    )
    (run / "measures" / "nav_nav_1.columns.json").write_text(
        json.dumps({"name": "nav", "node": "nav_1", "columns": ["seq", "t", "a [m/s2]", "g"]})
    )
    (run / "measures" / "omega_acc_computer.csv").write_text(
        "".join(f"{i},{t0 + 50 * i},0.84\n" for i in range(1, 300))
    )
    (run / "measures" / "omega_acc_computer.columns.json").write_text(
        json.dumps({"name": "omega_acc", "node": "computer", "columns": ["seq", "t", "omega"]})
    )
    return run


@pytest.mark.parametrize("content", [b"", b"\x81\x00\xff", b'{"name": 5}', b"[1, 2]"])
@pytest.mark.parametrize("command", ["eval", "export"])
def test_a_broken_columns_sidecar_names_the_file(tmp_path, command, content):
    run = fake_run(tmp_path)
    side = run / "measures" / "omega_acc_computer.columns.json"
    side.write_bytes(content)
    args = ["--no-plots"] if command == "eval" else ["--mcap", str(tmp_path / "o.mcap")]
    out = hera(tmp_path, command, str(run), *args)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith(f"hera {command}: {side}: not a columns sidecar"), last
    assert not (tmp_path / "o.mcap").exists()


def test_a_failed_import_leaves_no_run_directory(tmp_path):
    src = tmp_path / "logs"
    src.mkdir()
    (src / "nav.csv").write_bytes(b"\x81\x00\xff" * 100)
    (src / "sonar1.csv").write_text("1,1000,0.5,0.1,0.2\n")
    out = hera(tmp_path, "import", "erlang-hera", str(src), str(tmp_path / "new"))
    assert out.returncode == 2, out.stderr
    assert out.stderr == (
        f"hera import: {src / 'nav.csv'}: not a text CSV (a log is seq,timestamp_ms,values)\n"
    )
    assert not (tmp_path / "new").exists()
    (src / "nav.csv").write_text("1,1000,0.1,0.2\n2,1010,0.1\n")  # a row cut short
    (tmp_path / "empty").mkdir()  # an empty folder given: it stays, empty
    out = hera(tmp_path, "import", "erlang-hera", str(src), str(tmp_path / "empty"))
    assert out.returncode == 2, out.stderr
    assert out.stderr == f"hera import: {src / 'nav.csv'}:2: expected 2 values, got 1\n"
    assert list((tmp_path / "empty").iterdir()) == []


def test_certs_never_replace_half_a_ca_or_a_broken_one(tmp_path):
    pytest.importorskip("cryptography")
    good = tmp_path / "good"
    assert hera(tmp_path, "certs", "train", "--out", str(good)).returncode == 0
    half = tmp_path / "half"
    half.mkdir()
    (half / "ca.pem").write_bytes((good / "ca.pem").read_bytes())
    out = hera(tmp_path, "certs", "train", "--out", str(half))
    assert out.returncode == 2
    assert out.stderr == (
        f"hera certs: {half}: holds ca.pem but not ca.key: a CA needs both (put ca.key back, "
        "or give a new folder for a new CA)\n"
    )
    assert (half / "ca.pem").read_bytes() == (good / "ca.pem").read_bytes()
    assert sorted(p.name for p in half.iterdir()) == ["ca.pem"]
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "ca.key").write_text("garbage\n")
    (broken / "ca.pem").write_bytes((good / "ca.pem").read_bytes())
    out = hera(tmp_path, "certs", "train", "--out", str(broken))
    assert out.returncode == 2
    assert out.stderr == (
        f"hera certs: {broken / 'ca.key'}: not the CA key made by 'hera certs' (PEM, EC)\n"
    )
    (broken / "ca.key").write_bytes((good / "computer.key").read_bytes())  # another key
    out = hera(tmp_path, "certs", "train", "--out", str(broken))
    assert out.returncode == 2
    assert out.stderr == f"hera certs: {broken}: ca.key is not the key of ca.pem\n"
    again = hera(tmp_path, "certs", "train", "--out", str(good))  # a whole CA is re-used
    assert again.returncode == 0, again.stderr


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file: is {run} a run directory of 'hera up'?"),
        ("x", "not a launcher's record (launcher_pid, written by 'hera up')"),
        ("{}", "not a launcher's record (launcher_pid, written by 'hera up')"),
    ],
)
def test_down_names_a_broken_launcher_record(tmp_path, content, message):
    run = tmp_path / "run"
    run.mkdir()
    if content is not None:
        (run / "launcher.json").write_text(content)
    out = hera(tmp_path, "down", "--run-dir", str(run))
    assert out.returncode == 2
    assert out.stderr == f"hera down: {run / 'launcher.json'}: {message.format(run=run)}\n"


@pytest.mark.parametrize("command", ["node", "router"])
def test_a_bad_log_level_is_refused_before_anything_is_made(tmp_path, command):
    run = tmp_path / "run"
    who = ["--node", "nav_1", "--run-dir", str(run)] if command == "node" else ["--name", "r"]
    out = hera(tmp_path, command, "train", *who, "--log-level", "LOUD")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera {command}: error: argument --log-level: must be one of DEBUG, INFO, WARNING, "
        "ERROR, CRITICAL, got 'LOUD'"
    )
    assert not run.exists()


def test_up_with_credentials_it_cannot_read_makes_no_run_directory(tmp_path):
    out = run_hera(tmp_path, "up", "train", "--cert", str(tmp_path / "nocerts"), cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr == (
        f"hera up: cannot read the cluster secret {tmp_path / 'nocerts' / 'secret'}: No such "
        "file or directory\n"
    )
    assert not (tmp_path / "hera-run").exists()  # nor hera-run/train pointing at an empty run
    out = hera(tmp_path, "up", "train", "--cert", str(tmp_path), "--run-dir", str(tmp_path / "r"))
    assert out.returncode == 2
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("settings", "problem"),
    [
        ('radius = "x"', "radius must be a finite number or null, got 'x'"),
        ("lock_count = 2.5", "lock_count must be an integer, got 2.5"),
        ("var_acc = true", "var_acc must be a finite number, got True"),
        ("var_acc = nan", "var_acc must be a finite number, got nan"),  # it crash-looped
        ("radius = inf", "radius must be a finite number or null, got inf"),
    ],
)
def test_a_model_setting_of_the_wrong_kind_is_refused_before_start(tmp_path, settings, problem):
    """The train's models have no check of their own: a setting's declared number kind is
    checked before a node starts (there it only said "could not convert string to float",
    in a restart loop)."""
    spec = tmp_path / "bad.toml"
    model = f"{{ model = {{ {settings} }} }}"
    spec.write_text(HEAD + f'[[nodes.measures]]\nuse = "track_radius"\nargs = {model}\n')
    out = hera(tmp_path, "node", str(spec), "--node", "a", "--check-only")
    assert out.returncode == 2
    assert out.stderr == (
        f"hera node: {spec}: measure 'track_radius' of node 'a': args: model: {problem}\n"
    )


def test_replay_with_world_overrides_into_its_recordings_is_refused(tmp_path):
    run = fake_run(tmp_path)
    before = (run / "cluster.json").read_text()
    out = hera(
        tmp_path, "replay", str(run), "--out", str(run), "--models", "e4",
        "--set", "world.radius=0.59",
    )  # fmt: skip
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera replay: --out {run} is the recordings' folder, whose cluster.json keeps the "
        "world the live run had: a replay with world overrides (--set world.KEY=V) needs "
        "another --out"
    )
    assert (run / "cluster.json").read_text() == before
    assert not (run / "measures" / "omega_acc_replay.csv").exists()


def test_replay_refuses_a_node_name_that_cannot_name_its_files(tmp_path):
    run = fake_run(tmp_path)
    out = hera(tmp_path, "replay", str(run), "--out", str(tmp_path / "o"), "--node", "a/b")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines()[-1] == (
        "hera replay: error: argument --node: must use only letters, digits, '_', '.' and '-' "
        "(no '/', '*', '$'), at most 64 of them, got 'a/b'"
    )
    assert not (tmp_path / "o").exists()


def test_eval_refuses_a_node_with_no_outputs(tmp_path):
    run = fake_run(tmp_path)
    plots = str(tmp_path / "p")
    out = hera(tmp_path, "eval", str(run), "--node", "computer,nav_9", "--plots", plots)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera eval: --node nav_9: no model outputs of that node in {run} (nodes: computer)"
    )
    assert out.stdout == ""
    assert not (tmp_path / "p").exists()


def test_a_last_row_cut_short_by_a_killed_logger_is_left_out(tmp_path):
    """A logger killed while it wrote a row leaves it without its line end (hera.csvlog:
    "loses at most the row being written"): eval and export read the rest; the same row
    with its line end is a bad row, named."""
    run = fake_run(tmp_path)
    csv = run / "measures" / "omega_acc_computer.csv"
    csv.write_text(csv.read_text() + "300,1015")
    out = hera(tmp_path, "eval", str(run), "--no-plots", "--json")
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr
    out = hera(tmp_path, "export", str(run), "--mcap", str(tmp_path / "o.mcap"))
    assert out.returncode == 0, out.stderr
    csv.write_text(csv.read_text() + "\n")
    out = hera(tmp_path, "eval", str(run), "--no-plots")
    assert out.returncode == 2
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera eval: {csv}:300: 0 values where the rows have 1"
    )


def test_eval_refuses_a_reference_that_is_not_there_even_with_a_truth(tmp_path):
    run = fake_run(tmp_path)  # the train's simulated world: scored against its truth
    ref = tmp_path / "stopwatch_x.csv"
    out = hera(tmp_path, "eval", str(run), "--no-plots", "--reference", str(ref))
    assert out.returncode == 2
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera eval: {ref}: a reference is a recording <name>_<node>.csv beside its "
        "<name>_<node>.columns.json"
    )


def test_a_campaign_name_that_cannot_name_its_folder_is_refused(tmp_path):
    """The name is the prefix of the campaign's run directory: hera-run/campaign-<name>-..."""
    camp = tmp_path / "c.toml"
    camp.write_text(
        '[campaign]\nname = "../x"\n[[faults]]\nkind = "crash"\ntarget = "nav_1"\n'
        'measure = "nav"\n[[faults]]\nkind = "explode"\ntarget = "nav_1"\n'
    )
    out = run_hera(tmp_path, "campaign", "train", str(camp), cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.splitlines() == [
        f"hera campaign: {camp}: [campaign]: name must use only letters, digits, '_', '.' and "
        "'-' (it names the run directory), at most 64 of them, got '../x'",
        f"hera campaign: {camp}: [[faults]] #2: kind must be one of crash, hang, kill, "
        "crash_node, pause, board, partition, loss, delay, reset, skew, got 'explode'",
    ]  # and not "a campaign needs [[faults]]": it has them
    assert not (tmp_path / "hera-run").exists()


@pytest.mark.parametrize(
    ("content", "why"),
    [
        ("[1, 2]", "a JSON object whose resolved_spec is the spec"),
        ('{"a": 1}', "a JSON object whose resolved_spec is the spec"),
        ('{"resolved_spec": {}}', "no key 'nodes'"),
    ],
)
def test_a_json_spec_that_is_not_a_resolved_one_says_what_it_lacks(tmp_path, content, why):
    spec = tmp_path / "cluster.json"
    spec.write_text(content)
    out = hera(tmp_path, "node", str(spec), "--node", "a", "--check-only")
    assert out.returncode == 2
    assert out.stderr == f"hera node: {spec}: not a resolved spec written by hera up ({why})\n"


def test_import_from_a_file_says_it_is_not_a_folder(tmp_path):
    (tmp_path / "nav.csv").write_text("1,1000,0.1,0.2\n")
    out = hera(tmp_path, "import", "erlang-hera", str(tmp_path / "nav.csv"), str(tmp_path / "o"))
    assert out.returncode == 2
    assert out.stderr == f"hera import: {tmp_path / 'nav.csv'}: not a folder of logs\n"
    assert not (tmp_path / "o").exists()


def test_eval_refuses_a_plots_folder_that_is_a_file_before_scoring(tmp_path):
    run = fake_run(tmp_path)
    (tmp_path / "plots").write_text("mine")
    out = hera(tmp_path, "eval", str(run), "--plots", str(tmp_path / "plots"))
    assert out.returncode == 2
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera eval: --plots {tmp_path / 'plots'}: not a folder"
    )
    assert out.stdout == ""  # refused before the table
    assert (tmp_path / "plots").read_text() == "mine"


def test_an_export_that_fails_midway_leaves_the_file_there_as_it_was(tmp_path, monkeypatch):
    """Written beside and renamed when done: a failure (or Ctrl-C) while writing leaves no
    file cut short, nor a user's file of that name cut short."""
    pytest.importorskip("mcap")
    from hera.export import mcap

    run = fake_run(tmp_path)
    out = tmp_path / "run.mcap"
    out.write_text("mine")
    calls = []

    def write(self, *a, **k):
        calls.append(1)
        if len(calls) > 10:
            raise KeyboardInterrupt

    monkeypatch.setattr(mcap.Channels, "write", write)
    with pytest.raises(KeyboardInterrupt):
        mcap.export_run(run, out)
    assert out.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run.mcap"]


def test_replay_does_not_write_over_another_run(tmp_path):
    """A replay's --out that holds a run of its own (a live run, an import) is refused: its
    cluster.json would be replaced by the recordings' and the two runs' records mixed. A new
    folder, a previous replay's (its replay.json) and the recordings' own are fine."""
    run = fake_run(tmp_path)
    other = tmp_path / "other"
    (other / "measures").mkdir(parents=True)
    (other / "cluster.json").write_text("mine")
    out = hera(tmp_path, "replay", str(run), "--out", str(other), "--models", "e4")
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        f"hera replay: --out {other} holds a run of its own (its cluster.json, and no "
        "replay.json of a replay): give a new folder, a previous replay's, or the recordings' own"
    )
    assert (other / "cluster.json").read_text() == "mine"
    assert list((other / "measures").iterdir()) == []
    for again in (tmp_path / "new", tmp_path / "new", run):
        out = hera(tmp_path, "replay", str(run), "--out", str(again), "--models", "e4")
        assert out.returncode == 0, out.stderr
