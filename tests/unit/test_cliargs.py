"""Numeric options of every command line are checked by argparse before anything starts:
one sentence naming the option and the value, exit code 2 (``hera.cliargs``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from harness import run_hera

from hera import cliargs

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("kind", "good", "bad", "says"),
    [
        (cliargs.positive, [("0.5", 0.5), ("3", 3.0)], ["0", "-1"], "must be a number > 0"),
        (cliargs.non_negative, [("0", 0.0), ("2.5", 2.5)], ["-0.1"], "must be a number >= 0"),
        (cliargs.count, [("1", 1), ("3000", 3000)], ["0", "-3"], "must be a whole number >= 1"),
        (cliargs.non_negative_int, [("0", 0), ("7", 7)], ["-1"], "must be a whole number >= 0"),
        (
            cliargs.port,
            [("0", 0), ("65535", 65535)],
            ["65536", "-1"],
            "must be a port from 0 to 65535",
        ),
        (cliargs.number, [("-2.5", -2.5), ("0", 0.0)], [], ""),
    ],
)
def test_each_kind_takes_its_range_and_names_a_value_outside_it(kind, good, bad, says):
    for text, value in good:
        assert kind(text) == value and type(kind(text)) is type(value)
    for text in bad:
        with pytest.raises(cliargs.argparse.ArgumentTypeError) as e:
            kind(text)
        assert str(e.value) == f"{says}, got {text!r}"
    for text in ("nan", "inf", "fast", "1.5x", ""):
        with pytest.raises(cliargs.argparse.ArgumentTypeError) as e:
            kind(text)
        assert repr(text) in str(e.value)


BAD_COMMAND_LINES = [
    ("up train --duration -1", "--duration: must be a number > 0, got '-1'"),
    ("up train --web 70000", "--web: must be a port from 0 to 65535, got '70000'"),
    ("eval x --settle nan", "--settle: must be a finite number, got 'nan'"),
    ("campaign train nemesis --seed -2", "--seed: must be a whole number >= 0, got '-2'"),
    ("echo obs1 --count 0", "--count: must be a whole number >= 1, got '0'"),
    ("bench kalman --steps many", "--steps: must be a whole number, got 'many'"),
    ("bench scale --seconds 0", "--seconds: must be a number > 0, got '0'"),
]


@pytest.mark.parametrize(("argv", "stderr_end"), BAD_COMMAND_LINES)
def test_a_bad_number_on_a_command_line_is_one_sentence_and_exit_code_2(tmp_path, argv, stderr_end):
    out = run_hera(tmp_path, *argv.split())  # a run directory made by mistake: tmp_path
    assert out.returncode == 2
    assert out.stderr.splitlines()[-1].endswith(f"error: argument {stderr_end}"), out.stderr
    assert out.stdout == "" and list(tmp_path.iterdir()) == []


def _bare_numeric_options(path: Path, root: Path) -> list[str]:
    """``add_argument(..., type=float | int)`` calls in one file: unchecked numbers."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            found += [
                f"{path.relative_to(root)}:{node.lineno}"
                for kw in node.keywords
                if kw.arg == "type" and isinstance(kw.value, ast.Name)
                and kw.value.id in ("float", "int")
            ]  # fmt: skip
    return found


def test_no_command_line_takes_an_unchecked_number():
    sources = [p for top in ("hera", "nodes", "models", "sync") for p in (ROOT / top).rglob("*.py")]
    bare = [hit for p in sources for hit in _bare_numeric_options(p, ROOT)]
    assert bare == [], f"numeric options without a hera.cliargs type: {bare}"


def test_the_reader_of_the_sources_finds_a_bare_number(tmp_path):
    planted = tmp_path / "planted.py"
    planted.write_text(
        "import argparse\n\nap = argparse.ArgumentParser()\n"
        'ap.add_argument("--n", type=int)\nap.add_argument("--x", type=float, default=1.0)\n'
        'ap.add_argument("--ok", type=str)\n'
    )
    assert _bare_numeric_options(planted, tmp_path) == ["planted.py:4", "planted.py:5"]


def test_lists_of_checked_values_name_the_first_bad_one():
    counts = cliargs.comma_separated(cliargs.whole_at_least(4))
    assert counts("8, 16,32") == [8, 16, 32]
    with pytest.raises(cliargs.argparse.ArgumentTypeError) as e:
        counts("8,3,2")
    assert str(e.value) == "must be a whole number >= 4, got '3'"
    words = cliargs.comma_separated(cliargs.one_of("grid", "staggered"))
    assert words("staggered") == ["staggered"]
    with pytest.raises(cliargs.argparse.ArgumentTypeError) as e:
        words("grid,")
    assert str(e.value) == "must be one of grid, staggered, got ''"
