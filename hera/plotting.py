"""Plots without a screen: matplotlib with its file-only backend, or a clear error."""

from __future__ import annotations

from typing import Any


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (PNG files, no display); ImportError with
    the install command when matplotlib is missing."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError("plots need matplotlib: pip install 'hera-fusion[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
