"""The pushbroom sensor on a circular orbit: projection of ground points, rays,
localisation, and stereo sensors for a base-to-height ratio.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.simulate.satellite.geodesy import (
    GM_EARTH,
    WGS84_A,
    WGS84_E2,
    _enu,
    _shift,
    _unit,
    ecef_to_geodetic,
    geodetic_to_ecef,
)

__all__ = [
    "CircularOrbit", "PushbroomSensor", "pushbroom_project", "pushbroom_ray",
    "pushbroom_localize", "stereo_sensors", "stereo_base_to_height",
]


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

