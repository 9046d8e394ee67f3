"""Simulated satellite pushbroom images with RPCs and known truth.

A physical line scanner on WGS84 (ECEF mathematics throughout, no map projection):

- :class:`CircularOrbit` - a circular orbit (Earth-fixed, Earth rotation ignored) at
  ``radius`` from the Earth's centre, through ``p0`` at ``t = 0`` moving along ``v0``;
  :meth:`~CircularOrbit.frame` is the orbital frame (x along track, z to the geocentre,
  y = z x x, to starboard).
- :class:`PushbroomSensor` - one image: a linear CCD of ``n_cols`` pixels across track
  with an angular pixel size ``ifov`` (GSD / altitude), ``n_rows`` lines of
  ``line_time`` seconds centred on ``t_center``, pointed by ``roll``, ``pitch`` and
  ``yaw`` (body to orbital frame ``R_y(pitch) R_x(roll) R_z(yaw)``; pitch > 0 looks
  forward) that drift smoothly, ``angle(t) = angle + drift[:, 0] tau + drift[:, 1] tau**2``
  with ``tau = t - t_center``. Pixel ``c`` of line ``r`` (centre convention, see below)
  looks along ``(0, (c - (n_cols - 1) / 2) ifov, 1)`` in the body frame at time
  ``t_center + (r - (n_rows - 1) / 2) line_time``.
- :func:`pushbroom_project` (ground to image; the line time is found by vectorised Newton
  iterations over all points at once), :func:`pushbroom_ray` and
  :func:`pushbroom_localize` (image to ground at a given height).
- :func:`stereo_sensors` - an along-track pair (forward, backward) or triplet (forward,
  nadir, backward) that all look at one ground point with a given base-to-height ratio.
- :func:`fit_rpc` - the terrain-independent RPC fit (Tao & Hu 2001): linear least
  squares of the rational functions on a 3-D grid of the ground domain, iteratively
  reweighted by the denominator with a small Tikhonov (ridge) term (the best of
  :data:`RIDGES` per coordinate), checked on the grid's cell centres. For the default
  scenario the fit is ~1e-8 px, for a 10 x 10 km image (20000 x 20000 px) with a
  strong attitude drift ~1e-4 px (``tests/test_satellite_sim.py`` prints the numbers).
- :func:`satellite_scenario` - a small scene (default near lon -87.0, lat 40.4, 3 x 3 km,
  smooth terrain 150-250 m ellipsoidal), its images with fitted RPCs as the vendor
  delivers them, a TRUE image-space bias per image (``BIAS_MODELS`` of
  :mod:`vectoradjust.sensor.rpc`, Grodecki & Dial 2003), control, check, tie and
  road-vertex points and their observations: the truth projected through the RPC plus
  the true bias (:func:`biased_project`) plus Gaussian noise.

Pixel convention as in :mod:`vectoradjust.sensor.rpc`: ``origin="center"`` puts the
centre of the first pixel at ``(0, 0)`` (the raw RPC formula: :func:`fit_rpc` fits the
RPC to these values), ``origin="corner"`` (GDAL's) puts the first pixel's upper-left
corner at ``(0, 0)``, i.e. ``corner = center + 0.5``. Columns run across track (RPC
"sample"), rows along track (RPC "line"). Heights are ellipsoidal (WGS84), lon/lat in
degrees.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``,
so the scenario is deterministic per seed. Imports numpy and scipy only.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Callable, Optional, Union

import numpy as np
from scipy import linalg

from vectoradjust.errors import ProjectError
from vectoradjust.sensor.rpc import BIAS_MODELS, RpcModel

__all__ = [
    "WGS84_A",
    "WGS84_E2",
    "GM_EARTH",
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "CircularOrbit",
    "PushbroomSensor",
    "pushbroom_project",
    "pushbroom_ray",
    "pushbroom_localize",
    "stereo_sensors",
    "stereo_base_to_height",
    "rpc_terms",
    "RIDGES",
    "fit_rpc",
    "image_domain",
    "biased_project",
    "SceneArea",
    "GroundPoints",
    "SatelliteScenario",
    "satellite_scenario",
]

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
#: the Earth's gravitational constant (m^3/s^2)
GM_EARTH = 3.986004418e14
_ORIGINS = {"center": 0.0, "corner": 0.5}
_KINDS = ("control", "check", "tie", "road")
#: ridge (Tikhonov) candidates of :func:`fit_rpc`
RIDGES = (0.0, 1e-12, 1e-10, 1e-8, 1e-6, 1e-4)


def _shift(origin: str) -> float:
    try:
        return _ORIGINS[origin]
    except KeyError:
        raise ValueError(f"origin must be 'center' or 'corner', not {origin!r}") from None


def _rng(seed: int, tag: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(tag.encode("utf-8"))])


# --------------------------------------------------------------------------- geodesy


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


# --------------------------------------------------------------------------- the sensor


@dataclass(frozen=True)
class CircularOrbit:
    """A circular orbit, Earth-fixed (the Earth's rotation is ignored).

    Attributes
    ----------
    radius : float
        Distance from the Earth's centre (m).
    p0 : numpy.ndarray, shape (3,)
        Unit vector of the position at ``t = 0``.
    v0 : numpy.ndarray, shape (3,)
        Unit vector of the direction of motion at ``t = 0`` (perpendicular to ``p0``).
    """

    radius: float
    p0: np.ndarray
    v0: np.ndarray

    @property
    def omega(self) -> float:
        """Angular rate (rad/s), Kepler's ``sqrt(GM / r**3)``."""
        return math.sqrt(GM_EARTH / self.radius**3)

    @property
    def speed(self) -> float:
        """Orbital speed (m/s)."""
        return self.omega * self.radius

    def position(self, t) -> np.ndarray:
        """ECEF position(s) at time(s) ``t`` (s), shape ``(..., 3)``."""
        wt = self.omega * np.asarray(t, dtype=float)[..., None]
        return self.radius * (np.cos(wt) * self.p0 + np.sin(wt) * self.v0)

    def frame(self, t) -> np.ndarray:
        """Orbital frame at ``t``: ``(..., 3, 3)``, columns x (along track), y, z (nadir)."""
        wt = self.omega * np.asarray(t, dtype=float)[..., None]
        z = -(np.cos(wt) * self.p0 + np.sin(wt) * self.v0)
        x = -np.sin(wt) * self.p0 + np.cos(wt) * self.v0
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=-1)


