"""Image coordinate refinement (interior orientation), DESIGN.md section 5.

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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Union

import numpy as np

from vectoradjust.errors import CameraError, MeasurementError
from vectoradjust.sensor.camera import CameraCalibration, brown_distort, brown_undistort

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

#: Mean earth radius (m) used by the earth curvature correction.
EARTH_RADIUS = 6_371_000.0

#: Which corrections :func:`refine` applies unless told otherwise. ``affine`` is used
#: only when an :class:`AffineFit` is passed; ``distortion`` only when the camera has
#: a distortion model. Refraction and earth curvature are off by default (contract).
DEFAULT_CORRECTIONS: dict[str, bool] = {
    "affine": True,
    "principal_point": True,
    "distortion": True,
    "refraction": False,
    "earth_curvature": False,
}

#: The steps in the order they are applied (``pixel_to_photo`` replaces ``affine``
#: for digital frames).
STEPS = (
    "affine",
    "pixel_to_photo",
    "principal_point",
    "distortion",
    "refraction",
    "earth_curvature",
)

PixelSize = Union[float, tuple[float, float], "AffineFit"]


# ============================================================================ affine
@dataclass
class AffineFit:
    """A least-squares 6-parameter affine from measured to calibrated fiducials.

    ``x = a0 + a1 u + a2 v``, ``y = b0 + b1 u + b2 v`` with ``(u, v)`` the measured
    coordinates (pixels: column, row; or comparator mm) and ``(x, y)`` the calibrated
    photo coordinates (mm).

    Attributes
    ----------
    params : numpy.ndarray, shape (6,)
        ``a0, a1, a2, b0, b1, b2``.
    ids : list of str
        Fiducial ids in the order of the arrays below.
    measured, calibrated : numpy.ndarray, shape (n, 2)
        The fiducials as measured and as calibrated (mm).
    residuals : numpy.ndarray, shape (n, 2)
        ``transform(measured) - calibrated`` (mm).
    rms_um : float
        Root mean square of the ``2n`` residual components (micrometres).
    max_um : float
        Largest residual vector length ``|v_i|`` (micrometres).
    sigma0_um : float or None
        ``sqrt(v'v / (2n - 6))`` (micrometres); ``None`` without redundancy.
    rms_px, max_px : float or None
        ``rms_um`` and ``max_um`` in pixels (lengths divided by ``sqrt(sx sy)``) when
        a pixel size is known.
    redundancy : int
        ``2n - 6``; 0 with exactly 3 fiducials (the fit is exact and checks nothing).
    unit : str
        Unit of the measured coordinates: ``"pixel"`` or ``"mm"``.
    pixel_size : tuple of float or None
        ``(sx, sy)`` (mm) used for the pixel figures.
    image_id : str or None
        The image, for messages and reports.
    note : str
        A remark for reports (e.g. "no redundancy").
    """

    params: np.ndarray
    ids: list[str]
    measured: np.ndarray
    calibrated: np.ndarray
    residuals: np.ndarray
    rms_um: float
    max_um: float
    sigma0_um: float | None
    rms_px: float | None
    max_px: float | None
    redundancy: int
    unit: str = "pixel"
    pixel_size: tuple[float, float] | None = None
    image_id: str | None = None
    note: str = ""

    @property
    def matrix(self) -> np.ndarray:
        """Linear part ``[[a1, a2], [b1, b2]]`` (mm per measured unit)."""
        a0, a1, a2, b0, b1, b2 = self.params
        return np.array([[a1, a2], [b1, b2]])

    @property
    def offset(self) -> np.ndarray:
        """Translation ``[a0, b0]`` (mm)."""
        return np.array([self.params[0], self.params[3]])

    @property
    def scale(self) -> tuple[float, float]:
        """Size of one measured unit along the measured axes (mm): ``(|col|, |row|)``.

        For pixel measurements this is the effective pixel size ``(sx, sy)``.
        """
        m = self.matrix
        return (float(np.hypot(m[0, 0], m[1, 0])), float(np.hypot(m[0, 1], m[1, 1])))

    @property
    def worst_fiducial(self) -> str | None:
        """Id of the fiducial with the largest residual (``None`` if all are zero)."""
        lengths = np.hypot(self.residuals[:, 0], self.residuals[:, 1])
        if lengths.size == 0 or not np.any(lengths > 0):
            return None
        return self.ids[int(np.argmax(lengths))]

    def transform(self, xy: Any) -> np.ndarray:
        """Measured coordinates ``(..., 2)`` -> photo coordinates (mm) ``(..., 2)``."""
        xy = _as_xy(xy, "measured coordinates")
        return xy @ self.matrix.T + self.offset

    def inverse_transform(self, xy_mm: Any) -> np.ndarray:
        """Photo coordinates (mm) ``(..., 2)`` -> measured coordinates ``(..., 2)``."""
        xy_mm = _as_xy(xy_mm, "photo coordinates")
        inv = np.linalg.inv(self.matrix)
        return (xy_mm - self.offset) @ inv.T

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (parameters, residuals per fiducial, statistics)."""
        return {
            "image_id": self.image_id,
            "unit": self.unit,
            "params": {
                k: float(v) for k, v in zip(("a0", "a1", "a2", "b0", "b1", "b2"), self.params)
            },
            "fiducials": {
                fid: {"vx_um": float(v[0] * 1000.0), "vy_um": float(v[1] * 1000.0)}
                for fid, v in zip(self.ids, self.residuals)
            },
            "rms_um": self.rms_um,
            "max_um": self.max_um,
            "sigma0_um": self.sigma0_um,
            "rms_px": self.rms_px,
            "max_px": self.max_px,
            "redundancy": self.redundancy,
            "note": self.note,
        }


def fit_fiducial_affine(
    measured: Any,
    calibrated: Any,
    pixel_size: float | tuple[float, float] | None = None,
    *,
    unit: str = "pixel",
    image_id: str | None = None,
) -> AffineFit:
    """Fit the 6-parameter affine from measured to calibrated fiducials by least squares.

    Parameters
    ----------
    measured : mapping or array_like
        ``{fiducial id: (u, v)}`` as measured (pixels: column, row with the row axis
        pointing down; or comparator mm), or an ``(n, 2)`` array in the same order
        as ``calibrated``.
    calibrated : mapping, array_like or CameraCalibration
        ``{fiducial id: (x, y)}`` in mm (the calibration report), an ``(n, 2)``
        array, or a camera whose ``fiducials`` are used.
    pixel_size : float or (float, float), optional
        Pixel size (mm) for the residuals in pixels; default the camera's.
    unit : {"pixel", "mm"}
        Unit of ``measured``.
    image_id : str, optional
        Names the image in messages.

    Returns
    -------
    AffineFit

    Raises
    ------
    CameraError
        Fewer than 3 fiducials, a measured id the calibration does not have, a camera
        without calibrated fiducials, collinear or non-finite fiducials.
    """
    img = _image_label(image_id)
    unit = _check_unit(unit, img)
    if isinstance(calibrated, CameraCalibration):
        if pixel_size is None:
            pixel_size = calibrated.pixel_size
        if calibrated.fiducials is None:
            raise CameraError(
                f"{img}: fiducials are measured but the camera has no calibrated fiducials",
                "Add [camera.fiducials] (id = [x, y] in mm from the calibration report)",
                details={"image_id": image_id, "key": "fiducials"},
            )
        calibrated = calibrated.fiducials
    uv, xy, ids = _fiducial_pairs(measured, calibrated, img, image_id)
    _check_fiducials(uv, xy, ids, img, image_id)
    n = len(ids)
    params, v = _solve_affine(uv, xy, ids, img, image_id)
    redundancy = 2 * n - 6
    vtv = float(np.sum(v * v))
    rms_um = float(np.sqrt(vtv / (2 * n))) * 1000.0
    max_um = float(np.max(np.hypot(v[:, 0], v[:, 1]))) * 1000.0
    sigma0_um = float(np.sqrt(vtv / redundancy)) * 1000.0 if redundancy > 0 else None
    ps = _pixel_pair(pixel_size, img) if pixel_size is not None else None
    if ps is not None:
        p = float(np.sqrt(ps[0] * ps[1]))
        rms_px, max_px = rms_um / 1000.0 / p, max_um / 1000.0 / p
    else:
        rms_px = max_px = None
    note = ""
    if redundancy == 0:
        note = (
            "exactly 3 fiducials: the affine fits them exactly (no redundancy); the "
            "residuals are zero and do not check the interior orientation"
        )
    return AffineFit(
        params=params,
        ids=ids,
        measured=uv,
        calibrated=xy,
        residuals=v,
        rms_um=rms_um,
        max_um=max_um,
        sigma0_um=sigma0_um,
        rms_px=rms_px,
        max_px=max_px,
        redundancy=redundancy,
        unit=unit,
        pixel_size=ps,
        image_id=image_id,
        note=note,
    )


def _fiducial_pairs(measured: Any, calibrated: Any, img: str,
                    image_id: str | None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Measured and calibrated fiducials as matching ``(n, 2)`` arrays, and their ids."""
    if isinstance(measured, Mapping):
        if not isinstance(calibrated, Mapping):
            raise TypeError("measured fiducials given by id need calibrated fiducials by id")
        cal = {str(k): v for k, v in calibrated.items()}
        ids = [str(k) for k in measured]
        unknown = [i for i in ids if i not in cal]
        if unknown:
            raise CameraError(
                f"{img}: measured fiducial id(s) {', '.join(repr(i) for i in unknown)} "
                f"are not in the calibration (which has {', '.join(repr(i) for i in cal)})",
                "Name the measured fiducials with the ids of the calibration report",
                details={"image_id": image_id, "fiducials": unknown},
            )
        uv = np.array([_pair_of(measured[k], f"{img}, fiducial {k}") for k in measured], float)
        xy = np.array([_pair_of(cal[i], f"calibrated fiducial {i}") for i in ids], float)
    else:
        uv = _as_xy(measured, f"{img}: measured fiducials").reshape(-1, 2)
        xy = _as_xy(calibrated, "calibrated fiducials").reshape(-1, 2)
        if uv.shape != xy.shape:
            raise CameraError(
                f"{img}: {len(uv)} measured but {len(xy)} calibrated fiducials",
                "Give the measured and calibrated fiducials in the same order",
                details={"image_id": image_id},
            )
        ids = [str(i) for i in range(len(uv))]
    return uv, xy, ids


def _check_fiducials(uv: np.ndarray, xy: np.ndarray, ids: list[str], img: str,
                     image_id: str | None) -> None:
    """Raise unless there are at least 3 fiducials with finite coordinates."""
    n = len(ids)
    if n < 3:
        raise CameraError(
            f"{img}: only {n} fiducial(s) measured"
            + (f" ({', '.join(ids)})" if ids else ""),
            "The 6-parameter affine needs at least 3 fiducials; measure 4 or more so "
            "that the fit is checked",
            details={"image_id": image_id, "count": n},
        )
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(xy))):
        raise CameraError(
            f"{img}: a fiducial coordinate is not a finite number",
            "Check the fiducial measurements",
            details={"image_id": image_id},
        )


def _solve_affine(uv: np.ndarray, xy: np.ndarray, ids: list[str], img: str,
                  image_id: str | None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine ``uv -> xy``: parameters (a0, a1, a2, b0, b1, b2), residuals."""
    n = len(ids)
    # Centre the measured coordinates for conditioning (pixel values are large).
    mean = uv.mean(axis=0)
    d = uv - mean
    sv = np.linalg.svd(d, compute_uv=False)
    if sv[-1] <= 1e-9 * max(sv[0], 1e-300):
        raise CameraError(
            f"{img}: the measured fiducials {', '.join(ids)} lie on one line",
            "Measure fiducials that span the image (corners and/or side midpoints)",
            details={"image_id": image_id},
        )
    design = np.column_stack([np.ones(n), d])
    coef, *_ = np.linalg.lstsq(design, xy, rcond=None)  # (3, 2): columns for x and y
    lin = coef[1:].T  # [[a1, a2], [b1, b2]]
    off = coef[0] - lin @ mean
    params = np.array([off[0], lin[0, 0], lin[0, 1], off[1], lin[1, 0], lin[1, 1]])
    fitted = uv @ lin.T + off
    v = fitted - xy
    return params, v


def interior_orientation_check(
    fit: AffineFit,
    pixel_size: float | tuple[float, float] | None = None,
    tolerance_px: float = 1.0,
) -> dict[str, Any]:
    """Interior orientation accuracy control: largest fiducial residual <= 1 pixel.

    DESIGN.md section 7 (PHOTOMOD, after CNIIGAIK 2002).

    Parameters
    ----------
    fit : AffineFit
    pixel_size : float or (float, float), optional
        Pixel size (mm); default the fit's, else (pixel measurements) the affine's
        scale. Lengths are divided by ``sqrt(sx sy)``.
    tolerance_px : float
        The tolerance in pixels (1 by default).

    Returns
    -------
    dict
        ``image_id``, ``max_residual_px``, ``max_residual_um``, ``rms_um``,
        ``tolerance_px``, ``passed`` (``None`` when 3 fiducials leave no redundancy:
        nothing was checked), ``redundancy``, ``worst_fiducial``, ``note``.

    Raises
    ------
    CameraError
        When no pixel size is known (comparator measurements in mm and none given).
    """
    img = _image_label(fit.image_id)
    if pixel_size is not None:
        ps = _pixel_pair(pixel_size, img)
    elif fit.pixel_size is not None:
        ps = fit.pixel_size
    elif fit.unit == "pixel":
        ps = fit.scale
    else:
        raise CameraError(
            f"{img}: the interior orientation check needs the pixel size",
            "Give pixel_size in [camera] (mm)",
            details={"image_id": fit.image_id, "key": "pixel_size"},
        )
    p = float(np.sqrt(ps[0] * ps[1]))
    max_px = fit.max_um / 1000.0 / p
    passed: bool | None = None if fit.redundancy == 0 else bool(max_px <= tolerance_px)
    return {
        "image_id": fit.image_id,
        "max_residual_px": float(max_px),
        "max_residual_um": float(fit.max_um),
        "rms_um": float(fit.rms_um),
        "tolerance_px": float(tolerance_px),
        "passed": passed,
        "redundancy": int(fit.redundancy),
        "worst_fiducial": fit.worst_fiducial,
        "note": fit.note,
    }


# ============================================================================ pixels
def pixel_to_photo(
    cols_rows: Any,
    pixel_size: float | tuple[float, float],
    image_size: tuple[int, int],
    *,
    origin: str = "center",
) -> np.ndarray:
    """Pixel coordinates of a digital frame -> photo coordinates (mm) about the image centre.

    Parameters
    ----------
    cols_rows : array_like, shape (..., 2)
        Column and row (the row axis points down).
    pixel_size : float or (float, float)
        ``(sx, sy)`` in mm.
    image_size : (int, int)
        ``(columns, rows)``.
    origin : {"center", "corner"}
        ``"center"``: integer coordinates are pixel centres, the centre of the
        top-left pixel is (0, 0) and the image centre is ``((cols-1)/2, (rows-1)/2)``.
        ``"corner"``: (0, 0) is the top-left corner of the top-left pixel (GDAL), the
        image centre is ``(cols/2, rows/2)``.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        ``x = (c - cc) sx`` (right), ``y = (rc - r) sy`` (up), mm about the image
        centre (the digital analogue of the fiducial centre). The principal point is
        reduced afterwards by :func:`refine`.
    """
    cr = _as_xy(cols_rows, "pixel coordinates")
    sx, sy = _pixel_pair(pixel_size, "pixel_to_photo")
    cc, rc = _image_centre(image_size, origin)
    return np.stack([(cr[..., 0] - cc) * sx, (rc - cr[..., 1]) * sy], axis=-1)


def photo_to_pixel(
    xy: Any,
    pixel_size: float | tuple[float, float],
    image_size: tuple[int, int],
    *,
    origin: str = "center",
) -> np.ndarray:
    """Inverse of :func:`pixel_to_photo`: photo mm about the image centre -> (column, row)."""
    xy = _as_xy(xy, "photo coordinates")
    sx, sy = _pixel_pair(pixel_size, "photo_to_pixel")
    cc, rc = _image_centre(image_size, origin)
    return np.stack([cc + xy[..., 0] / sx, rc - xy[..., 1] / sy], axis=-1)


def _image_centre(image_size: tuple[int, int], origin: str) -> tuple[float, float]:
    cols, rows = image_size
    origin = str(origin).lower()
    if origin == "center":
        return (cols - 1) / 2.0, (rows - 1) / 2.0
    if origin == "corner":
        return cols / 2.0, rows / 2.0
    raise CameraError(f"unknown pixel origin {origin!r}", "Use 'center' or 'corner'")


def sigma_pixels_to_mm(sigma_px: Any, pixel_size: PixelSize) -> float | np.ndarray:
    """Convert image-coordinate sigmas from pixels to millimetres.

    Parameters
    ----------
    sigma_px : float or array_like
        Sigma(s) in pixels (>= 0).
    pixel_size : float, (float, float) or AffineFit
        Pixel size in mm; a pair ``(sx, sy)`` or an affine fit (its scale) gives
        per-axis sigmas.

    Returns
    -------
    float or numpy.ndarray
        With a scalar pixel size: same shape as ``sigma_px``. With a pair or a fit:
        shape ``sigma_px.shape + (2,)`` holding ``(sigma_x, sigma_y)`` in mm.

    Raises
    ------
    MeasurementError
        For a negative or non-finite sigma.
    """
    s = np.asarray(sigma_px, float)
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise MeasurementError(
            f"image coordinate sigma {sigma_px!r} (pixels) is negative or not a number",
            "Give a positive sigma in pixels",
        )
    if isinstance(pixel_size, AffineFit):
        sx, sy = pixel_size.scale
        scalar = False
    elif np.ndim(pixel_size) == 0:
        sx = sy = _pixel_pair(pixel_size, "sigma conversion")[0]
        scalar = True
    else:
        sx, sy = _pixel_pair(pixel_size, "sigma conversion")
        scalar = False
    if scalar:
        out = s * sx
        return float(out) if out.ndim == 0 else out
    return s[..., None] * np.array([sx, sy])


# ============================================================================ lens
def smac_correction(xy: Any, xp: float, yp: float, K: Any, P: Any = ()) -> tuple:
    """SMAC (USGS) lens distortion formula: radial plus decentering terms.

    With ``xb = x - xp``, ``yb = y - yp``, ``r^2 = xb^2 + yb^2``:
    ``dx = xb (K0 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8)
    + (1 + P3 r^2 + P4 r^4) [P1 (r^2 + 2 xb^2) + 2 P2 xb yb]`` and
    ``dy = yb (K0 + ...) + (1 + P3 r^2 + P4 r^4) [2 P1 xb yb + P2 (r^2 + 2 yb^2)]``.
    In the USGS convention the corrected coordinate (relative to ``(xp, yp)``) is
    ``(xb + dx, yb + dy)``.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Measured photo coordinates (mm).
    xp, yp : float
        Centre of symmetry (mm), in the frame of ``xy``.
    K : sequence of up to 5 floats
        ``K0..K4`` (missing trailing ones are zero); units mm^-(2i) for ``Ki``.
    P : sequence of up to 4 floats
        ``P1..P4``.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``dx, dy`` (mm), each of shape ``xy.shape[:-1]``.
    """
    xy = _as_xy(xy, "photo coordinates")
    K = _padded(K, 5, "K")
    P = _padded(P, 4, "P")
    xb = xy[..., 0] - xp
    yb = xy[..., 1] - yp
    r2 = xb * xb + yb * yb
    radial = K[0] + r2 * (K[1] + r2 * (K[2] + r2 * (K[3] + r2 * K[4])))
    ddx, ddy = _decentering(xb, yb, r2, P)
    return xb * radial + ddx, yb * radial + ddy


def radial_polynomial_correction(xy: Any, xp: float, yp: float, k: Any, P: Any = ()) -> tuple:
    """Odd radial polynomial ``dr = k1 r^3 + k2 r^5 + k3 r^7 + k4 r^9`` (plus decentering).

    ``dx = xb dr / r``, ``dy = yb dr / r`` with ``xb = x - xp``; decentering ``P1..P4``
    as in :func:`smac_correction`. The sign convention is the camera's (see
    :mod:`vectoradjust.sensor.camera`).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``dx, dy`` (mm).
    """
    k = _padded(k, 4, "k")
    return smac_correction(xy, xp, yp, np.concatenate([[0.0], k]), P)


def decentering_correction(xy: Any, xp: float, yp: float, P: Any) -> tuple:
    """Decentering terms of :func:`smac_correction` alone: ``(dx, dy)`` in mm."""
    xy = _as_xy(xy, "photo coordinates")
    xb = xy[..., 0] - xp
    yb = xy[..., 1] - yp
    return _decentering(xb, yb, xb * xb + yb * yb, _padded(P, 4, "P"))


def _decentering(xb, yb, r2, P):
    factor = 1.0 + r2 * (P[2] + r2 * P[3])
    dx = factor * (P[0] * (r2 + 2.0 * xb * xb) + 2.0 * P[1] * xb * yb)
    dy = factor * (2.0 * P[0] * xb * yb + P[1] * (r2 + 2.0 * yb * yb))
    return dx, dy


def _padded(values: Any, n: int, name: str) -> np.ndarray:
    a = np.atleast_1d(np.asarray(values, float)).ravel()
    if a.size > n:
        raise ValueError(f"at most {n} {name} coefficients, got {a.size}")
    out = np.zeros(n)
    out[: a.size] = a
    return out


# ============================================================================ atmosphere
def ardc_k(H_km: Any, h_km: Any) -> float | np.ndarray:
    """ARDC 1959 model atmosphere refraction constant ``K`` (radians).

    ``K = [2410 H / (H^2 - 6 H + 250) - 2410 h^2 / ((h^2 - 6 h + 250) H)] 1e-6``.

    Parameters
    ----------
    H_km : float or array_like
        Flying height above sea level (km).
    h_km : float or array_like
        Terrain height above sea level (km); broadcast against ``H_km``.

    Returns
    -------
    float or numpy.ndarray
        ``K`` in radians (``K(3, 0.3) = 29.7088e-6``).

    Raises
    ------
    CameraError
        When a flying height is not above the terrain, or a value is not finite.
    """
    H, h = np.broadcast_arrays(np.asarray(H_km, float), np.asarray(h_km, float))
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(h))):
        raise CameraError(
            "the flying height or terrain height for the refraction correction is not a number",
            "Check the image positions and the terrain height",
        )
    bad = H <= h
    if np.any(bad):
        i = np.flatnonzero(bad.ravel())[0]
        raise CameraError(
            f"flying height {H.ravel()[i] * 1000.0:.1f} m is not above the terrain height "
            f"{h.ravel()[i] * 1000.0:.1f} m",
            "Heights are above sea level in metres: check ZL of the image and the terrain",
        )
    if np.any(H <= 0):
        raise CameraError(
            "flying height must be above sea level for the ARDC refraction model",
            "Check ZL of the images",
        )
    k = (2410.0 * H / (H * H - 6.0 * H + 250.0) - 2410.0 * h * h / ((h * h - 6.0 * h + 250.0) * H))
    k = k * 1e-6
    return float(k) if k.ndim == 0 else k


