"""Writing the derived products: uncertainty bands (polygons) and the equal-error map.

* :func:`uncertainty_bands_frame` / :func:`write_uncertainty_bands`: the G-bands
  (:func:`vectoradjust.accuracy.derived.segment_bands`) of every road feature, the segments'
  bands united per feature with shapely, as a polygon layer ``uncertainty_bands``
  (fields ``database``, ``feature_id``, ``confidence``, ``NSeg``) - in
  ``adjusted.gpkg`` beside the contract's layers, or as a shapefile.
* :func:`write_equal_error_map`: the equal-error grid
  (:func:`vectoradjust.accuracy.derived.equal_error_grid`) as a 3-band float32 GeoTIFF
  (sigma X, sigma Y, sigma Z in metres; nodata outside the stereo overlap).

Geodata libraries (geopandas, shapely, rasterio) are imported inside the functions.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np

from vectoradjust.accuracy.derived import EqualErrorGrid, band_segment_counts, segment_bands
from vectoradjust.errors import CancelledError, InputFileError

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun

__all__ = [
    "BAND_FIELDS",
    "uncertainty_bands_frame",
    "merge_band_parts",
    "LayerTable",
    "uncertainty_bands_file",
    "merge_band_files",
    "write_uncertainty_bands",
    "write_equal_error_map",
    "write_conflation_rasters",
    "EQUAL_ERROR_NODATA",
]

BAND_FIELDS = ["database", "feature_id", "confidence", "NSeg"]
EQUAL_ERROR_NODATA = -9999.0


def uncertainty_bands_frame(run: AdjustmentRun, confidence: float = 0.9, progress=None,
                            is_cancelled=None, part: tuple = (0, 1), **kwargs):
    """GeoDataFrame of the uncertainty bands: one (Multi)Polygon per road feature.

    Each feature's band is the union of the G-bands of its segments
    (:func:`vectoradjust.accuracy.derived.segment_bands`: measured segments from their
    joint covariance and the identification error, segments with a conflated end from
    the conflation's covariance once the run is conflated); features without a segment
    with a covariance at both ends are left out.

    Parameters
    ----------
    run : AdjustmentRun
    confidence : float
        Probability of the error ellipses (default 0.9).
    progress : callable, optional
        ``progress(fraction, message)`` per database, per chunk of about 1000 segments
        (their bands) and per chunk of whole features (their union).
    is_cancelled : callable, optional
        Polled as often; true raises :class:`vectoradjust.errors.CancelledError`.
    part : (int, int)
        ``(i, n)``: only the features whose index is ``i`` modulo ``n``, with their
        index in a column ``_feature`` (:func:`merge_band_parts` puts ``n`` parts
        together in the order of one whole frame); default all, no extra column.
    **kwargs
        ``n_pairs``, ``n_directions`` of :func:`vectoradjust.accuracy.derived.g_band_batch`;
        ``segments`` (``"all"``, ``"measured"``, ``"other"``) and ``only`` (database
        names) of :func:`_band_chunks`.

    Returns
    -------
    geopandas.GeoDataFrame
        Columns :data:`BAND_FIELDS` and the geometry (always MultiPolygon), in the
        run's CRS.
    """
    import geopandas as gpd
    import pandas as pd

    cols: dict = {f: [] for f in BAND_FIELDS}
    order: list = []
    geoms: list = []
    for name, feats, fids, counts, chunk in _band_chunks(run, confidence, progress,
                                                         is_cancelled, part, **kwargs):
        geoms += chunk
        cols["database"] += [name] * len(feats)
        cols["feature_id"] += [str(f) for f in fids]
        cols["confidence"] += [float(confidence)] * len(feats)
        cols["NSeg"] += counts.tolist()
        order += feats.tolist()
    if part[1] > 1:
        cols["_feature"] = order
    frame = pd.DataFrame(cols)
    frame["NSeg"] = frame["NSeg"].astype("int64")
    frame["confidence"] = frame["confidence"].astype(float)
    return gpd.GeoDataFrame(frame, geometry=gpd.GeoSeries(geoms, crs=run.data.crs),
                            crs=run.data.crs)


def _band_chunks(run: AdjustmentRun, confidence: float, progress, is_cancelled,
                 part: tuple, segments: str = "all", only=None, **kwargs):
    """The bands of every database a chunk of whole features at a time.

    Yields ``(database, feature indices, feature ids, segment counts, polygons)`` per
    chunk of :func:`_union_chunks`, in the order of the layer (database, then feature):
    a consumer that writes each chunk at once holds one chunk's polygons only.
    ``segments`` as :func:`segment_bands`; ``only``: these databases (default all).

    A conflated database's bands (``segments = "all"``) are those of its measured
    segments united with those of its conflated ones, feature by feature: the same
    polygons as when the measured ones were built before the conflation, in another
    process, and the conflated ones added afterwards (:func:`merge_band_parts`,
    :func:`merge_band_files`).
    """
    dbs = [d for d in run.databases if only is None or d.name in only]
    for i, d in enumerate(dbs):
        lo, hi = i / len(dbs), (i + 1) / len(dbs)
        if segments != "all" or band_segment_counts(run, d)[1] == 0:
            yield from _segment_chunks(run, d, confidence, progress, is_cancelled, part,
                                       segments, (lo, hi), **kwargs)
            continue
        mid = 0.5 * (lo + hi)
        rows = [list(_segment_chunks(run, d, confidence, progress, is_cancelled, part,
                                     which, where, **kwargs))
                for which, where in (("measured", (lo, mid)), ("other", (mid, hi)))]
        yield from _joined(d.name, [r for rs in rows for r in rs])


def _joined(name: str, rows: list, chunk: int = 5_000):
    """Rows of :func:`_segment_chunks` of the measured and then the conflated segments of
    one database as one row per feature (the two bands united, in that order), in
    chunks of ``chunk`` features."""
    if not rows:
        return
    f_all = np.concatenate([np.asarray(r[1], np.int64) for r in rows])
    fid = np.concatenate([np.asarray(r[2], dtype=object) for r in rows])
    cnt = np.concatenate([np.asarray(r[3], np.int64) for r in rows])
    geo = np.empty(len(f_all), dtype=object)
    geo[:] = [g for r in rows for g in r[4]]
    order = np.argsort(f_all, kind="stable")  # a feature's measured band first
    f_all, fid, cnt, geo = f_all[order], fid[order], cnt[order], geo[order]
    dup = np.flatnonzero(f_all[1:] == f_all[:-1]) + 1
    if dup.size:
        geo[dup - 1] = _united(geo[dup - 1], geo[dup])
        cnt[dup - 1] += cnt[dup]
    keep = np.ones(len(f_all), bool)
    keep[dup] = False
    f_all, fid, cnt, geo = f_all[keep], fid[keep], cnt[keep], geo[keep]
    for i in range(0, len(f_all), chunk):
        yield name, f_all[i:i + chunk], fid[i:i + chunk], cnt[i:i + chunk], \
            list(geo[i:i + chunk])


def _segment_chunks(run: AdjustmentRun, d, confidence: float, progress, is_cancelled,
                    part: tuple, segments: str, where: tuple, **kwargs):
    """:func:`_band_chunks` of one database and kind of segment (:func:`segment_bands`);
    ``where = (lo, hi)``: the share of the progress it reports in."""
    def step(fraction, what="segments"):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("Building the uncertainty bands was cancelled",
                                 "Run again, or leave the bands out (--no-bands)")
        if progress is not None:  # the bands of the segments, then their union
            done = 0.5 * fraction if what == "segments" else 0.5 + 0.5 * fraction
            progress(where[0] + done * (where[1] - where[0]),
                     f"uncertainty bands: {d.name} {what} {100 * fraction:3.0f} %")

    step(0.0)
    sb = segment_bands(run, d, confidence, part=part, progress=step, segments=segments,
                       **kwargs)
    if not sb.rings:
        return
    feats, counts = np.unique(sb.feature, return_counts=True)
    fids = d.shape.layer.feature_ids
    for g0, g1, chunk in _union_chunks(sb, np.searchsorted(feats, sb.feature), len(feats),
                                       lambda f: step(f, what="union")):
        yield d.name, feats[g0:g1], fids[feats[g0:g1]], counts[g0:g1], chunk


def _layer_key(run: AdjustmentRun, databases: list, features: np.ndarray) -> np.ndarray:
    """The sort key of band rows in the whole layer: by database (the run's order), then
    by feature index."""
    rank = {d.name: i for i, d in enumerate(run.databases)}
    return np.array([rank[x] for x in databases], np.int64) * (1 << 40) + \
        np.asarray(features, np.int64)


def _layer_order(run: AdjustmentRun, databases: list, features: np.ndarray) -> np.ndarray:
    """The order of band rows from several parts in the whole layer (:func:`_layer_key`)."""
    return np.argsort(_layer_key(run, databases, features), kind="stable")


def merge_band_parts(run: AdjustmentRun, parts: list):
    """The frames of :func:`uncertainty_bands_frame` ``part = (i, n)``, ``i = 0 .. n - 1``,
    as one frame in the order of the whole one (database, then feature)."""
    import pandas as pd

    parts = [p for p in parts if p is not None]
    if len(parts) == 1 and "_feature" not in parts[0].columns:
        return parts[0]
    frame = pd.concat(parts, ignore_index=True)
    need = _unbanded_conflation(run, frame["database"].tolist(), frame["NSeg"].to_numpy())
    if need:  # the parts were built before the conflation: its segments' bands here
        conf = float(frame["confidence"].iloc[0]) if len(frame) else 0.9
        extra = uncertainty_bands_frame(run, conf, part=(0, 1), segments="other", only=need)
        extra["_feature"] = _feature_index(run, extra)
        frame = pd.concat([frame, extra], ignore_index=True)
    order = _layer_order(run, frame["database"].tolist(), frame["_feature"].to_numpy())
    frame = frame.iloc[order].reset_index(drop=True)
    key = _layer_key(run, frame["database"].tolist(), frame["_feature"].to_numpy())
    dup = np.flatnonzero(key[1:] == key[:-1]) + 1  # a feature in a part and in the extra
    if dup.size:
        geo = frame.geometry.to_numpy()
        geo[dup - 1] = _united(geo[dup - 1], geo[dup])
        frame = frame.set_geometry(geo, crs=frame.crs)
        frame.loc[dup - 1, "NSeg"] = frame["NSeg"].to_numpy()[dup - 1] + \
            frame["NSeg"].to_numpy()[dup]
        frame = frame.drop(index=dup).reset_index(drop=True)
    return frame.drop(columns="_feature")


def _feature_index(run: AdjustmentRun, frame) -> np.ndarray:
    """Feature index of each row of a band frame without ``_feature``."""
    idx = np.zeros(len(frame), np.int64)
    for d in run.databases:
        m = (frame["database"] == d.name).to_numpy()
        if m.any():
            fids = np.asarray(d.shape.layer.feature_ids).astype(str)
            order = np.argsort(fids, kind="stable")
            pos = np.searchsorted(fids[order], frame["feature_id"].to_numpy()[m].astype(str))
            idx[m] = order[pos]
    return idx


def _unbanded_conflation(run: AdjustmentRun, databases: list, nseg: np.ndarray) -> list:
    """The databases whose bands were built before the conflation (the command line's
    band processes start right after the adjustment): their rows hold the measured
    segments only although the conflated ones have a covariance now."""
    got: dict = {}
    for name, n in zip(databases, np.asarray(nseg, np.int64)):
        got[name] = got.get(name, 0) + int(n)
    need = []
    for d in run.databases:
        n_meas, n_other = band_segment_counts(run, d)
        if n_other and got.get(d.name, 0) == n_meas:
            need.append(d.name)
    return need


def _united(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise union of two arrays of (Multi)Polygons, as MultiPolygons."""
    import shapely

    u = shapely.union(a, b)
    one = shapely.get_type_id(u) == 3
    if one.any():
        u[one] = shapely.multipolygons(u[one], indices=np.arange(int(one.sum())))
    return u


def _feature_unions(sb, group: np.ndarray, n: int, step, chunk: int = 50_000) -> list:
    """The union of each feature's segment bands (:func:`_union_chunks` put together)."""
    out: list = []
    for _, _, part in _union_chunks(sb, group, n, step, chunk):
        out += part
    return out


def _union_chunks(sb, group: np.ndarray, n: int, step, chunk: int = 50_000):
    """The union of each feature's segment bands, in chunks of whole features: yields
    ``(g0, g1, polygons of the features g0 .. g1 - 1)``.

    ``group`` (s,) numbers the features ``0 .. n - 1``; the segments' rings are made
    polygons (``make_valid`` where a ring touches itself) and united about ``chunk``
    segments at a time, so the GEOS copies of the rings stay bounded; ``step(fraction)``
    after every chunk. From ``derived._KERNEL_MIN`` segments on, with numba, by the
    compiled union (:func:`_kernel_union`, about five times faster than GEOS), else and
    for the features it leaves by GEOS (:func:`_union_per_feature`).
    """
    import shapely

    from vectoradjust.accuracy.derived import band_kernels as derived

    kernel = derived._union_kernel() if len(group) >= derived._KERNEL_MIN else None
    in_order = bool(np.all(group[1:] >= group[:-1]))  # segments feature by feature
    order = np.arange(len(group)) if in_order else np.argsort(group, kind="stable")
    starts = np.searchsorted(group[order], np.arange(n + 1))  # segments of each feature
    g0 = 0
    while g0 < n:
        g1 = int(np.searchsorted(starts, starts[g0] + chunk, side="right")) - 1
        g1 = min(max(g1, g0 + 1), n)
        seg = order[starts[g0]:starts[g1]]
        lo, hi = sb.offsets[seg], sb.offsets[seg + 1]
        sizes = hi - lo
        ok = sizes >= 4  # fewer points: a degenerate ring (no finite covariance), no area
        polys = np.full(len(seg), shapely.from_wkt("POLYGON EMPTY"), dtype=object)
        if in_order and ok.all():  # the rings of the chunk are one run of points
            xy = sb.xy[sb.offsets[starts[g0]]:sb.offsets[starts[g1]]]
        else:
            take = np.repeat(lo - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes) + \
                np.arange(int(sizes.sum()))
            xy = sb.xy[take[np.repeat(ok, sizes)]]
        polys[ok] = shapely.polygons(shapely.linearrings(
            xy, indices=np.repeat(np.arange(ok.sum()), sizes[ok])))
        bad = ~shapely.is_valid(polys)  # a ring may touch itself in degenerate cases
        polys[bad] = shapely.make_valid(polys[bad])
        if kernel is None:
            yield g0, g1, list(_union_per_feature(polys, group[seg] - g0, g1 - g0))
        else:
            usable = np.where(ok, np.where(bad, -1, 1), 0).astype(np.int8)
            yield g0, g1, list(_kernel_union(kernel, xy, np.where(ok, sizes, 0), usable,
                                             polys, starts[g0:g1 + 1] - starts[g0]))
        step(g1 / n)
        g0 = g1


def _kernel_union(kernel, xy: np.ndarray, sizes: np.ndarray, usable: np.ndarray,
                  polys: np.ndarray, fs: np.ndarray) -> np.ndarray:
    """:func:`_union_per_feature` by the compiled union
    (:func:`vectoradjust.accuracy._unionkernel.union_rings`) of features whose rings are
    in order: feature ``f`` has the rings ``fs[f] .. fs[f + 1] - 1``, ring ``r`` the
    ``sizes[r]`` points of ``xy`` after those of the rings before it (``usable``: 1 a
    valid ring, 0 none, -1 one not valid). The features it leaves are united by GEOS
    from their ``polys``."""
    import shapely

    n = len(fs) - 1
    off = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    closed = (xy[off[:-1][sizes > 0]] == xy[off[1:][sizes > 0] - 1]).all(axis=1)
    if not closed.all():  # the kernel takes closed rings only
        usable = usable.copy()
        usable[np.flatnonzero(sizes > 0)[~closed]] = -1
    pts, loops, lstart, status = kernel(np.ascontiguousarray(xy, dtype=float), off,
                                        np.asarray(fs, np.int64), usable, 1e-10)
    out = np.full(n, shapely.from_wkt("MULTIPOLYGON EMPTY"), dtype=object)
    if len(loops):
        rings = shapely.linearrings(pts, indices=np.repeat(np.arange(len(loops)),
                                                           loops[:, 1] - loops[:, 0]))
        outer = loops[:, 2] > 0  # each feature's outer loop before its holes
        parts = shapely.polygons(rings, indices=np.cumsum(outer) - 1)
        feature = np.repeat(np.arange(n), np.diff(lstart))[outer]
        have = np.unique(feature)
        out[have] = shapely.multipolygons(parts, indices=np.searchsorted(have, feature))
    left = np.flatnonzero(status)
    if len(left):  # by GEOS
        ring_feature = np.repeat(np.arange(n), np.diff(fs))
        take = np.isin(ring_feature, left)
        out[left] = _union_per_feature(polys[take], np.searchsorted(left, ring_feature[take]),
                                       len(left))
    return out


def _union_per_feature(polys: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:
    """The union of the polygons of every group, as MultiPolygons, all groups at once.

    shapely 2 array functions only: the (valid) polygons of a group are collected into
    one overlapping MultiPolygon and buffered by 0, which nodes all rings at once and
    keeps every point of positive depth - the union of the members, without a Python
    loop over features (and faster than ``union_all`` per feature or ``make_valid(...,
    method="structure")``; tests/test_derived.py checks it against ``union_all``).
    Returns ``n`` MultiPolygons (empty where a group has none).
    """
    import shapely

    def polygon_parts(geoms, index):
        parts, which = shapely.get_parts(geoms, return_index=True)
        ok = (shapely.get_type_id(parts) == 3) & ~shapely.is_empty(parts)
        return parts[ok], index[which[ok]]

    simple = shapely.get_type_id(polys) == 3
    if simple.all():  # no GeometryCollection from make_valid: the polygons are the parts
        parts, g = polys[~shapely.is_empty(polys)], group[~shapely.is_empty(polys)]
    else:
        parts, g = polygon_parts(polys, group)
    multi = np.full(n, None, dtype=object)
    if len(parts):
        have, g = np.unique(g, return_inverse=True)  # sorted; groups without parts left out
        order = np.argsort(g, kind="stable")
        multi[have] = shapely.multipolygons(parts[order], indices=g[order])
    multi = np.where(shapely.is_missing(multi), shapely.from_wkt("MULTIPOLYGON EMPTY"), multi)
    united = shapely.buffer(multi, 0.0)
    out = np.full(n, shapely.from_wkt("MULTIPOLYGON EMPTY"), dtype=object)
    kind = shapely.get_type_id(united)
    done = (kind == 6) & ~shapely.is_empty(united)
    out[done] = united[done]  # already MultiPolygons
    one = np.flatnonzero((kind == 3) & ~shapely.is_empty(united))
    if len(one):  # a single polygon: a MultiPolygon of one part
        out[one] = shapely.multipolygons(united[one], indices=np.arange(len(one)))
    rest = np.flatnonzero((kind != 3) & (kind != 6))
    if len(rest):  # anything else (a collection): its polygon parts
        parts, g = polygon_parts(united[rest], rest)
        if len(parts):
            built = shapely.multipolygons(parts, indices=g)
            have = np.unique(g)
            out[have] = built[have]
    return out


class LayerTable:
    """A layer as Arrow record batches with WKB geometries, written by GDAL's Arrow
    interface: no shapely object in the process that writes it.

    Parameters
    ----------
    batches : callable
        ``batches()`` returns a ``pyarrow.RecordBatchReader`` of the rows in order
        (attribute columns and a binary ``geometry`` column).
    crs : str
        The layer's CRS (anything pyproj reads).
    geometry_type : str
        OGR geometry type of the layer, e.g. ``"MultiPolygon"``.
    rows : int
        Number of features.
    """

    def __init__(self, batches, crs: str, geometry_type: str, rows: int) -> None:
        self.batches, self.crs, self.geometry_type, self.rows = batches, crs, geometry_type, rows

    def __len__(self) -> int:
        return self.rows

    def write(self, path, layer: Optional[str], driver: str) -> None:
        """Write the layer (replaces a layer of the same name; shapefiles as UTF-8)."""
        from pyogrio.raw import write_arrow
        from pyproj import CRS

        kw = {"encoding": "UTF-8"} if driver == "ESRI Shapefile" else {}
        write_arrow(self.batches(), str(path), layer=layer, driver=driver,
                    geometry_name="geometry", geometry_type=self.geometry_type,
                    crs=CRS.from_user_input(self.crs).to_wkt("WKT1_GDAL"), **kw)


def arrow_layers() -> bool:
    """True when layers can go between processes and to GDAL as Arrow data."""
    try:
        import pyarrow  # noqa: F401
        from pyogrio.raw import write_arrow  # noqa: F401
    except ImportError:
        return False
    return True


#: rows of the bands layer put in order and written at a time
BAND_BATCH = 5_000


def _band_schema():
    """Columns of a band file (:func:`uncertainty_bands_file`)."""
    import pyarrow as pa

    return pa.schema([("database", pa.string()), ("feature_id", pa.string()),
                      ("confidence", pa.float64()), ("NSeg", pa.int64()),
                      ("_feature", pa.int64()), ("geometry", pa.binary())])


def uncertainty_bands_file(run: AdjustmentRun, folder, confidence: float = 0.9,
                           progress=None, is_cancelled=None, part: tuple = (0, 1),
                           name: Optional[str] = None, **kwargs) -> str:
    """:func:`uncertainty_bands_frame` written to an Arrow IPC file in ``folder`` (a band
    process's result: the main process maps the file instead of receiving polygons),
    a chunk of features at a time as they are united.

    Columns :data:`BAND_FIELDS`, ``_feature`` (the feature's index) and ``geometry``
    (WKB); ``name`` the file's name (default ``bands_<i>_of_<n>.arrow``). Returns the
    file's path.
    """
    import pyarrow as pa
    import shapely

    schema = _band_schema()
    path = Path(folder) / (name or f"bands_{part[0]}_of_{part[1]}.arrow")
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(sink, schema) as w:
        # a chunk of features written as soon as it is united: the polygons of one chunk
        # are held at a time, not those of the whole share
        for name, feats, fids, counts, polys in _band_chunks(run, confidence, progress,
                                                             is_cancelled, part, **kwargs):
            wkb = shapely.to_wkb(np.asarray(polys, dtype=object), output_dimension=2)
            w.write_table(pa.table([
                pa.array([name] * len(feats), type=pa.string()),
                pa.array([str(f) for f in fids], type=pa.string()),
                pa.array(np.full(len(feats), float(confidence)), type=pa.float64()),
                pa.array(np.asarray(counts, np.int64), type=pa.int64()),
                pa.array(np.asarray(feats, np.int64), type=pa.int64()),
                pa.array(wkb, type=pa.binary())], schema=schema), max_chunksize=BAND_BATCH)
    return str(path)


def merge_band_files(run: AdjustmentRun, paths: list) -> LayerTable:
    """The files of :func:`uncertainty_bands_file` (parts ``(i, n)``) as one layer in the
    order of the whole one (database, then feature), as :func:`merge_band_parts`.

    Only the two key columns are read to put the rows in order. The rows themselves are
    read from the files when the layer is written, :data:`BAND_BATCH` at a time: each
    file is already in layer order, so a batch of the layer is a run of consecutive rows
    of every file. The polygons are not memory-mapped, so the writing process holds about
    one batch of them, not the whole layer.
    """
    paths = [str(p) for p in paths if p]
    keys, bounds = _band_file_keys(run, paths)
    plan = _merge_plan(paths, keys)

    def batches():
        return _merged_band_batches(paths, bounds, plan)

    return LayerTable(batches, str(run.data.crs), "MultiPolygon", int((~plan["dup"]).sum()))


def _band_file_keys(run: AdjustmentRun, paths: list) -> tuple:
    """Layer keys and record batch bounds of each band file in ``paths``; the bands of
    conflation segments the files lack (built before the conflation) are written to one
    more file, appended to ``paths``."""
    keys, bounds, names, nseg, conf = [], [], [], [], []
    for p in paths:
        k, b, nm, ns, c = _file_keys(run, p)
        keys.append(k), bounds.append(b), names.extend(nm), nseg.append(ns), conf.extend(c)
    need = _unbanded_conflation(run, names, np.concatenate(nseg) if nseg else np.zeros(0))
    if need and paths:  # built before the conflation: its segments' bands here
        extra = uncertainty_bands_file(run, Path(paths[0]).parent, conf[0] if conf else 0.9,
                                       segments="other", only=need,
                                       name="bands_conflated.arrow")
        k, b, *_ = _file_keys(run, extra)
        paths.append(extra), keys.append(k), bounds.append(b)
    return keys, bounds


def _merge_plan(paths: list, keys: list) -> dict:
    """How the rows of the band files interleave into the layer: ``order`` (rows of all
    files concatenated, in layer order), ``first`` (each file's first row), ``source``
    (each row's file), ``cuts`` (batch bounds, a feature's two rows in one batch) and
    ``dup`` (the second row of a feature, merged into the first)."""
    key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    order = np.argsort(key, kind="stable")
    first = np.concatenate([[0], np.cumsum([len(k) for k in keys], dtype=np.int64)])
    source = np.repeat(np.arange(len(paths)), np.diff(first))
    for f in range(len(paths)):  # each file in layer order: its rows come as they are
        if np.any(np.diff(keys[f]) <= 0):
            raise ValueError(f"{paths[f]}: the band rows are not in layer order")
    skey = key[order]
    cuts = np.arange(0, len(order), BAND_BATCH)
    cuts = np.unique(np.r_[cuts[(cuts == 0) | (skey[cuts] != skey[cuts - 1])],
                           len(order)])  # a feature's two rows in one batch
    dup = np.r_[False, skey[1:] == skey[:-1]]
    return {"order": order, "first": first, "source": source, "cuts": cuts, "dup": dup}


def _merged_band_batches(paths: list, bounds: list, plan: dict):
    """The merged layer as a ``pyarrow.RecordBatchReader``: a batch of the layer is a run
    of consecutive rows of every file (:func:`_merge_plan`), read when it is asked for."""
    import pyarrow as pa

    order, first, source = plan["order"], plan["first"], plan["source"]
    cuts, dup = plan["cuts"], plan["dup"]
    schema = _band_schema().remove(_band_schema().get_field_index("_feature"))
    files = [pa.OSFile(p) for p in paths]
    readers = [pa.ipc.open_file(f) for f in files]
    cached = [(-1, None)] * len(paths)
    done = np.zeros(len(paths), np.int64)  # rows of each file already in the layer

    def rows(f, a, b):
        """Rows ``a .. b - 1`` of file ``f`` as tables (its record batches read once)."""
        out = []
        j = int(np.searchsorted(bounds[f], a, side="right")) - 1
        while a < b:
            if cached[f][0] != j:
                cached[f] = (j, readers[f].get_batch(j))
            lo, hi = bounds[f][j], bounds[f][j + 1]
            take = min(b, hi) - a
            out.append(cached[f][1].slice(a - lo, take))
            a += take
            j += 1
        return out

    def gen():
        try:
            yield from ordered()
        finally:
            cached[:] = [(-1, None)] * len(paths)
            for f in files:
                f.close()

    def ordered():
        for i, j in zip(cuts[:-1], cuts[1:]):
            o = order[i:j]
            src = source[o]
            n = np.bincount(src, minlength=len(paths))
            pieces, base = [], np.zeros(len(paths), np.int64)
            for f in np.flatnonzero(n):
                base[f] = sum(len(p) for p in pieces)
                pieces += rows(f, int(done[f]), int(done[f] + n[f]))
            # position of every row of the batch among the pieces: file f's rows come
            # in its own order, after the rows of the files before it
            local = base[src] + (o - first[src] - done[src])
            done[:] += n
            batch = pa.Table.from_batches(pieces, schema=_band_schema()).drop(["_feature"])
            batch = batch.take(pa.array(local)).combine_chunks()
            yield from _merged_rows(batch, dup[i:j]).to_batches()

    return pa.RecordBatchReader.from_batches(schema, gen())


def _file_keys(run: AdjustmentRun, path: str):
    """Layer keys, record batch bounds, databases, ``NSeg`` and confidences of the rows
    of a band file (the pages of those columns only)."""
    import pyarrow as pa

    with pa.memory_map(path) as src:
        reader = pa.ipc.open_file(src)
        sizes = [reader.get_batch(j).num_rows for j in range(reader.num_record_batches)]
        table = reader.read_all()
        names = table.column("database").to_pylist()
        key = _layer_key(run, names, np.array(table.column("_feature").to_numpy(), np.int64))
        nseg = np.array(table.column("NSeg").to_numpy(), np.int64)
        conf = table.column("confidence").to_pylist()[:1]
        del table, reader
    return key, np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]), names, nseg, conf


def _merged_rows(batch, dup: np.ndarray):
    """Rows of a batch with a feature's second row (``dup``: the conflated segments' band
    of a feature whose measured segments' band came before it) united into the first."""
    import pyarrow as pa
    import shapely

    if not dup.any():
        return batch
    d = np.flatnonzero(dup)
    geo = shapely.from_wkb(np.asarray(batch.column("geometry").to_pylist(), dtype=object))
    geo[d - 1] = _united(geo[d - 1], geo[d])
    nseg = np.array(batch.column("NSeg").to_numpy(), np.int64)
    nseg[d - 1] += nseg[d]
    keep = pa.array(~dup)
    batch = batch.set_column(batch.schema.get_field_index("NSeg"), "NSeg", pa.array(nseg))
    wkb = shapely.to_wkb(geo, output_dimension=2)
    batch = batch.set_column(batch.schema.get_field_index("geometry"), "geometry",
                             pa.array(wkb, type=pa.binary()))
    return batch.filter(keep)


def write_uncertainty_bands(run: AdjustmentRun, path, layer: str = "uncertainty_bands",
                            fmt: Optional[str] = None, confidence: float = 0.9,
                            **kwargs) -> str:
    """Write the uncertainty bands as a polygon layer.

    Parameters
    ----------
    run : AdjustmentRun
    path : str or os.PathLike
        A GeoPackage (the layer is added to it, or replaces a layer of that name; the
        other layers are kept) or a shapefile.
    layer : str
        Layer name in a GeoPackage.
    fmt : {"gpkg", "shp"}, optional
        Default: from the file extension (``.shp`` -> shapefile, else GeoPackage).
    confidence : float
    **kwargs
        Passed to :func:`uncertainty_bands_frame`.

    Returns
    -------
    str
        The path written.

    Raises
    ------
    InputFileError
        If the file cannot be written.
    """
    p = Path(path)
    if fmt is None:
        fmt = "shp" if p.suffix.lower() == ".shp" else "gpkg"
    if fmt not in ("gpkg", "shp"):
        raise InputFileError(f"Output format {fmt!r} is not supported", "Use gpkg or shp")
    gdf = uncertainty_bands_frame(run, confidence, **kwargs)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "gpkg":
            gdf.to_file(p, layer=layer, driver="GPKG", engine="pyogrio")
        else:
            gdf.to_file(p, driver="ESRI Shapefile", engine="pyogrio", encoding="UTF-8")
    except Exception as exc:  # pyogrio/GDAL errors: report the file and the cause
        raise InputFileError(
            f"Cannot write the uncertainty bands to {str(p)!r} ({exc})",
            "Choose a writable output path (and close the file in other programs)",
            path=str(p),
        ) from exc
    return str(p)


def write_equal_error_map(grid: EqualErrorGrid, path, crs,
                          nodata: float = EQUAL_ERROR_NODATA) -> str:
    """Write an equal-error grid as a 3-band float32 GeoTIFF.

    Bands: 1 sigma X, 2 sigma Y, 3 sigma Z (m, a posteriori), with band descriptions;
    cells outside the stereo overlap hold ``nodata``.

    Parameters
    ----------
    grid : EqualErrorGrid
        From :func:`vectoradjust.accuracy.derived.equal_error_grid`.
    path : str or os.PathLike
    crs : str or pyproj.CRS or rasterio CRS
        The project CRS.
    nodata : float

    Returns
    -------
    str
        The path written.
    """
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.transform import Affine

    p = Path(path)
    bands = np.stack([grid.sigma_x, grid.sigma_y, grid.sigma_z]).astype(np.float32)
    bands = np.where(np.isfinite(bands), bands, np.float32(nodata))
    if hasattr(crs, "to_wkt"):
        crs = crs.to_wkt()
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with rasterio.open(
            p, "w", driver="GTiff", height=bands.shape[1], width=bands.shape[2], count=3,
            dtype="float32", crs=crs, transform=Affine(*grid.transform), nodata=nodata,
            compress="deflate",
        ) as dst:
            dst.write(bands)
            for i, name in enumerate(("sigma X (m)", "sigma Y (m)", "sigma Z (m)"), start=1):
                dst.set_band_description(i, name)
            dst.update_tags(units="m", quantity="a-posteriori standard deviation of a point "
                            "intersected from the stereo pair (equal-error map)")
    except (OSError, RasterioError) as exc:
        raise InputFileError(
            f"Cannot write the equal-error map {str(p)!r} ({exc})",
            "Choose a writable output path",
            path=str(p),
        ) from exc
    return os.fspath(p)


def write_conflation_rasters(run: AdjustmentRun, out_dir, cell: Optional[float] = None,
                             nodata: float = EQUAL_ERROR_NODATA) -> dict:
    """Each conflated database's displacement field as a 5-band float32 GeoTIFF.

    ``conflation_<database>.tif``: bands dX, dY, dZ (adjusted - database, m) and CE90,
    LE90 (m) of the corrected position, on a grid over the database's extent
    (:func:`vectoradjust.conflation.field_grid`); NaN (no field) as ``nodata``.

    Parameters
    ----------
    run : AdjustmentRun
    out_dir : str or os.PathLike
    cell : float, optional
        Cell size (m); default: about 200 cells over the extent.
    nodata : float

    Returns
    -------
    dict
        Path written per database name (databases without a field are left out).
    """
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.transform import from_origin

    from vectoradjust.conflation import field_grid

    written = {}
    for d in run.databases:
        g = field_grid(d, cell)
        if g is None:
            continue
        bands = np.stack([g[k] for k in ("dx", "dy", "dz", "ce90", "le90")]).astype(np.float32)
        bands = np.where(np.isfinite(bands), bands, np.float32(nodata))
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in d.name)
        p = Path(out_dir) / f"conflation_{safe}.tif"
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            with rasterio.open(p, "w", driver="GTiff", height=bands.shape[1],
                               width=bands.shape[2], count=5, dtype="float32",
                               crs=run.data.crs, nodata=nodata, compress="deflate",
                               transform=from_origin(g["x0"], g["y0"], g["cell"], g["cell"])
                               ) as dst:
                dst.write(bands)
                for i, name in enumerate(("dX (m)", "dY (m)", "dZ (m)", "CE90 (m)",
                                          "LE90 (m)"), start=1):
                    dst.set_band_description(i, name)
                dst.update_tags(units="m", quantity=f"conflation field of {d.name}: "
                                "displacement adjusted - database and its CE90/LE90")
        except (OSError, RasterioError) as exc:
            raise InputFileError(f"Cannot write the conflation raster {str(p)!r} ({exc})",
                                 "Choose a writable output directory", path=str(p)) from exc
        written[d.name] = os.fspath(p)
    return written
