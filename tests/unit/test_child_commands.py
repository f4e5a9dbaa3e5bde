"""Child processes run the installed hera, not the working folder's: ``python -m`` and
``python -c`` put the working folder first on ``sys.path``, so run from a source checkout
beside a non-editable install (the README's ``pip install .`` then ``hera ...`` in the
clone) they imported the checkout's ``hera``, which refuses to load there. The benchmarks
of the AHRS (``hera bench ahrs --cpu``) and of the bus (its zenoh peer) failed that way."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hera import launcher

ROOT = str(Path(launcher.__file__).resolve().parents[1])


@pytest.fixture
def checkout_like(tmp_path, monkeypatch):
    """A working folder whose ``hera`` refuses to be imported, with this hera on the path
    as an install's site-packages is (after the working folder)."""
    (tmp_path / "hera").mkdir()
    (tmp_path / "hera" / "__init__.py").write_text("raise ImportError('the decoy hera')\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYTHONPATH", ROOT)
    return tmp_path


def _run(cmd: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60)


def test_the_decoy_is_what_python_dash_m_imports(checkout_like):
    """The fixture reproduces the failure (else the tests below prove nothing)."""
    out = _run([sys.executable, "-m", "hera", "--version"])
    assert out.returncode != 0 and "the decoy hera" in out.stderr


def test_node_command_runs_the_installed_hera(checkout_like):
    out = _run(launcher.node_command("--version"))
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("hera ")


def test_module_command_runs_a_module_of_the_installed_hera_with_its_arguments(checkout_like):
    out = _run(launcher.module_command("hera", "--version"))
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("hera ")
    bad = _run(launcher.module_command("hera", "no-such-command"))
    assert bad.returncode == 2 and "no-such-command" in bad.stderr
