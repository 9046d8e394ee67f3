"""Error propagation from adjusted points to derived quantities (Filin & Doytsher 1998).

Anything computed from adjusted points - a distance, a road's length, an average
height, a profile, a DTM height, a contour - gets the covariance
``Sigma_f = F Sigma F'`` with ``F`` the Jacobian of the derived function and ``Sigma``
the FULL covariance of the points involved (``DESIGN.md`` section 6). Neighbouring
points of a photogrammetric adjustment are typically 90-97 % correlated, and ignoring
the covariances BETWEEN points roughly halves or doubles the answer; every function
here therefore also reports the "without covariances" value, computed with the
per-point blocks only (the block-diagonal part of ``Sigma``: each point keeps its own
3x3 (or 2x2) covariance, the cross-covariances between points are set to zero).

Also here: the G-band of a line segment (Shi & Liu 2000) and the equal-error grid of a
stereo pair (sigma of a forward-intersected ground point, including the exterior
orientation's uncertainty).

Heart module: numpy and scipy only; everything is vectorised over points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np
from scipy.spatial import ConvexHull
from scipy.special import gammaincinv  # chi2.ppf(q, k) = 2 gammaincinv(k/2, q)

from vectoradjust.sensor.collinearity import partials

__all__ = [
    "PropagationResult",
    "propagate",
    "block_diagonal",
    "DistanceResult",
    "distance",
    "polyline_length",
    "mean_height",
    "ProfileResult",
    "height_profile",
    "bilinear_coefficients",
    "DTMResult",
    "dtm_bilinear",
    "contour_tolerance",
    "confidence_scale",
    "g_band",
    "g_band_polyline",
    "GridSigma",
    "point_sigma_grid",
]

ArrayLike = Union[float, np.ndarray, list, tuple]


# ------------------------------------------------------------------------------ general
def block_diagonal(cov, block_size: int) -> np.ndarray:
    """The covariance "without covariances between points".

    Parameters
    ----------
    cov : array_like, shape (n, n)
        Full covariance of ``n / block_size`` points, point-major
        (``x1, y1, z1, x2, ...``).
    block_size : int
        Coordinates per point (3 for XYZ, 2 for XY, 1 keeps only the diagonal).

    Returns
    -------
    numpy.ndarray, shape (n, n)
        ``cov`` with every entry outside the diagonal ``block_size`` blocks set to 0.
    """
    c = np.asarray(cov, float)
    n = c.shape[0]
    if c.shape != (n, n) or n % block_size:
        raise ValueError(f"covariance of shape {c.shape} does not split into {block_size}-blocks")
    point = np.arange(n) // block_size
    return np.where(point[:, None] == point[None, :], c, 0.0)


def _full_cov(cov, n: int, d: int) -> np.ndarray:
    """``(n d, n d)`` covariance from a full matrix or ``(n, d, d)`` blocks."""
    c = np.asarray(cov, float)
    if c.shape == (n * d, n * d):
        return c
    if c.shape == (n, d, d):
        out = np.zeros((n, d, n, d))
        idx = np.arange(n)
        out[idx, :, idx, :] = c
        return out.reshape(n * d, n * d)
    raise ValueError(
        f"covariance of shape {c.shape} does not fit {n} points of dimension {d}: give "
        f"({n * d}, {n * d}) or ({n}, {d}, {d})"
    )


@dataclass
class PropagationResult:
    """Result of :func:`propagate`.

    Attributes
    ----------
    value : float or numpy.ndarray, shape (m,)
        ``func(x)``.
    covariance : numpy.ndarray, shape (m, m)
        ``F Sigma F'`` with the full covariance.
    sigma : float or numpy.ndarray, shape (m,)
        Square roots of its diagonal.
    covariance_variance_only : numpy.ndarray, shape (m, m)
        ``F Sigma_b F'`` with ``Sigma_b`` the block-diagonal part (per point).
    sigma_variance_only : float or numpy.ndarray, shape (m,)
        Square roots of its diagonal ("without covariances between points").
    jacobian : numpy.ndarray, shape (m, n)
    """

    value: float | np.ndarray
    covariance: np.ndarray
    sigma: float | np.ndarray
    covariance_variance_only: np.ndarray
    sigma_variance_only: float | np.ndarray
    jacobian: np.ndarray


def _fd_steps(x: np.ndarray, cov: np.ndarray, step) -> np.ndarray:
    if step is not None:
        h = np.broadcast_to(np.asarray(step, float), x.shape).astype(float)
    else:
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        scale = np.maximum(np.abs(x), 1.0)
        # a thousandth of the standard deviation: the scale on which the linearisation
        # is used; never below the round-off floor of x itself
        h = np.where(sig > 0, 1e-3 * sig, np.cbrt(np.finfo(float).eps) * scale)
        h = np.maximum(h, 1e4 * np.finfo(float).eps * scale)
    return (x + h) - x  # exactly representable steps


def propagate(
    func: Callable[[np.ndarray], ArrayLike],
    x,
    cov,
    jacobian: Callable[[np.ndarray], np.ndarray] | np.ndarray | None = None,
    step=None,
    block_size: int = 3,
) -> PropagationResult:
    """General first-order propagation ``Sigma_f = F Sigma F'``.

    Parameters
    ----------
    func : callable
        ``func(x) -> scalar or (m,)``.
    x : array_like, shape (n,)
        Parameter vector, e.g. the flattened XYZ of several points (point-major).
    cov : array_like, shape (n, n)
        FULL covariance of ``x``.
    jacobian : callable or array_like, optional
        Analytic Jacobian ``(m, n)`` (or a callable returning it). Default: central
        finite differences.
    step : float or array_like, optional
        Finite-difference step(s). Default: ``1e-3`` standard deviation of each
        parameter (scale-aware: the linearisation is only used within a few sigma),
        at least ``1e4 eps max(|x|, 1)``; parameters with zero variance use
        ``eps^(1/3) max(|x|, 1)``.
    block_size : int
        Coordinates per point for :attr:`PropagationResult.sigma_variance_only` (the
        block-diagonal part of ``cov``: covariances between points ignored). 3 for
        XYZ, 2 for XY, 1 for "variances only".

    Returns
    -------
    PropagationResult
    """
    x = np.asarray(x, float).ravel()
    n = x.size
    cov = np.asarray(cov, float)
    if cov.shape != (n, n):
        raise ValueError(f"covariance must be ({n}, {n}); got {cov.shape}")
    f0 = np.asarray(func(x), float)
    scalar = f0.ndim == 0
    f0v = f0.ravel()
    if jacobian is None:
        h = _fd_steps(x, cov, step)
        jac = np.empty((f0v.size, n))
        for i in range(n):  # black-box function: one column per parameter
            xp = x.copy()
            xm = x.copy()
            xp[i] += h[i]
            xm[i] -= h[i]
            jac[:, i] = (np.asarray(func(xp), float).ravel()
                         - np.asarray(func(xm), float).ravel()) / (2 * h[i])
    else:
        jac = jacobian(x) if callable(jacobian) else jacobian
        jac = np.asarray(jac, float).reshape(f0v.size, n)
    c_full = jac @ cov @ jac.T
    c_blk = jac @ block_diagonal(cov, block_size) @ jac.T
    s_full = np.sqrt(np.clip(np.diag(c_full), 0.0, None))
    s_blk = np.sqrt(np.clip(np.diag(c_blk), 0.0, None))
    if scalar:
        return PropagationResult(float(f0), c_full, float(s_full[0]), c_blk, float(s_blk[0]), jac)
    return PropagationResult(f0v.reshape(f0.shape), c_full, s_full, c_blk, s_blk, jac)


# --------------------------------------------------------------------- lines and heights
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


# -------------------------------------------------------------------------- DTM, contours
def bilinear_coefficients(corner_heights, cell_size) -> np.ndarray:
    """Coefficients ``a, b, c, d`` of ``h = a + b u + c v + d u v`` in one grid cell.

    Parameters
    ----------
    corner_heights : array_like, shape (..., 4)
        ``h00, h10, h01, h11``: heights at ``(X0, Y0)``, ``(X0 + dx, Y0)``,
        ``(X0, Y0 + dy)``, ``(X0 + dx, Y0 + dy)``.
    cell_size : float or (float, float)
        ``dx`` (and ``dy``).

    Returns
    -------
    numpy.ndarray, shape (..., 4)
    """
    h = np.asarray(corner_heights, float)
    dx, dy = np.broadcast_to(np.asarray(cell_size, float), (2,))
    h00, h10, h01, h11 = h[..., 0], h[..., 1], h[..., 2], h[..., 3]
    return np.stack([h00, (h10 - h00) / dx, (h01 - h00) / dy,
                     (h11 - h10 - h01 + h00) / (dx * dy)], axis=-1)


@dataclass
class DTMResult:
    """Bilinear DTM height with its uncertainty (:func:`dtm_bilinear`).

    Attributes
    ----------
    h : float or numpy.ndarray
        Interpolated height(s).
    sigma : float or numpy.ndarray
        Standard deviation (corner heights, cell origin and query point errors).
    sigma_heights_only : float or numpy.ndarray
        From the corner heights only.
    covariance : numpy.ndarray, shape (k, k)
        Covariance between the ``k`` interpolated heights (they share the corners).
    coefficients : numpy.ndarray, shape (4,)
        ``a, b, c, d``.
    jacobian : numpy.ndarray, shape (k, 6)
        ``d h / d(h00, h10, h01, h11, X0, Y0)``.
    """

    h: float | np.ndarray
    sigma: float | np.ndarray
    sigma_heights_only: float | np.ndarray
    covariance: np.ndarray
    coefficients: np.ndarray
    jacobian: np.ndarray


def _corner_xy_covariance(weights, bcd, cell, cov_corners_xy) -> np.ndarray:
    """Height covariance from independent planimetric errors of the four corners."""
    b, c, d = bcd
    dx, dy = cell
    cu = np.array([0.0, dx, 0.0, dx])  # corner offsets h00, h10, h01, h11
    cv = np.array([0.0, 0.0, dy, dy])
    g = np.column_stack([b + d * cv, c + d * cu])  # gradient at each corner
    cc = np.broadcast_to(np.asarray(cov_corners_xy, float), (4, 2, 2))
    var_corner = np.einsum("ki,kij,kj->k", g, cc, g)  # (4,) height variance per corner
    return (weights * var_corner) @ weights.T


def dtm_bilinear(
    corner_heights,
    cov_heights,
    origin,
    cell_size,
    point,
    cov_origin=None,
    cov_point=None,
    cov_corners_xy=None,
) -> DTMResult:
    """Height in a DTM cell by bilinear interpolation, with propagated sigma.

    ``h = a + b (X - X0) + c (Y - Y0) + d (X - X0)(Y - Y0)`` (Filin & Doytsher 1998),
    with ``a, b, c, d`` from the four corner heights (:func:`bilinear_coefficients`).

    Parameters
    ----------
    corner_heights : array_like, shape (4,)
        ``h00, h10, h01, h11`` (see :func:`bilinear_coefficients`).
    cov_heights : array_like, shape (4, 4)
        Their full covariance.
    origin : (float, float)
        Cell origin ``X0, Y0`` (the ``h00`` corner).
    cell_size : float or (float, float)
    point : array_like, shape (2,) or (k, 2)
        Query point(s) ``X, Y``.
    cov_origin : array_like, shape (2, 2), optional
        Covariance of the cell origin (moves the whole cell; shared by all points).
    cov_point : array_like, shape (2, 2) or (k, 2, 2), optional
        Planimetric covariance of each query point (independent between points).
    cov_corners_xy : array_like, shape (2, 2) or (4, 2, 2), optional
        Planimetric covariance of each corner, independent between the corners: a
        corner measured ``e`` off its nominal position carries the height of the
        terrain there, ``g_i' e`` off (``g_i`` the cell's gradient at the corner), and
        that error enters ``h`` with the corner's weight ``w_i``. On a plane of slope
        ``tan a`` with ``sigma_xy`` at the corners and at the point, a cell centre gets
        ``(1 + 1/4) tan^2 a sigma_xy^2`` from the planimetric errors (0.0031 sigma^2
        at 5 %, 0.078 at 25 %: Filin & Doytsher's slope examples, printed as 0.003
        and 0.08).

    Returns
    -------
    DTMResult
        ``d h / d X0 = -(b + d (Y - Y0))``, ``d h / d Y0 = -(c + d (X - X0))``.
    """
    hc = np.asarray(corner_heights, float).reshape(4)
    ch = np.asarray(cov_heights, float).reshape(4, 4)
    x0, y0 = (float(v) for v in origin)
    dx, dy = np.broadcast_to(np.asarray(cell_size, float), (2,))
    pts = np.asarray(point, float)
    single = pts.ndim == 1
    pts = pts.reshape(-1, 2)
    a, b, c, d = bilinear_coefficients(hc, (dx, dy))
    u = pts[:, 0] - x0
    v = pts[:, 1] - y0
    h = a + b * u + c * v + d * u * v
    su, sv = u / dx, v / dy
    jac = np.column_stack([(1 - su) * (1 - sv), su * (1 - sv), (1 - su) * sv, su * sv,
                           -(b + d * v), -(c + d * u)])
    sig = np.zeros((6, 6))
    sig[:4, :4] = ch
    if cov_origin is not None:
        sig[4:, 4:] = np.asarray(cov_origin, float).reshape(2, 2)
    cov = jac @ sig @ jac.T
    cov_h = jac[:, :4] @ ch @ jac[:, :4].T
    if cov_point is not None:
        cp = np.broadcast_to(np.asarray(cov_point, float), (len(pts), 2, 2))
        grad = -jac[:, 4:]  # d h / d(X, Y)
        cov = cov + np.diag(np.einsum("ki,kij,kj->k", grad, cp, grad))
    if cov_corners_xy is not None:
        cov = cov + _corner_xy_covariance(jac[:, :4], (b, c, d), (dx, dy), cov_corners_xy)
    s = np.sqrt(np.clip(np.diag(cov), 0, None))
    sh = np.sqrt(np.clip(np.diag(cov_h), 0, None))
    if single:
        return DTMResult(float(h[0]), float(s[0]), float(sh[0]), cov,
                         np.array([a, b, c, d]), jac)
    return DTMResult(h, s, sh, cov, np.array([a, b, c, d]), jac)


def contour_tolerance(b, c, d, x, y, x0, y0, dh, min_slope: float = 1e-12):
    """Horizontal tolerance of a contour line from a height tolerance.

    ``dx = dh / (b + d (y - y0))``, ``dy = dh / (c + d (x - x0))``: the horizontal
    shift along X (resp. Y) that changes the bilinear height by ``dh``.

    Parameters
    ----------
    b, c, d : float or array_like
        Bilinear coefficients of the cell (:func:`bilinear_coefficients`).
    x, y : float or array_like
        Position(s) on the contour.
    x0, y0 : float or array_like
        Cell origin.
    dh : float or array_like
        Height tolerance (e.g. the propagated height sigma, or a fraction of the
        contour interval).
    min_slope : float
        Slopes with ``|b + d (y - y0)| <= min_slope`` (resp. ``c + d (x - x0)``)
        count as flat.

    Returns
    -------
    dx, dy : numpy.ndarray or float
        Tolerances as magnitudes (``>= 0``), broadcast over the inputs. Where the
        surface is flat in that direction the tolerance is infinite (``inf``): no
        horizontal shift changes the height.
    """
    b, c, d, x, y, x0, y0, dh = (np.asarray(t, float) for t in (b, c, d, x, y, x0, y0, dh))
    sx = b + d * (y - y0)
    sy = c + d * (x - x0)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(np.abs(sx) > min_slope, np.abs(dh) / np.abs(sx), np.inf)
        ty = np.where(np.abs(sy) > min_slope, np.abs(dh) / np.abs(sy), np.inf)
    return _scalar(tx), _scalar(ty)


# ----------------------------------------------------------------------------- G-band
def confidence_scale(confidence: float, dof: int = 2) -> float:
    """``sqrt(chi2_dof(confidence))``: the error-ellipse scale for a confidence level.

    For ``dof = 2``, ``confidence = 0.9``: 2.1460.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError("confidence must be between 0 and 1")
    return float(np.sqrt(2.0 * gammaincinv(0.5 * dof, confidence)))


