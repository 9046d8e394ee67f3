"""Ground frames: the adjustment's object coordinates to WGS84 longitude, latitude, height.

An RPC model maps geodetic longitude and latitude (degrees) and the height above the
WGS84 ellipsoid (metres) to pixels, while the adjustment works in metric object
coordinates ``X, Y, Z``. A *ground frame* converts between the two and gives the
Jacobian ``d(lon, lat, h) / d(X, Y, Z)`` that chains the RPC partials to the object
point:

- :class:`GroundFrame` - the interface (``to_geodetic``, ``from_geodetic``,
  ``description``).
- :class:`EnuFrame` - an exact local East-North-Up tangent frame at a point of the
  WGS84 ellipsoid, through geocentric (ECEF) coordinates, with the analytic Jacobian.
- :class:`CallableFrame` - wraps a pair of functions (e.g. a pyproj transformer from a
  UTM zone, see :func:`vectoradjust.files.rpc.crs_frame`) and differentiates them by
  central differences.

Accuracy of :class:`EnuFrame` (measured in ``tests/test_ground.py``): geodetic from
ECEF by Bowring's formula iterated three times (two already converge); the error
left is float64 rounding, not the method: an ulp of a geocentric coordinate is
9.3e-10 m and one of a latitude near 34 degrees 7.9e-10 m. Against a 40-digit
evaluation (mpmath) the latitude is within 1.1e-9 m and the height within 1.5e-9 m up
to 1000 km altitude; ECEF agrees with PROJ (EPSG:4979 -> 4978) within 9.3e-10 m, ENU
with PROJ's ``topocentric`` within 3.3e-9 m, and ENU -> geodetic -> ENU returns within
3.3e-9 m (out to 500 km and 700 km up). (PROJ 9.5's own ECEF -> geodetic is up to
5.7 mm off between 10 and 1000 km altitude.) The Jacobian is exact: the inverse of
the analytic ``d(ECEF)/d(lon, lat, h)``, rotated into the local frame. It is singular
at the poles (longitude undefined).

Accuracy of :class:`CallableFrame` (measured in ``tests/test_ground.py`` on UTM zone
35S through PROJ against PROJ's analytic projection factors, and on
:class:`EnuFrame`'s functions against its analytic Jacobian): central differences
have a truncation error ``step**2 / 6 * f'''``, tiny for a map projection (relative
8e-9 with a 1 km step, hence about 1e-14 with 1 m), and a rounding error that grows
as ``1 / step`` (relative 1.2e-7 with a 1 cm step). With the default 1 m step the
Jacobian agrees to 1.0e-9 (UTM) and 1.6e-9 (ENU) relatively; 10-100 m steps reach the
1.3e-10 floor, but 1 m keeps a bilinear geoid grid (15' cells) differentiated locally.

Imports numpy only.
"""

from __future__ import annotations

import abc
from typing import Callable

import numpy as np

__all__ = [
    "WGS84_A",
    "WGS84_F",
    "GroundFrame",
    "EnuFrame",
    "CallableFrame",
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "geodetic_jacobian_ecef",
]

#: semi-major axis of WGS84 (m)
WGS84_A = 6378137.0
#: flattening of WGS84
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)
_B = WGS84_A * (1.0 - WGS84_F)
_EP2 = _E2 / (1.0 - _E2)
_BOWRING_ITERATIONS = 3


def _points(a, name: str) -> np.ndarray:
    """``a`` as a float array of shape (n, 3) (a single point (3,) becomes (1, 3))."""
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), not {np.shape(a)}")
    return arr


def geodetic_to_ecef(llh) -> np.ndarray:
    """Geocentric (ECEF) coordinates of WGS84 geodetic points (closed form).

    Parameters
    ----------
    llh : array_like, shape (n, 3)
        Longitude and latitude in degrees, ellipsoidal height in metres.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        ``X, Y, Z`` in metres.
    """
    p = _points(llh, "llh")
    lam, phi, h = np.radians(p[:, 0]), np.radians(p[:, 1]), p[:, 2]
    sphi, cphi = np.sin(phi), np.cos(phi)
    n = WGS84_A / np.sqrt(1.0 - _E2 * sphi**2)
    return np.column_stack([(n + h) * cphi * np.cos(lam), (n + h) * cphi * np.sin(lam),
                            (n * (1.0 - _E2) + h) * sphi])


