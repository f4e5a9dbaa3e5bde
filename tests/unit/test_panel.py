import math

from hera.application import Application, Estimate, Panel
from hera.models.train.app import TrainApp, train_truth
from hera.models.train.measures import TrackMag
from hera.panel import estimates_panels, render_panel
from hera.plugins import AppIndex

WORLD = {"scenario": "train", "epoch": 1.0e9, "radius": 0.6, "omega": 0.84}


def test_each_estimate_is_shown_with_its_error_against_the_truth_at_its_time():
    t = 1.0e9 + 5.0
    tr = train_truth(WORLD).at(t)
    est = [tr["x [m]"] + 0.03, tr["y [m]"] - 0.04, 0.0, 0.84 * 1.02, 0.6 - 0.011]
    sample = {"name": "track_mag", "node": "c", "t": t, "values": est}
    (panel,) = estimates_panels({"track_mag": TrackMag}, [sample], WORLD, AppIndex([TrainApp()]))
    text = render_panel(panel)
    assert text.splitlines()[0] == "estimates (truth from the simulated world) on node c:"
    row = next(line for line in text.splitlines() if line.startswith("track_mag (e9)"))
    cells = row.split()[2:]  # after "track_mag (e9)": omega, err, r, err, x, y, pos err
    assert cells[1] == "+2.00"  # omega error, %
    assert cells[3] == "-1.1"  # radius error, cm
    assert float(cells[6]) == round(100 * math.hypot(0.03, 0.04), 1)  # position error, cm
    assert text.splitlines()[-1].startswith("truth")


def test_a_model_of_no_application_gets_a_plain_panel():
    class Thing:
        columns = ("a [m]",)

    sample = {"name": "thing", "node": "n", "t": 1.0, "values": [1.5]}
    (panel,) = estimates_panels({"thing": Thing}, [sample], {}, AppIndex([]))
    assert panel.rows == (("thing", "n", "a [m]=1.5"),)


def test_panels_are_aligned_columns():
    class App(Application):
        def panel(self, estimates, truth):
            return Panel("t", ("model", "value"), (("a", "1"), ("longer name", "22.5")))

    text = render_panel(App().panel([Estimate("a", "n", 0.0, {})], None))
    lines = text.splitlines()
    assert lines[0] == "t:"
    assert lines[1] == "model       value"
    assert lines[3] == "longer name  22.5"


def test_a_panel_that_raises_names_its_application_and_line_and_hides_no_other():
    """A KeyError in a user's panel() showed as 'estimates: query failed ('velocity [m/s]')'
    every second, logged nowhere, and took every other application's panel with it."""

    class Broken(Application):
        name = "cart"

        def panel(self, estimates, truth):
            return Panel("cart", ("v",), ((estimates[0].values["velocity [m/s]"],),))

    class Thing:
        columns = ("a [m]",)

    class Other:
        columns = ("a [m]",)

    broken, train = Broken(), TrainApp()
    index = AppIndex([broken, train])
    index.app_of = lambda cls: broken if cls is Thing else train if cls is TrackMag else None
    samples = [
        {"name": "thing", "node": "n", "t": 1.0, "values": [1.5]},
        {"name": "track_mag", "node": "c", "t": 1.0e9 + 5.0, "values": [0.6, 0.0, 0.0, 0.84, 0.6]},
        {"name": "other", "node": "n", "t": 1.0, "values": [2.5]},
    ]
    classes = {"thing": Thing, "track_mag": TrackMag, "other": Other}
    panels = estimates_panels(classes, samples, WORLD, index)
    titles = [p.title for p in panels]
    assert titles[0].startswith("cart: panel failed (KeyError: 'velocity [m/s]', test_panel.py:")
    assert any(t.startswith("estimates") for t in titles)  # the train's stands
    assert panels[-1].rows == (("other", "n", "a [m]=2.5"),)