def _psd_sqrt(c: np.ndarray) -> np.ndarray:
    """``S`` with ``S S' = C`` for a stack of PSD 2x2 matrices (eigen-decomposition)."""
    w, v = np.linalg.eigh(0.5 * (c + np.swapaxes(c, -1, -2)))
    return v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def _circumscribed(s: np.ndarray, n_theta: int) -> np.ndarray:
    """Vertices of polygons circumscribing the ellipses ``{S z : |z| = 1}``.

    The unit circle is touched at ``n_theta`` uniform angles and at the four points
    whose images are the ellipse's extreme points along the local axes (normal and
    parallel to the segment); consecutive tangent lines meet at the vertices. The
    affine image contains the ellipse, and its extent along both axes is exact.
    Returns ``(m, n_theta + 4, 2)`` offsets from the centres.
    """
    m = s.shape[0]
    psi = np.broadcast_to(np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False), (m, n_theta))
    dirs = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]])
    st_m = np.einsum("tji,dj->tdi", s, dirs)  # S' m: circle point of the support in m
    psi_sup = np.arctan2(st_m[..., 1], st_m[..., 0]) % (2 * np.pi)
    psi = np.sort(np.concatenate([psi, psi_sup], axis=1), axis=1)
    nxt = np.concatenate([psi[:, 1:], psi[:, :1] + 2 * np.pi], axis=1)
    half = 0.5 * (nxt - psi)
    mid = psi + half
    radius = 1.0 / np.cos(half)
    z = np.stack([radius * np.cos(mid), radius * np.sin(mid)], axis=-1)
    return np.einsum("tij,tpj->tpi", s, z)