def refraction_correction(xy: Any, f: float, H_m: Any, h_m: Any) -> np.ndarray:
    """Correct photo coordinates for atmospheric refraction (ARDC model).

    ``dr = K (r + r^3 / f^2)``, ``x' = x (1 - dr / r)``, ``y' = y (1 - dr / r)``:
    refraction displaces images outward, the correction moves them inward.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Photo coordinates (mm) relative to the principal point.
    f : float
        Focal length (mm).
    H_m : float or array_like, shape (...)
        Flying height above sea level (m), one per point allowed (each image's own).
    h_m : float or array_like
        Terrain height above sea level (m).

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Corrected coordinates (mm).
    """
    xy = _as_xy(xy, "photo coordinates")
    k = np.asarray(ardc_k(np.asarray(H_m, float) / 1000.0, np.asarray(h_m, float) / 1000.0))
    r2 = np.sum(xy * xy, axis=-1)
    scale = 1.0 - k * (1.0 + r2 / (f * f))
    return xy * scale[..., None]


def earth_curvature_correction(
    xy: Any, f: float, height_above_ground: Any, R: float = EARTH_RADIUS
) -> np.ndarray:
    """Correct photo coordinates for earth curvature (map-projection ground frame).

    ``dr = r^3 H' / (2 R f^2)``. In a map projection the terrain curves away below the
    tangent plane by ``D^2 / (2R)`` at ground distance ``D``, so its images lie closer
    to the centre than a flat-earth collinearity predicts; the correction moves them
    outward: ``x' = x (1 + dr / r)``.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Photo coordinates (mm) relative to the principal point.
    f : float
        Focal length (mm).
    height_above_ground : float or array_like, shape (...)
        ``H'`` flying height above the terrain (m), one per point allowed.
    R : float
        Earth radius (m).

    Returns
    -------
    numpy.ndarray, shape (..., 2)
    """
    xy = _as_xy(xy, "photo coordinates")
    hag = np.asarray(height_above_ground, float)
    if not np.all(np.isfinite(hag)) or np.any(hag <= 0):
        raise CameraError(
            "the flying height above ground for the earth curvature correction is not "
            "positive",
            "Check ZL of the images and the terrain height",
        )
    r2 = np.sum(xy * xy, axis=-1)
    scale = 1.0 + r2 * hag / (2.0 * R * f * f)
    return xy * scale[..., None]


