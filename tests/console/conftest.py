"""A headless Chromium shared by the web view's browser tests (see tests/support/browser.py)."""

from __future__ import annotations

import pytest
from browser import launch
from playwright.sync_api import sync_playwright


@pytest.fixture(scope="session")
def browser(tmp_path_factory):
    with sync_playwright() as p:
        context = launch(p, tmp_path_factory.mktemp("chromium-profile"))
        yield context
        context.close()
