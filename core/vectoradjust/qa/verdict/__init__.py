"""Accuracy control of an adjustment run: the QA verdict (``docs/method.md`` section 7).

:func:`accuracy_control` judges a finished :class:`~vectoradjust.pipeline.AdjustmentRun`
stage by stage against the tolerances that :mod:`vectoradjust.qa.tolerances` derives from the
product specification (``[qa]``), the camera and the pixel size:

===================== ====================================================================
interior orientation  per image, the largest fiducial residual (from ``data.interior``
                      when fiducial fits were made; else not evaluated)
relative orientation  per stereo pair, the vertical parallax left after the adjustment
                      (mean and max of ``|py|``)
triplets              per three consecutive images, the discrepancies of the points
                      intersected in the two adjacent models (E_xy, E_z, image scale)
block adjustment      control (GCP) and check point residuals, XY and Z
orthophoto            the height tolerance dh_DTM / 3 on the block; dh_DTM reported
DTM heights           with a DEM in the project: the DEM's bilinear height at every
                      control and check point against its surveyed Z (dh_DTM for
                      orthophotos, the check point height rule for maps)
orthomosaic           0.5 / 0.7 mm on GCP and check points; seamlines not measured here
===================== ====================================================================

Choices (documented here because the manual leaves them open)
-------------------------------------------------------------
* **Vertical parallax after the adjustment** is computed from the OBSERVED photo
  coordinates and the ADJUSTED exterior orientation, in the pair's epipolar-normalised
  frame (:func:`vectoradjust.qa.tolerances.vertical_parallax`): it is how far the two observed
  rays of a point miss each other across the base, which is what a relative
  orientation check measures. It needs no object point (so it does not depend on how
  the adjustment shared a point's misclosure between its two, three or more rays), it
  is exact (no linearisation), and it is zero for intersecting rays whatever the
  attitudes. To first order it equals the difference of the two images' y residuals
  in that frame (``py = -(v_y,left - v_y,right)``), which the tests use as an
  independent check.
* **Stereo pairs** are consecutive images of ``[[images]]`` (flight order) with at
  least ``min_pair_points`` common points (6: the standard points of a relative
  orientation); ``pairs="all"`` takes every image pair with that many common points.
* **Triplets** are three consecutive images with at least ``min_triplet_points``
  points on all three. Each such point is intersected (:func:`vectoradjust.adjust.bundle.intersect`,
  adjusted EO held fixed) from its two rays in model (1, 2) and from those in model
  (2, 3); the difference is taken to image scale with ``m = H / f`` (``H`` the height
  of the middle exposure station above the point). The photo base ``b`` of
  ``E_z = (f / b) E_xy`` is the mean of the two models' air bases divided by ``m``.
  Triplet stages are judged on the MEAN discrepancy with every point against twice
  the tolerance (``E_max ~ 2 E_mean``), like the block.
* **Pixel size**: the ``pixel_size`` argument, else ``[qa] pixel_size``, else the
  camera calibration's (``sqrt(sx sy)`` for rectangular pixels). Without one, the
  pixel-based stages are reported with their measured values but not evaluated
  (``n/a``), and the verdict says so.
* **Working-area radius** ``r`` of the orthophoto height tolerance: ``[qa]
  working_radius`` or the largest radial distance of a measured image point from the
  principal point.

A "heart" module: numpy and other vectoradjust heart modules only; no file I/O.

Modules (by topic)
------------------
- :mod:`~vectoradjust.qa.verdict.spec` - the ``[qa]`` table, pixel size, working radius.
- :mod:`~vectoradjust.qa.verdict.image_checks` - observation pairs, parallax, triplets,
  interior orientation stages.
- :mod:`~vectoradjust.qa.verdict.block_checks` - zones, strips, the free model.
- :mod:`~vectoradjust.qa.verdict.assess` - :class:`QAReport` and :func:`accuracy_control`.
- :mod:`~vectoradjust.qa.verdict.render` - the HTML section and production rows.
"""

from __future__ import annotations

from vectoradjust.qa.verdict.assess import (
    QAReport,
    accuracy_control,
    control_qa_field,
)
from vectoradjust.qa.verdict.block_checks import (
    block_view,
    inter_strip_stages,
    strips_from_project,
    zone_stages,
)
from vectoradjust.qa.verdict.image_checks import (
    interior_stages,
    observation_pairs,
    pair_parallax,
    triplet_discrepancies,
)
from vectoradjust.qa.verdict.render import (
    html_section,
    production_rows,
)
from vectoradjust.qa.verdict.spec import (
    PAIR_MODES as PAIR_MODES,
)
from vectoradjust.qa.verdict.spec import (
    resolve_pixel_size,
    spec_from_table,
    working_radius_mm,
)

__all__ = [
    "QAReport",
    "spec_from_table",
    "resolve_pixel_size",
    "working_radius_mm",
    "observation_pairs",
    "pair_parallax",
    "triplet_discrepancies",
    "interior_stages",
    "block_view",
    "zone_stages",
    "inter_strip_stages",
    "strips_from_project",
    "accuracy_control",
    "control_qa_field",
    "html_section",
    "production_rows",
]
