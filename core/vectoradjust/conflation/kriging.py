"""Simple kriging from the ``k`` nearest measured points (:func:`krige`) and its
leave-one-out cross-validation (:func:`cross_validate`), also at the distance bands' distances
(:func:`band_factors`, the variance calibration by distance).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from vectoradjust.conflation.covariance import CovarianceModel, _neighbours, _system
from vectoradjust.errors import CancelledError

__all__ = ["krige", "cross_validate", "band_factors"]


def _solve_chunk(models: list, xy_m, dist, idx, tgt=None) -> list:
    """Simple kriging of one chunk for each ``(cov, resid, noise[, carry[, u]])`` of
    ``models`` (same measured points and neighbours): prediction (b, c), signal error
    variance (b,) and the kriging weights' sums of ``carry`` (b, f) (None without
    ``carry``). ``u`` (m, r): the measured points' shared noise (:func:`_system`);
    ``tgt`` (b,): the targets' own indices when they are measured points (leave-one-out),
    whose noise is shared with their neighbours (the variance is then relative to
    the held-out point's own noise, which the caller adds)."""
    out = []
    dd = None
    for cov, resid, noise, *rest in models:
        carry = rest[0] if rest else None
        u = rest[1] if len(rest) > 1 else None
        nc = 0 if carry is None else carry.shape[1]
        if cov.sill <= 0 or cov.length <= 0:  # no correlated signal: the trend alone
            out.append((np.zeros((len(idx), resid.shape[1])), np.zeros(len(idx)),
                        None if carry is None else np.zeros((len(idx), nc))))
            continue
        if dd is None:  # the neighbours' distances, once for all models
            px, py = xy_m[idx, 0], xy_m[idx, 1]  # (b, k)
            dd = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
        u_t = None if u is None or tgt is None else u[tgt]
        a, c = _system(cov, dd, dist, noise[idx], None if u is None else u[idx], u_t)
        w = np.linalg.solve(a, c[:, :, None])[:, :, 0]
        sig = cov.sill - np.einsum("bk,bk->b", w, c)
        out.append((np.einsum("bk,bkc->bc", w, resid[idx]),
                    np.maximum(sig, 0.0) if u_t is None else sig,
                    None if carry is None else np.einsum("bk,bkf->bf", w, carry[idx])))
    return out


def krige(cov: CovarianceModel, xy_m: np.ndarray, resid: np.ndarray, noise: np.ndarray,
          xy_p: np.ndarray, k: int, *, skip_self: bool = False, chunk: int = 20000,
          progress: Optional[Callable[[float], None]] = None,
          is_cancelled: Optional[Callable[[], bool]] = None):
    """Predict the residual field at ``xy_p`` from the ``k`` nearest measured points.

    Parameters
    ----------
    cov : CovarianceModel
    xy_m : numpy.ndarray, shape (m, 2)
        Measured points.
    resid : numpy.ndarray, shape (m, c)
        Their residuals (displacement less trend).
    noise : numpy.ndarray, shape (m,)
        Their known noise variance per component.
    xy_p : numpy.ndarray, shape (n, 2)
        Where to predict.
    k : int
        Neighbours (at most ``m``, or ``m - 1`` with ``skip_self``).
    skip_self : bool
        ``xy_p`` are the measured points themselves, each left out of its own
        prediction (leave-one-out).
    chunk : int
        Targets per batched solve (memory ``chunk * k^2`` floats).
    progress, is_cancelled : callable, optional
        ``progress(fraction)`` after each chunk; ``is_cancelled()`` true raises
        :class:`~vectoradjust.errors.CancelledError`.

    Returns
    -------
    pred : numpy.ndarray, shape (n, c)
    var : numpy.ndarray, shape (n,)
        Variance of the signal's prediction error ``C(0) - c' (C + N)^-1 c``.
    nearest : numpy.ndarray, shape (n,)
        Distance to the nearest measured point used.
    """
    (res,), nearest = _krige_many([(cov, resid, noise, None)], xy_m, xy_p, k, skip_self,
                                  chunk, progress, is_cancelled)
    return res[0], res[1], nearest


def _krige_many(models: list, xy_m, xy_p, k: int, skip_self: bool = False,
                chunk: int = 20000, progress=None, is_cancelled=None):
    """:func:`krige` for several ``(cov, resid, noise[, carry])`` on the same measured
    points: one KD-tree query and one distance matrix per chunk. ``carry`` (m, f), per
    measured point, is summed with the kriging weights (the trend's design, whose error
    the prediction carries only by ``G(x) - sum w_i G(x_i)``, :func:`_trend_cov`).
    Returns ``[(pred, var, wsum)], nearest`` (``wsum`` None without ``carry``)."""
    from scipy.spatial import cKDTree

    n = len(xy_p)
    k = int(min(k, len(xy_m) - (1 if skip_self else 0)))
    out = [(np.zeros((n, m[1].shape[1])), np.full(n, float(m[0].sill)),
            None if len(m) < 4 or m[3] is None else np.zeros((n, m[3].shape[1])))
           for m in models]
    nearest = np.full(n, np.inf)
    if n == 0 or k < 1:
        return out, nearest
    tree = cKDTree(xy_m)
    for s in range(0, n, chunk):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("The conflation was cancelled", "Run it again when ready")
        e = min(s + chunk, n)
        dist, idx = _neighbours(tree, xy_p[s:e], k, skip_self)
        tgt = np.arange(s, e) if skip_self else None
        for (pred, var, ws), (p, v, w) in zip(out, _solve_chunk(models, xy_m, dist, idx, tgt)):
            pred[s:e], var[s:e] = p, v
            if ws is not None:
                ws[s:e] = w
        nearest[s:e] = dist[:, 0]
        if progress is not None:
            progress(e / n)
    return out, nearest


def cross_validate(cov: CovarianceModel, xy_m: np.ndarray, resid: np.ndarray,
                   noise: np.ndarray, k: int, factor: float) -> dict:
    """Leave-one-out cross-validation of the field at the measured points.

    Each measured point is predicted from its ``k`` nearest other measured points and
    compared with its own (noisy) residual; the error's predicted variance is the
    kriging variance plus the database noise plus the point's own noise.

    Parameters
    ----------
    factor : float
        Radius (LE90 or CE90 factor) of the predicted sigma the share is counted in:
        :data:`CE90_CIRCULAR` for two components, :data:`LE90` for one.

    Returns
    -------
    dict
        ``count``, ``rmse`` (over the components, per point the root of the sum of
        squares), ``rmse_trend_only`` (the same without the signal),
        ``share_within_90`` and the mean predicted sigma.
    """
    m = len(xy_m)
    if m < 3:
        return {"count": int(m), "rmse": None, "rmse_trend_only": None,
                "share_within_90": None, "mean_sigma": None}
    pred, var, _ = krige(cov, xy_m, resid, noise, xy_m, k, skip_self=True)
    return _cv_stats(cov, resid, noise, pred, var, factor)


def _cv_stats(cov: CovarianceModel, resid, noise, pred, var, factor: float) -> dict:
    """The leave-one-out figures from the held-out predictions."""
    m = len(resid)
    err = resid - pred
    sig = np.sqrt(var + cov.nugget + noise)
    size = np.sqrt((err ** 2).sum(axis=1))
    return {"count": int(m), "rmse": float(np.sqrt(np.mean(size ** 2))),
            "rmse_trend_only": float(np.sqrt(np.mean((resid ** 2).sum(axis=1)))),
            "share_within_90": float(np.mean(size <= factor * sig)),
            "mean_sigma": float(np.mean(sig))}


def band_factors(cov: CovarianceModel, xy_m: np.ndarray, resid: np.ndarray,
                 noise: np.ndarray, k: int, edges=(0.0, 50.0, 100.0, 200.0, np.inf),
                 max_targets: int = 1000, min_count: int = 30, seed: int = 0) -> np.ndarray:
    """Calibration of the horizontal prediction variance per distance band, from
    leave-one-out errors at the band's distance (docs/method.md section 10).

    The plug-in kriging variance treats the fitted covariance as known; its CE90
    factor (:func:`ce90_factor`) adds the sill's and the noise's estimation error, not
    a covariance function of the wrong shape (a Gaussian of 150 m for a field of
    300-1500 m waves). So the errors are measured where the vertices are: each measured
    point (at most ``max_targets``, seeded) is predicted from its ``k`` nearest other
    points at least the band's lower edge away ("h-block" cross-validation: a point 150
    m from the nearest measured one is predicted from points >= 100 m away), and the
    band's factor is the mean standardised square error ``z^2 = |e|^2 / (c kappa^2
    s2)`` (``s2`` the plug-in variance with the database and the point's own noise,
    ``kappa`` its CE90 factor, ``c`` components), at least 1: the variances are only
    widened. A band with fewer than ``min_count`` such predictions takes the factor of
    the band before it (1 for the first).

    Returns
    -------
    numpy.ndarray, shape (len(edges) - 1,)
        The factor of each band ``[edges[j], edges[j + 1])`` of the nearest measured
        distance.
    """
    from scipy.spatial import cKDTree

    from vectoradjust.conflation.ce90 import ce90_factor

    m = len(xy_m)
    out = np.ones(len(edges) - 1)
    if cov is None or cov.sill <= 0 or cov.length <= 0 or m < k + 2:
        return out
    tgt = np.arange(m)
    if m > max_targets:
        tgt = np.sort(np.random.default_rng(seed).choice(m, max_targets, replace=False))
    tree = cKDTree(xy_m)
    for j, lo in enumerate(edges[:-1]):
        z2 = _band_z2(cov, tree, xy_m, resid, noise, tgt, k, float(lo), ce90_factor)
        prev = out[j - 1] if j else 1.0
        out[j] = max(float(np.mean(z2)), 1.0) if len(z2) >= min_count else prev
    return out


def _band_z2(cov, tree, xy_m, resid, noise, tgt, k: int, lo: float, ce90_factor):
    """``z^2`` of :func:`band_factors` of the targets that have ``k`` measured points
    at least ``lo`` away (and not themselves)."""
    m = len(xy_m)
    near = (tree.query_ball_point(xy_m[tgt], lo, return_length=True) if lo > 0
            else np.ones(len(tgt), int))
    kk = int(min(m, k + int(np.max(near)) + 1))
    dist, idx = _neighbours(tree, xy_m[tgt], kk, False)
    ok = (dist >= lo) & (idx != tgt[:, None]) & (dist > 0 if lo > 0 else True)
    have = ok.sum(axis=1) >= k
    if not have.any():
        return np.zeros(0)
    ok, dist, idx, t = ok[have], dist[have], idx[have], tgt[have]
    order = np.argsort(~ok, axis=1, kind="stable")[:, :k]  # the first k valid, nearest first
    dist, idx = np.take_along_axis(dist, order, 1), np.take_along_axis(idx, order, 1)
    px, py = xy_m[idx, 0], xy_m[idx, 1]
    dd = np.hypot(px[:, :, None] - px[:, None, :], py[:, :, None] - py[:, None, :])
    a, c = _system(cov, dd, dist, noise[idx])
    w = np.linalg.solve(a, c[:, :, None])[:, :, 0]
    e = resid[t] - np.einsum("bk,bkc->bc", w, resid[idx])
    s2 = np.maximum(cov.sill - (w * c).sum(axis=1), 0.0) + cov.nugget + noise[t]
    kap = ce90_factor(cov, cov.sill * (1.0 - w.sum(axis=1)) ** 2, np.full(len(t), cov.nugget),
                      s2)
    return (e ** 2).sum(axis=1) / (resid.shape[1] * kap ** 2 * s2)
