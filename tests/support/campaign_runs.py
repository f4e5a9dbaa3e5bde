"""Running ``hera campaign`` from tests as a user does, and reading its verdicts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from harness import cluster_env

from hera.campaign import checkers, history
from hera.campaign.runner import processes_of
from hera.campaign.schema import CHECKERS

MUST_PASS = CHECKERS  # every checker of the campaign, none skipped


def run_campaign(tmp_path: Path, *args: str, timeout: float = 600) -> tuple[int, Path, str]:
    """``hera campaign ARGS --run-dir DIR``; its exit code, directory and output."""
    folder = tmp_path / "campaign"
    cmd = [sys.executable, "-m", "hera", "campaign", *args, "--run-dir", str(folder)]
    out = subprocess.run(
        cmd, env=cluster_env(tmp_path), capture_output=True, text=True, timeout=timeout
    )
    assert not processes_of(folder), "processes of the campaign outlived it"
    return out.returncode, folder, out.stdout + out.stderr


def verdicts(folder: Path) -> dict[str, checkers.Verdict]:
    return {v.name: v for v in checkers.run_all(history.load(folder))}


def assert_complete_report(folder: Path) -> None:
    md = (folder / "report.md").read_text()
    for section in ("## Verdict", "## Timeline", "## Faults", "## Checkers"):
        assert section in md
    assert "![timeline](timeline.png)" in md
    html = (folder / "report.html").read_text()
    assert "<img src='timeline.png'" in html and "<table>" in html
    png = (folder / "timeline.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def assert_passed(
    code: int, folder: Path, out: str, names: tuple[str, ...] = MUST_PASS
) -> dict[str, checkers.Verdict]:
    """The campaign exited 0 and each of ``names`` passed (not skipped); its verdicts."""
    v = verdicts(folder)
    assert code == 0, out + "\n".join(f"{k}: {x.summary}" for k, x in v.items())
    for name in names:
        assert v[name].passed and not v[name].skipped, (name, v[name].summary)
    return v
