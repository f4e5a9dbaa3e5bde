"""The package as a user installs it: ``pip install .`` (not editable) into a fresh venv,
next to an out-of-tree application (``tests/plugin_app``, built and installed as its own
wheel), used from outside and from inside the checkout.

One venv is built for the module (two wheels, their dependencies); the cluster runs are
short (a few seconds each).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

from hera.estimation.cache import numba_folder
from hera.spec import tomllib

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "tests" / "plugin_app"


def test_every_source_package_is_listed_in_pyproject():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    mapping = {src: dst for dst, src in cfg["package-dir"].items()}
    found = set()
    for top in ("hera", "nodes", "models", "sync", "deploy"):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top).parts
            found.add(".".join((mapping[top], *rel)))
    assert found == listed, f"add to / remove from [tool.setuptools] packages: {found ^ listed}"


def _wheel(src: Path, out: Path) -> Path:
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q"]
        + ["-w", str(out), str(src)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return out


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv with hera-fusion and hera-thermo installed from wheels; its bin dir."""
    tmp = tmp_path_factory.mktemp("install")
    wheels = _wheel(ROOT, tmp / "wheels")
    _wheel(PLUGIN, wheels)
    env_dir = tmp / "venv"
    venv.create(env_dir, with_pip=True)
    pip = [str(env_dir / "bin" / "python"), "-m", "pip", "install", "-q"]
    hera_whl = next(wheels.glob("hera_fusion-*.whl"))
    thermo_whl = next(wheels.glob("hera_thermo-*.whl"))
    out = subprocess.run(
        [*pip, str(hera_whl), str(thermo_whl)], capture_output=True, text=True, timeout=900
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return env_dir / "bin"


def _run(bin_dir: Path, *cmd: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["HERA_REGISTRY"] = str(cwd / "registry")
    return subprocess.run(
        [str(bin_dir / cmd[0]), *cmd[1:]],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_one_namespace_and_the_plugins_are_found(installed, tmp_path):
    probe = (
        "import importlib.util, hera, hera.nodes, hera.models, hera.sync, hera.deploy\n"
        "assert all(importlib.util.find_spec(m) is None for m in ('nodes', 'models', 'sync'))\n"
        "print(hera.nodes.__file__)\n"
    )
    out = _run(installed, "python", "-c", probe, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert str(installed.parent) in out.stdout and str(ROOT) not in out.stdout
    measures = _run(installed, "hera", "measures", cwd=tmp_path)
    assert measures.returncode == 0, measures.stderr
    for name in ("counter", "track_mag", "sonar", "thermo", "thermo_filter"):
        assert f"\n{name} " in "\n" + measures.stdout, name
    apps = _run(installed, "hera", "apps", cwd=tmp_path).stdout
    assert all(f"{a} " in apps for a in ("train", "simulator", "thermo")), apps
    examples = _run(installed, "hera", "examples", cwd=tmp_path).stdout
    assert all(f"{e} " in examples for e in ("train", "observers", "thermo")), examples


def test_python_m_hera_in_the_checkout_says_what_to_run(installed):
    """The checkout's hera/ shadows the installed package when run from the repo root with
    ``python -m``: it must say so in one sentence rather than fail later."""
    out = _run(installed, "python", "-m", "hera", "measures", cwd=ROOT)
    assert out.returncode == 2
    assert f"without an editable install: run 'pip install -e {ROOT}'" in out.stderr
    assert "Traceback" not in out.stderr, out.stderr


def test_hera_up_from_the_checkout_runs_the_installed_package(installed, tmp_path):
    """The README's main command runs ``hera up deploy/...`` in the checkout after a plain
    ``pip install .``: its node processes must not pick up the checkout's sources."""
    run = tmp_path / "run"
    out = _run(
        installed,
        "hera",
        "up",
        "deploy/observers.toml",
        "--duration",
        "4",
        "--run-dir",
        str(run),
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "5/5 nodes up" in out.stdout
    logs = "".join(p.read_text() for p in (run / "logs").glob("*.log"))
    assert "Error" not in logs and "exited with code" not in out.stdout, logs[-2000:]
    assert len(list((run / "measures").glob("obs*_n*.csv"))) == 20


def test_an_out_of_tree_application_runs_scores_and_replays(installed, tmp_path):
    run = tmp_path / "run"
    up = _run(
        installed, "hera", "up", "thermo", "--duration", "8", "--run-dir", str(run), cwd=tmp_path
    )
    assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-2000:]
    assert "thermo:" in up.stdout and "degC" in up.stdout  # its live panel
    ev = _run(installed, "hera", "eval", str(run), "--json", cwd=tmp_path)
    assert ev.returncode == 0, ev.stderr
    rows = {(r["model"], r["node"]): r for r in json.loads(ev.stdout)}
    assert set(rows) == {("thermo_filter", "sensor"), ("thermo_filter", "desk")}
    said = up.stdout[-3000:] + "".join(
        f"\n--- {log.name}\n" + log.read_text()[-3000:] for log in (run / "logs").glob("*.log")
    )
    for r in rows.values():
        assert r["application"] == "thermo", r
        assert r["estimates"] > 40, f"{r}\n{said}"  # 8 s at 10 Hz from when all were up
        assert r["rmse_degc"] < 0.25  # sensor noise 0.3 degC: the filter does better
    # the README's model pickles (F and Q are methods): each node checkpoints it on disk
    logs = "".join(log.read_text() for log in (run / "logs").glob("*.log"))
    assert "no checkpoints" not in logs, said
    assert {c.parts[-3] for c in run.glob("state/*/checkpoints/thermo_filter.pickle")} == {
        "sensor",
        "desk",
    }
    # plots are the application's too; this install has no matplotlib, and says so
    assert "plots skipped: plots need matplotlib: pip install 'hera-fusion[plot]'" in ev.stderr
    rp = _run(installed, "hera", "replay", str(run), "--out", str(tmp_path / "again"), cwd=tmp_path)
    assert rp.returncode == 0, rp.stderr
    counters = json.loads(
        (tmp_path / "again" / "measures" / "thermo_filter_replay.counters.json").read_text()
    )
    assert counters == {"rejected": 0}
    again = _run(installed, "hera", "eval", str(tmp_path / "again"), "--json", cwd=tmp_path)
    (row,) = json.loads(again.stdout)
    assert row["application"] == "thermo" and row["rmse_degc"] < 0.25


@pytest.mark.slow  # CI budget: a second cold compile (45-60 s); CI's first is in
# tests/estimation/test_backend_loading.py
def test_the_install_compiles_its_kernels_once_into_a_user_cache(installed, tmp_path):
    """The README's install brings numba (a core dependency): ``hera bench kalman --quick``
    reports the compiled backend. The kernels are compiled once, with a line saying so,
    into the per-user cache although the installed package is read only (the venv is
    bind-mounted read-only for the runs); the next process loads them without compiling."""
    site = Path(
        _run(
            installed, "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])",
            cwd=tmp_path,
        ).stdout.strip()
    )  # fmt: skip
    assert (site / "numba").is_dir(), "numba is not installed by the plain install"
    # the benchmark's peer, as the README says (scipy is FilterPy's import-time need;
    # --no-deps keeps matplotlib out, which another test of this venv relies on)
    pip = [str(installed / "python"), "-m", "pip", "install", "-q"]
    got = subprocess.run([*pip, "scipy"], capture_output=True, text=True, timeout=600)
    assert got.returncode == 0, got.stderr[-2000:]
    got = subprocess.run([*pip, "--no-deps", "filterpy"], capture_output=True, text=True)
    assert got.returncode == 0, got.stderr[-2000:]
    venv_dir = installed.parent
    cache = tmp_path / "cache"

    def read_only(*cmd: str, cwd: Path = tmp_path) -> subprocess.CompletedProcess:
        script = (
            f'mount --bind -o ro "{venv_dir}" "{venv_dir}" && touch "{site}/w" 2>/dev/null '
            '&& { echo "site-packages is writable"; exit 3; }; exec "$@"'
        )
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        env.pop("NUMBA_CACHE_DIR", None)
        env.update(PATH=f"{installed}{os.pathsep}{env.get('PATH', '')}", XDG_CACHE_HOME=str(cache))
        return subprocess.run(
            ["unshare", "--mount", "sh", "-c", script, "sh", *cmd],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )

    where = cache / "hera" / "numba"
    # the kernels of an install deleted since: the compile removes them (never loadable)
    gone = where / numba_folder(tmp_path / "deleted-venv" / "estimation" / "kernels_numba.py")
    gone.mkdir(parents=True)
    (gone / "kernels_numba.kf_step-10.py311.nbi").write_bytes(b"x" * 4096)
    (gone / "hera-origin").write_text(f"{tmp_path / 'deleted-venv' / 'estimation'}\n")
    # run in the source checkout, as the README's install and run are: its own hera must
    # not be what the compile helpers and the memory probe import (python -c's path)
    bench = read_only("hera", "bench", "kalman", "--quick", cwd=ROOT)
    assert bench.returncode == 0, bench.stdout[-2000:] + bench.stderr[-2000:]
    assert "hera.estimation backend: numba" in bench.stdout, bench.stdout[:500]
    assert sum(line.startswith(("KF ", "EKF ", "UKF ")) for line in bench.stdout.splitlines()) == 27
    lines = bench.stderr.splitlines()
    assert any(
        line.startswith("hera.estimation: compiling ") and str(where) in line for line in lines
    ), bench.stderr[-2000:]
    jobs = min(os.cpu_count() or 1, 4)  # the compile shared between processes
    shared = f"(in {jobs} processes, " if jobs > 1 else "(20-50 s"
    assert any(line.startswith("hera.estimation: compiling ") and shared in line for line in lines)
    assert any(
        line.startswith("hera.estimation: numba kernels compiled in ") and "cached in" in line
        for line in lines
    ), bench.stderr[-2000:]
    assert "a compile helper ended" not in bench.stderr, bench.stderr[-2000:]
    assert "a process that runs these filters (probe failed)" not in bench.stdout
    assert list(where.rglob("kernels_numba.*.nbi")), "nothing cached in the user cache"
    assert not list(venv_dir.rglob("*.nbi")), "numba wrote into the installed package"
    again = read_only(
        "python", "-c", "from hera.estimation import backend; print(backend.backend())"
    )
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout.strip() == "numba" and "compiling" not in again.stderr, again.stderr
    assert (
        "hera.estimation: removed from the cache the kernels of 1 install that no longer "
        "exists" in bench.stderr
    ), bench.stderr[-2000:]
    assert not gone.exists()
    listed = read_only("hera", "cache")  # the set this install uses, its origin recorded
    assert listed.returncode == 0, listed.stderr
    assert f"{site / 'hera' / 'estimation'} (this install)" in listed.stdout, listed.stdout
