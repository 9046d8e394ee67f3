"""The buffer test with flat or square end caps, exactly, by segments (numpy only).

:func:`vectoradjust.accuracy.buffer.segment_buffer_test` measures the round buffer (the
points within ``x`` of the reference lines). With flat or square end caps - GEOS's
buffer styles ``flat`` and ``square`` with round joins - the buffer of one line part is
the union of

* a rectangle per segment: the points whose projection falls on the segment and lie
  within ``x`` of it; at a free end of the part, with square caps, the rectangle runs
  ``x`` beyond the end (flat caps: it stops there);
* a round join per inner vertex ``v`` (and, for a closed part, at its first vertex): the
  sector of the disc of radius ``x`` around ``v`` between the two segments' normals on
  the outer side of the turn, ``|w| <= x``, ``w . d_in >= 0``, ``w . d_out <= 0``
  (``w = point - v``, ``d_in``, ``d_out`` the directions of the segments before and
  after ``v``).

Both are convex, so a straight tested segment meets each in one interval of its
parameter, in closed form; the length inside the union is that of the union of the
intervals (:func:`vectoradjust.accuracy.buffer.covered_length`). GEOS's polygon buffers
(``shapely.buffer(..., cap_style="flat")``, QGIS) approximate the round joins by chords
(``quad_segs`` per quarter circle), so they are narrower there by at most
``x (1 - cos(pi / (4 quad_segs)))``. The QGIS plugin's buffer test reads the layers and
calls :func:`capped_buffer_test`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

from vectoradjust.accuracy.buffer import (
    SEGMENT_CHUNK,
    _cut,
    _disc,
    _Grid,
    _rows,
    _slab,
    covered_length,
)

__all__ = ["CAP_STYLES", "CappedReference", "capped_buffer_test", "part_segments"]

#: end caps measured here (round: :func:`vectoradjust.accuracy.buffer.segment_buffer_test`)
CAP_STYLES = ("flat", "square")


def _clean_part(xy: np.ndarray) -> np.ndarray:
    """A part's XY vertices without repeated consecutive vertices or non-finite rows."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) < 2:
        return xy
    keep = np.r_[True, np.any(xy[1:] != xy[:-1], axis=1)]
    return xy[keep]


def part_segments(parts: Sequence[np.ndarray]) -> tuple:
    """Segments of line parts, which of them end the part, and the parts' joins.

    Parameters
    ----------
    parts : sequence of numpy.ndarray, shape (k, 2)
        The vertices of each line part (a multi-line's parts one by one).

    Returns
    -------
    seg : numpy.ndarray, shape (n, 2, 2)
        The segments (zero-length ones dropped).
    first, last : numpy.ndarray of bool, shape (n,)
        The segment starts, ends, an open part (where a square cap extends it).
    joins : numpy.ndarray, shape (m, 3, 2)
        ``(v, d_in, d_out)`` of every round join: inner vertices, and the first vertex of
        a closed part (its first and last vertices equal, at least three segments).
    """
    segs, first, last, joins = [], [], [], []
    for part in parts:
        xy = _clean_part(part)
        if len(xy) < 2:
            continue
        s = np.stack([xy[:-1], xy[1:]], axis=1)
        n = len(s)
        closed = n >= 3 and np.array_equal(xy[0], xy[-1])
        f, la = np.zeros(n, bool), np.zeros(n, bool)
        if not closed:
            f[0], la[-1] = True, True
        d = s[:, 1] - s[:, 0]
        d = d / np.hypot(d[:, 0], d[:, 1])[:, None]
        if n > 1:
            joins.append(np.stack([xy[1:-1], d[:-1], d[1:]], axis=1))
        if closed:
            joins.append(np.stack([xy[:1], d[-1:], d[:1]], axis=1))
        segs.append(s)
        first.append(f)
        last.append(la)
    if not segs:
        return np.zeros((0, 2, 2)), np.zeros(0, bool), np.zeros(0, bool), np.zeros((0, 3, 2))
    joins = np.concatenate(joins) if joins else np.zeros((0, 3, 2))
    return np.concatenate(segs), np.concatenate(first), np.concatenate(last), joins


