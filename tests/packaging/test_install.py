"""``pip install .`` (not editable) into a fresh venv gives a working ``hera`` under one
namespace: nodes/, models/ and sync/ become hera.nodes, hera.models, hera.sync."""

from __future__ import annotations

import subprocess
import sys
import venv
from pathlib import Path

from hera.spec import tomllib

ROOT = Path(__file__).resolve().parents[2]


def test_every_source_package_is_listed_in_pyproject():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    mapping = {src: dst for dst, src in cfg["package-dir"].items()}
    found = set()
    for top in ("hera", "nodes", "models", "sync"):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top).parts
            found.add(".".join((mapping[top], *rel)))
    assert found == listed, f"add to / remove from [tool.setuptools] packages: {found ^ listed}"


def test_wheel_installs_into_a_fresh_venv(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(wheels),
            str(ROOT),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    wheel = next(wheels.glob("hera_fusion-*.whl"))
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    subprocess.run(
        [py, "-m", "pip", "install", "-q", str(wheel)], check=True, capture_output=True, timeout=600
    )
    probe = (
        "import importlib.util, hera, hera.nodes, hera.models, hera.sync, hera.estimation\n"
        "assert all(importlib.util.find_spec(m) is None for m in ('nodes', 'models', 'sync'))\n"
        "print(hera.nodes.__file__)\n"
    )
    out = subprocess.run(
        [py, "-c", probe], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert str(env_dir) in out.stdout and str(ROOT) not in out.stdout
    measures = subprocess.run(
        [env_dir / "bin" / "hera", "measures"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert measures.returncode == 0 and "counter" in measures.stdout
    # hera up starts nodes with `python -m hera`, which puts the current folder first on
    # sys.path: from the repo root the source hera/ is found before the installed one and
    # must still reach hera.models, hera.nodes and hera.sync
    load = "from hera.plugins import find_measure as f; print(f('track_mag'), f('sonar'))"
    from_root = subprocess.run(
        [py, "-c", load], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert from_root.returncode == 0, from_root.stderr[-2000:]
    assert "TrackMag" in from_root.stdout and "Sonar" in from_root.stdout
