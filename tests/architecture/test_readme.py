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


def test_every_spec_the_readme_shows_is_one_hera_up_takes():
    """A TOML block with a ``[cluster]`` table is a whole spec: it must pass every check a
    spec passes before start (the annotated one once declared 'obs1' twice). The plugin
    example's files are left to the test that installs that package."""
    from hera.preflight import check_spec
    from hera.spec import parse_spec, tomllib

    shown_files = r"<!-- file: \S+ -->\n`[^`]+`:\n\n```\w+\n.*?```\n"
    text = re.sub(shown_files, "", README, flags=re.S)
    specs = [
        data
        for block in re.findall(r"```toml\n(.*?)```", text, re.S)
        if "cluster" in (data := tomllib.loads(block))
    ]
    assert specs
    for i, data in enumerate(specs):
        check_spec(parse_spec(data, f"README spec {i}"))


def _github_anchor(heading: str) -> str:
    """The anchor GitHub (and PyPI) give a heading: lower case, punctuation dropped
    (backticks, dots, parentheses, colons), spaces made hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_contents_list_every_section_in_order_with_working_anchors():
    block = re.search(r"<!-- contents[^>]*-->\n(.*?)\n<!-- /contents -->", README, re.S)
    assert block is not None, "the README lost its contents markers"
    links = re.findall(r"\[([^\]]+)\]\(#([^)]+)\)", block.group(1))
    headings = re.findall(r"^## (.+)$", README, re.M)
    assert [text for text, _ in links] == [h.replace("`", "") for h in headings]
    assert [anchor for _, anchor in links] == [_github_anchor(h) for h in headings]
    assert _github_anchor("Estimation library (`hera.estimation`)") == (
        "estimation-library-heraestimation"
    )
