"""Shared pieces of the command-line modules: JSON output and error handling."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from vectoradjust.errors import CancelledError, InputFileError, VectorAdjustError

__all__ = ["clean_json", "write_json", "run_command", "fmt_number"]


def clean_json(obj):
    """A JSON-ready copy: numpy scalars/arrays to Python, NaN and inf to None."""
    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return clean_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(out_dir, name: str, payload: dict) -> Path:
    """Write ``payload`` as strict JSON to ``out_dir/name`` (atomically, dir created)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        path = out / name
        tmp = out / f".{name}.tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(clean_json(payload), fh, indent=2, allow_nan=False)
        tmp.replace(path)
    except OSError as exc:
        raise InputFileError(f"Cannot write {name} in {str(out)!r} ({exc})",
                             "Choose a writable directory with --out") from exc
    return path


def run_command(args) -> int:
    """Call ``args.func(args)``; user errors become one message and an exit status.

    Returns 0 on success, 1 for a :class:`VectorAdjustError`, 130 when cancelled or
    interrupted.
    """
    try:
        return int(args.func(args) or 0)
    except CancelledError as exc:
        print(f"\nvectoradjust: cancelled: {exc}", file=sys.stderr)
        return 130
    except VectorAdjustError as exc:
        print(f"\nvectoradjust: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\nvectoradjust: interrupted", file=sys.stderr)
        return 130


def fmt_number(v, nd: int = 3) -> str:
    """A number for a printed table: ``nd`` decimals, ``-`` for None/NaN, text as is."""
    if v is None:
        return "-"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f"{x:.{nd}f}" if math.isfinite(x) else "-"