def _hull_ring(pts: np.ndarray) -> np.ndarray:
    try:
        hull = ConvexHull(pts)
    except Exception:  # degenerate (flat) point set: joggle
        hull = ConvexHull(pts, qhull_options="QJ")
    return pts[hull.vertices]  # counter-clockwise


def _chords(ring: np.ndarray, u: np.ndarray):
    """Lowest and highest ``w`` of a convex polygon on the vertical lines ``u``."""
    p0 = ring
    p1 = np.roll(ring, -1, axis=0)
    u0, u1 = p0[:, 0][:, None], p1[:, 0][:, None]
    w0, w1 = p0[:, 1][:, None], p1[:, 1][:, None]
    du = u1 - u0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(du != 0, (u[None, :] - u0) / du, np.nan)
    inside = (t >= 0) & (t <= 1)
    w = w0 + t * (w1 - w0)
    # vertical edges and vertices exactly on the line
    on_vert = (du == 0) & (u0 == u[None, :])
    hi = np.max(np.where(inside, w, -np.inf), axis=0)
    lo = np.min(np.where(inside, w, np.inf), axis=0)
    hi = np.maximum(hi, np.max(np.where(on_vert, np.maximum(w0, w1), -np.inf), axis=0))
    lo = np.minimum(lo, np.min(np.where(on_vert, np.minimum(w0, w1), np.inf), axis=0))
    return lo, hi


