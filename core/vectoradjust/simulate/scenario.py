"""Deterministic simulation of the dissertation's stereo set-up (``docs/method.md`` sections 1, 9).

:func:`make_scenario` builds, from a seed, everything an adjustment needs plus the
truth to judge it by: a strip of vertical aerial photographs (Wild RC10,
``f = 152.4 mm``, 23 x 23 cm, 1:4000, 609.6 m above a terrain at about 188 m, 80 %
forward overlap, east-west flight line, EPSG:32616 around the Purdue campus), a smooth
terrain and its DEM, true road centrelines (a street grid split at intersections, a
curved residential street, a two-part feature), three road databases that sample the
same roads with their own vertices and positional errors (OSM, TNM, TIGER), surveyed
control and check points, tie points, and the image measurements (projections of the
TRUE points plus noise). Optionally (``calibration=``, ``effects=``, ``scan=``) the
image coordinates carry the principal point, lens distortion, atmospheric refraction
and earth curvature of a calibrated camera and are measured in scanner pixels with
fiducials, so that the refinement chain (:mod:`vectoradjust.sensor.interior`) has something
to undo. :func:`write_project` writes the scenario as a project that
follows the file contract; ``python -m vectoradjust.simulate OUT_DIR`` (:func:`main`)
does it from the command line.

The pieces live in the sibling modules: :mod:`~vectoradjust.simulate.geometry` (set-up
constants, terrain, DEM, random streams), :mod:`~vectoradjust.simulate.roads` (true
roads and road databases), :mod:`~vectoradjust.simulate.imaging` (exterior orientation,
image measurements, physical effects, scanning), :mod:`~vectoradjust.simulate.container`
(:class:`Scenario`), :mod:`~vectoradjust.simulate.writer` (:func:`write_project`) and
:mod:`~vectoradjust.simulate.readme` (:func:`describe`); this module assembles them.
Its ``__all__`` names (``write_project``, ``describe``, ``terrain_height``, ...) are
still importable from here, as when it held the whole simulator.

The options of :func:`make_scenario` in detail:

- ``calibration``: the image coordinates are photo coordinates in the fiducial frame
  (ideal coordinates about the principal point + the principal point); the default
  camera is an RC10 with f = 152.4 mm, principal point (0, 0), nothing else (the image
  coordinates are exactly those without a calibration).
- ``effects``: each effect is the exact inverse of its correction in
  :mod:`vectoradjust.sensor.refine`, with each image's TRUE flying height and each
  point's TRUE terrain height (the correction uses the approximate ZL and the mean
  terrain height). They are applied after the format test and before the noise, so
  that the points measured and the noise drawn are those of the same seed without
  effects.
- ``scan``: every image gets a random scanner affine (film rotation ~0.3 deg, placement
  ~40 px, scale 1e-4, shear 1e-4 rad) with the calibration's ``pixel_size``; the image
  coordinates (with their noise) are converted to pixels and the calibrated fiducials
  are measured in pixels with ``N(0, fiducial_sigma)`` (mm) noise. ``measurements`` and
  their sigmas are then in pixels.
- ``pointing_sigma`` (default 0: the images show exactly the true point): the point
  measured on every image is the true shape point moved horizontally, the same on
  every image, with Z = terrain there. Control and tie points are unaffected.
- ``true_roads`` (``grid`` and ``block_size`` are then ignored): centreline XY in a
  projected CRS (m), a :class:`RoadLines`, the path of a GeoJSON file of LineStrings
  (:func:`read_road_lines`) or a sequence of ``(n, 2)`` arrays. Vertices within 1 mm
  are one vertex and the lines are split into features at the vertices they share
  (intersections); the roads are translated so that the centre of their bounding box
  is ``center`` (about 600 m x 600 m fit the inset stereo overlap of a pair; vertices
  outside the overlap are not measured). With ``n_shape_points`` the vertex spacing is
  chosen to give about that many measured shape points in all; otherwise
  ``vertex_spacing`` or each database's own spacing applies.

The numerical part imports only numpy and other heart modules; geopandas, shapely,
rasterio and pandas are imported inside :func:`write_project`.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``,
so that changing, say, the number of tie points leaves the road databases unchanged.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from vectoradjust.errors import ProjectError, VectorAdjustError
from vectoradjust.model import Camera, ControlPoints, ImageSpec, LineLayer, Measurements, VectorSpec
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.simulate.container import Scenario
from vectoradjust.simulate.geometry import (
    CENTER,
    CONTROL_SIGMA,
    CRS,
    DEFAULT_DATE,
    DEM_NODATA,
    FOCAL_LENGTH,
    _make_dem,
    _rng,
    _stereo_overlap,
    _terrain_xyz,
    terrain_height,
)
from vectoradjust.simulate.imaging import (
    EFFECTS,
    FIDUCIAL_SIGMA,
    _check_effects,
    _exterior_orientation,
    _image_ids,
    _Imaging,
    _scan_measurements,
)
from vectoradjust.simulate.readme import describe
from vectoradjust.simulate.real_roads import RoadLines, _real_roads, read_road_lines
from vectoradjust.simulate.roads import (
    DATABASES,
    DatabaseModel,
    _database_models,
    _dense_scene,
    _grid_roads,
    _make_database,
    _spread_intervals,
    _TrueRoads,
    _truth_lines,
)
from vectoradjust.simulate.writer import write_project

__all__ = [
    "DatabaseModel",
    "DATABASES",
    "EFFECTS",
    "Scenario",
    "make_scenario",
    "terrain_height",
    "write_project",
    "describe",
    "main",
    "RoadLines",
    "read_road_lines",
]


# --- the scenario --------------------------------------------------------------------
def make_scenario(
    seed: int = 0, *, n_images: int = 2,
    grid: tuple[int, int] = (3, 3), block_size: float = 150.0, vertex_spacing: float | None = None,
    n_control: int = 24, n_check: int = 6, n_tie: int = 10, sigma_image: float = 0.015,
    databases: Sequence[str | DatabaseModel] = ("OSM", "TNM", "TIGER"),
    n_shape_points: int | None = None,
    shape_sigma: tuple[float, float, float] = (10.0, 10.0, 10.0),
    position_noise: float = 3.0, attitude_noise: float = 0.3, dem_noise: float = 0.15,
    sigma_position: float | None = 100.0, sigma_attitude: float | None = 5.0,
    date: str | None = DEFAULT_DATE,
    image_distortion: Callable[[np.ndarray], np.ndarray] | None = None,
    pointing_sigma: float = 0.0, center: tuple[float, float] = CENTER,
    calibration: CameraCalibration | None = None, effects: Sequence[str] = (),
    scan: bool = False, fiducial_sigma: float = FIDUCIAL_SIGMA,
    true_roads: RoadLines | str | Path | Sequence[np.ndarray] | None = None,
) -> Scenario:
    """Simulate the dissertation's set-up, deterministically from ``seed``.

    Parameters
    ----------
    seed : int
        Seed of every random stream.
    n_images : int
        Images in the east-west strip (>= 2), 80 % forward overlap; ids ``L, R`` for
        two, ``I01, I02, ...`` otherwise.
    grid, block_size : (int, int), float
        Number of east-west and north-south streets of the default scene; their spacing
        (m), an upper bound in dense mode.
    vertex_spacing : float, optional
        Vertex spacing (m) on straight roads of every database (default: each database's
        own, :data:`DATABASES`); ignored in dense mode.
    n_control, n_check, n_tie : int
        Control points (in the adjustment), check points (independent) and tie points.
    sigma_image : float
        Standard deviation of the image coordinates (mm).
    databases : sequence of str or DatabaseModel
        Road databases to simulate (names from :data:`DATABASES` or custom models).
    n_shape_points : int, optional
        Dense mode (benchmarks): a street grid filling the stereo overlap with about this
        many measured shape points in all databases together.
    shape_sigma : (float, float, float)
        Prior sigma of shape points written to each ``[[vectors]]`` entry (m).
    position_noise, attitude_noise, dem_noise : float
        Standard deviations of the true exposure stations about the flight plan (m in X
        and Y, half of it in Z), of the true omega, phi, kappa (degrees) and of the DEM
        heights about the true terrain (m).
    sigma_position, sigma_attitude : float or None
        Priors of the approximate exterior orientation (m, degrees); None = free.
    date : str or None
        Acquisition date written for every image (provenance).
    image_distortion : callable, optional
        ``xy_mm (k, 2) -> xy (k, 2)`` applied to the ideal projections before the noise
        (lens distortion, refraction, ...); the format test uses its output.
    pointing_sigma : float
        The analyst's identification error of a shape point (m, per horizontal axis): the
        images show the true point moved by ``N(0, pointing_sigma)`` onto the terrain.
    center : (float, float)
        Model centre (UTM 16N).
    calibration : vectoradjust.sensor.camera.CameraCalibration, optional
        The camera (module docstring): its focal length and principal point make the
        image coordinates; its distortion, fiducials and pixel size serve ``effects``
        and ``scan``. Default: f = 152.4 mm, principal point (0, 0), nothing else.
    effects : sequence of str
        Physical effects put into the image coordinates (module docstring), a subset of
        :data:`EFFECTS` (``distortion, refraction, earth_curvature``); needs ``calibration``.
    scan, fiducial_sigma : bool, float
        Measure in scanner pixels (module docstring), the fiducials with ``N(0,
        fiducial_sigma)`` (mm) noise. Needs ``calibration`` with fiducials and pixel size.
    true_roads : RoadLines, str, pathlib.Path or sequence of (n, 2) arrays, optional
        Real true roads (projected CRS, m) instead of the street grid (module docstring):
        a :class:`RoadLines`, a GeoJSON file of LineStrings or the lines' vertices.

    Returns
    -------
    Scenario
    """
    args = _Args.of(dict(locals()))  # the arguments as given, checked
    flight = _flight(args)
    ground = _ground(args, flight)
    return _assemble(args, flight, ground)


# --- make_scenario, step by step -----------------------------------------------------
@dataclass(frozen=True)
class _Args:
    """The arguments of :func:`make_scenario`, checked: ``n_images`` an int, ``effects``
    the checked tuple, ``center`` floats, ``models`` the databases' models."""

    seed: int
    n_images: int
    grid: tuple
    block_size: float
    vertex_spacing: float | None
    n_control: int
    n_check: int
    n_tie: int
    sigma_image: float
    models: list
    n_shape_points: int | None
    shape_sigma: tuple
    position_noise: float
    attitude_noise: float
    dem_noise: float
    sigma_position: float | None
    sigma_attitude: float | None
    date: str | None
    image_distortion: Callable[[np.ndarray], np.ndarray] | None
    pointing_sigma: float
    center: tuple[float, float]
    calibration: CameraCalibration | None
    effects: tuple
    scan: bool
    fiducial_sigma: float
    true_roads: RoadLines | str | Path | Sequence[np.ndarray] | None

    @classmethod
    def of(cls, kw: dict) -> _Args:
        """Check the keyword arguments ``kw`` of :func:`make_scenario`."""
        _check_sizes(kw["n_images"], kw["n_shape_points"])
        kw["models"] = _database_models(kw.pop("databases"))
        kw["center"] = (float(kw["center"][0]), float(kw["center"][1]))
        kw["n_images"] = int(kw["n_images"])
        kw["effects"] = _check_effects(kw["effects"], kw["calibration"], kw["scan"])
        return cls(**kw)