# ============================================================================ the chain
class RefineResult(NamedTuple):
    """Refined coordinates and what was done to them.

    Attributes
    ----------
    xy : numpy.ndarray, shape (..., 2)
        Refined photo coordinates (mm).
    summary : dict
        ``image_id``, ``input_unit``, ``corrections`` (per step: ``applied``,
        ``max_um`` = largest size of that step's change in micrometres, ``None`` for
        unit conversions), ``applied`` (step names in order) and ``principal_point``
        (the ``(x0, y0)`` the collinearity equations must use with ``xy``: ``(0, 0)``
        when the principal point was reduced here).
    """

    xy: np.ndarray
    summary: dict


class _Chain:
    """The resolved refinement chain of one image (shared by refine and distort)."""

    def __init__(
        self,
        camera: Any,
        affine: AffineFit | None,
        unit: str,
        flying_height: Any,
        terrain_height: Any,
        corrections: Mapping[str, bool] | None,
        image_id: str | None,
        shape: tuple[int, ...],
    ) -> None:
        self.img = _image_label(image_id)
        self.image_id = image_id
        self.cam = _as_calibration(camera)
        self.unit = _check_unit(unit, self.img)
        sw = _switches(corrections, self.img)
        self.affine = affine if (affine is not None and sw["affine"]) else None
        if self.affine is not None and self.affine.unit != self.unit:
            raise CameraError(
                f"{self.img}: the fiducial affine was fitted to {self.affine.unit} "
                f"measurements but the image coordinates are in {self.unit}",
                "Measure fiducials and points in the same unit",
                details={"image_id": image_id},
            )
        self.digital = self.affine is None and self.unit == "pixel"
        if self.digital:
            missing = [
                k for k in ("pixel_size", "image_size") if getattr(self.cam, k) is None
            ]
            if missing:
                raise CameraError(
                    f"{self.img}: image coordinates are in pixels but there are no fiducial "
                    f"measurements for it and the camera has no {' and no '.join(missing)}",
                    f"Measure at least 3 fiducials of {self.img} (4 or more for a check), or "
                    "for a digital frame give pixel_size (mm) and image_size [columns, rows] "
                    "in [camera]",
                    details={"image_id": image_id, "keys": missing},
                )
        self.pp_applied = sw["principal_point"]
        pp = np.array(self.cam.principal_point, float)
        self.pp = pp if self.pp_applied else np.zeros(2)
        self.dist_applied = sw["distortion"] and self.cam.has_distortion
        self.center = np.array(self.cam.symmetry_center, float) - self.pp
        self.refr_applied = sw["refraction"]
        self.curv_applied = sw["earth_curvature"]
        self.H = self.h = None
        if self.refr_applied or self.curv_applied:
            need = [
                name
                for name, val in (
                    ("refraction", sw["refraction"]),
                    ("earth curvature", sw["earth_curvature"]),
                )
                if val
            ]
            if flying_height is None or terrain_height is None:
                raise CameraError(
                    f"{self.img}: the {' and '.join(need)} correction needs the flying height "
                    "and the terrain height",
                    "Give the image's approximate position (ZL, m above sea level) and the "
                    "mean terrain height, or switch the correction off in [corrections]",
                    details={"image_id": image_id},
                )
            try:
                self.H = np.broadcast_to(np.asarray(flying_height, float), shape)
                self.h = np.broadcast_to(np.asarray(terrain_height, float), shape)
            except ValueError:
                raise CameraError(
                    f"{self.img}: flying_height/terrain_height do not match the {shape} points",
                    "Give one value per image or one per point",
                ) from None
        self.f = self.cam.focal_length

    # -- forward steps (measured -> refined) --------------------------------------
    def to_photo(self, xy: np.ndarray) -> np.ndarray:
        if self.affine is not None:
            return self.affine.transform(xy)
        if self.digital:
            return pixel_to_photo(
                xy, self.cam.pixel_size, self.cam.image_size, origin=self.cam.pixel_origin
            )
        return xy

    def lens(self, xy: np.ndarray) -> np.ndarray:
        if self.cam.distortion_model == "brown":  # its formula is the distortion: inverted
            try:
                return brown_undistort(xy, self.f, self.cam.brown_coefficients, self.center)
            except CameraError as exc:
                raise CameraError(f"{self.img}: {exc.what}", exc.mend,
                                  details={**(exc.details or {}), "image_id": self.image_id}
                                  ) from None
        dx, dy = smac_correction(
            xy,
            self.center[0],
            self.center[1],
            self.cam.radial_coefficients,
            self.cam.decentering_coefficients,
        )
        return xy + self.cam.distortion_sign * np.stack([dx, dy], axis=-1)

    def refraction(self, xy: np.ndarray) -> np.ndarray:
        return refraction_correction(xy, self.f, self.H, self.h)

    def curvature(self, xy: np.ndarray) -> np.ndarray:
        return earth_curvature_correction(xy, self.f, self.H - self.h)

    # -- inverse steps ---------------------------------------------------------------
    def from_photo(self, xy: np.ndarray) -> np.ndarray:
        if self.affine is not None:
            return self.affine.inverse_transform(xy)
        if self.digital:
            return photo_to_pixel(
                xy, self.cam.pixel_size, self.cam.image_size, origin=self.cam.pixel_origin
            )
        return xy