def g_band(
    p1,
    p2,
    cov_joint,
    confidence: float = 0.9,
    n_samples: int = 33,
    *,
    n_theta: int = 64,
    pieces: bool = False,
):
    """G-band (Shi & Liu 2000): confidence region of a line segment.

    For ``t`` in ``[0, 1]`` the point ``P(t) = (1 - t) P1 + t P2`` has covariance
    ``C(t) = F(t) C_joint F(t)'`` with ``F(t) = [(1 - t) I, t I]``; the band is the
    union (envelope) of the error ellipses of ``P(t)`` scaled by
    ``k = sqrt(chi2_2(confidence))``.

    Construction: ``n_samples`` values of ``t``; each ellipse is replaced by a
    circumscribed polygon (``n_theta + 4`` tangent points, four of them the ellipse's
    extreme points normal and parallel to the segment, so the extents along those
    directions are exact). The convex hull of every consecutive pair of ellipses is formed
    (``scipy.spatial.ConvexHull``). Because the support function of ``C(t)`` is convex
    in ``t``, every ellipse between two samples lies inside the hull of the pair, so the
    union of the hulls contains the whole band and is exact where the envelope is
    straight (it overestimates the band only by ``O(dt^2)`` where it curves). The
    single ring returned is that union, taken as the region between the lowest and
    highest hull boundary on every line normal to the segment (evaluated at all hull
    vertices). This assumes each normal line cuts the band in one interval, true in the
    usual case of ellipses small compared with the segment; for a very short segment
    with large, differently shaped end ellipses the ring may slightly fill concave
    notches (use ``pieces=True`` and a polygon union for the exact union of hulls).
    A zero-length segment is treated as lying along X.

    Parameters
    ----------
    p1, p2 : array_like, shape (d,)
        End points (only X, Y are used).
    cov_joint : array_like, shape (2d, 2d)
        Joint covariance of ``[p1, p2]`` (``p1``'s coordinates first).
    confidence : float
        Probability of the ellipses (2 degrees of freedom).
    n_samples : int
        Number of ``t`` samples (>= 2).
    n_theta : int
        Tangent points per ellipse (besides the four extreme points).
    pieces : bool
        Return the list of per-pair hull rings instead (the caller can union them,
        e.g. with shapely).

    Returns
    -------
    numpy.ndarray, shape (k, 2)
        Closed ring (first point repeated at the end), counter-clockwise, in the
        coordinates of the input. With ``pieces=True``: a list of such rings.
    """
    a = np.asarray(p1, float)
    b = np.asarray(p2, float)
    dd = a.shape[0]
    cj = np.asarray(cov_joint, float)
    if cj.shape != (2 * dd, 2 * dd) or b.shape != (dd,) or dd < 2:
        raise ValueError(f"g_band: points of dimension {dd} need a ({2 * dd}, {2 * dd}) "
                         f"joint covariance; got {cj.shape}")
    if n_samples < 2:
        raise ValueError("g_band needs n_samples >= 2")
    sel = [0, 1, dd, dd + 1]
    cxy = cj[np.ix_(sel, sel)]
    k = confidence_scale(confidence, 2)
    delta = b[:2] - a[:2]
    length = float(np.hypot(*delta))
    e_u = delta / length if length > 0 else np.array([1.0, 0.0])
    e_n = np.array([-e_u[1], e_u[0]])
    rot = np.vstack([e_u, e_n])  # world -> local
    t = np.linspace(0.0, 1.0, n_samples)
    fmat = np.zeros((n_samples, 2, 4))
    fmat[:, :, :2] = (1 - t)[:, None, None] * np.eye(2)
    fmat[:, :, 2:] = t[:, None, None] * np.eye(2)
    c_t = np.einsum("ij,tjk,lk->til", rot, np.einsum("tij,jk,tlk->til", fmat, cxy, fmat), rot)
    centres = np.column_stack([t * length, np.zeros(n_samples)])
    s = _psd_sqrt(c_t)
    ell = centres[:, None, :] + k * _circumscribed(s, n_theta)
    hulls = [_hull_ring(np.vstack([ell[j], ell[j + 1]])) for j in range(n_samples - 1)]

    def to_world(ring_local: np.ndarray) -> np.ndarray:
        w = a[:2] + ring_local @ rot
        return np.vstack([w, w[:1]])

    if pieces:
        return [to_world(h) for h in hulls]
    stations = np.unique(np.concatenate([h[:, 0] for h in hulls]))
    lo = np.full(stations.size, np.inf)
    hi = np.full(stations.size, -np.inf)
    for h in hulls:
        l_h, h_h = _chords(h, stations)
        lo = np.minimum(lo, l_h)
        hi = np.maximum(hi, h_h)
    ok = np.isfinite(lo) & np.isfinite(hi)
    st, lo, hi = stations[ok], lo[ok], hi[ok]
    tol = 1e-7 * max(float(np.max(hi - lo)), 1e-300)
    k_lo = _simplify_chain(st, lo, tol)
    k_hi = _simplify_chain(st, hi, tol)
    ring = np.vstack([np.column_stack([st[k_lo], lo[k_lo]]),
                      np.column_stack([st[k_hi][::-1], hi[k_hi][::-1]])])
    # drop the repeated points at the two ends where lo == hi
    keep = np.ones(len(ring), bool)
    keep[1:] = np.any(np.abs(np.diff(ring, axis=0)) > 0, axis=1)
    return to_world(ring[keep])