class _Flight(NamedTuple):
    camera: Camera
    true_eo: np.ndarray  # (n, 6) true exterior orientation
    ids: list  # image ids
    imaging: _Imaging
    images: list  # ImageSpec: approximate exterior orientation
    overlap: tuple  # (ov_x, in_x, in_y) of :func:`_stereo_overlap`
    dem: tuple  # (grid, transform)


def _flight(a: _Args) -> _Flight:
    """The camera, the true and approximate exterior orientation, the overlap, the DEM."""
    camera = _camera(a.calibration)
    cx, cy = a.center
    plan_x, true_eo = _exterior_orientation(a.seed, a.n_images, cx, cy, a.position_noise,
                                            a.attitude_noise)
    ids = _image_ids(a.n_images)
    imaging = _Imaging.of(camera, true_eo, ids, a.sigma_image, a.image_distortion, a.effects)
    images = _images(ids, true_eo, a.sigma_position, a.sigma_attitude, a.date)
    overlap = _stereo_overlap(plan_x, cy)
    dem = _make_dem(true_eo, a.center, a.seed, a.dem_noise)
    return _Flight(camera, true_eo, ids, imaging, images, overlap, dem)


class _Ground(NamedTuple):
    spacing: float | None  # the databases' vertex spacing (dense or real roads: chosen)
    real: dict | None  # the real roads for Scenario.options
    control: ControlPoints
    control_true: np.ndarray
    tie_ids: np.ndarray
    tie_true: np.ndarray
    dbs: list  # _SimulatedDatabase per model
    measured: tuple  # (measurements, unit, fiducials, scan_affine) of :func:`_measurements`
    lines: tuple  # (truth lines, their attributes)


