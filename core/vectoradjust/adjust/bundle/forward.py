"""Forward intersection of points with the exterior orientation held fixed
(:func:`intersect`).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)
from vectoradjust.sensor.collinearity import (
    partials,
    project,
)
from vectoradjust.sensor.models import SensorSet, observe_rpc

__all__ = ["intersect"]


def intersect(
    eo: np.ndarray,
    obs_point: np.ndarray,
    obs_image: np.ndarray,
    obs_xy: np.ndarray,
    obs_sigma: np.ndarray,
    n_points: int,
    focal_length: float,
    principal_point=(0.0, 0.0),
    *,
    eo_cov_full: Optional[np.ndarray] = None,
    variance_factor: float = 1.0,
    max_iterations: int = 20,
    tolerance: float = 1e-6,
    sensors: Optional[SensorSet] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward intersection of points from fixed (adjusted) exterior orientation.

    Used for check points, which stay out of the adjustment. The covariance includes
    the exterior orientation's uncertainty:
    ``C = s0^2 Npp^-1 + Npp^-1 N_pe C_ee N_ep Npp^-1``.

    Parameters
    ----------
    eo : numpy.ndarray, shape (n, 6)
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
    obs_xy, obs_sigma : numpy.ndarray, shape (k, 2)
    n_points : int
    focal_length : float
    principal_point : (float, float)
    eo_cov_full : numpy.ndarray, shape (6n, 6n), optional
        Full a-posteriori covariance of all exterior orientations.
    variance_factor : float
        sigma0^2 applied to the image weights' cofactors.
    max_iterations : int
    tolerance : float
        Largest coordinate correction (m) at convergence.
    sensors : SensorSet, optional
        The images' sensor models (RPC images: ``eo`` rows are their bias parameters and
        ``obs_xy`` pixels); None: frame cameras.

    Returns
    -------
    xyz : numpy.ndarray, shape (n_points, 3)
        NaN for points with fewer than two rays.
    cov : numpy.ndarray, shape (n_points, 3, 3)
    """
    pp = np.asarray(principal_point, float)
    if sensors is None or not sensors.is_rpc.any():
        xyz = ray_intersection(eo, obs_point, obs_image, obs_xy, n_points, focal_length, pp)
    else:
        xyz = approximate_points(sensors, eo, obs_point, obs_image, obs_xy, n_points,
                                 focal_length, pp)
    ok = np.isfinite(xyz).all(axis=1)
    use = ok[obs_point]
    op, oi, oxy, osg = obs_point[use], obs_image[use], obs_xy[use], obs_sigma[use]
    x = np.where(ok[:, None], xyz, 0.0)
    w = 1.0 / osg**2
    for _ in range(max_iterations):
        pred, a_eo, a_pt = _observe(eo, oi, x[op], focal_length, pp, sensors)
        ell = oxy - pred
        npp, wap = _point_normals(op, a_pt, w, ok, n_points)
        tp = _block_sum(op, np.einsum("kri,kr->ki", wap, ell), n_points)
        dx = np.einsum("mij,mj->mi", inv3x3(npp), tp)
        x += dx
        if np.abs(dx).max(initial=0.0) < tolerance:
            break
    _, a_eo, a_pt = _observe(eo, oi, x[op], focal_length, pp, sensors)
    npp_inv = inv3x3(_point_normals(op, a_pt, w, ok, n_points)[0])
    cov = variance_factor * npp_inv
    if eo_cov_full is not None:
        cov = cov + _eo_part(npp_inv, a_eo * w[:, :, None], a_pt, op, oi, eo_cov_full,
                             eo.shape[0])
    x[~ok] = np.nan
    cov[~ok] = np.nan
    return x, cov


def _point_normals(op: np.ndarray, a_pt: np.ndarray, w: np.ndarray, ok: np.ndarray,
                   n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Normal matrices ``N_pp (n_points, 3, 3)`` of the points (identity where ``~ok``) and
    the weighted point partials ``W A_p (k, 2, 3)``."""
    wap = a_pt * w[:, :, None]
    npp = _block_sum(op, np.einsum("kri,krj->kij", a_pt, wap), n_points)
    npp[~ok] = np.eye(3)
    return npp, wap


def _eo_part(npp_inv: np.ndarray, wa_eo: np.ndarray, a_pt: np.ndarray, op: np.ndarray,
             oi: np.ndarray, eo_cov_full: np.ndarray, n: int) -> np.ndarray:
    """The exterior orientation's share ``Npp^-1 N_pe C_ee N_ep Npp^-1`` of the points'
    covariance, ``(n_points, 3, 3)``; ``wa_eo`` are the weighted EO partials ``W A_e`` of
    the ``n`` images."""
    n_points = npp_inv.shape[0]
    nep = np.einsum("kri,krj->kij", wa_eo, a_pt)  # (k, 6, 3)
    z = np.zeros((n_points, 3, n, 6))
    np.add.at(z, (op, slice(None), oi), np.transpose(nep, (0, 2, 1)))
    z = np.einsum("mab,mbc->mac", npp_inv, z.reshape(n_points, 3, 6 * n))
    return np.einsum("mai,ij,mbj->mab", z, eo_cov_full, z)


def _observe(eo: np.ndarray, oi: np.ndarray, x: np.ndarray, focal_length: float,
             pp: np.ndarray, sensors: Optional[SensorSet]):
    """Computed image coordinates ``(k, 2)`` of points ``x (k, 3)`` on images ``oi`` and
    the partials ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)``, each image through its model."""
    if sensors is None or not sensors.is_rpc[oi].any():
        pred = project(eo[oi], x, focal_length, pp)
        a_eo, a_pt = partials(eo[oi], x, focal_length)
        return pred, a_eo, a_pt
    k = len(oi)
    pred, a_eo, a_pt = np.empty((k, 2)), np.empty((k, 2, 6)), np.empty((k, 2, 3))
    rpc = sensors.is_rpc[oi]
    if (~rpc).any():
        pred[~rpc] = project(eo[oi[~rpc]], x[~rpc], focal_length, pp)
        a_eo[~rpc], a_pt[~rpc] = partials(eo[oi[~rpc]], x[~rpc], focal_length)
    llh, jac = sensors.frame.to_geodetic(x[rpc])
    sel = np.flatnonzero(rpc)
    for i in np.unique(oi[sel]).tolist():
        on = oi[sel] == i
        pred[sel[on]], a_eo[sel[on]], a_pt[sel[on]] = observe_rpc(
            sensors.rpc[i], eo[i], llh[on], jac[on])
    return pred, a_eo, a_pt

