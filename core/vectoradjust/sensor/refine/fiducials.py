"""The fiducial affine transformation: :class:`AffineFit`, :func:`fit_fiducial_affine` and
the interior orientation check.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.refine.coerce import (
    _as_xy,
    _check_unit,
    _image_label,
    _pair_of,
    _pixel_pair,
)

__all__ = ["AffineFit", "fit_fiducial_affine", "interior_orientation_check"]


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
    calibrated, pixel_size = _calibrated_fiducials(calibrated, pixel_size, img, image_id)
    uv, xy, ids = _fiducial_pairs(measured, calibrated, img, image_id)
    _check_fiducials(uv, xy, ids, img, image_id)
    params, v = _solve_affine(uv, xy, ids, img, image_id)
    stats = _residual_stats(v, pixel_size, img)
    return AffineFit(
        params=params,
        ids=ids,
        measured=uv,
        calibrated=xy,
        residuals=v,
        unit=unit,
        image_id=image_id,
        **stats,
    )


def _calibrated_fiducials(calibrated: Any, pixel_size: Any, img: str,
                          image_id: str | None) -> tuple[Any, Any]:
    """A camera's calibrated fiducials and pixel size (when not given); others unchanged."""
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
    return calibrated, pixel_size


def _residual_stats(v: np.ndarray, pixel_size: Any, img: str) -> dict[str, Any]:
    """The fit statistics of :class:`AffineFit` from the residuals ``v (n, 2)`` (mm).

    ``rms_um, max_um, sigma0_um`` (None without redundancy), ``rms_px, max_px`` (None
    without a pixel size), ``redundancy``, ``pixel_size`` and ``note``.
    """
    n = len(v)
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
    return {"rms_um": rms_um, "max_um": max_um, "sigma0_um": sigma0_um, "rms_px": rms_px,
            "max_px": max_px, "redundancy": redundancy, "pixel_size": ps, "note": note}


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

    docs/method.md section 7 (PHOTOMOD, after CNIIGAIK 2002).

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

