"""Measured quantities the tolerances are compared with: vertical parallax of a pair and
its statistics, model discrepancies of a triplet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.qa.tolerances.limits import _pixel
from vectoradjust.qa.tolerances.stages import _json_number
from vectoradjust.sensor.collinearity import rotation_matrix

__all__ = ["ParallaxStats", "vertical_parallax", "parallax_stats", "model_discrepancies"]


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

