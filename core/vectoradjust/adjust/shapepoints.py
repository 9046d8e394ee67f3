"""Shape points: the vertices of road features as object points.

Ids follow the contract: ``<feature id>_<vertex index>``, the vertex index 0-based
along the feature and continuing across parts. Vertices at the same XY (within the
merge tolerance, 1 mm by default) are one object point; any of their ids may be
measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from vectoradjust.model import LineLayer

__all__ = ["ShapePoints", "extract_shape_points", "lookup"]


@dataclass
class ShapePoints:
    """Vertices of one road layer and the object points they form.

    Attributes
    ----------
    layer : LineLayer
    vertex_ids : numpy.ndarray of str, shape (nv,)
    vertex_object : numpy.ndarray of int, shape (nv,)
        Object point of each vertex.
    object_xyz : numpy.ndarray, shape (no, 3)
        Database coordinates of each object point (those of its first vertex).
    object_vertex : numpy.ndarray of int, shape (no,)
        First vertex of each object point (its canonical id).
    """

    layer: LineLayer
    vertex_ids: np.ndarray
    vertex_object: np.ndarray
    object_xyz: np.ndarray
    object_vertex: np.ndarray

    @property
    def n_objects(self) -> int:
        """Number of distinct object points."""
        return len(self.object_xyz)

    @property
    def object_ids(self) -> np.ndarray:
        """Canonical id (first vertex's) of every object point."""
        return self.vertex_ids[self.object_vertex]


def vertex_ids(layer: LineLayer) -> np.ndarray:
    """Contract ids ``<feature id>_<vertex index>`` of all vertices of ``layer``."""
    fid = layer.feature_ids[layer.vertex_feature].astype(str)
    return np.char.add(np.char.add(fid, "_"), layer.vertex_index.astype(str))


def extract_shape_points(layer: LineLayer, tolerance: float = 0.001) -> ShapePoints:
    """Build shape points from a line layer.

    Parameters
    ----------
    layer : LineLayer
    tolerance : float
        Vertices closer than this in XY (m) are merged into one object point.

    Returns
    -------
    ShapePoints
    """
    ids = vertex_ids(layer)
    nv = len(ids)
    xy = layer.coords[:, :2]
    if nv:
        tree = cKDTree(xy)
        pairs = tree.query_pairs(r=tolerance, output_type="ndarray")
    else:
        pairs = np.zeros((0, 2), np.int64)
    if len(pairs):
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(nv, nv))
        _, labels = connected_components(graph, directed=False)
    else:
        labels = np.arange(nv)
    # number components in the order of their first vertex
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertex_object = rank[np.asarray(inverse).reshape(-1)]
    object_vertex = first[order]
    return ShapePoints(layer, ids, vertex_object, layer.coords[object_vertex].copy(), object_vertex)


def lookup(keys: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Index of each of ``ids`` in ``keys`` (unique), -1 where absent; vectorised.

    The strings are compared through a 64-bit hash of their characters (an integer
    search instead of a string search: ~5x faster for a million ids); every match is
    confirmed on the strings themselves, and equal hashes among the keys (a collision or
    a repeated key) fall back to the search on the strings.
    """
    keys = _as_text(keys)
    ids = _as_text(ids)
    if len(keys) == 0:
        return np.full(len(ids), -1, np.int64)
    width = max(keys.dtype.itemsize, ids.dtype.itemsize) // 4
    if width == 0 or len(ids) == 0:
        return _lookup_strings(keys, ids)
    keys = keys.astype(f"<U{width}", copy=False)  # copied only when the width differs
    ids = ids.astype(f"<U{width}", copy=False)
    hk, hi = string_hash(keys), string_hash(ids)
    order = np.argsort(hk, kind="stable")
    sh = hk[order]
    if np.any(sh[1:] == sh[:-1]):
        return _lookup_strings(keys, ids)
    pos = np.clip(np.searchsorted(sh, hi), 0, len(sh) - 1)
    cand = order[pos]
    found = (sh[pos] == hi) & (keys[cand] == ids)
    return np.where(found, cand, -1).astype(np.int64)


def _lookup_strings(keys: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """:func:`lookup` by a binary search on the strings."""
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    pos = np.searchsorted(sk, ids)
    pos = np.clip(pos, 0, len(sk) - 1)
    found = sk[pos] == ids
    return np.where(found, order[pos], -1).astype(np.int64)


def _as_text(a) -> np.ndarray:
    """``a`` as a ``str`` array: itself when it is one already (no copy)."""
    a = np.asarray(a)
    return a if a.dtype.kind == "U" else a.astype(str)


def string_codes(a: np.ndarray) -> np.ndarray:
    """The characters of a ``str`` array as code points (n, width), 0 after the end."""
    a = np.ascontiguousarray(_as_text(a))
    width = a.dtype.itemsize // 4
    return a.view(np.uint32).reshape(len(a), width) if width else np.zeros((len(a), 0),
                                                                           np.uint32)


#: multiplier of :func:`string_hash` (the 64-bit FNV prime)
_HASH_MULT = 1099511628211


def string_hash(a: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """A 64-bit polynomial hash of each string of a ``str`` array (one width for all).

    ``h = sum_i c_i m^(w - 1 - i)`` modulo 2^64 over the ``w`` code points ``c_i`` (0
    after the end): the value of Horner's rule ``h = h m + c_i``, computed as one
    product of the codes with the powers of ``m`` per chunk of strings (unsigned
    arithmetic wraps modulo 2^64), which reads every string once.
    """
    codes = string_codes(a)
    n, w = codes.shape
    powers = np.array([pow(_HASH_MULT, w - 1 - i, 1 << 64) for i in range(w)], np.uint64)
    h = np.zeros(n, np.uint64)
    for start in range(0, n, chunk):  # chunks: the widened codes stay small
        h[start:start + chunk] = codes[start:start + chunk].astype(np.uint64) @ powers
    return h