def _ground(a: _Args, fl: _Flight) -> _Ground:
    """The true roads, control, check and tie points, the databases and the measurements."""
    ov_x, in_x, in_y = fl.overlap
    roads, spacing, dense_nseg, real = _true_roads(
        a.center, a.grid, a.block_size, a.vertex_spacing, a.n_shape_points, len(a.models), ov_x,
        in_x, in_y, a.true_roads)
    control, control_true = _control_points(a.seed, in_x, in_y, a.n_control, a.n_check,
                                            a.center)
    tie_ids, tie_true = _tie_points(a.seed, in_x, in_y, a.n_tie, a.center)
    meas_parts = _point_measurements(a.seed, fl.imaging, control, control_true, tie_ids,
                                     tie_true)
    dbs = [_simulate_database(model, roads, a.seed, spacing, dense_nseg, fl.imaging,
                              a.shape_sigma, a.pointing_sigma, a.center) for model in a.models]
    measured = _measurements(
        meas_parts + [db.measurements for db in dbs], fl.ids, a.sigma_image, a.seed,
        scan=a.scan, calibration=a.calibration, fiducial_sigma=a.fiducial_sigma)
    lines = _truth_lines(roads, a.center)
    return _Ground(spacing, real, control, control_true, tie_ids, tie_true, dbs, measured,
                   lines)


