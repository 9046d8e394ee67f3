"""Interpolation of a height model (TIN, bilinear, bicubic) as a sparse operator, and the
propagated covariance of interpolated heights.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import sparse

from vectoradjust.accuracy.dtm.models import METHODS, HeightModel, NodeGrid

__all__ = ["Interpolated", "interpolation_operator", "interpolate", "keys_weights"]


_CHUNK = 1024



@dataclass
class Interpolated:
    """Heights at query points as a linear function of the model's parameters.

    Attributes
    ----------
    h : numpy.ndarray, shape (q,)
        Heights (NaN outside the model).
    jacobian : scipy.sparse.csr_matrix, shape (q, m)
        ``d h / d parameters`` (zero rows outside).
    gradient : numpy.ndarray, shape (q, 2)
        ``d h / d(X, Y)`` of the surface at the query points.
    valid : numpy.ndarray of bool, shape (q,)
    """

    h: np.ndarray
    jacobian: sparse.csr_matrix
    gradient: np.ndarray
    valid: np.ndarray


def keys_weights(t: np.ndarray, a: float = -0.5) -> np.ndarray:
    """Keys' cubic convolution weights of the nodes at ``-1, 0, 1, 2`` for offset ``t``.

    Parameters
    ----------
    t : numpy.ndarray
        Fractional position in ``[0, 1]``.
    a : float
        Kernel parameter (-1/2: third-order accurate).

    Returns
    -------
    numpy.ndarray, shape (..., 4)
        Weights (they sum to 1) and, second, their derivatives by ``t``.
    """
    t = np.asarray(t, float)
    s = np.stack([1 + t, t, 1 - t, 2 - t], axis=-1)
    sign = np.array([1.0, 1.0, -1.0, -1.0])  # d s / d t

    def k(s):
        near = (a + 2) * s**3 - (a + 3) * s**2 + 1
        far = a * s**3 - 5 * a * s**2 + 8 * a * s - 4 * a
        return np.where(s <= 1, near, far)

    def dk(s):
        near = 3 * (a + 2) * s**2 - 2 * (a + 3) * s
        far = 3 * a * s**2 - 10 * a * s + 8 * a
        return np.where(s <= 1, near, far)

    return np.stack([k(s), dk(s) * sign], axis=0)


def _axis_weights(frac: np.ndarray, n: int, method: str):
    """Node indices, weights and weight derivatives along one axis."""
    if method == "bilinear":
        i0 = np.clip(np.floor(frac), 0, max(n - 2, 0)).astype(np.int64)
        t = frac - i0
        idx = i0[:, None] + np.arange(2)
        w = np.column_stack([1 - t, t])
        dw = np.column_stack([-np.ones_like(t), np.ones_like(t)])
        ok = (frac >= 0) & (frac <= n - 1)
    else:
        i0 = np.clip(np.floor(frac), 1, max(n - 3, 1)).astype(np.int64)
        t = frac - i0
        idx = i0[:, None] + np.arange(-1, 3)
        w, dw = keys_weights(t)
        ok = (frac >= 1) & (frac <= n - 2)
    return idx, w, dw, ok


def _grid_operator(grid: NodeGrid, query: np.ndarray, method: str):
    """Sparse weights (q, nodes) of a grid interpolation and their X/Y derivatives."""
    fc = (query[:, 0] - grid.x0) / grid.dx
    fr = (query[:, 1] - grid.y0) / grid.dy
    ci, cw, cdw, cok = _axis_weights(fc, grid.cols, method)
    ri, rw, rdw, rok = _axis_weights(fr, grid.rows, method)
    k = ci.shape[1]
    node = (ri[:, :, None] * grid.cols + ci[:, None, :]).reshape(len(query), k * k)
    w = (rw[:, :, None] * cw[:, None, :]).reshape(len(query), -1)
    wx = (rw[:, :, None] * cdw[:, None, :]).reshape(len(query), -1) / grid.dx
    wy = (rdw[:, :, None] * cw[:, None, :]).reshape(len(query), -1) / grid.dy
    ok = cok & rok
    node = np.where(ok[:, None], np.clip(node, 0, grid.rows * grid.cols - 1), 0)
    rows = np.repeat(np.arange(len(query)), k * k)
    shape = (len(query), grid.rows * grid.cols)

    def mat(v):
        return sparse.csr_matrix((np.where(ok[:, None], v, 0.0).ravel(), (rows, node.ravel())),
                                 shape=shape)

    return mat(w), mat(wx), mat(wy), ok


def _tin_operator(model: HeightModel, query: np.ndarray) -> Interpolated:
    """Linear interpolation in the Delaunay triangles of the points."""
    tri = model.tin
    xyz = model.xyz
    # the directed walk of find_simplex can take seconds for points outside the hull
    # (scipy 1.17: 9 s for 2400 points on 600 triangles); brute force is linear in both
    s = tri.find_simplex(query, bruteforce=len(tri.simplices) < 20000)
    ok = s >= 0
    s0 = np.where(ok, s, 0)
    tr = tri.transform[s0]
    b2 = np.einsum("qij,qj->qi", tr[:, :2, :], query - tr[:, 2, :])
    w = np.column_stack([b2, 1 - b2.sum(axis=1)])
    verts = tri.simplices[s0]
    z = xyz[verts, 2]
    # plane gradient: grad h = sum_i z_i grad w_i, grad of (w0, w1) = rows of T
    gw = np.concatenate([tr[:, :2, :], -tr[:, :2, :].sum(axis=1, keepdims=True)], axis=1)
    g = np.einsum("qi,qij->qj", z, gw)
    h = np.where(ok, (w * z).sum(axis=1), np.nan)
    w = np.where(ok[:, None], w, 0.0)
    rows = np.repeat(np.arange(len(query)), 9)
    cols = (3 * verts[:, :, None] + np.arange(3)).reshape(-1)
    vals = np.stack([-w * g[:, 0:1], -w * g[:, 1:2], w], axis=-1).reshape(-1)
    jac = sparse.csr_matrix((vals, (rows, cols)), shape=(len(query), 3 * len(xyz)))
    return Interpolated(h, jac, np.where(ok[:, None], g, np.nan), ok)


def interpolation_operator(model: HeightModel, query, method: str = "tin",
                           nodes: Optional[NodeGrid] = None) -> Interpolated:
    """Heights at ``query`` and their Jacobian by the model's parameters.

    Parameters
    ----------
    model : HeightModel
    query : array_like, shape (q, 2)
    method : {"tin", "bilinear", "bicubic"}
        ``tin`` needs a points model. ``bilinear`` / ``bicubic`` interpolate in the
        DEM's nodes, or (points model) in ``nodes`` whose heights are the TIN's.
    nodes : NodeGrid, optional
        The node grid of a points model's bilinear / bicubic surface.

    Returns
    -------
    Interpolated
    """
    q = np.asarray(query, float).reshape(-1, 2)
    if method not in METHODS:
        raise ValueError(f"interpolation {method!r}: use one of {', '.join(METHODS)}")
    if method == "tin":
        if model.kind != "points":
            raise ValueError("TIN interpolation needs the adjusted points (a points model)")
        return _tin_operator(model, q)
    if model.kind == "points":
        if nodes is None:
            raise ValueError("bilinear / bicubic on points need the node grid (nodes=)")
        at = _tin_operator(model, nodes.xy())
        node_h = at.h
        node_jac = at.jacobian
    else:
        nodes = model.grid
        node_h = model.heights.ravel()
        node_jac = None
    w, wx, wy, ok = _grid_operator(nodes, q, method)
    bad_nodes = ~np.isfinite(node_h)
    if bad_nodes.any():
        ok &= np.asarray(abs(w)[:, bad_nodes].sum(axis=1)).ravel() == 0
        node_h = np.where(bad_nodes, 0.0, node_h)
    h = np.where(ok, w @ node_h, np.nan)
    g = np.column_stack([wx @ node_h, wy @ node_h])
    jac = w if node_jac is None else (w @ node_jac).tocsr()
    keep = sparse.diags(ok.astype(float))
    return Interpolated(h, (keep @ jac).tocsr(), np.where(ok[:, None], g, np.nan), ok)


def _covariance(model: HeightModel, ja: sparse.csr_matrix,
                jb: Optional[sparse.csr_matrix] = None, diagonal: bool = False) -> np.ndarray:
    """``J_a Sigma J_b'`` (or its diagonal) on the parameters the rows use."""
    jb = ja if jb is None else jb
    cols = np.union1d(ja.indices, jb.indices).astype(np.int64)
    if cols.size == 0:
        n = ja.shape[0]
        return np.zeros(n) if diagonal else np.zeros((n, jb.shape[0]))
    c = model.parameter_covariance(cols)
    a = ja[:, cols].toarray()
    b = jb[:, cols].toarray()
    if diagonal:
        return np.einsum("ij,ij->i", a @ c, b)
    return a @ c @ b.T


