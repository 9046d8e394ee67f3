"""Buffer test of line accuracy (Goodchild and Hunter 1997).

The reference lines are buffered by a width ``x``; the statistic is the share of the
tested lines' total length that lies inside that buffer, as a function of ``x``
(e.g. "98 % of the adjusted road inside a 1 m buffer of the surveyed centre line").

This module uses shapely (imported lazily), so it is not part of the numerical heart.
Coordinates must be in a projected CRS (metres); the caller transforms them.

Buffers are polygons: round caps and joins are approximated by ``quad_segs`` chords per
quarter circle whose vertices lie on the circle, so a round part of a buffer is at most
``x (1 - cos(pi / (4 quad_segs)))`` (0.03 % of ``x`` for the default 32) too narrow.
Straight parts (offsets parallel to a reference segment) are exact.

``method="exact"`` (and the ``[truth]`` buffer test of ``adjust``) measures the same
quantity without polygons, linear in the size of the data: the buffer of a line is the
union of the capsules (points within ``x``) of its segments, so the part of a tested
segment inside it is a union of intervals of its parameter, one per nearby reference
segment (found by sorting boxes on a grid), computed in closed form and merged with numpy. It is
the exact round buffer: it differs from the polygon method only where a tested line
crosses a round cap or join, by at most the chord error above (the polygon is that
much too narrow there).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import LayerError

__all__ = ["buffer_test", "segment_buffer_test", "line_segments", "capsule_intervals",
           "covered_length", "covered_lengths", "SegmentBuffer"]

_LINE_TYPES = ("LineString", "MultiLineString", "LinearRing")


def _as_geometry_array(geoms: Any, role: str) -> np.ndarray:
    """Flatten a geometry or a sequence of geometries into an array of line parts."""
    import shapely

    if geoms is None:
        items: list = []
    elif isinstance(geoms, shapely.Geometry):
        items = [geoms]
    elif isinstance(geoms, Iterable) and not isinstance(geoms, (str, bytes)):
        items = list(geoms)
    else:
        raise TypeError(f"{role}: expected a shapely geometry or a sequence of them")
    keep = []
    for i, g in enumerate(items):
        if g is None:
            continue
        if not isinstance(g, shapely.Geometry):
            raise TypeError(f"{role}[{i}]: expected a shapely geometry, got {type(g).__name__}")
        if g.is_empty:
            continue
        if g.geom_type == "GeometryCollection":
            parts = [p for p in shapely.get_parts(g) if not p.is_empty]
        else:
            parts = [g]
        for p in parts:
            if p.geom_type not in _LINE_TYPES:
                raise LayerError(
                    f"{role} geometry {i} is a {p.geom_type}, not a line",
                    "Pass LineString or MultiLineString geometries to the buffer test",
                )
            keep.append(p)
    return np.asarray(keep, dtype=object)


def buffer_test(
    tested: Any,
    reference: Any,
    widths: Any,
    *,
    quad_segs: int = 32,
    cap_style: str = "round",
    method: str = "polygon",
) -> list[dict[str, Any]]:
    """Share of the tested lines' length inside buffers of the reference lines.

    For each width ``x`` the reference lines (all of them, united) are buffered by
    ``x`` and the length of the tested lines inside the buffer (boundary included)
    is divided by their total length. Overlapping reference buffers count once;
    tested lines are measured as given (a line that appears twice counts twice in
    both the numerator and the denominator).

    Parameters
    ----------
    tested : shapely geometry or sequence of them
        The lines under test (LineString / MultiLineString; None and empty
        geometries are skipped), projected coordinates in metres.
    reference : shapely geometry or sequence of them
        The reference ("true") lines, same CRS.
    widths : float or sequence of float
        Buffer widths (>= 0), in the CRS units. A width of 0 gives an empty buffer
        and a share of 0.
    quad_segs : int, optional
        Chords per quarter circle of round caps/joins (default 32).
    cap_style : {"round", "flat", "square"}, optional
        Buffer end caps (default "round", the usual buffer).
    method : {"polygon", "exact"}, optional
        ``"polygon"`` (default): shapely buffers of the united reference lines, as
        GIS software computes them (``quad_segs`` chords on round parts).
        ``"exact"``: the exact round buffer by segments (see the module notes;
        linear time, for large layers); needs ``cap_style="round"`` and ignores
        ``quad_segs``.

    Returns
    -------
    list of dict
        One dict per width, in the given order:
        ``{"width", "share", "length_inside", "length_total"}`` (plain floats;
        ``share`` is None when the tested lines have no length).

    Raises
    ------
    ValueError
        If a width is negative or not finite.
    LayerError
        If a geometry is not a line.
    """
    import shapely

    w = _checked_widths(widths, method, cap_style)
    tst = _as_geometry_array(tested, "tested")
    ref = _as_geometry_array(reference, "reference")
    total = float(np.sum(shapely.length(tst))) if tst.size else 0.0
    if method == "exact":
        return _rows(w, _exact_inside(tst, ref, w) if total > 0 else np.zeros(len(w)), total)
    return _rows(w, _polygon_inside(tst, ref, w, total, quad_segs, cap_style), total)


def _checked_widths(widths: Any, method: str, cap_style: str) -> np.ndarray:
    """The widths of :func:`buffer_test` as a 1-D float array, checked with its
    ``method`` and ``cap_style`` (ValueError when they do not fit)."""
    w = np.atleast_1d(np.asarray(widths, dtype=float))
    if w.ndim != 1:
        raise ValueError("widths must be a number or a 1-D sequence of numbers")
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"buffer widths must be finite and >= 0, got {w.tolist()}")
    if method not in ("polygon", "exact"):
        raise ValueError(f"method must be 'polygon' or 'exact', got {method!r}")
    if method == "exact" and cap_style != "round":
        raise ValueError("method='exact' measures the round buffer; use cap_style='round'")
    return w


def _polygon_inside(tst: np.ndarray, ref: np.ndarray, widths: np.ndarray, total: float,
                    quad_segs: int, cap_style: str) -> list[float]:
    """Length of the tested lines inside shapely's buffer of the united reference lines,
    per width (``method="polygon"`` of :func:`buffer_test`)."""
    import shapely

    ref_parts = [p for g in ref for p in shapely.get_parts(g)]
    ref_lines = shapely.multilinestrings(ref_parts) if ref_parts else None
    results = []
    for width in widths:
        inside = 0.0
        if total > 0 and width > 0 and ref_lines is not None:
            buf = shapely.buffer(ref_lines, float(width), quad_segs=quad_segs, cap_style=cap_style)
            shapely.prepare(buf)
            hit = shapely.intersects(buf, tst)
            if np.any(hit):
                inter = shapely.intersection(tst[hit], buf)
                inside = float(np.sum(shapely.length(inter)))
        results.append(inside)
    return results


def _rows(widths: np.ndarray, inside, total: float) -> list[dict[str, Any]]:
    """The result dictionaries of :func:`buffer_test`."""
    rows = []
    for width, x in zip(widths, inside):
        share = None if total <= 0 else min(max(float(x) / total, 0.0), 1.0)
        rows.append({"width": float(width), "share": share, "length_inside": float(x),
                     "length_total": total})
    return rows


#: tested segments measured per step of the exact method (bounded memory)
SEGMENT_CHUNK = 200_000


def _exact_inside(tst: np.ndarray, ref: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """Length of the tested lines inside the exact round buffers (by segments)."""
    return _segments_inside(SegmentBuffer(line_segments(ref)), line_segments(tst), widths)


def _segments_inside(buf: SegmentBuffer, seg: np.ndarray, widths: np.ndarray,
                     chunk: int = 0, step: Optional[Any] = None) -> np.ndarray:
    """Length of the segments ``seg`` inside each width's buffer ``buf``, ``chunk``
    segments at a time (default :data:`SEGMENT_CHUNK`), ``step(n)`` after each."""
    chunk = int(chunk) if chunk and chunk > 0 else SEGMENT_CHUNK
    inside = np.zeros(len(widths))
    for k in range(0, len(seg), chunk):
        inside += buf.inside(seg[k:k + chunk], widths)
        if step is not None:
            step(len(seg[k:k + chunk]))
    return inside


def segment_buffer_test(tested: np.ndarray, reference: np.ndarray, widths: Any, *,
                        chunk: int = 0, step: Optional[Any] = None) -> list[dict[str, Any]]:
    """:func:`buffer_test` with ``method="exact"`` on segment arrays (numpy only).

    For callers that read the lines themselves (the QGIS plugin converts its layers to
    segments): the same computation and result rows as ``buffer_test(..., method="exact")``
    of the lines the segments come from.

    Parameters
    ----------
    tested, reference : numpy.ndarray, shape (n, 2, 2)
        Segments (:func:`line_segments`: no zero-length segment, none joining two parts),
        projected coordinates in metres.
    widths : float or sequence of float
        Buffer widths (>= 0).
    chunk : int, optional
        Tested segments measured per step (default :data:`SEGMENT_CHUNK`).
    step : callable, optional
        ``step(n)`` after each chunk of ``n`` segments (progress; it may raise to stop).

    Returns
    -------
    list of dict
        ``{"width", "share", "length_inside", "length_total"}`` per width.

    Raises
    ------
    ValueError
        If a width is negative or not finite.
    """
    w = np.atleast_1d(np.asarray(widths, dtype=float)).reshape(-1)
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"buffer widths must be finite and >= 0, got {w.tolist()}")
    seg = np.asarray(tested, float).reshape(-1, 2, 2)
    ref = np.asarray(reference, float).reshape(-1, 2, 2)
    total = float(np.sum(np.hypot(*(seg[:, 1] - seg[:, 0]).T))) if len(seg) else 0.0
    if total <= 0 or not len(ref):
        if step is not None:
            step(len(seg))
        return _rows(w, np.zeros(len(w)), total)
    return _rows(w, _segments_inside(SegmentBuffer(ref), seg, w, chunk, step), total)


# ------------------------------------------------------------------ exact, by segments
def line_segments(geoms: Any) -> np.ndarray:
    """The straight segments of line geometries as an ``(n, 2, 2)`` array (XY).

    Segments never join two parts of a multi-line; zero-length segments are dropped.
    """
    import shapely

    arr = np.asarray(geoms, dtype=object).reshape(-1)
    if arr.size == 0:
        return np.zeros((0, 2, 2))
    parts = shapely.get_parts(arr)
    xy, idx = shapely.get_coordinates(parts, return_index=True)
    if len(xy) < 2:
        return np.zeros((0, 2, 2))
    same = idx[1:] == idx[:-1]
    seg = np.stack([xy[:-1][same], xy[1:][same]], axis=1)
    keep = np.any(seg[:, 0] != seg[:, 1], axis=1) & np.isfinite(seg).all(axis=(1, 2))
    return seg[keep]


def _slab(p0: np.ndarray, q: np.ndarray, lo, hi) -> tuple:
    """Parameter interval where ``lo <= p0 + t q <= hi`` (empty: start > end)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - p0) / q
        t2 = (hi - p0) / q
    flat = q == 0
    inside = (p0 >= lo) & (p0 <= hi)
    start = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    end = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return start, end


