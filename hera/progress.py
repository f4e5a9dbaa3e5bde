"""Progress of long commands (``hera replay``, ``eval``, ``export``) on stderr.

On a terminal one line is rewritten in place (at most 5 times a second); otherwise (a log,
a pipe) a line is printed at most every :data:`LOG_EVERY_S` seconds, and always at the end,
with the elapsed time. ``HERA_PROGRESS=0`` silences it. A :class:`Progress` is the
``progress(done, total)`` callback the long functions take.
"""

from __future__ import annotations

import os
import sys
import time
from typing import IO

TTY_EVERY_S = 0.2
LOG_EVERY_S = 5.0


class Progress:
    """``progress(done, total)`` callback printing ``label: 42% (420/1000)``."""

    def __init__(self, label: str, stream: IO[str] | None = None) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.quiet = os.environ.get("HERA_PROGRESS", "1") == "0"
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.started = time.monotonic()
        self._last_print = float("-inf")
        self._last: tuple[int, int] | None = None
        self._open_line = False

    def __call__(self, done: int, total: int) -> None:
        self._last = (done, total)
        now = time.monotonic()
        if self.quiet or now - self._last_print < (TTY_EVERY_S if self.tty else LOG_EVERY_S):
            return
        self._last_print = now
        self._show(done, total)

    def _show(self, done: int, total: int, end: bool = False) -> None:
        pct = 100.0 * done / total if total else 100.0
        text = f"{self.label}: {pct:3.0f}% ({done}/{total})"
        if end:
            text += f" in {time.monotonic() - self.started:.1f} s"
        if self.tty:
            self.stream.write("\r" + text + ("\n" if end else ""))
            self._open_line = not end
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def say(self, text: str) -> None:
        """Print one line of news (``hera replay --smooth``: a model left out), below the
        progress line on a terminal."""
        if self.quiet:
            return
        if self._open_line:
            self.stream.write("\n")
            self._open_line = False
        self.stream.write(f"  {text}\n")
        self.stream.flush()

    def finish(self) -> None:
        """Print the final line (once), if anything was counted."""
        if self._last is not None and not self.quiet:
            self._show(*self._last, end=True)
            self._last = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()
