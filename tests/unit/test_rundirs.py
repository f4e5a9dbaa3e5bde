"""Run directories that cannot be made are refused in one sentence naming the folder."""

from __future__ import annotations

import pytest

from hera.rundirs import RunDirError, new_run_dir, prepare_run_dir


def test_a_run_directory_that_cannot_be_made_is_named_with_the_reason(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunDirError) as e:
        prepare_run_dir(tmp_path / "file" / "run")
    assert str(e.value) == f"cannot make the run directory {tmp_path}/file/run: Not a directory"
    with pytest.raises(RunDirError) as e:
        new_run_dir("c", base=tmp_path / "file" / "runs")
    assert str(e.value) == f"cannot make the folder of runs {tmp_path}/file/runs: Not a directory"


def test_new_run_directories_never_share_a_name(tmp_path):
    runs = [new_run_dir("c", base=tmp_path, now=1.0e9) for _ in range(3)]
    assert len({r.name for r in runs}) == 3 and all(r.is_dir() for r in runs)
    assert (tmp_path / "c").resolve() == runs[-1]