def ecef_to_geodetic(xyz) -> np.ndarray:
    """WGS84 geodetic coordinates of geocentric points (Bowring, iterated).

    Parameters
    ----------
    xyz : array_like, shape (n, 3)
        ECEF ``X, Y, Z`` in metres (not near the Earth's centre).

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Longitude and latitude in degrees, ellipsoidal height in metres.

    Notes
    -----
    Bowring's parametric-latitude formula converges cubically; three iterations
    leave an error far below the rounding of float64 geocentric coordinates. The
    height ``p cos(phi) + Z sin(phi) - a sqrt(1 - e2 sin^2 phi)`` is well conditioned
    at every latitude, the poles included.
    """
    p3 = _points(xyz, "xyz")
    x, y, z = p3[:, 0], p3[:, 1], p3[:, 2]
    p = np.hypot(x, y)
    beta = np.arctan2(z, (1.0 - WGS84_F) * p)
    phi = beta
    for _ in range(_BOWRING_ITERATIONS):
        phi = np.arctan2(z + _EP2 * _B * np.sin(beta) ** 3, p - _E2 * WGS84_A * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(phi), np.cos(phi))
    sphi, cphi = np.sin(phi), np.cos(phi)
    h = p * cphi + z * sphi - WGS84_A * np.sqrt(1.0 - _E2 * sphi**2)
    return np.column_stack([np.degrees(np.arctan2(y, x)), np.degrees(phi), h])


def _enu_axes(lon_deg, lat_deg) -> np.ndarray:
    """Unit vectors east, north, up in ECEF, shape (n, 3, 3): ``[:, k]`` is axis k."""
    lam, phi = np.radians(np.asarray(lon_deg, float)), np.radians(np.asarray(lat_deg, float))
    sl, cl, sp, cp = np.sin(lam), np.cos(lam), np.sin(phi), np.cos(phi)
    zero = np.zeros_like(sl)
    east = np.stack([-sl, cl, zero], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp], axis=-1)
    return np.stack([east, north, up], axis=-2)


def geodetic_jacobian_ecef(llh) -> np.ndarray:
    """Analytic ``d(lon [deg], lat [deg], h [m]) / d(X, Y, Z)`` of ECEF points.

    Parameters
    ----------
    llh : array_like, shape (n, 3)
        The points' geodetic coordinates (degrees, metres).

    Returns
    -------
    numpy.ndarray, shape (n, 3, 3)
        Rows lon, lat, h; columns X, Y, Z. The inverse of ``d(ECEF)/d(lon, lat, h)``,
        whose columns are ``(N + h) cos(phi) * east``, ``(M + h) * north`` and ``up``
        (per radian), with ``N`` and ``M`` the prime-vertical and meridian radii of
        curvature. Infinite longitude rows at the poles.
    """
    p = _points(llh, "llh")
    sphi = np.sin(np.radians(p[:, 1]))
    w = np.sqrt(1.0 - _E2 * sphi**2)
    n_rad = WGS84_A / w
    m_rad = WGS84_A * (1.0 - _E2) / w**3
    axes = _enu_axes(p[:, 0], p[:, 1])
    with np.errstate(divide="ignore"):
        lon_row = 1.0 / ((n_rad + p[:, 2]) * np.cos(np.radians(p[:, 1])))
        scale = np.column_stack([np.degrees(lon_row), np.degrees(1.0 / (m_rad + p[:, 2])),
                                 np.ones(len(p))])
    return axes * scale[:, :, None]


