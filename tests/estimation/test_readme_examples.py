"""The estimation library's examples in the README run as written, each as a script of its
own in a fresh process (they named ``g``, ``H_gyro``, ``dt`` and more that they never
defined, so a user copying them was stopped at once)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _examples() -> list[str]:
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## Estimation library", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```\n", section, re.S)


def test_every_example_of_the_estimation_section_runs_as_written(tmp_path):
    examples = _examples()
    assert len(examples) == 2, "the section's examples changed: check this test still runs them"
    outputs = []
    for i, code in enumerate(examples):
        script = tmp_path / f"example_{i}.py"
        script.write_text(code)
        out = subprocess.run(
            [sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300
        )
        assert out.returncode == 0, f"example {i} of the README failed:\n{out.stderr[-2000:]}"
        outputs.append(out.stdout)
    # the comment beside the first example's print is what it prints
    printed = re.search(r"print\(result\.accepted, result\.rejected\)  # (.*)\n", examples[0])
    assert printed is not None and outputs[0].strip() == printed.group(1)