def refine(
    xy: Any,
    camera: Any,
    *,
    affine: AffineFit | None = None,
    unit: str = "mm",
    flying_height: Any = None,
    terrain_height: Any = None,
    corrections: Mapping[str, bool] | None = None,
    image_id: str | None = None,
) -> RefineResult:
    """Refine the measured image coordinates of one image.

    Order: affine (or pixel_to_photo) -> principal point -> lens distortion ->
    atmospheric refraction -> earth curvature.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Measured coordinates: pixels (column, row) with ``unit="pixel"``, or mm.
    camera : CameraCalibration or object with ``focal_length``/``principal_point``
        A :class:`vectoradjust.model.Camera` is accepted too; its ``calibration``
        (a CameraCalibration or the raw ``[camera]`` table) is used when present.
    affine : AffineFit, optional
        The image's fiducial affine (:func:`fit_fiducial_affine`).
    unit : {"mm", "pixel"}
        Unit of ``xy``. Pixels need either ``affine`` or the camera's ``pixel_size``
        and ``image_size`` (digital frame).
    flying_height : float or array_like, shape (...)
        Flying height above sea level (m): the image's ZL, or one per point.
        Needed by refraction and earth curvature.
    terrain_height : float or array_like
        Mean terrain height above sea level (m).
    corrections : mapping, optional
        Switches overriding :data:`DEFAULT_CORRECTIONS` (keys ``affine``,
        ``principal_point``, ``distortion``, ``refraction``, ``earth_curvature``). The
        caller switches earth curvature on only for a map-projection ground frame.
    image_id : str, optional
        Names the image in messages and in the summary.

    Returns
    -------
    RefineResult
        ``(xy, summary)``; see :class:`RefineResult`.

    Raises
    ------
    CameraError
        Pixel measurements without an affine or a pixel size, unknown switches,
        a correction that lacks its heights, an affine fitted in another unit.
    """
    xy = _as_xy(xy, f"{_image_label(image_id)}: image coordinates")
    ch = _Chain(
        camera, affine, unit, flying_height, terrain_height, corrections, image_id, xy.shape[:-1]
    )
    steps: dict[str, dict[str, Any]] = {s: {"applied": False, "max_um": None} for s in STEPS}

    def size(a: np.ndarray, b: np.ndarray) -> float:
        if a.size == 0:
            return 0.0
        d = a - b
        return float(np.max(np.hypot(d[..., 0], d[..., 1]))) * 1000.0

    out = ch.to_photo(xy)
    if ch.affine is not None:
        steps["affine"] = {
            "applied": True,
            "max_um": None if ch.unit == "pixel" else size(out, xy),
        }
    elif ch.digital:
        steps["pixel_to_photo"] = {"applied": True, "max_um": None}
    if ch.pp_applied:
        new = out - ch.pp
        steps["principal_point"] = {"applied": True, "max_um": size(new, out)}
        out = new
    if ch.dist_applied:
        new = ch.lens(out)
        steps["distortion"] = {
            "applied": True,
            "max_um": size(new, out),
            "model": ch.cam.distortion_model,
        }
        out = new
    if ch.refr_applied:
        new = ch.refraction(out)
        k = np.asarray(ardc_k(ch.H / 1000.0, ch.h / 1000.0))
        steps["refraction"] = {
            "applied": True,
            "max_um": size(new, out),
            "K_urad": float(np.max(k)) * 1e6 if k.size else None,
        }
        out = new
    if ch.curv_applied:
        new = ch.curvature(out)
        steps["earth_curvature"] = {"applied": True, "max_um": size(new, out)}
        out = new
    summary = {
        "image_id": image_id,
        "input_unit": ch.unit,
        "corrections": steps,
        "applied": [s for s in STEPS if steps[s]["applied"]],
        "principal_point": (0.0, 0.0) if ch.pp_applied else tuple(ch.cam.principal_point),
    }
    return RefineResult(out, summary)


