"""Hera for Python: distributed, fault-tolerant sensor fusion on Eclipse Zenoh."""

import sys as _sys
from pathlib import Path as _Path

__version__ = "0.1.0"


def _check_checkout() -> None:
    """nodes/, models/, sync/ and deploy/ install as hera.nodes, hera.models, hera.sync and
    hera.deploy (pyproject's package-dir). Imported from a source checkout that is not
    installed in editable mode (``python -m hera`` run in the checkout after ``pip install
    .``), this package would lack them: say so, and what to run, instead of failing later."""
    root = _Path(__file__).resolve().parent.parent
    if not (root / "pyproject.toml").is_file() or not (root / "models").is_dir():
        return
    from importlib.util import find_spec

    if find_spec("hera.models") is None:
        message = (
            f"hera is imported from the source checkout {root} without an editable install: "
            f"run 'pip install -e {root}' (or run hera from another folder)"
        )
        if _sys.argv[:1] == ["-m"]:  # `python -m hera`: a sentence, not a traceback
            print(f"hera: {message}", file=_sys.stderr)
            raise SystemExit(2)
        raise ImportError(message)


_check_checkout()
