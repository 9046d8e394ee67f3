"""Image coordinate refinement (interior orientation), docs/method.md section 5.

Measured image coordinates (scanner/camera pixels, or comparator millimetres) are
turned into refined photo coordinates (mm) by, in this order:

1. ``affine`` - the 6-parameter affine from measured to calibrated fiducials
   (:func:`fit_fiducial_affine`); for a digital frame without fiducials,
   ``pixel_to_photo`` with the pixel size instead;
2. ``principal_point`` - reduction to the principal point ``(x0, y0)``;
3. ``distortion`` - lens distortion (SMAC/USGS or the odd radial polynomial, with
   decentering; :mod:`vectoradjust.sensor.camera` states the sign convention; or the
   Brown/OpenCV model, inverted exactly);
4. ``refraction`` - atmospheric refraction, ARDC 1959 model (:func:`ardc_k`);
5. ``earth_curvature`` - only for a map-projection ground frame.

Each step is switchable (:data:`DEFAULT_CORRECTIONS`). :func:`refine` applies the
chain to the points of one image and reports, per step, whether it was applied and
its largest size in micrometres; :func:`distort` is its exact inverse (for
simulation: ideal photo coordinates -> what the scanner would measure).

When the principal point is reduced here, the returned coordinates are relative to
the principal point and the collinearity equations must then use
``principal_point = (0, 0)``; ``refine`` returns the principal point to use in its
summary (``summary["principal_point"]``).

Pure numerics: numpy only; vectorised over points (no Python loop over points).

Modules (by topic)
------------------
- :mod:`~vectoradjust.sensor.refine.fiducials` - the fiducial affine, interior orientation check.
- :mod:`~vectoradjust.sensor.refine.pixels` - pixel <-> photo coordinates, sigmas in mm.
- :mod:`~vectoradjust.sensor.refine.corrections` - distortion, refraction, earth curvature.
- :mod:`~vectoradjust.sensor.refine.chain` - :func:`refine` and :func:`distort`.
- :mod:`~vectoradjust.sensor.refine.coerce` - steps, switches, argument helpers,
  :func:`as_calibration`.
"""

from __future__ import annotations

from vectoradjust.sensor.refine.chain import (
    RefineResult,
    distort,
    refine,
)
from vectoradjust.sensor.refine.coerce import (
    DEFAULT_CORRECTIONS,
    as_calibration,
)
from vectoradjust.sensor.refine.coerce import (
    STEPS as STEPS,
)
from vectoradjust.sensor.refine.corrections import (
    EARTH_RADIUS,
    ardc_k,
    decentering_correction,
    earth_curvature_correction,
    radial_polynomial_correction,
    refraction_correction,
    smac_correction,
)
from vectoradjust.sensor.refine.fiducials import (
    AffineFit,
    fit_fiducial_affine,
    interior_orientation_check,
)
from vectoradjust.sensor.refine.pixels import (
    PixelSize as PixelSize,
)
from vectoradjust.sensor.refine.pixels import (
    photo_to_pixel,
    pixel_to_photo,
    sigma_pixels_to_mm,
)

__all__ = [
    "AffineFit",
    "RefineResult",
    "DEFAULT_CORRECTIONS",
    "EARTH_RADIUS",
    "fit_fiducial_affine",
    "pixel_to_photo",
    "photo_to_pixel",
    "smac_correction",
    "radial_polynomial_correction",
    "decentering_correction",
    "ardc_k",
    "refraction_correction",
    "earth_curvature_correction",
    "refine",
    "distort",
    "sigma_pixels_to_mm",
    "interior_orientation_check",
    "as_calibration",
]
