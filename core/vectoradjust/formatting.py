"""Numbers as text for printed tables (CLI, QGIS log)."""

from __future__ import annotations

import math
from typing import Optional

__all__ = ["fmt_number", "float_or_none"]


def fmt_number(v, nd: int = 3) -> str:
    """A number for a printed table: ``nd`` decimals, ``-`` for None/NaN, text as is."""
    if v is None:
        return "-"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{x:.{nd}f}" if math.isfinite(x) else "-"


def float_or_none(x) -> Optional[float]:
    """A finite float, or None (None, NaN and infinity): for JSON."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None
