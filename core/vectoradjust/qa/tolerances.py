"""Production accuracy control: tolerances from the product specification.

A production line accepts a block only if every stage is within tolerances that
follow from the camera, the pixel size, the map scale and the contour interval
(PHOTOMOD manual, after the Russian 2002 instruction of CNIIGAiK, GKINP-02-036-02;
``DESIGN.md`` section 7). Nothing here is typed in by the user: every tolerance is
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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vectoradjust.errors import ControlError, ProjectError
from vectoradjust.sensor.collinearity import rotation_matrix

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

#: Allowed values of ``[qa] product``.
PRODUCTS = ("topographic map", "orthophoto", "orthomosaic")
#: Allowed values of ``[qa] terrain``.
TERRAINS = ("flat", "hilly", "mountainous")
#: Allowed statistics of a stage.
STATISTICS = ("mean", "rms", "max")

_SPEC_KEYS = ("product", "map_scale", "contour_interval", "terrain", "orthophoto_scale",
              "pixel_size", "working_radius")

# The published rules, in millimetres at the scale of the product (GKINP-02-036-02 as
# quoted by the PHOTOMOD manual; DESIGN.md section 7).
_GCP_XY_MM = 0.2
_CHECK_XY_MM = 0.3
_GCP_Z_FACTOR = 0.15
# (contour interval in m, factor) for check points: 0.2 h for 1 m, 0.25 h for 2.5 m,
# 0.35 h for 5 and 10 m.
_CHECK_Z_TABLE = ((1.0, 0.20), (2.5, 0.25), (5.0, 0.35), (10.0, 0.35))
_DTM_PLANIMETRIC_MM = 0.3
_ORTHO_XY_MM = {"flat": 0.5, "hilly": 0.5, "mountainous": 0.7}
_SEAMLINE_MM = {"flat": 0.7, "hilly": 0.7, "mountainous": 1.0}


# --------------------------------------------------------------------------- spec
def _canonical_product(value: Any) -> str:
    if not isinstance(value, str):
        raise ProjectError(
            f"[qa] product = {value!r} is not a text value",
            f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
            details={"key": "product", "allowed": list(PRODUCTS)},
        )
    canon = " ".join(value.strip().lower().replace("_", " ").replace("-", " ").split())
    if canon not in PRODUCTS:
        raise ProjectError(
            f"[qa] product = {value!r} is not allowed",
            f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
            details={"key": "product", "allowed": list(PRODUCTS)},
        )
    return canon


def _canonical_terrain(value: Any) -> str:
    canon = value.strip().lower() if isinstance(value, str) else value
    if canon not in TERRAINS:
        raise ProjectError(
            f"[qa] terrain = {value!r} is not allowed",
            f"set terrain to one of: {', '.join(repr(t) for t in TERRAINS)}",
            details={"key": "terrain", "allowed": list(TERRAINS)},
        )
    return canon


def _scale_denominator(key: str, value: Any) -> float | None:
    """``2000``, ``2000.0`` or ``"1:2000"`` -> 2000.0; ``None`` stays ``None``."""
    if value is None:
        return None
    mend = f"give {key} as the scale denominator, e.g. 2000 or \"1:2000\" for 1:2000"
    number: Any = value
    if isinstance(value, str):
        text = value.strip().replace(" ", "")
        if ":" in text:
            one, _, den = text.partition(":")
            if one != "1":
                raise ProjectError(f"[qa] {key} = {value!r} is not a map scale", mend,
                                   details={"key": key})
            text = den
        try:
            number = float(text)
        except ValueError:
            raise ProjectError(f"[qa] {key} = {value!r} is not a map scale", mend,
                               details={"key": key}) from None
    if isinstance(number, bool) or not isinstance(number, (int, float, np.integer, np.floating)):
        raise ProjectError(f"[qa] {key} = {value!r} is not a number", mend, details={"key": key})
    number = float(number)
    if not math.isfinite(number) or number <= 1.0:
        raise ProjectError(f"[qa] {key} = {value!r} is not a scale denominator (> 1)", mend,
                           details={"key": key})
    return number


def _positive(key: str, value: Any, unit: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProjectError(f"[qa] {key} = {value!r} is not a number",
                           f"give {key} in {unit}, a positive number", details={"key": key})
    number = float(value)
    if not math.isfinite(number) or number <= 0.0:
        raise ProjectError(f"[qa] {key} = {value!r} must be positive",
                           f"give {key} in {unit}, a positive number", details={"key": key})
    return number


@dataclass
class QASpec:
    """The product specification (``[qa]`` table of the project file).

    Parameters
    ----------
    product : str
        ``"topographic map"``, ``"orthophoto"`` or ``"orthomosaic"``.
    map_scale : float or None
        Scale denominator ``M`` of the map (2000 for 1:2000). Required for a
        topographic map; for an orthophoto/orthomosaic it is used when
        ``orthophoto_scale`` is not given.
    contour_interval : float or None
        Contour interval ``h`` in metres (required for a topographic map).
    terrain : str
        ``"flat"``, ``"hilly"`` or ``"mountainous"`` (orthomosaic tolerances).
    orthophoto_scale : float or None
        Scale denominator of the orthophoto / orthomosaic, if it differs from the map.
    pixel_size : float or None
        Scanning / sensor pixel size (mm) for the pixel-based stages, when the camera
        calibration does not give one (scanned film), e.g. 0.012 for 12 micrometres.
    working_radius : float or None
        Radius ``r`` of the working area on the image (mm) for the orthophoto height
        tolerance ``dh_DTM``; by default the caller derives it from the measurements.

    Raises
    ------
    ProjectError
        For an unknown product or terrain, a non-positive or missing number; the
        message names the ``[qa]`` key and the allowed values.
    """

    product: str
    map_scale: float | None = None
    contour_interval: float | None = None
    terrain: str = "flat"
    orthophoto_scale: float | None = None
    pixel_size: float | None = None
    working_radius: float | None = None

    def __post_init__(self) -> None:
        self.product = _canonical_product(self.product)
        self.terrain = _canonical_terrain(self.terrain)
        self.map_scale = _scale_denominator("map_scale", self.map_scale)
        self.orthophoto_scale = _scale_denominator("orthophoto_scale", self.orthophoto_scale)
        self.contour_interval = _positive("contour_interval", self.contour_interval, "metres")
        self.pixel_size = _positive("pixel_size", self.pixel_size, "millimetres (0.012 = 12 um)")
        if self.pixel_size is not None and self.pixel_size > 1.0:
            raise ProjectError(f"[qa] pixel_size = {self.pixel_size!r} mm is implausibly large",
                               "give pixel_size in millimetres: 12 micrometres is 0.012",
                               details={"key": "pixel_size"})
        self.working_radius = _positive("working_radius", self.working_radius, "millimetres")
        if self.product == "topographic map":
            for key in ("map_scale", "contour_interval"):
                if getattr(self, key) is None:
                    raise ProjectError(
                        f"[qa] {key} is missing (product = 'topographic map' needs it)",
                        "add map_scale (e.g. 2000 for 1:2000) and contour_interval "
                        "(metres) to [qa]",
                        details={"key": key},
                    )
        elif self.map_scale is None and self.orthophoto_scale is None:
            raise ProjectError(
                f"[qa] orthophoto_scale is missing (product = {self.product!r} needs a scale)",
                "add orthophoto_scale (or map_scale), e.g. 2000 for 1:2000, to [qa]",
                details={"key": "orthophoto_scale"},
            )

    @property
    def product_scale(self) -> float:
        """Scale denominator the product's tolerances refer to (orthophoto scale first)."""
        if self.product == "topographic map":
            return float(self.map_scale)  # type: ignore[arg-type]
        return float(self.orthophoto_scale if self.orthophoto_scale is not None
                     else self.map_scale)  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, d: dict) -> QASpec:
        """Build and validate a specification from the ``[qa]`` table.

        Parameters
        ----------
        d : dict
            Keys ``product`` (required), ``map_scale``, ``contour_interval``,
            ``terrain``, ``orthophoto_scale``, ``pixel_size`` (mm), ``working_radius``
            (mm).

        Returns
        -------
        QASpec

        Raises
        ------
        ProjectError
            Unknown key, missing product, or a value :class:`QASpec` rejects.
        """
        if not isinstance(d, dict):
            raise ProjectError("[qa] is not a table",
                               "write [qa] as a TOML table with product = ...")
        unknown = sorted(set(d) - set(_SPEC_KEYS))
        if unknown:
            raise ProjectError(
                f"[qa] has unknown key(s) {', '.join(repr(k) for k in unknown)}",
                f"use only {', '.join(_SPEC_KEYS)}",
                details={"keys": unknown, "allowed": list(_SPEC_KEYS)},
            )
        if "product" not in d:
            raise ProjectError(
                "[qa] product is missing",
                f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
                details={"key": "product", "allowed": list(PRODUCTS)},
            )
        return cls(
            product=d["product"],
            map_scale=d.get("map_scale"),
            contour_interval=d.get("contour_interval"),
            terrain=d.get("terrain", "flat"),
            orthophoto_scale=d.get("orthophoto_scale"),
            pixel_size=d.get("pixel_size"),
            working_radius=d.get("working_radius"),
        )

    def as_dict(self) -> dict:
        """JSON-serialisable copy of the specification."""
        return {
            "product": self.product,
            "map_scale": self.map_scale,
            "contour_interval": self.contour_interval,
            "terrain": self.terrain,
            "orthophoto_scale": self.orthophoto_scale,
            "pixel_size": self.pixel_size,
            "working_radius": self.working_radius,
        }


