"""The tolerances of each stage, computed from the specification, the camera and the pixel
size: interior and relative orientation, triplets, block, DTM heights, orthophoto and
orthomosaic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vectoradjust.qa.tolerances.product import QASpec

__all__ = [
    "PixelTolerance", "BlockTolerances", "OrthomosaicTolerance",
    "interior_orientation_tolerance", "relative_orientation_tolerance", "triplet_tolerance",
    "stereo_base_mm", "check_z_factor", "block_tolerances", "orthophoto_dtm_tolerance",
    "dtm_height_tolerance", "orthomosaic_tolerance", "max_from_mean", "rms_from_mean",
    "mean_from_rms",
]


# The published rules, in millimetres at the scale of the product (GKINP-02-036-02 as
# quoted by the PHOTOMOD manual; docs/method.md section 7).
_GCP_XY_MM = 0.2



_CHECK_XY_MM = 0.3



_GCP_Z_FACTOR = 0.15



# (contour interval in m, factor) for check points: 0.2 h for 1 m, 0.25 h for 2.5 m,
# 0.35 h for 5 and 10 m.
_CHECK_Z_TABLE = ((1.0, 0.20), (2.5, 0.25), (5.0, 0.35), (10.0, 0.35))



_DTM_PLANIMETRIC_MM = 0.3



_ORTHO_XY_MM = {"flat": 0.5, "hilly": 0.5, "mountainous": 0.7}



_SEAMLINE_MM = {"flat": 0.7, "hilly": 0.7, "mountainous": 1.0}



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

