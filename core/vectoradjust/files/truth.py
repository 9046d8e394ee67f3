"""True centrelines (``[truth]``) and the buffer test of a run against them.

With a ``[truth]`` table (true centrelines) in the project, ``adjust`` and ``compare`` add
the share of each database's lines inside 1 m and 2 m (or ``widths``) of the truth
before and after the adjustment to ``summary.json`` (``databases[].truth.buffer``).
Reading uses geopandas/pyproj, imported inside the functions.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import LayerError, ProjectError

__all__ = ["parse_widths", "read_lines", "truth_buffer", "drive_truth_buffer", "truth_jobs",
           "line_ranges", "project_truth", "truth_line_distances", "drive_truth_lines",
           "TruthBefore", "LayerBefore", "truth_before"]


def parse_widths(text) -> list:
    """``"1,2,5"`` or a list of numbers -> sorted positive widths (m)."""
    if isinstance(text, str):
        parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    else:
        parts = list(text)
    try:
        widths = sorted({float(p) for p in parts})
    except (TypeError, ValueError) as exc:
        raise ProjectError(f"buffer widths {text!r} are not numbers",
                           "Give widths in metres, e.g. --widths 1,2,5") from exc
    if not widths or widths[0] < 0:
        raise ProjectError(f"buffer widths {text!r} must be >= 0 and not empty",
                           "Give widths in metres, e.g. --widths 1,2,5")
    return widths


def read_lines(path, crs=None, layer=None):
    """The line geometries of a layer (shapely), transformed to ``crs`` if given.

    Returns
    -------
    geometries : numpy.ndarray of shapely geometries
    crs : pyproj.CRS
    """
    import geopandas as gpd

    from vectoradjust.files.readers import check_projected_crs

    p = Path(path)
    if not p.exists():
        raise LayerError(f"Line layer {str(p)!r} does not exist", "Check the path", path=str(p))
    try:
        gdf = gpd.read_file(p, **({"layer": layer} if layer else {}))
    except Exception as exc:  # pyogrio raises several types
        raise LayerError(f"{p}: cannot be read as a vector layer ({exc})",
                         "Give a shapefile, GeoPackage or GeoJSON of lines", path=str(p)) from exc
    if not isinstance(gdf, gpd.GeoDataFrame):
        raise LayerError(f"{p}: has no geometries", "Give a line layer to the buffer test",
                         path=str(p))
    if gdf.crs is None:
        raise LayerError(f"{p}: the layer has no coordinate reference system",
                         "Add a .prj file or define the CRS", path=str(p))
    types = set(gdf.geometry.geom_type.dropna())
    if types - {"LineString", "MultiLineString", "LinearRing"}:
        raise LayerError(f"{p}: holds {', '.join(sorted(types))} geometries, not lines",
                         "Give line layers to the buffer test", path=str(p))
    target = crs if crs is not None else gdf.crs
    check_projected_crs(target, f"{p}")
    if not gdf.crs.equals(target):
        gdf = gdf.to_crs(target)
    return gdf.geometry.to_numpy(), gdf.crs


_LAST_TRUTH: dict = {}


def _truth_lines(path, crs):
    """:func:`read_lines` of the ``[truth]`` centrelines, kept for the next call with the
    same file (unchanged size and time) and CRS: ``adjust`` runs the buffer test and the
    distance table on the same lines, and reads them once."""
    p = Path(path)
    key = _truth_key(p, crs)
    if key not in _LAST_TRUTH:
        lines = read_lines(p, crs)[0]
        _LAST_TRUTH.clear()
        _LAST_TRUTH[key] = lines
    return _LAST_TRUTH[key]


def _truth_key(path, crs) -> tuple:
    """What :func:`_truth_lines` keeps the lines under: the file (its size and time)
    and the CRS."""
    p = Path(path)
    st = p.stat() if p.exists() else None
    return (str(p.resolve()), st and (st.st_mtime_ns, st.st_size), crs.to_wkt())


def line_ranges(feature: np.ndarray, part: np.ndarray) -> list:
    """``(start, end)`` vertex ranges of the feature parts with >= 2 vertices (numpy only,
    so the QGIS plugin builds the same lines with its own geometry engine)."""
    key = np.asarray(feature, dtype=np.int64) * 100000 + np.asarray(part, dtype=np.int64)
    if len(key) == 0:
        return []
    brk = np.flatnonzero(np.diff(key)) + 1
    return [(int(s), int(e)) for s, e in zip(np.r_[0, brk], np.r_[brk, len(key)]) if e - s >= 2]


def _linestrings(xy: np.ndarray, ranges: list) -> list:
    """shapely LineStrings of the vertex ranges ``xy[s:e]``."""
    import shapely

    return [shapely.linestrings(xy[s:e]) for s, e in ranges]


def _lines(xy: np.ndarray, feature: np.ndarray, part: np.ndarray) -> list:
    """LineStrings from vertex arrays (one per feature part with >= 2 vertices)."""
    return _linestrings(xy, line_ranges(feature, part))


#: tested lines measured against the truth buffers per step (progress and cancel between steps)
TRUTH_CHUNK = 20000


def _check(is_cancelled) -> None:
    if is_cancelled is not None and is_cancelled():
        from vectoradjust.errors import CancelledError

        raise CancelledError("The buffer test against the true centrelines was cancelled",
                             "Run again to completion, or remove [truth] from the project")


def _truth_buffers(truth, is_cancelled=None):
    """The true lines' segments on a grid of boxes, for the exact round buffers of every width.

    :class:`vectoradjust.accuracy.buffer.SegmentBuffer`: built once for every database,
    before and after, and for the distance table of the same lines (kept while
    :func:`_truth_lines` returns the same array); linear in the number of segments.
    """
    from vectoradjust.accuracy.buffer import SegmentBuffer, line_segments

    _check(is_cancelled)
    kept = _LAST_BUFFER.get("truth")
    if kept is not None and kept[0] is truth:  # the lines of :func:`_truth_lines`, again
        return kept[1]
    geoms = [g for g in truth if g is not None and not g.is_empty]
    buffers = SegmentBuffer(line_segments(geoms))
    _LAST_BUFFER["truth"] = (truth, buffers)
    return buffers


#: the segments of the last true lines (the buffer test and the distance table share them)
_LAST_BUFFER: dict = {}


def _range_segments(xy: np.ndarray, ranges: list, with_index: bool = False):
    """The segments ``(n, 2, 2)`` of the lines ``xy[s:e]`` (one line per range); with
    ``with_index`` also the row of ``xy`` each segment starts at: ``(segments, rows)``."""
    if not ranges:
        seg, i = np.zeros((0, 2, 2)), np.zeros(0, dtype=np.int64)
        return (seg, i) if with_index else seg
    r = np.asarray(ranges, dtype=np.int64).reshape(-1, 2)
    nseg = r[:, 1] - r[:, 0] - 1
    first = np.repeat(r[:, 0], nseg)
    offset = np.arange(int(nseg.sum())) - np.repeat(np.cumsum(nseg) - nseg, nseg)
    i = first + offset
    seg = np.stack([xy[i, :2], xy[i + 1, :2]], axis=1)
    ok = np.isfinite(seg).all(axis=(1, 2))  # a vertex without coordinates: no segment
    return (seg[ok], i[ok]) if with_index else seg[ok]


def _shares(xy: np.ndarray, ranges: list, buffers, widths, step) -> list:
    """Share of the lines' length inside each width's buffer, in chunks of
    :data:`TRUTH_CHUNK` lines (``step(n)`` after each)."""
    seg_all = _range_segments(xy, ranges)
    length = np.hypot(*(seg_all[:, 1] - seg_all[:, 0]).T)
    total = float(np.sum(length)) if len(seg_all) else 0.0
    inside = []
    for k in range(0, max(len(ranges), 1), TRUTH_CHUNK):
        part = ranges[k:k + TRUTH_CHUNK]
        if total > 0 and part:
            inside.append(_segment_inside(buffers, _range_segments(xy, part), widths))
        step(len(part))
    return _share_values(np.concatenate(inside) if inside else None, length, widths)


def _segment_inside(buffers, seg: np.ndarray, widths) -> np.ndarray:
    """Each segment's length inside each width's buffer, ``(n, n_widths)``: the same
    values bit for bit whatever the segments measured with it, so that
    :func:`truth_before`'s shares of a whole layer equal those of some of its lines."""
    return buffers.inside(seg, widths, per_segment=True)


