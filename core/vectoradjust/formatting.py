"""Numbers as text for printed tables (CLI, QGIS log)."""

from __future__ import annotations

import math

__all__ = ["fmt_number"]


def fmt_number(v, nd: int = 3) -> str:
    """A number for a printed table: ``nd`` decimals, ``-`` for None/NaN, text as is."""
    if v is None:
        return "-"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{x:.{nd}f}" if math.isfinite(x) else "-"