@dataclass(frozen=True)
class PushbroomSensor:
    """One pushbroom image (see the module docstring for the geometry).

    Attributes
    ----------
    orbit : CircularOrbit
    t_center : float
        Time of the image's middle line (s).
    line_time : float
        Seconds per line.
    n_cols, n_rows : int
        Image size (pixels across track, lines).
    ifov : float
        Angular size of a CCD pixel (rad).
    roll, pitch, yaw : float
        Pointing at ``t_center`` (rad).
    drift : numpy.ndarray, shape (3, 2)
        Attitude drift of roll, pitch, yaw: rate (rad/s) and quadratic term (rad/s^2).
    name : str
    """

    orbit: CircularOrbit
    t_center: float
    line_time: float
    n_cols: int
    n_rows: int
    ifov: float
    roll: float
    pitch: float
    yaw: float = 0.0
    drift: np.ndarray = field(default_factory=lambda: np.zeros((3, 2)))
    name: str = "image"

    @property
    def t_start(self) -> float:
        """Time of the first line's centre (s)."""
        return self.t_center - 0.5 * (self.n_rows - 1) * self.line_time

    @property
    def size(self) -> tuple[int, int]:
        """``(n_cols, n_rows)``."""
        return int(self.n_cols), int(self.n_rows)

    def rotation(self, t) -> np.ndarray:
        """Body-to-ECEF rotation at ``t``, shape ``(n, 3, 3)``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        tau = t - self.t_center
        d = np.asarray(self.drift, dtype=float)
        roll = self.roll + d[0, 0] * tau + d[0, 1] * tau**2
        pitch = self.pitch + d[1, 0] * tau + d[1, 1] * tau**2
        yaw = self.yaw + d[2, 0] * tau + d[2, 1] * tau**2
        one, zero = np.ones_like(tau), np.zeros_like(tau)
        cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
        cy, sy = np.cos(yaw), np.sin(yaw)
        rx = np.stack([one, zero, zero, zero, cr, -sr, zero, sr, cr], -1).reshape(-1, 3, 3)
        ry = np.stack([cp, zero, sp, zero, one, zero, -sp, zero, cp], -1).reshape(-1, 3, 3)
        rz = np.stack([cy, -sy, zero, sy, cy, zero, zero, zero, one], -1).reshape(-1, 3, 3)
        return self.orbit.frame(t) @ ry @ rx @ rz


def _body_vectors(sensor: PushbroomSensor, xyz: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(n, 3)`` the vectors satellite -> point in the body frame at times ``t``."""
    rot = sensor.rotation(t)
    return np.einsum("nji,nj->ni", rot, xyz - sensor.orbit.position(t))


def _scan_times(sensor: PushbroomSensor, xyz: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """Time at which each point lies in the scan plane (body x = 0), by Newton's method.

    The derivative is a forward difference over ``1 ms``; the along-track angle is
    almost linear in time, so 3-5 iterations reach ``tol`` seconds (1e-8 line).
    """
    t = np.full(len(xyz), float(sensor.t_center))
    delta = 1e-3
    for _ in range(50):
        q0 = _body_vectors(sensor, xyz, t)
        q1 = _body_vectors(sensor, xyz, t + delta)
        f0, f1 = q0[:, 0] / q0[:, 2], q1[:, 0] / q1[:, 2]
        step = f0 * delta / (f1 - f0)
        t = t - step
        if not len(t) or np.max(np.abs(step)) < tol:
            return t
    raise RuntimeError("pushbroom ground-to-image iteration did not converge")


def pushbroom_project(
    sensor: PushbroomSensor, lon, lat, h, origin: str = "corner"
) -> tuple[np.ndarray, np.ndarray]:
    """Ground to image for a pushbroom sensor (rigorous model).

    Parameters
    ----------
    sensor : PushbroomSensor
    lon, lat : array_like
        Degrees (broadcast together with ``h``).
    h : array_like
        Ellipsoidal height (m).
    origin : {"corner", "center"}
        Pixel convention of the result (module docstring).

    Returns
    -------
    col, row : numpy.ndarray
        Pixel coordinates, the broadcast shape of the inputs. Points outside the image
        get coordinates outside ``[0, n_cols] x [0, n_rows]`` (the line time is solved
        for on the whole orbit).
    """
    lon, lat, h = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (lon, lat, h)))
    shape = lon.shape
    xyz = geodetic_to_ecef(lon.ravel(), lat.ravel(), h.ravel())
    t = _scan_times(sensor, xyz)
    q = _body_vectors(sensor, xyz, t)
    s = _shift(origin)
    col = 0.5 * (sensor.n_cols - 1) + q[:, 1] / q[:, 2] / sensor.ifov + s
    row = (t - sensor.t_start) / sensor.line_time + s
    return col.reshape(shape), row.reshape(shape)


