"""Propagation to a DTM and its contours: bilinear interpolation coefficients,
:func:`dtm_bilinear` and :func:`contour_tolerance`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.accuracy.propagate.lines import _scalar

__all__ = ["bilinear_coefficients", "DTMResult", "dtm_bilinear", "contour_tolerance"]


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

