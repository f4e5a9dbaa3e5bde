"""The web view's HTTP server (aiohttp): the page, its script, and one JSON endpoint.

- ``GET /``: the page (``static/index.html``), no build step, nothing loaded from the
  network; ``GET /static/<file>``: its script and style;
- ``GET /api/poll?streams=NAME/NODE,...&since=T``: :meth:`hera.console.state.Console.poll`
  (the cluster, the streams, the downsampled points of the chosen streams from epoch time
  ``T``, the applications' panels). The page asks about four times a second.

It listens on loopback only (127.0.0.1 or ::1): the page can start nothing, but it shows
everything, and another address needs TLS and an operator certificate, which this version
does not have. :class:`ConsoleServer` runs it on its own thread and event loop (``hera up
--web``); :func:`serve` runs ``hera view``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hera.console.state import Console
from hera.spec import load_spec

log = logging.getLogger("hera.console")

STATIC = Path(__file__).with_name("static")
FILES = {"app.js": "text/javascript", "style.css": "text/css"}


def check_host(host: str) -> str:
    """``host`` if it is a loopback address; ValueError saying why not otherwise."""
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        raise ValueError(f"web view address {host!r} is not an IP address") from None
    if not loopback:
        raise ValueError(
            f"the web view serves loopback addresses only (127.0.0.1, ::1), not {host!r}: "
            "another address needs TLS with an operator certificate, which this version "
            "does not have (reach it through an SSH tunnel)"
        )
    return host


def make_app(console: Console | Callable[[], Console]) -> Any:
    """The aiohttp application of the web view of ``console`` (or of whichever console a
    callable gives at each request: ``hera view`` swaps it when the cluster restarts)."""
    current = console if callable(console) else lambda: console
    from aiohttp import web

    async def index(request: web.Request) -> web.Response:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def static(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in FILES:
            raise web.HTTPNotFound(text=f"no file {name!r}")
        return web.FileResponse(
            STATIC / name, headers={"Content-Type": FILES[name], "Cache-Control": "no-store"}
        )

    async def poll(request: web.Request) -> web.Response:
        streams = [s for s in request.query.get("streams", "").split(",") if s]
        since_text = request.query.get("since")
        try:
            since = float(since_text) if since_text else None
        except ValueError:
            raise web.HTTPBadRequest(
                text=f"since must be epoch seconds, got {since_text!r}"
            ) from None
        return web.json_response(current().poll(streams, since), dumps=json.dumps)

    app = web.Application()
    app.router.add_get("/", index)
    app.router.add_get("/static/{name}", static)
    app.router.add_get("/api/poll", poll)
    return app


class ConsoleServer:
    """The web view served on its own thread (see the module docstring)."""

    def __init__(self, console: Console, host: str = "127.0.0.1", port: int = 8765) -> None:
        check_host(host)
        try:
            import aiohttp  # noqa: F401
        except ImportError:
            raise ImportError(
                "the web view needs aiohttp: pip install 'hera-fusion[console]'"
            ) from None
        self.console = console
        self.host, self.port = host, port
        self.url: str | None = None
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="console-web", daemon=True)

    def start(self, timeout: float = 10.0) -> str:
        """Start serving; return the page's URL (OSError if the port is taken)."""
        self._thread.start()
        self._ready.wait(timeout)
        if self._error is not None:
            raise self._error
        if self.url is None:
            raise OSError(f"the web view did not start within {timeout:g} s")
        return self.url

    def _run(self) -> None:
        from aiohttp import web

        asyncio.set_event_loop(self._loop)
        runner = web.AppRunner(make_app(lambda: self.console), access_log=None)
        try:
            self._loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, self.host, self.port)
            self._loop.run_until_complete(site.start())
            host, port = runner.addresses[0][:2]
            self.url = f"http://{'[' + host + ']' if ':' in host else host}:{port}/"
        except BaseException as e:
            self._error = e
            self._ready.set()
            return
        self._ready.set()
        try:
            self._loop.run_forever()
        finally:
            self._loop.run_until_complete(runner.cleanup())
            self._loop.close()

    def close(self) -> None:
        """Stop serving (the console stays open)."""
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)


def _run_of(run_dir: Path) -> tuple[int, int] | None:
    """What identifies the run behind ``run_dir`` (a folder, or the ``hera-run/<cluster>``
    link to the latest): its ``cluster.json``'s inode and time, None while there is none."""
    try:
        st = (Path(run_dir) / "cluster.json").stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns


def serve(run_dir: Path, host: str, port: int, duration: float | None = None) -> int:
    """``hera view``: serve the web view of the cluster of ``run_dir`` until Ctrl-C or
    ``duration`` s. A cluster started again there (``hera up --run-dir`` the same folder, or
    a new run the ``hera-run/<cluster>`` link now points to, with new ports) is followed:
    the view joins it with a fresh console, the page keeps its address."""
    check_host(host)
    run = _run_of(run_dir)
    console = Console(load_spec(Path(run_dir) / "cluster.json"), run_dir)
    server = ConsoleServer(console, host, port)
    try:
        url = server.start()
        print(f"web view of cluster {console.spec.name!r} on {url} (Ctrl-C to stop)", flush=True)
        end = None if duration is None else time.monotonic() + duration
        while end is None or time.monotonic() < end:
            time.sleep(0.2)
            now = _run_of(run_dir)
            if now is None or now == run:
                continue
            try:
                fresh = Console(load_spec(Path(run_dir) / "cluster.json"), run_dir)
            except Exception as e:  # cluster.json half written: the next look reads it
                log.debug("the new run is not readable yet: %s", e)
                continue
            run, old, server.console = now, server.console, fresh
            old.close()
            print(f"web view: following the new run of {fresh.spec.name!r}", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
        server.console.close()
    return 0
