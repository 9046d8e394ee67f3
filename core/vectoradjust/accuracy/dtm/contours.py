"""Contour lines of a grid (marching squares) with their accuracy:
:func:`contour_segments`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from vectoradjust.accuracy.dtm.grid_accuracy import DTMProduct

__all__ = ["ContourSegments", "contour_segments"]


@dataclass
class ContourSegments:
    """Contour segments of a DTM with their horizontal uncertainty.

    Attributes
    ----------
    level : numpy.ndarray, shape (m,)
    xy : numpy.ndarray, shape (m, 2, 2)
        Start and end point of each segment.
    sigma_z : numpy.ndarray, shape (m, 2)
        Height sigma at both ends (interpolated along the cell edges).
    tan_slope : numpy.ndarray, shape (m, 2)
    sigma_xy : numpy.ndarray, shape (m, 2)
        ``sigma_z / tan(slope)``, at most ``max_width`` (horizontal uncertainty).
    capped : numpy.ndarray of bool, shape (m, 2)
        Where the slope was too flat and ``max_width`` was used.
    """

    level: np.ndarray
    xy: np.ndarray
    sigma_z: np.ndarray
    tan_slope: np.ndarray
    sigma_xy: np.ndarray
    capped: np.ndarray

    def buffer_rings(self) -> np.ndarray:
        """Per segment the quadrilateral ``(m, 4, 2)`` reaching ``sigma_xy`` to each side.

        Its corners are the segment's ends moved by their own ``sigma_xy`` along the
        segment's normal, both ways; the union of a level's quadrilaterals is its
        contour's uncertainty buffer.
        """
        d = self.xy[:, 1] - self.xy[:, 0]
        n = np.column_stack([-d[:, 1], d[:, 0]])
        length = np.hypot(n[:, 0], n[:, 1])
        n = n / np.where(length > 0, length, 1.0)[:, None]
        w0, w1 = self.sigma_xy[:, 0:1], self.sigma_xy[:, 1:2]
        return np.stack([self.xy[:, 0] + w0 * n, self.xy[:, 1] + w1 * n,
                         self.xy[:, 1] - w1 * n, self.xy[:, 0] - w0 * n], axis=1)


# marching squares: corners 0 (r, c), 1 (r, c+1), 2 (r+1, c+1), 3 (r+1, c); edges
# 0 = 0-1, 1 = 1-2, 2 = 2-3, 3 = 3-0; case (bit k: corner k above) -> edge pairs
_EDGES = np.array([[0, 1], [1, 2], [3, 2], [0, 3]])
_CASES = {1: [(3, 0)], 2: [(0, 1)], 3: [(3, 1)], 4: [(1, 2)], 6: [(0, 2)], 7: [(3, 2)],
          8: [(2, 3)], 9: [(0, 2)], 11: [(1, 2)], 12: [(1, 3)], 13: [(0, 1)], 14: [(3, 0)]}
_SADDLES = {5: ([(0, 1), (2, 3)], [(3, 0), (1, 2)]), 10: ([(3, 0), (1, 2)], [(0, 1), (2, 3)])}


def _edge_points(fields: list, rr, cc, edge, level):
    """Crossing of ``level`` on an edge of each cell: values of every field there."""
    a, b = _EDGES[edge, 0], _EDGES[edge, 1]
    dr = np.array([0, 0, 1, 1])
    dc = np.array([0, 1, 1, 0])
    h = fields[0]
    ha = h[rr + dr[a], cc + dc[a]]
    hb = h[rr + dr[b], cc + dc[b]]
    t = np.clip((level - ha) / np.where(hb == ha, 1.0, hb - ha), 0.0, 1.0)
    return [f[rr + dr[a], cc + dc[a]] * (1 - t) + f[rr + dr[b], cc + dc[b]] * t
            for f in fields[1:]]


def _level_segments(fields: list, level: float) -> list:
    """Segments of one level: lists of per-field (k, 2) start and end values."""
    h = fields[0]
    q = [h[:-1, :-1], h[:-1, 1:], h[1:, 1:], h[1:, :-1]]
    ok = np.all([np.isfinite(v) for v in q], axis=0)
    case = sum(((v >= level) & ok).astype(int) << k for k, v in enumerate(q))
    case = np.where(ok, case, 0)
    centre = 0.25 * sum(np.where(ok, v, 0.0) for v in q)
    out = []
    for code in range(1, 15):
        rr, cc = np.nonzero(case == code)
        if rr.size == 0:
            continue
        if code in _SADDLES:
            hi = centre[rr, cc] >= level
            pairs_hi, pairs_lo = _SADDLES[code]
            groups = [(pairs_hi, hi), (pairs_lo, ~hi)]
        else:
            groups = [(_CASES[code], np.ones(rr.size, bool))]
        for pairs, sel in groups:
            for e0, e1 in pairs:
                p0 = _edge_points(fields, rr[sel], cc[sel], e0, level)
                p1 = _edge_points(fields, rr[sel], cc[sel], e1, level)
                out.append((p0, p1))
    return out


def contour_segments(product: DTMProduct, interval: float,
                     max_width: Optional[float] = None) -> ContourSegments:
    """Contours of a DTM product with the horizontal uncertainty ``sigma_z / tan a``.

    Marching squares on the cell-centre heights (saddles resolved by the cell's mean).
    Along a contour the height is fixed; a height error ``sigma_z`` moves it by
    ``sigma_z / tan a`` across the slope ``a`` (the gradient's magnitude; Filin &
    Doytsher's ``dh / (b + d (y - y0))`` along one axis).

    Parameters
    ----------
    product : DTMProduct
    interval : float
        Contour interval (m); levels are its multiples.
    max_width : float, optional
        Cap of ``sigma_xy`` where the terrain is flat; default 5 cells.

    Returns
    -------
    ContourSegments
    """
    if not interval > 0:
        raise ValueError("the contour interval must be positive")
    gt = product.transform
    rows, cols = product.height.shape
    cap = 5.0 * abs(gt[1]) if max_width is None else float(max_width)
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    x = gt[0] + (c + 0.5) * gt[1]
    y = gt[3] + (r + 0.5) * gt[5]
    fields = [product.height, x, y, product.sigma, product.tan_slope]
    h = product.height[np.isfinite(product.height)]
    parts = []
    if h.size and rows > 1 and cols > 1:
        for level in np.arange(np.ceil(h.min() / interval), np.floor(h.max() / interval) + 1):
            for p0, p1 in _level_segments(fields, level * interval):
                parts.append((level * interval, p0, p1))
    if not parts:
        z = np.zeros((0, 2))
        return ContourSegments(np.zeros(0), np.zeros((0, 2, 2)), z, z, z, z.astype(bool))
    level = np.concatenate([np.full(len(p0[0]), lv) for lv, p0, _ in parts])

    def two(i):
        return np.concatenate([np.column_stack([p0[i], p1[i]]) for _, p0, p1 in parts])

    xy = np.stack([np.stack([two(0)[:, k], two(1)[:, k]], axis=-1) for k in range(2)], axis=1)
    sz, tan = two(2), two(3)
    with np.errstate(divide="ignore", invalid="ignore"):
        width = sz / tan
    capped = ~(width <= cap)
    return ContourSegments(level, xy, sz, tan, np.where(capped, cap, width), capped)