def _disc(w: np.ndarray, u: np.ndarray, uu: np.ndarray, x: float) -> tuple:
    """Parameter interval where ``|w + t u| <= x`` (``uu = u.u > 0``)."""
    b = np.einsum("ij,ij->i", w, u)
    c = np.einsum("ij,ij->i", w, w) - x * x
    disc = b * b - uu * c
    root = np.sqrt(np.clip(disc, 0.0, None))
    ok = disc >= 0
    return (np.where(ok, (-b - root) / uu, np.inf), np.where(ok, (-b + root) / uu, -np.inf))


def capsule_intervals(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray,
                      x: float) -> tuple:
    """Where the segments ``p -> q`` run within ``x`` of the segments ``a -> b``.

    The points within ``x`` of a segment form a capsule (a rectangle and two discs),
    which is convex, so a straight segment meets it in one interval of its parameter
    ``t`` (``p + t (q - p)``, ``0 <= t <= 1``): the hull of the intervals in the two
    discs and in the rectangle, each in closed form.

    Parameters
    ----------
    p, q : numpy.ndarray, shape (n, 2)
        The tested segments (non-zero length).
    a, b : numpy.ndarray, shape (n, 2)
        The reference segments, paired row by row with the tested ones.
    x : float
        The distance (buffer width).

    Returns
    -------
    start, end : numpy.ndarray, shape (n,)
        The interval, clipped to ``[0, 1]``; empty where ``start >= end``.
    """
    u = q - p
    uu = np.einsum("ij,ij->i", u, u)
    starts, ends = zip(_disc(p - a, u, uu, x), _disc(p - b, u, uu, x))
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    n = np.column_stack([-e[:, 1], e[:, 0]])
    w = p - a
    s0, s1 = _slab(np.einsum("ij,ij->i", w, e), np.einsum("ij,ij->i", u, e), 0.0, length)
    r0, r1 = _slab(np.einsum("ij,ij->i", w, n), np.einsum("ij,ij->i", u, n), -x, x)
    rect0 = np.where(length > 0, np.maximum(s0, r0), np.inf)
    rect1 = np.where(length > 0, np.minimum(s1, r1), -np.inf)
    empty = rect0 > rect1
    start = np.minimum(np.minimum(*starts), np.where(empty, np.inf, rect0))
    end = np.maximum(np.maximum(*ends), np.where(empty, -np.inf, rect1))
    return np.clip(start, 0.0, 1.0), np.clip(end, 0.0, 1.0)


