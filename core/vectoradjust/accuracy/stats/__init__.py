"""Accuracy statistics: CE90/LE90, RMSE, NSSDA, ASPRS 2023, bias, chi-square test.

Everything here is a numerical heart module (numpy and scipy only) and is vectorised:
per-point quantities (:func:`ce90`, :func:`ce90_exact`, :func:`le90`,
:func:`circular_error_probability`) accept arrays of any leading shape.

Conventions (docs/method.md section 4)
------------------------------
* Horizontal covariances are ``(..., 2, 2)`` arrays in the ground frame (X east,
  Y north). Only their symmetric part is used.
* **CE90** is the radius ``R`` with ``P(|e| <= R) = 0.9`` for a bivariate normal
  error ``e``; **LE90** the half-width with ``P(|e_z| <= R) = 0.9``.
* In principal axes (standard deviations ``sa >= sb``, bias ``(ma, mb)``)::

      P(R) = int_{-R}^{R} phi((y - mb)/sb)/sb [Phi((h - ma)/sa) - Phi((-h - ma)/sa)] dy,
      h = sqrt(R^2 - y^2).

  The outer integral runs along the axis with the *smaller* standard deviation and
  only over ``mb +- 9 sb`` (the neglected mass is below 3e-19). With the smooth
  substitution ``y = R sin t`` (which removes the square-root end singularity of
  ``h``) it is evaluated with Gauss-Legendre on four panels split at the density
  peak ``y = mb`` and where the inner step sits (``h = |ma|``), 32 nodes each.
  Measured against 30-digit adaptive quadrature (mpmath) on random cases with axis
  ratios 1e-4..1 and bias up to 300 sigma, the largest absolute error in P was 1e-11
  (``validation/ce90_coverage.py``).
* Radii are found by a vectorised, bracketed Newton iteration (bisection whenever a
  Newton step leaves the bracket); the derivative ``dP/dR`` comes from the same
  quadrature. Relative tolerance 1e-12: a step ends the iteration when it is below that,
  or when its error estimated from the convergence (``|P''| s^2 / (2 |P'|)``, ``P''``
  from the last two slopes) is below 1 % of it, which saves one evaluation of P in
  about four. The radius is then as exact as P: against mpmath roots on thin biased
  ellipses (axis ratio 1e-4) both stopping rules were within 2.6e-12 relative. Cost
  with a bias: about 40 us per point (2-core reference machine); use :func:`ce90` for
  millions of unbiased points.
* :func:`ce90` (no bias, the per-point case; 10^6 points in 0.13-0.25 s)
  interpolates a table of ``g(rho) = CE90/sigma_max`` over
  ``rho = sigma_min/sigma_max`` in [0, 1] (4097 nodes, built once on first use,
  ~0.25 s). The interpolation error is below 1e-8 relative (see
  :func:`ce90_ratio_factor`).

Check values: ``g(0) = 1.644854`` (= Phi^-1(0.95)), ``g(1) = 2.145966``
(= sqrt(-2 ln 0.1)), ``g(0.5) = 1.737080``. The handed-over design (DESIGN.md) once gave 1.716257
for the ratio 0.5; that number is ``g(0.45)`` (three independent computations agree, see
``tests/test_stats.py``).

Undefined values (no data, zero degrees of freedom) are ``None`` in the dictionaries
returned here, so that they can be written to JSON as they are; array functions
return NaN.

Modules (by topic)
------------------
- :mod:`~vectoradjust.accuracy.stats.circular` - P(|e| <= R), CE90 exact and tabled.
- :mod:`~vectoradjust.accuracy.stats.linear` - LE90 and the Doucette/Ager approximations.
- :mod:`~vectoradjust.accuracy.stats.standards` - bias, RMSE, NSSDA, ASPRS 2023.
- :mod:`~vectoradjust.accuracy.stats.absolute` - absolute accuracy, chi-square test, ratios.
"""

from __future__ import annotations

from vectoradjust.accuracy.stats.absolute import (
    AbsoluteAccuracy,
    absolute_accuracy,
    chi_square_test,
    improvement,
    recovery_rate,
)
from vectoradjust.accuracy.stats.circular import (
    CE90_CIRCULAR_FACTOR,
    LE90_FACTOR,
    ager_ce90,
    ce90,
    ce90_exact,
    ce90_ratio_factor,
    circular_error,
    circular_error_probability,
    principal_axes,
)
from vectoradjust.accuracy.stats.circular import (
    _ce90_table as _ce90_table,
)
from vectoradjust.accuracy.stats.circular import (
    _solve_radius as _solve_radius,
)
from vectoradjust.accuracy.stats.linear import (
    ager_le90,
    doucette_ce90,
    le90,
    linear_error,
)
from vectoradjust.accuracy.stats.standards import (
    asprs2023,
    bias_direction,
    bias_statement,
    nssda,
    rmse,
    rmse_summary,
)

__all__ = [
    "LE90_FACTOR",
    "CE90_CIRCULAR_FACTOR",
    "circular_error_probability",
    "circular_error",
    "ce90",
    "ce90_exact",
    "ce90_ratio_factor",
    "le90",
    "linear_error",
    "principal_axes",
    "doucette_ce90",
    "ager_ce90",
    "ager_le90",
    "AbsoluteAccuracy",
    "absolute_accuracy",
    "rmse",
    "rmse_summary",
    "nssda",
    "asprs2023",
    "bias_direction",
    "bias_statement",
    "chi_square_test",
    "recovery_rate",
    "improvement",
]