# ------------------------------------------------------------------- tolerances
@dataclass(frozen=True)
class PixelTolerance:
    """An image-space tolerance, in millimetres and in pixels.

    ``mean_*`` is ``None`` where the rule limits only the maximum.
    """

    max_mm: float
    max_px: float
    mean_mm: float | None = None
    mean_px: float | None = None

    def as_dict(self) -> dict:
        """JSON-serialisable copy."""
        return {"mean_mm": self.mean_mm, "mean_px": self.mean_px,
                "max_mm": self.max_mm, "max_px": self.max_px}


def _pixel(pixel_size_mm: float) -> float:
    p = float(pixel_size_mm)
    if not math.isfinite(p) or p <= 0.0:
        raise ValueError(f"pixel size must be a positive number of mm, got {pixel_size_mm!r}")
    return p


def _scalar_or_array(a: np.ndarray):
    return float(a) if a.ndim == 0 else a


def max_from_mean(mean_tolerance):
    """Limiting (maximum) tolerance from a mean tolerance: ``E_max = 2 E_mean``.

    The instruction's rule ("limiting discrepancies must not exceed twice the mean");
    the relative-orientation rule (mean 0.5 px, max 1 px) is the same rule.
    """
    return _scalar_or_array(2.0 * np.asarray(mean_tolerance, float))


