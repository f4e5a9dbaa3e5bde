"""The README shows what the code does: the spec reference is the declarations', and the
"Write your own application" example is the package the tests install and run."""

from __future__ import annotations

import re
from pathlib import Path

from hera.spec import reference

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def test_the_spec_reference_is_generated_from_the_declarations():
    body = re.search(r"<!-- spec-reference[^>]*-->\n(.*?)\n<!-- /spec-reference -->", README, re.S)
    assert body is not None, "the README lost its spec reference markers"
    assert body.group(1) == reference(), "put hera.spec.reference() between the markers"


def test_the_application_example_is_the_tested_package():
    shown = dict(re.findall(r"<!-- file: (\S+) -->\n`[^`]+`:\n\n```\w+\n(.*?)```\n", README, re.S))
    assert set(shown) == {
        "tests/plugin_app/pyproject.toml",
        "tests/plugin_app/hera_thermo/measures.py",
        "tests/plugin_app/hera_thermo/app.py",
        "tests/plugin_app/hera_thermo/thermo.toml",
    }
    for rel, text in shown.items():
        assert (ROOT / rel).read_text() == text, f"README's copy of {rel} is out of date"