def covered_length(seg: np.ndarray, start: np.ndarray, end: np.ndarray,
                   seg_length: np.ndarray) -> float:
    """Total length covered by the union of parameter intervals of segments.

    ``seg[i]`` is the segment of interval ``[start[i], end[i]]`` (within ``[0, 1]``);
    intervals of the same segment that overlap count once. ``seg_length`` gives every
    segment's length. Sorting and a running maximum; no Python loop.
    """
    keep = end > start
    seg, start, end = seg[keep], start[keep], end[keep]
    if seg.size == 0:
        return 0.0
    order = np.lexsort((start, seg))
    seg, start, end = seg[order], start[order], end[order]
    # segments 2 apart on one axis: a running maximum never carries over to the next one
    rank = np.concatenate([[0], np.cumsum(seg[1:] != seg[:-1])]).astype(float)
    s = start + 2.0 * rank
    e = end + 2.0 * rank
    reach = np.maximum.accumulate(e)
    before = np.concatenate([[-np.inf], reach[:-1]])
    new = np.clip(e - np.maximum(s, before), 0.0, None)
    return float(np.sum(new * seg_length[seg]))


def covered_lengths(seg: np.ndarray, start: np.ndarray, end: np.ndarray,
                    seg_length: np.ndarray) -> np.ndarray:
    """:func:`covered_length` per segment: ``out[k]`` is the length of segment ``k``
    covered by the union of its intervals (``len(seg_length)`` values, 0 for a segment
    without intervals); their sum is :func:`covered_length` up to rounding. A segment's
    value depends only on its own intervals (bit for bit), whatever the others."""
    keep = end > start
    seg, start, end = seg[keep], start[keep], end[keep]
    order = np.lexsort((start, seg))
    seg, start, end = seg[order], start[order], end[order]
    first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]]) if seg.size else seg
    # where each interval's segment starts in the sorted list, and the running maximum of
    # the ends within each segment (exact: no offsets, so a segment's value does not
    # depend on the other segments measured with it)
    pos = np.arange(seg.size) - np.repeat(first, np.diff(np.r_[first, seg.size]))
    reach = end.copy()
    shift = 1
    while seg.size and shift <= pos.max():  # doubling: log2(intervals per segment) steps
        reach[shift:] = np.where(pos[shift:] >= shift,
                                 np.maximum(reach[shift:], reach[:-shift]), reach[shift:])
        shift *= 2
    before = np.where(pos > 0, np.r_[-np.inf, reach[:-1]], -np.inf)
    new = np.clip(end - np.maximum(start, before), 0.0, None)
    return np.bincount(seg, weights=new * seg_length[seg], minlength=len(seg_length))


