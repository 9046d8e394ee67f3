"""Production accuracy control: tolerances from the product specification.

A production line accepts a block only if every stage is within tolerances that
follow from the camera, the pixel size, the map scale and the contour interval
(PHOTOMOD manual, after the Russian 2002 instruction of CNIIGAiK, GKINP-02-036-02;
``docs/method.md`` section 7). Nothing here is typed in by the user: every tolerance is
computed from the ``[qa]`` product specification (:class:`QASpec`) and the camera.

Stages and their tolerances
---------------------------
===================== ==================================================================
interior orientation  max fiducial residual <= 1 pixel
relative orientation  mean |vertical parallax| <= 0.5 pixel, max <= 1 pixel
triplets              E_xy <= sqrt(2) * 0.5 pixel, E_z = (f / b) E_xy (image scale)
block (map)           GCP mean 0.2 mm at map scale (XY), 0.15 h (Z); check points
                      0.3 mm (XY) and 0.2 / 0.25 / 0.35 h (Z) for h = 1 / 2.5 / 5-10 m
block (orthophoto)    dh_DTM = 0.3 mm * f * M / r; block Z tolerance dh_DTM / 3
DTM heights           at control and check points: dh_DTM (orthophoto), the check
                      point height rule (map); mean, a point at twice
orthomosaic           0.5 mm (flat, hilly) / 0.7 mm (mountainous) at orthophoto scale;
                      seamlines 0.7 / 1.0 mm
===================== ==================================================================

The tolerances of the block are on the MEAN error. The limiting (maximum) error is
twice the mean (``E_max ~ 2 E_mean``; the instruction's "limiting discrepancies must
not exceed twice the mean"), and the RMS about ``sqrt(2) E_mean``
(:func:`max_from_mean`, :func:`rms_from_mean`). The relative orientation rule
(mean 0.5 pixel, max 1 pixel) is the same rule. A single point is therefore judged
against the limiting tolerance, a stage by its statistic.

A "heart" module (numpy and :mod:`vectoradjust.sensor.collinearity` only): the functions
take numbers and arrays; the caller wires them to adjustment results, files and
reports.

Modules (by topic)
------------------
- :mod:`~vectoradjust.qa.tolerances.product` - :class:`QASpec`, products, terrains.
- :mod:`~vectoradjust.qa.tolerances.limits` - the tolerance of every stage.
- :mod:`~vectoradjust.qa.tolerances.measured` - vertical parallax, model discrepancies.
- :mod:`~vectoradjust.qa.tolerances.stages` - stage results and the verdict.
- :mod:`~vectoradjust.qa.tolerances.control_points` - QA of control and check points.
"""

from __future__ import annotations

from vectoradjust.qa.tolerances.control_points import (
    ControlPointQA,
    control_point_qa,
)
from vectoradjust.qa.tolerances.limits import (
    BlockTolerances,
    OrthomosaicTolerance,
    PixelTolerance,
    block_tolerances,
    check_z_factor,
    dtm_height_tolerance,
    interior_orientation_tolerance,
    max_from_mean,
    mean_from_rms,
    orthomosaic_tolerance,
    orthophoto_dtm_tolerance,
    relative_orientation_tolerance,
    rms_from_mean,
    stereo_base_mm,
    triplet_tolerance,
)
from vectoradjust.qa.tolerances.measured import (
    ParallaxStats,
    model_discrepancies,
    parallax_stats,
    vertical_parallax,
)
from vectoradjust.qa.tolerances.product import (
    _SPEC_KEYS as _SPEC_KEYS,
)
from vectoradjust.qa.tolerances.product import (
    PRODUCTS,
    TERRAINS,
    QASpec,
)
from vectoradjust.qa.tolerances.product import (
    STATISTICS as STATISTICS,
)
from vectoradjust.qa.tolerances.stages import (
    QAVerdict,
    StageResult,
    check_stage,
    parallax_stages,
    qa_verdict,
)

__all__ = [
    "PRODUCTS",
    "TERRAINS",
    "QASpec",
    "PixelTolerance",
    "BlockTolerances",
    "OrthomosaicTolerance",
    "ParallaxStats",
    "StageResult",
    "QAVerdict",
    "ControlPointQA",
    "interior_orientation_tolerance",
    "relative_orientation_tolerance",
    "triplet_tolerance",
    "stereo_base_mm",
    "check_z_factor",
    "block_tolerances",
    "orthophoto_dtm_tolerance",
    "dtm_height_tolerance",
    "orthomosaic_tolerance",
    "max_from_mean",
    "rms_from_mean",
    "mean_from_rms",
    "vertical_parallax",
    "parallax_stats",
    "model_discrepancies",
    "check_stage",
    "parallax_stages",
    "qa_verdict",
    "control_point_qa",
]
