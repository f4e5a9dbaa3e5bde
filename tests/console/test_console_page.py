"""The page draws every kind of application view (plane, attitude, grid) and stays sound
when the server stops answering: a stub console behind the real server, in Chromium."""

from __future__ import annotations

import math
import time

from browser import artifacts_dir

from hera.console.server import ConsoleServer

PANELS = [
    {
        "title": "a plane",
        "kind": "plane",
        "data": {
            "shapes": [{"circle": [0, 0, 1]}, {"line": [[-1, -1], [1, 1]]}],
            "points": [
                {"label": "est", "x": 0.5, "y": 0.2, "heading": 1.0},
                {"label": "truth", "x": 0.4, "y": 0.3, "truth": True},
            ],
        },
    },
    {  # a scene a few centimetres wide (the 3-D position's, no shapes): not zoomed to them
        "title": "a small plane",
        "kind": "plane",
        "data": {
            "shapes": [],
            "points": [{"label": "p", "x": 0.30, "y": 0.10}, {"label": "q", "x": 0.31, "y": 0.11}],
        },
    },
    {
        "title": "attitudes",
        "kind": "attitude",
        "data": {
            "bodies": [
                {"label": "ahrs a", "roll": 0.2, "pitch": -0.1, "yaw": 1.2},
                {"label": "truth", "roll": 0.0, "pitch": 0.0, "yaw": 1.0, "truth": True},
            ],
            "north": 0.5,  # rad from +x: the headings are north - yaw, clockwise from N
        },
    },
    {
        "title": "occupancy",
        "kind": "grid",
        "data": {
            "origin": [0, 0],
            "cell": 0.5,
            "min": 0,
            "max": 1,
            "values": [[0.1, 0.9, None], [0.5, 0.0, 1.0]],
            "points": [{"label": "robot", "x": 0.5, "y": 0.5}],
        },
    },
]


class StubConsole:
    """Answers like :class:`hera.console.state.Console` for one made-up stream."""

    def __init__(self) -> None:
        self.polls = 0
        self.fail = False

    def poll(self, streams, since):
        self.polls += 1
        if self.fail:
            raise RuntimeError("the view lost its cluster")
        now = time.time()
        points = [
            [
                int(t * 10),
                t,
                1,
                [math.sin(t)],
                [math.sin(t) - 0.1],
                [math.sin(t) + 0.1],
                [math.sin(t) + 0.01],
            ]
            for t in (now - 3 + k / 10 for k in range(30))
            if since is None or t >= since
        ]
        return {
            "time": now,
            "bucket_s": 0.1,
            "cluster": {
                "name": "stub",
                "uptime_s": 1.0,
                "sync": [],
                "problems": [],
                "events": [{"t": now, "node": "a", "kind": "inject", "text": "crash obs1"}],
                "nodes": [
                    {
                        "name": "a",
                        "state": "up",
                        "pid": 1,
                        "restarts": 0,
                        "measures": {},
                        "rate_hz": 10.0,
                        "rejected": 0,
                        "peers": 0,
                    }
                ],
            },
            "streams": [
                {
                    "stream": "s/a",
                    "name": "s",
                    "node": "a",
                    "columns": ["v [m]"],
                    "model": True,
                    "label": "s",
                    "truth": ["v [m]"],
                    "rate_hz": 10.0,
                }
            ],
            "data": {"s/a": {"points": points}} if "s/a" in streams else {},
            "panels": PANELS,
        }


def test_the_page_draws_every_kind_of_view_and_says_when_the_server_is_gone(browser):
    stub = StubConsole()
    server = ConsoleServer(stub, "127.0.0.1", 0)
    url = server.start()
    page = None
    try:
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        for kind in ("plane", "attitude", "grid"):
            page.wait_for_selector(f"#panels .panel[data-kind='{kind}']", timeout=5000)
        planes = page.locator("#panels .panel[data-kind='plane']")
        assert planes.nth(0).get_attribute("data-bounds") == "-1.200,1.200,-1.200,1.200"
        # 0.5 m at least, about the points: 0.305 +/- 0.25, 0.105 +/- 0.25
        assert planes.nth(1).get_attribute("data-bounds") == "0.055,0.555,-0.145,0.355"
        attitude = page.locator("#panels .panel[data-kind='attitude']")
        assert attitude.get_attribute("data-points") == "2"
        # 0.5 - 1.2 rad = -40.1 deg, 0.5 - 1.0 rad = -28.6 deg: the needles' headings
        assert attitude.get_attribute("data-headings") == "319.9,331.4"
        page.wait_for_function("(window.hera.points['s/a'] || 0) >= 30", timeout=5000)
        assert "crash obs1" in page.inner_text("#events")
        path = artifacts_dir() / "panels.png"
        page.screenshot(path=str(path), full_page=True)
        print(f"screenshot: {path}")
        stub.fail = True  # the server answers 500: the page says so and keeps its plots
        page.wait_for_function("window.hera.errors > 0", timeout=5000)
        assert page.inner_text("#live") == "no answer from the view server"
        # the nodes and plots are greyed, the summary says since when (it kept "1/1 up")
        assert page.evaluate("document.body.classList.contains('stale')")
        assert page.inner_text("#summary").startswith("no answer since ")
        assert page.locator("#charts .chart").count() == 1
        stub.fail = False
        page.wait_for_function("document.querySelector('#live').className === 'ok'")
        assert not page.evaluate("document.body.classList.contains('stale')")
        assert page.inner_text("#summary").startswith("1/1 nodes up")
        bad = page.request.get(url + "api/poll?since=yesterday")
        assert bad.status == 400 and "since" in bad.text()
        assert page.request.get(url + "static/secret.py").status == 404
        assert not errors, errors
    finally:
        if page is not None:
            page.close()  # however the test ends: an open page goes on polling
        server.close()
