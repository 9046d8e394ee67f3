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
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from vectoradjust.errors import LayerError

__all__ = ["buffer_test"]

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

    w = np.atleast_1d(np.asarray(widths, dtype=float))
    if w.ndim != 1:
        raise ValueError("widths must be a number or a 1-D sequence of numbers")
    if np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"buffer widths must be finite and >= 0, got {w.tolist()}")
    tst = _as_geometry_array(tested, "tested")
    ref = _as_geometry_array(reference, "reference")
    total = float(np.sum(shapely.length(tst))) if tst.size else 0.0
    ref_parts = [p for g in ref for p in shapely.get_parts(g)]
    ref_lines = shapely.multilinestrings(ref_parts) if ref_parts else None
    results = []
    for width in w:
        inside = 0.0
        if total > 0 and width > 0 and ref_lines is not None:
            buf = shapely.buffer(ref_lines, float(width), quad_segs=quad_segs, cap_style=cap_style)
            shapely.prepare(buf)
            hit = shapely.intersects(buf, tst)
            if np.any(hit):
                inter = shapely.intersection(tst[hit], buf)
                inside = float(np.sum(shapely.length(inter)))
        share = (inside / total) if total > 0 else None
        if share is not None:
            share = min(max(share, 0.0), 1.0)
        results.append(
            {
                "width": float(width),
                "share": share,
                "length_inside": inside,
                "length_total": total,
            }
        )
    return results

