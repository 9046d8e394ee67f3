"""Writing the contract's outputs: ``adjusted.gpkg`` (or shapefiles) and ``summary.json``.

Everything is written to a temporary directory first and moved into place only when
all files were written, so a failing run leaves nothing half-written.
"""

from __future__ import annotations

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

from vectoradjust.errors import CancelledError, InputFileError
from vectoradjust.files.jsonfile import (
    FEATURE_ACCURACY_CSV,
    clean_json,
    move_feature_statements,
)
from vectoradjust.results import AdjustmentRun

__all__ = ["write_outputs", "shape_points_frame", "features_frame", "control_points_frame",
           "json_default", "renamed_input_fields", "run_input_fields"]

SHAPE_FIELDS = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ",
                "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "CE90_meas", "LE90_meas",
                "NImages", "Adjusted", "Database", "Source"]
FEATURE_FIELDS = ["NPts", "NAdj", "RMSE_X", "RMSE_Y", "RMSE_Z", "RMSE", "Length", "LengthSD",
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
        cols = {f: _nullable(v[f], adj) if f in _MASKED_SHAPE_FIELDS else _nullable(v[f])
                for f in SHAPE_FIELDS}
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
        col = np.concatenate([np.asarray(d.vertices[f]) for d in dbs])
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
    import shapely

    layer = d.shape.layer
    nf = layer.n_features
    out = [None] * nf
    if len(layer.coords) == 0:
        return out
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
        parts = [p for p in parts if len(p) >= 2] or parts
        if len(parts) == 1:
            out[f] = shapely.linestrings(parts[0]) if len(parts[0]) >= 2 else shapely.points(
                parts[0][0])
        else:
            out[f] = shapely.multilinestrings(
                [shapely.linestrings(p) for p in parts if len(p) >= 2])
    return out


def features_frame(run: AdjustmentRun):
    """GeoDataFrame of the ``features`` layer: every input feature and attribute kept."""
    import geopandas as gpd
    import pandas as pd

    renamed = renamed_input_fields(run_input_fields(run))
    frames = []
    for d in run.databases:
        layer = d.shape.layer
        cols: dict = {}
        for name, values in layer.attributes.items():
            cols[renamed.get(name, name)] = list(values)
        for f in FEATURE_FIELDS:
            if f == "Database":
                cols[f] = [d.name] * layer.n_features
            else:
                cols[f] = _nullable(d.features[f])
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
    """Write one layer; returns GDAL's warnings as run warnings instead of printing them."""
    with warnings.catch_warnings(record=True) as caught, _unsynced_sqlite():
        warnings.simplefilter("always")
        if hasattr(gdf, "write"):  # a LayerTable (Arrow, WKB): straight to GDAL
            gdf.write(path, layer, "GPKG" if fmt == "gpkg" else "ESRI Shapefile")
        elif fmt == "gpkg":
            gdf.to_file(path, layer=layer, driver="GPKG", engine="pyogrio", **_arrow_writing())
        else:
            gdf.to_file(path, driver="ESRI Shapefile", engine="pyogrio", encoding="UTF-8")
    where = f"{path.name} layer {layer}" if layer else path.name
    out: list = []
    for w in caught:
        text = _writer_warning(str(w.message), where)
        if text and text not in out:
            out.append(text)
    return out


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
    """Write ``adjusted.gpkg`` (or three shapefiles) and ``summary.json`` into ``out_dir``.

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
        Paths written, by name.
    """
    if fmt not in ("gpkg", "shp"):
        raise InputFileError(f"Output format {fmt!r} is not supported", "Use gpkg or shp")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"Cannot create the output directory {str(out)!r} ({exc})",
                             "Choose a writable directory with --out") from exc
    step = _Steps(progress, is_cancelled, 8 if bands and run.databases else 7)
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
    tmp = Path(tempfile.mkdtemp(prefix=".vectoradjust-", dir=out))
    written = {}
    try:
        notes: list = []
        # each table is let go once written: the memory of a written layer is free for
        # the next one (the bands layer, last, waits for its processes meanwhile)
        if fmt == "gpkg":
            for name in list(frames):
                gdf = _ready(frames.pop(name), step, name)
                step(f"writing the {name} layer")
                notes += _write_layer(gdf, tmp / "adjusted.gpkg", name, fmt)
                del gdf
            names = ["adjusted.gpkg"]
        else:
            names = []
            for name in list(frames):
                gdf = _ready(frames.pop(name), step, name)
                step(f"writing {name}.shp")
                notes += _write_layer(gdf, tmp / f"{name}.shp", None, fmt)
                del gdf
                names += [p.name for p in tmp.glob(f"{name}.*")]
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
        for n in names:
            os.replace(tmp / n, out / n)
            written[n] = str(out / n)
        for n in ("flagged_observations.csv", FEATURE_ACCURACY_CSV):
            if n not in names and (out / n).is_file():  # an earlier run's, not this one's
                (out / n).unlink()
        if progress is not None:
            progress(1.0, "outputs written")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return written
