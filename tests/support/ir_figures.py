"""Print the offline figures of the seed-000 models that the README quotes.

    python tests/support/ir_figures.py        (about 20 s)

Each line: what was measured and its min - max over seeds 0-3 (the offline runs of
tests/models/test_ir_models.py: simulated boards drive the very model objects).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).parent), str(Path(__file__).parents[1] / "models")]

from ir_offline import EPOCH  # noqa: E402
from test_ir_models import (  # noqa: E402
    APP,
    HIDDEN,
    LONG,
    PAIR,
    SHORT,
    TRIO,
    WITH_SHORT,
    EvalOptions,
    IrTracker,
    accuracy,
    at,
    errors,
    hot_error,
    plate,
    track,
)

SEEDS = range(4)


def span(values) -> str:
    v = [x for x in values if x is not None]
    return f"{min(v):.2f} - {max(v):.2f}" if v else "-"


def study() -> dict:
    return {
        "good": IrTracker(),
        "high_r": IrTracker(r={"ir_medium": 0.1, "ir_long": 0.09}),
        "high_q": IrTracker(q=[0.6, 0.85]),
    }


def tracking() -> None:
    cv = {"scenario": "ir_constant_velocity"}
    rm = [track(cv, s, {"e": IrTracker()}, 30.0)[1]["e"] for s in SEEDS]
    print(f"constant velocity 20-60 cm: RMSE cm {span(r['rmse_cm'] for r in rm)}")
    far = {"scenario": "ir_constant_velocity", "near_cm": 25.0, "far_cm": 75.0}
    rf = [track(far, s, {"e": IrTracker()}, 30.0)[1]["e"] for s in SEEDS]
    print(f"constant velocity 25-75 cm: RMSE cm {span(r['rmse_cm'] for r in rf)}")
    still = {"scenario": "ir_stationary", "distance_cm": 70.0}
    pi = [track(still, s, {"e": IrTracker(x0=[50.0, 0.0])}, 10.0)[1]["e"] for s in SEEDS]
    print(f"poor initial guess: within 1 cm after s {span(r['converge_s'] for r in pi)}")
    for name, kw in (("start mixture", {}), ("wide prior alone", {"v0_still": 0})):
        starts = [
            track(still, s, {"e": IrTracker(x0=[50.0, 0.0], **kw)}, 6.0, parts)[1]["e"]
            for s in range(60)
            for parts in (PAIR, PAIR[::-1])
        ]
        conv = np.array([9.0 if r["converge_s"] is None else r["converge_s"] for r in starts])
        print(
            f"poor initial guess, {name}, seeds 0-59 x both sensor orders: within 1 cm in"
            f" <= 1 s {(conv <= 1.0).sum()} of {len(conv)}, 95th percentile"
            f" {np.percentile(conv, 95):.2f} s, worst {conv.max():.2f} s"
        )
    s24 = {"scenario": "ir_stationary", "distance_cm": 24.0}
    trio = [track(s24, s, {"e": IrTracker(sensors=WITH_SHORT)}, 30.0, TRIO) for s in SEEDS]
    frac = [o.models["e"].counters()["ir_short_gated"] / 1500 for o, _ in trio]
    worst = span(r["e"]["max_err_cm"] for _, r in trio)
    print(f"short at 24 cm (with medium, long): gated {span(frac)}, max error cm {worst}")
    pair = {"ir_long": LONG, "ir_short": SHORT}
    parts = (("ir_long", LONG), ("ir_short", SHORT))
    ls = []
    for s in SEEDS:
        gated = {"g": IrTracker(sensors=pair), "o": IrTracker(sensors=pair, gate=0.0)}
        ls.append(track(s24, s, gated, 30.0, parts)[1])
    print(
        f"long + short at 24 cm: max error cm gated {span(r['g']['max_err_cm'] for r in ls)},"
        f" without the gate {span(r['o']['max_err_cm'] for r in ls)}"
    )
    for gone in ("ir_long", "ir_medium"):
        rows = []
        for s in SEEDS:
            _, r = track(cv, s, {"e": IrTracker()}, skip={gone: lambda tau: 12 <= tau < 24})
            ser = r["e"]["series"]
            err = errors(ser, cv, s)
            m = (ser.t - EPOCH >= 12) & (ser.t - EPOCH < 24)
            rows.append(float(np.sqrt(np.mean(err[m] ** 2))))
        print(f"{gone} silent 12-24 s: RMSE cm meanwhile {span(rows)}")
    bf = [track({"scenario": "ir_back_and_forth"}, s, study(), 30.0)[1] for s in SEEDS]
    for k in ("good", "high_r", "high_q"):
        rmse, lag = span(r[k]["rmse_cm"] for r in bf), span(r[k]["lag_s"] for r in bf)
        print(f"back-and-forth, {k}: RMSE cm {rmse}, lag s {lag}")


def maps() -> None:
    dflt = [plate({"scenario": "ir_plate"}, s, 150.0) for s in SEEDS]
    fused = span(100 * accuracy(t, at(x["fused"], 60.0)) for t, x in dflt)
    ir = span(100 * accuracy(t, at(x["ir"], 60.0)) for t, x in dflt)
    print(f"cold plate: cells right at 60 s % fused {fused}, IR alone {ir}")
    sc = [APP.score(x["fused"], t, EvalOptions()) for t, x in dflt]
    found, err = span(s["hot_found_s"] for s in sc), span(s["hot_err_cm"] for s in sc)
    print(f"cold plate: hot block found after s {found}, error at 150 s cm {err}")
    hid = [plate(HIDDEN, s, 150.0) for s in SEEDS]
    for k in ("fused", "ir", "thermal"):
        acc = span(100 * accuracy(t, at(x[k], 140.0)) for t, x in hid)
        err = span(hot_error(at(x[k], 140.0)[2], t) for t, x in hid)
        print(f"hidden hot block, {k}: cells right % {acc}, hot block error cm {err}")


if __name__ == "__main__":
    tracking()
    maps()