def _local_covariance(model: HeightModel, idx: np.ndarray) -> np.ndarray:
    """Covariance blocks ``(q, k, k)`` of the parameters ``idx`` (q, k) of each row."""
    if model.kind == "points":
        return model.covariance[idx[:, :, None], idx[:, None, :]]
    g = model.grid
    r, c = np.divmod(idx, g.cols)
    d = np.hypot((c[:, :, None] - c[:, None, :]) * g.dx, (r[:, :, None] - r[:, None, :]) * g.dy)
    if model.correlation_length > 0:
        return model.node_sigma ** 2 * np.exp(-d / model.correlation_length)
    return model.node_sigma ** 2 * (d == 0)


def _row_variance(model: HeightModel, jac: sparse.csr_matrix) -> np.ndarray:
    """``diag(J Sigma J')`` row by row from each row's own parameters."""
    jac = jac.tocsr()
    jac.sum_duplicates()
    nnz = np.diff(jac.indptr)
    out = np.zeros(jac.shape[0])
    k = int(nnz.max()) if nnz.size else 0
    if k == 0:
        return out
    chunk = max(1, 4_000_000 // (k * k))
    for i in range(0, jac.shape[0], chunk):
        sub = jac[i:i + chunk]
        n = np.diff(sub.indptr)
        pos = np.arange(k)[None, :] < n[:, None]
        idx = np.zeros((sub.shape[0], k), np.int64)
        w = np.zeros((sub.shape[0], k))
        idx[pos] = sub.indices
        w[pos] = sub.data
        out[i:i + chunk] = np.einsum("qi,qij,qj->q", w, _local_covariance(model, idx), w)
    return out


def interpolate(model: HeightModel, query, method: str = "tin",
                nodes: Optional[NodeGrid] = None, full: bool = False):
    """Heights at ``query`` with their propagated sigma (and full covariance).

    Parameters
    ----------
    model, query, method, nodes
        As :func:`interpolation_operator`.
    full : bool
        Also return the full covariance between the query heights.

    Returns
    -------
    (op, sigma) or (op, sigma, covariance)
        ``op`` the :class:`Interpolated`, ``sigma`` (q,) from ``F Sigma F'`` (NaN
        outside), and with ``full`` the (q, q) covariance.
    """
    op = interpolation_operator(model, query, method, nodes)
    if full:
        cov = _covariance(model, op.jacobian)
        var = np.diag(cov).copy()
    else:
        var = _row_variance(model, op.jacobian)
    sigma = np.where(op.valid, np.sqrt(np.clip(var, 0, None)), np.nan)
    return (op, sigma, cov) if full else (op, sigma)