def rms_from_mean(mean_tolerance):
    """RMS tolerance from a mean tolerance: ``RMS = sqrt(2) E_mean`` (manual's rule).

    Notes
    -----
    A rule of thumb, not a distribution identity: for normal errors the ratio
    RMS / mean|e| is ``sqrt(pi/2) = 1.2533`` in one dimension and
    ``2/sqrt(pi) = 1.1284`` for horizontal (Rayleigh) lengths, so ``sqrt(2)`` is
    lenient for an RMS check. Use :func:`check_stage` with ``statistic="mean"`` to
    test the rule as published.
    """
    return _scalar_or_array(math.sqrt(2.0) * np.asarray(mean_tolerance, float))


def mean_from_rms(rms_value):
    """Inverse of :func:`rms_from_mean`: ``E_mean = RMS / sqrt(2)``."""
    return _scalar_or_array(np.asarray(rms_value, float) / math.sqrt(2.0))


def interior_orientation_tolerance(pixel_size_mm: float) -> PixelTolerance:
    """Interior orientation: the largest fiducial residual must not exceed one pixel.

    Parameters
    ----------
    pixel_size_mm : float
        Scanning / sensor pixel size (mm), e.g. 0.012 for 12 micrometres.

    Returns
    -------
    PixelTolerance
        ``max_mm = pixel``, ``max_px = 1``; no mean limit.
    """
    p = _pixel(pixel_size_mm)
    return PixelTolerance(max_mm=p, max_px=1.0)


def relative_orientation_tolerance(pixel_size_mm: float) -> PixelTolerance:
    """Relative orientation: mean |vertical parallax| <= 0.5 px, maximum <= 1 px.

    Parameters
    ----------
    pixel_size_mm : float
        Pixel size (mm).

    Returns
    -------
    PixelTolerance
        ``mean_px = 0.5``, ``max_px = 1`` and the same in millimetres.
    """
    p = _pixel(pixel_size_mm)
    return PixelTolerance(max_mm=p, max_px=1.0, mean_mm=0.5 * p, mean_px=0.5)


def stereo_base_mm(frame_along_track_mm: float, forward_overlap: float = 0.6) -> float:
    """Photo base ``b`` (image scale) from the frame size along track and the overlap.

    ``b = (1 - p) l``: 92 mm for a 230 mm film frame at 60 % forward overlap.
    """
    p = float(forward_overlap)
    if not 0.0 <= p < 1.0:
        raise ValueError(f"forward overlap must be in [0, 1), got {forward_overlap!r}")
    return (1.0 - p) * float(frame_along_track_mm)


def triplet_tolerance(f_mm, base_mm, pixel_size_mm) -> tuple:
    """Acceptable discrepancies of points between adjacent models of a triplet.

    ``E_xy = sqrt(2) * 0.5 pixel`` (two independent half-pixel pointings) and
    ``E_z = (f / b) E_xy`` (a parallax error ``dp`` changes the height by
    ``(f / b) dp`` at image scale).

    Parameters
    ----------
    f_mm : float or array_like
        Focal length (mm).
    base_mm : float or array_like
        Photo base at image scale (mm), see :func:`stereo_base_mm`.
    pixel_size_mm : float or array_like
        Pixel size (mm).

    Returns
    -------
    (E_xy, E_z) : tuple of float or numpy.ndarray
        Millimetres at image scale (multiply by the photo-scale denominator for metres
        on the ground).
    """
    f = np.asarray(f_mm, float)
    b = np.asarray(base_mm, float)
    p = np.asarray(pixel_size_mm, float)
    if np.any(p <= 0) or np.any(b <= 0) or np.any(f <= 0):
        raise ValueError("focal length, base and pixel size must be positive")
    e_xy = math.sqrt(2.0) * 0.5 * p
    e_z = f / b * e_xy
    if e_z.ndim == 0:
        return float(np.broadcast_to(e_xy, e_z.shape)), float(e_z)
    return np.broadcast_to(e_xy, e_z.shape).copy(), e_z


def check_z_factor(contour_interval: float) -> tuple:
    """Check-point height tolerance as a fraction of the contour interval ``h``.

    Published: 0.2 h for h = 1 m, 0.25 h for 2.5 m, 0.35 h for 5 and 10 m.

    Other intervals (not in the instruction; our rule, conservative): the factor of
    the largest published interval not above ``h`` (so 2 m -> 0.2 h, 4 m -> 0.25 h,
    20 m -> 0.35 h), and 0.2 h below 1 m. The tolerance ``factor * h`` is then never
    looser than at the next published interval and never decreases as ``h`` grows.

    Parameters
    ----------
    contour_interval : float
        ``h`` in metres.

    Returns
    -------
    (factor, rule) : (float, str)
        ``rule`` is ``"published"`` or a short explanation of the fallback.
    """
    h = float(contour_interval)
    if not math.isfinite(h) or h <= 0.0:
        raise ValueError(f"contour interval must be positive, got {contour_interval!r}")
    for hp, factor in _CHECK_Z_TABLE:
        if math.isclose(h, hp, rel_tol=1e-9, abs_tol=1e-9):
            return factor, "published"
    if h < _CHECK_Z_TABLE[0][0]:
        return _CHECK_Z_TABLE[0][1], (
            f"h = {h:g} m is below the published intervals (1, 2.5, 5-10 m): 0.2 h as for 1 m"
        )
    lower = [(hp, fac) for hp, fac in _CHECK_Z_TABLE if hp <= h][-1]
    if h > _CHECK_Z_TABLE[-1][0]:
        return lower[1], (
            f"h = {h:g} m is above the published intervals (1, 2.5, 5-10 m): 0.35 h as for 10 m"
        )
    return lower[1], (
        f"h = {h:g} m is not a published interval (1, 2.5, 5-10 m): "
        f"{lower[1]:g} h as for the next smaller one, {lower[0]:g} m"
    )


