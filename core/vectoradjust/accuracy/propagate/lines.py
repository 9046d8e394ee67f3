"""Propagation to lines and heights: distances, polyline lengths, mean heights and height
profiles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.accuracy.propagate.general import _full_cov, block_diagonal

__all__ = [
    "DistanceResult", "distance", "polyline_length", "mean_height", "ProfileResult",
    "height_profile",
]


@dataclass
class DistanceResult:
    """A derived scalar with its sigma with and without the covariances between points.

    Attributes
    ----------
    value : float or numpy.ndarray
    sigma : float or numpy.ndarray
        With the full covariance.
    sigma_no_cov : float or numpy.ndarray
        With the per-point blocks only (covariances between points ignored).
    jacobian : numpy.ndarray
        ``d value / d coordinates`` (point-major), for further propagation.
    """

    value: float | np.ndarray
    sigma: float | np.ndarray
    sigma_no_cov: float | np.ndarray
    jacobian: np.ndarray


def _scalar(a):
    a = np.asarray(a)
    return float(a) if a.ndim == 0 else a


def distance(p1, p2, cov, dims: int = 2) -> DistanceResult:
    """Distance between two points and its standard deviation.

    ``F = [dx/D, dy/D, -dx/D, -dy/D]`` (2D, plus the ``dz/D`` terms in 3D).

    Parameters
    ----------
    p1, p2 : array_like, shape (..., d)
        The points (``d >= dims``; e.g. XYZ points for a horizontal distance).
    cov : array_like, shape (..., 2d, 2d)
        Joint covariance of ``[p1, p2]`` (``p1``'s coordinates first).
    dims : {2, 3}
        Horizontal (2) or spatial (3) distance.

    Returns
    -------
    DistanceResult
        ``sigma_no_cov`` ignores the cross-covariance between ``p1`` and ``p2``.
        ``jacobian`` has shape ``(..., 2d)``. Coincident points give ``nan`` sigmas
        (the distance is not differentiable there).
    """
    a = np.asarray(p1, float)
    b = np.asarray(p2, float)
    d = a.shape[-1]
    if dims not in (2, 3) or d < dims or b.shape[-1] != d:
        raise ValueError(f"dims={dims} needs points with at least {dims} coordinates")
    c = np.asarray(cov, float)
    if c.shape[-2:] != (2 * d, 2 * d):
        raise ValueError(f"covariance must end in ({2 * d}, {2 * d}); got {c.shape}")
    diff = a[..., :dims] - b[..., :dims]
    dist = np.sqrt(np.sum(diff**2, axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = diff / dist[..., None]
    jac = np.zeros(np.broadcast_shapes(u.shape[:-1], c.shape[:-2]) + (2 * d,))
    jac[..., :dims] = u
    jac[..., d:d + dims] = -u
    var = np.einsum("...i,...ij,...j->...", jac, c, jac)
    var_nc = (np.einsum("...i,...ij,...j->...", jac[..., :d], c[..., :d, :d], jac[..., :d])
              + np.einsum("...i,...ij,...j->...", jac[..., d:], c[..., d:, d:], jac[..., d:]))
    return DistanceResult(
        _scalar(dist),
        _scalar(np.sqrt(np.clip(var, 0, None))),
        _scalar(np.sqrt(np.clip(var_nc, 0, None))),
        jac,
    )


def _segment_units(xyz: np.ndarray, dims: int):
    seg = np.diff(xyz[:, :dims], axis=0)
    length = np.sqrt(np.sum(seg**2, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, seg / length[:, None], 0.0)
    return length, u


def polyline_length(xyz, cov, dims: int = 2) -> DistanceResult:
    """Length of a polyline and its standard deviation (chain rule over all vertices).

    ``L = sum_i |p_{i+1} - p_i|``; ``dL/dp_i = u_{i-1} - u_i`` with ``u_i`` the unit
    vector of segment ``i``. A zero-length segment contributes a zero gradient (its
    length is not differentiable there).

    Parameters
    ----------
    xyz : array_like, shape (n, d)
        Vertices (``d`` = 2 or 3).
    cov : array_like, shape (n d, n d) or (n, d, d)
        Full covariance of the vertices (point-major) or per-vertex blocks.
    dims : {2, 3}
        Horizontal (2) or 3D (3) length.

    Returns
    -------
    DistanceResult
        ``jacobian`` has shape ``(n d,)``; ``sigma_no_cov`` uses the per-vertex blocks.
    """
    p = np.asarray(xyz, float)
    n, d = p.shape
    if dims not in (2, 3) or d < dims:
        raise ValueError(f"dims={dims} needs vertices with at least {dims} coordinates")
    c = _full_cov(cov, n, d)
    length, u = _segment_units(p, dims)
    grad = np.zeros((n, d))
    grad[:-1, :dims] -= u
    grad[1:, :dims] += u
    g = grad.ravel()
    var = g @ c @ g
    var_nc = g @ block_diagonal(c, d) @ g
    return DistanceResult(float(length.sum()), float(np.sqrt(max(var, 0.0))),
                          float(np.sqrt(max(var_nc, 0.0))), g)


def mean_height(z, cov) -> DistanceResult:
    """Average of heights and its standard deviation.

    Parameters
    ----------
    z : array_like, shape (n,)
    cov : array_like, shape (n, n)
        Their full covariance.

    Returns
    -------
    DistanceResult
        ``sigma_no_cov`` uses the variances only. Example (Filin & Doytsher): two
        heights with variance ``m^2`` and covariance ``0.9 m^2`` give ``0.95 m^2`` for
        the mean, against ``0.5 m^2`` without the covariance.
    """
    z = np.asarray(z, float).ravel()
    n = z.size
    c = np.asarray(cov, float)
    if c.shape != (n, n):
        raise ValueError(f"covariance must be ({n}, {n}); got {c.shape}")
    g = np.full(n, 1.0 / n)
    var = g @ c @ g
    var_nc = np.sum(np.diag(c)) / n**2
    return DistanceResult(float(z.mean()), float(np.sqrt(max(var, 0.0))),
                          float(np.sqrt(max(var_nc, 0.0))), g)


@dataclass
class ProfileResult:
    """Height profile along a line (:func:`height_profile`).

    Attributes
    ----------
    chainage : numpy.ndarray, shape (n,)
        Cumulative horizontal (or 3D) distance from the first vertex.
    z : numpy.ndarray, shape (n,)
    sigma_z : numpy.ndarray, shape (n,)
        Vertical standard deviation per vertex.
    sigma_chainage : numpy.ndarray, shape (n,)
        Standard deviation of the chainage (full covariance; 0 at the start).
    sigma_chainage_no_cov : numpy.ndarray, shape (n,)
        The same ignoring the covariances between vertices.
    cov_z : numpy.ndarray, shape (n, n)
        Covariance of the heights (e.g. for height differences along the profile).
    """

    chainage: np.ndarray
    z: np.ndarray
    sigma_z: np.ndarray
    sigma_chainage: np.ndarray
    sigma_chainage_no_cov: np.ndarray
    cov_z: np.ndarray


def height_profile(xyz, cov, dims: int = 2) -> ProfileResult:
    """Profile of a 3D line: chainage, heights and their standard deviations.

    Parameters
    ----------
    xyz : array_like, shape (n, 3)
    cov : array_like, shape (3n, 3n) or (n, 3, 3)
    dims : {2, 3}
        Chainage measured horizontally (2, default) or in 3D.

    Returns
    -------
    ProfileResult
    """
    p = np.asarray(xyz, float)
    n, d = p.shape
    if d != 3:
        raise ValueError("height_profile needs XYZ vertices")
    c = _full_cov(cov, n, 3)
    length, u = _segment_units(p, dims)
    chain = np.concatenate([[0.0], np.cumsum(length)])
    # d chainage_k / d p: sum over the segments before k
    g = np.zeros((n - 1, n, 3))
    idx = np.arange(n - 1)
    g[idx, idx, :dims] = -u
    g[idx, idx + 1, :dims] = u
    jac = np.concatenate([np.zeros((1, 3 * n)), np.cumsum(g.reshape(n - 1, 3 * n), axis=0)])
    var_c = np.einsum("ki,ij,kj->k", jac, c, jac)
    var_c_nc = np.einsum("ki,ij,kj->k", jac, block_diagonal(c, 3), jac)
    iz = 3 * np.arange(n) + 2
    cov_z = c[np.ix_(iz, iz)]
    return ProfileResult(
        chainage=chain,
        z=p[:, 2].copy(),
        sigma_z=np.sqrt(np.clip(np.diag(cov_z), 0, None)),
        sigma_chainage=np.sqrt(np.clip(var_c, 0, None)),
        sigma_chainage_no_cov=np.sqrt(np.clip(var_c_nc, 0, None)),
        cov_z=cov_z,
    )

