"""The code runs on the oldest Python the package accepts (``requires-python``), although CI
runs one interpreter: vermin reads every source file for the standard-library modules,
functions and syntax it uses, and names any that need a newer Python (a module that only
newer Pythons have, such as ``tomllib``, must stand behind a version test or an import
fallback, as ``hera.spec`` does)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from hera.spec import tomllib

ROOT = Path(__file__).resolve().parents[2]
VERMIN = Path(sys.executable).with_name("vermin")
SOURCES = ("hera", "nodes", "models", "sync", "tests")


def _oldest_python() -> str:
    """The lowest version ``requires-python`` admits, e.g. "3.10"."""
    spec = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    match = re.fullmatch(r">=\s*(\d+\.\d+)", spec)
    assert match, f"requires-python {spec!r} is not of the form '>=X.Y'"
    return match.group(1)


def _vermin(*paths: Path) -> subprocess.CompletedProcess:
    target = f"-t={_oldest_python()}-"  # the trailing '-': that version or older must do
    return subprocess.run(
        [str(VERMIN), "-q", target, "--no-tips", "--violations", "--eval-annotations"]
        + [str(p) for p in paths],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_every_source_file_runs_on_the_oldest_python_the_package_accepts():
    out = _vermin(*(ROOT / s for s in SOURCES))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]


def test_a_module_only_newer_pythons_have_is_found(tmp_path):
    (tmp_path / "guarded.py").write_text(
        "import sys\n\nif sys.version_info >= (3, 11):\n    import tomllib\n"
        "else:\n    import tomli as tomllib\n"
    )
    assert _vermin(tmp_path).returncode == 0
    (tmp_path / "bare.py").write_text("import tomllib\n")
    out = _vermin(tmp_path)
    assert out.returncode != 0
    assert "bare.py" in out.stdout and "'tomllib' module requires" in out.stdout
    assert "guarded.py" not in out.stdout