def distort(
    xy_true: Any,
    camera: Any,
    *,
    affine: AffineFit | None = None,
    unit: str = "mm",
    flying_height: Any = None,
    terrain_height: Any = None,
    corrections: Mapping[str, bool] | None = None,
    image_id: str | None = None,
    tol: float = 1e-11,
    max_iter: int = 100,
) -> np.ndarray:
    """Inverse of :func:`refine`: ideal photo coordinates -> what would be measured.

    For simulation: ideal coordinates (as :func:`refine` returns them, i.e. relative
    to the principal point when it is reduced) are given earth curvature, refraction
    and lens distortion, shifted by the principal point and mapped through the
    inverse affine (or to pixels), so that ``refine(distort(x)) == x``. The
    non-linear steps are inverted by fixed-point iteration to ``tol`` (mm).

    Parameters
    ----------
    xy_true : array_like, shape (..., 2)
        Ideal photo coordinates (mm).
    camera, affine, unit, flying_height, terrain_height, corrections, image_id
        As for :func:`refine` (``unit`` is the unit of the returned measurements).
    tol : float
        Convergence tolerance of each inversion (mm).
    max_iter : int
        Iteration limit of each inversion.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Measured coordinates (pixels or mm).

    Raises
    ------
    CameraError
        As :func:`refine`, or when a correction is too strong to be inverted.
    """
    xy = _as_xy(xy_true, f"{_image_label(image_id)}: photo coordinates")
    ch = _Chain(
        camera, affine, unit, flying_height, terrain_height, corrections, image_id, xy.shape[:-1]
    )
    out = xy
    if ch.curv_applied:
        out = _invert(ch.curvature, out, tol, max_iter, "earth curvature", ch.img)
    if ch.refr_applied:
        out = _invert(ch.refraction, out, tol, max_iter, "refraction", ch.img)
    if ch.dist_applied and ch.cam.distortion_model == "brown":  # the forward model itself
        out = brown_distort(out, ch.f, ch.cam.brown_coefficients, ch.center)
    elif ch.dist_applied:
        out = _invert(ch.lens, out, tol, max_iter, "lens distortion", ch.img)
    if ch.pp_applied:
        out = out + ch.pp
    return ch.from_photo(out)


