"""Residual vectors of the adjusted shape points for a map: start, (scaled) end, length
and azimuth.

A residual vector runs from a vertex's database position to its adjusted position,
``V = adjusted - database`` (the ``Vx``, ``Vy``, ``Vz`` fields of ``shape_points``). For a
readable map it is drawn ``scale`` times its length; the fields keep the true values.
The azimuth is the direction of the horizontal residual, clockwise from grid north (+Y)
in degrees ``[0, 360)``, the convention of
:func:`vectoradjust.accuracy.stats.bias_direction`. numpy only; the QGIS plugin's
residual layer (``qgis_plugin/results.py``) converts these arrays to features.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ResidualVectors", "residual_vectors", "residual_azimuth"]


@dataclass(frozen=True)
class ResidualVectors:
    """Residual vectors as lines, one row per vertex.

    Attributes
    ----------
    start : numpy.ndarray, shape (n, 3)
        The database position; an unknown Z is 0 (as the headless writer writes it).
    end : numpy.ndarray, shape (n, 3)
        ``start + scale * V`` (an unknown ``Vz`` counts as 0).
    length : numpy.ndarray, shape (n,)
        The true horizontal length ``hypot(Vx, Vy)`` (m), not scaled.
    azimuth : numpy.ndarray, shape (n,)
        :func:`residual_azimuth` of ``(Vx, Vy)`` (degrees).
    """

    start: np.ndarray
    end: np.ndarray
    length: np.ndarray
    azimuth: np.ndarray


def residual_azimuth(vx, vy) -> np.ndarray:
    """Direction of horizontal vectors, clockwise from grid north (+Y), degrees [0, 360).

    Parameters
    ----------
    vx, vy : array_like
        East and north components.

    Returns
    -------
    numpy.ndarray
        ``degrees(atan2(vx, vy)) mod 360``; 0 for a zero vector, NaN where a component is
        NaN.
    """
    vx, vy = np.asarray(vx, float), np.asarray(vy, float)
    return np.mod(np.degrees(np.arctan2(vx, vy)), 360.0)


def residual_vectors(x, y, z, vx, vy, vz, scale: float = 1.0) -> ResidualVectors:
    """Residual vectors of vertices as map lines (see the module).

    Parameters
    ----------
    x, y, z : array_like, shape (n,)
        Database positions (m); Z may be NaN (unknown).
    vx, vy, vz : array_like, shape (n,)
        Residuals ``adjusted - database`` (m); ``vz`` may be NaN.
    scale : float, optional
        Exaggeration of the drawn vectors (default 1: true size).

    Returns
    -------
    ResidualVectors
    """
    x, y, z, vx, vy, vz = (np.asarray(a, float).reshape(-1) for a in (x, y, z, vx, vy, vz))
    s = float(scale)
    z0 = np.where(np.isfinite(z), z, 0.0)
    dz = np.where(np.isfinite(vz), vz, 0.0)
    start = np.column_stack([x, y, z0])
    end = np.column_stack([x + s * vx, y + s * vy, z0 + s * dz])
    return ResidualVectors(start=start, end=end, length=np.hypot(vx, vy),
                           azimuth=residual_azimuth(vx, vy))
