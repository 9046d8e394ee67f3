"""The refinement's steps and default switches (:data:`STEPS`, :data:`DEFAULT_CORRECTIONS`)
and its argument helpers: coordinate pairs, pixel sizes, units, the correction switches
and :func:`as_calibration`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import CameraCalibration

__all__ = ["DEFAULT_CORRECTIONS", "as_calibration"]


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