def _share_values(inside: Optional[np.ndarray], length: np.ndarray, widths) -> list:
    """The share of the segments (``length``) inside each width's buffer from their
    lengths inside (:func:`_segment_inside`; None: none inside); None without length."""
    total = float(np.sum(length)) if len(length) else 0.0
    if total <= 0:
        return [None] * len(widths)
    # per width a contiguous row: numpy's pairwise summation (rounding ~ log n, not n)
    sums = (np.ascontiguousarray(inside.T).sum(axis=1) if inside is not None and len(inside)
            else np.zeros(len(widths)))
    return [min(max(float(x) / total, 0.0), 1.0) for x in sums]


def _adjusted_features(d) -> np.ndarray:
    """The features of a run's database with at least one adjusted vertex (sorted)."""
    return np.unique(d.shape.layer.vertex_feature[d.vertices["Adjusted"] == 1])


def truth_jobs(run) -> list:
    """The lines a buffer test compares: ``(database, summary entry, xy before, xy after,
    line ranges)`` per database with adjusted vertices (only features with at least one
    adjusted vertex; the others did not move)."""
    jobs = []
    for d, entry in zip(run.databases, run.summary.get("databases", [])):
        layer = d.shape.layer
        keep = np.isin(layer.vertex_feature, _adjusted_features(d))
        if keep.any():
            ranges = line_ranges(layer.vertex_feature[keep], layer.vertex_part[keep])
            jobs.append((d, entry, layer.coords[keep, :2], d.adjusted_coords[keep, :2], ranges))
    return jobs