def _simplify_chain(u: np.ndarray, w: np.ndarray, tol: float) -> np.ndarray:
    """Mask of the vertices of a chain ``w(u)`` to keep: drops near-collinear vertices.

    Vertices whose distance (along ``w``) from the chord of their neighbours is below
    ``tol`` are removed, never two neighbours in one pass; the passes repeat until
    nothing changes. The deviation of every removed vertex from the final chain stays
    within a few ``tol``.
    """
    keep = np.ones(u.size, bool)
    for sweep in range(200):
        idx = np.flatnonzero(keep)
        if idx.size < 3:
            break
        uu, ww = u[idx], w[idx]
        span = uu[2:] - uu[:-2]
        with np.errstate(invalid="ignore", divide="ignore"):
            pred = ww[:-2] + (ww[2:] - ww[:-2]) * (uu[1:-1] - uu[:-2]) / span
        cand = (span > 0) & (np.abs(ww[1:-1] - pred) < tol)
        parity = np.arange(1, idx.size - 1) % 2 == sweep % 2
        rem = cand & parity
        if not rem.any():
            if not (cand & ~parity).any():
                break
            continue
        keep[idx[1:-1][rem]] = False
    return keep


def g_band_polyline(xyz, cov_joint, confidence: float = 0.9, n_samples: int = 33, **kwargs):
    """G-bands of every segment of a polyline.

    Parameters
    ----------
    xyz : array_like, shape (n, d)
        Vertices (X, Y used).
    cov_joint : array_like, shape (n d, n d)
        Full covariance of the vertices (point-major).
    confidence, n_samples, **kwargs
        As :func:`g_band`.

    Returns
    -------
    list of numpy.ndarray
        One ring per segment (``n - 1``); their union is the band of the line.
    """
    p = np.asarray(xyz, float)
    n, d = p.shape
    c = _full_cov(cov_joint, n, d)
    out = []
    for i in range(n - 1):  # one band per segment
        idx = np.arange(i * d, (i + 2) * d)
        out.append(g_band(p[i], p[i + 1], c[np.ix_(idx, idx)], confidence, n_samples,
                          **kwargs))
    return out