def orthophoto_dtm_tolerance(f_mm, scale, r_mm) -> tuple:
    """DTM accuracy needed for an orthophoto: ``dh_DTM = 0.3 mm * f * M / r``.

    A height error ``dh`` displaces a point at radial distance ``r`` on the image by
    ``r dh / H`` (image) = ``r dh / f`` on the ground; requiring at most 0.3 mm at
    the orthophoto scale ``1:M`` gives the formula. The block adjustment must then
    hold ``dh_DTM / 3`` in height.

    Parameters
    ----------
    f_mm : float or array_like
        Focal length (mm).
    scale : float or array_like
        Scale denominator ``M`` of the orthophoto (or a :class:`QASpec`, whose
        product scale is used).
    r_mm : float or array_like
        Distance on the image from the nadir (principal) point to the farthest point
        of the working area (mm); the manual uses 134 mm for 23 x 23 cm film.

    Returns
    -------
    (dh_dtm, dh_block) : tuple of float or numpy.ndarray
        Metres: the DTM tolerance and the block-adjustment height tolerance (a third).
    """
    if isinstance(scale, QASpec):
        scale = scale.product_scale
    f = np.asarray(f_mm, float)
    m = np.asarray(scale, float)
    r = np.asarray(r_mm, float)
    if np.any(f <= 0) or np.any(m <= 0) or np.any(r <= 0):
        raise ValueError("focal length, scale and r must be positive")
    dh = _DTM_PLANIMETRIC_MM * 1e-3 * m * f / r
    if dh.ndim == 0:
        return float(dh), float(dh) / 3.0
    return dh, dh / 3.0


def dtm_height_tolerance(spec: QASpec, f_mm: float | None = None,
                         r_mm: float | None = None) -> tuple:
    """Mean-error tolerance of DTM heights at control and check points (m).

    * topographic map: the check points' height rule (:func:`check_z_factor` x h):
      the contours are drawn from the DTM, so its heights must hold what the map's
      heights must hold (our reading; the manual states no separate DTM rule for maps);
    * orthophoto / orthomosaic: ``dh_DTM = 0.3 mm f M / r``
      (:func:`orthophoto_dtm_tolerance`), which needs ``f`` and ``r``.

    A single point is judged against twice the tolerance (``E_max ~ 2 E_mean``).

    Parameters
    ----------
    spec : QASpec
    f_mm, r_mm : float, optional
        Focal length and working-area radius (mm) for orthophotos.

    Returns
    -------
    (tolerance, rule) : (float or None, str)
        None when it cannot be derived (no focal length); ``rule`` says which rule.
    """
    if spec.product == "topographic map":
        h = float(spec.contour_interval)  # type: ignore[arg-type]
        factor, _ = check_z_factor(h)
        return factor * h, f"{factor:g} h (check point heights, h = {h:g} m)"
    if f_mm is None or r_mm is None or not np.isfinite(f_mm):
        return None, "dh_DTM needs a frame camera's focal length"
    dh = orthophoto_dtm_tolerance(f_mm, spec.product_scale, r_mm)[0]
    return dh, f"dh_DTM = 0.3 mm x f x M / r (f = {f_mm:g} mm, r = {r_mm:.1f} mm)"


@dataclass(frozen=True)
class OrthomosaicTolerance:
    """Orthomosaic tolerances at the orthophoto scale (mm on the product, m on the ground)."""

    scale: float
    terrain: str
    xy_mm: float
    seamline_mm: float

    @property
    def xy_m(self) -> float:
        """Mean error of GCP / check points on the orthomosaic (ground metres)."""
        return self.xy_mm * 1e-3 * self.scale

    @property
    def seamline_m(self) -> float:
        """Mismatch of contours along the seamlines (ground metres)."""
        return self.seamline_mm * 1e-3 * self.scale

    def as_dict(self) -> dict:
        """JSON-serialisable copy."""
        return {"scale": self.scale, "terrain": self.terrain, "xy_mm": self.xy_mm,
                "xy_m": self.xy_m, "seamline_mm": self.seamline_mm,
                "seamline_m": self.seamline_m}


def orthomosaic_tolerance(spec: QASpec) -> OrthomosaicTolerance:
    """Orthomosaic: 0.5 mm (flat, hilly) / 0.7 mm (mountainous); seamlines 0.7 / 1.0 mm.

    Parameters
    ----------
    spec : QASpec
        Its orthophoto scale (else map scale) and terrain are used.

    Returns
    -------
    OrthomosaicTolerance
    """
    return OrthomosaicTolerance(scale=spec.product_scale, terrain=spec.terrain,
                                xy_mm=_ORTHO_XY_MM[spec.terrain],
                                seamline_mm=_SEAMLINE_MM[spec.terrain])


