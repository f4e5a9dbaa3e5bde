"""``hera --help`` lists every command with a one-line summary, each command's help ends
with an example of that command, and ``hera --version`` names the versions a bug report
needs, read from the one place the version is written (``hera.__version__``)."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from importlib.metadata import version

import hera
from hera.cli import VERSIONS_OF, _parser, version_line


def _commands() -> dict[str, argparse.ArgumentParser]:
    (sub,) = (a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_the_top_level_help_lists_every_command_with_a_summary():
    top = _parser().format_help()
    commands = _commands()
    assert len(commands) >= 20
    for name in commands:
        line = re.search(rf"^    {re.escape(name)}\s+(\S.*)$", top, re.M)
        assert line, f"'hera --help' does not list {name!r} with a summary"


def test_every_command_has_a_description_and_an_example_of_itself():
    for name, parser in _commands().items():
        text = parser.format_help()
        assert parser.description and parser.description.endswith("."), name
        example = text.split("example:\n", 1)
        assert len(example) == 2, f"'hera {name} --help' has no example"
        assert example[1].lstrip().startswith(f"hera {name}"), (name, example[1])


def test_version_names_hera_python_and_the_core_dependencies():
    out = subprocess.run(
        [sys.executable, "-m", "hera", "--version"], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip()
    assert line == version_line()
    assert line.startswith(f"hera {hera.__version__} (Python {sys.version.split()[0]}; ")
    for dist in VERSIONS_OF:
        assert f"{dist} {version(dist)}" in line


def test_the_installed_version_is_the_one_hera_declares():
    assert version("hera-fusion") == hera.__version__
