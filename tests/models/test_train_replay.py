"""`hera replay` and `hera eval` on train runs (issue 20): chained models in one call,
overrides of model settings and of the world checked against what is declared, and runs
scored against a reference series when their world has no truth."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from harness import cluster_env

from hera.evaluate import by_model, evaluate
from hera.nodes.offline import simulate
from hera.recordings import CsvWriter, LiveStart, read_csv, start_marker, write_start
from hera.replay import (
    LiveSchedule,
    dependency_order,
    model_args_from_spec,
    why_recordings_incomplete,
)
from hera.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """30 s of the boards of deploy/train.toml: no model output, no bilateration."""
    tmp = tmp_path_factory.mktemp("sim")
    return simulate(load_spec(ROOT / "deploy" / "train.toml"), tmp / "sim", 30.0, seed=3)


def hera(*args: str, tmp: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hera", *args],
        env=cluster_env(tmp),
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_a_model_fed_by_another_runs_after_it_in_the_same_replay(sim, tmp_path):
    out = tmp_path / "out"
    proc = hera("replay", str(sim), "--out", str(out), "--models", "e5", tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "bilateration" in proc.stdout  # replayed because e5 takes its output
    res = by_model(evaluate(out))
    assert res[("bilateration", "replay")]["estimates"] > 20
    # e5 localised the train from the replayed fixes (without them: ~80 cm off)
    assert res[("track_bilat", "replay")]["pos_rmse_cm"] < 20
    assert json.loads((out / "replay.json").read_text())["recordings"] == str(sim.resolve())
    # the models' diagnostic counters beside their estimates: e5 seeded theta from a fix
    counters = json.loads((out / "measures" / "track_bilat_replay.counters.json").read_text())
    assert counters["seeds"] >= 1 and counters["late"] == 0, counters
    assert {"rejected", "unlocks", "off_track", "direction_fixes"} <= set(counters)


def test_spec_given_by_name_or_with_aliases_replays_the_chain(sim, tmp_path):
    """``--spec`` takes an example's name, and a spec whose measures use the thesis aliases
    (``use = "e5"``): the models keep the spec's names, bilateration still feeds e5."""
    text = (ROOT / "deploy" / "train.toml").read_text()
    assert 'use = "track_bilat"' in text and 'use = "track_radius"' in text
    aliased = tmp_path / "aliased.toml"
    aliased.write_text(
        text.replace('use = "track_bilat"', 'use = "e5"').replace(
            'use = "track_radius"', 'use = "e8"'
        )
    )
    out = tmp_path / "aliased"
    proc = hera(
        "replay", str(sim), "--out", str(out), "--spec", str(aliased), "--models", "e5,e8",
        tmp=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    res = by_model(evaluate(out))
    assert set(res) == {("e5", "replay"), ("e8", "replay"), ("bilateration", "replay")}
    assert res[("e5", "replay")]["pos_rmse_cm"] < 20  # fed by the replayed fixes
    named = tmp_path / "named"
    proc = hera(
        "replay", str(sim), "--out", str(named), "--spec", "train_rough", "--models", "e9",
        tmp=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (named / "measures" / "track_mag_replay.csv").exists()


def test_models_feeding_each_other_in_a_cycle_are_refused():
    class M:
        def __init__(self, *inputs):
            self.inputs = inputs

    assert dependency_order({"b": M("a"), "a": M("nav"), "c": M("b", "a")}) == ["a", "b", "c"]
    with pytest.raises(ValueError, match="cycle: x, y"):
        dependency_order({"x": M("y"), "y": M("x"), "z": M("nav")})


def test_set_overrides_a_model_setting_and_the_world(sim, tmp_path):
    base, moved = tmp_path / "base", tmp_path / "moved"
    args = ("replay", str(sim), "--models", "e8")
    assert hera(*args, "--out", str(base), tmp=tmp_path).returncode == 0
    proc = hera(
        *args,
        "--out",
        str(moved),
        "--set",
        "track_radius.radius=0.75",
        "--set",
        "track_radius.radius_var0=1e-8",
        "--set",
        "track_radius.q_radius=0",
        "--set",
        "world.radius=0.75",
        tmp=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    last = (moved / "measures" / "track_radius_replay.csv").read_text().splitlines()[-1]
    assert float(last.split(",")[-1]) == pytest.approx(0.75, abs=0.001)  # held there
    base_last = (base / "measures" / "track_radius_replay.csv").read_text().splitlines()[-1]
    assert float(base_last.split(",")[-1]) == pytest.approx(0.6, abs=0.02)
    world = json.loads((moved / "cluster.json").read_text())["resolved_spec"]["world"]
    assert world["radius"] == 0.75


@pytest.mark.parametrize(
    ("override", "says"),
    [
        ("track_radius.radiuss=0.57", "has no setting 'radiuss' (did you mean 'radius'?)"),
        ("track_radius.radius=abc", "radius must be a finite number or null, got 'abc'"),
        ("track_mag.radius=0.57", "no model 'track_mag' among the replayed ones"),
        ("world.radiuss=0.6", "unknown world keys for scenario 'train': ['radiuss']"),
        ("radius=0.57", "expected MODEL.SETTING=VALUE or world.KEY=VALUE"),
    ],
)
def test_a_bad_override_is_one_clear_sentence_and_exit_2(sim, tmp_path, override, says):
    out = tmp_path / "out"
    proc = hera(
        "replay", str(sim), "--out", str(out), "--models", "e8", "--set", override, tmp=tmp_path
    )
    assert proc.returncode == 2, proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and override in lines[0], proc.stderr
    assert not (out / "measures").exists()  # nothing written


def test_eval_without_truth_scores_against_a_reference_series_and_says_so(sim, tmp_path):
    out = tmp_path / "out"
    assert (
        hera("replay", str(sim), "--out", str(out), "--models", "e7", tmp=tmp_path).returncode == 0
    )
    spec = json.loads((out / "cluster.json").read_text())
    spec["resolved_spec"]["world"] = {}  # as a real rig's run: no simulated world
    (out / "cluster.json").write_text(json.dumps(spec))
    ref = CsvWriter(tmp_path / "ref", "laps", "stopwatch", ["omega [rad/s]"])
    epoch = float(load_spec(sim / "cluster.json").world["epoch"])
    for i in range(31):
        ref.write(epoch + i, [0.84 * 1.01])  # a stopwatch 1 % fast
    ref.close()
    reference = tmp_path / "ref" / "measures" / "laps_stopwatch.csv"
    proc = hera("eval", str(out), "--no-plots", "--reference", str(reference), tmp=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"train: scored against reference series {reference}" in proc.stdout
    res = by_model(evaluate(out, reference=reference))
    assert res[("track_gyro", "replay")]["omega_settled_rms_pct"] == pytest.approx(1.0, abs=0.3)
    # without it, the train's own reference: lap timing over the replay's source recordings
    (out / "replay.json").write_text(json.dumps({"recordings": str(sim)}))
    rows = evaluate(out)
    assert rows[0].source.startswith("self-consistency") and "lap timing" in rows[0].source
    bad = hera("eval", str(out), "--reference", str(tmp_path / "nope.csv"), tmp=tmp_path)
    assert bad.returncode == 2 and "nope.csv" in bad.stderr


def test_replay_runs_on_the_specs_backend_unless_told_and_both_agree(sim, tmp_path):
    """The live nodes fuse on the spec's ``estimation_backend`` (numpy by default), and so
    does the replay: the same arithmetic, and no numba compile for a numpy run.
    ``--backend`` picks another. The two backends agree to rounding on the same inputs; the
    train's branch grid then picks between near-equal branches (a discrete choice), which
    can turn a rounding difference into one of about 2e-5 that the filter forgets again."""
    out = {}
    for backend in (None, "numba"):
        dest = tmp_path / str(backend)
        extra = ["--backend", backend] if backend else []
        proc = hera("replay", str(sim), "--out", str(dest), "--models", "e7", *extra, tmp=tmp_path)
        assert proc.returncode == 0, proc.stderr
        said = "numba (--backend)" if backend else "numpy (the spec's estimation_backend)"
        assert f"estimation backend: {said}" in proc.stderr, proc.stderr
        (csv,) = (dest / "measures").glob("track_gyro_replay.csv")
        out[backend] = np.loadtxt(csv, delimiter=",", skiprows=1)
    # the default replay of this numpy spec never even imports numba (no compile)
    probe = (
        "import sys; from hera.cli import main; "
        f"rc = main(['replay', {str(sim)!r}, '--out', {str(tmp_path / 'probe')!r}, "
        "'--models', 'e7']); print(rc, 'numba' in sys.modules)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", probe], env=cluster_env(tmp_path), capture_output=True, text=True
    )
    assert proc.stdout.split()[-2:] == ["0", "False"], proc.stdout[-500:] + proc.stderr[-2000:]
    a, b = out[None], out["numba"]
    assert a.shape == b.shape and len(a) > 1000
    np.testing.assert_allclose(a[:30], b[:30], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-4)


def test_start_like_says_which_live_models_it_cannot_repeat(sim, tmp_path):
    """A live model whose start marker records samples given out of time order is named,
    with what happened; one given every sample in order is not."""
    run = tmp_path / "run"
    shutil.copytree(sim, run)
    proc = hera(
        "replay",
        str(run),
        "--out",
        str(run),
        "--models",
        "e4,e6",
        "--node",
        "computer",
        tmp=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    measures = run / "measures"
    first = read_csv(measures / "omega_acc_computer.csv", "omega_acc", "computer")[0].t
    write_start(
        start_marker(measures, "omega_acc", "computer"), LiveStart(first, 2, first + 1.5, 0, 0)
    )
    write_start(start_marker(measures, "track_sonar", "computer"), LiveStart(first, 0, None, 0, 0))
    proc = hera("replay", str(run), "--out", str(tmp_path / "out"), "--models", "e4,e6",
                "--start-like", "computer", tmp=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (
        "omega_acc: live on computer it was given 2 sample(s) out of time order, the first"
        " 1.500 s after its start; the replay may differ from there" in proc.stdout
    )
    assert "track_sonar:" not in proc.stdout


def _write_rows(run: Path, name: str, node: str, rows) -> None:
    """Write ``rows`` as ``run/measures/<name>_<node>.csv``."""
    w = CsvWriter(run, name, node, ("a",) * len(rows[0].values))
    for r in rows:
        w.write(r.t, r.values)
    w.close()


def test_start_like_feeds_a_chained_model_what_every_replica_published(sim, tmp_path):
    """Two replicas of ``bilateration`` step at different moments, so each publishes fixes
    the other superseded; live, e5 on nav_1 fused the fixes of both (each once). A replay
    like nav_1 writes bilateration at nav_1's instants but feeds e5 every replica's fixes,
    and so repeats e5 exactly (it fed nav_1's alone before: a CI run's e5 then differed for
    10 s after the first fix only the other node had published)."""
    every = tmp_path / "every"  # e5 fed every fix: what nav_1 fused live
    proc = hera("replay", str(sim), "--out", str(every), "--models", "e5", "--node", "all",
                tmp=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    fixes = read_csv(every / "measures" / "bilateration_all.csv", "bilateration", "all")
    e5 = read_csv(every / "measures" / "track_bilat_all.csv", "track_bilat", "all")
    assert len(fixes) > 20
    run = tmp_path / "run"
    shutil.copytree(sim, run)
    measures = run / "measures"
    # nav_1 published two fixes in three, computer the others and half of nav_1's
    _write_rows(run, "bilateration", "nav_1", [f for i, f in enumerate(fixes) if i % 3])
    _write_rows(run, "bilateration", "computer", [f for i, f in enumerate(fixes) if i % 3 != 1])
    _write_rows(run, "track_bilat", "nav_1", e5)
    for name in ("bilateration", "track_bilat"):  # given every sample from the start, in order
        write_start(start_marker(measures, name, "nav_1"), LiveStart(0.0))
    write_start(start_marker(measures, "bilateration", "computer"), LiveStart(0.0))

    out = tmp_path / "like"
    proc = hera("replay", str(run), "--out", str(out), "--models", "e5",
                "--start-like", "nav_1", tmp=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "may differ" not in proc.stdout, proc.stdout
    got = read_csv(out / "measures" / "bilateration_replay.csv", "bilateration", "replay")
    assert [f.t for f in got] == [f.t for i, f in enumerate(fixes) if i % 3]  # nav_1's own
    again = read_csv(out / "measures" / "track_bilat_replay.csv", "track_bilat", "replay")
    assert [(r.t, r.values) for r in again] == [(r.t, r.values) for r in e5]

    # a replica that was given samples out of time order: e5's replay is said to be at risk
    write_start(
        start_marker(measures, "bilateration", "computer"), LiveStart(0.0, 2, fixes[5].t, 0, 0)
    )
    proc = hera("replay", str(run), "--out", str(tmp_path / "late"), "--models", "e5",
                "--start-like", "nav_1", tmp=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (
        "track_bilat is fed by it and may differ too: bilateration: live on computer it was "
        "given 2 sample(s) out of time order" in proc.stdout
    ), proc.stdout


def test_a_gap_in_the_recorded_seqs_names_the_models_it_may_change(sim, tmp_path):
    """A sample the log node did not record (its link dropped it under load, as in a CI
    run: sonar_1's seq 43 missing) may be one a model's own node fused: each model that
    takes that stream, itself or through a model it is fed by, is named, with the time from
    its start; a gap before a model's start, or in a stream it does not take, is not."""
    models = model_args_from_spec(load_spec(ROOT / "deploy" / "train.toml"))
    chosen = {n: models[n] for n in ("bilateration", "track_bilat", "omega_acc")}
    run = tmp_path / "run"
    shutil.copytree(sim, run)
    like = {n: LiveSchedule(0.0, frozenset(), frozenset()) for n in chosen}
    assert why_recordings_incomplete(run, chosen, like) == {}

    path = run / "measures" / "sonar_sonar_1.csv"
    rows = path.read_text().splitlines(keepends=True)
    gone = float(rows[10].split(",")[1]) / 1000.0
    path.write_text("".join(rows[:10] + rows[11:]))
    got = why_recordings_incomplete(run, chosen, like)
    assert set(got) == {"bilateration", "track_bilat"}, got  # omega_acc takes no sonar
    assert got["track_bilat"].startswith(
        "track_bilat: the recordings miss 1 sample(s) of its inputs (seqs skipped; the "
        "first of sonar from sonar_1, "
    )
    later = {n: LiveSchedule(gone + 1.0, frozenset(), frozenset()) for n in chosen}
    assert why_recordings_incomplete(run, chosen, later) == {}
