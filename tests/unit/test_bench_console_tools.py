"""``hera bench console`` names what it lacks, in one sentence with exit code 2, before it
starts anything: Playwright and aiohttp are not in the README's install, and the browser is
a system package (the bare ``No module named 'playwright'`` said neither)."""

from __future__ import annotations

import os

import pytest

from hera import cli
from hera.bench import console


def test_a_missing_browser_is_named_with_what_to_install(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("HERA_CHROMIUM", str(tmp_path / "no-chromium"))
    with pytest.raises(ImportError) as e:
        console.check_tools()
    text = str(e.value)
    assert f"a Chromium at {tmp_path / 'no-chromium'}" in text
    assert "pip install 'hera-fusion[console]' playwright" in text
    assert "apt-get install chromium" in text and "\n" not in text

    started = []
    monkeypatch.setattr(console, "measure", lambda *a: started.append(a))
    assert cli.main(["bench", "console", "--seconds", "1"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("hera bench: the console benchmark drives the web view"), err
    assert not started  # refused before any cluster starts


@pytest.mark.skipif(not os.access("/usr/bin/chromium", os.X_OK), reason="no Chromium here")
def test_nothing_is_said_when_everything_is_there(monkeypatch):
    monkeypatch.delenv("HERA_CHROMIUM", raising=False)
    console.check_tools()  # the test extra has Playwright and aiohttp
