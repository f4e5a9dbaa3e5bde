"""3-D position from three sonars (thesis ch. 7.2): our EKF on raw ranges and the thesis's
e10, offline over several seeds (the models the live measures run, fed the simulated
MaxSonars' readings in turn: 20 deg cone, 1-inch rounding, noise), and their bookkeeping.

Targets (issue 11), worst seed measured in the README: ours <= 2 cm RMSE on ``target3d``
(worst 1.16); with a sonar lost, the two observed axes within 3 cm (RMS over the loss), the
lost axis's reported standard deviation growing, all back within 2 s of its return. At the
data sheet's 2.5 cm of noise the issue's 2 cm is not met at the published 0.2 s age (an
oracle told which axis moves gets 1.71-1.95 cm there, README "Known limits"): that case is
held at its measured level.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim3d import SONARS, run_position

from hera.models.position3d.sonars import beam_points, parse_sonars
from hera.models.position3d.thesis import ThesisPosition
from hera.models.position3d.tracker import RangeTracker
from hera.store import Sample

SEEDS = range(5)


def test_rmse_on_target3d_is_within_2_cm_on_every_seed_and_beats_e10():
    ours = [run_position(seed).rmse_cm() for seed in SEEDS]
    thesis = [run_position(seed, thesis=True).rmse_cm() for seed in SEEDS[:2]]
    assert max(ours) <= 2.0, np.round(ours, 2)
    assert min(thesis) > 2 * max(ours), (thesis, ours)  # slant ranges read as axial ones


def test_at_2_5_cm_of_noise_ours_holds_its_level_beats_e10_and_gains_from_a_longer_lag():
    """The MaxSonar data sheet's 2.5 cm as white noise (the simulator's default is 1 cm):
    measured 2.15-2.40 cm over seeds 0-7 at the default 0.2 s age, 1.76-1.92 at ``lag =
    0.6``, e10 5.95-6.50 (``python tests/support/apps3d_figures.py noise position``)."""
    noisy = {"noise_m": 0.025}
    ours = [run_position(seed, sonar_model=noisy).rmse_cm() for seed in SEEDS]
    thesis = [run_position(seed, sonar_model=noisy, thesis=True).rmse_cm() for seed in SEEDS[:2]]
    older = [
        run_position(seed, sonar_model=noisy, settings={"lag": 0.6}).rmse_cm() for seed in SEEDS[:3]
    ]
    assert max(ours) <= 2.6, np.round(ours, 2)
    assert min(thesis) > 2 * max(ours), (thesis, ours)
    # about four readings of each axis after the estimate instead of one: 0.48-0.51 cm better
    assert all(o - a >= 0.3 for o, a in zip(ours[:3], older, strict=True)), (ours, older)


def _tilted() -> dict:
    """Three sonars off the axes, each pointing at the middle of the target's moves."""
    c = np.array((1.25, 1.25, 1.25))
    out = {}
    for node, pos in (
        ("s1", (-0.55, 0.35, 0.6)),
        ("s2", (1.9, -0.6, 0.8)),
        ("s3", (0.6, 1.8, 3.0)),
    ):
        d = c - np.array(pos)
        out[node] = (pos, tuple(d / np.linalg.norm(d)))
    return out


def test_sonars_at_arbitrary_poses_track_within_2_cm():
    rmse = [run_position(seed, sonars=_tilted()).rmse_cm() for seed in range(3)]
    assert max(rmse) <= 2.0, rmse  # 1.24-1.39 over five seeds
    with pytest.raises(ValueError, match="not along an axis"):
        ThesisPosition(sonars={n: {"position": list(p), "direction": list(d)}
                               for n, (p, d) in _tilted().items()})  # fmt: skip


# CI budget: sonar_x in CI, the other two with ``pytest -m slow`` (the same code, 10 s)
@pytest.mark.parametrize(
    "node",
    [
        "sonar_x",
        pytest.param("sonar_y", marks=pytest.mark.slow),
        pytest.param("sonar_z", marks=pytest.mark.slow),
    ],
)
def test_a_lost_sonar_leaves_two_axes_accurate_and_says_the_third_is_unknown(node):
    """The sonar gone for 1.5 s (a SIGKILLed node is back in about 1 s), at twelve phases of
    the motion (its own axis moving, or another): the observed axes' RMS over the loss stays
    within 3 cm, the lost axis's reported std grows at least threefold, and from 2 s after
    the sonar's return the position is back within its usual 2 cm RMSE with its usual std.
    Longer losses while the lost axis moves cost the others more, through the slant ranges:
    up to 4 cm at 2 s (README)."""
    i = "xyz".index(node[-1])
    others = [k for k in range(3) if k != i]
    for start in np.arange(18.0, 36.0, 1.5):
        end = start + 1.5
        r = run_position(1, down={node: (start, end)}, duration=45.0)
        gone = (r.t >= start) & (r.t < end)
        before = (r.t >= start - 3.0) & (r.t < start)
        after = (r.t >= end + 2.0) & (r.t < end + 8.0)
        rms = np.sqrt(np.mean(r.err[gone][:, others] ** 2, axis=0))
        assert rms.max() <= 0.03, (node, start, rms)
        assert r.std[gone, i].max() >= 3 * np.median(r.std[before, i]), (node, start)
        assert r.rmse_cm(after) <= 2.0, (node, start, r.rmse_cm(after))
        assert np.median(r.std[after, i]) <= 1.5 * np.median(r.std[before, i]), (node, start)