def _rect_intervals(p, u, a, b, ext0, ext1, x) -> tuple:
    """Parameter interval of ``p + t u`` in the rectangles of the segments ``a -> b``
    (half-width ``x``, running ``ext0`` before ``a`` and ``ext1`` beyond ``b``)."""
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    e = d / length[:, None]
    n = np.column_stack([-e[:, 1], e[:, 0]])
    w = p - a
    s0, s1 = _slab(np.einsum("ij,ij->i", w, e), np.einsum("ij,ij->i", u, e), -ext0,
                   length + ext1)
    r0, r1 = _slab(np.einsum("ij,ij->i", w, n), np.einsum("ij,ij->i", u, n), -x, x)
    return np.maximum(s0, r0), np.minimum(s1, r1)


def _join_intervals(p, u, v, d_in, d_out, x) -> tuple:
    """Parameter interval of ``p + t u`` in the round-join sectors at ``v``."""
    w = p - v
    uu = np.einsum("ij,ij->i", u, u)
    c0, c1 = _disc(w, u, uu, x)
    a0, a1 = _slab(np.einsum("ij,ij->i", w, d_in), np.einsum("ij,ij->i", u, d_in), 0.0,
                   np.inf)
    b0, b1 = _slab(np.einsum("ij,ij->i", w, d_out), np.einsum("ij,ij->i", u, d_out),
                   -np.inf, 0.0)
    return np.maximum.reduce([c0, a0, b0]), np.minimum.reduce([c1, a1, b1])


class CappedReference:
    """Flat- or square-capped buffers of reference line parts, to measure tested
    segments against (see the module).

    Parameters
    ----------
    parts : sequence of numpy.ndarray, shape (k, 2)
        The reference lines' parts (projected XY, metres).
    cap_style : {"flat", "square"}
        The end caps; joins are round.
    """

    def __init__(self, parts: Sequence[np.ndarray], cap_style: str = "flat") -> None:
        if cap_style not in CAP_STYLES:
            raise ValueError(f"cap_style must be one of {CAP_STYLES}, got {cap_style!r}")
        self.cap_style = cap_style
        seg, first, last, joins = part_segments(parts)
        self.origin = seg[0, 0].copy() if len(seg) else np.zeros(2)
        seg = seg - self.origin
        ext = np.abs(seg[:, 1] - seg[:, 0]).max(axis=1) if len(seg) else np.ones(1)
        span = float(np.ptp(seg.reshape(-1, 2), axis=0).max()) if len(seg) else 1.0
        #: grid cell, as :class:`vectoradjust.accuracy.buffer.SegmentBuffer` chooses it
        self.cell = float(max(np.median(ext), span / 2 ** 20, 1e-6))
        pieces, rows = _cut(seg, 4 * self.cell, with_rows=True)
        starts = np.r_[True, rows[1:] != rows[:-1]] if len(rows) else np.zeros(0, bool)
        ends = np.r_[rows[1:] != rows[:-1], True] if len(rows) else np.zeros(0, bool)
        self.seg = pieces
        self.cap0 = first[rows] & starts if len(rows) else starts
        self.cap1 = last[rows] & ends if len(rows) else ends
        self.joins = joins.copy()
        if len(joins):
            self.joins[:, 0] -= self.origin

    def __len__(self) -> int:
        return len(self.seg)

    def _grid(self, reach: float) -> tuple:
        """The rectangles' and joins' boxes grown by ``reach``, on one grid."""
        lo = np.concatenate([self.seg.min(axis=1), self.joins[:, 0]])
        hi = np.concatenate([self.seg.max(axis=1), self.joins[:, 0]])
        size = max(self.cell, reach)
        return _Grid(lo - reach, hi + reach, size), size

    def inside(self, tested: np.ndarray, widths) -> np.ndarray:
        """Length of the tested segments ``(n, 2, 2)`` inside each width's buffer."""
        widths = np.asarray(widths, float).reshape(-1)
        seg = np.asarray(tested, float).reshape(-1, 2, 2) - self.origin
        out = np.zeros(len(widths))
        if not len(self.seg) or not len(seg) or not np.any(widths > 0):
            return out
        xmax = float(widths.max())
        grid, size = self._grid(2.0 * xmax if self.cap_style == "square" else xmax)
        seg = _cut(seg, 4 * size)
        length = np.hypot(*(seg[:, 1] - seg[:, 0]).T)
        i, j = grid.pairs(seg.min(axis=1), seg.max(axis=1))
        is_rect = j < len(self.seg)
        ir, jr = i[is_rect], j[is_rect]
        ij, jj = i[~is_rect], j[~is_rect] - len(self.seg)
        for k, x in enumerate(widths):
            if x <= 0:
                continue
            e0 = np.where(self.cap0[jr], x, 0.0) if self.cap_style == "square" else 0.0
            e1 = np.where(self.cap1[jr], x, 0.0) if self.cap_style == "square" else 0.0
            p, u = seg[ir, 0], seg[ir, 1] - seg[ir, 0]
            r0, r1 = _rect_intervals(p, u, self.seg[jr, 0], self.seg[jr, 1], e0, e1, x)
            p, u = seg[ij, 0], seg[ij, 1] - seg[ij, 0]
            jn = self.joins[jj]
            c0, c1 = _join_intervals(p, u, jn[:, 0], jn[:, 1], jn[:, 2], x)
            start = np.clip(np.concatenate([r0, c0]), 0.0, 1.0)
            end = np.clip(np.concatenate([r1, c1]), 0.0, 1.0)
            out[k] = covered_length(np.concatenate([ir, ij]), start, end, length)
        return out