def _cells(lo: np.ndarray, hi: np.ndarray, size: float) -> tuple:
    """The grid cells ``(ix, iy)`` every box ``lo .. hi`` (n, 2) covers, and its row."""
    c0 = np.floor(lo / size).astype(np.int64)
    c1 = np.floor(hi / size).astype(np.int64)
    nx, ny = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
    count = nx * ny
    row = np.repeat(np.arange(len(lo)), count)
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    return c0[row, 0] + k // ny[row], c0[row, 1] + k % ny[row], row


def _cut(seg: np.ndarray, step: float, with_rows: bool = False):
    """Segments ``(n, 2, 2)`` longer than ``step`` (per axis) cut into equal pieces.

    Exact for the buffer test: a segment's buffer is the union of its pieces' buffers,
    and a tested segment's length inside a buffer is the sum of its pieces'. With
    ``with_rows``, also the row of ``seg`` each piece comes from: ``(pieces, rows)``.
    """
    rows = None
    if not len(seg):
        pieces_of, rows = seg, np.zeros(0, dtype=np.int64)
    else:
        ext = np.abs(seg[:, 1] - seg[:, 0]).max(axis=1)
        pieces = np.maximum(np.ceil(ext / step), 1).astype(np.int64)
        if pieces.max() == 1:
            pieces_of = seg
        else:
            rows = np.repeat(np.arange(len(seg)), pieces)
            k = np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces)
            t0, t1 = (k / pieces[rows])[:, None], ((k + 1) / pieces[rows])[:, None]
            a, d = seg[rows, 0], seg[rows, 1] - seg[rows, 0]
            pieces_of = np.stack([a + t0 * d, np.where(t1 >= 1, seg[rows, 1], a + t1 * d)],
                                 axis=1)
    if not with_rows:
        return pieces_of
    return pieces_of, (np.arange(len(seg)) if rows is None else rows)


