"""The ToF height models (seed 001): the seed's equations, the range geometry, the sensor
health, outliers and faults, and accuracy over several seeds and worlds, offline (the
simulated boards on a fake clock driving the very model objects the measures run)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from appsim import MOUNTS, Fault, run_model, tof_boards, tof_samples, tof_scores
from parallel import run_each

from hera.estimation import set_backend
from hera.models.tof.health import DEAD, INCONSISTENT, INVALID, OK, STUCK, SensorHealth
from hera.models.tof.height import TofHeight
from hera.models.tof.kinematics import ca_matrices, cv_matrices
from hera.models.tof.plane import range_jacobian, range_of
from hera.nodes import geometry as gm
from hera.nodes.tof.sim import true_range
from hera.store import Sample

DESK = {"scenario": "desk"}


def reading(node, t, d, status=0, mount=None, seq=1, rates=None):
    """A sample of the ``vl53l1`` measure; its noisy rates differ reading to reading."""
    x, y = mount if mount is not None else MOUNTS[node.split("_")[-1]]
    rates = rates if rates is not None else (0.3, 5.0 + 0.01 * math.sin(1000.0 * t))
    return Sample("vl53l1", node, seq, t, 0.0, 0.0, (d, *rates, float(status), x, y))


def test_the_seeds_process_models():
    dt = 0.01
    F, Q = cv_matrices(dt, 0.1)
    assert F.tolist() == [[1.0, 0.0], [dt, 1.0]]
    assert pytest.approx(0.01 * np.outer([dt, dt * dt / 2], [dt, dt * dt / 2])) == Q
    F, Q = ca_matrices(dt, 1.0)
    assert F.tolist() == [[1.0, 0.0, 0.0], [dt, 1.0, 0.0], [dt * dt / 2, dt, 1.0]]
    g = np.array([dt, dt * dt / 2, dt**3 / 6])  # seed task 4: piecewise white jerk
    assert pytest.approx(np.outer(g, g)) == Q


def test_the_range_model_is_the_simulators_geometry_and_its_jacobian_is_right():
    rng = np.random.default_rng(0)
    for _ in range(50):
        h, p, r = rng.uniform(0.05, 0.5), rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4)
        x, y = rng.uniform(-0.05, 0.05, 2)
        q = gm.from_euler(r, p, rng.uniform(-3, 3))  # yaw changes nothing
        assert range_of(h, p, r, x, y) == pytest.approx(true_range((0, 0, h), q, (x, y)))
        eps = 1e-7
        num = [
            (range_of(h + eps, p, r, x, y) - range_of(h - eps, p, r, x, y)) / (2 * eps),
            (range_of(h, p + eps, r, x, y) - range_of(h, p - eps, r, x, y)) / (2 * eps),
            (range_of(h, p, r + eps, x, y) - range_of(h, p, r - eps, x, y)) / (2 * eps),
        ]
        assert range_jacobian(h, p, r, x, y) == pytest.approx(num, rel=1e-6, abs=1e-8)


def test_seed_kinds_are_the_seeds_filter_at_100_hz():
    """tof_ca fed one reading every 0.1 s on the 10 ms grid gives what the seed's code does:
    a predict every 0.01 s, an update on every tenth (task 3, gate off)."""
    m = TofHeight(kind="ca", gate=None)
    rng = np.random.default_rng(1)
    truth = [0.1 + 0.05 * math.sin(0.7 * k * 0.1) for k in range(60)]
    zs = [v + rng.normal(0, 0.003) for v in truth]
    m.process(reading("tof_centre", 0.0, zs[0]))
    x, P = m.imm.x.copy(), m.imm.P.copy()
    F, Q = ca_matrices(0.01, 0.1)
    H, R = np.array([[0.0, 0.0, 1.0]]), 0.003**2
    for k in range(1, 60):
        for _ in range(10):
            x, P = F @ x, F @ P @ F.T + Q
        S = (H @ P @ H.T)[0, 0] + R
        K = (P @ H.T / S).ravel()
        x = x + K * (zs[k] - x[2])
        P = (np.eye(3) - np.outer(K, H)) @ P
        m.process(reading("tof_centre", round(k * 0.1, 10), zs[k], seq=k + 1))
        assert m.estimate()[1][0] == pytest.approx(x[2], abs=1e-9)
        assert pytest.approx(P, abs=1e-12) == m.imm.P


def test_between_readings_the_forecast_carries_the_state_without_changing_it():
    m = TofHeight(kind="ca", gate=None)
    for k in range(30):
        m.process(reading("tof_centre", k * 0.1, 0.1 + 0.02 * k * 0.1, seq=k + 1))
    t, v = m.estimate()
    h, vel, acc = v[0], v[1], v[2]
    ft, fv = m.forecast(t + 0.05)
    assert ft == pytest.approx(t + 0.05)
    assert fv[0] == pytest.approx(h + vel * 0.05 + acc * 0.05**2 / 2)
    assert m.estimate() == (t, v)
    assert m.forecast(t - 1.0)[0] == t  # never before the state


def test_the_centre_sensor_models_use_only_the_centre_sensor():
    m = TofHeight(kind="cv")
    assert not m.process(reading("tof_left", 0.0, 0.3))
    assert m.estimate() is None
    assert m.process(reading("tof_centre", 0.01, 0.12))
    assert m.estimate()[1][0] == pytest.approx(0.12)


def test_invalid_statuses_and_outliers_are_not_fused():
    m = TofHeight(kind="plane")
    t = 0.0
    for k in range(60):
        for i, node in enumerate(("tof_left", "tof_centre", "tof_right")):
            t = k * 0.1 + i * 0.03
            m.process(reading(node, t, 0.15 + 0.001 * ((k + i) % 3 - 1), seq=k + 1))
    before = m.estimate()[1][0]
    for status in (1, 2, 4, 7):  # invalid rangings carry garbage distances
        assert not m.process(reading("tof_centre", t + 0.01 * status, 0.02, status, seq=100))
    assert not m.process(reading("tof_left", t + 0.1, 0.35, seq=101))  # a 20 cm outlier
    assert m.estimate()[1][0] == pytest.approx(before, abs=0.0005)
    other = Sample("vl53l1", "tof_centre", 102, t + 0.2, 0, 0, (0.15, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0))
    assert not m.process(other)  # not a vl53l1 reading (7 values): refused, counted
    c = m.counters()
    assert c["invalid"] == 5 and c["gated"] == 1 and c["relocks"] == 0
    assert m.estimate()[1][-1] == 0.0  # no sensor faulty


def test_a_move_faster_than_the_model_relocks_instead_of_ignoring_the_board():
    m = TofHeight(kind="ca")  # the seed's sigma_j = 0.1: a stiff model
    for k in range(30):
        m.process(reading("tof_centre", k * 0.1, 0.10, seq=k + 1))
    for k in range(30, 36):
        m.process(reading("tof_centre", k * 0.1, 0.30, seq=k + 1))
    assert m.counters()["relocks"] == 1
    assert m.estimate()[1][0] == pytest.approx(0.30, abs=0.005)
    assert m.counters()["code vl53l1@tof_centre"] == OK  # one sensor cannot blame itself


def test_health_codes():
    h = SensorHealth(stuck_repeats=4, dead_s=0.5, invalid_run=3, gated_run=5)
    keys = [("vl53l1", n) for n in ("tof_left", "tof_centre", "tof_right")]
    vals = {k: [0.1, 0.3, 5.0, 0.0, *MOUNTS[k[1].split("_")[1]]] for k in keys}
    for i in range(4):
        for k in keys:
            v = list(vals[k])
            if k[1] != "tof_right":
                v[2] += 0.01 * i  # the right one repeats itself exactly
            h.observe(k, i * 0.1, v)
    assert [h.sensors[k].code for k in keys] == [OK, OK, STUCK]
    assert h.mask() == 0b100  # bit 2: the rightmost sensor
    s = h.observe(keys[0], 0.4, [0.1, 0.3, 5.0, 2.0, -0.03, -0.02])
    assert not h.usable(s)
    for i in range(2):
        h.observe(keys[0], 0.5 + i * 0.1, [0.1, 0.3, 5.0 + i, 2.0, -0.03, -0.02])
    assert h.sensors[keys[0]].code == INVALID and h.mask() == 0b100  # invalid is no fault
    for _ in range(5):
        h.fused(h.sensors[keys[1]], accepted=False)
    assert h.sensors[keys[1]].code == INCONSISTENT and h.mask() == 0b110
    h.fused(h.sensors[keys[1]], accepted=True)
    h.tick(1.3)
    assert [h.sensors[k].code for k in keys] == [DEAD, DEAD, DEAD]
    c = h.counters()
    assert (c["stuck events"], c["inconsistent events"], c["dead events"]) == (1, 1, 3)
    assert c["recoveries"] >= 1 and c["code vl53l1@tof_right"] == DEAD


# -- offline accuracy over several seeds and worlds ---------------------------------------------

WORLDS = [
    (0, {}),
    (1, {"height": 0.15, "fast_s": 0.6}),
    (2, {"tilt_deg": 10.0, "roll_deg": 8.0, "slow_s": 5.0}),
]


def test_three_sensor_height_meets_the_targets_with_margin():
    """Issue 12: RMSE <= 1.5 mm when still, <= 4 mm over the whole scenario (sigma 3 mm);
    asserted with 15 % margin, in each of WORLDS (run on every core). The seed's filters are
    far from it (README table)."""
    calls = [
        dict(
            kinds=["plane", "fused"] if seed == 0 else ["plane"],
            world={**DESK, **world, "seed": seed},
            duration=60.0,
            seed=seed,
        )
        for seed, world in WORLDS
    ]
    for (seed, _), res in zip(WORLDS, run_each(tof_scores, calls), strict=True):
        plane = res["plane"]
        assert plane["still_mm"] <= 1.3, (seed, plane)
        assert plane["rmse_mm"] <= 3.4, (seed, plane)
        assert plane["lag_ms"] <= 20.0, (seed, plane)
        assert plane["tilt_deg"] <= 3.0, (seed, plane)
        assert plane["counters"]["relocks"] == 0, seed
        if "fused" in res:  # beats the seed's task 4
            assert res["fused"]["rmse_mm"] > 1.5 * plane["rmse_mm"], seed


def test_a_fast_move_from_still_is_caught_once():
    """Three sensors read together (the seed's board: readings 100 ms apart): a fast move
    that starts while the filter holds the board still outruns its gate; the filter catches
    it (two readings in a row refused, consistent with a move: an onset; or a relock). The
    catch must not take the board for still again (no second catch at once) and the
    estimate follows within 0.15 s. Measured before the relock's motion spread: relocks
    every 100 ms and 54 mm off."""
    from hera.models.tof.app import HEIGHT, desk_truth

    world = {**DESK, "seed": 0}
    truth = desk_truth(world)
    caught, worst = [], 0.0
    for draw in (8, 9, 10, 11):
        feed = tof_samples(world, 17.0, draw, phases={"left": 0.0, "centre": 0.002, "right": 0.004})
        model, i, times = TofHeight(kind="plane"), 0, []
        for k in range(1700):
            now = 0.01 * k
            while i < len(feed) and feed[i][0] <= now:
                before = model.counts["relocks"] + model.counts["onsets"]
                model.process(feed[i][1])
                if model.counts["relocks"] + model.counts["onsets"] > before:
                    times.append(feed[i][1].t)
                i += 1
            est = model.forecast(now)
            if est is not None and any(r + 0.15 <= now <= r + 0.5 for r in times):
                worst = max(worst, abs(est[1][0] - truth.at(now)[HEIGHT]))
        assert np.all(np.diff(times) > 0.3), (draw, times)
        caught += times
    assert caught  # the case arose
    assert worst <= 0.03, worst


def _fast_move(t: float, t0: float, drop: float = 0.18, span: float = 0.7) -> float:
    """The height (m) of a level board held at 0.25 m, moved down by ``drop`` m in ``span``
    s from ``t0`` with minimum jerk (the desk scenario's fast move: up to 2.1 m/s^2)."""
    tau = min(1.0, max(0.0, (t - t0) / span))
    return 0.25 - drop * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)


def _still_then_moving(t0: float, end: float, noise: dict[float, float | None]):
    """Readings of the three sensors in turn (33 ms apart) of :func:`_fast_move` from
    ``t0``; ``noise``: the error (m) of the reading at a time (rounded to ms; None: an
    invalid status), else a small alternating one."""
    out, k, t = [], 0, 0.0
    nodes = ("tof_left", "tof_centre", "tof_right")
    while t < end:
        err = noise.get(round(t, 3), 0.001 * (-1) ** k)
        status = 2 if err is None else 0
        d = _fast_move(t, t0) + (err or 0.0)
        out.append(reading(nodes[k % 3], t, d, status, seq=k // 3 + 1))
        k += 1
        t = round(k / 30.0, 6)
    return out


def test_a_move_that_starts_while_still_is_fused_after_two_readings_not_relocked():
    """The live failure this guards against (a CI run: 52 mm off for 0.13 s, RMSE 4.1 mm
    against 4): a fast move starts while the board is held still, a reading early in it reads
    high, and the next ones are all refused by every mode (the moving modes restart from the
    still one's certain zero motion at every reading). Two refused readings in a row that a
    move explains are an onset: both are fused, 33 ms before a relock would be."""
    readings = _still_then_moving(4.0, 4.6, {4.1: 0.006, 4.133: None})
    m = TofHeight(kind="plane")
    caught = None
    for r in readings:
        m.process(r)
        if caught is None and m.counts["onsets"]:
            caught = r.t
    c = m.counters()
    assert c["relocks"] == 0 and c["onsets"] == 1, c
    assert caught is not None and caught < 4.3
    t, v = m.estimate()
    assert v[0] == pytest.approx(_fast_move(t, 4.0), abs=0.004)  # on the board again
    assert v[1] < -0.2  # and moving with it


def test_a_lone_outlier_while_still_is_no_onset():
    """An outlier 3 cm off between good readings of a still board: refused, nothing else;
    two in a row that no move explains (+3 cm, then -3 cm): refused too."""
    for noise in ({2.0: 0.03}, {2.0: 0.03, 2.033: -0.03}):
        m = TofHeight(kind="plane")
        for r in _still_then_moving(10.0, 3.0, noise):
            m.process(r)
        c = m.counters()
        assert c["onsets"] == 0 and c["relocks"] == 0 and c["gated"] == len(noise), (noise, c)
        assert m.estimate()[1][0] == pytest.approx(0.25, abs=0.001)


@pytest.mark.parametrize(
    ("seed", "sensor", "kind"),
    [(0, "centre", "stuck"), (1, "left", "stuck"), (2, "right", "dropout")],
)
def test_with_one_sensor_stuck_or_dead_it_is_reported_within_1_s_and_height_holds(
    seed, sensor, kind
):
    """Issue 12: one sensor stuck, <= 5 mm and the fault reported within 1 s (a dropout
    that lasts: the sensor is dead)."""
    at = 15.0
    world = {**DESK, "seed": seed}
    feed = tof_samples(world, 45.0, seed, [Fault(sensor, at, kind)])
    model = TofHeight(kind="plane")
    series = run_model(model, feed, duration=45.0)
    from hera.application import EvalOptions, Series
    from hera.models.tof.app import desk_truth, score_height

    mask = series.column("faulty [mask]")
    bit = {"left": 1, "centre": 2, "right": 4}[sensor]
    hit = np.nonzero((series.t >= at) & (mask.astype(int) & bit > 0))[0]
    assert len(hit) and series.t[hit[0]] - at <= 1.0, "fault not reported within 1 s"
    assert not np.any(mask[series.t < at])  # no false alarm before
    after = series.t >= at
    late = Series("m", "n", series.columns, series.t[after], series.values[after])
    got = score_height(late, desk_truth(world), EvalOptions(after=0.0))
    assert got["rmse_mm"] <= 4.7, got
    code = model.counters()[f"code vl53l1@tof_{sensor}"]
    assert code == (STUCK if kind == "stuck" else DEAD)


def test_biased_and_mis_scaled_sensors_degrade_by_their_bias_only():
    """Offsets of 1 mm and scale errors of 0.3 % (sigma, per sensor): the filter stays
    sound, and the error grows by no more than the sensors' own errors (at 0.3 m, the
    highest the board goes)."""
    board = {"offset_sigma_m": 0.001, "scale_sigma": 0.003}
    for seed in (3,):
        res = tof_scores(["plane"], {**DESK, "seed": seed}, 60.0, seed, board=board)["plane"]
        worst = 1000.0 * max(
            abs(b.offset) + 0.3 * abs(b.scale) for b in tof_boards(DESK, seed, board).values()
        )
        assert worst > 0.5  # the sensors are biased
        assert res["still_mm"] <= 1.3 + worst, (res, worst)
        assert res["rmse_mm"] <= 3.4 + worst, (res, worst)
        assert res["counters"]["relocks"] == 0


def test_numpy_and_numba_give_the_same_heights():
    pytest.importorskip("numba")
    feed = tof_samples({**DESK, "seed": 5}, 15.0, 5)
    out = {}
    try:
        for backend in ("numpy", "numba"):
            set_backend(backend)
            for kind in ("ca", "plane"):
                out[backend, kind] = run_model(TofHeight(kind=kind), feed, forecast_hz=None)
    finally:
        set_backend("auto")
    for kind in ("ca", "plane"):
        a, b = out["numpy", kind], out["numba", kind]
        assert len(a) == len(b) > 100
        assert np.max(np.abs(a.values - b.values)) < 1e-9


def test_imm_mixing_gives_a_mode_its_prior_for_states_another_lacks():
    """Granstrom, Willett & Bar-Shalom 2015: mode 0's component mixed into mode 1 carries
    entry[(0, 1)] on top of P_0; mode 0's own mixing and the means are unchanged."""
    from hera.estimation import KalmanFilter, mixture
    from hera.models.tof.imm import Imm, transition

    F, Q = np.eye(2), np.zeros((2, 2))
    xs = [np.array([0.0, 1.0]), np.array([0.5, 1.2])]
    Ps = [np.diag([1e-6, 1e-4]), np.diag([0.3, 2e-4])]
    E = np.diag([4.0, 0.0])
    mu = np.array([0.9, 0.1])
    filters = [KalmanFilter(x, P, F, Q) for x, P in zip(xs, Ps, strict=True)]
    plain = Imm(filters, mu, [0.5, 0.5])
    wide = Imm([KalmanFilter(f.x, f.P, F, Q) for f in filters], mu, [0.5, 0.5], {(0, 1): E})
    plain.mix(0.1)
    wide.mix(0.1)
    Pi = transition([0.5, 0.5], 0.1)
    w1 = Pi[:, 1] * mu / (Pi.T @ mu)[1]
    x1, P1 = mixture(xs, [Ps[0] + E, Ps[1]], w1)
    assert pytest.approx(x1) == wide.filters[1].x and pytest.approx(P1) == wide.filters[1].P
    assert pytest.approx(plain.filters[1].x) == wide.filters[1].x
    assert wide.filters[1].P[0, 0] == pytest.approx(plain.filters[1].P[0, 0] + w1[0] * 4.0)
    assert pytest.approx(plain.filters[0].P) == wide.filters[0].P
    with pytest.raises(ValueError, match=r"entry \(1, 1\)"):
        Imm(wide.filters, mu, [0.5, 0.5], {(1, 1): E})


@pytest.mark.parametrize("onset", [[[1.0, 0.1]], [[0, 0], [0, 0], [1, 0.1], [-1, 0.1]], [1, 2]])
def test_a_bad_onset_setting_is_refused_with_its_value(onset):
    with pytest.raises(ValueError, match=r"onset .* one \[a, v\] pair"):
        TofHeight(kind="plane", onset=onset)