def _assemble(a: _Args, fl: _Flight, g: _Ground) -> Scenario:
    """The :class:`Scenario` of the pieces."""
    measurements, unit, fiducials, scan_affine = g.measured
    dbs = g.dbs
    return Scenario(
        seed=int(a.seed), crs=CRS, camera=fl.camera, images=fl.images, true_eo=fl.true_eo,
        measurements=measurements, control=g.control, control_true=g.control_true,
        tie_ids=g.tie_ids, tie_true=g.tie_true, layers={db.name: db.layer for db in dbs},
        vector_specs={db.name: db.spec for db in dbs}, truth={db.name: db.truth for db in dbs},
        measured={db.name: db.measured for db in dbs}, truth_lines=g.lines[0],
        truth_line_attributes=g.lines[1], dem_grid=fl.dem[0], dem_transform=fl.dem[1],
        dem_nodata=DEM_NODATA, center=a.center, databases={m.name: m for m in a.models},
        sigma_image=float(a.sigma_image), options=_options(a, g.spacing, g.real), unit=unit,
        fiducials=fiducials, scan_affine=scan_affine, effects=tuple(a.effects),
    )


def _check_sizes(n_images, n_shape_points) -> None:
    if int(n_images) < 2:
        raise ProjectError(f"n_images = {n_images} cannot form a stereo model",
                           "Simulate at least 2 images")
    if n_shape_points is not None and int(n_shape_points) < 1:
        raise ProjectError(f"n_shape_points = {n_shape_points} must be positive",
                           "Give the number of measured shape points wanted, e.g. 100000")


def _camera(calibration: CameraCalibration | None) -> Camera:
    """The camera of the image coordinates: the calibration's, or the plain RC10."""
    if calibration is None:
        return Camera(FOCAL_LENGTH, (0.0, 0.0))
    return Camera(calibration.focal_length, tuple(calibration.principal_point),
                  calibration=calibration)


