"""The seed-000 models offline: simulated boards drive the very model objects the fusion
measures run, in measurement-time order, over several seeds and worlds (``ir_offline``).

Tracker (lab 2): RMSE <= 0.5 cm on the constant-velocity scenario with the medium + long
pair; within 1 cm in <= 1 s from the poor initial guess; the short sensor's second spike
gated, counted and never dragging the estimate by 1 cm (and dragging it without the
gate); tracking on one sensor while the other is gone; re-acquisition after a loss; the
seed's Q/R study; biased sensors and dropouts.

Map (lab 3): >= 95 % of the cells right after 60 s of scanning and the hot block within a
cell once the heat has arrived, over seeds, plate physics and layouts; on the seed's
ambiguity case (the hot block hidden from the IR) the fused map beats IR alone and thermal
alone.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from ir_offline import (
    EPOCH,
    LONG,
    MEDIUM,
    PAIR,
    SHORT,
    Clock,
    errors,
    ir_source,
    rms,
    run,
    start_scores,
    tc_sources,
    track,
)
from parallel import run_each

from hera.application import EvalOptions, Series
from hera.models.ir.app import IrApp, hot_error, ir_truth, map_accuracy, plate_maps
from hera.models.ir.calibration import FITS, sensor_fits
from hera.models.ir.grid import OccupancyGrid
from hera.models.ir.measures import IrTrack, OccupancyFused, OccupancyIr, OccupancyThermal
from hera.models.ir.thermal import ThermalModel, green
from hera.models.ir.tiles import COLUMNS, HEADER, TILE, assemble, split
from hera.models.ir.tracker import IrTracker
from hera.store import Sample
from hera.wire import decode, encode

APP = IrApp()
SEEDS = range(6)


# -- calibration -------------------------------------------------------------------------


def test_the_models_fits_are_the_seeds_lab_1_curves():
    for part, ((d0, v0), (d1, v1)) in {
        SHORT: ((4.0, 2.34), (30.0, 0.34)),
        MEDIUM: ((10.0, 1.99), (80.0, 0.14)),
        LONG: ((20.0, 2.50), (150.0, 0.40)),
    }.items():
        law = FITS[part]
        assert law.volts(d0) == pytest.approx(v0, abs=0.01)
        assert law.volts(d1) == pytest.approx(v1, abs=0.01)
        assert law.distance(law.volts(33.0)) == pytest.approx(33.0)
    assert FITS[LONG].slope(50.0) == pytest.approx(-29.088 * 50.0**-1.873, rel=0.05)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"sensors": {"a": "GP2Y0A99"}}, ["GP2Y0A99", "known"]),
        ({"sensors": {"a": MEDIUM}, "r": {"b": 0.1}}, ["r names ['b']", "not sensors"]),
        ({"sensors": {"a": MEDIUM}, "r": {"a": 0}}, ["r['a']", "> 0"]),
        ({"sensors": {"a": MEDIUM}, "fits": {"a": [1, 2]}}, ["[a, b, c]"]),
        ({"sensors": {"a": MEDIUM}, "fits": {"a": [1.0, 0.5, 0.0]}}, ["b < 0"]),
    ],
)
def test_bad_sensor_settings_are_refused_naming_them(kwargs, words):
    with pytest.raises(ValueError) as e:
        sensor_fits(kwargs["sensors"], kwargs.get("fits"), kwargs.get("r"))
    for w in words:
        assert w in str(e.value)


@pytest.mark.parametrize(
    ("settings", "word"),
    [
        ({"q": [1.0]}, "q"),
        ({"p0": [0, 1]}, "p0"),
        ({"v0_still": -1.0}, "v0_still"),
        ({"v0_still": True}, "v0_still"),
        ({"gate": 1.5}, "gate"),
        ({"lost_window": 1}, "lost_window"),
        ({"iterations": 0}, "iterations"),
    ],
)
def test_bad_tracker_settings_are_refused_through_the_measure(settings, word):
    with pytest.raises(ValueError, match=word):
        IrTrack.make_model(settings)
    # and before any node starts: the spec check builds the model
    (problem,) = IrTrack.check_args({"model": settings}, "spec.toml: measure 'ir_track'")
    assert problem.startswith("spec.toml: measure 'ir_track': model: ") and word in problem
    with pytest.raises(ValueError, match="unknown setting 'speed'"):
        IrTrack.make_model({"speed": 1})


# -- tracker -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "world",
    [
        {"scenario": "ir_constant_velocity"},  # 20-60 cm at 2 cm/s, 2 s turns
        {"scenario": "ir_constant_velocity", "near_cm": 25.0, "far_cm": 75.0, "speed_cm_s": 1.0},
        {"scenario": "ir_constant_velocity", "speed_cm_s": 3.0, "turn_s": 3.0},
        {"scenario": "ir_constant_velocity", "turn_s": 1.0},
    ],
)
def test_constant_velocity_rmse_is_under_half_a_cm_with_the_medium_long_pair(world):
    """Issue 13: RMSE <= 0.5 cm over a 30 s run; measured 0.17-0.41 cm over these seeds
    and worlds (the error grows with the distance, as the sensors' slope flattens)."""
    worst = 0.0
    for seed in range(4):
        _, scores = track(world, seed, {"ekf": IrTracker()}, duration=30.0)
        worst = max(worst, scores["ekf"]["rmse_cm"])
    assert worst <= 0.45, worst  # 0.5 with a margin


def test_from_the_poor_initial_guess_within_a_cm_in_a_second():
    """Seed scenario 4 (start at 50 cm, target at 70): the error is within 1 cm, and its RMS
    over the next second too, after <= 1 s (measured 0.00-0.18 s; the plain EKF, one
    linearisation at the prediction, 0.06-0.82 s here and 2.6 s at seed 5 when the medium
    sensor's reading comes first). The plain EKF's first update leaves the estimate several
    cm short, the iterated one takes the reading for what it holds."""
    for seed in SEEDS:
        _, scores = track(
            {"scenario": "ir_stationary", "distance_cm": 70.0},
            seed,
            {"ekf": IrTracker(x0=[50.0, 0.0]), "plain": IrTracker(x0=[50.0, 0.0], iterations=1)},
            duration=10.0,
        )
        s, plain = scores["ekf"], scores["plain"]
        assert abs(plain["series"].column("distance [cm]")[0] - 70.0) > 2.0  # it starts off
        assert s["converge_s"] is not None and s["converge_s"] <= 1.0, (seed, s["converge_s"])
        assert s["rmse_cm"] <= 0.6, (seed, s["rmse_cm"])


def _starts(*studies):
    """For each study (world, x0, settings), each start of seeds 0-19 in both sensor orders
    (whichever reading comes first), 4 s: (the RMS error over 0.3-2 s, the largest
    |velocity| then, the converge time). All the studies' starts in one pool on every core."""
    calls = [
        dict(world=world, seed=seed, x0=x0, seconds=4.0, parts=parts, settings=settings)
        for world, x0, settings in studies
        for seed in range(20)
        for parts in (PAIR, PAIR[::-1])
    ]
    scores = np.array(run_each(start_scores, calls))
    return np.split(scores, len(studies))


def test_the_start_mixture_keeps_a_still_block_still_and_catches_a_moving_one():
    """The start's velocity prior is a mixture, a block at rest (1 cm/s) or moving (5
    cm/s), run as two weighted EKFs. On the poor-initial-guess block (at rest) it beats the
    wide prior alone: the noise winds up less velocity (measured: mean largest |v| 2.6 cm/s
    against 3.9), so the first seconds are nearer (RMS 0.51 against 0.61 cm, 95th
    percentile of the converge time 0.23 s against 0.84). On random moves it loses nothing
    to the wide prior, where the narrow prior alone is up to 1.8 s late."""
    still = {"scenario": "ir_stationary", "distance_cm": 70.0}
    moving = {"scenario": "ir_back_and_forth"}
    mix, wide, mix_m, wide_m, narrow = _starts(
        (still, [50.0, 0.0], {}),
        (still, [50.0, 0.0], {"v0_still": 0}),
        (moving, None, {}),
        (moving, None, {"v0_still": 0}),
        (moving, None, {"p0": [100.0, 1.0], "v0_still": 0}),
    )
    assert mix[:, 1].mean() < 0.8 * wide[:, 1].mean(), (mix[:, 1].mean(), wide[:, 1].mean())
    assert mix[:, 0].mean() < 0.9 * wide[:, 0].mean(), (mix[:, 0].mean(), wide[:, 0].mean())
    assert np.percentile(mix[:, 2], 95) <= 0.5, np.sort(mix[:, 2])[-4:]
    assert (mix[:, 2] <= 1.0).mean() >= 0.95, np.sort(mix[:, 2])[-4:]
    assert mix_m[:, 2].max() <= 0.3 and mix_m[:, 0].mean() <= 1.05 * wide_m[:, 0].mean()
    assert narrow[:, 2].max() > 1.0  # the narrow prior alone is late on a moving start


def test_the_start_hypotheses_merge_into_one_filter():
    """Once the readings outweigh the two priors the hypotheses are the same Gaussian and
    are merged (counted; measured after 1.6-2.3 s here, 0.5-2.6 s over the scenarios): the
    tracker runs one EKF from then on."""
    for seed in range(3):
        tracker = IrTracker(x0=[50.0, 0.0])
        world = {"scenario": "ir_stationary", "distance_cm": 70.0}
        track(world, seed, {"e": tracker}, 5.0)
        assert len(tracker.hypotheses) == 1 and tracker.counters()["merged"] == 1, seed
    single = IrTracker(x0=[50.0, 0.0], v0_still=0)
    track({"scenario": "ir_stationary", "distance_cm": 70.0}, 0, {"e": single}, 2.0)
    assert len(single.hypotheses) == 1 and single.counters()["merged"] == 0


def test_the_tracker_pickles_for_its_checkpoint_and_goes_on_the_same():
    """A fusion measure's checkpoint on disk is the model pickled (``hera.checkpoints``):
    a copy taken while both start hypotheses run, and one taken after they merged, go on
    exactly as the original."""
    seen: list[Sample] = []
    recorder = IrTracker(x0=[50.0, 0.0])
    process = recorder.process
    recorder.process = lambda s: seen.append(s) or process(s)  # type: ignore[method-assign]
    track({"scenario": "ir_stationary", "distance_cm": 70.0}, 2, {"e": recorder}, 6.0)
    for cut in (20, len(seen) // 2):
        model = IrTracker(x0=[50.0, 0.0])
        for sample in seen[:cut]:
            model.process(sample)
        assert len(model.hypotheses) == (2 if cut == 20 else 1)
        copy = pickle.loads(pickle.dumps(model))
        for sample in seen[cut:]:
            model.process(sample)
            copy.process(sample)
            assert copy.estimate() == model.estimate()


TRIO = (*PAIR, ("ir_short", SHORT))
WITH_SHORT = {"ir_medium": MEDIUM, "ir_long": LONG, "ir_short": SHORT}


@pytest.mark.parametrize(
    "world",
    [
        {"scenario": "ir_stationary", "distance_cm": 24.0},
        {"scenario": "ir_constant_velocity", "near_cm": 20.0, "far_cm": 30.0, "speed_cm_s": 1.0},
    ],
)
def test_the_short_sensors_second_spike_is_gated_counted_and_harmless(world):
    """The short sensor sits on its second spike for ~20 % of its readings (seed lab 1):
    the gate rejects about that many (counted: the ``gated`` column and the model's
    counters), and the estimate with the short sensor stays within 1 cm of the truth."""
    for seed in range(3):
        out, scores = track(world, seed, {"ekf": IrTracker(sensors=WITH_SHORT)}, 30.0, TRIO)
        c = out.models["ekf"].counters()
        short = c["ir_short_used"] + c["ir_short_gated"]
        assert 0.15 * short <= c["ir_short_gated"] <= 0.3 * short, c
        assert scores["ekf"]["gated"] >= c["ir_short_gated"]
        assert scores["ekf"]["max_err_cm"] <= 1.0, scores["ekf"]["max_err_cm"]


def test_without_the_gate_the_second_spike_drags_the_estimate():
    """The check above can fail: with the long and short sensors at 24 cm (the short one's
    weight is then large), no gate lets the spikes pull the estimate over 1 cm off."""
    sensors = {"ir_long": LONG, "ir_short": SHORT}
    parts = (("ir_long", LONG), ("ir_short", SHORT))
    for seed in range(3):
        _, scores = track(
            {"scenario": "ir_stationary", "distance_cm": 24.0},
            seed,
            {"gated": IrTracker(sensors=sensors), "open": IrTracker(sensors=sensors, gate=0.0)},
            30.0,
            parts,
        )
        assert scores["gated"]["max_err_cm"] <= 1.0
        assert scores["open"]["max_err_cm"] > 1.5 and scores["open"]["gated"] == 0


@pytest.mark.parametrize("gone", ["ir_long", "ir_medium"])
def test_tracking_goes_on_with_one_sensor_and_recovers(gone):
    """One board silent from 12 s to 24 s: the estimates go on from the other sensor
    (every 20 ms), and the error is back to its fault-free level once both report."""
    world = {"scenario": "ir_constant_velocity"}
    for seed in range(3):
        out, scores = track(
            world, seed, {"ekf": IrTracker()}, skip={gone: lambda tau: 12 <= tau < 24}
        )
        s = scores["ekf"]["series"]
        tau = s.t - EPOCH
        err = errors(s, world, seed)
        during, after = (tau >= 12) & (tau < 24), tau >= 27
        assert np.max(np.diff(tau[during])) < 0.05  # no gap in the estimates
        assert rms(err[during]) <= 1.5 and np.max(np.abs(err[during])) <= 4.0
        assert rms(err[after]) <= 0.5
        used = out.models["ekf"].counters()[f"{gone}_used"]
        assert used > 0.95 * 50 * (40 - 12)  # it is fused again after it came back


def test_a_lost_filter_reacquires():
    """Random back-and-forth moves faster than the seed's Q expects: readings start being
    gated out. Re-acquisition (P widened when half of the last 20 are gated) keeps the
    error bounded; without it (a window too long to fill) the filter coasts far off."""
    world = {"scenario": "ir_back_and_forth"}
    with_it, without = [], []
    for seed in range(3):
        out, scores = track(
            world, seed, {"ekf": IrTracker(), "never": IrTracker(lost_window=10**9)}, 30.0
        )
        with_it.append(scores["ekf"]["max_err_cm"])
        without.append(scores["never"]["max_err_cm"])
    assert max(with_it) <= 10.0, with_it
    assert max(without) > 1.3 * max(with_it), (with_it, without)


def test_the_seeds_q_r_study():
    """Seed lab 2: a 150x larger R smooths but lags (scenario 2); a 300x larger Q follows
    the sensors with little lag but jitters (scenario 3)."""

    def models():
        return {
            "good": IrTracker(),
            "high_r": IrTracker(r={"ir_medium": 0.1, "ir_long": 0.09}),
            "high_q": IrTracker(q=[0.6, 0.85]),
        }

    lags, jitter = {}, {}
    for seed in range(3):
        _, scores = track({"scenario": "ir_back_and_forth"}, seed, models(), 30.0)
        for k, v in scores.items():
            lags.setdefault(k, []).append(v["lag_s"])
        _, still = track({"scenario": "ir_stationary", "distance_cm": 40.0}, seed, models(), 10.0)
        for k, v in still.items():
            d = v["series"].column("distance [cm]")
            jitter.setdefault(k, []).append(float(np.std(np.diff(d))))
    mean = {k: float(np.mean(v)) for k, v in lags.items()}
    assert mean["high_r"] > mean["good"] + 0.3 and mean["high_q"] < mean["good"], mean
    shake = {k: float(np.mean(v)) for k, v in jitter.items()}
    assert shake["high_q"] > 1.5 * shake["good"] > 1.5 * shake["high_r"], shake


def test_biased_sensors_and_dropouts_degrade_gracefully():
    """A biased, mis-scaled long sensor (30 mV, 3 %) barely matters (the medium one carries
    the fix); 30 % of both sensors' readings lost still tracks within 0.7 cm RMS; a 10 mV
    offset on the medium sensor, which the fit trusts, costs about a centimetre (a real
    unit needs its own lab-1 fit: the ``fits`` setting)."""
    world = {"scenario": "ir_constant_velocity"}
    for seed in range(3):
        _, a = track(
            world,
            seed,
            {"ekf": IrTracker()},
            board_model={"ir_long": {"offset_v": 0.03, "gain": 1.03}},
        )
        assert a["ekf"]["rmse_cm"] <= 0.5
        lost = set(np.nonzero(np.random.default_rng(seed).random(4000) < 0.3)[0].tolist())
        drop = {
            n: (lambda tau, lost=lost: round(tau * 50) in lost) for n in ("ir_medium", "ir_long")
        }
        _, b = track(world, seed, {"ekf": IrTracker()}, skip=drop)
        assert b["ekf"]["rmse_cm"] <= 0.7
        _, c = track(
            world, seed, {"ekf": IrTracker()}, board_model={"ir_medium": {"offset_v": 0.01}}
        )
        assert c["ekf"]["rmse_cm"] <= 1.5


def test_a_sensor_out_of_its_range_is_not_used():
    """At 15 cm the long sensor (20-150 cm) is on the folded part of its curve: skipped."""
    out, scores = track(
        {"scenario": "ir_stationary", "distance_cm": 15.0}, 0, {"ekf": IrTracker()}, 10.0
    )
    c = out.models["ekf"].counters()
    assert c["ir_long_used"] == 0 and c["ir_long_out_of_range"] + c["saturated"] >= 450
    assert scores["ekf"]["max_err_cm"] <= 0.5


# -- the map -----------------------------------------------------------------------------

HIDDEN = {
    "scenario": "ir_plate",
    "blocks": [
        {"x": 4, "y": 7, "w": 2, "h": 2, "hot": True},  # bottom centre, hidden from both scanners
        {"x": 2, "y": 7, "w": 1, "h": 2},  # by this block from the left
        {"x": 4, "y": 5, "w": 2, "h": 1},  # and this one from the top
    ],
}


def plate(world, seed, duration, models=None):
    world = {**world, "seed": seed, "epoch": EPOCH}
    clock = Clock()
    sources = [
        ir_source(world, clock, "ir_left", SHORT, seed, scanner="left"),
        ir_source(world, clock, "ir_top", SHORT, seed, scanner="top", phase=0.005),
        *tc_sources(world, clock, seed),
    ]
    models = models or {
        "fused": OccupancyFused.make_model({}),
        "ir": OccupancyIr.make_model({}),
        "thermal": OccupancyThermal.make_model({}),
    }
    out = run(world, sources, models, clock, duration, seed=seed)
    truth = ir_truth(world)
    series = {}
    for name in models:
        t, v = out.series(name)
        series[name] = Series(name, "offline", COLUMNS, t, v, OccupancyFused)
    return truth, series


def at(series: Series, seconds: float):
    """The map made ``seconds`` after the first one."""
    maps = plate_maps(series)
    return [m for m in maps if m[0] - maps[0][0] <= seconds + 1e-6][-1]


def accuracy(truth, m) -> float:
    _, grid, _, cell = m
    return map_accuracy(grid, truth.occupancy(*grid.shape, cell))


@pytest.mark.parametrize("seed", range(4))
def test_the_map_is_95_percent_right_after_60_s_and_finds_the_hot_block(seed):
    """Default plate, the hot block put down at the start: >= 95 % of the cells right at
    60 s (measured 98-99 %); no hot block named until the heat reaches the thermocouples
    (found after 16-20 s), and from then on within one cell in every map (measured: at
    most 0.27 cm off)."""
    truth, s = plate({"scenario": "ir_plate"}, seed, 150.0)
    assert accuracy(truth, at(s["fused"], 60.0)) >= 0.95
    scores = APP.score(s["fused"], truth, EvalOptions())
    assert scores["hot_found_s"] is not None and 5.0 <= scores["hot_found_s"] <= 60.0
    maps = plate_maps(s["fused"])
    errs = [hot_error(m[2], truth) for m in maps if m[2][2] > 0]
    assert len(errs) >= len(maps) - 61 and max(errs) <= 1.0, max(errs)


def _layout(hot: tuple[int, int], cold: tuple[int, int]) -> dict:
    """The plate with a 2 x 2 hot block and a 1 x 2 cold one at these (x, y) cells."""
    return {
        "scenario": "ir_plate",
        "blocks": [
            {"x": hot[0], "y": hot[1], "w": 2, "h": 2, "hot": True},
            {"x": cold[0], "y": cold[1], "w": 1, "h": 2},
        ],
    }


# CI budget: one of each pair of physics, one layout and the warm plate in CI; the other
# four with ``pytest -m slow`` (10 s)
@pytest.mark.parametrize(
    "world",
    [
        {"scenario": "ir_plate", "loss_time_s": 75.0},
        pytest.param({"scenario": "ir_plate", "loss_time_s": 300.0}, marks=pytest.mark.slow),
        pytest.param({"scenario": "ir_plate", "alpha_cm2_s": 0.15}, marks=pytest.mark.slow),
        {"scenario": "ir_plate", "alpha_cm2_s": 0.6},
        _layout((1, 1), (5, 4)),
        pytest.param(_layout((7, 1), (3, 4)), marks=pytest.mark.slow),
        pytest.param(_layout((1, 7), (5, 2)), marks=pytest.mark.slow),
        {"scenario": "ir_plate", "hot_since_s": 300.0},
    ],
)
def test_the_map_holds_across_plate_physics_and_layouts(world):
    """The thermal model knows none of the simulator's constants (its kernel is a 1 mm
    aluminium plate's fin length): half and double the heat loss and diffusivity, other
    layouts, a plate already warm at the start (no offset calibration possible)."""
    warm = bool(world.get("hot_since_s"))
    for seed in (0, 1):
        models = {"fused": OccupancyFused.make_model({"baseline_s": 0.0})} if warm else None
        truth, s = plate(world, seed, 30.0 if warm else 120.0, models)
        scores = APP.score(s["fused"], truth, EvalOptions())
        assert scores["map_pct"] >= 95.0, scores
        assert scores["hot_err_cm"] is not None and scores["hot_err_cm"] <= 1.0, scores


def test_on_the_seeds_ambiguity_case_the_fused_map_beats_each_alone():
    """Seed lab 3, "heat source at bottom centre": the hot block sits between the two bottom
    thermocouples, and here two cold blocks hide it from both IR scanners. IR alone leaves
    its cells unknown and cannot say which block is hot; thermal alone knows nothing of
    the cold blocks or the free cells; fused, the IR's free space and the heat together map
    the plate and put the hot block where no IR could see it."""
    fused_errs, thermal_errs = [], []
    for seed in range(4):
        truth, s = plate(HIDDEN, seed, 150.0)
        fused, ir, thermal = (at(s[k], 140.0) for k in ("fused", "ir", "thermal"))
        acc = {
            k: accuracy(truth, m) for k, m in (("fused", fused), ("ir", ir), ("thermal", thermal))
        }
        assert acc["fused"] >= 0.98 and acc["fused"] >= acc["ir"] + 0.02 > acc["thermal"], acc
        hidden = fused[1][7:9, 4:6]  # the hidden block's cells: heat says occupied
        assert (hidden > 0).all() and (hidden > 0.4).sum() >= 2, hidden
        assert (ir[1][7:9, 4:6] == 0).all()  # IR alone: unknown
        assert ir[2][2] == 0.0  # IR alone: no hot block
        fused_errs.append(hot_error(fused[2], truth))
        thermal_errs.append(hot_error(thermal[2], truth))
    assert max(fused_errs) <= 1.0, fused_errs  # within one cell, where no IR saw it
    assert np.mean(fused_errs) < np.mean(thermal_errs), (fused_errs, thermal_errs)


def test_the_ir_inverse_model_frees_up_to_the_surface_and_marks_it():
    grid = OccupancyGrid(use="ir", ir={"ir_left": SHORT})
    law = grid.laws["ir_left"]
    for k in range(10):  # one fixed sensor at y = 4.5, looking along +x at 11 cm (x = 6)
        t = 100.0 + 0.02 * k
        grid.process(Sample("ir_left", "n", k + 1, t, 0.0, t, (law.volts(11.0), -5.0, 4.5, 0.0)))
    grid.process(Sample("ir_left", "n", 99, 102.5, 0.0, 102.5, (law.volts(11.0), -5.0, 4.5, 0.0)))
    row = grid.logodds()[4]
    assert (row[:6] < 0).all() and row[6] > 0 and (row[7:] == 0).all()
    assert (np.delete(grid.logodds(), 4, axis=0) == 0).all()


def test_a_long_silence_makes_one_map_not_one_per_second():
    grid = OccupancyGrid(use="ir", ir={"ir_left": SHORT})
    v = grid.laws["ir_left"].volts(11.0)
    grid.process(Sample("ir_left", "n", 1, 100.0, 0.0, 100.0, (v, -5.0, 4.5, 0.0)))
    grid.process(Sample("ir_left", "n", 2, 100.5, 0.0, 100.5, (v, -5.0, 4.5, 0.0)))
    grid.process(Sample("ir_left", "n", 3, 3700.2, 0.0, 3700.2, (v, -5.0, 4.5, 0.0)))
    rows = grid.outputs()
    assert len(rows) == 2 and [t for t, _ in rows] == [101.0, 3700.0]
    assert grid.counters()["skipped"] == 3599
    assert not grid.process(Sample("ir_left", "n", 4, 3000.0, 0.0, 3000.0, (v, -5.0, 4.5, 0.0)))
    assert grid.counters()["late"] == 1


def test_the_thermal_posterior_finds_a_source_and_waits_for_heat():
    ys, xs = np.mgrid[0:10, 0:10]
    cells = np.column_stack(((xs.ravel() + 0.5), (ys.ravel() + 0.5)))
    sensors = [(0.5, 0.5), (9.5, 0.5), (0.5, 9.5), (9.5, 9.5), (5.0, 5.0)]
    g = green(np.array(sensors), cells, 10.0, 10.0, 6.0)
    assert np.allclose(
        green(cells[:5], cells[:5], 10, 10, 6), green(cells[:5], cells[:5], 10, 10, 6).T
    )
    model = ThermalModel(cells, sensors, 10.0, 10.0)
    for k in (12, 37, 88):
        post = model.posterior(21.0 + 5.0 * g[:, k] / np.ptp(g[:, k]))  # a 5 degC spread
        assert int(np.argmax(post)) == k
    assert model.posterior([21.0, 21.2, 21.1, 21.0, 21.3]) is None  # no heat yet


@pytest.mark.parametrize(
    ("size", "cell", "tiles"), [((10, 10), 1.0, 1), ((10, 10), 0.5, 2), ((33, 17), 1.0, 3)]
)
def test_maps_travel_in_tiles_of_at_most_256_values(size, cell, tiles):
    rng = np.random.default_rng(1)
    cols, rows = round(size[0] / cell), round(size[1] / cell)
    grid = np.round(rng.normal(0, 3, (rows, cols)), 3)
    out = split(grid, cell, (1.0, 2.0, 0.5))
    assert len(out) == tiles and all(len(r) == len(HEADER) + TILE == 256 for r in out)
    for r in out:
        assert decode(encode(1, 1.0, r)).values == pytest.approx(r)
    ((t, back, hot, c),) = assemble([5.0] * len(out), out)
    assert np.array_equal(back, grid) and hot == (1.0, 2.0, 0.5) and c == cell
    assert assemble([5.0], out[:1]) == [] if tiles > 1 else True


def test_a_large_map_comes_out_as_every_tile_of_every_epoch():
    """A 20 x 20 map (0.5 cm cells): two tiles per mapping epoch, in order, through the
    model's ``outputs()``; put back together they are the model's map."""
    model = OccupancyFused.make_model({"cell_cm": 0.5})
    truth, s = plate({"scenario": "ir_plate"}, 0, 20.0, {"fused": model})
    rows = s["fused"].values
    assert {int(r[1]) for r in rows} == {2} and [int(r[0]) for r in rows[:4]] == [0, 1, 0, 1]
    maps = plate_maps(s["fused"])
    assert len(maps) == len(rows) // 2 and maps[-1][1].shape == (20, 20)
    assert np.allclose(maps[-1][1], np.round(model.logodds(), 3))


@pytest.mark.parametrize(
    ("settings", "word"),
    [
        ({"use": "sonar"}, "use"),
        ({"thermal": ["tc1"]}, "thermal"),
        ({"size_cm": [10, -1]}, "size_cm"),
        ({"p_occ": 1.0}, "p_occ"),
        ({"ir": {"ir_left": "GP2Y0A99"}}, "GP2Y0A99"),
    ],
)
def test_bad_map_settings_are_refused(settings, word):
    with pytest.raises(ValueError, match=word):
        OccupancyGrid(**settings)
    if "use" not in settings:  # use is fixed by each measure
        (problem,) = OccupancyFused.check_args({"model": settings}, "spec")
        assert word in problem