def _invert(
    forward: Callable[[np.ndarray], np.ndarray],
    target: np.ndarray,
    tol: float,
    max_iter: int,
    what: str,
    img: str,
) -> np.ndarray:
    """Solve ``forward(m) = target`` for ``m`` by ``m <- m + (target - forward(m))``.

    Converges when the Jacobian of ``forward`` is close to the identity, as it is for
    every correction here (they change coordinates by parts per thousand at most).
    """
    m = target.copy()
    for _ in range(max_iter):
        res = target - forward(m)
        if res.size == 0 or float(np.max(np.abs(res))) <= tol:
            return m
        m = m + res
    raise CameraError(
        f"{img}: the {what} correction could not be inverted to {tol:g} mm in "
        f"{max_iter} iterations",
        "Check the camera's distortion coefficients and their convention",
    )


# ============================================================================ helpers
def _as_xy(xy: Any, what: str) -> np.ndarray:
    a = np.array(xy, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 2:
        raise CameraError(
            f"{what} must have two columns (x, y), got shape {a.shape}",
            "Pass an (n, 2) array",
        )
    return a


def _pair_of(v: Any, what: str) -> tuple[float, float]:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (2,):
        raise CameraError(f"{what}: expected two numbers (x, y), got {v!r}", "")
    return float(a[0]), float(a[1])


def _pixel_pair(pixel_size: Any, where: str) -> tuple[float, float]:
    try:
        a = np.atleast_1d(np.asarray(pixel_size, dtype=float)).ravel()
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.size == 1:
        a = np.array([a[0], a[0]])
    if a.size != 2 or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise CameraError(
            f"{where}: pixel size {pixel_size!r} is not one or two positive numbers (mm)",
            "Give pixel_size in millimetres, e.g. 0.012 for 12 micrometres",
            details={"key": "pixel_size"},
        )
    return float(a[0]), float(a[1])


def _image_label(image_id: str | None) -> str:
    return f"image {image_id!r}" if image_id is not None else "image"


def _check_unit(unit: str, img: str) -> str:
    u = str(unit).strip().lower()
    if u in ("pixel", "pixels", "px"):
        return "pixel"
    if u in ("mm", "millimetre", "millimeter", "millimetres", "millimeters"):
        return "mm"
    raise CameraError(
        f"{img}: unknown image coordinate unit {unit!r}",
        "Use unit = 'mm' or 'pixel' in [measurements]",
        details={"key": "unit", "value": unit},
    )


def _switches(corrections: Mapping[str, bool] | None, img: str) -> dict[str, bool]:
    sw = dict(DEFAULT_CORRECTIONS)
    if corrections is None:
        return sw
    if not isinstance(corrections, Mapping):
        raise CameraError(
            f"[corrections] must be a table of switches, not {corrections!r}",
            "Write e.g. refraction = true",
        )
    for key, val in corrections.items():
        if key not in sw:
            raise CameraError(
                f"[corrections]: unknown switch {key!r}",
                f"Accepted switches: {', '.join(DEFAULT_CORRECTIONS)}",
                details={"key": key},
            )
        if not isinstance(val, (bool, np.bool_)):
            raise CameraError(
                f"[corrections]: {key} must be true or false, not {val!r}",
                f"Write {key} = true or {key} = false",
                details={"key": key},
            )
        sw[key] = bool(val)
    return sw


def as_calibration(camera: Any) -> CameraCalibration:
    """The :class:`CameraCalibration` of a camera given in any accepted form.

    Parameters
    ----------
    camera : CameraCalibration, vectoradjust.model.Camera or mapping
        A ``Camera``'s ``calibration`` (a CameraCalibration or the raw ``[camera]``
        table) is used when present, else its ``focal_length`` and
        ``principal_point``; a mapping is read as a ``[camera]`` table.

    Returns
    -------
    CameraCalibration
    """
    if isinstance(camera, CameraCalibration):
        return camera
    cal = getattr(camera, "calibration", None)
    if isinstance(cal, CameraCalibration):
        return cal
    if isinstance(cal, Mapping):  # the raw (already merged) [camera] table
        return CameraCalibration.from_dict(cal)
    if hasattr(camera, "focal_length"):
        return CameraCalibration(
            focal_length=camera.focal_length,
            principal_point=tuple(getattr(camera, "principal_point", (0.0, 0.0))),
        )
    if isinstance(camera, Mapping):
        return CameraCalibration.from_dict(camera)
    raise TypeError(f"not a camera: {camera!r}")


_as_calibration = as_calibration
