"""The train ladder over many seeds, worlds and both directions of travel, offline (issue 20).

Each run simulates a spec's boards on a virtual clock (hera.nodes.offline), replays every
model over the recordings (hera.replay: bilateration chained into e5) and scores them with
hera.evaluate: the code paths of `hera up` + `hera replay` + `hera eval`, without the
processes (tests/models/test_train_cluster.py and test_train_rough_cluster.py run real
clusters).

- The rough rig (deploy/train_rough.toml, scenario train_rough), 4 seeds in CI, 10 with
  `-m slow` (a new rig each: radius, rails, table tilt, heading offset, boards' errors) x
  both directions, 90 s:
  every rung e5-e9 locks within two laps and never stays on a wrong branch for more than a
  lap; settled omega (after 30 s) within 0.5 % for e7-e9; e8/e9 radius within the rails
  with a standard deviation <= 5 mm over the second half; no estimate of omega, once
  locked, under half the truth.
- The plain world (deploy/train.toml), 3 seeds in CI (random start angles) x both directions,
  30 s: no inversion of the ladder of thesis fig. 6.5 (0.1 pp of slack), e7 within 1 % once
  settled, the README's accuracy figures with margin. `-m slow`: 30 seeds each way.
- The lap-timing reference (hera eval's self-consistency) against the truth.
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest
from parallel import run_each
from train_offline import train_run

from hera.application import EvalOptions
from hera.models.train.app import train_truth
from hera.models.train.laps import lap_reference
from hera.spec import load_spec

ROUGH_RUNGS = ("track_bilat", "track_sonar", "track_gyro", "track_radius", "track_mag")
FIG_6_5 = ("omega_acc", "track_sonar", "track_gyro", "track_radius", "track_mag")


def _runs(tmp: Path, spec: str, seeds, omegas, duration: float, settle: float):
    keys = [(seed, omega) for omega in omegas for seed in seeds]
    calls = [
        dict(
            spec=spec,
            tmp=tmp / f"{spec}-{seed}-{omega}",
            seed=seed,
            duration=duration,
            world={"omega": omega},
            options=EvalOptions(settle=settle),
        )
        for seed, omega in keys
    ]
    return _scored(keys, calls)


def _scored(keys, calls):
    """{key: ({model: scores}, sim dir)} of the offline runs ``calls`` (on every core)."""
    results = run_each(train_run, calls)
    return {
        key: ({m: r for (m, _), r in res.items()}, call["tmp"] / "sim")
        for key, call, res in zip(keys, calls, results, strict=True)
    }


ROUGH_SEEDS = range(4)
"""The rough rigs CI runs (each seed a new rig, both ways); ``-m slow`` runs seeds 0-9."""


@pytest.fixture(scope="module")
def rough(tmp_path_factory):
    return _rough_runs(tmp_path_factory.mktemp("rough"), ROUGH_SEEDS)


def _rough_runs(tmp, seeds):
    return _runs(tmp, "train_rough", seeds, (0.7, -0.7), 90.0, 30.0)


def _each(runs, rungs):
    for (seed, omega), (res, _) in runs.items():
        for rung in rungs:
            yield f"seed {seed} omega {omega:+}", rung, res[rung]


def _check_locks(runs):
    for where, rung, r in _each(runs, ROUGH_RUNGS):
        assert r["lock_laps"] is not None and r["lock_laps"] <= 2.0, (where, rung, r)
        assert r["wrong_laps"] <= 1.0, (where, rung, r)


def _check_settled(runs):
    for where, rung, r in _each(runs, ROUGH_RUNGS[2:]):
        assert r["omega_settled_rms_pct"] <= 0.5, (where, rung, r)


def _check_radius(runs):
    for where, rung, r in _each(runs, ("track_radius", "track_mag")):
        assert r["radius_off_mm"] == 0.0, (where, rung, r)
        assert r["radius_std_mm"] <= 5.0, (where, rung, r)


def _check_no_echo_pull(runs):
    for where, rung, r in _each(runs, ROUGH_RUNGS):
        assert r["omega_low_pct"] > 50.0, (where, rung, r)


def test_rough_every_rung_locks_within_two_laps_and_never_stays_on_a_wrong_branch(rough):
    _check_locks(rough)


def test_rough_settled_omega_within_half_a_percent_for_e7_to_e9(rough):
    _check_settled(rough)


def test_rough_radius_within_the_rails_and_steady(rough):
    _check_radius(rough)


def test_rough_no_echo_pulls_omega_below_half_its_value(rough):
    _check_no_echo_pull(rough)


@pytest.mark.slow
def test_rough_over_ten_rigs_each_way(tmp_path):
    runs = _rough_runs(tmp_path, range(10))
    for check in (_check_locks, _check_settled, _check_radius, _check_no_echo_pull):
        check(runs)


def _check_plain(runs):
    for (seed, omega), (res, _) in runs.items():
        where = f"seed {seed} omega {omega:+}"
        w = [res[m]["omega_settled_rms_pct"] for m in FIG_6_5]
        for a, wa, b, wb in zip(FIG_6_5, w, FIG_6_5[1:], w[1:], strict=False):
            assert wb <= wa + 0.1, (where, a, wa, b, wb)  # the ladder, no inversion
        # e7 within 1 % once settled (10 s: acquired, the gyro's scale learnt): before,
        # e7's w is the gyro's average, 0.5 % (1 sigma) at 3 s from vibration alone
        e7 = res["track_gyro"]
        assert e7["omega_max_pct"] <= 1.0, (where, e7)
        assert e7["omega_settled_rms_pct"] <= 0.4, (where, e7)
        assert res["track_radius"]["radius_rms_cm"] <= 0.6, (where, res["track_radius"])
        assert res["track_mag"]["pos_rmse_cm"] <= 1.0, (where, res["track_mag"])
        assert res["track_sonar"]["pos_rmse_cm"] <= res["track_bilat"]["pos_rmse_cm"], where
        for rung in FIG_6_5[1:]:
            assert res[rung]["lock_laps"] <= 1.0 and res[rung]["wrong_laps"] == 0.0, where


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return _plain_after(tmp_path_factory.mktemp("plain"), range(3))


def _plain_after(tmp, seeds):
    """Runs of the plain world, every error counted from 10 s (``after`` = ``settle``)."""
    keys = [(seed, omega) for omega in (0.84, -0.84) for seed in seeds]
    calls = [
        dict(
            spec="train",
            tmp=tmp / f"train-{seed}-{omega}",
            seed=seed,
            duration=30.0,
            world={"omega": omega, "phase": random.Random(seed).uniform(-math.pi, math.pi)},
            options=EvalOptions(after=10.0, settle=10.0),
        )
        for seed, omega in keys
    ]
    return _scored(keys, calls)


def test_plain_world_ladder_holds_and_e7_stays_within_1pct_once_settled(plain):
    _check_plain(plain)


@pytest.mark.slow
def test_plain_world_ladder_over_30_runs_each_way(tmp_path):
    _check_plain(_plain_after(tmp_path, range(30)))


@pytest.mark.parametrize("omega", [-0.5, 0.5])
def test_the_issues_clockwise_rig_tracks_like_the_counter_clockwise_one(tmp_path, omega):
    """Issue 20's case: the plain world with radius 0.75 m and omega -0.5 rad/s (sonars
    below the track pointing +y, the models told the radius) made every rung collapse to
    omega = 0, e7 included, while counter-clockwise tracked within 0.3 %. Both ways now:
    no rung's omega ever under half the truth after 3 s (once locked, for the rungs with
    theta), e7-e9 settled within 0.5 %, e4-e6 within 5 %. Measured over seeds 0-4 both
    ways: e7-e9 settled 0.13-0.31 %, e4 1.5-8.2 %, lowest omega 62.7 % (e4)."""
    models = {m: {"radius": 0.75} for m in FIG_6_5 + ("track_bilat",)}
    res = train_run(
        "train",
        tmp_path,
        seed=1,
        duration=40.0,
        world={"omega": omega, "radius": 0.75},
        models=models,
        options=EvalOptions(after=3.0, settle=15.0),
    )
    res = {m: r for (m, _), r in res.items()}
    for rung in FIG_6_5 + ("track_bilat",):
        r = res[rung]
        assert r["omega_low_pct"] > 50.0, (rung, r)
        bound = 0.5 if rung in ROUGH_RUNGS[2:] else 5.0
        assert r["omega_settled_rms_pct"] <= bound, (rung, r)


def _lap_errors(runs):
    for (seed, omega), (_, sim) in runs.items():
        ref = lap_reference([sim])
        assert ref is not None and "lap timing" in ref.source
        truth = train_truth(load_spec(sim / "cluster.json").world)
        t0 = float(load_spec(sim / "cluster.json").world["epoch"])
        probe = [t0 + 12.0 + i for i in range(10)]
        errs = [
            abs(ref.truth.at(t)["omega [rad/s]"] / truth.at(t)["omega [rad/s]"] - 1)
            for t in probe
            if ref.truth.at(t)
        ]
        yield (seed, omega), errs


def test_lap_timing_reference_matches_the_truth(plain, rough):
    """The self-consistent reference of runs without truth: signed right, within 0.4 %
    on the plain world (30 s: 3 or 4 passes per sonar) and 0.6 % on the rough one (90 s,
    2 Hz sonars)."""
    for runs, tol in ((plain, 0.004), (rough, 0.006)):
        for where, errs in _lap_errors(runs):
            assert errs and max(errs) <= tol, (where, errs)
