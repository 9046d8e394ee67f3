"""A second, independent formulation of the frame camera's physics (the simulator's truth).

The adjustment corrects image coordinates with :mod:`vectoradjust.sensor.collinearity`
and :mod:`vectoradjust.sensor.refine`. A simulator that made its image coordinates with
the same functions (``project`` and ``distort``, the inverse of ``refine``) would only
show that they invert each other. This module is written from the physics, not from
those modules, and imports none of them:

- **attitude**: a unit quaternion composed of three axis-angle rotations (omega about X,
  then phi about the once-rotated Y, then kappa about the twice-rotated Z; the
  sequential omega-phi-kappa of Wolf & Dewitt, *Elements of Photogrammetry*), rotating
  vectors by ``q v q*`` (:func:`attitude_quaternion`, :func:`quaternion_rotate`);
- **projection**: the ray from the perspective centre to the point, in camera axes, cut
  with the image plane ``z = -f`` (:func:`image_of`);
- **lens**: the calibration's correction polynomial (SMAC or odd radial, with
  decentering) gives the ideal position of a recorded one; the recorded position of an
  ideal one is found by Newton's method in the plane with the analytic Jacobian
  (:func:`lens_record`);
- **refraction**: the ARDC 1959 model, ``K`` from the published formula and the outward
  displacement ``dr = K (r + r^3 / f^2)``, inverted by Newton's method on the radius
  (:func:`ardc_constant`, :func:`refraction_record`); and, to check the model itself,
  Snell's law through a layered US Standard Atmosphere 1976 (:func:`traced_refraction`);
- **earth curvature**: in the image plane, ``dr = r^3 H' / (2 R f^2)`` inverted in closed
  form (the real root of the cubic, hyperbolic form; :func:`curvature_record`); and, as
  a fully physical alternative, the map frame wrapped onto a sphere with every camera
  levelled at its own nadir and the rays bent by the atmosphere (:func:`sphere_image`).

:func:`record` chains the image-plane models as a camera records them (earth curvature
and refraction act on the ray before it reaches the lens, the lens last, then the
principal point): the simulator's image coordinates (:mod:`.imaging`, :mod:`.block`).
:func:`sphere_image` is a different model of the same physics, not the product's
model: its agreement with the product's corrections is a measured modelling error
(``tests/test_physics_independent.py``), not a round trip.

Conventions: photo coordinates in millimetres, x right, y up; exterior orientation
``[XL, YL, ZL, omega, phi, kappa]`` (metres, radians); the camera looks along its -z
axis; heights in metres above sea level.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vectoradjust.errors import CameraError

__all__ = [
    "EARTH_RADIUS",
    "quaternion_multiply",
    "quaternion_conjugate",
    "quaternion_rotate",
    "axis_angle_quaternion",
    "attitude_quaternion",
    "camera_vector",
    "image_of",
    "lens_correction",
    "lens_record",
    "ardc_constant",
    "refraction_record",
    "curvature_record",
    "record",
    "standard_atmosphere",
    "refractivity",
    "traced_refraction",
    "sphere_image",
]

#: Mean earth radius (m) of the image-plane earth curvature model (the sphere's radius).
EARTH_RADIUS = 6_371_000.0


# ============================================================================ quaternions
def quaternion_multiply(a: Any, b: Any) -> np.ndarray:
    """Hamilton product ``a b`` of quaternions ``(w, x, y, z)``, shape ``(..., 4)``.

    Parameters
    ----------
    a, b : array_like, shape (..., 4)
        Quaternions, broadcastable.

    Returns
    -------
    numpy.ndarray, shape (..., 4)
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    v = aw * bv + bw * av + np.cross(av, bv)
    return np.concatenate([w, v], axis=-1)


