"""hera eval's scoring step: an output an application cannot score is said, not crashed on."""

from __future__ import annotations

import numpy as np

from hera.application import Application, EvalOptions, Metric, Series
from hera.evaluate import Scored, _score, notes, to_json


class MaxError(Application):
    """Scores the largest value from ``after`` s on (as an application would: max() of the
    settled part, which fails on an empty part)."""

    name = "maxapp"
    metrics = (Metric("max", "max", "m"),)

    def score(self, series, truth, options):
        settled = series.t - series.t[0] >= options.after
        return {"max": float(max(series.column("x [m]")[settled]))}


def series(seconds: float, rate: float = 10.0) -> Series:
    t = 1000.0 + np.arange(0.0, seconds, 1.0 / rate)
    return Series("model", "n1", ("x [m]",), t, np.arange(len(t), dtype=float)[:, None])


def test_an_output_long_enough_is_scored():
    scores, note = _score(MaxError(), series(5.0), None, EvalOptions(after=3.0))
    assert note is None and scores == {"max": 49.0}


def test_a_series_shorter_than_after_is_not_scored_and_says_why():
    s = series(2.0)
    scores, note = _score(MaxError(), s, None, EvalOptions(after=3.0))
    assert scores == {}
    assert note == (
        "model on n1: not scored: 20 estimates over 1.9 s, and scores count from 3 s after "
        "the first (--after)"
    )
    scores, note = _score(MaxError(), series(0.0), None, EvalOptions(after=3.0))
    assert scores == {} and "0 estimates over 0.0 s" in note


def test_an_application_that_fails_to_score_is_named_and_the_rest_goes_on():
    class Broken(MaxError):
        name = "broken"

        def score(self, series, truth, options):
            raise KeyError("x [m]")

    scores, note = _score(Broken(), series(5.0), None, EvalOptions())
    assert scores == {}
    assert note == "model on n1: not scored: application 'broken' failed: KeyError('x [m]')"
    row = Scored(series(5.0), Broken(), "model", scores, None, note)
    assert notes([row]) == [note]
    assert to_json([row])[0]["note"] == note