@dataclass(frozen=True)
class BlockTolerances:
    """Block-adjustment tolerances on the MEAN error, in ground metres.

    A ``None`` tolerance is not checked (e.g. heights of an orthomosaic). The
    limiting error of a single point is :func:`max_from_mean` of these.
    """

    product: str
    scale: float
    gcp_xy: float | None
    gcp_z: float | None
    check_xy: float | None
    check_z: float | None
    notes: tuple = ()

    def as_dict(self) -> dict:
        """JSON-serialisable copy."""
        return {"product": self.product, "scale": self.scale, "gcp_xy": self.gcp_xy,
                "gcp_z": self.gcp_z, "check_xy": self.check_xy, "check_z": self.check_z,
                "statistic": "mean", "notes": list(self.notes)}


def block_tolerances(
    spec: QASpec,
    focal_length_mm: float | None = None,
    working_radius_mm: float | None = None,
) -> BlockTolerances:
    """Tolerances of the block adjustment on control (GCP) and check points.

    * topographic map: GCP 0.2 mm x M (XY), 0.15 h (Z); check points 0.3 mm x M (XY)
      and :func:`check_z_factor` x h (Z).
    * orthophoto: XY as for a map at the orthophoto scale (0.2 / 0.3 mm; our
      reading: the manual states only the height rule for orthophotos); Z for both
      ``dh_DTM / 3`` (:func:`orthophoto_dtm_tolerance`), which needs the focal length
      and the working-area radius; without them Z is not checked (a note says so).
    * orthomosaic: XY 0.5 / 0.7 mm x M for GCP and check points
      (:func:`orthomosaic_tolerance`); Z as for an orthophoto when ``f`` and ``r``
      are given, else not checked.

    Parameters
    ----------
    spec : QASpec
    focal_length_mm, working_radius_mm : float, optional
        Camera focal length and radius ``r`` of the working area on the image (mm).

    Returns
    -------
    BlockTolerances
        Mean-error tolerances in metres.
    """
    m = spec.product_scale
    notes: list[str] = []
    if spec.product == "topographic map":
        h = float(spec.contour_interval)  # type: ignore[arg-type]
        factor, rule = check_z_factor(h)
        if rule != "published":
            notes.append(rule)
        return BlockTolerances(
            product=spec.product, scale=m,
            gcp_xy=_GCP_XY_MM * 1e-3 * m, gcp_z=_GCP_Z_FACTOR * h,
            check_xy=_CHECK_XY_MM * 1e-3 * m, check_z=factor * h, notes=tuple(notes),
        )
    z: float | None = None
    if focal_length_mm is not None and working_radius_mm is not None:
        z = orthophoto_dtm_tolerance(focal_length_mm, m, working_radius_mm)[1]
    else:
        notes.append("heights not checked: dh_DTM / 3 needs the focal length and the "
                     "working-area radius r")
    if spec.product == "orthophoto":
        gcp_xy, check_xy = _GCP_XY_MM * 1e-3 * m, _CHECK_XY_MM * 1e-3 * m
    else:
        gcp_xy = check_xy = orthomosaic_tolerance(spec).xy_m
    return BlockTolerances(product=spec.product, scale=m, gcp_xy=gcp_xy, gcp_z=z,
                           check_xy=check_xy, check_z=z, notes=tuple(notes))


# ------------------------------------------------------------ measured quantities
def vertical_parallax(xy_left, xy_right, eo_left, eo_right, focal_length: float,
                      principal_point=(0.0, 0.0)) -> np.ndarray:
    """Vertical (y) parallax of conjugate points in the epipolar-normalised pair.

    Both rays are expressed in a frame whose x axis is the air base and whose z axis
    is the mean optical axis made perpendicular to it; then
    ``py = y_n,left - y_n,right`` with ``y_n = -f (d . e2) / (d . e3)``. Rays that
    intersect (coplanar with the base) have ``py = 0`` whatever the attitudes; for
    vertical photos with the base along x, ``py = y_left - y_right``.

    Parameters
    ----------
    xy_left, xy_right : array_like, shape (k, 2)
        Photo coordinates (mm) of the same points on the left and right image.
    eo_left, eo_right : array_like, shape (6,) or (k, 6)
        Exterior orientation ``XL, YL, ZL, omega, phi, kappa`` (m, rad).
    focal_length : float
        Focal length (mm).
    principal_point : (float, float)
        ``x0, y0`` (mm).

    Returns
    -------
    numpy.ndarray, shape (k,)
        Vertical parallax in millimetres at image scale.

    Notes
    -----
    After a bundle adjustment the lead computes parallax from image residuals; this
    function serves relative orientation and checks from measured coordinates.
    """
    xl = np.asarray(xy_left, float)
    xr = np.asarray(xy_right, float)
    el = np.asarray(eo_left, float)
    er = np.asarray(eo_right, float)
    f = float(focal_length)
    x0, y0 = principal_point

    def rays(xy, eo):
        m = rotation_matrix(eo[..., 3], eo[..., 4], eo[..., 5])
        v = np.stack([xy[..., 0] - x0, xy[..., 1] - y0, np.full(xy.shape[:-1], -f)], -1)
        # object-space direction: M^T v ; camera z axis in object space: M^T e_z
        return np.einsum("...ji,...j->...i", m, v), m[..., 2, :]

    dl, zl = rays(xl, el)
    dr, zr = rays(xr, er)
    base = er[..., :3] - el[..., :3]
    e1 = base / np.linalg.norm(base, axis=-1, keepdims=True)
    w = zl + zr
    e3 = w - np.sum(w * e1, axis=-1, keepdims=True) * e1
    e3 = e3 / np.linalg.norm(e3, axis=-1, keepdims=True)
    e2 = np.cross(e3, e1)
    yl = -f * np.sum(dl * e2, -1) / np.sum(dl * e3, -1)
    yr = -f * np.sum(dr * e2, -1) / np.sum(dr * e3, -1)
    return yl - yr