def quaternion_conjugate(q: Any) -> np.ndarray:
    """``q*`` (the inverse rotation of a unit quaternion), shape ``(..., 4)``."""
    q = np.asarray(q, float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quaternion_rotate(q: Any, v: Any) -> np.ndarray:
    """Rotate vectors ``v`` by unit quaternions ``q``: the vector part of ``q v q*``.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions ``(w, x, y, z)``.
    v : array_like, shape (..., 3)
        Vectors, broadcastable against ``q``.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        ``v + 2 w (u x v) + 2 u x (u x v)`` with ``u`` the vector part of ``q``.
    """
    q = np.asarray(q, float)
    v = np.asarray(v, float)
    w, u = q[..., :1], q[..., 1:]
    uv = np.cross(u, v)
    return v + 2.0 * w * uv + 2.0 * np.cross(u, uv)


def axis_angle_quaternion(axis: Any, angle: Any) -> np.ndarray:
    """The unit quaternion of a rotation by ``angle`` (radians) about ``axis``.

    Parameters
    ----------
    axis : array_like, shape (..., 3)
        Rotation axes (need not be unit vectors; a zero axis gives the identity).
    angle : array_like, shape (...)
        Right-handed rotation angles (radians).

    Returns
    -------
    numpy.ndarray, shape (..., 4)
        ``(cos(a/2), sin(a/2) n)`` with ``n`` the unit axis.
    """
    axis = np.asarray(axis, float)
    angle = np.asarray(angle, float)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit = np.divide(axis, norm, out=np.zeros(np.broadcast_shapes(axis.shape, norm.shape)),
                     where=norm > 0)
    half = 0.5 * angle[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * unit], axis=-1)


def attitude_quaternion(omega: Any, phi: Any, kappa: Any) -> np.ndarray:
    """The rotation that carries camera axes into the ground frame, as a quaternion.

    The camera is turned by omega about the ground X axis, then by phi about its once
    rotated Y axis, then by kappa about its twice rotated Z axis (the sequential
    rotations of Wolf & Dewitt). Rotations about the rotated (body) axes compose by
    multiplying on the right: ``q = q_X(omega) q_Y(phi) q_Z(kappa)``, with
    ``q_X(a) = (cos a/2, sin a/2, 0, 0)`` etc. Multiplied out (``c1 = cos omega/2``,
    ``s1 = sin omega/2``, ... ``s3 = sin kappa/2``)::

        w = c1 c2 c3 - s1 s2 s3        x = s1 c2 c3 + c1 s2 s3
        y = c1 s2 c3 - s1 c2 s3        z = c1 c2 s3 + s1 s2 c3

    (``tests/test_physics_independent.py`` checks it against
    :func:`quaternion_multiply` of the three :func:`axis_angle_quaternion`). A camera
    vector ``c`` points along ``quaternion_rotate(q, c)`` in the ground frame.

    Parameters
    ----------
    omega, phi, kappa : array_like
        Angles (radians), broadcastable.

    Returns
    -------
    numpy.ndarray, shape (..., 4)
    """
    o, p, k = np.broadcast_arrays(np.asarray(omega, float), np.asarray(phi, float),
                                  np.asarray(kappa, float))
    c1, s1 = np.cos(0.5 * o), np.sin(0.5 * o)
    c2, s2 = np.cos(0.5 * p), np.sin(0.5 * p)
    c3, s3 = np.cos(0.5 * k), np.sin(0.5 * k)
    return np.stack([c1 * c2 * c3 - s1 * s2 * s3, s1 * c2 * c3 + c1 * s2 * s3,
                     c1 * s2 * c3 - s1 * c2 * s3, c1 * c2 * s3 + s1 * s2 * c3], axis=-1)