def drive_truth_buffer(run, widths, shares, truth_path, progress=None,
                       is_cancelled=None, before=None) -> dict:
    """The buffer test of every database before and after, with any geometry engine.

    ``shares(xy, ranges, step)`` returns the share of the lines ``xy[s:e]`` (one per
    range) inside each width's buffer and calls ``step(n)`` after each chunk of ``n``
    lines; here ``step`` reports ``progress(fraction, message)`` and polls
    ``is_cancelled`` (:class:`vectoradjust.errors.CancelledError`). Writes
    ``run.summary["databases"][i]["truth"]["buffer"]`` and returns ``{database: entry}``.

    ``before`` (:func:`truth_before`, optional) gives the shares before the adjustment
    of the databases whose layer it was computed on (the others are measured here).
    """
    say = progress or (lambda fraction, message="": None)
    jobs = truth_jobs(run)
    known = [_before_shares(before, d, widths, truth_path, run) for d, *_ in jobs]
    todo = max(sum((1 if k is not None else 2) * len(job[-1]) for job, k in zip(jobs, known)),
               1)
    done = [0]
    out = {}
    for (d, entry, xy_before, xy_after, ranges), known_before in zip(jobs, known):
        def step(n, name=d.name):
            done[0] += n
            say(done[0] / todo, f"buffer test: {name}")
            _check(is_cancelled)

        _check(is_cancelled)
        say(done[0] / todo, f"buffer test: {d.name}")
        before_shares = (known_before if known_before is not None
                         else shares(xy_before, ranges, step))
        after = shares(xy_after, ranges, step)
        res = {"widths": list(widths), "before": before_shares, "after": after,
               "truth_lines": str(truth_path)}
        out[d.name] = res
        entry.setdefault("truth", {})["buffer"] = res
    say(1.0, "buffer test: done")
    return out


def truth_buffer(run, truth_path, widths=(1.0, 2.0), progress=None, is_cancelled=None,
                 before=None) -> dict:
    """Share of each database's lines inside buffers of the true lines, before and after.

    Only features with at least one adjusted vertex are compared (the others did not
    move). Returns ``{database: {"widths", "before", "after"}}`` and writes the same into
    ``run.summary["databases"][i]["truth"]["buffer"]``. The shares are those of
    :func:`vectoradjust.accuracy.buffer.buffer_test` with ``method="exact"`` (the exact
    round buffer, linear time; the polygon method is narrower on round caps and joins
    by at most 0.03 % of the width).

    Parameters
    ----------
    progress : callable, optional
        ``progress(fraction, message)``, called per database and per chunk of
        ``TRUTH_CHUNK`` lines.
    is_cancelled : callable, optional
        Polled as often; when it returns True, :class:`vectoradjust.errors.CancelledError`
        is raised.
    before : TruthBefore, optional
        The shares before the adjustment computed beforehand (:func:`truth_before`, e.g.
        in another process while the adjustment ran); only the after half is measured
        here for the databases it matches (the same layer, widths and true lines).
    """
    from pyproj import CRS

    widths = [float(w) for w in widths]
    say = progress or (lambda fraction, message="": None)
    say(0.0, "buffer test: reading the true centrelines")
    _adopt_lines(before, truth_path, CRS.from_user_input(run.data.crs))
    truth = _truth_lines(truth_path, CRS.from_user_input(run.data.crs))
    say(0.0, "buffer test: indexing the true centrelines")
    buffers = _truth_buffers(truth, is_cancelled)

    def shares(xy, ranges, step):
        return _shares(xy, ranges, buffers, widths, step)

    return drive_truth_buffer(run, widths, shares, truth_path, say, is_cancelled, before)


