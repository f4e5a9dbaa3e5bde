"""The terminal view fits the terminal: no line longer than its width, no more lines than
its height, the nodes, the sync leader and one line per model first."""

from __future__ import annotations

import pytest

from hera.measures.app import Observers
from hera.models.train.app import TrainApp, train_truth
from hera.models.train.measures import (
    BilaterationMeasure,
    OmegaAcc,
    TrackBilat,
    TrackGyro,
    TrackMag,
    TrackRadius,
    TrackSonar,
)
from hera.panel import estimates_panels
from hera.plugins import AppIndex
from hera.statusview import render_node, render_view

WORLD = {"scenario": "train", "epoch": 1.0e9, "radius": 0.6, "omega": 0.84}
MODELS = {
    "bilateration": BilaterationMeasure,
    "omega_acc": OmegaAcc,
    "track_bilat": TrackBilat,
    "track_sonar": TrackSonar,
    "track_gyro": TrackGyro,
    "track_radius": TrackRadius,
    "track_mag": TrackMag,
}


def _measure(rate: float, restarts: int = 0, state: str = "running") -> dict:
    return {
        "state": state,
        "restarts": restarts,
        "rate_hz": rate,
        "jitter_ms": {"p99": 1.61},
        "counters": {"fused": 2047, "late": 0, "beam_edge": 57},
        "last_error": "ValueError: bad" if restarts else None,
    }


def _train_status() -> tuple[dict, dict]:
    status, launcher = {}, {}
    for i, node in enumerate(("computer", "nav_1", "sonar_1", "sonar_2")):
        ms = {m: _measure(20.0) for m in MODELS} if node in ("computer", "nav_1") else {}
        ms["sonar" if node.startswith("sonar") else "mag"] = _measure(7.7)
        status[node] = {
            "pid": 20817 + i,
            "measures": ms,
            "rejected": {},
            "peers": ["computer", "nav_1", "sonar_1", "sonar_2"],
            "rss_mb": 61.2,
            "sync": {
                "groups": {
                    "sonar": {
                        "role": "leader" if i == 2 else "follower",
                        "leader": "sonar_1",
                        "epoch": 3,
                        "holder": "sonar_2/sonar" if i == 2 else None,
                    }
                }
            },
        }
        launcher[node] = {"pid": 20817 + i, "state": "up", "restarts": 0, "age_s": 30.0}
    return status, launcher


def _train_panels() -> list:
    t = 1.0e9 + 20.0
    truth = train_truth(WORLD).at(t)
    samples = []
    for name, cls in MODELS.items():
        values = [truth.get(c, 0.0) * 1.001 for c in cls.columns]
        samples.append({"name": name, "node": "computer", "t": t, "values": values})
    return estimates_panels(MODELS, samples, WORLD, AppIndex([TrainApp()]))


@pytest.mark.parametrize(("width", "height"), [(80, 24), (120, 40)])
def test_the_train_fits_the_terminal(width, height):
    status, launcher = _train_status()
    text = render_view(
        "train",
        status,
        launcher,
        uptime=31,
        run_dir="hera-run/train-20261130",
        panels=_train_panels(),
        width=width,
        height=height,
    )
    lines = text.splitlines()
    assert len(lines) <= height and max(map(len, lines)) <= width, text
    assert lines[0].startswith("cluster train: 4/4 nodes up, 31 s")
    for node in status:
        assert any(line.startswith(node) for line in lines), node
    assert "sync sonar: leader sonar_1 (epoch 3), slot held by sonar_2/sonar" in lines
    models = [line.split()[0] for line in lines if line.startswith(tuple(MODELS))]
    assert models == list(MODELS)  # one line per model, in the ladder's order
    assert lines[-1].startswith("truth")
    assert not any(line.endswith("~") for line in lines)  # nothing had to be cut


def test_a_small_terminal_cuts_and_counts_what_does_not_fit():
    status, launcher = _train_status()
    text = render_view("train", status, launcher, panels=_train_panels(), width=60, height=14)
    lines = text.splitlines()
    assert len(lines) == 14 and max(map(len, lines)) <= 60
    assert lines[-1].startswith("... ") and "more lines" in lines[-1]


def test_problems_and_starting_nodes_are_said():
    status, launcher = _train_status()
    status["nav_1"]["measures"]["mag"] = _measure(0.0, restarts=2, state="backoff")
    status["nav_1"]["rejected"] = {"malformed": 3}
    del status["sonar_2"]
    launcher["sonar_2"]["age_s"] = 1.0
    text = render_view("train", status, launcher, width=120, height=40)
    assert text.splitlines()[0].startswith("cluster train: 3/4 nodes up (1 starting)")
    assert "problems: nav_1/mag backoff x2 (ValueError: bad); nav_1 rejected malformed=3" in text


def test_a_measure_in_trouble_is_a_problem_while_it_lasts():
    status, launcher = _train_status()
    mag = status["nav_1"]["measures"]["mag"]
    mag["trouble"] = "board not answering (I2C bus error)"
    text = render_view("train", status, launcher, width=120, height=40)
    assert "problems: nav_1/mag board not answering (I2C bus error)" in text
    detail = render_node({**status["nav_1"], "node": "nav_1", "cluster": "train"})
    assert "now: board not answering (I2C bus error)" in detail
    mag["trouble"] = None
    assert "problems" not in render_view("train", status, launcher, width=120, height=40)


def test_the_observers_count_shows_per_node():
    samples = [
        {"name": f"obs{j}", "node": f"n{i}", "t": 1.0, "values": [20.0 - (i == 3)]}
        for i in range(1, 6)
        for j in range(1, 5)
    ]
    from hera.measures.counter import Counter

    shown = {f"obs{j}": Counter for j in range(1, 5)}
    (panel,) = estimates_panels(shown, samples, {}, AppIndex([Observers()]))
    assert panel.rows[0] == ("n1", "20 20 20 20") and panel.rows[2] == ("n3", "19 19 19 19")


def test_one_node_in_detail():
    status, _ = _train_status()
    text = render_node({**status["nav_1"], "node": "nav_1", "cluster": "train", "uptime_s": 9})
    assert text.splitlines()[0] == "node nav_1 of cluster train: pid 20818, up 9 s, 61 MB"
    assert "track_gyro" in text and "beam_edge=57" in text


def test_one_node_says_what_its_store_takes():
    status, _ = _train_status()
    base = {**status["nav_1"], "node": "nav_1", "cluster": "train", "uptime_s": 9}
    for takes, shown in ((None, "every sample"), ([], "nothing"), (["obs*", "nav"], "obs*, nav")):
        text = render_node({**base, "store": {**base.get("store", {}), "takes": takes}})
        assert f"takes: {shown}" in text.splitlines()