def _images(ids: list, true_eo: np.ndarray, sigma_position, sigma_attitude, date) -> list:
    """Approximate exterior orientation: true positions rounded to metres, zero attitude."""
    return [
        ImageSpec(ids[i], np.round(true_eo[i, :3]), np.zeros(3), sigma_position, sigma_attitude,
                  date)
        for i in range(len(ids))
    ]


def _true_roads(center, grid, block_size, vertex_spacing, n_shape_points, n_models: int,
                ov_x, in_x, in_y, true_roads=None):
    """The true roads, the vertex spacing of the databases and, dense, their intervals.

    The default scene (:func:`_grid_roads`) has its middle east-west street run 60 m
    west out of the stereo overlap ``ov_x``; dense mode (``n_shape_points``) fills the
    inset ``in_x, in_y``; ``true_roads`` (:func:`_real_roads`) replaces both scenes.
    The last value describes the real roads for :attr:`Scenario.options` (None without).
    """
    if true_roads is not None:
        lines = RoadLines.of(true_roads)
        roads, shift = _real_roads(lines, center)
        real = {"source": lines.source, "lines": len(lines.lines),
                "features": len(roads.name), "shift": list(shift)}
        if n_shape_points is None:
            return roads, vertex_spacing, None, real
        nseg, spacing = _spread_intervals(roads, n_models, n_shape_points)
        return roads, spacing, nseg, real
    if n_shape_points is None:
        roads = _grid_roads(center[0], center[1], grid, float(block_size), ov_x[0] - 60.0)
        return roads, vertex_spacing, None, None
    roads, dense_nseg, spacing = _dense_scene(in_x, in_y, n_models, n_shape_points, block_size)
    return roads, spacing, dense_nseg, None


def _farthest_points(cand: np.ndarray, n: int, center) -> np.ndarray:
    """Indices of ``n`` well-spread candidates (farthest-point sampling)."""
    if n <= 0:
        return np.zeros(0, np.int64)
    d0 = np.hypot(cand[:, 0] - center[0], cand[:, 1] - center[1])
    chosen = [int(np.argmax(d0))]
    dmin = np.hypot(*(cand - cand[chosen[0]]).T)
    for _ in range(1, min(n, len(cand))):
        j = int(np.argmax(dmin))
        chosen.append(j)
        dmin = np.minimum(dmin, np.hypot(*(cand - cand[j]).T))
    return np.asarray(chosen, np.int64)


def _control_points(seed: int, in_x, in_y, n_control: int, n_check: int, center):
    """Well-spread control (``GCP..``) and check (``CHK..``) points in the inset overlap.

    Returns the surveyed points (true + survey noise) and their true coordinates.
    """
    rng = _rng(seed, "control")
    cand = np.column_stack([rng.uniform(*in_x, 4000), rng.uniform(*in_y, 4000)])
    pick = _farthest_points(cand, n_control + n_check, center)
    control_true = _terrain_xyz(cand[pick], center)
    nc = min(n_control, len(pick))
    role = np.array(["control"] * nc + ["check"] * (len(pick) - nc), dtype=object)
    width_c = max(2, len(str(max(n_control, 1))))
    width_k = max(2, len(str(max(n_check, 1))))
    cid = [f"GCP{i + 1:0{width_c}d}" for i in range(nc)]
    cid += [f"CHK{i + 1:0{width_k}d}" for i in range(len(pick) - nc)]
    surveyed = np.round(control_true + rng.normal(0.0, CONTROL_SIGMA, control_true.shape), 3)
    control = ControlPoints(np.array(cid, dtype=object), surveyed,
                            np.tile(CONTROL_SIGMA, (len(cid), 1)), role, source="gcps.csv")
    return control, control_true


def _tie_points(seed: int, in_x, in_y, n_tie: int, center):
    """Tie point ids (``T..``) and true coordinates, uniform in the inset overlap."""
    rng = _rng(seed, "ties")
    txy = np.column_stack([rng.uniform(*in_x, n_tie), rng.uniform(*in_y, n_tie)])
    tie_true = _terrain_xyz(txy, center)
    width_t = max(2, len(str(max(n_tie, 1))))
    tie_ids = np.array([f"T{i + 1:0{width_t}d}" for i in range(n_tie)], dtype=object).astype(str)
    return tie_ids, tie_true


