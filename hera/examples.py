"""Example specs: the ones shipped in the package (``hera.deploy``) and the applications'.

``hera examples`` lists them; ``hera up NAME`` (and every command that takes a spec) runs
one by name when no file of that name exists, so the examples work from a wheel install as
well as from a checkout (``hera up deploy/train.toml``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from hera.spec import SpecError


def examples() -> dict[str, Path]:
    """Every example spec by name: the package's, then each application's."""
    from hera.plugins import installed_apps

    out: dict[str, Path] = {}
    folder = resources.files("hera.deploy")
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            out[entry.name[: -len(".toml")]] = Path(str(entry))
    for app in installed_apps():
        for name, path in app.examples().items():
            out.setdefault(name, Path(path))
    return out


def describe(path: Path) -> str:
    """The first comment line of a spec (what it is), without the ``#``."""
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
        if line.strip():
            break
    return ""


def resolve_spec(arg: str) -> Path:
    """The spec file ``arg`` names: a path if one exists, else an example's name;
    SpecError naming both possibilities otherwise."""
    path = Path(arg)
    if path.exists():
        return path
    known = examples()
    if arg in known:
        return known[arg]
    names = ", ".join(sorted(known)) or "none"
    raise SpecError(f"no spec file {arg!r} and no example of that name (examples: {names})")
