"""Two-step stereo orientation: relative, then absolute, with error propagation.

The classical alternative to the bundle adjustment (``docs/method.md`` section 6):

1. :func:`relative_orientation` - a dependent pair: the left photo is fixed at
   ``(0, 0, f)`` with zero rotations, the right photo's ``XL`` is held at the mean
   x-parallax (this fixes the model scale) and ``omega, phi, kappa, YL, ZL`` of the
   right photo are solved, either by the collinearity equations with the model points
   as unknowns (B. Dewitt's public-domain ``relor.c``) or by the coplanarity condition
   in the Gauss-Helmert model. Both are rigorous least squares for the same functional
   model and give the same orientation; model coordinates (in photo millimetres) come
   with their FULL covariance ``F_m Sigma_rr F_m'``.
2. :func:`conformal3d` - the 7-parameter similarity ``X = s M' x + T`` from model to
   ground (B. Dewitt's ``3DCONF.c``: ``M = M_kappa M_phi M_omega`` is transposed),
   either by ordinary least squares on the ground residuals or by the Gauss-Helmert
   model ``A dx + B v + w = 0`` with errors in the model AND the ground coordinates.
3. :func:`two_step` - both steps and the ground coordinates of every point with
   their full covariance.

Conventions: photo coordinates in millimetres, angles in radians (degrees only in
printed reports), ``M = M_kappa M_phi M_omega`` (:mod:`vectoradjust.sensor.collinearity`).
Heart module: numpy and scipy only.

Modules (by topic)
------------------
- :mod:`~vectoradjust.adjust.orientation.common` - rotation partials, weights, covariances.
- :mod:`~vectoradjust.adjust.orientation.relative` - relative orientation, model points.
- :mod:`~vectoradjust.adjust.orientation.conformal` - 3D conformal (Gauss-Helmert).
- :mod:`~vectoradjust.adjust.orientation.stepwise` - :func:`two_step`.
"""

from __future__ import annotations

from vectoradjust.adjust.orientation.common import (
    _vertical_parallax as _vertical_parallax,
)
from vectoradjust.adjust.orientation.common import (
    rotation_matrix_partials,
)
from vectoradjust.adjust.orientation.conformal import (
    Conformal3D,
    conformal3d,
)
from vectoradjust.adjust.orientation.conformal import (
    _conf_apply as _conf_apply,
)
from vectoradjust.adjust.orientation.relative import (
    RelativeOrientation,
    model_intersection,
    relative_orientation,
)
from vectoradjust.adjust.orientation.stepwise import (
    TwoStep,
    two_step,
)

__all__ = [
    "rotation_matrix_partials",
    "RelativeOrientation",
    "relative_orientation",
    "model_intersection",
    "Conformal3D",
    "conformal3d",
    "TwoStep",
    "two_step",
]