def _rotate_back(q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``q* d q`` (the inverse rotation), component by component for speed.

    ``v = d - 2 w (u x d) + 2 u x (u x d)`` with ``u`` the vector part of ``q``.
    """
    w, ux, uy, uz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    cx, cy, cz = uy * dz - uz * dy, uz * dx - ux * dz, ux * dy - uy * dx  # u x d
    ex, ey, ez = uy * cz - uz * cy, uz * cx - ux * cz, ux * cy - uy * cx  # u x (u x d)
    return np.stack([dx - 2.0 * w * cx + 2.0 * ex, dy - 2.0 * w * cy + 2.0 * ey,
                     dz - 2.0 * w * cz + 2.0 * ez], axis=-1)


# ============================================================================ projection
def camera_vector(eo: Any, xyz: Any) -> np.ndarray:
    """The vector from the perspective centre to the object point, in camera axes.

    Parameters
    ----------
    eo : array_like, shape (..., 6)
        ``XL, YL, ZL, omega, phi, kappa``.
    xyz : array_like, shape (..., 3)
        Object points, broadcastable against ``eo``.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        The ground vector ``xyz - (XL, YL, ZL)`` turned back by the attitude (``q* d q``).
    """
    eo = np.asarray(eo, float)
    d = np.asarray(xyz, float) - eo[..., :3]
    q = attitude_quaternion(eo[..., 3], eo[..., 4], eo[..., 5])
    return _rotate_back(q, d)


def _cut_image_plane(v: np.ndarray, focal_length: float) -> np.ndarray:
    """Where the ray ``t v`` (``t > 0``) from the perspective centre meets ``z = -f``.

    NaN for rays that do not meet the plane in front of the camera (``v_z >= 0``).
    """
    vz = v[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(vz < 0.0, -float(focal_length) / vz, np.nan)
    return t[..., None] * v[..., :2]


def image_of(eo: Any, xyz: Any, focal_length: float,
             principal_point: Sequence[float] = (0.0, 0.0)) -> np.ndarray:
    """Ideal photo coordinates of object points: the ray cut with the image plane.

    Parameters
    ----------
    eo : array_like, shape (..., 6)
        ``XL, YL, ZL, omega, phi, kappa`` (metres, radians).
    xyz : array_like, shape (..., 3)
        Object points (metres), broadcastable against ``eo``.
    focal_length : float
        ``f`` (mm): the image plane is ``z = -f`` in camera axes.
    principal_point : (float, float)
        ``x0, y0`` (mm), added to the result.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Photo coordinates (mm); NaN for points behind the camera.
    """
    xy = _cut_image_plane(camera_vector(eo, xyz), focal_length)
    return xy + np.asarray(principal_point, float)


# ============================================================================ lens
def _lens_terms(calibration: Any):
    """Radial (``xb``-multiplying, powers of ``r^2``) and decentering coefficients, the
    sign of the formula and the centre of symmetry about the principal point."""
    model = str(calibration.distortion_model).strip().lower()
    coef = {str(k): float(v) for k, v in dict(calibration.distortion_coefficients).items()}
    if model == "smac":  # dx = xb (K0 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + ...
        radial = [coef.get(f"K{i}", 0.0) for i in range(5)]
    elif model == "polynomial":  # dr = k1 r^3 + ... + k4 r^9, dx = xb dr / r
        radial = [0.0] + [coef.get(f"k{i}", 0.0) for i in range(1, 5)]
    else:
        radial = [0.0] * 5
    decentering = [coef.get(f"P{i}", 0.0) for i in range(1, 5)] if model != "none" else [0.0] * 4
    sign = 1.0 if str(calibration.distortion_convention).lower() == "correction" else -1.0
    pp = np.asarray(calibration.principal_point, float)
    centre = pp if calibration.distortion_center is None else np.asarray(
        calibration.distortion_center, float)
    return radial, decentering, sign, centre - pp


def _lens_formula(u: np.ndarray, radial, decentering):
    """The SMAC formula ``F(u)`` and its Jacobian ``dF/du`` at ``u`` (about the centre)."""
    ux, uy = u[..., 0], u[..., 1]
    s = ux * ux + uy * uy
    rho = sum(k * s**i for i, k in enumerate(radial))
    drho = sum(i * k * s ** (i - 1) for i, k in enumerate(radial) if i > 0)
    p1, p2, p3, p4 = decentering
    g = 1.0 + p3 * s + p4 * s * s
    dg = p3 + 2.0 * p4 * s
    tx = p1 * (s + 2.0 * ux * ux) + 2.0 * p2 * ux * uy
    ty = 2.0 * p1 * ux * uy + p2 * (s + 2.0 * uy * uy)
    f = np.stack([rho * ux + g * tx, rho * uy + g * ty], axis=-1)
    jac = np.empty(u.shape[:-1] + (2, 2))
    # d(rho u)/du = rho I + 2 rho' u u'; d(g t)/du = g dt/du + 2 g' t u'
    jac[..., 0, 0] = rho + 2 * drho * ux * ux + g * (6 * p1 * ux + 2 * p2 * uy) + 2 * dg * tx * ux
    jac[..., 0, 1] = 2 * drho * ux * uy + g * (2 * p1 * uy + 2 * p2 * ux) + 2 * dg * tx * uy
    jac[..., 1, 0] = 2 * drho * uy * ux + g * (2 * p1 * uy + 2 * p2 * ux) + 2 * dg * ty * ux
    jac[..., 1, 1] = rho + 2 * drho * uy * uy + g * (2 * p1 * ux + 6 * p2 * uy) + 2 * dg * ty * uy
    return f, jac


def lens_correction(xy: Any, calibration: Any) -> np.ndarray:
    """The ideal position of recorded photo coordinates (the calibration's formula).

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Recorded coordinates about the principal point (mm).
    calibration : CameraCalibration
        Read for ``distortion_model``, ``distortion_coefficients``,
        ``distortion_convention``, ``distortion_center`` and ``principal_point``.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        ``xy + F(xy - c)`` for the ``"correction"`` convention, ``xy - F(xy - c)`` for
        ``"distortion"`` (``c`` the centre of symmetry about the principal point).
    """
    xy = np.asarray(xy, float)
    radial, decentering, sign, centre = _lens_terms(calibration)
    f, _ = _lens_formula(xy - centre, radial, decentering)
    return xy + sign * f


def lens_record(xy: Any, calibration: Any, tol: float = 1e-12, max_iter: int = 30) -> np.ndarray:
    """Where the lens puts the image of an ideal position: :func:`lens_correction` inverted.

    Newton's method in the plane: ``m <- m - J^-1 (m + s F(m - c) - ideal)`` with the
    analytic Jacobian ``J = I + s dF/dm``.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal coordinates about the principal point (mm).
    calibration : CameraCalibration
    tol : float
        Largest residual accepted (mm).
    max_iter : int

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Recorded coordinates about the principal point (mm).

    Raises
    ------
    CameraError
        When the iteration does not reach ``tol`` (a distortion too strong to invert).
    """
    ideal = np.asarray(xy, float)
    radial, decentering, sign, centre = _lens_terms(calibration)
    m = ideal.copy()
    for _ in range(max_iter):
        f, jac = _lens_formula(m - centre, radial, decentering)
        res = m + sign * f - ideal
        if res.size == 0 or float(np.max(np.abs(res))) <= tol:
            return m
        a = 1.0 + sign * jac[..., 0, 0]
        b = sign * jac[..., 0, 1]
        c = sign * jac[..., 1, 0]
        d = 1.0 + sign * jac[..., 1, 1]
        det = a * d - b * c
        m = m - np.stack([(d * res[..., 0] - b * res[..., 1]) / det,
                          (a * res[..., 1] - c * res[..., 0]) / det], axis=-1)
    raise CameraError(f"the lens distortion could not be inverted to {tol:g} mm in "
                      f"{max_iter} Newton steps",
                      "Check the camera's distortion coefficients and their convention")


# ============================================================================ atmosphere
def ardc_constant(flying_height: Any, terrain_height: Any) -> np.ndarray:
    """Refraction constant ``K`` (radians) of the ARDC 1959 model atmosphere.

    ``K = [2410 H / (H^2 - 6 H + 250) - 2410 h^2 / ((h^2 - 6 h + 250) H)] 1e-6`` with
    ``H`` and ``h`` in kilometres (Wolf & Dewitt, *Elements of Photogrammetry*; the
    model of the U.S. Air Force's Air Research and Development Command, 1959). The ray
    reaching the camera is tilted away from the vertical by ``K tan(theta)``.

    Parameters
    ----------
    flying_height, terrain_height : array_like
        Heights above sea level (metres), broadcastable.

    Returns
    -------
    numpy.ndarray
    """
    big = np.asarray(flying_height, float) / 1000.0
    small = np.asarray(terrain_height, float) / 1000.0
    if np.any(big <= small):
        raise CameraError("a flying height is not above the terrain height",
                          "Heights are above sea level in metres")
    first = 2410.0 * big / (big**2 - 6.0 * big + 250.0)
    second = 2410.0 * small**2 / ((small**2 - 6.0 * small + 250.0) * big)
    return (first - second) * 1e-6


def _radial_scale(xy: np.ndarray, new_r: np.ndarray, r: np.ndarray) -> np.ndarray:
    scale = np.divide(new_r, r, out=np.ones_like(r), where=r > 0)
    return xy * scale[..., None]


def refraction_record(xy: Any, focal_length: float, k: Any, tol: float = 1e-13,
                      max_iter: int = 20) -> np.ndarray:
    """Move ideal photo coordinates outward by atmospheric refraction (ARDC model).

    The recorded radius ``t`` solves ``t - K (t + t^3 / f^2) = r`` (the ideal radius);
    Newton's method on the radius from ``t = r``; the direction is unchanged.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal coordinates about the principal point (mm).
    focal_length : float
    k : array_like, shape (...)
        ``K`` (radians), one per point allowed (:func:`ardc_constant`).
    tol : float
        Convergence of the radius (mm).
    max_iter : int

    Returns
    -------
    numpy.ndarray, shape (..., 2)
    """
    xy = np.asarray(xy, float)
    k = np.broadcast_to(np.asarray(k, float), xy.shape[:-1])
    f2 = float(focal_length) ** 2
    r = np.hypot(xy[..., 0], xy[..., 1])
    t = r.copy()
    for _ in range(max_iter):
        g = t * (1.0 - k) - k * t**3 / f2 - r
        step = g / ((1.0 - k) - 3.0 * k * t * t / f2)
        t = t - step
        if step.size == 0 or float(np.max(np.abs(step))) <= tol:
            return _radial_scale(xy, t, r)
    raise CameraError("the refraction displacement did not converge",
                      "Check the flying and terrain heights")


def curvature_record(xy: Any, focal_length: float, height_above_ground: Any,
                     radius: float = EARTH_RADIUS) -> np.ndarray:
    """Move ideal (flat map frame) photo coordinates inward by earth curvature.

    A point ``D`` from the nadir lies ``D^2 / (2R)`` below the map's plane, so its image
    is nearer the centre: the recorded radius ``t`` solves ``t + a t^3 = r`` with
    ``a = H' / (2 R f^2)``. Its one real root in closed form:
    ``t = 2 / sqrt(3a) sinh(asinh(3 sqrt(3a) r / 2) / 3)`` (from
    ``sinh 3u = 3 sinh u + 4 sinh^3 u``).

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal coordinates about the principal point (mm).
    focal_length : float
    height_above_ground : array_like, shape (...)
        ``H'`` (m), one per point allowed.
    radius : float
        Earth radius (m).

    Returns
    -------
    numpy.ndarray, shape (..., 2)
    """
    xy = np.asarray(xy, float)
    hag = np.broadcast_to(np.asarray(height_above_ground, float), xy.shape[:-1])
    if np.any(hag <= 0):
        raise CameraError("a flying height above ground is not positive",
                          "Check the flying and terrain heights")
    a = hag / (2.0 * float(radius) * float(focal_length) ** 2)
    r = np.hypot(xy[..., 0], xy[..., 1])
    root3a = np.sqrt(3.0 * a)
    t = 2.0 / root3a * np.sinh(np.arcsinh(1.5 * root3a * r) / 3.0)
    return _radial_scale(xy, t, r)


def record(xy: Any, calibration: Any, effects: Sequence[str], flying_height: Any = None,
           terrain_height: Any = None) -> np.ndarray:
    """What the camera records of ideal photo coordinates (the simulator's physics).

    In the order light meets them: earth curvature and refraction (on the ray, before
    the lens), lens distortion, then the principal point is added.

    Parameters
    ----------
    xy : array_like, shape (n, 2)
        Ideal (flat map frame) coordinates about the principal point (mm).
    calibration : CameraCalibration
    effects : sequence of str
        Any of ``"distortion"``, ``"refraction"``, ``"earth_curvature"``.
    flying_height, terrain_height : array_like, optional
        ``ZL`` of the image and the point's height (m above sea level), per point
        allowed; needed by refraction and earth curvature.

    Returns
    -------
    numpy.ndarray, shape (n, 2)
        Recorded coordinates in the fiducial frame (mm).
    """
    out = np.asarray(xy, float)
    f = float(calibration.focal_length)
    if "earth_curvature" in effects:
        out = curvature_record(out, f, np.asarray(flying_height, float)
                               - np.asarray(terrain_height, float))
    if "refraction" in effects:
        out = refraction_record(out, f, ardc_constant(flying_height, terrain_height))
    if "distortion" in effects:
        out = lens_record(out, calibration)
    return out + np.asarray(calibration.principal_point, float)


# ---------------------------------------------------------------- a layered atmosphere
# US Standard Atmosphere 1976 (NOAA/NASA/USAF): sea level 288.15 K and 101325 Pa, lapse
# rate 6.5 K/km to 11 km, isothermal above (to 20 km); g0 = 9.80665 m/s^2, molar mass of
# air 0.0289644 kg/mol, gas constant 8.31432 J/(mol K) (the standard's own value).
_T0, _P0, _LAPSE, _TROPOPAUSE = 288.15, 101325.0, 0.0065, 11000.0
_GMR = 9.80665 * 0.0289644 / 8.31432


def standard_atmosphere(z: Any) -> tuple[np.ndarray, np.ndarray]:
    """Temperature (K) and pressure (Pa) of the US Standard Atmosphere 1976 up to 20 km.

    Parameters
    ----------
    z : array_like
        Geopotential height (m).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``T``, ``P``.
    """
    z = np.asarray(z, float)
    low = np.minimum(z, _TROPOPAUSE)
    temp = _T0 - _LAPSE * low
    pres = _P0 * (temp / _T0) ** (_GMR / _LAPSE)
    above = np.maximum(z - _TROPOPAUSE, 0.0)
    pres = pres * np.exp(-_GMR * above / temp)
    return temp, pres


def refractivity(z: Any, wavelength: float = 0.55) -> np.ndarray:
    """``n - 1`` of dry air at height ``z`` (m) of the standard atmosphere.

    Edlen (1966) for standard air (15 degrees C, 101325 Pa):
    ``(n_s - 1) 1e8 = 8342.13 + 2406030 / (130 - s^2) + 15997 / (38.9 - s^2)``,
    ``s = 1 / wavelength`` (micrometres), scaled with the density (Gladstone-Dale):
    ``(n - 1) = (n_s - 1) (P / 101325) (288.15 / T)``.

    Parameters
    ----------
    z : array_like
        Height (m).
    wavelength : float
        Micrometres (0.55: the middle of the visible band).

    Returns
    -------
    numpy.ndarray
    """
    s2 = 1.0 / float(wavelength) ** 2
    ns = (8342.13 + 2406030.0 / (130.0 - s2) + 15997.0 / (38.9 - s2)) * 1e-8
    temp, pres = standard_atmosphere(z)
    return ns * (pres / 101325.0) * (288.15 / temp)


def _layered_distance(theta_top, n_top, n_layers, dz):
    """Horizontal run of a ray through flat homogeneous layers and its derivative.

    Snell's law at every interface: ``n_i sin(theta_i) = n_top sin(theta_top)``.
    """
    s = n_top[..., None] * np.sin(theta_top)[..., None] / n_layers
    c = np.sqrt(1.0 - s * s)
    dist = np.sum(dz[..., None] * s / c, axis=-1)
    dtheta = n_top[..., None] * np.cos(theta_top)[..., None] / (n_layers * c)
    deriv = np.sum(dz[..., None] * dtheta / (c * c), axis=-1)
    return dist, deriv


def traced_refraction(flying_height: Any, terrain_height: Any, nadir_angle: Any,
                      layers: int = 400, wavelength: float = 0.55) -> np.ndarray:
    """Refraction angle at the camera by Snell's law through a layered standard atmosphere.

    The air between the point (height ``h``) and the camera (``H``) is cut into
    ``layers`` flat homogeneous layers with the index of refraction of the US Standard
    Atmosphere 1976 at their middles (:func:`refractivity`). The ray that leaves the
    point and reaches the camera travels the same horizontal distance as the straight
    line (the chord) at ``nadir_angle``; its direction at the camera is found by
    Newton's method on that distance.

    Parameters
    ----------
    flying_height, terrain_height : array_like
        Heights above sea level (m), broadcastable.
    nadir_angle : array_like
        Angle of the chord from the camera's vertical (radians), below 80 degrees.
    layers : int
        Number of layers.
    wavelength : float
        Micrometres.

    Returns
    -------
    numpy.ndarray
        Apparent minus chord nadir angle (radians, positive: the image is displaced
        away from the nadir). ``K = delta / tan(nadir_angle)`` compares with
        :func:`ardc_constant`.
    """
    big, small, chord = np.broadcast_arrays(np.asarray(flying_height, float),
                                            np.asarray(terrain_height, float),
                                            np.asarray(nadir_angle, float))
    frac = (np.arange(layers) + 0.5) / layers
    dz = (big - small) / layers
    n_layers = 1.0 + refractivity(small[..., None] + frac * (big - small)[..., None],
                                  wavelength)
    n_top = 1.0 + refractivity(big, wavelength)
    target = (big - small) * np.tan(chord)
    theta = chord.copy()
    for _ in range(30):
        dist, deriv = _layered_distance(theta, n_top, n_layers, dz)
        step = np.divide(dist - target, deriv, out=np.zeros_like(dist), where=deriv > 0)
        theta = theta - step
        if step.size == 0 or float(np.max(np.abs(step))) < 1e-15:
            break
    return theta - chord


# ============================================================================ the sphere
def _on_sphere(xy: np.ndarray, z: np.ndarray, center: np.ndarray, radius: float,
               datum: float):
    """Map coordinates wrapped onto a sphere (azimuthal equidistant about ``center``).

    Map distances from ``center`` are arcs at height ``datum``. Returns the points in a
    frame with its origin at the earth's centre and its axes east, north, up at
    ``center``; the central angle and the unit map direction from ``center``.
    """
    d = xy - center
    dist = np.hypot(d[..., 0], d[..., 1])
    unit = np.where(dist[..., None] > 0, d / np.where(dist > 0, dist, 1.0)[..., None],
                    np.array([1.0, 0.0]))
    ang = dist / (radius + datum)
    up = np.stack([np.sin(ang) * unit[..., 0], np.sin(ang) * unit[..., 1], np.cos(ang)], -1)
    return (radius + z)[..., None] * up, ang, unit


def _bend(v: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Tilt direction vectors (local level axes, pointing down) away from the nadir."""
    h = np.hypot(v[..., 0], v[..., 1])
    theta = np.arctan2(h, -v[..., 2]) + delta
    norm = np.linalg.norm(v, axis=-1)
    horiz = np.divide(v[..., :2], h[..., None], out=np.zeros(v.shape[:-1] + (2,)),
                      where=h[..., None] > 0)
    return norm[..., None] * np.concatenate(
        [np.sin(theta)[..., None] * horiz, -np.cos(theta)[..., None]], axis=-1)


def sphere_image(eo: Any, xyz: Any, focal_length: float, center: Sequence[float], *,
                 radius: float = EARTH_RADIUS, datum_height: float = 0.0,
                 refraction: str | None = None, layers: int = 400) -> np.ndarray:
    """Photo coordinates on a round earth, the rays optionally bent by the atmosphere.

    The map frame is wrapped onto a sphere of radius ``radius`` at sea level
    (azimuthal equidistant about ``center``: map distance from ``center`` = arc length
    at ``datum_height``; ``Z`` = height above sea level). Every camera stands ``ZL``
    above sea level over its map position and its attitude is taken relative to its
    own local level (the centre's east-north-up carried along the great circle to the
    camera's nadir). With ``refraction`` the ray is tilted away from the camera's
    vertical by the refraction angle.

    Parameters
    ----------
    eo : array_like, shape (n, 6)
        Exterior orientation, map frame (m, rad).
    xyz : array_like, shape (n, 3)
        Object points, map frame.
    focal_length : float
    center : (float, float)
        The map point where the sphere touches the map plane.
    radius : float
        Sphere radius at sea level (m).
    datum_height : float
        Height (m) at which the map's scale is true (0: sea level, as in a map
        projection; the terrain's height: a project frame at ground scale). Away from
        it, horizontal distances are ``(R + Z) / (R + datum)`` times the map's: the
        grid-to-ground scale, which the image-plane earth curvature model does not
        contain (measured: 4.3 um at the sample's format corners with ``datum = 0``,
        0.13 um with the terrain's height).
    refraction : {None, "ardc", "traced"}
        None: straight rays; ``"ardc"``: ``K tan(theta)`` with :func:`ardc_constant`;
        ``"traced"``: :func:`traced_refraction` (US Standard Atmosphere 1976).
    layers : int
        Layers of the traced atmosphere.

    Returns
    -------
    numpy.ndarray, shape (n, 2)
        Photo coordinates about the principal point (mm), no lens distortion.
    """
    eo = np.atleast_2d(np.asarray(eo, float))
    xyz = np.atleast_2d(np.asarray(xyz, float))
    c = np.asarray(center, float)
    point, _, _ = _on_sphere(xyz[:, :2], xyz[:, 2], c, radius, datum_height)
    station, ang, unit = _on_sphere(eo[:, :2], eo[:, 2], c, radius, datum_height)
    axis = np.stack([-unit[:, 1], unit[:, 0], np.zeros(len(unit))], axis=-1)
    level = axis_angle_quaternion(axis, ang)  # centre's level axes -> the nadir's
    v = quaternion_rotate(quaternion_conjugate(level), point - station)
    if refraction is not None:
        theta = np.arctan2(np.hypot(v[:, 0], v[:, 1]), -v[:, 2])
        if refraction == "ardc":
            delta = ardc_constant(eo[:, 2], xyz[:, 2]) * np.tan(theta)
        elif refraction == "traced":
            delta = traced_refraction(eo[:, 2], xyz[:, 2], theta, layers=layers)
        else:
            raise ValueError(f"unknown refraction model {refraction!r}")
        v = _bend(v, delta)
    q = attitude_quaternion(eo[:, 3], eo[:, 4], eo[:, 5])
    return _cut_image_plane(_rotate_back(q, v), focal_length)
