"""Distances of points to the nearest reference line when only the lines near the
points were read (numpy only).

A caller that reads a large layer of true centrelines only inside a box around its
points (the QGIS plugin's ``TrueLines``) finds each point's nearest segment among those
read, by a growing radius (:func:`nearest_distances`), and reads the whole layer only
for the points whose nearest read line is farther than the box's edge
(:func:`room_in_box`): a line not read lies outside the box, so at least that far.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Optional

import numpy as np

from vectoradjust.accuracy.buffer import SegmentBuffer

__all__ = ["room_in_box", "nearest_distances"]

#: points per query of :func:`nearest_distances` (bounded memory)
POINT_CHUNK = 5000
#: the radius of :func:`nearest_distances` grows by this factor per round ...
GROWTH = 4.0
#: ... up to this (m): farther points get NaN
MAX_RADIUS = 1e8


def room_in_box(xy: np.ndarray, box: Optional[tuple]) -> np.ndarray:
    """Each point's distance to the edge of ``box`` (negative outside it).

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
    box : (xmin, ymin, xmax, ymax) or None
        None: no box (every line was read): ``inf``.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    if box is None:
        return np.full(len(xy), np.inf)
    x0, y0, x1, y1 = (float(v) for v in box)
    return np.minimum.reduce([xy[:, 0] - x0, x1 - xy[:, 0], xy[:, 1] - y0, y1 - xy[:, 1]])


def nearest_distances(buffers: SegmentBuffer, xy: np.ndarray,
                      check: Optional[Callable[[], None]] = None) -> np.ndarray:
    """Each point's distance to the nearest segment of ``buffers``.

    Searches within the grid's cell, then within a radius growing by :data:`GROWTH`
    (:meth:`vectoradjust.accuracy.buffer.SegmentBuffer.nearest_distance`), for
    :data:`POINT_CHUNK` points at a time.

    Parameters
    ----------
    buffers : SegmentBuffer
    xy : numpy.ndarray, shape (n, 2)
    check : callable, optional
        Called before every query (it may raise to stop: Cancel).

    Returns
    -------
    numpy.ndarray, shape (n,)
        NaN for points without coordinates, and beyond :data:`MAX_RADIUS`.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    out = np.full(len(xy), np.nan)
    for k in range(0, len(xy), POINT_CHUNK):
        pts = xy[k:k + POINT_CHUNK]
        best = np.full(len(pts), np.nan)
        radius = max(buffers.cell, 1.0)
        todo = np.arange(len(pts))
        while len(todo):
            if check is not None:
                check()
            d = buffers.nearest_distance(pts[todo], radius)
            hit = np.isfinite(d)
            best[todo[hit]] = d[hit]
            todo = todo[~hit]
            radius *= GROWTH
            if radius > MAX_RADIUS:
                break
        out[k:k + POINT_CHUNK] = best
    return out
