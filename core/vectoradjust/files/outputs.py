"""Writing the contract's outputs: ``adjusted.gpkg`` (or shapefiles) and ``summary.json``.

Everything is written to a temporary directory first and moved into place only when
all files were written, so a failing run leaves nothing half-written. A whole run
(the command line's layers, tables, report, ...) is written the same way through
:class:`RunFolder`: its output folder locked (:class:`DirLock`), the files staged and
moved into place at the end, ``run_manifest.json`` (:data:`MANIFEST`) last.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import re
import shutil
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.accuracy.tables import shape_point_column
from vectoradjust.errors import CancelledError, InputFileError
from vectoradjust.files.jsonfile import (
    FEATURE_ACCURACY_CSV,
    clean_json,
    move_feature_statements,
)
from vectoradjust.results import AdjustmentRun

__all__ = ["write_outputs", "shape_points_frame", "features_frame", "control_points_frame",
           "json_default", "renamed_input_fields", "run_input_fields", "input_field_types",
           "attribute_array", "storable_frame", "field_change", "text_value", "FIELD_KINDS"]

SHAPE_FIELDS = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ",
                "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "CE90_meas", "LE90_meas",
                "NImages", "Adjusted", "Database", "Source", "Problem"]
FEATURE_FIELDS = ["NPts", "NAdj", "RMSE_X", "RMSE_Y", "RMSE_Z", "RMSE", "CE90", "LE90",
                  "Length", "LengthSD",
                  "LengthSDnc", "LengthSDOf", "FirstX",
                  "FirstY", "LastX", "LastY", "Images", "ImgDate", "Database", "Problem"]
CONTROL_FIELDS = ["point_id", "role", "X", "Y", "Z", "AdjX", "AdjY", "AdjZ", "Vx", "Vy", "Vz",
                  "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "NImages", "Used"]


#: names an input attribute may not keep besides ours (the geometry column and GeoPackage's fid)
RESERVED_NAMES = ("geometry", "fid")
#: longest field name a shapefile holds
SHAPEFILE_NAME_LENGTH = 10


def renamed_input_fields(names) -> dict:
    """The new names of input attributes that would clash with the product's fields.

    The product's field names (``FEATURE_FIELDS``, the file contract) are fixed. An input
    field whose name equals one of them case-insensitively (GeoPackage and shapefile
    names are case-insensitive), or ``geometry``/``fid``, or an earlier input field, is
    kept as ``in_<name>``: at most 10 characters (shapefile-safe) and unique,
    case-insensitively, among all fields of the ``features`` layer (a number is
    appended when needed).

    Parameters
    ----------
    names : iterable of str
        The input field names, in order.

    Returns
    -------
    dict
        ``{input name: output name}`` of the renamed fields only (empty when none clash).
    """
    names = [str(n) for n in names]
    reserved = {f.lower() for f in FEATURE_FIELDS} | set(RESERVED_NAMES)
    taken = reserved | {n.lower() for n in names}
    seen: set = set()
    out: dict = {}
    for n in names:
        low = n.lower()
        if low not in reserved and low not in seen:
            seen.add(low)
            continue
        new = ("in_" + n)[:SHAPEFILE_NAME_LENGTH]
        k = 1
        while new.lower() in taken:
            tail = str(k)
            new = ("in_" + n)[:SHAPEFILE_NAME_LENGTH - len(tail)] + tail
            k += 1
        taken.add(new.lower())
        out[n] = new
    return out


def run_input_fields(run: AdjustmentRun) -> list:
    """The input attribute names of all databases of a run (first appearance order)."""
    names: list = []
    for d in run.databases:
        names += [n for n in d.shape.layer.attributes if n not in names]
    return names


def json_default(o):
    """JSON encoder fallback for numpy scalars and arrays (NaN -> null)."""
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def _nullable(col: np.ndarray, mask: Optional[np.ndarray] = None):
    """A column for writing: floats as nullable ``Float64`` (NaN or ``~mask`` -> null)."""
    import pandas as pd

    arr = np.asarray(col)
    if arr.dtype.kind == "f":
        valid = np.isfinite(arr)
        if mask is not None:
            valid &= mask
        return pd.arrays.FloatingArray(np.where(valid, arr, 0.0), ~valid)
    if arr.dtype.kind in "iub":
        out = pd.array(arr.astype(np.int64), dtype="Int64")
        if mask is not None:
            out[~mask] = pd.NA
        return out
    out = arr.astype(object)
    if mask is not None:
        out[~mask] = None
    return out


#: float fields of shape_points that are null where the vertex got no value (unmeasured,
#: not conflated)
_MASKED_SHAPE_FIELDS = ("Vx", "Vy", "Vz", "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90",
                        "CE90_meas", "LE90_meas")


def _valued_vertices(v: dict) -> np.ndarray:
    """Vertices whose V, sigmas and CE90/LE90 have values: measured, or corrected by the
    conflation."""
    adj = np.asarray(v["Adjusted"]) == 1
    if "Source" in v:
        adj = adj | np.isin(v["Source"], ("interpolated", "extrapolated"))
    return adj


def shape_points_frame(run: AdjustmentRun):
    """GeoDataFrame of the ``shape_points`` layer (Point Z at the adjusted position)."""
    import geopandas as gpd
    import pandas as pd
    import shapely

    frames = []
    for d in run.databases:
        v = d.vertices
        adj = _valued_vertices(v)
        cols = {f: _nullable(shape_point_column(v, f), adj) if f in _MASKED_SHAPE_FIELDS
                else _nullable(shape_point_column(v, f)) for f in SHAPE_FIELDS}
        geom = shapely.points(np.column_stack([v["AdjX"], v["AdjY"],
                                               np.nan_to_num(v["AdjZ"], nan=0.0)]))
        frames.append(gpd.GeoDataFrame(pd.DataFrame(cols), geometry=geom, crs=run.data.crs))
    if not frames:
        return gpd.GeoDataFrame(pd.DataFrame({f: [] for f in SHAPE_FIELDS}),
                                geometry=gpd.GeoSeries([], crs=run.data.crs), crs=run.data.crs)
    return pd.concat(frames, ignore_index=True)


def shape_points_table(run: AdjustmentRun):
    """The ``shape_points`` layer as Arrow columns and WKB points (a
    :class:`~vectoradjust.files.derived_outputs.LayerTable`): the layer of
    :func:`shape_points_frame` without a pandas frame or a shapely object per vertex
    (a million vertices: seconds and about a gigabyte less). None without databases.
    """
    import pyarrow as pa

    from vectoradjust.files.derived_outputs import LayerTable

    dbs = list(run.databases)
    if not dbs:
        return None
    adj = np.concatenate([_valued_vertices(d.vertices) for d in dbs])
    arrays = []
    for f in SHAPE_FIELDS:
        col = np.concatenate([np.asarray(shape_point_column(d.vertices, f)) for d in dbs])
        if col.dtype.kind == "f":
            valid = np.isfinite(col) & (adj if f in _MASKED_SHAPE_FIELDS else True)
            arrays.append(pa.array(np.where(valid, col, 0.0), mask=~valid))
        elif col.dtype.kind in "iub":
            arrays.append(pa.array(col.astype(np.int64)))
        else:
            arrays.append(pa.array(col.astype(object), type=pa.string()))
    xyz = np.concatenate([np.column_stack([d.vertices["AdjX"], d.vertices["AdjY"],
                                           np.nan_to_num(d.vertices["AdjZ"], nan=0.0)])
                          for d in dbs]).astype(float)
    arrays.append(_point_z_wkb(xyz))
    table = pa.Table.from_arrays(arrays, names=[*SHAPE_FIELDS, "geometry"])
    return LayerTable(lambda: pa.RecordBatchReader.from_batches(
        table.schema, table.to_batches(max_chunksize=65536)), run.data.crs, "Point Z",
        table.num_rows)


def _point_z_wkb(xyz: np.ndarray):
    """ISO WKB of 3-D points (little endian, type 1001) as an Arrow binary array."""
    import pyarrow as pa

    n = len(xyz)
    rec = np.empty(n, dtype=[("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8"),
                             ("z", "<f8")])
    rec["order"], rec["type"] = 1, 1001
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    offsets = np.arange(n + 1, dtype=np.int32) * rec.dtype.itemsize
    return pa.Array.from_buffers(pa.binary(), n, [None, pa.py_buffer(offsets),
                                                  pa.py_buffer(rec.tobytes())])


def _feature_geometries(d) -> list:
    """The adjusted line of every feature, of the input's geometry type: a layer of
    MultiLineStrings only gives MultiLineStrings (one part too), any other a
    LineString for a feature of one part and a MultiLineString for one of several (as
    read: a shapefile's arcs, a mixed layer); None for a feature without a line (its
    ``Problem`` says why). A vertex without a height (NaN, flagged in ``Problem``) is
    written with Z = 0."""
    import shapely

    layer = d.shape.layer
    nf = layer.n_features
    out = [None] * nf
    if len(layer.coords) == 0:
        return out
    multi_only = set(str(layer.geometry_type).split(",")) == {"MultiLineString"}
    adj = d.adjusted_coords
    z = np.nan_to_num(adj[:, 2], nan=0.0)
    xyz = np.column_stack([adj[:, :2], z])
    fi, part = layer.vertex_feature, layer.vertex_part
    key = fi * 100000 + part
    brk = np.flatnonzero(np.diff(key)) + 1
    starts = np.r_[0, brk]
    ends = np.r_[brk, len(key)]
    parts_by_feature: dict = {}
    for s, e in zip(starts, ends):
        parts_by_feature.setdefault(int(fi[s]), []).append(xyz[s:e])
    for f, parts in parts_by_feature.items():
        parts = [p for p in parts if len(p) >= 2]
        if not parts:  # a single vertex is no line: no geometry in a line layer
            continue
        if len(parts) == 1 and not multi_only:
            out[f] = shapely.linestrings(parts[0])
        else:
            out[f] = shapely.multilinestrings([shapely.linestrings(p) for p in parts])
    return out


def _arrow_type(name: Optional[str]):
    """The Arrow type of a type name (:func:`vectoradjust.files.readers.read_line_layer`'s
    ``reading["fields"]``), or None when the name gives none (then the values tell)."""
    import pyarrow as pa

    if not name or name in ("null", "mixed"):
        return None
    try:
        return pa.type_for_alias(name)
    except (ValueError, KeyError):
        pass
    m = re.fullmatch(r"timestamp\[(s|ms|us|ns), tz=(.+)\]", name)
    return pa.timestamp(m.group(1), m.group(2)) if m else None


_ARROW_ERRORS = ("ArrowInvalid", "ArrowTypeError", "ArrowNotImplementedError")


def attribute_array(values, type_name: Optional[str] = None):
    """An input attribute column as an Arrow array of its type, values exact.

    Parameters
    ----------
    values : sequence
        Plain Python values (``int`` exact beyond 2^53, ``datetime.date`` ...), None or
        NaN for NULL.
    type_name : str, optional
        Arrow type name (``"int32"``, ``"date32[day]"``, ``"timestamp[ms, tz=UTC]"`` ...):
        kept even when every value is NULL. Without it, or when the values do not fit it,
        the type is inferred from the values; values of no common type are written as
        text.

    Returns
    -------
    pyarrow.Array
    """
    import pyarrow as pa

    errors = tuple(getattr(pa, e) for e in _ARROW_ERRORS) + (TypeError, ValueError,
                                                             OverflowError)
    wanted = _arrow_type(type_name)
    vals = values.tolist() if isinstance(values, np.ndarray) else list(values)
    for t in ([wanted] if wanted is not None else []) + [None]:
        try:
            arr = pa.array(vals, type=t, from_pandas=True)
        except errors:
            continue
        if not pa.types.is_null(arr.type):
            return arr
    return pa.array([None if _missing(v) else (v.isoformat() if hasattr(v, "isoformat")
                                                else str(v)) for v in vals], type=pa.string())


def _pandas_column(arr):
    """An Arrow array as a pandas column of the same type (pandas' Arrow types); the plain
    Python values where pandas has none (before 1.5)."""
    import pandas as pd

    make = getattr(pd.arrays, "ArrowExtensionArray", None)
    return make(arr) if make is not None else arr.to_pylist()


def _missing(v) -> bool:
    """None, NaN, NaT or pandas' NA."""
    if v is None:
        return True
    try:
        return bool(v != v)
    except (TypeError, ValueError):  # pandas' NA has no truth value
        return True


def _common_type(names: list) -> Optional[str]:
    """One type for a field that several databases hold: their own when they agree,
    the widest integer or a real when all are numbers, else text."""
    import pyarrow as pa

    given = list(dict.fromkeys(n for n in names if n and n not in ("null", "mixed")))
    if len(given) <= 1:
        return given[0] if given else None
    types = [_arrow_type(n) for n in given]
    if all(t is not None and pa.types.is_integer(t) for t in types):
        return "int64"
    if all(t is not None and (pa.types.is_integer(t) or pa.types.is_floating(t))
           for t in types):
        return "double"
    return "string"


def input_field_types(run: AdjustmentRun) -> dict:
    """``{input field: Arrow type name or None}`` over all databases of a run.

    A database's type of a field is the one its reader states (``LineLayer.reading
    ["fields"]``), else the one its values give; several databases holding a field with
    different types get one common type (:func:`_common_type`).
    """
    seen: dict = {}
    for d in run.databases:
        layer = d.shape.layer
        stated = (getattr(layer, "reading", None) or {}).get("fields") or {}
        for name, values in layer.attributes.items():
            t = stated.get(name) or str(attribute_array(values).type)
            seen.setdefault(name, []).append(t)
    return {name: _common_type(ts) for name, ts in seen.items()}


def features_frame(run: AdjustmentRun):
    """GeoDataFrame of the ``features`` layer: every input feature and attribute kept.

    Every input field of the run is a column of its type (:func:`input_field_types`;
    NULL in the databases without it), values exact: int64 beyond 2^53, dates, booleans,
    unicode text. The geometry is of the input's type (:func:`_feature_geometries`; the
    GeoPackage layer is written without promoting LineStrings to MultiLineStrings).
    ``CE90`` / ``LE90`` are the largest of the feature's vertices'
    (:func:`vectoradjust.accuracy.derived.feature_vertex_accuracy`), ``LengthSD`` that of
    all its vertices with a covariance, measured and conflated
    (:func:`vectoradjust.accuracy.derived.feature_accuracy`).
    """
    import geopandas as gpd
    import pandas as pd

    from vectoradjust.accuracy.derived import feature_accuracy

    names = run_input_fields(run)
    renamed = renamed_input_fields(names)
    types = input_field_types(run)
    frames = []
    for d in run.databases:
        layer = d.shape.layer
        if run.result is not None and "LengthSD" in d.features:
            feature_accuracy(run, d)  # CE90 / LE90, the conflated vertices' LengthSD
        cols: dict = {}
        for name in names:
            values = layer.attributes.get(name, [None] * layer.n_features)
            cols[renamed.get(name, name)] = _pandas_column(
                attribute_array(values, types.get(name)))
        for f in FEATURE_FIELDS:
            if f == "Database":
                cols[f] = [d.name] * layer.n_features
            else:
                cols[f] = _nullable(d.features.get(f, np.full(layer.n_features, np.nan)))
        geoms = _feature_geometries(d)
        frames.append(gpd.GeoDataFrame(pd.DataFrame(cols), geometry=gpd.GeoSeries(
            geoms, crs=run.data.crs), crs=run.data.crs))
    if not frames:
        return gpd.GeoDataFrame(pd.DataFrame({f: [] for f in FEATURE_FIELDS}),
                                geometry=gpd.GeoSeries([], crs=run.data.crs), crs=run.data.crs)
    return pd.concat(frames, ignore_index=True)


def control_points_frame(run: AdjustmentRun):
    """GeoDataFrame of the ``control_points`` layer (at the adjusted, else surveyed, place)."""
    import geopandas as gpd
    import pandas as pd
    import shapely

    c = run.control_points
    used = c["Used"] == 1
    cols = {}
    for f in CONTROL_FIELDS + (["QA"] if "QA" in c else []):
        col = c[f]
        cols[f] = _nullable(col)
    xyz = np.where(used[:, None], np.column_stack([c["AdjX"], c["AdjY"], c["AdjZ"]]),
                   np.column_stack([c["X"], c["Y"], c["Z"]]))
    geom = shapely.points(xyz) if len(xyz) else gpd.GeoSeries([], crs=run.data.crs)
    return gpd.GeoDataFrame(pd.DataFrame(cols), geometry=geom, crs=run.data.crs)


_LAUNDERED = re.compile(r"Normalized/laundered field name: '(.+)' to '(.+)'")
_TRUNCATED_VALUE = re.compile(r"Value '.*' of field (\S+) has been truncated to (\d+) characters",
                              re.DOTALL)


def _writer_warning(message: str, where: str) -> Optional[str]:
    """A GDAL/pyogrio/geopandas warning raised while writing, as a run warning (or None)."""
    msg = " ".join(str(message).split())
    if msg.startswith("Column names longer than 10 characters"):
        return None  # geopandas' generic notice; GDAL names every laundered field
    m = _LAUNDERED.search(msg)
    if m:
        return (f"{where}: input field {m.group(1)!r} is written as {m.group(2)!r} "
                f"(shapefile field names have at most 10 characters; use --format gpkg to "
                f"keep the name)")
    m = _TRUNCATED_VALUE.search(msg)
    if m:
        return (f"{where}: text values of field {m.group(1)!r} are cut to {m.group(2)} "
                f"characters (the shapefile limit; use --format gpkg to keep them whole)")
    if len(msg) > 300:
        msg = msg[:300] + "..."
    return f"{where}: {msg}"


def _arrow_writing() -> dict:
    """``{"use_arrow": True}`` where pyogrio can write through Arrow (pyarrow installed:
    columns go to GDAL in bulk, not feature by feature), else ``{}``."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return {}
    return {"use_arrow": True}


@contextmanager
def _unsynced_sqlite():
    """GeoPackage writing without SQLite's wait for the disk after every transaction
    (``OGR_SQLITE_SYNCHRONOUS=OFF``), the setting before restored afterwards.

    :func:`write_outputs` writes into a temporary folder and moves the files into place
    only when all are written, so an interrupted run leaves no half-written GeoPackage
    among the outputs; the files are then as safe as any other file written without
    ``fsync`` (the CSV files, summary.json)."""
    try:
        from pyogrio import get_gdal_config_option, set_gdal_config_options
    except ImportError:
        yield
        return
    old = get_gdal_config_option("OGR_SQLITE_SYNCHRONOUS")
    set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": "OFF"})
    try:
        yield
    finally:
        set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": old})


def _write_layer(gdf, path: Path, layer: Optional[str], fmt: str) -> list:
    """Write one layer; returns GDAL's warnings as run warnings instead of printing them,
    and what the format cannot hold and was written otherwise (:func:`storable_frame`)."""
    where = f"{path.name} layer {layer}" if layer else path.name
    out: list = []
    if not hasattr(gdf, "write"):
        gdf, out = storable_frame(gdf, fmt, where)
    with warnings.catch_warnings(record=True) as caught, _unsynced_sqlite():
        warnings.simplefilter("always")
        if hasattr(gdf, "write"):  # a LayerTable (Arrow, WKB): straight to GDAL
            gdf.write(path, layer, "GPKG" if fmt == "gpkg" else "ESRI Shapefile")
        elif fmt == "gpkg":  # the features keep their LineString / MultiLineString
            keep = {"promote_to_multi": False} if layer == "features" else {}
            gdf.to_file(path, layer=layer, driver="GPKG", engine="pyogrio", **_arrow_writing(),
                        **keep)
        else:  # through Arrow too: int64, dates and booleans keep their DBF types
            gdf.to_file(path, driver="ESRI Shapefile", engine="pyogrio", encoding="UTF-8",
                        **_arrow_writing())
    for w in caught:
        text = _writer_warning(str(w.message), where)
        if text and text not in out:
            out.append(text)
    return out


#: the longest integer text (sign included) GDAL reads back from a shapefile as an
#: integer: a wider DBF numeric field is read as real numbers
SHAPEFILE_INTEGER_DIGITS = 18
#: the longest 32-bit integer text a shapefile's integer field is read back as 32-bit
SHAPEFILE_INT32_DIGITS = 9
#: decimals of a real in a shapefile (GDAL writes a real field as DBF ``N(24, 15)``)
SHAPEFILE_REAL_DECIMALS = 15
_FORMAT_NAMES = {"gpkg": "a GeoPackage", "shp": "a shapefile"}
#: the kinds of attribute :func:`field_change` knows
FIELD_KINDS = ("int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
               "float16", "float32", "float64", "string", "bool", "date", "datetime", "time",
               "binary", "list", "struct", "other")


def text_value(v, kind: str = "other") -> Optional[str]:
    """An attribute value as the text a format without its type gets: ISO 8601 for dates
    and times, JSON for lists and structures, hexadecimal for binary, the digits of a
    number; None stays None."""
    if v is None:
        return None
    if kind in ("list", "struct"):
        return json.dumps(v, ensure_ascii=False, default=lambda o: (
            o.isoformat() if hasattr(o, "isoformat") else
            bytes(o).hex() if isinstance(o, (bytes, bytearray)) else str(o)))
    if isinstance(v, (bytes, bytearray, memoryview)):
        return bytes(v).hex()
    if isinstance(v, (dt.datetime, dt.time)) and v.microsecond % 1000 == 0 and v.microsecond:
        return v.isoformat(timespec="milliseconds")  # as GDAL writes them
    return v.isoformat() if hasattr(v, "isoformat") else str(v)


def field_change(kind: str, values, fmt: str,
                 hint: str = "use --format gpkg") -> Optional[tuple]:
    """What ``fmt`` cannot hold of an attribute field, and what is written instead.

    Parameters
    ----------
    kind : str
        One of :data:`FIELD_KINDS` (``"int64"``, ``"datetime"`` ...).
    values : sequence
        The field's values, plain Python (None for NULL).
    fmt : {"gpkg", "shp"}
    hint : str
        How the user keeps the type (the command line: ``use --format gpkg``).

    Returns
    -------
    tuple or None
        None when the format holds the field as it is; else ``(as_text, what)``:
        ``as_text`` true when the field is to be written as text (:func:`text_value`),
        false when the values are written as they are but come back otherwise; ``what``
        the warning's text after the field's name. A time of day is text in both
        formats; for a shapefile, a date and time is text (ISO 8601), so are integers
        wider than :data:`SHAPEFILE_INTEGER_DIGITS` characters (GDAL would read them back
        as reals), binary (hexadecimal) and lists (JSON); integers read back with another
        width and reals with more than :data:`SHAPEFILE_REAL_DECIMALS` decimals are
        reported.
    """
    fmt_name = _FORMAT_NAMES.get(fmt, fmt)
    keep = f"; {hint} to keep it" if fmt == "shp" else ""
    if kind == "time":
        return True, f"(time of day) is written as text (HH:MM:SS): {fmt_name} has no time type"
    if kind == "struct" or (fmt == "shp" and kind == "list"):
        return True, f"(a list or structure) is written as JSON text{keep}"
    if fmt != "shp":
        return None
    if kind == "datetime":
        return True, ("(date and time) is written as text (ISO 8601, e.g. 2021-03-04T05:06:07): "
                      f"a shapefile has no date-time type{keep}")
    if kind == "binary":
        return True, f"(binary) is written as hexadecimal text{keep}"
    if kind.startswith(("int", "uint")):
        return _shapefile_integers(kind, values, hint)
    if kind.startswith("float"):
        return _shapefile_reals(kind, values, hint)
    return None


def _shapefile_reals(kind: str, values, hint: str) -> Optional[tuple]:
    """:func:`field_change` of reals in a shapefile: the DBF holds them as text with
    :data:`SHAPEFILE_REAL_DECIMALS` decimals (GDAL's ``N(24, 15)``)."""
    vals = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    changed = [v for v in vals if float(f"{v:.{SHAPEFILE_REAL_DECIMALS}f}") != v]
    what = []
    if kind != "float64":
        what.append(f"({kind[5:]}-bit reals) is read back as 64-bit reals")
    if changed:
        v = changed[0]
        what.append(f"{'and has' if what else 'has'} {len(changed)} of its {len(vals)} values "
                    f"with more than {SHAPEFILE_REAL_DECIMALS} decimals (e.g. {v!r} is written "
                    f"as {float(f'{v:.{SHAPEFILE_REAL_DECIMALS}f}')!r}): a shapefile holds "
                    f"reals as text with {SHAPEFILE_REAL_DECIMALS} decimals; {hint} to keep "
                    "them exact")
    return (False, " ".join(what)) if what else None


def _shapefile_integers(kind: str, values, hint: str) -> Optional[tuple]:
    """:func:`field_change` of integers in a shapefile."""
    vals = [int(v) for v in values if v is not None]
    widest = max(vals, key=lambda v: len(str(v)), default=0)
    width = len(str(widest))
    if width > SHAPEFILE_INTEGER_DIGITS:
        return True, (
            f"holds integers wider than {SHAPEFILE_INTEGER_DIGITS} characters (e.g. {widest}), "
            "which a shapefile cannot give back exactly (GDAL reads so wide a field as real "
            "numbers): the field is written as text, every digit kept; "
            f"{hint} to keep it an integer field")
    unsigned = kind.startswith("u")
    bits = int(kind[4:] if unsigned else kind[3:])
    back = 64 if bits > 32 or width > SHAPEFILE_INT32_DIGITS or (unsigned and bits == 32) else 32
    if back == bits and not unsigned:
        return None
    return False, (f"({'unsigned ' if unsigned else ''}{bits}-bit integers) is read back as "
                   f"{back}-bit integers, the values unchanged: a shapefile's integer type "
                   "follows the field's width")


def _arrow_kind(t) -> str:
    """The :data:`FIELD_KINDS` name of an Arrow type."""
    import pyarrow as pa

    if pa.types.is_integer(t):
        return str(t)  # int8 ... uint64
    if pa.types.is_floating(t):
        return f"float{t.bit_width}"
    for test, kind in ((pa.types.is_boolean, "bool"), (pa.types.is_date, "date"),
                       (pa.types.is_timestamp, "datetime"), (pa.types.is_time, "time"),
                       (pa.types.is_string, "string"), (pa.types.is_large_string, "string"),
                       (pa.types.is_binary, "binary"), (pa.types.is_large_binary, "binary"),
                       (pa.types.is_list, "list"), (pa.types.is_large_list, "list"),
                       (pa.types.is_struct, "struct"), (pa.types.is_map, "struct")):
        if test(t):
            return kind
    return "other"


def storable_frame(gdf, fmt: str, where: str) -> tuple:
    """The frame as ``fmt`` can hold it, and a run warning per field it changes.

    The input attribute columns (pandas Arrow types, :func:`features_frame`) go through
    :func:`field_change`: a field the format cannot hold is written as text
    (:func:`text_value`), or as it is when only its reading back differs; each is a
    warning naming the field. What the driver itself changes (names cut to 10
    characters, texts to 254) is reported from GDAL's warnings (:func:`_writer_warning`).

    Returns
    -------
    frame : GeoDataFrame
        ``gdf`` itself when nothing changes, else a changed copy.
    notes : list of str
        ``"<where>: field 'stamp' (date and time) is written as text ..."``.
    """
    import pandas as pd
    import pyarrow as pa

    out, notes = gdf, []
    geometry = getattr(gdf, "_geometry_column_name", "geometry")
    for name in gdf.columns:
        if name == geometry or not isinstance(gdf[name].dtype, getattr(pd, "ArrowDtype", ())):
            continue
        arr = pa.array(gdf[name].array)
        kind = _arrow_kind(arr.type)
        values = arr.to_pylist()
        change = field_change(kind, values, fmt)
        if change is None:
            continue
        as_text, what = change
        notes.append(f"{where}: field {name!r} {what}")
        if as_text:
            out = out.copy() if out is gdf else out
            out[name] = _pandas_column(
                pa.array([text_value(v, kind) for v in values], type=pa.string()))
    return out, notes


FLAGGED_COLUMNS = ["kind", "image", "point", "point_kind", "component", "unit", "residual", "w",
                   "redundancy", "suspected_error", "mdb", "line", "observation"]


def _write_flagged(rows: list, path: Path) -> None:
    """The flagged observations (w-test) as CSV, largest |w| first."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=FLAGGED_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in FLAGGED_COLUMNS})


def _ready(frame, step, name: str):
    """The frame itself, or the result of a deferred one (``frame(progress)``)."""
    if not callable(frame):
        return frame
    step(f"building the {name} layer")
    return frame(step.within)


class _Steps:
    """Progress and cancel between the stages of :func:`write_outputs`."""

    def __init__(self, progress, is_cancelled, total: int) -> None:
        self.progress, self.is_cancelled, self.total, self.n = progress, is_cancelled, total, 0

    def __call__(self, message: str) -> None:
        if self.is_cancelled is not None and self.is_cancelled():
            raise CancelledError("Writing the outputs was cancelled", "Run it again when ready")
        if self.progress is not None:
            self.progress(min(0.95, self.n / self.total), message)
        self.n += 1

    def within(self, fraction: float, message: str) -> None:
        """Progress inside the current step (``fraction`` of it done)."""
        if self.progress is not None:
            self.progress(min(0.95, (self.n - 1 + fraction) / self.total), message)


def write_outputs(run: AdjustmentRun, out_dir, fmt: str = "gpkg",
                  extra_json: Optional[dict] = None, bands: bool = True,
                  progress=None, is_cancelled=None) -> dict:
    """Write ``adjusted.gpkg`` (or four shapefiles) and ``summary.json`` into ``out_dir``.

    The files are written into a staging folder and moved into place only when all are
    written (:class:`RunFolder`). Called while a :class:`RunFolder` of ``out_dir`` (or of a
    folder holding it) is open in this process, they go into its staging folder and its
    commit moves them, with the run's other files; otherwise this call is a run of its
    own: ``out_dir`` is locked, the files move into place at the end, the previous run's
    files that this one did not write (another format) are removed and
    :data:`MANIFEST` is written last.

    Parameters
    ----------
    run : AdjustmentRun
    out_dir : str or os.PathLike
        Created if missing; existing outputs of the same names are replaced.
    fmt : {"gpkg", "shp"}
    extra_json : dict, optional
        More keys for summary.json.
    bands : bool or callable
        Also write the ``uncertainty_bands`` layer (90 % G-band of every measured
        road segment, Shi & Liu 2000). A callable ``bands(progress)`` returns that
        layer's frame when it is needed, after the other layers are written (the command
        line builds it in a second process meanwhile).
    progress : callable, optional
        ``progress(fraction, message)`` before each table is built and each layer written.
    is_cancelled : callable, optional
        Polled at the same points; true raises :class:`CancelledError` and nothing of
        this call is left in ``out_dir``.

    Returns
    -------
    dict
        Paths written (where they end up), by name.

    Raises
    ------
    InputFileError
        The format is unknown, ``out_dir`` cannot be written, another run is writing
        into it, or the disk is full (the previous result is then left as it was).
    """
    if fmt not in ("gpkg", "shp"):
        raise InputFileError(f"Output format {fmt!r} is not supported", "Use gpkg or shp")
    out = Path(out_dir)
    folder = RunFolder.holding(out)
    if folder is not None:
        written = _write_staged(run, folder, out, fmt, extra_json, bands, progress,
                                is_cancelled)
    else:
        with RunFolder(out, command="write_outputs") as own:
            written = _write_staged(run, own, out, fmt, extra_json, bands, progress,
                                    is_cancelled)
            own.commit()
    if progress is not None:
        progress(1.0, "outputs written")
    return written


def _frames(run: AdjustmentRun, bands, step, is_cancelled) -> dict:
    """The layers to write, by name (tables, or callables building them when needed)."""
    frames = {}
    for name, make in (("shape_points", shape_points_frame), ("features", features_frame),
                       ("control_points", control_points_frame)):
        step(f"building the {name} table")
        table = None
        if name == "shape_points" and run.databases and _arrow_writing():
            table = shape_points_table(run)  # straight to GDAL's Arrow interface
        frames[name] = table if table is not None else make(run)
    if callable(bands) and run.databases:  # built elsewhere: asked for when written
        frames["uncertainty_bands"] = bands
    elif bands and run.databases:
        from vectoradjust.files.derived_outputs import uncertainty_bands_frame

        step("building the uncertainty_bands layer")
        frames["uncertainty_bands"] = uncertainty_bands_frame(
            run, progress=step.within, is_cancelled=is_cancelled)
    return frames


def _write_layers(frames: dict, tmp: Path, fmt: str, step) -> tuple:
    """Every layer into ``tmp``; (file names, GDAL's warnings). Each table is let go once
    written: the memory of a written layer is free for the next one (the bands layer,
    last, waits for its processes meanwhile)."""
    notes: list = []
    names: list = []
    for name in list(frames):
        gdf = _ready(frames.pop(name), step, name)
        if fmt == "gpkg":
            step(f"writing the {name} layer")
            notes += _write_layer(gdf, tmp / "adjusted.gpkg", name, fmt)
        else:
            step(f"writing {name}.shp")
            notes += _write_layer(gdf, tmp / f"{name}.shp", None, fmt)
            names += [p.name for p in tmp.glob(f"{name}.*")]
        del gdf
    return (["adjusted.gpkg"] if fmt == "gpkg" else names), notes


def _write_staged(run: AdjustmentRun, folder: RunFolder, out: Path, fmt: str,
                  extra_json: Optional[dict], bands, progress, is_cancelled) -> dict:
    """The files of :func:`write_outputs` written into ``folder``'s staging folder."""
    step = _Steps(progress, is_cancelled, 8 if bands and run.databases else 7)
    frames = _frames(run, bands, step, is_cancelled)
    tmp = folder.staged(out)
    tmp.mkdir(parents=True, exist_ok=True)
    names, notes = _write_layers(frames, tmp, fmt, step)
    if notes:  # into the run's warnings (printed, in summary.json and the report)
        run.summary["warnings"] = list(run.summary.get("warnings", [])) + notes
    if run.flagged:
        _write_flagged(run.flagged, tmp / "flagged_observations.csv")
        names.append("flagged_observations.csv")
    if any(im.model == "rpc" for im in run.data.images):
        from vectoradjust.files.rpc import write_corrected_rpcs

        names += write_corrected_rpcs(run, tmp, out)  # also notes them in the summary
    step("writing summary.json")
    summary = dict(run.summary)
    summary["renamed_input_fields"] = renamed_input_fields(run_input_fields(run))
    if extra_json:
        summary.update(extra_json)
    summary, feature_csv = move_feature_statements(summary, tmp)  # summary.json bounded
    if feature_csv is not None:
        names.append(feature_csv.name)
    with open(tmp / "summary.json", "w", encoding="utf-8") as fh:
        json.dump(clean_json(summary), fh, indent=2, default=json_default)
    names.append("summary.json")
    # an earlier run's, when this one has none: removed by the commit
    folder.claim("flagged_observations.csv", FEATURE_ACCURACY_CSV, under=out)
    return {n: str(out / n) for n in names}


# ----------------------------------------------------------------- the run's folder
__all__ += ["RunFolder", "DirLock", "MANIFEST", "LOCK_NAME", "is_disk_full", "read_manifest"]

#: the record of a finished run, moved into its folder last: every file of the run with
#: its size and SHA-256 and ``"complete": true``. A folder whose manifest is missing, or
#: says ``"complete": false``, or does not match the files, holds no complete result.
MANIFEST = "run_manifest.json"
#: the lock of a folder while a run writes into it (the writing process's pid inside)
LOCK_NAME = ".vectoradjust.lock"
#: the staging folder of a run inside its output folder (hidden; removed at the end)
_STAGE_PREFIX = ".vectoradjust-stage-"
#: temporaries of runs (staging folders, band shares, probes) left by a killed run
_LEFTOVER_PREFIXES = (".vectoradjust-", ".vectoradjust-probe-")
#: file names the commands write: such files in a folder that no manifest claims are
#: reported (they may be left by a run of an older version, or be the user's)
_PRODUCT_NAMES = frozenset(
    ["adjusted.gpkg", "summary.json", "report.html", "qa.json", "flagged_observations.csv",
     FEATURE_ACCURACY_CSV, "truth_points.csv", "truth_line_points.csv", "compare.csv",
     "compare.json", "common_points.csv"]
    + [f"{stem}.{ext}" for stem in ("shape_points", "features", "control_points",
                                    "uncertainty_bands")
       for ext in ("shp", "shx", "dbf", "prj", "cpg")])
#: the files a user opens first are moved into place last
_LAST = ("report.html", "summary.json")

_ACTIVE: dict = {}  # real path of a folder -> its RunFolder open in this process
_LOCK_FDS: set = set()  # descriptors of the locks this process holds


def _close_locks_in_child() -> None:
    """A forked child (band shares, the report) holds no lock of its parent: the lock
    ends with the run's own process, not with a child left running after a kill."""
    for fd in list(_LOCK_FDS):
        try:
            os.close(fd)
        except OSError:
            pass
    _LOCK_FDS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_locks_in_child)


def _now() -> str:
    import datetime

    return datetime.datetime.now().astimezone().isoformat(timespec="seconds")


def _try_lock(fd: int) -> bool:
    """An exclusive, non-blocking lock on the open file ``fd`` (False: held elsewhere).
    The system lets go of it when the holding process ends, however it ends."""
    try:
        import fcntl
    except ImportError:  # Windows: a byte far beyond the text, so the pid stays readable
        import msvcrt

        os.lseek(fd, 1 << 20, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # BlockingIOError: another process holds it
        return False
    return True


def _holder(fd: int) -> dict:
    """The lock file's record of its holder (empty when unreadable)."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        doc = json.loads(os.read(fd, 4096).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _busy_error(folder: Path, lock: Path, holder: dict) -> InputFileError:
    who = []
    if holder.get("pid"):
        who.append(f"pid {holder['pid']}")
    if holder.get("host") and holder.get("host") != _hostname():
        who.append(f"on {holder['host']}")
    if holder.get("command"):
        who.append(str(holder["command"]))
    if holder.get("started"):
        who.append(f"since {holder['started']}")
    return InputFileError(
        f"Another vectoradjust run{' (' + ', '.join(who) + ')' if who else ''} is writing "
        f"into the output directory {str(folder)!r}",
        "Wait until it has finished, or give this run another output directory (--out): "
        "two runs into one folder would mix their files",
        path=str(folder), details={"lock": str(lock), **holder})


def _hostname() -> str:
    import socket

    return socket.gethostname()


class DirLock:
    """An exclusive lock on an output folder: the file ``.vectoradjust.lock`` in it,
    holding the pid, host, command and start of the run that writes there.

    The lock itself is the system's (``flock``; on Windows ``msvcrt.locking``), which
    ends with the holding process however it ends: a run that was killed leaves the file,
    with its dead pid, and the next run takes it over. A second run while the first
    lives gets a clear error (:class:`~vectoradjust.errors.InputFileError`) naming the
    first one's pid. Forked children do not hold their parent's lock.

    Parameters
    ----------
    folder : str or os.PathLike
        An existing folder.
    command : str
        What holds it (shown to a second run).
    """

    def __init__(self, folder, command: str = "vectoradjust") -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.command = command
        self.fd: Optional[int] = None
        self.pid: Optional[int] = None
        #: the record of the lock's previous holder, a run that ended without letting go
        #: (killed), or None
        self.taken_over: Optional[dict] = None

    def acquire(self) -> DirLock:
        """Take the lock (OSError: the folder is not writable; InputFileError: held)."""
        for _ in range(100):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            if not _try_lock(fd):
                holder = _holder(fd)
                os.close(fd)
                raise _busy_error(self.folder, self.path, holder)
            if _same_file(fd, self.path):  # not removed by its holder meanwhile
                break
            os.close(fd)
        else:  # pragma: no cover - a lock file replaced a hundred times in a row
            raise _busy_error(self.folder, self.path, {})
        old = _holder(fd)
        self.taken_over = old if old.get("pid") else None
        record = {"pid": os.getpid(), "host": _hostname(), "command": self.command,
                  "started": _now()}
        os.lseek(fd, 0, os.SEEK_SET)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps(record).encode("utf-8"))
        self.fd, self.pid = fd, os.getpid()
        _LOCK_FDS.add(fd)
        return self

    def release(self) -> None:
        """Let go (the file is removed); nothing in a forked child or when not held."""
        if self.fd is None or self.pid != os.getpid():
            return
        fd, self.fd = self.fd, None
        _LOCK_FDS.discard(fd)
        if os.name == "posix":  # removed while held: no other run takes a removed file
            if _same_file(fd, self.path):
                _unlink(self.path)
            os.close(fd)
        else:
            os.close(fd)
            _unlink(self.path)

    def __enter__(self) -> DirLock:
        try:
            return self.acquire()
        except InputFileError:  # held by another run (an OSError too): says so itself
            raise
        except OSError as exc:
            raise InputFileError(
                f"Cannot write into the output directory {str(self.folder)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.folder)) from exc

    def __exit__(self, *exc) -> bool:
        self.release()
        return False


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _real(path) -> Path:
    return Path(os.path.realpath(os.fspath(path)))


def is_disk_full(exc: BaseException) -> bool:
    """True when ``exc`` (or an exception it was raised from) says the disk is full."""
    import errno

    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC,
                                                      getattr(errno, "EDQUOT", -1)):
            return True
        text = str(exc).lower()
        if any(s in text for s in ("no space left", "disk is full", "disk quota",
                                   "disk full")):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


#: a write error (GDAL, SQLite, OS) with less than this free on the disk is a full disk:
#: SQLite's own message can be lost ("cannot rollback - no transaction is active")
NEARLY_FULL_BYTES = 4 * 1024 * 1024


def _write_error_on_a_full_disk(exc: BaseException, folder: Path) -> bool:
    """A GDAL/OGR, SQLite or OS write error while the disk of ``folder`` is (nearly)
    full."""
    names = {type(e).__name__ for e in (exc, exc.__cause__, exc.__context__) if e is not None}
    if not (names & {"DataLayerError", "DataSourceError", "FieldError", "GeometryError",
                     "CPLE_AppDefinedError", "CPLE_FileIOError", "OperationalError"}
            or (isinstance(exc, OSError) and not isinstance(exc, InputFileError))):
        return False  # (an InputFileError is an OSError too: the user's, not the disk's)
    try:
        probe = Path(folder)
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        return shutil.disk_usage(probe).free < NEARLY_FULL_BYTES
    except OSError:
        return False


def _disk_full_error(folder: Path, exc: BaseException) -> InputFileError:
    import errno

    text = " ".join(str(exc).split())[:200]
    cause = exc
    for _ in range(10):  # the system's own words, without the staging folder's name
        if cause is None:
            break
        if isinstance(cause, OSError) and cause.errno == errno.ENOSPC and cause.strerror:
            text = cause.strerror
            break
        cause = cause.__cause__ or cause.__context__
    return InputFileError(
        f"The disk of the output directory {str(folder)!r} is full ({text})",
        "Free some space or choose another directory with --out: a run needs room for all "
        "its new files beside the previous run's until it has finished (the previous "
        "result in the folder is left as it was)", path=str(folder))


def read_manifest(folder) -> Optional[dict]:
    """The :data:`MANIFEST` of ``folder`` (None: none, or not one of vectoradjust's)."""
    try:
        doc = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != "vectoradjust" or \
            not isinstance(doc.get("files"), dict):
        return None
    return doc


def _inside(folder: Path, rel: str) -> bool:
    """``rel`` names a file in ``folder`` (a manifest cannot point outside it)."""
    from pathlib import PurePosixPath

    p = PurePosixPath(rel)
    return bool(rel) and not p.is_absolute() and ".." not in p.parts and \
        not p.parts[0].startswith(".") and rel != MANIFEST


def _staged_files(stage: Path) -> list:
    """The run's files in its staging folder (relative POSIX paths; hidden ones, the
    temporaries, left out)."""
    out = []
    for root, dirs, files in os.walk(stage):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        rel = Path(root).relative_to(stage)
        out += [(rel / f).as_posix() for f in sorted(files) if not f.startswith(".")]
    return out


def _file_entry(path: Path) -> dict:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return {"size": path.stat().st_size, "sha256": h.hexdigest()}


def _write_doc(path: Path, doc: dict) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1, default=json_default)


def _listed(names: list, n: int = 8) -> str:
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


class RunFolder:
    """An output folder written as one whole: locked, staged, moved into place, recorded.

    Inside ``with RunFolder(out) as folder:`` every file of the run is written into
    ``folder.stage`` (a hidden folder in ``out``); :meth:`commit` moves them into place
    and writes :data:`MANIFEST` last. A run that fails, is cancelled or interrupted
    (Ctrl-C) leaves the folder as it was: the staging folder is removed on the way out.
    A run killed outright leaves its hidden staging folder and lock file, which the next
    run into the folder removes and takes over; the previous result stays complete.

    The commit removes the files of the previous run (those its manifest lists, and the
    :meth:`claim`-ed names) that this run did not write: a re-run in another format
    leaves no old layers beside the new ones. Files named like outputs but claimed by
    no manifest are left and reported in :attr:`notes`. While the commit moves the files
    (milliseconds), the manifest says ``"complete": false``: a run killed right then
    leaves a folder that says it is incomplete, never a mix that looks complete.

    :func:`write_outputs` called on ``out`` (or a folder inside it) while it is open
    writes into the staging folder (:meth:`holding`).

    Parameters
    ----------
    path : str or os.PathLike
        The output folder; created if missing (and removed again if the run left it
        empty).
    command : str
        The command writing it (in the lock and the manifest).

    Raises
    ------
    InputFileError
        On entering: the folder cannot be made or written, or another run holds it
        (:class:`DirLock`). On leaving with an exception that says the disk is full: that,
        with what to do.
    """

    def __init__(self, path, command: str = "adjust") -> None:
        self.path = Path(path)
        self.command = command
        self.stage: Optional[Path] = None
        #: what the run should be told: ``(kind, text)``, kind ``"info"`` or ``"warning"``
        self.notes: list = []
        self.claimed: set = set()
        self.committed = False
        self._lock = DirLock(self.path, command)
        self._made = False
        self._pid: Optional[int] = None
        self._started = _now()

    @staticmethod
    def holding(path) -> Optional[RunFolder]:
        """The open RunFolder of this process that ``path`` lies in, or None."""
        p = _real(path)
        for q in (p, *p.parents):
            f = _ACTIVE.get(q)
            if f is not None and f._pid == os.getpid():
                return f
        return None

    def staged(self, path) -> Path:
        """Where a file or folder meant for ``path`` (in this folder) is written now."""
        return self.stage / _real(path).relative_to(_real(self.path))

    def final(self, path) -> Path:
        """Where a file written into the staging folder ends up."""
        return self.path / _real(path).relative_to(_real(self.stage))

    def claim(self, *names, under=None) -> None:
        """Names of files this run owns in the folder (``under`` a folder in it) whether
        it writes them or not: left from an earlier run and not written now, they go."""
        base = _real(under if under is not None else self.path).relative_to(_real(self.path))
        self.claimed.update((base / n).as_posix() for n in names)

    def __enter__(self) -> RunFolder:
        self._made = False
        try:
            self._made = not self.path.exists()  # (PermissionError above an unsearchable folder)
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock.acquire()
        except InputFileError:  # held by another run (an OSError too): says so itself
            self._drop_made()
            raise
        except OSError as exc:
            self._drop_made()
            raise InputFileError(
                f"Cannot write into the output directory {str(self.path)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.path)) from exc
        except BaseException:
            self._drop_made()
            raise
        self._pid = os.getpid()
        try:
            self._clear_leftovers()
            self.stage = Path(tempfile.mkdtemp(prefix=_STAGE_PREFIX, dir=self.path))
        except OSError as exc:
            self._lock.release()
            self._drop_made()
            raise InputFileError(
                f"Cannot write into the output directory {str(self.path)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.path)) from exc
        _ACTIVE[_real(self.path)] = self
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self._pid != os.getpid():  # a forked child leaving the parent's frame
            return False
        _ACTIVE.pop(_real(self.path), None)
        if self.stage is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self.stage = None
        self._lock.release()
        self._drop_made()
        if exc is not None and not isinstance(exc, (CancelledError, KeyboardInterrupt)) \
                and (is_disk_full(exc) or _write_error_on_a_full_disk(exc, self.path)):
            raise _disk_full_error(self.path, exc) from exc
        return False

    def _drop_made(self) -> None:
        """The folder removed again when this run made it and left nothing in it."""
        if self._made:
            try:
                self.path.rmdir()
            except OSError:
                pass

    def _clear_leftovers(self) -> None:
        """The temporaries of a run into this folder that was killed (its staging folder,
        its band shares): nobody else writes there while the lock is ours."""
        gone = []
        for p in self.path.iterdir():
            if p.name != LOCK_NAME and p.name.startswith(_LEFTOVER_PREFIXES):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    _unlink(p)
                gone.append(p.name)
        old = self._lock.taken_over
        if gone or (old and old.get("pid") != os.getpid()):
            pid = f" (pid {old['pid']})" if old and old.get("pid") else ""
            self.notes.append(("info", f"an earlier run into {self.path}{pid} did not finish; "
                               "its lock and temporary files were taken over and removed"))

    def commit(self) -> list:
        """Move the staged files into place, remove the previous run's files this run did
        not write, and write the manifest last.

        Returns
        -------
        list of (str, str)
            :attr:`notes`: the previous run's files removed, files named like outputs that
            no manifest claims (left where they are).
        """
        new = _staged_files(self.stage)
        entries = {rel: _file_entry(self.stage / rel) for rel in new}
        ours, sizes = self._previous_files()
        stale = sorted(r for r in ours - set(new) if (self.path / r).is_file()
                       and (sizes.get(r) is None or (self.path / r).stat().st_size == sizes[r]))
        foreign = sorted(p.name for p in self.path.iterdir()
                         if p.name in _PRODUCT_NAMES and p.is_file()
                         and p.name not in entries and p.name not in ours)
        doc = {"written_by": "vectoradjust", "command": self.command, "complete": False,
               "started": self._started, "files": entries, "earlier": sorted(ours)}
        pending, done = self.stage / ".pending.json", self.stage / ".done.json"
        _write_doc(pending, doc)
        doc.pop("earlier")
        doc.update(complete=True, finished=_now(), removed=stale, not_of_this_run=foreign)
        _write_doc(done, doc)
        os.replace(pending, self.path / MANIFEST)  # from now on: incomplete
        for rel in stale:
            _unlink(self.path / rel)
            self._prune(Path(rel).parent)
        for rel in sorted(new, key=lambda r: (_LAST.index(Path(r).name) + 1
                                              if Path(r).name in _LAST else 0, r)):
            (self.path / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.stage / rel, self.path / rel)
        os.replace(done, self.path / MANIFEST)  # complete
        self.committed = True
        if stale:
            self.notes.append(("info", f"removed {len(stale)} file(s) of the previous run "
                               f"that this run did not write: {_listed(stale)}"))
        if foreign:
            self.notes.append(("warning", f"{self.path} holds {len(foreign)} file(s) named like "
                               f"vectoradjust outputs that this run did not write and no "
                               f"{MANIFEST} claims: {_listed(foreign)}; they are not part of "
                               "this result (delete them if an earlier run left them)"))
        return self.notes

    def _previous_files(self) -> tuple:
        """The files the folder's manifest claims (also those an interrupted commit was
        replacing) and the claimed names, with the sizes the manifest gives."""
        doc = read_manifest(self.path) or {"files": {}, "complete": True}
        # (an interrupted commit: some files old, some new; all of them the runs')
        sizes = {r: (e.get("size") if isinstance(e, dict) and doc.get("complete") is True
                     else None) for r, e in doc["files"].items()}
        earlier = doc.get("earlier") if isinstance(doc.get("earlier"), list) else []
        ours = {r for r in [*sizes, *earlier, *self.claimed]
                if isinstance(r, str) and _inside(self.path, r)}
        return ours, {r: s for r, s in sizes.items() if isinstance(s, int)}

    def _prune(self, rel: Path) -> None:
        """Empty folders left by removed files (up to the run's folder)."""
        while rel.parts:
            try:
                (self.path / rel).rmdir()
            except OSError:
                return
            rel = rel.parent