def capped_buffer_test(tested: np.ndarray, reference_parts: Sequence[np.ndarray], widths: Any,
                       cap_style: str = "flat", *, chunk: int = 0,
                       step: Optional[Any] = None) -> list[dict[str, Any]]:
    """The buffer test with flat or square end caps (round joins), exactly.

    Parameters
    ----------
    tested : numpy.ndarray, shape (n, 2, 2)
        Tested segments (as :func:`vectoradjust.accuracy.buffer.line_segments` gives).
    reference_parts : sequence of numpy.ndarray, shape (k, 2)
        The reference lines' parts, each its vertices in order.
    widths : float or sequence of float
        Buffer widths (>= 0).
    cap_style : {"flat", "square"}
        End caps of the reference lines' buffers.
    chunk : int, optional
        Tested segments measured per step (default
        :data:`vectoradjust.accuracy.buffer.SEGMENT_CHUNK`).
    step : callable, optional
        ``step(n)`` after each chunk of ``n`` segments (progress; it may raise to stop).

    Returns
    -------
    list of dict
        ``{"width", "share", "length_inside", "length_total"}`` per width, as
        :func:`vectoradjust.accuracy.buffer.segment_buffer_test`.

    Raises
    ------
    ValueError
        If a width is negative or not finite, or ``cap_style`` is not flat or square.
    """
    w = np.atleast_1d(np.asarray(widths, dtype=float)).reshape(-1)
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"buffer widths must be finite and >= 0, got {w.tolist()}")
    ref = CappedReference(reference_parts, cap_style)
    seg = np.asarray(tested, float).reshape(-1, 2, 2)
    total = float(np.sum(np.hypot(*(seg[:, 1] - seg[:, 0]).T))) if len(seg) else 0.0
    inside = np.zeros(len(w))
    chunk = int(chunk) if chunk and chunk > 0 else SEGMENT_CHUNK
    for k in range(0, max(len(seg), 1), chunk):
        part = seg[k:k + chunk]
        if total > 0 and len(ref):
            inside += ref.inside(part, w)
        if step is not None:
            step(len(part))
    return _rows(w, inside, total)
