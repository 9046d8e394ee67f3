"""Linear error (LE90) and the closed-form approximations other software uses (Doucette's
CE90, Ager's LE90), for comparison.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr, ndtri

from vectoradjust.accuracy.stats.circular import (
    _MAX_ITER,
    _RTOL,
    _SQRT_2PI,
    _check_probability,
    _out,
    principal_axes,
)

__all__ = ["le90", "linear_error", "doucette_ce90", "ager_le90"]


def linear_error(sigma, bias=None, probability: float = 0.9):
    """Exact linear error ``R`` with ``P(|e| <= R) = probability``, ``e ~ N(bias, sigma^2)``.

    Parameters
    ----------
    sigma : array_like
        Standard deviations (>= 0).
    bias : array_like, optional
        Mean errors (sign irrelevant).
    probability : float, optional
        Default 0.9.

    Returns
    -------
    float or numpy.ndarray
        Without bias ``Phi^-1((1 + p)/2) sigma``; with bias the root of
        ``Phi((R - mu)/s) - Phi((-R - mu)/s) = p`` (vectorised Newton, bracketed).
    """
    p = _check_probability(probability)
    s = np.asarray(sigma, dtype=float)
    if np.any(s < 0):
        raise ValueError("standard deviations must be >= 0")
    if bias is None:
        return _out(float(ndtri(0.5 * (1.0 + p))) * s)
    s, mu = np.broadcast_arrays(s, np.abs(np.asarray(bias, dtype=float)))
    shape = s.shape
    s, mu = s.ravel().astype(float), mu.ravel().astype(float)
    out = np.full(s.shape, np.nan)
    ok = np.isfinite(s) & np.isfinite(mu)
    zero = ok & (s == 0)
    out[zero] = mu[zero]
    act = np.flatnonzero(ok & (s > 0))
    if act.size:
        sa, m = s[act], mu[act]
        # Phi((R - mu)/s) - Phi((-R - mu)/s) lies between Phi((R-mu)/s) - (1-Phi(..)) ...
        lo = m + float(ndtri(p)) * sa
        lo = np.maximum(lo, 0.0)
        hi = m + float(ndtri(0.5 * (1.0 + p))) * sa
        x = 0.5 * (lo + hi)
        done = np.zeros(act.size, dtype=bool)
        for _ in range(_MAX_ITER):
            live = np.flatnonzero(~done)
            if live.size == 0:
                break
            xl, sl, ml = x[live], sa[live], m[live]
            zp, zm = (xl - ml) / sl, (-xl - ml) / sl
            f = ndtr(zp) - ndtr(zm) - p
            df = (np.exp(-0.5 * zp * zp) + np.exp(-0.5 * zm * zm)) / (_SQRT_2PI * sl)
            below = f < 0
            lo[live] = np.where(below, xl, lo[live])
            hi[live] = np.where(below, hi[live], xl)
            with np.errstate(divide="ignore", invalid="ignore"):
                newton = np.where(f == 0, xl, xl - f / df)
            bad = ~(np.isfinite(newton) & (newton >= lo[live]) & (newton <= hi[live]))
            xn = np.where(bad, 0.5 * (lo[live] + hi[live]), newton)
            tol = _RTOL * np.maximum(xn, hi[live]) + 1e-300
            done[live] = (np.abs(xn - xl) <= tol) | (hi[live] - lo[live] <= tol) | (f == 0)
            x[live] = xn
        out[act] = x
    return _out(out.reshape(shape))


def le90(sigma_z, bias=None):
    """LE90 of vertical errors: ``1.644854 sigma_z`` without bias, exact root with bias.

    Parameters
    ----------
    sigma_z : array_like
        Vertical standard deviations (>= 0).
    bias : array_like, optional
        Vertical mean errors; with a bias the result is the root of
        ``Phi((R - mu)/s) - Phi((-R - mu)/s) = 0.9``.

    Returns
    -------
    float or numpy.ndarray
    """
    return linear_error(sigma_z, bias, 0.9)


# ---------------------------------------------------------------------------
# approximations (for comparison with other software)
# ---------------------------------------------------------------------------


def doucette_ce90(cov):
    """Doucette / Greenwalt-Shultz approximation ``2.1460 (a + b) / 2``.

    ``a``, ``b`` are the semi-axes of the 1-sigma error ellipse. Good only for
    ``b/a >= 0.6`` (it gives 1.073 a instead of 1.645 a for b = 0).

    Parameters
    ----------
    cov : array_like, shape (..., 2, 2)

    Returns
    -------
    float or numpy.ndarray, shape (...)
    """
    smax, smin, _ = principal_axes(cov)
    return _out(2.1460 * 0.5 * (smax + smin))


def ager_le90(mu, sigma):
    """Ager (NIMA) LE90 of a vertical error with bias, formula of docs/method.md section 4.

    With ``k = |mu| / sigma``: ``k <= 1.4``:
    ``|mu| + sigma (1.6435 - 0.999556 k + 0.923237 k^2 - 0.282533 k^3)``;
    otherwise ``|mu| + 1.2815 sigma``.

    Parameters
    ----------
    mu : array_like
        Vertical bias (sign irrelevant).
    sigma : array_like
        Vertical standard deviation.

    Returns
    -------
    float or numpy.ndarray
    """
    m, s = np.broadcast_arrays(np.abs(np.asarray(mu, float)), np.asarray(sigma, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(s > 0, m / s, np.where(m > 0, np.inf, 0.0))
        poly = 1.6435 - 0.999556 * k + 0.923237 * k**2 - 0.282533 * k**3
        res = np.where(k <= 1.4, m + s * poly, m + 1.2815 * s)
    res = np.where(np.isnan(m) | np.isnan(s), np.nan, res)
    return _out(res)