def _point_measurements(seed: int, imaging: _Imaging, control: ControlPoints,
                        control_true: np.ndarray, tie_ids: np.ndarray, tie_true: np.ndarray):
    """``(point id, image index, xy)`` of the measurements of control, check and tie points."""
    rng = _rng(seed, "image")
    pi, ii, obs, _ = imaging.observe(control_true, rng)
    out = [(np.asarray(control.point_id, dtype=str)[pi], ii, obs)]
    pi, ii, obs, _ = imaging.observe(tie_true, rng)
    out.append((tie_ids[pi], ii, obs))
    return out


class _SimulatedDatabase(NamedTuple):
    name: str
    layer: LineLayer  # stored vertices
    spec: VectorSpec  # its [[vectors]] entry
    truth: tuple  # (point id, true XYZ) of every vertex
    measured: np.ndarray  # per vertex: is its object point measured on the images?
    measurements: tuple  # (point id, image index, xy) of every measurement


def _simulate_database(model: DatabaseModel, roads: _TrueRoads, seed: int, spacing, nseg,
                       imaging: _Imaging, shape_sigma, pointing_sigma: float,
                       center) -> _SimulatedDatabase:
    """One road database: its layer and truth, and the image measurements of its points.

    The analyst identifies each object point with an error of ``N(0, pointing_sigma)``
    per axis (the measured point lies on the terrain there).
    """
    layer, pids, true_xy, group, group_first = _make_database(
        model, roads, seed, spacing, CRS, nseg)
    true_xyz = _terrain_xyz(true_xy, center)
    spec = VectorSpec(
        name=model.name, path=f"{model.stem}_roads.shp", id_field=model.id_field,
        sigma=tuple(float(s) for s in shape_sigma), dem="dem.tif",
        truth=f"truth_{model.stem}.csv",
        # the analyst states the identification error the simulation makes (horizontal;
        # the measured point lies on the terrain, so vertically only through the slope)
        identification_sigma=(float(pointing_sigma), 0.0) if pointing_sigma > 0 else None)
    rng_db = _rng(seed, f"image:{model.name}")
    seen_xyz = true_xyz[group_first]
    if pointing_sigma > 0:
        pxy = seen_xyz[:, :2] + _rng(seed, f"pointing:{model.name}").normal(
            0.0, pointing_sigma, (len(seen_xyz), 2))
        seen_xyz = np.column_stack([pxy, terrain_height(pxy[:, 0], pxy[:, 1], center)])
    gp, ii, obs, seen = imaging.observe(seen_xyz, rng_db)
    return _SimulatedDatabase(model.name, layer, spec, (pids, true_xyz), seen[group],
                              (pids[group_first[gp]], ii, obs))


def _measurements(meas_parts: list, ids: list, sigma_image: float, seed: int, *, scan: bool,
                  calibration: CameraCalibration | None, fiducial_sigma: float):
    """All image measurements in one table, in scanner pixels when ``scan``.

    Returns the measurements, their unit, the measured fiducials and the scanner
    affines (both None unless ``scan``).
    """
    point_id = np.concatenate([p[0].astype(str) for p in meas_parts])
    img_index = np.concatenate([p[1] for p in meas_parts]).astype(np.int64)
    image_id = np.asarray(ids, dtype=str)[img_index]
    xy = np.concatenate([p[2] for p in meas_parts]).reshape(-1, 2)
    sigma = np.full(xy.shape, float(sigma_image))
    unit, fiducials, scan_affine = "mm", None, None
    if scan:
        xy, sigma, fiducials, scan_affine = _scan_measurements(
            xy, sigma, img_index, calibration, ids, seed, fiducial_sigma)
        unit = "pixel"
    xy = np.round(xy, 4 if scan else 6)
    measurements = Measurements(point_id, image_id, xy, sigma, source="image_points.csv")
    return measurements, unit, fiducials, scan_affine


