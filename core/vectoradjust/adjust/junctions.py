"""Vertices of left-out roads that are junctions with the roads of a run.

When a road layer holds only some of the roads of its ``[[vectors]]`` entry (a selection,
a filter, deleted features), the measurements of the roads it does not hold are left
out of the run - except at a vertex that lies on a vertex of a road it holds (a
junction, within the merge tolerance of
:func:`vectoradjust.adjust.shapepoints.extract_shape_points`): those measurements are
renamed to the held vertex. numpy and scipy only; the QGIS
plugin (``qgis_plugin/algorithms/matching.py``) reads the layers and calls
:func:`junction_renames`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from vectoradjust.adjust.shapepoints import vertex_ids
from vectoradjust.model import LineLayer

__all__ = ["nearest_within", "junction_renames"]


def nearest_within(points: np.ndarray, targets: np.ndarray, tolerance: float) -> np.ndarray:
    """Index of each point's nearest target within ``tolerance`` in XY, else -1.

    Parameters
    ----------
    points : numpy.ndarray, shape (n, >=2)
        Points (their first two columns are used).
    targets : numpy.ndarray, shape (m, >=2)
        Candidates (a KD-tree of their XY).
    tolerance : float
        Largest distance (m) of a match.

    Returns
    -------
    numpy.ndarray of int, shape (n,)
        Row of ``targets`` nearest each point, -1 where none is within ``tolerance``
        (and for every point when there is no target).
    """
    pts = np.asarray(points, float)
    tgt = np.asarray(targets, float)
    pts = pts[:, :2] if pts.ndim == 2 else pts.reshape(-1, 2)
    tgt = tgt[:, :2] if tgt.ndim == 2 else tgt.reshape(-1, 2)
    out = np.full(len(pts), -1, dtype=np.int64)
    if not len(pts) or not len(tgt):
        return out
    tol = float(tolerance)
    dist, idx = cKDTree(tgt).query(pts, distance_upper_bound=tol)
    hit = dist <= tol
    out[hit] = idx[hit]
    return out


def junction_renames(full: LineLayer, kept: LineLayer, missing: Iterable,
                     tolerance: float) -> dict[str, Optional[str]]:
    """What becomes of the vertex ids of the roads ``missing`` from ``kept``.

    Parameters
    ----------
    full : LineLayer
        Every road of the entry's file.
    kept : LineLayer
        The roads of the run (a part of ``full``, same CRS).
    missing : iterable of str
        Feature ids of ``full`` that ``kept`` does not hold.
    tolerance : float
        Merge tolerance (m): a vertex of a missing road this close to a vertex of a kept
        road is that vertex.

    Returns
    -------
    dict
        ``{vertex id of a missing road: vertex id in kept, or None (left out)}``
        (:func:`vectoradjust.adjust.shapepoints.vertex_ids`); empty without missing roads.
    """
    missing = sorted(str(m) for m in missing)
    if not missing:
        return {}
    ids = vertex_ids(full)
    gone = np.isin(full.feature_ids[full.vertex_feature].astype(str), missing)
    renames: dict[str, Optional[str]] = dict.fromkeys(ids[gone].tolist())
    kept_ids = vertex_ids(kept)
    if len(kept_ids) and gone.any():
        j = nearest_within(full.coords[gone], kept.coords, tolerance)
        hit = j >= 0
        renames.update(zip(ids[gone][hit].tolist(), kept_ids[j[hit]].astype(str).tolist()))
    return renames
