"""DTM and contour accuracy (Filin & Doytsher 1998; Torlegard; Li 1993).

A height interpolated in a DTM is a linear (first-order) function of the quantities
that define it: the adjusted points' X, Y, Z (a TIN, or a grid whose nodes were
interpolated from the points) or the heights of a DEM's nodes. Its variance is
``F Sigma F'`` with ``F`` the interpolation's Jacobian and ``Sigma`` the FULL
covariance of those quantities (``docs/method.md`` section 6). Two further terms are added
to the variance:

* **sampling** (Torlegard et al. 1986): photogrammetric heights hold 0.2-0.4 per mille
  of the flying height ``H`` on flat terrain and 1-2 per mille in mountains. We take
  0.3 per mille up to a mean slope of 5 % and 1.5 per mille from 50 %, linear in the
  slope's tangent in between (:func:`sampling_sigma`).
* **terrain** (Li 1993): ``b (1 + 4 S / W) (S tan a)^2`` with ``b = 17/3072``, ``S``
  the sampling interval, ``a`` the mean slope and ``W`` the mean wavelength of the
  terrain (:func:`terrain_variance`; ``W`` from the zero crossings of the detrended
  heights, :func:`mean_wavelength`).

Both use each cell's own mean slope, averaged over about one wavelength around it (at
most ten sampling intervals; :func:`local_mean_slope`), so that a flat valley and a
steep flank beside it get their own terms; ``terms="area"`` gives the whole area one
value, as the sources do.

Interpolations (:func:`interpolation_operator`):

* ``tin``: linear in the Delaunay triangles of the points. Moving a vertex ``i``
  horizontally changes the height at ``q`` by ``-w_i(q) grad h`` (the surface is a
  plane in the triangle), so ``d h / d(X_i, Y_i, Z_i) = w_i (-g_x, -g_y, 1)``.
* ``bilinear`` and ``bicubic`` (Keys' cubic convolution, ``a = -1/2``) on a node grid.
  With adjusted points, the nodes are the cell corners and their heights the TIN's
  (``F = W_grid F_tin``). With a DEM, the nodes are its cells (GDAL "pixel is area":
  the cell centres) and their covariance ``sigma_n^2 exp(-d / L)`` (the DEM's stated
  node sigma and correlation length ``L``; ``L = 0``: independent nodes).

Products: per-cell sigma and LE90 (:func:`dtm_product`), contour segments with their
horizontal uncertainty ``sigma_z / tan(slope)`` (:func:`contour_segments`), profile
(:func:`profile_accuracy`) and volume (:func:`volume_accuracy`) standard deviations.

Heart module: numpy and scipy only.

Modules (by topic)
------------------
- :mod:`~vectoradjust.accuracy.dtm.models` - height models (points, DEM, a run's).
- :mod:`~vectoradjust.accuracy.dtm.interpolation` - TIN/bilinear/bicubic operators.
- :mod:`~vectoradjust.accuracy.dtm.grid_accuracy` - added terms and :func:`dtm_product`.
- :mod:`~vectoradjust.accuracy.dtm.contours` - contour segments and their accuracy.
- :mod:`~vectoradjust.accuracy.dtm.profiles` - profile and volume accuracy.
"""

from __future__ import annotations

from vectoradjust.accuracy.dtm.contours import (
    ContourSegments,
    contour_segments,
)
from vectoradjust.accuracy.dtm.grid_accuracy import (
    LI_B,
    DTMProduct,
    dtm_product,
    local_mean_slope,
    mean_wavelength,
    sampling_per_mille,
    sampling_sigma,
    terrain_variance,
)
from vectoradjust.accuracy.dtm.interpolation import (
    Interpolated,
    interpolate,
    interpolation_operator,
    keys_weights,
)
from vectoradjust.accuracy.dtm.models import (
    METHODS as METHODS,
)
from vectoradjust.accuracy.dtm.models import (
    HeightModel,
    NodeGrid,
    dem_model,
    points_model,
    run_dem_model,
    run_flying_height,
    run_points_model,
)
from vectoradjust.accuracy.dtm.profiles import (
    ProfileAccuracy,
    VolumeAccuracy,
    points_in_polygon,
    profile_accuracy,
    volume_accuracy,
)
from vectoradjust.accuracy.stats import LE90_FACTOR  # LE90 / sigma, normal error

__all__ = [
    "LI_B",
    "local_mean_slope",
    "LE90_FACTOR",
    "NodeGrid",
    "HeightModel",
    "Interpolated",
    "points_model",
    "dem_model",
    "interpolation_operator",
    "interpolate",
    "keys_weights",
    "sampling_per_mille",
    "sampling_sigma",
    "terrain_variance",
    "mean_wavelength",
    "DTMProduct",
    "dtm_product",
    "ContourSegments",
    "contour_segments",
    "ProfileAccuracy",
    "profile_accuracy",
    "VolumeAccuracy",
    "volume_accuracy",
    "points_in_polygon",
    "run_points_model",
    "run_flying_height",
    "run_dem_model",
]