def _options(a: _Args, spacing: float | None, real_roads: dict | None) -> dict:
    """The arguments of :func:`make_scenario` as :attr:`Scenario.options` records them."""
    cal = a.calibration
    return {
        "seed": int(a.seed), "n_images": a.n_images, "grid": list(a.grid),
        "block_size": float(a.block_size), "vertex_spacing": a.vertex_spacing,
        "n_control": a.n_control, "n_check": a.n_check, "n_tie": a.n_tie,
        "sigma_image": a.sigma_image, "databases": [m.name for m in a.models],
        "n_shape_points": a.n_shape_points, "shape_sigma": list(a.shape_sigma),
        "position_noise": a.position_noise, "attitude_noise": a.attitude_noise,
        "dem_noise": a.dem_noise, "image_distortion": a.image_distortion is not None,
        "pointing_sigma": float(a.pointing_sigma),
        "dense_spacing": spacing if a.n_shape_points is not None else None,
        "camera": None if cal is None else (cal.name or "calibrated camera"),
        "camera_file": None if cal is None or cal.source is None else Path(cal.source).name,
        "effects": list(a.effects), "scan": bool(a.scan),
        "fiducial_sigma": float(a.fiducial_sigma) if a.scan else None,
        "true_roads": real_roads,
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``python -m vectoradjust.simulate OUT_DIR [--seed N] [--shape-points N]``.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status.
    """
    parser = argparse.ArgumentParser(
        prog="python -m vectoradjust.simulate",
        description="Write a simulated vectoradjust project (stereo pair or strip, "
        "OSM/TNM/TIGER roads, control, DEM, truth).")
    parser.add_argument("out_dir", help="output directory (created)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--shape-points", type=int, default=None,
                        help="dense mode: about this many measured shape points in all")
    parser.add_argument("--images", type=int, default=2, help="images in the strip (>= 2)")
    parser.add_argument("--format", choices=("shp", "gpkg"), default="shp",
                        help="format of the road layers (default shp)")
    parser.add_argument("--camera", default=None,
                        help="camera TOML file (calibration) the image coordinates are made with")
    parser.add_argument("--effects", default="",
                        help="comma-separated physical effects in the image coordinates: "
                        f"{', '.join(EFFECTS)} (need --camera)")
    parser.add_argument("--scan", action="store_true",
                        help="measure in scanner pixels with fiducials (needs --camera with "
                        "fiducials and pixel_size)")
    parser.add_argument("--roads", default=None, metavar="GEOJSON",
                        help="real true roads: GeoJSON LineStrings in a projected CRS (m), "
                        "centred on the model instead of the street grid")
    parser.add_argument("--pointing-sigma", type=float, default=0.0,
                        help="identification error of the analyst per horizontal axis (m, "
                        "object space); written as identification_sigma (default 0)")
    parser.add_argument("--reweight", choices=("none", "two-pass", "vce"), default="none",
                        help="[adjustment] reweight written to the project (default none)")
    parser.add_argument("--shape-sigma", type=float, nargs=3, default=(10.0, 10.0, 10.0),
                        metavar=("SX", "SY", "SZ"),
                        help="prior sigma of the shape points written to [[vectors]] sigma (m; "
                        "default 10 10 10; SZ: the DEM's vertical accuracy, e.g. 0.15)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        cal = CameraCalibration.from_file(args.camera) if args.camera else None
        sc = make_scenario(args.seed, n_images=args.images, n_shape_points=args.shape_points,
                           calibration=cal, effects=args.effects, scan=args.scan,
                           true_roads=args.roads, pointing_sigma=args.pointing_sigma,
                           shape_sigma=tuple(args.shape_sigma))
        path = write_project(sc, args.out_dir, format=args.format, reweight=args.reweight)
    except VectorAdjustError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    pid = np.unique(sc.measurements.point_id)
    n_shape = int(np.sum(np.isin(pid, np.concatenate([v[0] for v in sc.truth.values()]))))
    print(f"wrote {path} ({len(sc.measurements.point_id)} image measurements of "
          f"{len(pid)} points, {n_shape} of them shape points) in "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
