import math

from hera.models.train import truth_columns

from hera.estimates_view import render_estimates

WORLD = {"scenario": "train", "epoch": 1.0e9, "radius": 0.6, "omega": 0.84}
COLS = ("x [m]", "y [m]", "theta [rad]", "omega [rad/s]", "radius [m]")


def test_each_estimate_is_shown_with_its_error_against_the_truth_at_its_time():
    t = 1.0e9 + 5.0
    tr = truth_columns(WORLD, t)
    est = [tr["x [m]"] + 0.03, tr["y [m]"] - 0.04, 0.0, 0.84 * 1.02, 0.6 - 0.011]
    text = render_estimates(
        {"track_mag": COLS}, [{"name": "track_mag", "node": "c", "t": t, "values": est}], WORLD
    )
    row = next(line for line in text.splitlines() if line.startswith("track_mag (e9)"))
    cells = row.split()[2:]  # after "track_mag (e9)": node, omega, err, r, err, x, y, pos err
    assert cells[2] == "+2.00"  # omega error, %
    assert cells[4] == "-1.1"  # radius error, cm
    assert float(cells[7]) == round(100 * math.hypot(0.03, 0.04), 1)  # position error, cm


def test_models_without_estimates_yet_say_so():
    assert "none yet" in render_estimates({"track_mag": COLS}, [], WORLD)
