"""Conflation: correct the road databases.

Every vertex of a database is corrected by least-squares collocation (this package's
main part, below); :mod:`~vectoradjust.conflation.smart` conflates several adjusted
databases feature by feature. It sits beside :mod:`vectoradjust.accuracy` (it moves
vertices, it does not only describe them) and uses its tables.

docs/method.md section 10: a database vertex is ``X_db = X_true + T_db + s(x) + e_db``. The
adjustment measures some vertices; their displacement ``d = X_hat - X_db`` is the
negative of the database error, seen through the measurement noise (the adjusted point's
covariance and the identification error). This module predicts the displacement at
every other vertex

    d(x) = t(x) + c_xm (C_mm + N)^-1 (d_m - t_m)

with the trend ``t`` the database's estimated systematic offset (``-G(x) T``,
:mod:`vectoradjust.adjust.offsets`; a constant mean for axes the offset model does not
cover, applied only where it is significant), ``C(r)`` a covariance function
(exponential or Gaussian) and ``N = diag(n_db + D_i)`` the white noise: the database's
own random error ``n_db`` plus the measured point's variance ``D_i`` (the images' share
of its covariance plus the identification variance). ``C0``, ``L`` and ``n_db`` are the
parameters whose leave-one-out predictions of the measured points score best (the
negative log predictive density, a proper scoring rule, :func:`fit_covariance`); the
semivariogram's least-squares fit gives the start; ``n_db`` is then taken as its mean
given the data (flat prior, :func:`_nugget_posterior`). The measured
displacement is taken as the images see it (:func:`image_only`): the adjusted shape
point is pulled towards the database by its prior, which would shrink the field.
The variance of the real vertex's position error is
``C(0) - c_xm (C_mm + N)^-1 c_mx + n_db + Var(t(x))`` (the unmeasured vertex carries
its own database noise ``n_db``; the trend's variance from the joint covariance of the
adjusted points, :func:`_mean_variance`). The horizontal CE90 is that of the predictive
distribution, the normal mixed over the distributions of the estimated ``n_db`` and
``C0`` (:func:`ce90_factor`; the sill with the database's stated variance as its prior,
:func:`_sill_prior`, which carries the vertices far from measured patches); the sigmas
are the plug-in ones.

Only the ``k`` nearest measured points enter each prediction (a KD-tree; the ``k x k``
systems are solved batch-wise with :func:`numpy.linalg.solve`), so the cost is linear
in the number of vertices. Horizontal (X and Y share one covariance function) and
vertical are separate fields. Numpy and scipy only.

Modules (by topic)
------------------
- :mod:`~vectoradjust.conflation.settings` - settings and constants.
- :mod:`~vectoradjust.conflation.covariance` - the covariance function and its fit.
- :mod:`~vectoradjust.conflation.ce90` - the predictive CE90 (noise and sill posterior).
- :mod:`~vectoradjust.conflation.optimize` - the covariance fit's bounded minimisers.
- :mod:`~vectoradjust.conflation.kriging` - kriging and cross-validation.
- :mod:`~vectoradjust.conflation.fields` - the trend and the fields of a database.
- :mod:`~vectoradjust.conflation.coverage` - coverage per distance band, truth check.
- :mod:`~vectoradjust.conflation.images` - image-only positions, the sill's prior.
- :mod:`~vectoradjust.conflation.prediction` - the prediction, :class:`FieldModel`.
- :mod:`~vectoradjust.conflation.run` - conflating a database and a run, the grid.
- :mod:`~vectoradjust.conflation.smart` - smart conflation: adjusted databases matched
  feature by feature, the more accurate feature prevailing.
"""

from __future__ import annotations

# the public API (``__all__``) and, as ``name as name``, the other names that modules
# and tests use from here (patch a name in the module that looks it up, not here)
from vectoradjust.conflation.ce90 import (
    _ce90_table as _ce90_table,
)
from vectoradjust.conflation.ce90 import (
    _gauss_rule as _gauss_rule,
)
from vectoradjust.conflation.ce90 import (
    ce90_factor,
)
from vectoradjust.conflation.covariance import (
    CovarianceModel,
    empirical_semivariogram,
    fit_covariance,
)
from vectoradjust.conflation.covariance import (
    _fit_white as _fit_white,
)
from vectoradjust.conflation.covariance import (
    _loo_score as _loo_score,
)
from vectoradjust.conflation.covariance import (
    _loo_score_fisher as _loo_score_fisher,
)
from vectoradjust.conflation.covariance import (
    _loo_score_grad as _loo_score_grad,
)
from vectoradjust.conflation.covariance import (
    _loo_setup as _loo_setup,
)
from vectoradjust.conflation.covariance import (
    _nugget_scores as _nugget_scores,
)
from vectoradjust.conflation.covariance import (
    _projected_bfgs as _projected_bfgs,
)
from vectoradjust.conflation.covariance import (
    _sill_dof as _sill_dof,
)
from vectoradjust.conflation.coverage import (
    DISTANCE_BANDS,
    band_coverage,
)
from vectoradjust.conflation.fields import (
    _Trend as _Trend,
)
from vectoradjust.conflation.fields import (
    _trend_cov as _trend_cov,
)
from vectoradjust.conflation.fields import (
    _trend_design as _trend_design,
)
from vectoradjust.conflation.fields import (
    _trend_field_cov as _trend_field_cov,
)
from vectoradjust.conflation.images import (
    _mean_variance as _mean_variance,
)
from vectoradjust.conflation.images import (
    _measured_objects as _measured_objects,
)
from vectoradjust.conflation.images import (
    _orientation_basis as _orientation_basis,
)
from vectoradjust.conflation.images import (
    _sill_prior as _sill_prior,
)
from vectoradjust.conflation.images import (
    image_only,
)
from vectoradjust.conflation.kriging import (
    _krige_many as _krige_many,
)
from vectoradjust.conflation.kriging import (
    cross_validate,
    krige,
)
from vectoradjust.conflation.prediction import (
    FieldModel,
)
from vectoradjust.conflation.run import (
    conflate_database,
    conflate_run,
    field_grid,
)
from vectoradjust.conflation.run import (
    inside_hull as inside_hull,
)
from vectoradjust.conflation.settings import (
    CE90_CIRCULAR,
    CONFLATION_KEYS,
    LE90,
    SILL_PRIOR_DOF,
    SOURCES,
    ConflationSettings,
    settings_from_table,
)

__all__ = [
    "ConflationSettings",
    "CovarianceModel",
    "settings_from_table",
    "fit_covariance",
    "empirical_semivariogram",
    "krige",
    "cross_validate",
    "image_only",
    "FieldModel",
    "field_grid",
    "ce90_factor",
    "conflate_database",
    "conflate_run",
    "SOURCES",
    "CONFLATION_KEYS",
    "CE90_CIRCULAR",
    "LE90",
    "band_coverage",
    "DISTANCE_BANDS",
    "SILL_PRIOR_DOF",
]
