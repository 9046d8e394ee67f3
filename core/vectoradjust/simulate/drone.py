"""A simulated drone block over real road geometry, its road database as the control.

:func:`make_drone_block` flies ``n_strips`` north-south strips of a DJI-like frame camera
(:data:`DJI_CAMERA`: ``f = 8.8 mm``, 13.2 x 8.8 mm sensor, 5472 x 3648 px, 2.41 um
pixels) over real road centrelines (a :class:`~vectoradjust.simulate.real_roads.RoadLines`,
e.g. the Helsinki window of ``tests/data/helsinki``), nadir with a small random
attitude, and measures every road vertex (shape point) on every image that sees it.
It returns the :class:`~vectoradjust.model.ProjectData` the pipeline needs (as
``make_scenario(...).to_project_data()`` does for the stereo set-up) and the truth.

The error model (issue 29, "roads as control"):

- the road database (``OSM``): the true vertices plus a systematic error common to all
  of them, ``N(0, systematic_sigma)`` (horizontal per axis, vertical), plus per object
  point ``N(0, sqrt(sigma^2 - systematic_sigma^2))``; its ``[[vectors]]`` entry states
  exactly that (``sigma``, ``systematic_sigma``, ``role = "control"``) and the heights
  come from the layer (no DEM);
- the analyst's identification of a vertex on the images: the measured point is the
  true vertex moved ``N(0, identification)`` per horizontal axis, on the terrain
  (stated as ``identification_sigma = (identification, 0)``);
- the image coordinates: the ideal projection (:func:`vectoradjust.simulate.physics.image_of`,
  written apart from ``sensor/``) plus ``N(0, pixel_sigma)`` pixels;
- the approximate camera positions (EXIF-like GPS): the true ones plus ``N(0, gps_sigma)``
  on every axis, stated as ``sigma_position = gps_sigma``; the approximate attitude is the
  flight plan's (nadir, ``kappa`` along the strip), with no prior by default.

No control points. The random streams are those of
:func:`vectoradjust.simulate.geometry._rng` (one per component), so the same seed gives
the same block and measurements whatever the database error drawn.

Numpy and scipy only (through the sibling simulation modules).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.adjust.shapepoints import vertex_ids
from vectoradjust.model import (
    AdjustmentSettings,
    Camera,
    ControlPoints,
    ImageSpec,
    LineLayer,
    Measurements,
    ProjectData,
    VectorSpec,
)
from vectoradjust.simulate.geometry import _rng, terrain_height
from vectoradjust.simulate.physics import image_of
from vectoradjust.simulate.real_roads import RoadLines, _real_roads

__all__ = ["DroneCamera", "DJI_CAMERA", "DroneBlock", "flight_plan", "make_drone_block"]


@dataclass(frozen=True)
class DroneCamera:
    """A frame camera without distortion (principal point at the centre).

    Attributes
    ----------
    focal_length : float
        mm.
    sensor : (float, float)
        Sensor width (along photo x) and height (along photo y), mm.
    pixels : (int, int)
        Image width and height in pixels.
    name : str
    """

    focal_length: float
    sensor: tuple
    pixels: tuple
    name: str = "frame camera"

    @property
    def pixel_size(self) -> float:
        """Pixel pitch (mm)."""
        return float(self.sensor[0]) / float(self.pixels[0])

    def footprint(self, height: float) -> tuple:
        """Ground width and height (m) of a nadir image ``height`` m above the terrain."""
        s = float(height) / self.focal_length
        return float(self.sensor[0]) * s, float(self.sensor[1]) * s


#: a DJI Phantom 4 Pro-like camera (1" sensor)
DJI_CAMERA = DroneCamera(8.8, (13.2, 8.8), (5472, 3648), "DJI FC6310-like")
TERRAIN_LEVEL = 12.0  # m: roughly the height of central Helsinki above sea level
FORMAT_MARGIN_PX = 10.0  # a point this close to the image edge is not measured


@dataclass
class DroneBlock:
    """A simulated drone block, its project data and the truth.

    Attributes
    ----------
    data : vectoradjust.model.ProjectData
        Images (approximate EO and priors), measurements (mm), no control points, the
        road database (``data.vectors[0]``) and ``data.truth`` (every vertex's true XYZ).
    true_eo : numpy.ndarray, shape (n, 6)
        True ``XL, YL, ZL, omega, phi, kappa`` (m, radians), in ``data.images`` order.
    systematic : numpy.ndarray, shape (3,)
        The database's systematic error drawn for this block (m).
    strip, column : numpy.ndarray of int, shape (n,)
        Strip and position along the strip of every image.
    base, spacing : float
        Distance between exposures along a strip and between strips (m).
    measured_points : int
        Object points (distinct road vertices) measured on at least two images.
    options : dict
        The arguments of :func:`make_drone_block`.
    """

    data: ProjectData
    true_eo: np.ndarray
    systematic: np.ndarray
    strip: np.ndarray
    column: np.ndarray
    base: float
    spacing: float
    measured_points: int
    options: dict = field(default_factory=dict)


def flight_plan(center, n_strips: int, per_strip: int, footprint: tuple, forward: float,
                side: float) -> tuple:
    """Nominal exposure stations of north-south strips, alternating direction.

    Photo x (the long side) points east on strips flown north (``kappa = 0``) and west
    on strips flown south (``kappa = pi``).

    Parameters
    ----------
    center : (float, float)
        Block centre (m).
    n_strips, per_strip : int
    footprint : (float, float)
        Ground width (across the strip, photo x) and length (along, photo y), m.
    forward, side : float
        Forward and side overlap (0-1).

    Returns
    -------
    xy : numpy.ndarray, shape (n, 2)
    kappa : numpy.ndarray, shape (n,)
        Nominal kappa (radians).
    strip, column : numpy.ndarray of int
    base, spacing : float
        Along-strip and between-strip distances (m).
    """
    base = (1.0 - forward) * footprint[1]
    spacing = (1.0 - side) * footprint[0]
    strip = np.repeat(np.arange(n_strips), per_strip)
    column = np.tile(np.arange(per_strip), n_strips)
    south = strip % 2 == 1
    along = np.where(south, per_strip - 1 - column, column)  # flown back and forth
    xy = np.column_stack([
        center[0] + (strip - (n_strips - 1) / 2.0) * spacing,
        center[1] + (along - (per_strip - 1) / 2.0) * base,
    ])
    kappa = np.where(south, math.pi, 0.0)
    return xy, kappa, strip, column, float(base), float(spacing)


def _true_eo(seed, xy, kappa, height, center, position_noise, attitude_noise):
    """True EO about the plan: position noise (m; half of it in Z) and attitude (deg)."""
    rng = _rng(seed, "drone-eo")
    n = len(xy)
    eo = np.zeros((n, 6))
    eo[:, :2] = xy + rng.normal(0.0, position_noise, (n, 2))
    ground = terrain_height(xy[:, 0], xy[:, 1], center) - terrain_height(
        center[0], center[1], center) + TERRAIN_LEVEL
    eo[:, 2] = ground + height + rng.normal(0.0, position_noise / 2.0, n)
    eo[:, 3:] = np.radians(rng.normal(0.0, attitude_noise, (n, 3)))
    eo[:, 5] += kappa
    return eo


def _terrain(xy: np.ndarray, center) -> np.ndarray:
    """True terrain height (m): the simulator's gentle terrain about ``TERRAIN_LEVEL``."""
    return (terrain_height(xy[:, 0], xy[:, 1], center)
            - terrain_height(center[0], center[1], center) + TERRAIN_LEVEL)


def _road_layer(roads, name: str, crs: str) -> tuple:
    """The true roads as a line layer (one feature per piece): layer, object point of
    every vertex, and the first vertex of every object point."""
    feat = np.repeat(roads.part_feature, np.diff(roads.part_ptr))
    first = np.searchsorted(feat, feat, side="left")
    vindex = np.arange(len(feat)) - first
    n_feat = len(roads.name)
    fids = np.array([f"w{i + 1}" for i in range(n_feat)], dtype=object)
    attrs = {"osm_id": list(fids), "name": list(roads.name), "highway": list(roads.highway)}
    coords = np.column_stack([roads.coords, np.full(len(feat), np.nan)])
    layer = LineLayer(name, fids, attrs, coords, feat, vindex, np.zeros(len(feat), np.int64),
                      crs=crs, source=f"{name.lower()}_roads.gpkg")
    _, group_first, group = np.unique(roads.coords, axis=0, return_index=True,
                                      return_inverse=True)
    return layer, np.asarray(group).reshape(-1), group_first


def _database_errors(seed, n_points, sigma, systematic_sigma):
    """The systematic error (3,) and the per-point random errors (n, 3)."""
    sig = np.array([sigma[0], sigma[1], sigma[2]], float)
    sys_ = np.array([systematic_sigma[0], systematic_sigma[0], systematic_sigma[1]], float)
    rand = np.sqrt(np.maximum(sig**2 - sys_**2, 0.0))
    shift = _rng(seed, "drone-systematic").normal(0.0, 1.0, 3) * sys_
    noise = _rng(seed, "drone-random").normal(0.0, 1.0, (n_points, 3)) * rand
    return shift, noise


def _observe(seed, camera: DroneCamera, true_eo, xyz, pixel_sigma):
    """Point index, image index and noisy photo coordinates (mm) of the points seen
    inside the format (less a margin) on at least two images."""
    xy = image_of(true_eo[None, :, :], xyz[:, None, :], camera.focal_length)
    half = np.array(camera.sensor, float) / 2.0 - FORMAT_MARGIN_PX * camera.pixel_size
    with np.errstate(invalid="ignore"):
        inside = np.all(np.abs(xy) < half, axis=2)
    seen = inside.sum(axis=1) >= 2
    pi, ii = np.nonzero(inside & seen[:, None])
    rng = _rng(seed, "drone-image")
    obs = xy[pi, ii] + rng.normal(0.0, pixel_sigma * camera.pixel_size, (len(pi), 2))
    return pi, ii, obs


def _images(seed, true_eo, kappa, gps_sigma, sigma_attitude, use_gps: bool = True) -> list:
    """Approximate EO: GPS positions (truth + noise), the plan's attitude (degrees); without
    ``use_gps`` no position prior."""
    rng = _rng(seed, "drone-gps")
    pos = true_eo[:, :3] + rng.normal(0.0, gps_sigma, (len(true_eo), 3))
    images = [ImageSpec(f"DJI_{i + 1:04d}", pos[i], np.array([0.0, 0.0, math.degrees(k)]),
                        gps_sigma, sigma_attitude)
              for i, k in enumerate(kappa)]
    if not use_gps:
        for im in images:
            im.sigma_position = None
    return images


def _roads_of(roads, center, name: str, crs: str) -> tuple:
    """The road lines, the block centre (default: the middle of the roads' bounding box),
    and the true roads as a layer with the object point of every vertex and the first
    vertex of every object point (:func:`_road_layer`)."""
    lines = RoadLines.of(roads)
    allxy = np.concatenate(lines.lines)
    if center is None:
        center = tuple(0.5 * (allxy.min(axis=0) + allxy.max(axis=0)))
    center = (float(center[0]), float(center[1]))
    true_roads, _ = _real_roads(lines, 0.5 * (allxy.min(axis=0) + allxy.max(axis=0)))
    layer, group, group_first = _road_layer(true_roads, name, crs)
    return lines, center, layer, group, group_first


def _database(seed, layer: LineLayer, group: np.ndarray, group_first: np.ndarray, center,
              sigma, systematic_sigma) -> tuple:
    """Put the database error into ``layer`` (in place): its true vertices on the terrain
    plus the systematic and the per-point errors (:func:`_database_errors`).

    Returns the object points' true XY ``(m, 2)`` and XYZ ``(m, 3)`` and the systematic
    error ``(3,)``.
    """
    pts_xy = layer.coords[group_first, :2]
    true_xyz = np.column_stack([pts_xy, _terrain(pts_xy, center)])
    shift, noise = _database_errors(seed, len(group_first), sigma, systematic_sigma)
    layer.coords = true_xyz[group] + shift + noise[group]
    return pts_xy, true_xyz, shift


def _project_data(seed, crs: str, camera: DroneCamera, images: list, meas: Measurements,
                  spec: VectorSpec, layer: LineLayer, truth: tuple) -> ProjectData:
    """The block's project data: no control points, the road database as the control."""
    name = spec.name
    return ProjectData(
        crs=crs, camera=Camera(camera.focal_length, (0.0, 0.0)), images=images,
        measurements=meas,
        control=ControlPoints(np.zeros(0, str), np.zeros((0, 3)), np.zeros((0, 3)),
                              np.zeros(0, str), source="<no control>"),
        vectors=[(spec, layer)], settings=AdjustmentSettings(),
        truth={name: truth},
        corrections={"refraction": False, "earth_curvature": False},
        source=f"<simulated drone block, seed {seed}>")


def _vector_spec(name, sigma, systematic_sigma, identification, role) -> VectorSpec:
    return VectorSpec(
        name=name, path=f"{name.lower()}_roads.gpkg", id_field="osm_id",
        sigma=tuple(float(s) for s in sigma), identification_sigma=(
            (float(identification), 0.0) if identification > 0 else None),
        offset="none" if role == "control" else "shift", role=role,
        systematic_sigma=(None if systematic_sigma is None or not any(systematic_sigma)
                          else tuple(float(s) for s in systematic_sigma)))


def make_drone_block(
    roads, seed: int = 0, *, n_strips: int = 5, per_strip: int = 10,
    flying_height: float = 110.0, forward_overlap: float = 0.75, side_overlap: float = 0.65,
    camera: DroneCamera = DJI_CAMERA, pixel_sigma: float = 1.0, identification: float = 0.2,
    sigma: tuple = (1.5, 1.5, 3.0), systematic_sigma: tuple = (1.0, 2.0),
    stated_systematic: Optional[tuple] = None, gps_sigma: float = 3.0, use_gps: bool = True,
    position_noise: float = 2.0, attitude_noise: float = 1.5,
    sigma_attitude: Optional[float] = None, center: Optional[tuple] = None,
    crs: str = "EPSG:32635", name: str = "OSM",
) -> DroneBlock:
    """Simulate a drone block over real roads whose database is the only control.

    Parameters
    ----------
    roads : RoadLines, str, pathlib.Path or sequence of (n, 2) arrays
        The true road centrelines (projected CRS, m); split into features at shared
        vertices (:func:`vectoradjust.simulate.real_roads._real_roads`). Their vertices
        are the database's vertices.
    seed : int
    n_strips, per_strip : int
        Block layout (default 5 x 10 = 50 images).
    flying_height : float
        Above the terrain (m); 110 m gives 3.0 cm pixels with :data:`DJI_CAMERA`.
    forward_overlap, side_overlap : float
    camera : DroneCamera
    pixel_sigma : float
        Image coordinate noise (pixels, per axis).
    identification : float
        The analyst's identification error per horizontal axis (m, object space).
    sigma : (float, float, float)
        The database's whole error per axis (m), stated in its ``[[vectors]]`` entry.
    systematic_sigma : (float, float)
        Its systematic part (horizontal per axis, vertical; m): simulated.
    stated_systematic : (float, float), optional
        The systematic part stated in ``[[vectors]]`` (default: ``systematic_sigma``;
        ``(0, 0)`` states none, the wrong model).
    gps_sigma : float
        Camera position error of the EXIF-like GPS (m, every axis) and its prior sigma.
    use_gps : bool
        False: no camera position prior (the road database alone fixes the datum).
    position_noise, attitude_noise : float
        True EO about the flight plan (m, half in Z; degrees).
    sigma_attitude : float, optional
        Attitude prior (degrees); None: free.
    center : (float, float), optional
        Block centre; default the centre of the roads' bounding box.
    crs : str
        The roads' CRS (default UTM 35N, Helsinki).
    name : str
        Database name.

    Returns
    -------
    DroneBlock
    """
    args = dict(locals())  # the arguments as given, for DroneBlock.options
    lines, center, layer, group, group_first = _roads_of(roads, center, name, crs)
    xy, kappa, strip, column, base, spacing = flight_plan(
        center, n_strips, per_strip, camera.footprint(flying_height), forward_overlap,
        side_overlap)
    true_eo = _true_eo(seed, xy, kappa, flying_height, center, position_noise, attitude_noise)
    pts_xy, true_xyz, shift = _database(seed, layer, group, group_first, center, sigma,
                                        systematic_sigma)
    pi, ii, obs = _identify_and_observe(seed, camera, true_eo, pts_xy, center, identification,
                                        pixel_sigma)
    images = _images(seed, true_eo, kappa, gps_sigma if use_gps else 0.0, sigma_attitude,
                     use_gps)
    vid = vertex_ids(layer)
    meas = Measurements(vid[group_first[pi]], np.array([im.id for im in images])[ii], obs,
                        pixel_sigma * camera.pixel_size, source="image_points.csv")
    stated = systematic_sigma if stated_systematic is None else stated_systematic
    spec = _vector_spec(name, sigma, stated, identification, "control")
    data = _project_data(seed, crs, camera, images, meas, spec, layer,
                         (vid, true_xyz[group]))
    options = _options(args, stated, lines.source)
    return DroneBlock(data, true_eo, shift, strip, column, base, spacing,
                      int(len(np.unique(pi))), options)


def _identify_and_observe(seed, camera: DroneCamera, true_eo: np.ndarray, pts_xy: np.ndarray,
                          center, identification: float, pixel_sigma: float) -> tuple:
    """The analyst identifies each object point ``N(0, identification)`` off (per horizontal
    axis, on the terrain); its observations (:func:`_observe`)."""
    ident_xy = pts_xy + _rng(seed, "drone-identification").normal(
        0.0, identification, pts_xy.shape)
    seen_xyz = np.column_stack([ident_xy, _terrain(ident_xy, center)])
    return _observe(seed, camera, true_eo, seen_xyz, pixel_sigma)


def _options(args: dict, stated, roads_source) -> dict:
    """The arguments of :func:`make_drone_block` as :attr:`DroneBlock.options` records them."""
    use_gps = args["use_gps"]
    return {"seed": int(args["seed"]), "n_strips": args["n_strips"],
            "per_strip": args["per_strip"], "flying_height": args["flying_height"],
            "forward_overlap": args["forward_overlap"], "side_overlap": args["side_overlap"],
            "camera": args["camera"].name, "pixel_sigma": args["pixel_sigma"],
            "identification": args["identification"], "sigma": list(args["sigma"]),
            "systematic_sigma": list(args["systematic_sigma"]),
            "stated_systematic": list(stated),
            "gps_sigma": args["gps_sigma"] if use_gps else None,
            "sigma_attitude": args["sigma_attitude"], "roads": roads_source}
