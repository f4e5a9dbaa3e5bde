"""The runtime names no application: import-linter contracts (pyproject's
``[tool.importlinter]``) and a scan of the runtime's string constants.

The contracts are checked on the layout a wheel installs (``nodes/``, ``models/``,
``sync/``, ``deploy/`` under ``hera/``), built in a temporary folder from the checkout, and
each is shown to fail on a copy with one forbidden import added.
"""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hera.plugins import AppIndex, installed_apps, known_measures

ROOT = Path(__file__).resolve().parents[2]
LINT = Path(sys.executable).with_name("lint-imports")
MAPPED = ("models", "nodes", "sync", "deploy")


def _installed_layout(dest: Path) -> Path:
    """The package as a wheel lays it out, copied into ``dest``; returns ``dest``."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "hera", dest / "hera", ignore=ignore)
    for top in MAPPED:
        shutil.copytree(ROOT / top, dest / "hera" / top, ignore=ignore)
    return dest


def _lint(tree: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(LINT), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=tree,
        env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_the_import_contracts_hold(tmp_path):
    out = _lint(_installed_layout(tmp_path))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "2 kept, 0 broken" in out.stdout


@pytest.mark.parametrize(
    ("module", "line", "broken"),
    [
        ("hera/node.py", "import hera.models.train.app", "hera.node is not allowed to import"),
        ("hera/evaluate.py", "from hera.nodes import world", "hera.evaluate is not allowed"),
        ("hera/launcher.py", "import hera.sync", "hera.launcher is not allowed to import"),
        ("hera/nodes/boards.py", "import hera.models", "hera.nodes is not allowed to import"),
        (
            "hera/models/train/tracker.py",
            "from hera.nodes.world import truth_at",
            "hera.models is not allowed to import hera.nodes",
        ),
        ("hera/newthing.py", "x = 1", "hera.newthing"),  # exhaustive: every module placed
    ],
)
def test_each_contract_catches_a_forbidden_import(tmp_path, module, line, broken):
    tree = _installed_layout(tmp_path)
    path = tree / module
    path.write_text((path.read_text() if path.exists() else "") + f"\n{line}\n")
    out = _lint(tree)
    assert out.returncode != 0 and broken in out.stdout + out.stderr, out.stdout[-3000:]


def _runtime_modules() -> list[Path]:
    """Every module of the runtime layer (pyproject's contract) and the command line."""
    from hera.spec import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in cfg["contracts"] if c["id"] == "layers")["layers"]
    names = [n.strip() for n in layers[-1].split(":")] + ["cli"]
    out = []
    for n in names:
        base = ROOT / "hera" / n
        out.extend(sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")])
    return [p for p in out if p.exists()]


def _strings(path: Path) -> list[tuple[int, str]]:
    """String constants of a module that are not docstrings, nor the values of a
    module-level ``HELP_EXAMPLES`` dict (help texts that show the shipped examples)."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in tree.body:
        target = getattr(node, "targets", [None])[0] if isinstance(node, ast.Assign) else None
        if isinstance(target, ast.Name) and target.id == "HELP_EXAMPLES":
            docs.update(id(c) for c in ast.walk(node.value) if isinstance(c, ast.Constant))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        first = body[0] if isinstance(body, list) and body else None
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
            docs.add(id(first.value))
    return [
        (n.lineno, n.value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
    ]


def _application_words() -> set[str]:
    """Names of every installed application, its measures and the simulator's scenarios."""
    from hera.nodes.world import scenarios

    words = {app.name for app in installed_apps()} | set(scenarios())
    index = AppIndex()
    for name, _target in known_measures().items():
        from hera.plugins import find_measure

        if index.app_of(find_measure(name)) is not None:
            words.add(name)
    return words


def _scan(paths: list[Path], words: set[str]) -> list[str]:
    """Every non-docstring string constant of ``paths`` naming one of ``words``."""
    pattern = re.compile(
        r"(?<![A-Za-z0-9_])(" + "|".join(map(re.escape, sorted(words))) + r")(?![A-Za-z0-9_])"
    )
    found = []
    for path in paths:
        for line, text in _strings(path):
            hit = pattern.search(text)
            if hit:
                found.append(f"{path.name}:{line}: {text!r} names {hit.group(1)!r}")
    return found


def test_the_runtime_names_no_application_model_or_scenario():
    words = _application_words()
    assert {"train", "track_gyro", "e7", "sonar", "nav", "still"} <= words  # it knows them
    found = _scan(_runtime_modules(), words)
    assert not found, "\n".join(found)


def test_the_name_scan_catches_a_named_scenario(tmp_path):
    """The scan must fail on the kind of line the runtime once had."""
    bad = tmp_path / "bad.py"
    bad.write_text('"""Docs may say train."""\n\ndef f(w):\n    return w["scenario"] == "train"\n')
    assert _scan([bad], _application_words()) == ["bad.py:4: 'train' names 'train'"]


def test_there_is_no_second_copy_of_the_package():
    out = subprocess.run(
        [sys.executable, "-c", "import hera.hera"], cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode != 0 and "No module named 'hera.hera'" in out.stderr
