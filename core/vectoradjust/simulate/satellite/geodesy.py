"""Geodesy of the simulation: WGS84 constants, geodetic <-> ECEF, local east-north-up
frames, and the small shared helpers (pixel origin shift, seeded random generators).
"""

from __future__ import annotations

import math
import zlib

import numpy as np

__all__ = ["WGS84_A", "WGS84_E2", "GM_EARTH", "geodetic_to_ecef", "ecef_to_geodetic"]


WGS84_A = 6378137.0



WGS84_F = 1.0 / 298.257223563



WGS84_E2 = WGS84_F * (2.0 - WGS84_F)



#: the Earth's gravitational constant (m^3/s^2)
GM_EARTH = 3.986004418e14



_ORIGINS = {"center": 0.0, "corner": 0.5}



def _shift(origin: str) -> float:
    try:
        return _ORIGINS[origin]
    except KeyError:
        raise ValueError(f"origin must be 'center' or 'corner', not {origin!r}") from None



def _rng(seed: int, tag: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(tag.encode("utf-8"))])



def geodetic_to_ecef(lon, lat, h) -> np.ndarray:
    """WGS84 geodetic to Earth-centred Earth-fixed coordinates.

    Parameters
    ----------
    lon, lat : array_like
        Degrees.
    h : array_like
        Ellipsoidal height (m).

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        X, Y, Z (m).
    """
    lon_r = np.radians(np.asarray(lon, dtype=float))
    lat_r = np.radians(np.asarray(lat, dtype=float))
    h = np.asarray(h, dtype=float)
    sin_lat = np.sin(lat_r)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    x = (n + h) * np.cos(lat_r) * np.cos(lon_r)
    y = (n + h) * np.cos(lat_r) * np.sin(lon_r)
    z = (n * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF to WGS84 geodetic coordinates (fixed-point iteration on the latitude).

    Parameters
    ----------
    xyz : array_like, shape (..., 3)

    Returns
    -------
    lon, lat : numpy.ndarray
        Degrees.
    h : numpy.ndarray
        Ellipsoidal height (m); exact to well below a millimetre up to orbit heights.
    """
    xyz = np.asarray(xyz, dtype=float)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(10):
        sin_lat = np.sin(lat)
        w = np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
        h = p * np.cos(lat) + z * sin_lat - WGS84_A * w
        n = WGS84_A / w
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    sin_lat = np.sin(lat)
    h = p * np.cos(lat) + z * sin_lat - WGS84_A * np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return np.degrees(np.arctan2(y, x)), np.degrees(lat), h


def _enu(lon: float, lat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """East, north and up unit vectors (ECEF) at a geodetic position."""
    lo, la = math.radians(lon), math.radians(lat)
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    north = np.array([-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)])
    up = np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
    return east, north, up


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)