def _group_min(best: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
    """``best[index] = min(best[index], values)`` with repeated indices (sort + reduceat)."""
    order = np.argsort(index, kind="stable")
    idx, val = index[order], values[order]
    start = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    best[idx[start]] = np.minimum(best[idx[start]], np.minimum.reduceat(val, start))


class _Grid:
    """Boxes on a uniform grid, to find the pairs of overlapping boxes by sorting
    (:meth:`pairs`): a superset of the segments within a distance, without GEOS."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, size: float) -> None:
        self.lo, self.hi, self.size = lo, hi, size
        ix, iy, row = _cells(lo, hi, size)
        self.span = int(iy.max() - iy.min() + 3) if len(iy) else 1
        self.y0 = int(iy.min()) - 1 if len(iy) else 0
        key = ix * self.span + (iy - self.y0)
        order = np.argsort(key, kind="stable")
        self.key, self.row = key[order], row[order]

    def pairs(self, lo: np.ndarray, hi: np.ndarray) -> tuple:
        """``(i, j)``: every box ``i`` of ``lo .. hi`` overlapping the grid's box ``j``,
        each pair once (in the cell holding the low corner of the overlap)."""
        ix, iy, row = _cells(lo, hi, self.size)
        inside = (iy >= self.y0) & (iy < self.y0 + self.span)
        ix, iy, row = ix[inside], iy[inside], row[inside]
        key = ix * self.span + (iy - self.y0)
        a = np.searchsorted(self.key, key, side="left")
        b = np.searchsorted(self.key, key, side="right")
        n = b - a
        i = np.repeat(row, n)
        cell = np.repeat(key, n)
        j = self.row[np.repeat(a - np.cumsum(n) + n, n) + np.arange(int(n.sum()))]
        olo = np.maximum(lo[i], self.lo[j])
        ohi = np.minimum(hi[i], self.hi[j])
        ok = np.all(olo <= ohi, axis=1)  # the boxes overlap (not only share a cell)
        c = np.floor(olo[ok] / self.size).astype(np.int64)
        once = c[:, 0] * self.span + (c[:, 1] - self.y0) == cell[ok]
        return i[ok][once], j[ok][once]


class SegmentBuffer:
    """Exact round buffers of reference lines, for measuring tested segments against.

    Parameters
    ----------
    reference : numpy.ndarray, shape (n, 2, 2)
        Reference segments (:func:`line_segments`).

    The segments' boxes go on a uniform grid once (numpy sorting, no GEOS); :meth:`inside`
    pairs every tested segment with the reference segments whose boxes, grown by the
    largest width, overlap its box, and merges the intervals of
    :func:`capsule_intervals` (empty for the pairs farther apart). Segments longer than
    four cells, reference and tested, are cut into pieces (:func:`_cut`, exact), so no
    box covers more than a few cells.
    """

    def __init__(self, reference: np.ndarray) -> None:
        ref = np.asarray(reference, float).reshape(-1, 2, 2)
        self.origin = ref[0, 0].copy() if len(ref) else np.zeros(2)
        ref = ref - self.origin
        #: tested segments per query (the pairs of one query are held at once)
        self.chunk = 50_000
        self._grids: dict = {}
        ext = np.abs(ref[:, 1] - ref[:, 0]).max(axis=1) if len(ref) else np.ones(1)
        span = float(np.ptp(ref.reshape(-1, 2), axis=0).max()) if len(ref) else 1.0
        #: grid cell: the median reference segment's extent (a few cells per segment),
        #: at least 2^-20 of the extent (cell numbers stay far inside int64)
        self.cell = float(max(np.median(ext), span / 2 ** 20, 1e-6))
        self.ref = _cut(ref, 4 * self.cell)

    def _grid(self, distance: float) -> _Grid:
        """The reference boxes grown by ``distance``, on the grid (kept per distance)."""
        if distance not in self._grids:
            lo = self.ref.min(axis=1) - distance
            hi = self.ref.max(axis=1) + distance
            if len(self._grids) >= 2:  # the buffer's and the nearest query's: no more
                self._grids.pop(next(iter(self._grids)))
            self._grids[distance] = _Grid(lo, hi, max(self.cell, distance))
        return self._grids[distance]

    def nearest_distance(self, xy: np.ndarray, radius: Optional[float] = None) -> np.ndarray:
        """Distance of each point ``xy`` (n, 2) to the nearest reference segment, where
        it is at most ``radius`` (default: one grid cell); NaN for the farther points
        (the caller asks another index for those) and for points without coordinates."""
        pts = np.asarray(xy, float).reshape(-1, 2) - self.origin
        out = np.full(len(pts), np.nan)
        ok = np.flatnonzero(np.isfinite(pts).all(axis=1))
        if not len(self.ref) or not len(ok):
            return out
        r = float(self.cell if radius is None else radius)
        grid = self._grid(r)
        for k in range(0, len(ok), self.chunk):
            rows = ok[k:k + self.chunk]
            p = pts[rows]
            i, j = grid.pairs(p, p)
            if not len(i):
                continue
            a, b = self.ref[j, 0], self.ref[j, 1]
            d, w = b - a, p[i] - a
            dd = np.einsum("ij,ij->i", d, d)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.clip(np.where(dd > 0, np.einsum("ij,ij->i", w, d) / dd, 0.0), 0.0, 1.0)
            dist = np.hypot(*(w - t[:, None] * d).T)
            best = np.full(len(rows), np.inf)
            _group_min(best, i, dist)
            best[best > r] = np.inf
            out[rows] = np.where(np.isfinite(best), best, np.nan)
        return out

    def inside(self, tested: np.ndarray, widths, per_segment: bool = False) -> np.ndarray:
        """Length of the tested segments ``(n, 2, 2)`` inside each width's buffer.

        Returns the ``(len(widths),)`` sums over the segments, or with ``per_segment``
        the ``(n, len(widths))`` length of each tested segment inside each buffer (its
        column sums are the sums up to rounding). A segment's values are the
        same whatever the other segments measured with it (bit for bit).
        """
        widths = np.asarray(widths, float).reshape(-1)
        seg = np.asarray(tested, float).reshape(-1, 2, 2) - self.origin
        out = np.zeros((len(seg), len(widths)) if per_segment else len(widths))
        if not len(self.ref) or not len(seg) or not np.any(widths > 0):
            return out
        if len(seg) > self.chunk:  # bounded memory: the pairs of one chunk at a time
            for k in range(0, len(seg), self.chunk):
                if per_segment:  # each segment's values do not depend on the chunks
                    out[k:k + self.chunk] = self._inside(seg[k:k + self.chunk], widths, True)
                else:
                    out += self.inside(seg[k:k + self.chunk] + self.origin, widths)
            return out
        return self._inside(seg, widths, per_segment)

    def _inside(self, seg: np.ndarray, widths: np.ndarray, per_segment: bool) -> np.ndarray:
        """:meth:`inside` of one chunk of segments relative to :attr:`origin`."""
        out = np.zeros((len(seg), len(widths)) if per_segment else len(widths))
        grid = self._grid(float(widths.max()))
        # a long tested segment: pieces of a few cells (``row``: the segment of each)
        seg, row = _cut(seg, 4 * grid.size, with_rows=True)
        length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
        # candidates: tested boxes overlapping the reference boxes grown by the widest
        # buffer (every pair within that distance, and some farther that add nothing)
        i, j = grid.pairs(seg.min(axis=1), seg.max(axis=1))
        p, q = seg[i, 0], seg[i, 1]
        a, b = self.ref[j, 0], self.ref[j, 1]
        for k, x in enumerate(widths):
            if x > 0:
                start, end = capsule_intervals(p, q, a, b, float(x))
                if per_segment:
                    out[:, k] = np.bincount(row, weights=covered_lengths(i, start, end, length),
                                            minlength=len(out))
                else:
                    out[k] = covered_length(i, start, end, length)
        return out
