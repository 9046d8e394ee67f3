"""The simulated scene: area, ground points and :func:`satellite_scenario`, which observes
them on the images with known truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.sensor.rpc import BIAS_MODELS
from vectoradjust.simulate.satellite.geodesy import WGS84_A, WGS84_E2, _rng
from vectoradjust.simulate.satellite.pushbroom import (
    pushbroom_project,
    stereo_base_to_height,
    stereo_sensors,
)
from vectoradjust.simulate.satellite.rpc_fit import biased_project, fit_rpc, image_domain

__all__ = ["SceneArea", "GroundPoints", "SatelliteScenario", "satellite_scenario"]


_KINDS = ("control", "check", "tie", "road")



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


def _sensors(area: SceneArea, n_images: int, rng: np.random.Generator, drift_sigma,
             **geometry) -> list:
    """The true pushbroom sensors (:func:`stereo_sensors` with ``geometry``: base_to_height,
    altitude, gsd, size) with random attitude drift and yaw (drawn in that order)."""
    drift = rng.normal(0.0, 1.0, (n_images, 3, 2)) * np.asarray(drift_sigma, float)
    return stereo_sensors(area.lon, area.lat, area.h_mean, n_images, drift=drift,
                          yaw=rng.normal(0.0, 10.0 * drift_sigma[0], n_images), **geometry)


def _fit_rpcs(sensors: list, rpc_h_range) -> tuple[list, list, list]:
    """The RPCs fitted to every sensor over its image domain and their misfits (RMS, max)."""
    rpcs, rms, worst = [], [], []
    for s in sensors:
        lon_r, lat_r = image_domain(s, rpc_h_range)
        rpc, r, m = fit_rpc(lambda lo, la, hh, s=s: pushbroom_project(s, lo, la, hh),
                            lon_r, lat_r, rpc_h_range, s.size, source=f"<simulated {s.name}>")
        rpcs.append(rpc)
        rms.append(r)
        worst.append(m)
    return rpcs, rms, worst


def satellite_scenario(
    n_images: int = 2,
    bias: str = "shift",
    bias_size_px: float = 8.0,
    seed: int = 0,
    ground: Union[SceneArea, GroundPoints, None] = None,
    *,
    sigma_px: float = 0.3, linear_size_px: Optional[float] = None,
    base_to_height: float = 0.6, altitude: float = 600e3, gsd: float = 0.5,
    image_size: tuple[int, int] = (8000, 8000),
    rpc_h_range: tuple[float, float] = (-100.0, 500.0),
    drift_sigma: tuple[float, float] = (1e-5, 1e-5),
    n_control: int = 6, n_check: int = 10, n_tie: int = 30, n_road: int = 60,
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
    sensors = _sensors(area, n_images, _rng(geo_seed, "attitude"), drift_sigma,
                       base_to_height=base_to_height, altitude=altitude, gsd=gsd, size=image_size)
    rpcs, rms, worst = _fit_rpcs(sensors, rpc_h_range)
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

