"""Simulated images and image measurements.

The exterior orientation of the strip (:func:`_exterior_orientation`), the image
coordinates of ground points seen on at least two images (:func:`_observe`), the
physical effects a calibrated camera puts into them (:data:`EFFECTS`,
:func:`_physics`: principal point, lens distortion, atmospheric refraction, earth
curvature) and, with ``scan=True``, scanner pixels and measured fiducials
(:func:`_scan_measurements`).

The truth is made by :mod:`vectoradjust.simulate.physics` (quaternion attitude, the ray
cut with the image plane, the effects inverted by Newton's method and in closed form),
a formulation written apart from the product's ``sensor.collinearity.project`` and
``sensor.refine.distort``, so that the corrections recovering the truth is not a round
trip through the same code. The two agree to about 1e-11 mm
(``tests/test_physics_independent.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.model import Camera
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.interior import FiducialMeasurements
from vectoradjust.simulate.geometry import (
    BASE,
    FLYING_HEIGHT,
    FORMAT_HALF,
    TERRAIN_LEVEL,
    _rng,
)
from vectoradjust.simulate.physics import image_of, record

#: Physical effects :func:`make_scenario` can put into the image coordinates (the
#: ``[corrections]`` switches that undo them).
EFFECTS = ("distortion", "refraction", "earth_curvature")
FIDUCIAL_SIGMA = 0.002  # mm, default pointing precision of a fiducial measurement


def _image_ids(n_images: int) -> list:
    """``L, R`` for a stereo pair, ``I01, I02, ...`` for a strip."""
    return ["L", "R"] if n_images == 2 else [f"I{i + 1:02d}" for i in range(n_images)]


def _exterior_orientation(seed: int, n_images: int, cx: float, cy: float,
                          position_noise: float, attitude_noise: float):
    """Flight plan X of every exposure and the true EO ``(n_images, 6)`` around it."""
    rng = _rng(seed, "eo")
    plan_x = cx + (np.arange(n_images) - (n_images - 1) / 2.0) * BASE
    true_eo = np.zeros((n_images, 6))
    true_eo[:, 0] = plan_x + rng.normal(0.0, position_noise, n_images)
    true_eo[:, 1] = cy + rng.normal(0.0, position_noise, n_images)
    true_eo[:, 2] = TERRAIN_LEVEL + FLYING_HEIGHT + rng.normal(0.0, position_noise / 2.0, n_images)
    true_eo[:, 3:] = np.radians(rng.normal(0.0, attitude_noise, (n_images, 3)))
    return plan_x, true_eo


def _observe(xyz, true_eo, camera: Camera, sigma, rng, distortion, min_images=2,
             physics=None):
    """Image measurements of points seen (inside the format) on >= ``min_images`` images.

    ``physics(xy, xyz, pi, ii)`` (optional) turns the ideal coordinates of the seen
    measurements into what the camera records (principal point, distortion,
    refraction, earth curvature); it is applied after the format test and before the
    noise, so that neither the points selected nor the noise drawn depend on it.

    Returns point index, image index and measured xy (mm) per measurement, plus the
    per-point "measured" flag.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    n, m = len(xyz), len(true_eo)
    if n == 0:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)),
                np.zeros(0, bool))
    xy = image_of(true_eo[None, :, :], xyz[:, None, :], camera.focal_length,
                  camera.principal_point)
    if distortion is not None:
        xy = np.asarray(distortion(xy.reshape(-1, 2)), float).reshape(n, m, 2)
    inside = np.all(np.abs(xy) < FORMAT_HALF, axis=2)
    seen = inside.sum(axis=1) >= min_images
    pi, ii = np.nonzero(inside & seen[:, None])
    xy_seen = xy[pi, ii]
    if physics is not None:
        xy_seen = physics(xy_seen, xyz, pi, ii)
    obs = xy_seen + rng.normal(0.0, sigma, (len(pi), 2))
    return pi, ii, obs, seen


@dataclass(frozen=True)
class _Imaging:
    """How a scenario's image measurements are made (see :func:`_observe`)."""

    true_eo: np.ndarray
    view: Camera  # the projection about the principal point; physics adds it (and the effects)
    sigma: float
    distortion: Callable | None
    physics: Callable | None

    @classmethod
    def of(cls, camera: Camera, true_eo: np.ndarray, ids: list, sigma: float,
           distortion: Callable | None, effects: tuple) -> _Imaging:
        """Measurements with ``camera``: its calibration (if any) makes the physics."""
        cal = camera.calibration
        physics = None if cal is None else _physics(cal, effects, true_eo, ids)
        return cls(true_eo, Camera(camera.focal_length, (0.0, 0.0)), sigma, distortion, physics)

    def observe(self, xyz, rng: np.random.Generator):
        """:func:`_observe` of ground points ``xyz`` with noise from ``rng``."""
        return _observe(xyz, self.true_eo, self.view, self.sigma, rng, self.distortion,
                        physics=self.physics)


