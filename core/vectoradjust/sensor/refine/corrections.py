"""The physical corrections of image coordinates: lens distortion (SMAC, radial polynomial,
decentering), atmospheric refraction (ARDC) and earth curvature.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.refine.coerce import _as_xy

__all__ = [
    "EARTH_RADIUS", "smac_correction", "radial_polynomial_correction", "decentering_correction",
    "ardc_k", "refraction_correction", "earth_curvature_correction",
]


#: Mean earth radius (m) used by the earth curvature correction.
EARTH_RADIUS = 6_371_000.0



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

