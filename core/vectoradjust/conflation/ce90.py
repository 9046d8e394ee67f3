"""The predictive distribution's CE90: the database noise's posterior mean, the sill's
degrees of freedom and the CE90 factor mixed over both (:func:`ce90_factor`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.conflation.covariance import CovarianceModel

__all__ = ["ce90_factor"]


def _variance_nodes(nu: float, n: int = 16):
    """Nodes and weights of ``X = nu / chi2_nu`` (the posterior of a variance with ``nu``
    degrees of freedom relative to its estimate): generalised Gauss-Laguerre on the
    chi-square density for ``nu < 30``, Gauss-Hermite on the Wilson-Hilferty cube for
    larger ``nu``, ``X = 1`` for ``nu`` inf."""
    if not np.isfinite(nu) or nu > 1e6:
        return np.ones(1), np.ones(1)
    if nu < 30:
        from scipy.special import roots_genlaguerre

        y, w = roots_genlaguerre(n, nu / 2.0 - 1.0)  # chi2 = 2 y, y ~ Gamma(nu / 2)
        return nu / (2.0 * y), w / w.sum()
    z, w = np.polynomial.hermite_e.hermegauss(n)
    c = 2.0 / (9.0 * nu)
    return 1.0 / np.maximum(1.0 - c + z * np.sqrt(c), 1e-3) ** 3, w / w.sum()


def _gauss_rule(x: np.ndarray, w: np.ndarray, n: int = 8):
    """An ``n``-point Gauss rule of the discrete distribution ``(x, w)`` (Stieltjes'
    procedure, Golub-Welsch): it integrates polynomials of degree ``2 n - 1`` exactly,
    with ``n`` nodes instead of all of ``x``."""
    x, w = np.asarray(x, float), np.asarray(w, float) / np.sum(w)
    n = int(min(n, len(x)))
    alpha, beta = np.zeros(n), np.zeros(n)
    p_prev, p = np.zeros_like(x), np.ones_like(x)
    norm_prev = 1.0
    for k in range(n):
        norm = float(np.sum(w * p * p))
        if norm <= 1e-300:
            n = k
            break
        alpha[k] = float(np.sum(w * x * p * p)) / norm
        beta[k] = norm / norm_prev if k else 0.0
        p_prev, p = p, (x - alpha[k]) * p - beta[k] * p_prev
        norm_prev = norm
    jac = np.diag(alpha[:n]) + np.diag(np.sqrt(beta[1:n]), 1) + np.diag(np.sqrt(beta[1:n]), -1)
    nodes, vec = np.linalg.eigh(jac)
    return nodes, vec[0] ** 2


def _ce90_table(cov: CovarianceModel, n_grid: int = 33) -> np.ndarray:
    """``kappa(f_s, f_n)`` on a ``n_grid x n_grid`` lattice of ``[0, 1]^2``: the CE90 of
    the predictive distribution over that of the plug-in normal (:func:`ce90_factor`).

    A vertex's variance ``V`` is made of the signal's part ``f_s V`` (proportional to
    the sill), the database noise's ``f_n V`` and a known rest; the predictive
    distribution of its circular error is the normal's mixed over the parameters'
    distributions, ``P(R > r) = E exp(-r^2 / (2 V (f_t + f_s X_s + f_n X_n)))`` with
    ``X_s = nu / chi2_nu`` (:func:`_variance_nodes`; the Student-t construction) and
    ``X_n`` the database noise's distribution given the data
    (``cov.nugget_posterior``, as an 8-point Gauss rule, :func:`_gauss_rule`). With
    ``cov.sill_prior = (S0, nu0)`` (the database's stated variance, :func:`_sill_prior`)
    the sill's distribution is the posterior of the conjugate prior, ``X_s = q nu' /
    chi2_nu'`` with ``nu' = nu + nu0`` and ``q = (nu C0 + nu0 S0) / (nu' C0)``: it
    matters only where ``nu`` is a few (the sill seen on a few patches). ``r`` solves
    ``P = 0.1`` by Newton's method on ``log r^2``, safeguarded by bisection in the
    bracket of the smallest and the largest mixed variance. Lattice points with
    ``f_s + f_n > 1`` take the value of ``(f_s, f_n) / (f_s + f_n)``.
    """
    xs, ws = _variance_nodes(cov.sill_dof if cov.sill > 0 else float("inf"))
    if cov.sill_prior is not None and cov.sill > 0 and np.isfinite(cov.sill_dof):
        # the prior's scale and degrees of freedom join the estimate's (conjugate
        # scaled inverse chi-square): X_s = r nu' / chi2_nu'
        (s0, nu0), nu = cov.sill_prior, cov.sill_dof
        xs, ws = _variance_nodes(nu + nu0)
        xs = xs * (nu * cov.sill + nu0 * s0) / ((nu + nu0) * cov.sill)
    xn, wn = (_gauss_rule(*cov.nugget_posterior) if cov.nugget_posterior is not None
              else (np.ones(1), np.ones(1)))
    f = np.linspace(0.0, 1.0, n_grid)
    fs, fn = np.meshgrid(f, f, indexing="ij")
    tot = np.maximum(fs + fn, 1.0)
    fs, fn = (fs / tot).ravel(), (fn / tot).ravel()
    ft = np.maximum(1.0 - fs - fn, 0.0)
    a = np.maximum(ft[:, None, None] + fs[:, None, None] * xs[None, :, None]
                   + fn[:, None, None] * xn[None, None, :], 1e-12).reshape(len(fs), -1)
    w = (ws[:, None] * wn[None, :]).ravel()
    rho0 = np.log(10.0)
    # log r^2 / (2 V) between the all-small and the all-large case; Newton's steps on
    # the logarithm, bisection where a step leaves the bracket
    lo, hi = np.log(rho0 * a.min(axis=1)), np.log(rho0 * a.max(axis=1))
    x = np.full(len(a), np.log(rho0))
    x = np.clip(x, lo, hi)
    live = np.arange(len(a))  # the lattice points still iterating
    for _ in range(200):
        xl, al = x[live], a[live]
        rho = np.exp(xl)
        e = np.exp(-rho[:, None] / al)
        h = e @ w - 0.1
        lo[live], hi[live] = np.where(h > 0, xl, lo[live]), np.where(h > 0, hi[live], xl)
        slope = -rho * ((e / al) @ w)
        with np.errstate(divide="ignore", invalid="ignore"):
            new = xl - h / slope
        bad = ~((new > lo[live]) & (new < hi[live]))
        new = np.where(bad, 0.5 * (lo[live] + hi[live]), new)
        x[live] = new
        live = live[np.abs(new - xl) >= 1e-13]
        if not live.size:
            break
    rho = np.exp(x)
    return np.sqrt(rho / rho0).reshape(n_grid, n_grid)


def ce90_factor(cov: Optional[CovarianceModel], v_signal: np.ndarray, v_noise: np.ndarray,
                v_total: np.ndarray) -> np.ndarray:
    """CE90 of the predictive distribution over the CE90 of the plug-in normal.

    The covariance of a predicted vertex is built on estimated parameters: the
    database noise ``n_db`` (its mean given the data, whose distribution
    ``cov.nugget_posterior`` keeps) and the sill ``C0`` (estimated with
    ``cov.sill_dof`` degrees of freedom). Their uncertainty widens the distribution
    of the vertex's error beyond the normal of the same covariance, most where the
    sill dominates (far from measured points: there the sill is seen on a few
    correlation lengths only). The factor is bilinear in a table of ``(f_s, f_n) =
    (v_signal, v_noise) / v_total`` (:func:`_ce90_table`, once per model).

    Parameters
    ----------
    cov : CovarianceModel or None
        None: 1 everywhere.
    v_signal, v_noise, v_total : numpy.ndarray, shape (n,)
        The parts of a vertex's variance (per axis) that scale with the sill and with
        the database noise, and the whole variance.

    Returns
    -------
    numpy.ndarray, shape (n,)
        At least 1 (1 where ``v_total`` is not positive or not finite).
    """
    v_total = np.asarray(v_total, float)
    out = np.ones(v_total.shape)
    if cov is None:
        return out
    if cov._table is None:
        cov._table = _ce90_table(cov)
    tab = cov._table
    ok = np.isfinite(v_total) & (v_total > 0)
    n = tab.shape[0] - 1
    with np.errstate(invalid="ignore", divide="ignore"):
        fs = np.clip(np.asarray(v_signal, float)[ok] / v_total[ok], 0.0, 1.0) * n
        fn = np.clip(np.asarray(v_noise, float)[ok] / v_total[ok], 0.0, 1.0) * n
    fs, fn = np.nan_to_num(fs), np.nan_to_num(fn)
    i, j = np.minimum(fs.astype(np.int64), n - 1), np.minimum(fn.astype(np.int64), n - 1)
    u, v = fs - i, fn - j
    out[ok] = ((1 - u) * (1 - v) * tab[i, j] + u * (1 - v) * tab[i + 1, j]
               + (1 - u) * v * tab[i, j + 1] + u * v * tab[i + 1, j + 1])
    return np.maximum(out, 1.0)