def pushbroom_ray(
    sensor: PushbroomSensor, col, row, origin: str = "corner"
) -> tuple[np.ndarray, np.ndarray]:
    """Image to ray: the satellite position and the unit look direction (ECEF).

    Parameters
    ----------
    sensor : PushbroomSensor
    col, row : array_like
        Pixel coordinates in the ``origin`` convention.
    origin : {"corner", "center"}

    Returns
    -------
    position, direction : numpy.ndarray, shape (n, 3)
    """
    s = _shift(origin)
    col, row = np.broadcast_arrays(np.asarray(col, float).ravel(), np.asarray(row, float).ravel())
    t = sensor.t_start + (row - s) * sensor.line_time
    body = np.stack(
        [np.zeros_like(col), (col - s - 0.5 * (sensor.n_cols - 1)) * sensor.ifov,
         np.ones_like(col)], axis=-1)
    direction = _unit(np.einsum("nij,nj->ni", sensor.rotation(t), body))
    return sensor.orbit.position(t), direction


def pushbroom_localize(
    sensor: PushbroomSensor, col, row, h, origin: str = "corner"
) -> tuple[np.ndarray, np.ndarray]:
    """Image to ground at a given ellipsoidal height (the ray meets ``h``).

    Parameters
    ----------
    sensor : PushbroomSensor
    col, row : array_like
        Pixel coordinates in the ``origin`` convention.
    h : array_like
        Ellipsoidal height (m), broadcast with ``col``.
    origin : {"corner", "center"}

    Returns
    -------
    lon, lat : numpy.ndarray, shape (n,)
        Degrees.
    """
    pos, d = pushbroom_ray(sensor, col, row, origin)
    h = np.broadcast_to(np.asarray(h, dtype=float).ravel(), (len(pos),))
    # start: the ellipsoid with semi-axes a + h, b + h; then Newton on the geodetic height
    a, b = WGS84_A + h, WGS84_A * math.sqrt(1.0 - WGS84_E2) + h
    scale = np.stack([1.0 / a, 1.0 / a, 1.0 / b], axis=-1)
    ps, ds = pos * scale, d * scale
    qa, qb, qc = np.sum(ds * ds, 1), 2.0 * np.sum(ps * ds, 1), np.sum(ps * ps, 1) - 1.0
    s = (-qb - np.sqrt(np.maximum(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
    for _ in range(6):
        lon, lat, hh = ecef_to_geodetic(pos + s[:, None] * d)
        up = np.stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                       np.cos(np.radians(lat)) * np.sin(np.radians(lon)),
                       np.sin(np.radians(lat))], axis=-1)
        s = s - (hh - h) / np.sum(d * up, axis=1)
    lon, lat, _ = ecef_to_geodetic(pos + s[:, None] * d)
    return lon, lat


def stereo_sensors(
    lon: float,
    lat: float,
    h: float,
    n_images: int = 2,
    *,
    base_to_height: float = 0.6,
    altitude: float = 600e3,
    gsd: float = 0.5,
    size: tuple[int, int] = (8000, 8000),
    heading_deg: float = 192.0,
    cross_track_m: float = 40e3,
    drift: Optional[np.ndarray] = None,
    yaw: Optional[Sequence[float]] = None,
) -> list[PushbroomSensor]:
    """An along-track stereo pair or triplet whose image centres all see one ground point.

    The satellite passes ``cross_track_m`` to the side of the point (a small roll),
    heading ``heading_deg`` (clockwise from north). The pair is taken at
    ``-tau, +tau`` (forward, backward looking), the triplet at ``-tau, 0, +tau``
    (forward, nadir, backward), where ``tau`` makes the chord between the first and last
    satellite positions ``base_to_height * altitude``. Roll and pitch at each image's
    middle line point its centre pixel exactly at the ground point.

    Parameters
    ----------
    lon, lat, h : float
        The ground point (degrees, ellipsoidal m).
    n_images : int
        1 (nadir), 2 or 3.
    base_to_height : float
        Base (first to last image) over the altitude.
    altitude : float
        Orbit height above the ground point (m).
    gsd : float
        Ground sample distance at nadir (m); sets ``ifov`` and the line time.
    size : (int, int)
        ``(n_cols, n_rows)`` of every image.
    heading_deg, cross_track_m : float
    drift : numpy.ndarray, shape (n_images, 3, 2), optional
        Attitude drift per image (``PushbroomSensor.drift``); zero by default.
    yaw : sequence of float, optional
        Yaw per image (rad; rotates the CCD line about the centre pixel); zero by default.

    Returns
    -------
    list of PushbroomSensor
    """
    center = geodetic_to_ecef(lon, lat, h)
    r_ground = float(np.linalg.norm(center))
    up_gc = center / r_ground
    east, north, _ = _enu(lon, lat)
    hd = math.radians(heading_deg)
    along = math.sin(hd) * east + math.cos(hd) * north
    along = _unit(along - along.dot(up_gc) * up_gc)
    cross = np.cross(along, up_gc)
    p0 = _unit(up_gc + cross * (cross_track_m / r_ground))
    orbit = CircularOrbit(r_ground + altitude, p0, _unit(along - along.dot(p0) * p0))
    half = math.asin(0.5 * base_to_height * altitude / orbit.radius) / orbit.omega
    times = {1: [0.0], 2: [-half, half], 3: [-half, 0.0, half]}.get(int(n_images))
    if times is None:
        raise ProjectError(f"n_images = {n_images} is not 1, 2 or 3",
                           "Simulate a single image, an along-track pair or a triplet.")
    names = {1: ["nadir"], 2: ["forward", "backward"], 3: ["forward", "nadir", "backward"]}
    line_time = gsd / (orbit.speed * r_ground / orbit.radius)
    sensors = []
    for k, t in enumerate(times):
        los = orbit.frame(t).T @ _unit(center - orbit.position(t))
        sensors.append(PushbroomSensor(
            orbit, t, line_time, int(size[0]), int(size[1]), gsd / altitude,
            roll=-math.asin(los[1]), pitch=math.atan2(los[0], los[2]),
            yaw=0.0 if yaw is None else float(yaw[k]),
            drift=np.zeros((3, 2)) if drift is None else np.asarray(drift[k], float),
            name=names[len(times)][k]))
    return sensors


def stereo_base_to_height(first: PushbroomSensor, second: PushbroomSensor, lon, lat, h) -> float:
    """Base-to-height ratio of two images of a ground point.

    The base is the distance between the satellite positions when each image sees the
    point; the height is the mean of the two satellites' heights above the point.

    Parameters
    ----------
    first, second : PushbroomSensor
    lon, lat, h : float
        The ground point.

    Returns
    -------
    float
    """
    xyz = geodetic_to_ecef([lon], [lat], [h])
    positions = [s.orbit.position(_scan_times(s, xyz))[0] for s in (first, second)]
    heights = [ecef_to_geodetic(p)[2] - float(h) for p in positions]
    return float(np.linalg.norm(positions[1] - positions[0]) / np.mean(heights))


# --------------------------------------------------------------------------- RPC fit


def rpc_terms(lon_n, lat_n, h_n) -> np.ndarray:
    """The 20 cubic terms of an RPC00B polynomial in normalised L (lon), P (lat), H.

    Parameters
    ----------
    lon_n, lat_n, h_n : array_like
        Normalised coordinates.

    Returns
    -------
    numpy.ndarray, shape (n, 20)
        ``1 L P H LP LH PH L^2 P^2 H^2 PLH L^3 LP^2 LH^2 L^2P P^3 PH^2 L^2H P^2H H^3``.
    """
    lo, la, hh = (np.asarray(a, dtype=float).ravel() for a in (lon_n, lat_n, h_n))
    one = np.ones_like(lo)
    return np.stack([
        one, lo, la, hh, lo * la, lo * hh, la * hh, lo**2, la**2, hh**2,
        la * lo * hh, lo**3, lo * la**2, lo * hh**2, lo**2 * la, la**3, la * hh**2,
        lo**2 * hh, la**2 * hh, hh**3], axis=-1)


def _fit_ratio(terms: np.ndarray, y: np.ndarray, ridge: float, iterations: int):
    """Numerator and denominator (constant 1) of ``y = num.T / den.T`` (Tao & Hu 2001).

    Linearised ``num.T - y (den.T - 1) = y``, each row weighted by ``1 / den.T`` of the
    previous solution, with ``ridge`` times the identity added to the normal matrix;
    stops when the weights change by less than 1e-6.
    """
    n_terms = terms.shape[1]
    a = np.hstack([terms, -y[:, None] * terms[:, 1:]])
    reg = math.sqrt(ridge) * np.eye(a.shape[1])
    den = np.ones(len(y))
    for _ in range(max(int(iterations), 1)):
        w = 1.0 / den
        x = linalg.lstsq(np.vstack([a * w[:, None], reg]),
                         np.concatenate([y * w, np.zeros(a.shape[1])]))[0]
        den_new = terms @ np.concatenate([[1.0], x[n_terms:]])
        converged = np.max(np.abs(den_new - den)) < 1e-6  # weights settled
        den = den_new
        if converged:
            break
    return x[:n_terms], np.concatenate([[1.0], x[n_terms:]])


def _fit_coordinate(terms, y, check_terms, check_y, ridges, iterations):
    """The fit of :func:`_fit_ratio` with the best of the ``ridges``.

    Best: the smallest largest misfit on the check points among the fits whose
    denominator stays above 0.5 on the nodes and the check points (if none does, the
    smallest misfit).
    """
    best = None
    for ridge in ridges:
        num, den = _fit_ratio(terms, y, float(ridge), iterations)
        den_min = min(np.min(terms @ den), np.min(check_terms @ den))
        misfit = np.max(np.abs((check_terms @ num) / (check_terms @ den) - check_y))
        key = (bool(den_min < 0.5), float(misfit))
        if best is None or key < best[0]:
            best = (key, num, den)
    return best[1], best[2]


def _grid(ranges, counts, cell_centres: bool) -> tuple[np.ndarray, ...]:
    axes = []
    for (lo, hi), n in zip(ranges, counts):
        nodes = np.linspace(lo, hi, int(n))
        axes.append(0.5 * (nodes[1:] + nodes[:-1]) if cell_centres else nodes)
    return tuple(g.ravel() for g in np.meshgrid(*axes, indexing="ij"))


def _as_col_row(result) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(result, np.ndarray) and result.ndim == 2 and result.shape[1] == 2:
        return result[:, 0], result[:, 1]
    col, row = result
    return np.asarray(col, dtype=float).ravel(), np.asarray(row, dtype=float).ravel()


def fit_rpc(
    project_fn: Callable,
    lon_range: Sequence[float],
    lat_range: Sequence[float],
    h_range: Sequence[float],
    size: tuple[int, int],
    *,
    grid: tuple[int, int, int] = (20, 20, 7),
    origin: str = "corner",
    ridge: Union[float, Sequence[float]] = RIDGES,
    iterations: int = 10,
    source: str = "<simulated>",
) -> tuple[RpcModel, float, float]:
    """Terrain-independent RPC fit of a rigorous sensor model.

    The ground domain ``lon_range x lat_range x h_range`` (which sets the RPC offsets
    and scales) is sampled on a ``grid`` of nodes; line and sample are fitted
    separately as cubic rationals (RPC00B), by linear least squares of the linearised
    equations reweighted by the denominator (Tao & Hu 2001), with a ridge term
    ``ridge * I`` on the normal equations that keeps the denominators near 1. The fit is
    checked on the grid's cell centres (points between the nodes); with several
    ``ridge`` values, each coordinate takes the one with the smallest largest misfit
    there among the fits whose denominator stays above 0.5 (so for a smooth sensor the
    smallest ridge, for one that no cubic rational describes a stronger one that keeps
    the denominator from a pole).

    Parameters
    ----------
    project_fn : callable
        ``project_fn(lon, lat, h) -> (col, row)`` (or an ``(n, 2)`` array) for 1-D
        arrays, in the ``origin`` convention, e.g.
        ``lambda lo, la, h: pushbroom_project(sensor, lo, la, h)``.
    lon_range, lat_range, h_range : (float, float)
        The domain (degrees, degrees, ellipsoidal m).
    size : (int, int)
        ``(n_cols, n_rows)`` of the image; SAMP/LINE offsets and scales are its middle
        and half size.
    grid : (int, int, int)
        Nodes in lon, lat, h (at least 4 each for the cubic terms).
    origin : {"corner", "center"}
        Pixel convention of ``project_fn``.
    ridge : float or sequence of float
        Tikhonov parameter(s) (normalised coordinates); default :data:`RIDGES`.
    iterations : int
        Reweighting iterations at most.
    source : str
        ``RpcModel.source``.

    Returns
    -------
    rpc : RpcModel
    fit_rms_px : float
        RMS of the radial misfit ``hypot(dcol, drow)`` on the check points (px).
    fit_max_px : float
        Largest radial misfit on the check points (px).
    """
    s = _shift(origin)
    n_cols, n_rows = int(size[0]), int(size[1])
    ranges = [tuple(map(float, r)) for r in (lon_range, lat_range, h_range)]
    off = [0.5 * (lo + hi) for lo, hi in ranges]
    scale = [0.5 * (hi - lo) for lo, hi in ranges]
    samp_off, samp_scale = 0.5 * n_cols, 0.5 * n_cols
    line_off, line_scale = 0.5 * n_rows, 0.5 * n_rows

    def normalised(pts):
        return [(p - o) / sc for p, o, sc in zip(pts, off, scale)]

    ridges = np.atleast_1d(np.asarray(ridge, dtype=float))
    nodes, check = _grid(ranges, grid, False), _grid(ranges, grid, True)
    terms, t = rpc_terms(*normalised(nodes)), rpc_terms(*normalised(check))
    col, row = _as_col_row(project_fn(*nodes))
    col_k, row_k = _as_col_row(project_fn(*check))
    line_num, line_den = _fit_coordinate(terms, (row - s - line_off) / line_scale, t,
                                         (row_k - s - line_off) / line_scale, ridges, iterations)
    samp_num, samp_den = _fit_coordinate(terms, (col - s - samp_off) / samp_scale, t,
                                         (col_k - s - samp_off) / samp_scale, ridges, iterations)
    col, row = col_k, row_k
    d_row = (t @ line_num) / (t @ line_den) * line_scale + line_off - (row - s)
    d_col = (t @ samp_num) / (t @ samp_den) * samp_scale + samp_off - (col - s)
    radial = np.hypot(d_col, d_row)
    rpc = RpcModel(
        line_off=line_off, samp_off=samp_off, lat_off=off[1], long_off=off[0],
        height_off=off[2], line_scale=line_scale, samp_scale=samp_scale,
        lat_scale=scale[1], long_scale=scale[0], height_scale=scale[2],
        line_num=line_num, line_den=line_den, samp_num=samp_num, samp_den=samp_den,
        source=source)
    return rpc, float(np.sqrt(np.mean(radial**2))), float(np.max(radial))


def image_domain(
    sensor: PushbroomSensor, h_range: Sequence[float], margin: float = 0.02
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The lon/lat bounding box of an image's footprint over a height range.

    Parameters
    ----------
    sensor : PushbroomSensor
    h_range : (float, float)
        Lowest and highest ellipsoidal height (m).
    margin : float
        Fraction of the box's width added on every side.

    Returns
    -------
    lon_range, lat_range : (float, float)
    """
    n_cols, n_rows = sensor.size
    edge = np.linspace(0.0, 1.0, 9)
    col = np.concatenate([edge * n_cols, np.full(9, n_cols), edge * n_cols, np.zeros(9)])
    row = np.concatenate([np.zeros(9), edge * n_rows, np.full(9, n_rows), edge * n_rows])
    lons, lats = [], []
    for h in h_range:
        lo, la = pushbroom_localize(sensor, col, row, h)
        lons.append(lo)
        lats.append(la)
    lons, lats = np.concatenate(lons), np.concatenate(lats)
    d_lon, d_lat = margin * np.ptp(lons), margin * np.ptp(lats)
    return ((float(lons.min() - d_lon), float(lons.max() + d_lon)),
            (float(lats.min() - d_lat), float(lats.max() + d_lat)))


def biased_project(rpc: RpcModel, params, lon, lat, h, origin: str = "corner") -> np.ndarray:
    """The RPC projection plus the image-space bias (Grodecki & Dial 2003).

    ``col' = col + a0 + a1 u + a2 v``, ``row' = row + b0 + b1 u + b2 v`` with
    ``u = (col_c - SAMP_OFF) / SAMP_SCALE``, ``v = (row_c - LINE_OFF) / LINE_SCALE`` of the
    raw (centre-convention) RPC values (the definition of
    :func:`vectoradjust.sensor.rpc.biased_partials`, computed here independently).

    Parameters
    ----------
    rpc : RpcModel
    params : array_like, shape (6,)
        ``a0, a1, a2, b0, b1, b2`` (px).
    lon, lat, h : array_like
    origin : {"corner", "center"}

    Returns
    -------
    numpy.ndarray, shape (n, 2)
        ``col', row'``.
    """
    p = np.asarray(params, dtype=float)
    raw = np.asarray(rpc.project(lon, lat, h, origin="center"), dtype=float)
    out = np.array(rpc.project(lon, lat, h, origin=origin), dtype=float)
    u = (raw[:, 0] - rpc.samp_off) / rpc.samp_scale
    v = (raw[:, 1] - rpc.line_off) / rpc.line_scale
    out[:, 0] += p[0] + p[1] * u + p[2] * v
    out[:, 1] += p[3] + p[4] * u + p[5] * v
    return out


# --------------------------------------------------------------------------- the scene


@dataclass(frozen=True)
class SceneArea:
    """A square scene with a smooth terrain.

    Attributes
    ----------
    lon, lat : float
        Centre (degrees).
    size_m : float
        Side (m).
    h_mean, h_relief : float
        The terrain is ``h_mean`` plus at most ``h_relief`` (ellipsoidal m).
    """

    lon: float = -87.0
    lat: float = 40.4
    size_m: float = 3000.0
    h_mean: float = 200.0
    h_relief: float = 50.0

    def height(self, x, y) -> np.ndarray:
        """Terrain height at local east/north offsets ``x, y`` (m) from the centre."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        half = 0.5 * self.size_m
        shape = (0.6 * np.sin(2 * np.pi * x / 2700.0 + 0.4) * np.cos(2 * np.pi * y / 3300.0 - 0.2)
                 + 0.3 * np.clip(x / half, -1.0, 1.0)
                 + 0.1 * np.cos(2 * np.pi * (x + y) / 1900.0))
        return self.h_mean + self.h_relief * shape

    def to_lonlat(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Local east/north offsets (m) to lon/lat (degrees), by the radii of curvature."""
        la = math.radians(self.lat)
        w = math.sqrt(1.0 - WGS84_E2 * math.sin(la) ** 2)
        n_radius = WGS84_A / w
        m_radius = WGS84_A * (1.0 - WGS84_E2) / w**3
        lon = self.lon + np.degrees(np.asarray(x, float) / (n_radius * math.cos(la)))
        return lon, self.lat + np.degrees(np.asarray(y, float) / m_radius)


@dataclass(frozen=True)
class GroundPoints:
    """Explicit ground points for :func:`satellite_scenario` (instead of a generated scene).

    Attributes
    ----------
    ids : sequence of str
    lon, lat, h : array_like
        Degrees, ellipsoidal m.
    kind : sequence of str
        ``"control"``, ``"check"``, ``"tie"`` or ``"road"`` per point.
    """

    ids: Sequence[str]
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray
    kind: Sequence[str]


@dataclass
class SatelliteScenario:
    """A simulated satellite project and its truth (:func:`satellite_scenario`).

    Attributes
    ----------
    seed : int
    area : SceneArea
    sensors : list of PushbroomSensor
        The true physical images (forward, [nadir,] backward).
    rpcs : list of RpcModel
        The RPCs "as the vendor delivered them": fitted to ``sensors``, without the bias.
    fit_rms_px, fit_max_px : numpy.ndarray, shape (n_images,)
        The RPC fits' misfit on their check grids (:func:`fit_rpc`).
    bias_model : str
        Key of ``BIAS_MODELS``.
    true_bias : numpy.ndarray, shape (n_images, 6)
        ``a0, a1, a2, b0, b1, b2`` (px) per image; zero outside the bias model.
    point_ids, kind : numpy.ndarray of str
    lon, lat, h : numpy.ndarray
        The true ground points (degrees, ellipsoidal m).
    obs_point, obs_image : numpy.ndarray of int
        Point and image index of each observation.
    obs_col, obs_row, obs_sigma : numpy.ndarray
        Observed pixel coordinates (``origin`` convention) and their standard deviation.
    sigma_px : float
    origin : str
        ``"corner"``.
    base_to_height : float
        Measured between the first and last image at the scene centre.
    """

    seed: int
    area: SceneArea
    sensors: list
    rpcs: list
    fit_rms_px: np.ndarray
    fit_max_px: np.ndarray
    bias_model: str
    true_bias: np.ndarray
    point_ids: np.ndarray
    kind: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_col: np.ndarray
    obs_row: np.ndarray
    obs_sigma: np.ndarray
    sigma_px: float
    origin: str = "corner"
    base_to_height: float = float("nan")

    @property
    def n_images(self) -> int:
        """Number of images."""
        return len(self.rpcs)

    def true_projection(self, image: int, points=None) -> np.ndarray:
        """Noise-free observations of ``points`` (indices, default all) in ``image``.

        Returns
        -------
        numpy.ndarray, shape (n, 2)
            :func:`biased_project` with the true bias, ``origin`` convention.
        """
        idx = np.arange(len(self.lon)) if points is None else np.asarray(points)
        return biased_project(self.rpcs[image], self.true_bias[image], self.lon[idx],
                              self.lat[idx], self.h[idx], self.origin)


def _layout(area: SceneArea, rng: np.random.Generator, n_control: int, n_check: int,
            n_tie: int, n_road: int) -> tuple[list, np.ndarray, np.ndarray, list]:
    """Ids, local x, y (m) and kinds of the generated scene points."""
    half = 0.5 * area.size_m
    pattern = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1], [0, 0], [0, -1], [0, 1],
                        [-1, 0], [1, 0]], dtype=float) * 0.8
    n_pat = min(n_control, len(pattern))
    ctrl = np.vstack([pattern[:n_pat] + rng.uniform(-0.08, 0.08, (n_pat, 2)),
                      rng.uniform(-0.9, 0.9, (n_control - n_pat, 2))]) * half
    chk = rng.uniform(-0.85, 0.85, (n_check, 2)) * half
    tie = rng.uniform(-0.95, 0.95, (n_tie, 2)) * half
    ids = ([f"GCP{i + 1:02d}" for i in range(n_control)]
           + [f"CHK{i + 1:02d}" for i in range(n_check)]
           + [f"TIE{i + 1:03d}" for i in range(n_tie)])
    kinds = ["control"] * n_control + ["check"] * n_check + ["tie"] * n_tie
    roads = []
    counts = np.diff(np.linspace(0, n_road, 4).round().astype(int))
    for j, n in enumerate(counts):
        s = np.sort(rng.uniform(-0.9, 0.9, n))
        if j == 0:    # a straight road, roughly east-west
            xy = np.column_stack([s, 0.25 + 0.12 * s])
        elif j == 1:  # a straight road, roughly north-south
            xy = np.column_stack([-0.3 + 0.05 * s, s])
        else:         # a curved road: an arc around the south-east
            ang = 0.75 * np.pi * (s + 1.0)
            xy = np.column_stack([0.35 + 0.5 * np.cos(ang), -0.35 + 0.5 * np.sin(ang)])
        roads.append(xy * half)
        ids += [f"RD{j + 1}_{k + 1:03d}" for k in range(n)]
        kinds += ["road"] * n
    xy = np.vstack([ctrl, chk, tie] + roads)
    return ids, xy[:, 0], xy[:, 1], kinds


def _draw_bias(model: str, size_px: float, linear_px: float, n_images: int,
               rng: np.random.Generator) -> np.ndarray:
    """True bias parameters ``(n_images, 6)``: shifts ~ N(0, size), linear ~ N(0, linear)."""
    sigma = np.array([size_px, linear_px, linear_px] * 2)
    draw = rng.normal(0.0, 1.0, (n_images, 6)) * sigma
    out = np.zeros((n_images, 6))
    idx = list(BIAS_MODELS[model])
    out[:, idx] = draw[:, idx]
    return out


def _check_scenario_args(n_images, bias, sigma_px, ground) -> None:
    if n_images not in (2, 3):
        raise ProjectError(f"satellite_scenario: n_images = {n_images!r} is not 2 or 3",
                           "Simulate an along-track pair (2) or triplet (3).")
    if bias not in BIAS_MODELS:
        raise ProjectError(f"satellite_scenario: bias model {bias!r} is unknown",
                           f"Use one of {sorted(BIAS_MODELS)}.")
    if not sigma_px >= 0.0:
        raise ProjectError(f"satellite_scenario: sigma_px = {sigma_px!r} is not >= 0",
                           "Give the image noise as a non-negative standard deviation (px).")
    if ground is not None and not isinstance(ground, (SceneArea, GroundPoints)):
        raise ProjectError("satellite_scenario: ground is neither a SceneArea nor GroundPoints",
                           "Pass SceneArea(...) for a generated scene or GroundPoints(...).")
    if isinstance(ground, GroundPoints):
        if not set(ground.kind) <= set(_KINDS):
            raise ProjectError(f"satellite_scenario: point kinds {sorted(set(ground.kind))} "
                               f"include unknown ones", f"Use only {list(_KINDS)}.")
        sizes = {len(ground.ids), len(ground.kind)} | {
            np.size(a) for a in (ground.lon, ground.lat, ground.h)}
        if len(sizes) != 1 or not len(ground.ids):
            raise ProjectError("satellite_scenario: GroundPoints has fields of lengths "
                               f"{sorted(sizes)}",
                               "Give ids, lon, lat, h and kind of the same, non-zero length.")


def _ground_points(ground, seed: int, counts: tuple[int, int, int, int]):
    """The area and ids, kinds, lon, lat, h of the scene's points."""
    if isinstance(ground, GroundPoints):
        lon, lat, h = (np.asarray(a, dtype=float).ravel() for a in (ground.lon, ground.lat,
                                                                     ground.h))
        area = SceneArea(float(np.mean(lon)), float(np.mean(lat)), h_mean=float(np.mean(h)),
                         h_relief=float(np.ptp(h)) / 2.0)
        return area, list(ground.ids), list(ground.kind), lon, lat, h
    area = ground if isinstance(ground, SceneArea) else SceneArea()
    ids, x, y, kinds = _layout(area, _rng(seed, "layout"), *counts)
    lon, lat = area.to_lonlat(x, y)
    return area, ids, kinds, lon, lat, area.height(x, y)


def _observe(rpcs, sensors, true_bias, lon, lat, h, sigma_px, rng):
    """Observations of every point inside every image: biased RPC projection + noise."""
    pts, imgs, cols, rows = [], [], [], []
    for i, (rpc, sensor) in enumerate(zip(rpcs, sensors)):
        cr = biased_project(rpc, true_bias[i], lon, lat, h, origin="corner")
        noisy = cr + rng.normal(0.0, sigma_px, cr.shape)
        inside = np.flatnonzero((cr[:, 0] >= 0) & (cr[:, 0] <= sensor.n_cols)
                                & (cr[:, 1] >= 0) & (cr[:, 1] <= sensor.n_rows))
        pts.append(inside)
        imgs.append(np.full(len(inside), i))
        cols.append(noisy[inside, 0])
        rows.append(noisy[inside, 1])
    return tuple(np.concatenate(a) for a in (pts, imgs, cols, rows))


def satellite_scenario(
    n_images: int = 2,
    bias: str = "shift",
    bias_size_px: float = 8.0,
    seed: int = 0,
    ground: Union[SceneArea, GroundPoints, None] = None,
    *,
    sigma_px: float = 0.3,
    linear_size_px: Optional[float] = None,
    base_to_height: float = 0.6,
    altitude: float = 600e3,
    gsd: float = 0.5,
    image_size: tuple[int, int] = (8000, 8000),
    rpc_h_range: tuple[float, float] = (-100.0, 500.0),
    drift_sigma: tuple[float, float] = (1e-5, 1e-5),
    n_control: int = 6,
    n_check: int = 10,
    n_tie: int = 30,
    n_road: int = 60,
    geometry_seed: Optional[int] = None,
) -> SatelliteScenario:
    """A simulated satellite stereo scene with known truth.

    Parameters
    ----------
    n_images : {2, 3}
        Forward/backward pair or forward/nadir/backward triplet (:func:`stereo_sensors`).
    bias : str
        Key of ``BIAS_MODELS`` (``"none"``, ``"shift"``, ``"shift+drift"``, ``"affine"``).
    bias_size_px : float
        Standard deviation of the true shifts ``a0, b0`` (px).
    seed : int
    ground : SceneArea or GroundPoints, optional
        The scene (default ``SceneArea()``: lon -87.0, lat 40.4, 3 x 3 km) or explicit
        points.
    sigma_px : float
        Image noise (px), each coordinate.
    linear_size_px : float, optional
        Standard deviation of ``a1, a2, b1, b2`` (px at the image edge);
        ``bias_size_px / 5`` by default.
    base_to_height, altitude, gsd : float
        Geometry (:func:`stereo_sensors`); the satellite flies ``altitude`` above the
        scene centre.
    image_size : (int, int)
        ``(n_cols, n_rows)``; the default 4 x 4 km covers the scene in every image.
    rpc_h_range : (float, float)
        Height range (m) of the RPC fit's domain.
    drift_sigma : (float, float)
        Standard deviations of the attitude drift rates (rad/s) and quadratic terms
        (rad/s^2), and ``drift_sigma[0] * 10 s`` of the yaw (rad).
    n_control, n_check, n_tie, n_road : int
        Points of each kind in a generated scene.
    geometry_seed : int, optional
        Seed of the point layout and the attitude (so of the RPCs); ``seed`` by default.
        Fixing it while ``seed`` varies keeps the scene and images and redraws only the
        bias and the noise (Monte Carlo).

    Returns
    -------
    SatelliteScenario

    Raises
    ------
    vectoradjust.errors.ProjectError
        For an unknown bias model, a wrong number of images, a negative noise or
        inconsistent ``GroundPoints``.
    """
    _check_scenario_args(n_images, bias, sigma_px, ground)
    geo_seed = seed if geometry_seed is None else geometry_seed
    area, ids, kinds, lon, lat, h = _ground_points(
        ground, geo_seed, (n_control, n_check, n_tie, n_road))
    rng = _rng(geo_seed, "attitude")
    drift = rng.normal(0.0, 1.0, (n_images, 3, 2)) * np.asarray(drift_sigma, float)
    sensors = stereo_sensors(area.lon, area.lat, area.h_mean, n_images,
                             base_to_height=base_to_height, altitude=altitude, gsd=gsd,
                             size=image_size, drift=drift,
                             yaw=rng.normal(0.0, 10.0 * drift_sigma[0], n_images))
    rpcs, rms, worst = [], [], []
    for s in sensors:
        lon_r, lat_r = image_domain(s, rpc_h_range)
        rpc, r, m = fit_rpc(lambda lo, la, hh, s=s: pushbroom_project(s, lo, la, hh),
                            lon_r, lat_r, rpc_h_range, s.size, source=f"<simulated {s.name}>")
        rpcs.append(rpc)
        rms.append(r)
        worst.append(m)
    linear = bias_size_px / 5.0 if linear_size_px is None else linear_size_px
    true_bias = _draw_bias(bias, bias_size_px, linear, n_images, _rng(seed, "bias"))
    obs = _observe(rpcs, sensors, true_bias, lon, lat, h, sigma_px, _rng(seed, "noise"))
    return SatelliteScenario(
        seed=int(seed), area=area, sensors=sensors, rpcs=rpcs, fit_rms_px=np.array(rms),
        fit_max_px=np.array(worst), bias_model=bias, true_bias=true_bias,
        point_ids=np.array(ids, dtype=str), kind=np.array(kinds, dtype=str),
        lon=lon, lat=lat, h=h, obs_point=obs[0], obs_image=obs[1], obs_col=obs[2],
        obs_row=obs[3], obs_sigma=np.full(len(obs[0]), float(sigma_px)),
        sigma_px=float(sigma_px), origin="corner",
        base_to_height=stereo_base_to_height(sensors[0], sensors[-1], area.lon, area.lat,
                                             area.h_mean))