@dataclass(frozen=True)
class ParallaxStats:
    """Mean |py|, RMS and max |py| of a stereo pair, in micrometres and pixels."""

    n: int
    mean_um: float
    rms_um: float
    max_um: float
    mean_px: float
    rms_px: float
    max_px: float

    def as_dict(self) -> dict:
        """JSON-serialisable copy (NaN -> None)."""
        return {k: _json_number(getattr(self, k)) for k in
                ("n", "mean_um", "rms_um", "max_um", "mean_px", "rms_px", "max_px")}


def parallax_stats(py_mm, pixel_size_mm: float) -> ParallaxStats:
    """Statistics of vertical parallax residuals of one stereo pair.

    Parameters
    ----------
    py_mm : array_like, shape (k,)
        Vertical parallaxes (mm, image scale); NaNs are ignored.
    pixel_size_mm : float
        Pixel size (mm).

    Returns
    -------
    ParallaxStats
        Mean of ``|py|``, RMS and maximum of ``|py|`` in micrometres and pixels (NaN
        when there are no values).
    """
    p = _pixel(pixel_size_mm)
    a = np.abs(np.asarray(py_mm, float).ravel())
    a = a[np.isfinite(a)]
    if a.size == 0:
        nan = float("nan")
        return ParallaxStats(0, nan, nan, nan, nan, nan, nan)
    mean, rms, mx = float(a.mean()), float(np.sqrt(np.mean(a * a))), float(a.max())
    return ParallaxStats(int(a.size), mean * 1e3, rms * 1e3, mx * 1e3, mean / p, rms / p, mx / p)


def model_discrepancies(xyz_a, xyz_b, scale) -> tuple:
    """Discrepancies of the same points between two adjacent models, at image scale.

    Parameters
    ----------
    xyz_a, xyz_b : array_like, shape (k, 3)
        Ground (or scaled model) coordinates of the common points of a triplet from
        the first and second model (m).
    scale : float or array_like
        Photo-scale denominator ``m = H / f`` (so that 1 mm on the image is
        ``m / 1000`` m on the ground).

    Returns
    -------
    (e_xy, e_z) : numpy.ndarray, shape (k,) each
        Horizontal length and absolute height discrepancy, in millimetres at image
        scale (compare with :func:`triplet_tolerance`).
    """
    d = np.asarray(xyz_a, float) - np.asarray(xyz_b, float)
    s = np.asarray(scale, float)
    e_xy = np.hypot(d[..., 0], d[..., 1]) / s * 1e3
    e_z = np.abs(d[..., 2]) / s * 1e3
    return e_xy, e_z


# ---------------------------------------------------------------- stage results
def _json_number(x):
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass
class StageResult:
    """The outcome of one accuracy-control stage.

    Attributes
    ----------
    name : str
        Stage name, e.g. ``"block: GCP XY"``.
    tolerance : float
        Tolerance of the stage statistic.
    measured : float
        The statistic (NaN when there were no values).
    statistic : str
        ``"mean"``, ``"rms"`` or ``"max"`` (of the absolute values).
    point_tolerance : float
        Limit for a single point.
    passed : bool or None
        ``None`` when nothing was measured (not evaluated).
    unit : str
    rows : list of dict
        Per point ``{id, value, tolerance, passed}``.
    warnings : list
        Ids of rows that pass with a warning (a tie-point zone with 2 points).
    action : str
        What a failed row asks for: ``"re-measure"`` (its ids are points, listed in
        ``remeasure``) or e.g. ``"add tie points"`` (its ids are zones).
    """

    name: str
    tolerance: float
    measured: float
    statistic: str
    point_tolerance: float
    passed: bool | None
    unit: str = ""
    rows: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    action: str = "re-measure"

    @property
    def status(self) -> str:
        """``"pass"``, ``"fail"`` or ``"n/a"``."""
        return "n/a" if self.passed is None else ("pass" if self.passed else "fail")

    @property
    def failed_ids(self) -> list:
        """Ids of the points over their limit (to re-measure)."""
        return [r["id"] for r in self.rows if r["passed"] is False]

    def as_dict(self) -> dict:
        """JSON-serialisable copy."""
        return {
            "name": self.name,
            "status": self.status,
            "passed": self.passed,
            "statistic": self.statistic,
            "measured": _json_number(self.measured),
            "tolerance": _json_number(self.tolerance),
            "point_tolerance": _json_number(self.point_tolerance),
            "unit": self.unit,
            "failed_ids": list(self.failed_ids),
            "warnings": list(self.warnings),
            "action": self.action,
            "points": [
                {"id": r["id"], "value": _json_number(r["value"]),
                 "tolerance": _json_number(r["tolerance"]), "passed": r["passed"]}
                for r in self.rows
            ],
        }