class GroundFrame(abc.ABC):
    """Object coordinates ``X, Y, Z`` (metres) to WGS84 geodetic coordinates and back.

    Attributes
    ----------
    description : str
        What the frame is, for reports (e.g. "local ENU at 24.4057 E, 33.6726 S, 703 m").
    """

    description: str = "<ground frame>"

    @abc.abstractmethod
    def to_geodetic(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Geodetic coordinates of object points and their Jacobian.

        Parameters
        ----------
        xyz : numpy.ndarray, shape (n, 3)
            Object coordinates in metres.

        Returns
        -------
        llh : numpy.ndarray, shape (n, 3)
            Longitude, latitude (degrees) and ellipsoidal height (m) on WGS84.
        jac : numpy.ndarray, shape (n, 3, 3)
            ``d(lon, lat, h) / d(X, Y, Z)``: rows lon, lat, h; columns X, Y, Z.
        """

    @abc.abstractmethod
    def from_geodetic(self, llh: np.ndarray) -> np.ndarray:
        """Object coordinates of geodetic points.

        Parameters
        ----------
        llh : numpy.ndarray, shape (n, 3)
            Longitude, latitude (degrees), ellipsoidal height (m) on WGS84.

        Returns
        -------
        numpy.ndarray, shape (n, 3)
            ``X, Y, Z`` in metres.
        """

    def __repr__(self) -> str:
        return f"<{type(self).__name__}: {self.description}>"


class EnuFrame(GroundFrame):
    """The local East-North-Up tangent frame at a point of the WGS84 ellipsoid (exact).

    ``X`` east, ``Y`` north, ``Z`` up along the ellipsoid normal at the origin; the
    origin ``(lon0, lat0, h0)`` is ``(0, 0, 0)``. A Cartesian frame: distances are true
    3D distances, and ``Z`` departs from the ellipsoidal height by ``d**2 / (2 R)``
    at a distance ``d`` from the origin (8 cm at 1 km).

    Parameters
    ----------
    lon0, lat0 : float
        Origin longitude and latitude in degrees (not at a pole).
    h0 : float, optional
        Origin's ellipsoidal height in metres.
    """

    def __init__(self, lon0: float, lat0: float, h0: float = 0.0) -> None:
        if not (np.isfinite(lon0) and np.isfinite(lat0) and np.isfinite(h0)):
            raise ValueError(f"the ENU origin must be finite: {lon0}, {lat0}, {h0}")
        if not -90.0 < lat0 < 90.0:
            raise ValueError(f"the ENU origin's latitude must be inside (-90, 90): {lat0}")
        self.lon0, self.lat0, self.h0 = float(lon0), float(lat0), float(h0)
        self.origin_ecef = geodetic_to_ecef([[self.lon0, self.lat0, self.h0]])[0]
        #: columns: east, north, up unit vectors in ECEF (ECEF offset = R @ enu)
        self.rotation = _enu_axes(self.lon0, self.lat0).T
        ew = "E" if self.lon0 >= 0 else "W"
        ns = "N" if self.lat0 >= 0 else "S"
        self.description = (f"local East-North-Up frame (WGS84) at {abs(self.lon0):.6f} {ew}, "
                            f"{abs(self.lat0):.6f} {ns}, {self.h0:.3f} m ellipsoidal")

    def to_ecef(self, xyz) -> np.ndarray:
        """ECEF coordinates (m) of ENU points, shape (n, 3)."""
        return self.origin_ecef + _points(xyz, "xyz") @ self.rotation.T

    def from_ecef(self, ecef) -> np.ndarray:
        """ENU coordinates (m) of ECEF points, shape (n, 3)."""
        return (_points(ecef, "ecef") - self.origin_ecef) @ self.rotation

    def to_geodetic(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Geodetic coordinates and the exact Jacobian (see :meth:`GroundFrame.to_geodetic`)."""
        llh = ecef_to_geodetic(self.to_ecef(xyz))
        return llh, geodetic_jacobian_ecef(llh) @ self.rotation

    def from_geodetic(self, llh: np.ndarray) -> np.ndarray:
        """ENU coordinates of geodetic points (see :meth:`GroundFrame.from_geodetic`)."""
        return self.from_ecef(geodetic_to_ecef(llh))


class CallableFrame(GroundFrame):
    """A ground frame from a pair of functions, differentiated by central differences.

    Parameters
    ----------
    forward : callable
        ``forward(x, y, z) -> (lon, lat, h)`` on 1-D arrays (e.g. a pyproj
        ``Transformer.transform`` from the project CRS to EPSG:4979 with
        ``always_xy=True``); longitude and latitude in degrees, h ellipsoidal in m.
    inverse : callable
        ``inverse(lon, lat, h) -> (x, y, z)``.
    description : str
        For reports (the CRS and the transformation).
    step : float, optional
        Half the central-difference interval in metres (default 1 m). The truncation
        error is ``step**2 / 6`` times the third derivative, negligible for map
        projections and geoid grids (see the module docstring for measured values);
        much smaller steps only add rounding error.

    Notes
    -----
    :meth:`to_geodetic` calls ``forward`` once, on 7 n points (the points and their six
    neighbours). Longitude differences are taken modulo 360 degrees, so that points
    at the antimeridian differentiate correctly.
    """

    def __init__(self, forward: Callable, inverse: Callable, description: str,
                 step: float = 1.0) -> None:
        if not (np.isfinite(step) and step > 0):
            raise ValueError(f"step must be a positive number of metres, not {step!r}")
        self.forward, self.inverse = forward, inverse
        self.description = str(description)
        self.step = float(step)

    def _forward(self, pts: np.ndarray) -> np.ndarray:
        lon, lat, h = self.forward(pts[:, 0], pts[:, 1], pts[:, 2])
        return np.column_stack([np.asarray(lon, float), np.asarray(lat, float),
                                np.asarray(h, float)])

    def to_geodetic(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Geodetic coordinates and the central-difference Jacobian.

        See :meth:`GroundFrame.to_geodetic`.
        """
        pts = _points(xyz, "xyz")
        n = len(pts)
        offsets = np.concatenate([np.zeros((1, 3)), self.step * np.eye(3),
                                  -self.step * np.eye(3)])          # (7, 3)
        out = self._forward((pts[None, :, :] + offsets[:, None, :]).reshape(-1, 3))
        out = out.reshape(7, n, 3)
        diff = out[1:4] - out[4:7]                                   # (3 columns, n, 3)
        diff[:, :, 0] = (diff[:, :, 0] + 180.0) % 360.0 - 180.0
        jac = np.transpose(diff, (1, 2, 0)) / (2.0 * self.step)      # (n, rows, columns)
        return out[0], jac

    def from_geodetic(self, llh: np.ndarray) -> np.ndarray:
        """Object coordinates from ``inverse`` (see :meth:`GroundFrame.from_geodetic`)."""
        p = _points(llh, "llh")
        x, y, z = self.inverse(p[:, 0], p[:, 1], p[:, 2])
        return np.column_stack([np.asarray(x, float), np.asarray(y, float),
                                np.asarray(z, float)])