def _check_effects(effects, calibration, scan) -> tuple:
    if isinstance(effects, str):
        effects = [e for e in effects.replace(",", " ").split() if e]
    effects = tuple(str(e).strip().lower() for e in effects)
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise ProjectError(f"unknown simulated effect(s) {', '.join(map(repr, unknown))}",
                           f"Use any of {', '.join(EFFECTS)}")
    if (effects or scan) and calibration is None:
        raise ProjectError("simulated effects and scanning need a camera calibration",
                           "Pass calibration=CameraCalibration(...) (e.g. from a camera file)")
    if "distortion" in effects and not calibration.has_distortion:
        raise ProjectError("the 'distortion' effect needs a camera with a distortion model",
                           "Give the calibration [distortion] coefficients")
    if scan and (calibration.fiducials is None or calibration.pixel_size is None):
        raise ProjectError("scan=True needs a calibration with fiducials and pixel_size",
                           "Add [fiducials] and pixel_size to the camera")
    # the order of the chain, whatever the order given
    return tuple(e for e in EFFECTS if e in effects)


def _physics(calibration: CameraCalibration, effects: tuple, true_eo: np.ndarray, ids):
    """``(xy about the principal point, xyz, point index, image index) -> recorded mm``.

    :func:`vectoradjust.simulate.physics.record` with each image's TRUE flying height and
    each point's TRUE height (``ids`` is kept for the call signature).
    """

    def apply(xy, xyz, pi, ii):
        return record(xy, calibration, effects, flying_height=true_eo[np.asarray(ii), 2],
                      terrain_height=np.asarray(xyz, float)[np.asarray(pi), 2])

    return apply


def _pixel_mean(calibration: CameraCalibration) -> float:
    sx, sy = calibration.pixel_size
    return math.sqrt(sx * sy)


def _scanner_affines(calibration: CameraCalibration, n_images: int, seed: int) -> np.ndarray:
    """Random scanner affines (pixels -> photo mm), ``(n_images, 6)`` as a0, a1, a2, b0, b1, b2."""
    rng = _rng(seed, "scan")
    sx, sy = calibration.pixel_size
    if calibration.image_size is not None:
        cols, rows = calibration.image_size
    else:
        cols, rows = 2.0 * FORMAT_HALF / sx, 2.0 * FORMAT_HALF / sy
    out = np.zeros((n_images, 6))
    for i in range(n_images):
        theta = math.radians(rng.normal(0.0, 0.3))
        kx, ky = 1.0 + rng.normal(0.0, 1e-4, 2)
        shear = rng.normal(0.0, 1e-4)
        c0 = cols / 2.0 + rng.normal(0.0, 40.0)
        r0 = rows / 2.0 + rng.normal(0.0, 40.0)
        rot = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
        lin = rot @ np.array([[sx * kx, sx * kx * shear], [0.0, -sy * ky]])
        off = -lin @ np.array([c0, r0])
        out[i] = [off[0], lin[0, 0], lin[0, 1], off[1], lin[1, 0], lin[1, 1]]
    return out


def _mm_to_pixel(xy: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Invert ``x = a0 + a1 c + a2 r``, ``y = b0 + b1 c + b2 r`` row by row (vectorised)."""
    a0, a1, a2, b0, b1, b2 = params.T
    dx, dy = xy[:, 0] - a0, xy[:, 1] - b0
    det = a1 * b2 - a2 * b1
    return np.column_stack([(b2 * dx - a2 * dy) / det, (a1 * dy - b1 * dx) / det])


def _measure_fiducials(calibration: CameraCalibration, affines: np.ndarray, ids, seed: int,
                       sigma: float) -> FiducialMeasurements:
    rng = _rng(seed, "fiducials")
    fid_ids = list(calibration.fiducials)
    cal_xy = np.array([calibration.fiducials[f] for f in fid_ids], float)
    m, n = len(ids), len(fid_ids)
    measured = np.tile(cal_xy, (m, 1)) + rng.normal(0.0, sigma, (m * n, 2))
    px = _mm_to_pixel(measured, np.repeat(affines, n, axis=0))
    return FiducialMeasurements(np.repeat(np.asarray(ids, dtype=str), n),
                                np.tile(np.asarray(fid_ids, dtype=str), m), np.round(px, 4),
                                source="fiducials.csv")


def _scan_measurements(xy, sigma, img_index, calibration: CameraCalibration, ids, seed: int,
                       fiducial_sigma: float):
    """Image coordinates (mm) and their sigmas in scanner pixels, and measured fiducials.

    Returns ``(xy, sigma, fiducials, scan_affine)``.
    """
    scan_affine = _scanner_affines(calibration, len(ids), seed)
    xy = _mm_to_pixel(xy, scan_affine[img_index])
    sigma = sigma / _pixel_mean(calibration)
    fiducials = _measure_fiducials(calibration, scan_affine, ids, seed, fiducial_sigma)
    return xy, sigma, fiducials, scan_affine