def check_stage(name: str, values, ids: Sequence | None, tolerance: float,
                statistic: str = "mean", *, point_tolerance: float | None = None,
                unit: str = "") -> StageResult:
    """Judge one stage: its statistic against the tolerance, every point against its limit.

    Parameters
    ----------
    name : str
        Stage name for the report.
    values : array_like, shape (k,)
        Per-point errors; absolute values are used, NaNs ignored (reported as not
        evaluated).
    ids : sequence or None
        Point ids (``None``: ``0..k-1``).
    tolerance : float
        Tolerance of the statistic.
    statistic : {"mean", "rms", "max"}
        Statistic of ``|values|`` compared with ``tolerance``.
    point_tolerance : float, optional
        Limit for a single point. Default: ``2 tolerance`` for a mean
        (``E_max ~ 2 E_mean``), ``sqrt(2) tolerance`` for an RMS (``2 RMS / sqrt 2``),
        ``tolerance`` for a max.
    unit : str
        Unit label of values and tolerances.

    Returns
    -------
    StageResult
        ``passed`` is True when the statistic is within the tolerance AND no point is
        over its limit; ``None`` when there are no finite values.
    """
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {STATISTICS}, got {statistic!r}")
    v = np.abs(np.asarray(values, float).ravel())
    ids = list(range(v.size)) if ids is None else list(ids)
    if len(ids) != v.size:
        raise ValueError(f"{len(ids)} ids for {v.size} values")
    tol = float(tolerance)
    if point_tolerance is None:
        point_tolerance = {"mean": max_from_mean(tol), "rms": math.sqrt(2.0) * tol,
                           "max": tol}[statistic]
    ptol = float(point_tolerance)
    finite = np.isfinite(v)
    if not finite.any():
        measured = float("nan")
    elif statistic == "mean":
        measured = float(v[finite].mean())
    elif statistic == "rms":
        measured = float(np.sqrt(np.mean(v[finite] ** 2)))
    else:
        measured = float(v[finite].max())
    ok = v <= ptol
    rows = [
        {"id": i, "value": float(x), "tolerance": ptol, "passed": (bool(o) if f else None)}
        for i, x, o, f in zip(ids, v.tolist(), ok.tolist(), finite.tolist())
    ]
    if not finite.any():
        passed: bool | None = None
    else:
        passed = bool(measured <= tol) and bool(ok[finite].all())
    return StageResult(name=name, tolerance=tol, measured=measured, statistic=statistic,
                       point_tolerance=ptol, passed=passed, unit=unit, rows=rows)


def parallax_stages(name: str, py_mm, ids: Sequence | None, pixel_size_mm: float) -> list:
    """Relative-orientation stages of one stereo pair: mean |py| <= 0.5 px, max <= 1 px.

    Parameters
    ----------
    name : str
        Pair name, e.g. ``"L-R"``.
    py_mm : array_like, shape (k,)
        Vertical parallaxes (mm).
    ids : sequence or None
        Point ids.
    pixel_size_mm : float

    Returns
    -------
    list of StageResult
        ``relative orientation <name>: mean |py|`` and ``...: max |py|``, in pixels;
        every point is judged against 1 pixel in both.
    """
    p = _pixel(pixel_size_mm)
    tol = relative_orientation_tolerance(p)
    py_px = np.asarray(py_mm, float) / p
    return [
        check_stage(f"relative orientation {name}: mean |py|", py_px, ids, tol.mean_px,
                    "mean", point_tolerance=tol.max_px, unit="px"),
        check_stage(f"relative orientation {name}: max |py|", py_px, ids, tol.max_px,
                    "max", unit="px"),
    ]


@dataclass
class QAVerdict:
    """Overall verdict: every evaluated stage passed. Failing stages come first."""

    passed: bool
    stages: list
    nonconformities: list

    @property
    def remeasure(self) -> list:
        """Ids of all points to re-measure, worst stage first, each once."""
        seen: dict = {}
        for n in self.nonconformities:
            if n.get("action", "re-measure") != "re-measure":
                continue  # zone names, not points
            for i in n["ids"]:
                seen.setdefault(i, None)
        return list(seen)

    def as_dict(self) -> dict:
        """JSON-serialisable copy: verdict, non-conformities first, then all stages."""
        return {
            "verdict": "pass" if self.passed else "fail",
            "passed": self.passed,
            "nonconformities": [dict(n) for n in self.nonconformities],
            "remeasure": self.remeasure,
            "stages": [s.as_dict() for s in self.stages],
        }


def qa_verdict(stages: Sequence[StageResult]) -> QAVerdict:
    """Combine stage results into a verdict with the non-conformities first.

    Parameters
    ----------
    stages : sequence of StageResult

    Returns
    -------
    QAVerdict
        ``passed`` is True when no evaluated stage failed (stages with nothing to
        measure do not fail the block). ``stages`` is reordered: failed, then passed,
        then not evaluated (stable within each group). ``nonconformities`` lists, per
        failed stage, the statistic, its tolerance and the point ids to re-measure
        (worst first).
    """
    order = {"fail": 0, "pass": 1, "n/a": 2}
    ordered = sorted(stages, key=lambda s: order[s.status])
    nonconf = []
    for s in ordered:
        if s.status != "fail":
            continue
        bad = [r for r in s.rows if r["passed"] is False]
        sign = 1.0 if s.statistic == "min" else -1.0  # counts: the fewest first
        bad.sort(key=lambda r: sign * r["value"])
        nonconf.append({
            "stage": s.name,
            "statistic": s.statistic,
            "measured": _json_number(s.measured),
            "tolerance": _json_number(s.tolerance),
            "point_tolerance": _json_number(s.point_tolerance),
            "unit": s.unit,
            "action": s.action,
            "ids": [r["id"] for r in bad],
        })
    passed = not any(s.status == "fail" for s in ordered)
    return QAVerdict(passed=passed, stages=ordered, nonconformities=nonconf)


