"""Pixels and photo coordinates: pixel to photo (mm) and back, and pixel sigmas in
millimetres.
"""

from __future__ import annotations

from typing import Any, Union

import numpy as np

from vectoradjust.errors import CameraError, MeasurementError
from vectoradjust.sensor.refine.coerce import _as_xy, _pixel_pair
from vectoradjust.sensor.refine.fiducials import AffineFit

__all__ = ["pixel_to_photo", "photo_to_pixel", "sigma_pixels_to_mm"]


PixelSize = Union[float, tuple[float, float], "AffineFit"]



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