def project_truth(spec) -> Optional[tuple]:
    """``(path, widths)`` of the project's ``[truth]`` table, or None."""
    t = spec.raw.get("truth")
    if not t:
        return None
    if not isinstance(t, dict) or "path" not in t:
        raise ProjectError(f"{spec.path}: [truth] needs path = \"truth_roads.shp\"",
                           "Give the true centrelines as a line layer")
    p = Path(t["path"])
    p = p if p.is_absolute() else spec.base_dir / p
    return str(p), parse_widths(t.get("widths", [1.0, 2.0]))



def drive_truth_lines(run, distances, truth_path, as_columns: bool = False, progress=None,
                      before=None):
    """Each adjusted object point's distance to the nearest true centreline, before and
    after the adjustment, with any geometry engine (``distances(xy) -> (n,)`` array of
    the distances of the points ``xy`` (n, 2) to the nearest true line).

    Writes the share of points moved closer into ``run.summary["databases"][i]["truth"]
    ["lines"]`` (``count``, ``moved_closer``, ``rmse_before``, ``rmse_after``).

    Returns
    -------
    list of dict, or dict of numpy.ndarray
        One row per point: ``database, point_id, X, Y, AdjX, AdjY, D_before, D_after,
        Closer``; with ``as_columns`` the same table as columns (None without points).

    ``progress(fraction, message)``, optional, before each database. ``before``
    (:func:`truth_before`, optional): the distances of the database vertices computed
    beforehand, used for the databases whose layer it was computed on.
    """
    from vectoradjust.accuracy.tables import one_vertex_per_point
    from vectoradjust.files.study import rows_from_columns

    parts = []
    n_db = max(len(run.databases), 1)
    for i, (d, entry) in enumerate(zip(run.databases, run.summary.get("databases", []))):
        if progress is not None:
            progress(i / n_db, f"distances of {d.name} to the true centrelines")
        m = one_vertex_per_point(d.vertex_point)
        if not m.any():
            continue
        db, adj = d.shape.layer.coords[m, :2], d.adjusted_coords[m, :2]
        known = _matching(before, d, truth_path, run)
        if known is not None and known.vertex_distance is not None:  # computed beforehand
            dist = [known.vertex_distance[m], np.asarray(distances(adj), float)]
        else:
            dist = [np.asarray(distances(xy), float) for xy in (db, adj)]
        closer = dist[1] < dist[0]
        entry.setdefault("truth", {})["lines"] = {
            "truth_lines": str(truth_path), "count": int(m.sum()),
            "moved_closer": float(closer.mean()),
            "rmse_before": float(np.sqrt(np.mean(dist[0] ** 2))),
            "rmse_after": float(np.sqrt(np.mean(dist[1] ** 2)))}
        ids = d.shape.vertex_ids[m]
        parts.append({"database": np.full(len(ids), d.name, dtype=object),
                      "point_id": np.asarray(ids).astype(str).astype(object),
                      "X": db[:, 0], "Y": db[:, 1], "AdjX": adj[:, 0], "AdjY": adj[:, 1],
                      "D_before": dist[0], "D_after": dist[1], "Closer": closer.astype(int)})
    cols = ({k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else None)
    return cols if as_columns else rows_from_columns(cols)


def truth_line_distances(run, truth_path, as_columns: bool = False, progress=None,
                         before=None):
    """:func:`drive_truth_lines` with the true centrelines read by geopandas; the
    distances from their segments on a grid of boxes (numpy), for the points farther
    than its radius from shapely's STR-tree nearest query; the same rows and summary
    entry. ``before`` (:func:`truth_before`, optional): the database vertices' distances
    computed beforehand (only the adjusted points are measured here)."""
    from pyproj import CRS

    _adopt_lines(before, truth_path, CRS.from_user_input(run.data.crs))
    truth = _truth_lines(truth_path, CRS.from_user_input(run.data.crs))
    distances = _distance_function(truth)
    if distances is None:
        return None if as_columns else []
    return drive_truth_lines(run, distances, truth_path, as_columns, progress, before)


def _distance_function(truth):
    """``distances(xy)``: each point's distance to the nearest of the lines ``truth``
    (NaN for a point without coordinates); None when there are no lines. The segments
    on a grid of boxes (numpy) for the points near a line, shapely's STR-tree for the
    farther ones."""
    import shapely

    parts = [p for g in truth if g is not None and not g.is_empty for p in shapely.get_parts(g)]
    if not parts:
        return None
    near = _truth_buffers(truth)  # the segments on a grid (numpy): most points are near
    tree = None

    def distances(xy):
        nonlocal tree
        d = near.nearest_distance(xy)
        far = np.flatnonzero(np.isnan(d) & np.isfinite(xy).all(axis=1))
        if len(far):  # farther than the grid's radius: GEOS's nearest query
            tree = tree if tree is not None else shapely.STRtree(parts)
            d[far] = tree.query_nearest(shapely.points(xy[far]), return_distance=True,
                                        all_matches=False)[1]
        return d

    return distances


# ------------------------------------------------------------- the half before, beforehand
#: database vertices measured against the true lines per step of :func:`truth_before`
BEFORE_VERTEX_CHUNK = 200_000


@dataclass
class LayerBefore:
    """The ``[truth]`` values of one database's layer before the adjustment.

    Attributes
    ----------
    digest : str
        BLAKE2b of the layer's XY (the values belong to the layer with the same XY).
    n_vertices : int
        Vertices of the layer.
    segment_feature : numpy.ndarray of int, shape (ns,)
        The feature of each segment (the segments of :func:`_range_segments` of the
        layer's :func:`line_ranges`; none across a vertex without coordinates).
    segment_length : numpy.ndarray, shape (ns,)
        Each segment's length.
    inside : numpy.ndarray, shape (ns, n_widths)
        Each segment's length inside each width's exact round buffer of the true lines.
    vertex_distance : numpy.ndarray, shape (nv,) or None
        Each vertex's distance to the nearest true line (NaN without coordinates; None
        when there are no true lines).
    """

    digest: str
    n_vertices: int
    segment_feature: np.ndarray
    segment_length: np.ndarray
    inside: np.ndarray
    vertex_distance: Optional[np.ndarray]


@dataclass
class TruthBefore:
    """The ``[truth]`` tests' half before the adjustment, of every database
    (:func:`truth_before`): ``databases`` maps a database name to its
    :class:`LayerBefore`, computed against the lines of ``truth_path`` in ``crs`` for
    the buffer ``widths``."""

    truth_path: str
    widths: list
    crs: str
    databases: dict = field(default_factory=dict)
    #: the true lines as read (WKB), their key (:func:`_truth_key`) and segments on the
    #: grid, so that a process receiving the values need not read and index them again
    lines_key: Optional[tuple] = None
    lines_wkb: Optional[np.ndarray] = None
    buffers: object = None


def _digest(xy: np.ndarray) -> str:
    """BLAKE2b of an XY array's values (and shape)."""
    a = np.ascontiguousarray(xy, dtype=float)
    h = hashlib.blake2b(str(a.shape).encode(), digest_size=16)
    h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def truth_before(data, truth_path, widths=(1.0, 2.0), progress=None) -> TruthBefore:
    """The half of the ``[truth]`` tests that depends on the inputs only, for every
    feature of every database: per segment the length inside each buffer width and its
    length, per vertex the distance to the nearest true line.

    :func:`truth_buffer` and :func:`truth_line_distances` take the result (``before=``)
    and then measure only the adjusted coordinates; ``adjust`` computes it in another
    process while the adjustment runs. The values equal theirs (the buffer shares up to
    the order of the summation).

    Parameters
    ----------
    data : vectoradjust.model.ProjectData
        The project's inputs (``data.vectors``: the databases' line layers; ``data.crs``).
    truth_path : str or path
        The true centrelines (``[truth] path``).
    widths : sequence of float
        Buffer widths (m).
    progress : callable, optional
        ``progress(fraction, message)``, per chunk of segments or vertices.

    Returns
    -------
    TruthBefore
    """
    import shapely
    from pyproj import CRS

    say = progress or (lambda fraction, message="": None)
    widths = [float(w) for w in widths]
    say(0.0, "before the adjustment: reading the true centrelines")
    crs = CRS.from_user_input(data.crs)
    truth = _truth_lines(truth_path, crs)
    buffers = _truth_buffers(truth)
    distances = _distance_function(truth)
    todo = max(sum(2 * len(layer.coords) for _, layer in data.vectors), 1)
    done = [0]

    def step(n, name):
        done[0] += n
        say(min(done[0] / todo, 1.0), f"before the adjustment: {name}")

    out = TruthBefore(str(truth_path), widths, str(data.crs), lines_key=_truth_key(truth_path, crs),
                      lines_wkb=shapely.to_wkb(np.asarray(truth, dtype=object)), buffers=buffers)
    for spec, layer in data.vectors:
        rec = _layer_before(layer, buffers, distances, widths,
                            lambda n, name=spec.name: step(n, name))
        if rec is not None:
            out.databases[spec.name] = rec
    say(1.0, "before the adjustment: done")
    return out


def _layer_before(layer, buffers, distances, widths, step) -> Optional[LayerBefore]:
    """:class:`LayerBefore` of a line layer (None when a feature's vertices are not
    all in one run: leaving other features out would then join its runs into one line,
    which per-segment values of the whole layer cannot give)."""
    feature = np.asarray(layer.vertex_feature)
    if len(feature) and np.count_nonzero(np.diff(feature)) + 1 != len(np.unique(feature)):
        return None
    xy = np.asarray(layer.coords, float)[:, :2]
    seg, first = _range_segments(xy, line_ranges(feature, layer.vertex_part), with_index=True)
    length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
    inside = np.zeros((len(seg), len(widths)))
    chunk = max(int(buffers.chunk), 1)
    for k in range(0, len(seg), chunk):
        inside[k:k + chunk] = _segment_inside(buffers, seg[k:k + chunk], widths)
        step(len(xy) * len(seg[k:k + chunk]) / max(len(seg), 1))
    if not len(seg):
        step(len(xy))
    dist = None
    if distances is not None:
        dist = np.full(len(xy), np.nan)
        for k in range(0, len(xy), BEFORE_VERTEX_CHUNK):
            dist[k:k + BEFORE_VERTEX_CHUNK] = distances(xy[k:k + BEFORE_VERTEX_CHUNK])
            step(len(xy[k:k + BEFORE_VERTEX_CHUNK]))
    else:
        step(len(xy))
    return LayerBefore(_digest(xy), len(xy), feature[first], length, inside, dist)


def _matching(before, d, truth_path, run) -> Optional[LayerBefore]:
    """The values of ``before`` for the run's database ``d``, if computed on its layer
    (same name, vertices and XY), the same true lines (file, unchanged) and CRS; else
    None."""
    if before is None:
        return None
    rec = before.databases.get(d.name)
    layer = d.shape.layer
    if (rec is None or str(truth_path) != before.truth_path
            or str(getattr(getattr(run, "data", None), "crs", None)) != before.crs
            or rec.n_vertices != len(layer.coords)):
        return None
    if before.lines_key is not None:  # the true lines' file unchanged since
        from pyproj import CRS

        if _truth_key(truth_path, CRS.from_user_input(before.crs)) != before.lines_key:
            return None
    return rec if _digest(np.asarray(layer.coords)[:, :2]) == rec.digest else None


def _before_shares(before, d, widths, truth_path, run) -> Optional[list]:
    """The buffer shares before the adjustment of the features of ``d`` with adjusted
    vertices (those of :func:`truth_jobs`) from ``before``; None when it does not
    match (another layer, other widths or lines)."""
    rec = _matching(before, d, truth_path, run)
    if rec is None or [float(w) for w in widths] != list(before.widths):
        return None
    sel = np.isin(rec.segment_feature, _adjusted_features(d))
    return _share_values(rec.inside[sel], rec.segment_length[sel], widths)


def _adopt_lines(before, truth_path, crs) -> None:
    """Keep the true lines and their grid that came with ``before`` for
    :func:`_truth_lines` and :func:`_truth_buffers` when they are those of
    ``truth_path`` in ``crs`` (the same file, unchanged): not read and indexed again."""
    if before is None or before.lines_wkb is None or before.lines_key is None:
        return
    key = _truth_key(truth_path, crs)
    if key != before.lines_key or key in _LAST_TRUTH:
        return
    import shapely

    lines = shapely.from_wkb(before.lines_wkb)
    _LAST_TRUTH.clear()
    _LAST_TRUTH[key] = lines
    _LAST_BUFFER["truth"] = (lines, before.buffers)