# --------------------------------------------------------------- control points
_CONTROL_ROLES = {"control": "control", "gcp": "control", "check": "check"}


@dataclass
class ControlPointQA:
    """Per-point QA of control and check points and the four block stages.

    Attributes
    ----------
    ids : list
    roles : list of str
        ``"control"`` or ``"check"``.
    e_xy, e_z : numpy.ndarray
        Horizontal residual length and ``|vertical residual|`` (m).
    tol_xy, tol_z : numpy.ndarray
        The limit applied to each point (m; NaN where not checked).
    passed : numpy.ndarray of bool
        Per point: within both limits (the ``QA`` field of the output layer).
    stages : list of StageResult
        ``block: GCP XY``, ``block: GCP Z``, ``block: check XY``, ``block: check Z``
        (those with points and a tolerance).
    tolerances : BlockTolerances
    """

    ids: list
    roles: list
    e_xy: np.ndarray
    e_z: np.ndarray
    tol_xy: np.ndarray
    tol_z: np.ndarray
    passed: np.ndarray
    stages: list
    tolerances: BlockTolerances

    @property
    def qa_field(self) -> list:
        """``"pass"`` / ``"fail"`` per point, for the control_points layer."""
        return ["pass" if p else "fail" for p in self.passed.tolist()]

    @property
    def failed_ids(self) -> list:
        """Ids of the points that fail (to re-measure)."""
        return [i for i, p in zip(self.ids, self.passed.tolist()) if not p]


def control_point_qa(ids: Sequence, residuals, roles: Sequence[str], spec: QASpec,
                     focal_length_mm: float | None = None,
                     working_radius_mm: float | None = None,
                     point_rule: str = "limit") -> ControlPointQA:
    """Judge every control and check point against its tolerance.

    Parameters
    ----------
    ids : sequence
        Point ids, length ``n``.
    residuals : array_like, shape (n, 3)
        ``adjusted - surveyed`` (control points) or ``intersected - surveyed`` (check
        points), metres. XY uses the horizontal length, Z the absolute value.
    roles : sequence of str
        ``"control"`` (or ``"gcp"``) / ``"check"`` per point.
    spec : QASpec
    focal_length_mm, working_radius_mm : float, optional
        For orthophoto / orthomosaic height tolerances (:func:`block_tolerances`).
    point_rule : {"limit", "mean"}
        ``"limit"`` (default): a point fails over the limiting error, twice the mean
        tolerance (``E_max ~ 2 E_mean``); ``"mean"``: over the mean tolerance itself.

    Returns
    -------
    ControlPointQA

    Raises
    ------
    ControlError
        A role other than control / check (the point is named).
    """
    if point_rule not in ("limit", "mean"):
        raise ValueError(f"point_rule must be 'limit' or 'mean', got {point_rule!r}")
    ids = list(ids)
    res = np.asarray(residuals, float).reshape(-1, 3)
    if len(ids) != res.shape[0] or len(roles) != res.shape[0]:
        raise ValueError(f"{len(ids)} ids, {len(roles)} roles for {res.shape[0]} residuals")
    canon = []
    for pid, role in zip(ids, roles):
        key = str(role).strip().lower()
        if key not in _CONTROL_ROLES:
            raise ControlError(
                f"control point {pid!r} has role {role!r}",
                "set role to 'control' or 'check'",
                details={"point_id": pid, "role": role},
            )
        canon.append(_CONTROL_ROLES[key])
    tol = block_tolerances(spec, focal_length_mm, working_radius_mm)
    is_check = np.array([r == "check" for r in canon], bool)
    e_xy = np.hypot(res[:, 0], res[:, 1])
    e_z = np.abs(res[:, 2])
    scale = 2.0 if point_rule == "limit" else 1.0

    def limit(t):  # no tolerance (None), or none derivable (NaN: no focal length, RPCs)
        return np.nan if t is None or not np.isfinite(t) else scale * t

    tol_xy = np.where(is_check, limit(tol.check_xy), limit(tol.gcp_xy))
    tol_z = np.where(is_check, limit(tol.check_z), limit(tol.gcp_z))
    with np.errstate(invalid="ignore"):
        ok_xy = np.where(np.isnan(tol_xy), True, e_xy <= tol_xy)
        ok_z = np.where(np.isnan(tol_z), True, e_z <= tol_z)
    passed = ok_xy & ok_z

    stages = []
    for label, mask, txy, tz in (("GCP", ~is_check, tol.gcp_xy, tol.gcp_z),
                                 ("check", is_check, tol.check_xy, tol.check_z)):
        if not mask.any():
            continue
        sel_ids = [i for i, m in zip(ids, mask.tolist()) if m]
        for comp, vals, t in (("XY", e_xy[mask], txy), ("Z", e_z[mask], tz)):
            if t is None or not np.isfinite(t):
                continue
            stages.append(check_stage(f"block: {label} {comp}", vals, sel_ids, t, "mean",
                                      point_tolerance=scale * t, unit="m"))
    return ControlPointQA(ids=ids, roles=canon, e_xy=e_xy, e_z=e_z, tol_xy=tol_xy,
                          tol_z=tol_z, passed=passed, stages=stages, tolerances=tol)
