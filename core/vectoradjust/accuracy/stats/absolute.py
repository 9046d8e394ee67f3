"""Absolute accuracy of a set of errors (bias and dispersion), the global chi-square test
of the variance factor and the paper's ratios (recovery rate, improvement).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.special import chdtri

from vectoradjust.accuracy.stats.circular import (
    _json,
    _out,
    ager_ce90,
    circular_error,
    principal_axes,
)
from vectoradjust.accuracy.stats.linear import ager_le90, le90
from vectoradjust.accuracy.stats.standards import bias_direction, bias_statement
from vectoradjust.errors import ProjectError

__all__ = [
    "AbsoluteAccuracy", "absolute_accuracy", "chi_square_test", "recovery_rate", "improvement",
]


@dataclass(frozen=True)
class AbsoluteAccuracy:
    """Bias and dispersion of a set of errors with CE90/LE90 (see :func:`absolute_accuracy`).

    All lengths are in the units of the errors. Fields that cannot be computed
    (too few rows, no vertical column) are NaN; :meth:`as_dict` turns them into None.
    """

    count: int
    mean_x: float
    mean_y: float
    mean_z: float
    sigma_x: float
    sigma_y: float
    sigma_z: float
    cov_xy: float
    mu: float
    sigma_c: float
    ce90_exact: float
    ce90_formula: float
    le90_exact: float
    le90_formula: float
    rmse_x: float
    rmse_y: float
    rmse_z: float
    rmse_horizontal: float
    bias_magnitude: float
    bias_azimuth: float
    bias_direction: str
    bias_text: str

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dictionary (floats, ints, strings, None for undefined)."""
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, float):
                d[k] = _json(v)
        return d


def absolute_accuracy(errors, units: str = "m") -> AbsoluteAccuracy:
    """Absolute accuracy of a set of errors with bias (Ager / NIMA, docs/method.md section 4).

    Parameters
    ----------
    errors : array_like, shape (n, 2) or (n, 3)
        Errors per point, e.g. adjusted - truth or database - truth (X, Y[, Z]).
        Rows with a non-finite value are ignored.
    units : str, optional
        Unit name used in ``bias_text``.

    Returns
    -------
    AbsoluteAccuracy
        ``mean_*`` (bias per axis), ``sigma_*`` (sample standard deviations,
        ddof = 1), ``mu = |mean horizontal error|``,
        ``sigma_c = (sqrt(l1) + sqrt(l2)) / 2`` from the eigenvalues of the sample
        covariance of the horizontal errors, ``ce90_exact`` (numeric, with the mean as
        bias and the sample covariance), ``ce90_formula`` (Ager), ``le90_exact`` and
        ``le90_formula`` (when there is a Z column), the RMSEs, and the bias as
        magnitude, azimuth (degrees clockwise from north), compass direction and text
        (``"14.0 m towards south-east"``: the direction in which the tested positions
        are displaced when the errors are tested - truth). CE/LE values need at
        least 2 rows.
    """
    e = np.asarray(errors, dtype=float)
    if e.ndim != 2 or e.shape[1] not in (2, 3):
        raise ValueError(f"errors must have shape (n, 2) or (n, 3), got {e.shape}")
    e = e[np.all(np.isfinite(e), axis=1)]
    n = int(e.shape[0])
    has_z = e.shape[1] == 3
    nan = math.nan
    if n == 0:
        return AbsoluteAccuracy(0, *([nan] * 19), "", "bias unknown")
    mean = e.mean(axis=0)
    r = np.sqrt(np.mean(e * e, axis=0))
    mx, my = float(mean[0]), float(mean[1])
    mz = float(mean[2]) if has_z else nan
    mag, az, name = bias_direction(mx, my)
    text = bias_statement(mx, my, units=units)
    if n >= 2:
        c = np.cov(e[:, :2], rowvar=False, ddof=1)
        smax, smin, _ = principal_axes(c)
        sc = 0.5 * (float(smax) + float(smin))
        ce_ex = float(circular_error(c, np.array([mx, my]), 0.9))
        ce_f = float(ager_ce90(mag, sc))
        sx, sy, cxy = math.sqrt(c[0, 0]), math.sqrt(c[1, 1]), float(c[0, 1])
        if has_z:
            sz = float(np.std(e[:, 2], ddof=1))
            le_ex = float(le90(sz, mz))
            le_f = float(ager_le90(mz, sz))
        else:
            sz = le_ex = le_f = nan
    else:
        sc = ce_ex = ce_f = sx = sy = cxy = sz = le_ex = le_f = nan
    return AbsoluteAccuracy(
        count=n,
        mean_x=mx,
        mean_y=my,
        mean_z=mz,
        sigma_x=sx,
        sigma_y=sy,
        sigma_z=sz,
        cov_xy=cxy,
        mu=mag,
        sigma_c=sc,
        ce90_exact=ce_ex,
        ce90_formula=ce_f,
        le90_exact=le_ex,
        le90_formula=le_f,
        rmse_x=float(r[0]),
        rmse_y=float(r[1]),
        rmse_z=float(r[2]) if has_z else nan,
        rmse_horizontal=float(math.hypot(r[0], r[1])),
        bias_magnitude=mag,
        bias_azimuth=az,
        bias_direction=name,
        bias_text=text,
    )