# ---------------------------------------------------------------------- equal-error grid
@dataclass
class GridSigma:
    """Standard deviations of forward-intersected ground points (:func:`point_sigma_grid`).

    Attributes
    ----------
    sigma_x, sigma_y, sigma_z : numpy.ndarray
        Shape of the grid.
    cov : numpy.ndarray
        Grid shape + ``(3, 3)``.
    cov_images_only : numpy.ndarray
        The part due to the image coordinates alone (EO taken as error-free).
    """

    sigma_x: np.ndarray
    sigma_y: np.ndarray
    sigma_z: np.ndarray
    cov: np.ndarray
    cov_images_only: np.ndarray


def point_sigma_grid(eo_pair, cov_eo, f: float, sigma_image_mm, X, Y, Z) -> GridSigma:
    """Equal-error grid: sigma X, Y, Z of ground points intersected from a stereo pair.

    For every grid node the ground point is projected into both images and
    intersected back by least squares from its four photo coordinates. With
    ``N_pp = A_p' W A_p`` and ``N_pe = A_p' W A_e`` (``A_p``, ``A_e`` the collinearity
    partials with respect to the point and to the 12 exterior orientation parameters,
    ``W`` the image weights) the covariance of the intersected point is
    ``C = N_pp^-1 + N_pp^-1 N_pe C_ee N_ep N_pp^-1``.

    Parameters
    ----------
    eo_pair : array_like, shape (2, 6)
        ``XL, YL, ZL, omega, phi, kappa`` (m, rad) of the two images.
    cov_eo : array_like, shape (12, 12) or None
        Covariance of the 12 EO parameters (both images, same order; may contain the
        correlation between the images, e.g. from a bundle adjustment).
    f : float
        Focal length (mm).
    sigma_image_mm : float or array_like, shape (4,)
        Photo coordinate sigma(s) (xL, yL, xR, yR).
    X, Y, Z : array_like
        Grid node coordinates, broadcast to a common shape.

    Returns
    -------
    GridSigma
    """
    eo = np.asarray(eo_pair, float).reshape(2, 6)
    cee = np.zeros((12, 12)) if cov_eo is None else np.asarray(cov_eo, float).reshape(12, 12)
    X, Y, Z = np.broadcast_arrays(np.asarray(X, float), np.asarray(Y, float),
                                  np.asarray(Z, float))
    shape = X.shape
    pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    k = pts.shape[0]
    sig = np.broadcast_to(np.asarray(sigma_image_mm, float), (4,))
    w = 1.0 / sig**2
    ae0, ap0 = partials(np.broadcast_to(eo[0], (k, 6)), pts, f)
    ae1, ap1 = partials(np.broadcast_to(eo[1], (k, 6)), pts, f)
    ap = np.concatenate([ap0, ap1], axis=1)  # (k, 4, 3)
    ae = np.zeros((k, 4, 12))
    ae[:, :2, :6] = ae0
    ae[:, 2:, 6:] = ae1
    wap = w[None, :, None] * ap
    npp_inv = np.linalg.inv(np.einsum("kij,kil->kjl", ap, wap))
    npe = np.einsum("kij,kil->kjl", wap, ae)  # (k, 3, 12)
    g = npp_inv @ npe
    cov = npp_inv + np.einsum("kij,jl,kml->kim", g, cee, g)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0, None))
    return GridSigma(
        sigma_x=sd[:, 0].reshape(shape),
        sigma_y=sd[:, 1].reshape(shape),
        sigma_z=sd[:, 2].reshape(shape),
        cov=cov.reshape(shape + (3, 3)),
        cov_images_only=npp_inv.reshape(shape + (3, 3)),
    )
