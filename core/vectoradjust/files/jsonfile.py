"""Strict JSON output: numpy values to Python, NaN and infinity to null, written atomically."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from vectoradjust.errors import InputFileError

__all__ = ["clean_json", "write_json", "move_feature_statements", "FEATURE_ACCURACY_CSV"]


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


#: the per-feature accuracy statements, beside summary.json (one row per feature)
FEATURE_ACCURACY_CSV = "feature_accuracy.csv"


def _flat(row: dict, prefix: str = "") -> dict:
    """``{"rmse": {"x": 1}}`` -> ``{"rmse_x": 1}`` (nested dictionaries to columns)."""
    out: dict = {}
    for k, v in row.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}_"))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _paths(row: dict, prefix: tuple = ()) -> list:
    """Key paths of the leaves of a nested dict, in order."""
    out: list = []
    for k, v in row.items():
        out += _paths(v, prefix + (k,)) if isinstance(v, dict) else [prefix + (k,)]
    return out


def _get(row: dict, path: tuple):
    for k in path:
        if not isinstance(row, dict):
            return None
        row = row.get(k)
    return None if isinstance(row, dict) else row


def _json_cells(values: list) -> np.ndarray:
    """A column of JSON-ready values as an object array (NaN/inf written as empty); a
    column of floats and None (no booleans, no text) as floats, NaN for None/NaN/inf."""
    kinds = {type(v) for v in values}
    if kinds and kinds <= {float, int, type(None)} and kinds & {float, type(None)}:
        arr = np.array(values, dtype=float)  # None -> NaN
        arr[~np.isfinite(arr)] = np.nan
        return arr
    arr = np.empty(len(values), dtype=object)
    arr[:] = [clean_json(v) if not isinstance(v, (str, int, type(None))) else v
              for v in values]
    return arr


def _is_rows(value) -> bool:
    """A list of per-feature statements, or their columns
    (:class:`vectoradjust.accuracy.statements.FeatureStatements`)."""
    return isinstance(value, list) or hasattr(value, "columns")


def _statement_columns(feats: dict) -> dict:
    """``database`` and the flat columns of every database's per-feature statements:
    taken as they are from :class:`~vectoradjust.accuracy.statements.FeatureStatements`,
    gathered from the dicts of a list (every key path, nested keys joined with ``_``)."""
    parts = []
    for db, lst in feats.items():
        if not _is_rows(lst) or not len(lst):
            continue
        if hasattr(lst, "columns"):
            cols = lst.columns()
        else:
            paths: list = []
            for r in lst[:1000]:  # every row has the same keys; a few suffice
                paths += [p for p in _paths(r) if p not in paths]
            cols = {"_".join(p): _json_cells([_get(r, p) for r in lst]) for p in paths}
        parts.append({"database": np.full(len(lst), db, dtype=object), **cols})
    if not parts:
        return {"database": np.zeros(0, dtype=object)}
    names = list(parts[0])
    for p in parts[1:]:
        names += [k for k in p if k not in names]
    return {k: np.concatenate([_column_of(p, k) for p in parts]) for k in names}


def _column_of(part: dict, name: str) -> np.ndarray:
    """One database's column, empty cells (NaN) where it lacks the key."""
    n = len(part["database"])
    return np.asarray(part[name]) if name in part else np.full(n, np.nan)


def move_feature_statements(summary: dict, out_dir) -> tuple:
    """Move ``accuracy.features`` (one statement per road feature) out of summary.json.

    summary.json stays bounded whatever the number of features: the per-feature rows go
    to ``out_dir/feature_accuracy.csv`` (columns ``database, feature_id, count,
    mean_error_x, ..., asprs2023_rmse_3d``: the nested keys joined with ``_``) and
    ``accuracy.features`` becomes ``{"file", "count": {database: rows}, "columns"}``.

    Returns
    -------
    summary : dict
        A shallow copy with the pointer in place of the rows (the input is not changed).
    path : pathlib.Path or None
        The CSV written (None when there were no per-feature statements).
    """
    acc = summary.get("accuracy")
    feats = acc.get("features") if isinstance(acc, dict) else None
    if not isinstance(feats, dict) or not any(_is_rows(v) for v in feats.values()):
        stale = Path(out_dir) / FEATURE_ACCURACY_CSV
        if stale.is_file():  # from an earlier run into the same folder: not this run's
            stale.unlink()
        return summary, None
    cols = _statement_columns(feats)
    columns = list(cols)
    path = Path(out_dir) / FEATURE_ACCURACY_CSV
    from vectoradjust.files.study import write_csv

    write_csv(cols, path)
    out = dict(summary)
    out["accuracy"] = dict(acc)
    out["accuracy"]["features"] = {
        "file": FEATURE_ACCURACY_CSV,
        "count": {db: len(lst) for db, lst in feats.items() if _is_rows(lst)},
        "columns": columns,
        "note": "one row per feature in the CSV beside summary.json (kept out of "
                "summary.json so that its size does not grow with the data)",
    }
    return out, path