# ---------------------------------------------------------------------------
# global test and paper ratios
# ---------------------------------------------------------------------------


def chi_square_test(vtpv: float, dof: int, alpha: float = 0.05) -> dict[str, Any]:
    """Two-sided global (chi-square) test of the a-posteriori variance factor.

    Accept when ``chi2(r, alpha/2) <= v'Pv <= chi2(r, 1 - alpha/2)`` (quantiles of
    the chi-square distribution with ``r = dof`` degrees of freedom). For
    ``r = 18, alpha = 0.05`` the bounds are [8.2307, 31.5264].

    Parameters
    ----------
    vtpv : float
        Weighted sum of squared residuals ``v'Pv`` (a-priori reference variance 1).
    dof : int
        Redundancy ``r = n - u``.
    alpha : float, optional
        Significance level, 0 < alpha < 1 (the project's ``[adjustment] alpha``).

    Returns
    -------
    dict
        ``{statistic, lower, upper, alpha, passed}``; with ``dof <= 0`` there is no
        test: ``lower``, ``upper`` and ``passed`` are None.

    Raises
    ------
    ProjectError
        If ``alpha`` is not strictly between 0 and 1.
    """
    a = float(alpha)
    if not 0.0 < a < 1.0:
        raise ProjectError(
            f"[adjustment] alpha = {alpha} is not a significance level",
            "Set alpha to a number between 0 and 1, for example 0.05",
        )
    stat = _json(vtpv)
    r = int(dof)
    if r <= 0 or stat is None:
        return {"statistic": stat, "lower": None, "upper": None, "alpha": a, "passed": None}
    # chi2.ppf(q, r) = chdtri(r, 1 - q)
    lower = float(chdtri(r, 1.0 - a / 2.0))
    upper = float(chdtri(r, a / 2.0))
    return {
        "statistic": stat,
        "lower": lower,
        "upper": upper,
        "alpha": a,
        "passed": bool(lower <= stat <= upper),
    }


def recovery_rate(residual_rmse, true_rmse):
    """Recovery rate ``RMSE(residuals) / RMSE(database - truth)`` (docs/method.md section 4).

    A value near 1 means that the adjustment residuals recover the true
    displacement of the database. Note: the dissertation's percentages (3.57 m vs
    3.37 m "94 %", 22.41 m vs 22.52 m "99 %") equal the smaller RMSE over the larger
    one; this function returns the ratio exactly as docs/method.md section 4 defines it
    (3.57 / 3.37 = 1.059).

    Parameters
    ----------
    residual_rmse, true_rmse : array_like

    Returns
    -------
    float or numpy.ndarray
        NaN where ``true_rmse`` is 0.
    """
    a = np.asarray(residual_rmse, dtype=float)
    b = np.asarray(true_rmse, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _out(np.where(b != 0, a / np.where(b != 0, b, 1.0), np.nan))


def improvement(rmse_adjusted_vs_truth, rmse_database_vs_truth):
    """Relative improvement ``1 - RMSE(adjusted - truth) / RMSE(database - truth)``.

    Parameters
    ----------
    rmse_adjusted_vs_truth, rmse_database_vs_truth : array_like

    Returns
    -------
    float or numpy.ndarray
        E.g. 4.81 m -> 0.68 m gives 0.859 (86 % better). NaN where the database
        RMSE is 0.
    """
    a = np.asarray(rmse_adjusted_vs_truth, dtype=float)
    b = np.asarray(rmse_database_vs_truth, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _out(np.where(b != 0, 1.0 - a / np.where(b != 0, b, 1.0), np.nan))

