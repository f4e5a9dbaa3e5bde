"""Hera for Python: distributed, fault-tolerant sensor fusion on Eclipse Zenoh."""

from pathlib import Path as _Path

__version__ = "0.1.0"

# nodes/, models/ and sync/ install as hera.nodes, hera.models and hera.sync (pyproject's
# package-dir). When this package is imported from a source checkout instead (the repo root
# on sys.path, as `python -m hera` run from there does), look for them there too, so a
# checkout with a non-editable install does not lose half of the package.
_checkout = _Path(__file__).resolve().parent.parent
if (_checkout / "pyproject.toml").is_file() and (_checkout / "models" / "__init__.py").is_file():
    __path__.append(str(_checkout))
