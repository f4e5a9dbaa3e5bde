"""Debian's headless Chromium driven by Playwright for Python, for the web view's tests.

``npx playwright install`` cannot download browsers here: tests use ``/usr/bin/chromium``
(``.ci/run`` installs Debian's ``chromium``) with a fresh profile and no background
networking. Screenshots go to :func:`artifacts_dir`, printed by the tests.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = os.environ.get("HERA_CHROMIUM", "/usr/bin/chromium")
FLAGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
ROOT = Path(__file__).resolve().parents[2]


def artifacts_dir() -> Path:
    """Where screenshots are kept: ``$HERA_ARTIFACTS`` or ``<checkout>/artifacts/console``."""
    path = Path(os.environ.get("HERA_ARTIFACTS", ROOT / "artifacts" / "console"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def launch(playwright, profile: Path, width: int = 1280, height: int = 900):
    """A headless Chromium context with a fresh profile in ``profile``."""
    if not (Path(CHROMIUM).exists() or shutil.which(CHROMIUM)):
        pytest.fail(
            f"no Chromium at {CHROMIUM}: install Debian's chromium (apt-get install chromium), "
            "as .ci/run does, or set HERA_CHROMIUM"
        )
    return playwright.chromium.launch_persistent_context(
        str(profile),
        executable_path=CHROMIUM,
        headless=True,
        args=list(FLAGS),
        viewport={"width": width, "height": height},
    )
