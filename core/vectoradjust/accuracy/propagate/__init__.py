"""Error propagation from adjusted points to derived quantities (Filin & Doytsher 1998).

Anything computed from adjusted points - a distance, a road's length, an average
height, a profile, a DTM height, a contour - gets the covariance
``Sigma_f = F Sigma F'`` with ``F`` the Jacobian of the derived function and ``Sigma``
the FULL covariance of the points involved (``docs/method.md`` section 6). Neighbouring
points of a photogrammetric adjustment are typically 90-97 % correlated, and ignoring
the covariances BETWEEN points roughly halves or doubles the answer; every function
here therefore also reports the "without covariances" value, computed with the
per-point blocks only (the block-diagonal part of ``Sigma``: each point keeps its own
3x3 (or 2x2) covariance, the cross-covariances between points are set to zero).

Also here: the G-band of a line segment (Shi & Liu 2000) and the equal-error grid of a
stereo pair (sigma of a forward-intersected ground point, including the exterior
orientation's uncertainty).

Heart module: numpy and scipy only; everything is vectorised over points.

Modules (by topic)
------------------
- :mod:`~vectoradjust.accuracy.propagate.general` - :func:`propagate`, block-diagonal covariances.
- :mod:`~vectoradjust.accuracy.propagate.lines` - distances, lengths, heights, profiles.
- :mod:`~vectoradjust.accuracy.propagate.terrain` - the DTM (bilinear) and contours.
- :mod:`~vectoradjust.accuracy.propagate.bands` - the G-band and the equal-error grid.
"""

from __future__ import annotations

from vectoradjust.accuracy.propagate.bands import (
    GridSigma,
    confidence_scale,
    g_band,
    g_band_polyline,
    point_sigma_grid,
)
from vectoradjust.accuracy.propagate.general import (
    ArrayLike as ArrayLike,
)
from vectoradjust.accuracy.propagate.general import (
    PropagationResult,
    block_diagonal,
    propagate,
)
from vectoradjust.accuracy.propagate.lines import (
    DistanceResult,
    ProfileResult,
    distance,
    height_profile,
    mean_height,
    polyline_length,
)
from vectoradjust.accuracy.propagate.terrain import (
    DTMResult,
    bilinear_coefficients,
    contour_tolerance,
    dtm_bilinear,
)

__all__ = [
    "PropagationResult",
    "propagate",
    "block_diagonal",
    "DistanceResult",
    "distance",
    "polyline_length",
    "mean_height",
    "ProfileResult",
    "height_profile",
    "bilinear_coefficients",
    "DTMResult",
    "dtm_bilinear",
    "contour_tolerance",
    "confidence_scale",
    "g_band",
    "g_band_polyline",
    "GridSigma",
    "point_sigma_grid",
]
