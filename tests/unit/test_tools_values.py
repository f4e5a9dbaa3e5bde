"""Values given on the command line (``hera args set``): JSON when it parses, else the text,
and refused when it starts as JSON but is not (a mistyped object is not stored as a text)."""

from __future__ import annotations

import pytest

from hera.tools import parse_value


@pytest.mark.parametrize(
    ("text", "value"),
    [("3", 3), ("2.5", 2.5), ("[1, 2]", [1, 2]), ('{"a": 1}', {"a": 1}), ('"x"', "x"),
     ("true", True), ("hello", "hello"), ("hello world", "hello world"), ("", "")],
)  # fmt: skip
def test_json_when_it_parses_else_the_text(text, value):
    assert parse_value(text) == value


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("{bad json", "Expecting property name enclosed in double quotes at character 1"),
        ("[1, 2", "Expecting ',' delimiter at character 5"),
        ('"open', "Unterminated string starting at character 0"),
        ("  {x", "Expecting property name enclosed in double quotes at character 3"),
    ],
)
def test_a_text_that_starts_as_json_but_is_not_is_refused(text, why):
    with pytest.raises(ValueError) as e:
        parse_value(text)
    assert str(e.value) == (
        f"value {text!r} is not JSON ({why}): fix it, or give a text that does not start "
        "with '{', '[' or '\"'"
    )
