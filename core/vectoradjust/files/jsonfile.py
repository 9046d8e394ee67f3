"""Strict JSON output: numpy values to Python, NaN and infinity to null, written atomically."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from vectoradjust.errors import InputFileError

__all__ = ["clean_json", "write_json"]


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
