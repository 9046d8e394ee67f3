"""The output layers as tables: shape points, features and control points.

:func:`shape_points_frame`, :func:`features_frame` and :func:`control_points_frame` build
the GeoDataFrames of ``adjusted.gpkg`` (geopandas and shapely imported inside the
functions); :func:`shape_points_table` the shape points as an Arrow table for GDAL.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.accuracy.tables import shape_point_column
from vectoradjust.files.outputs.fields import (
    CONTROL_FIELDS,
    FEATURE_FIELDS,
    SHAPE_FIELDS,
    _pandas_column,
    attribute_array,
    input_field_types,
    renamed_input_fields,
    run_input_fields,
)
from vectoradjust.results import AdjustmentRun

__all__ = [
    "shape_points_frame",
    "features_frame",
    "control_points_frame",
    "shape_points_table",
]


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