def test_sonar_settings_are_checked_and_name_what_is_wrong():
    good = {"position": [0, 0, 0], "direction": [1, 0, 0]}
    with pytest.raises(ValueError, match="sonars must be a table"):
        parse_sonars([])
    with pytest.raises(ValueError, match="sonars.a needs direction"):
        parse_sonars({"a": {"position": [0, 0, 0]}})
    with pytest.raises(ValueError, match="sonars.a.position must be 3"):
        parse_sonars({"a": {**good, "position": [0, 0]}})
    with pytest.raises(ValueError, match="sonars.a.direction must not be zero"):
        parse_sonars({"a": {**good, "direction": [0, 0, 0]}})
    with pytest.raises(ValueError, match="unknown keys"):
        parse_sonars({"a": {**good, "angle": 3}})
    with pytest.raises(ValueError, match="q_acc must be a number > 0"):
        RangeTracker(sonars={"a": good}, q_acc=0.0)


def test_beam_points_need_three_directions():
    sonars = parse_sonars(
        {n: {"position": list(p), "direction": list(d)} for n, (p, d) in SONARS.items()}
    )
    p = beam_points({"sonar_x": 1.95, "sonar_y": 1.95, "sonar_z": 1.95}, sonars, 0.05)
    assert np.allclose(p, (1.0, 1.0, 1.0))
    assert beam_points({"sonar_x": 1.95, "sonar_y": 1.95}, sonars, 0.05) is None


def _reading(node, t, r, seq=1):
    return Sample("sonar", node, seq, t, 0.0, 0.0, (r, 0.0, 0.0))


def test_the_tracker_starts_once_its_sonars_place_the_target_and_ignores_strangers():
    cfg = {n: {"position": list(p), "direction": list(d)} for n, (p, d) in SONARS.items()}
    m = RangeTracker(sonars=cfg)
    assert not m.process(_reading("sonar_x", 0.00, 1.95))
    assert not m.process(_reading("sonar_y", 0.05, 1.95))
    assert m.estimate() is None
    assert not m.process(_reading("stranger", 0.07, 1.0))
    assert m.process(_reading("sonar_z", 0.10, 1.95))
    t, v = m.estimate()
    assert t == 0.10 and np.allclose(v[:3], (1.0, 1.0, 1.0), atol=1e-9)
    assert m.counters()["other"] == 1
    assert not m.process(_reading("sonar_x", -1.0, 1.95))  # older than max_lag
    assert m.counters()["late"] == 1
    # a jolt (a hand in the beam) is gated out
    assert m.process(_reading("sonar_x", 0.3, 0.8))
    assert m.counters()["rejected"] == 1


def test_thesis_model_reads_each_sonar_as_its_axis():
    cfg = {n: {"position": list(p), "direction": list(d)} for n, (p, d) in SONARS.items()}
    m = ThesisPosition(sonars=cfg)
    for k, node in enumerate(("sonar_x", "sonar_y", "sonar_z")):
        m.process(_reading(node, 0.05 * k, 1.95))
    _, v = m.estimate()
    assert np.allclose(v[:3], (1.0, 1.0, 1.0), atol=1e-9)  # z looks down from z = 3
    assert all(0 < s < 1 for s in v[3:])
    big = v[5]
    for k in range(3):  # only x keeps reading: the other axes' variance grows by Q a step
        m.process(_reading("sonar_x", 0.2 + 0.05 * k, 1.95))
    assert m.estimate()[1][5] > big
    assert math.isclose(m.estimate()[1][3] ** 2, m.kf.P[0, 0])


def test_numba_and_numpy_backends_give_the_same_track():
    from hera.estimation import active_backend, set_backend

    was = active_backend()
    try:
        runs = {}
        for backend in ("numpy", "numba"):
            set_backend(backend)
            r = run_position(4, duration=15.0, down={"sonar_y": (10.0, 11.5)})
            runs[backend] = np.concatenate((r.est, r.std), axis=1)
    finally:
        set_backend(was)
    assert runs["numpy"].shape == runs["numba"].shape
    assert np.abs(runs["numpy"] - runs["numba"]).max() < 1e-9
