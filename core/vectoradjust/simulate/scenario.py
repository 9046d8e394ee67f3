"""Deterministic simulation of the dissertation's stereo set-up (``DESIGN.md`` sections 1, 9).

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
follows the file contract; ``python -m vectoradjust.simulate OUT_DIR`` does it from
the command line.

The numerical part imports only numpy and other heart modules; geopandas, shapely,
rasterio and pandas are imported inside :func:`write_project`.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``,
so that changing, say, the number of tie points leaves the road databases unchanged.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from vectoradjust.adjust.dem import bilinear
from vectoradjust.errors import ProjectError, VectorAdjustError
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
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.collinearity import project
from vectoradjust.sensor.interior import FiducialMeasurements, refine_measurements
from vectoradjust.sensor.refine import distort

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
]

# --- the dissertation's set-up -------------------------------------------------------
CRS = "EPSG:32616"
CENTER = (506400.0, 4475000.0)  # model centre (UTM 16N), Purdue campus area
FOCAL_LENGTH = 152.4  # mm, Wild RC10
FORMAT_HALF = 115.0  # mm: 23 x 23 cm format
PHOTO_SCALE = 4000.0
TERRAIN_LEVEL = 188.0  # m MSL, mean terrain height of the model
FLYING_HEIGHT = FOCAL_LENGTH / 1000.0 * PHOTO_SCALE  # 609.6 m above terrain
FORWARD_OVERLAP = 0.8
GROUND_HALF = FORMAT_HALF / 1000.0 * PHOTO_SCALE  # 460 m
BASE = (1.0 - FORWARD_OVERLAP) * 2.0 * GROUND_HALF  # 184 m
DEM_CELL = 5.0
DEM_NODATA = -9999.0
CONTROL_SIGMA = (0.05, 0.05, 0.08)  # m, surveyed GCPs
DEFAULT_DATE = "1999-10-05"  # acquisition date written for provenance (simulated)
_INSET = 30.0  # m kept free inside the stereo overlap for control, ties and dense roads
#: Physical effects :func:`make_scenario` can put into the image coordinates (the
#: ``[corrections]`` switches that undo them).
EFFECTS = ("distortion", "refraction", "earth_curvature")
FIDUCIAL_SIGMA = 0.002  # mm, default pointing precision of a fiducial measurement


@dataclass(frozen=True)
class DatabaseModel:
    """Vertex sampling and positional error model of one road database.

    A database vertex is a point of the true centreline; its stored XY is the true XY
    plus ``bias`` (common to the database) plus a systematic shift of its feature
    (magnitude ``N(shift_mean, shift_sd)``, uniformly random direction) plus per-vertex
    noise ``N(0, noise)`` on each axis. A vertex shared by several features (an
    intersection) gets the shift of the first of them and one noise draw, so its
    stored XY is the same in every feature.

    Attributes
    ----------
    name : str
        ``[[vectors]] name``.
    id_field : str
        Name of the feature id field (at most 10 characters, shapefile-safe).
    stem : str
        File name stem: ``<stem>_roads.shp``, ``truth_<stem>.csv``.
    spacing : float
        Nominal vertex spacing along straight roads (m).
    curve_factor : float
        Spacing on curved roads is ``spacing * curve_factor``.
    bias : tuple of float
        Common horizontal offset ``(dx, dy)`` of the database (m).
    shift_mean, shift_sd : float
        Magnitude of the per-feature systematic shift (m).
    noise : float
        Per-vertex noise, standard deviation per axis (m).
    """

    name: str
    id_field: str
    stem: str
    spacing: float
    curve_factor: float
    bias: tuple[float, float]
    shift_mean: float
    shift_sd: float
    noise: float

    @property
    def expected_rmse(self) -> float:
        """Expected horizontal RMSE of the stored vertices against the truth (m)."""
        return math.sqrt(
            self.bias[0] ** 2
            + self.bias[1] ** 2
            + self.shift_mean**2
            + self.shift_sd**2
            + 2.0 * self.noise**2
        )


_TIGER_BIAS = 17.5  # m towards the south-east
DATABASES: dict[str, DatabaseModel] = {
    # dissertation head-to-head RMSE: TNM 2.89 m, OSM 4.35 m, TIGER 19.17 m
    "OSM": DatabaseModel("OSM", "osm_id", "osm", 20.0, 0.4, (0.0, 0.0), 3.0, 0.5, 2.2),
    "TNM": DatabaseModel("TNM", "permanent_", "tnm", 15.0, 0.4, (0.0, 0.0), 1.5, 0.3, 1.75),
    "TIGER": DatabaseModel(
        "TIGER",
        "tlid",
        "tiger",
        30.0,
        0.4,
        (_TIGER_BIAS / math.sqrt(2.0), -_TIGER_BIAS / math.sqrt(2.0)),
        4.0,
        1.0,
        4.5,
    ),
}


def terrain_height(x, y, center: Sequence[float] = CENTER) -> np.ndarray:
    """True terrain height (m MSL) of the simulated area.

    A gentle plane (4 m/km rising east, 3 m/km falling north), a 6 m hill 120 m east
    and 80 m north of the centre and a 2.5 m hollow to the south-west:
    ``z = 186 + 0.004 dx - 0.003 dy + 6 exp(-((dx-120)^2 + (dy-80)^2) / (2 180^2))
    - 2.5 exp(-((dx+250)^2 + (dy+200)^2) / (2 120^2))``, ``dx, dy`` from ``center``.

    Parameters
    ----------
    x, y : array_like
        Ground coordinates (m), broadcastable.
    center : (float, float)
        Model centre.

    Returns
    -------
    numpy.ndarray
    """
    dx = np.asarray(x, float) - center[0]
    dy = np.asarray(y, float) - center[1]
    hill = 6.0 * np.exp(-((dx - 120.0) ** 2 + (dy - 80.0) ** 2) / (2.0 * 180.0**2))
    hollow = 2.5 * np.exp(-((dx + 250.0) ** 2 + (dy + 200.0) ** 2) / (2.0 * 120.0**2))
    return TERRAIN_LEVEL - 2.0 + 0.004 * dx - 0.003 * dy + hill - hollow


def _rng(seed: int, tag: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(tag.encode("utf-8"))])


# --- scenario container --------------------------------------------------------------
@dataclass
class Scenario:
    """A simulated project and its truth.

    Attributes
    ----------
    seed : int
    crs : str
        ``"EPSG:32616"``.
    camera : vectoradjust.model.Camera
    images : list of vectoradjust.model.ImageSpec
        Approximate exterior orientation (true positions rounded to metres, zero
        attitude) with priors ``sigma_position`` (m) and ``sigma_attitude`` (deg).
    true_eo : numpy.ndarray, shape (n_images, 6)
        True ``XL, YL, ZL, omega, phi, kappa`` (m, radians).
    measurements : vectoradjust.model.Measurements
        Image coordinates (mm) of control, check, tie and shape points, every database.
    control : vectoradjust.model.ControlPoints
        Surveyed control (``role = "control"``) and check (``"check"``) points.
    control_true : numpy.ndarray, shape (n, 3)
        True coordinates of ``control`` (same order).
    tie_ids : numpy.ndarray of str
    tie_true : numpy.ndarray, shape (n_tie, 3)
    layers : dict of str to vectoradjust.model.LineLayer
        Database vertices (stored XY, Z = NaN as in the 2D files).
    vector_specs : dict of str to vectoradjust.model.VectorSpec
    truth : dict of str to (numpy.ndarray of str, numpy.ndarray (n, 3))
        Per database, the shape point id and true XYZ of EVERY vertex (layer order).
    measured : dict of str to numpy.ndarray of bool
        Per database and vertex: whether its object point is measured on the images.
    truth_lines : list of numpy.ndarray, shape (n, 3)
        True centrelines (one array per part), densified to at most 5 m, Z = terrain.
    truth_line_attributes : dict of str to list
        ``road_id``, ``part``, ``name``, ``highway`` of every truth line.
    dem_grid : numpy.ndarray, shape (rows, cols)
        DEM heights (float32 values), nodata cells equal to ``dem_nodata``.
    dem_transform : tuple of 6 float
        GDAL geotransform of the DEM.
    dem_nodata : float
    center : (float, float)
        Model centre used by :func:`terrain_height`.
    databases : dict of str to DatabaseModel
        Error models used.
    sigma_image : float
        Standard deviation of the image measurements (mm).
    options : dict
        The arguments of :func:`make_scenario` (for the README).
    unit : str
        Unit of ``measurements``: ``"mm"`` (photo coordinates in the fiducial frame) or
        ``"pixel"`` (scanner column, row; ``scan=True``).
    fiducials : FiducialMeasurements or None
        Measured fiducials (pixels) of every image when ``scan=True``.
    scan_affine : numpy.ndarray, shape (n_images, 6), or None
        True scanner affine of every image, pixels -> photo mm, as
        ``a0, a1, a2, b0, b1, b2`` (``x = a0 + a1 col + a2 row``, ``y = b0 + ...``).
    effects : tuple of str
        Physical effects in the image coordinates (subset of :data:`EFFECTS`).
    """

    seed: int
    crs: str
    camera: Camera
    images: list
    true_eo: np.ndarray
    measurements: Measurements
    control: ControlPoints
    control_true: np.ndarray
    tie_ids: np.ndarray
    tie_true: np.ndarray
    layers: dict
    vector_specs: dict
    truth: dict
    measured: dict
    truth_lines: list
    truth_line_attributes: dict
    dem_grid: np.ndarray
    dem_transform: tuple
    dem_nodata: float
    center: tuple
    databases: dict
    sigma_image: float
    options: dict = field(default_factory=dict)
    unit: str = "mm"
    fiducials: FiducialMeasurements | None = None
    scan_affine: np.ndarray | None = None
    effects: tuple = ()

    @property
    def calibration(self) -> CameraCalibration | None:
        """The camera calibration the image coordinates were made with, if any."""
        return self.camera.calibration

    def default_corrections(self) -> dict:
        """``[corrections]`` that undo exactly the simulated effects."""
        if self.calibration is None:
            return {"refraction": False, "earth_curvature": False}
        return {e: e in self.effects for e in EFFECTS}

    def to_project_data(self, vectors: Sequence[str] | None = None,
                        corrections: dict | None = None) -> ProjectData:
        """The scenario as in-memory project data (no files), Z of shape points from the DEM.

        Parameters
        ----------
        vectors : sequence of str, optional
            Database names to include (default: all). Measurements of the shape points
            of the databases left out are dropped, so that they do not turn into tie
            points.
        corrections : dict, optional
            ``[corrections]`` switches for the image coordinate refinement; keys not
            given take :meth:`default_corrections` (which undo the simulated effects).
            Only used when the scenario has a calibration (``calibration=``).

        Returns
        -------
        vectoradjust.model.ProjectData
            Each layer's Z is ``vectoradjust.adjust.dem.bilinear`` of the DEM at the stored XY;
            ``truth`` holds the selected databases' truth. With a calibration, the
            measurements are refined by :func:`vectoradjust.sensor.interior.refine_measurements`
            exactly as ``load_project_data`` would do from the written files, and
            ``interior`` holds its report.
        """
        names = list(self.layers) if vectors is None else [str(v) for v in vectors]
        unknown = [n for n in names if n not in self.layers]
        if unknown:
            raise ProjectError(
                f"the scenario has no database named {', '.join(map(repr, unknown))}",
                f"Choose from {', '.join(self.layers)}",
            )
        pairs = []
        for name in names:
            layer = self.layers[name]
            coords = layer.coords.copy()
            coords[:, 2] = bilinear(self.dem_grid, self.dem_transform, coords[:, :2],
                                    nodata=self.dem_nodata)
            pairs.append((replace(self.vector_specs[name]), replace(layer, coords=coords)))
        meas = self.measurements
        dropped = [n for n in self.layers if n not in names]
        if dropped:
            other = np.concatenate([self.truth[n][0] for n in dropped])
            keep = ~np.isin(meas.point_id, other)
            meas = Measurements(meas.point_id[keep], meas.image_id[keep], meas.xy[keep],
                                meas.sigma[keep], source=meas.source, rows=meas.rows[keep])
        else:
            meas = replace(meas, xy=meas.xy.copy(), sigma=meas.sigma.copy())
        images = [replace(im, position=im.position.copy(), attitude=im.attitude.copy())
                  for im in self.images]
        camera = replace(self.camera)
        corr = {"refraction": False, "earth_curvature": False}
        interior: dict = {}
        if self.calibration is not None:
            corr = self.default_corrections()
            corr.update(corrections or {})
            res = refine_measurements(meas, images, self.camera, corr, unit=self.unit,
                                      fiducials=self.fiducials, control=self.control)
            meas = res.measurements
            camera = Camera(self.camera.focal_length, res.principal_point,
                            calibration=self.calibration)
            interior = res.report
        return ProjectData(
            crs=self.crs,
            camera=camera,
            images=images,
            measurements=meas,
            control=replace(self.control, xyz=self.control.xyz.copy(),
                            sigma=self.control.sigma.copy()),
            vectors=pairs,
            settings=AdjustmentSettings(),
            truth={n: (self.truth[n][0].copy(), self.truth[n][1].copy()) for n in names},
            corrections=corr,
            source=f"<simulated scenario, seed {self.seed}>",
            interior=interior,
        )

    def database_errors(self, name: str, measured_only: bool = False) -> dict:
        """RMSE of a database's stored XY against the truth.

        Parameters
        ----------
        name : str
            Database name.
        measured_only : bool
            Only the vertices whose object point is measured on the images.

        Returns
        -------
        dict
            ``count, rmse_x, rmse_y, rmse_horizontal, mean_x, mean_y`` (m).
        """
        d = self.layers[name].coords[:, :2] - self.truth[name][1][:, :2]
        if measured_only:
            d = d[self.measured[name]]
        rx, ry = np.sqrt(np.mean(d**2, axis=0))
        return {
            "count": int(len(d)),
            "rmse_x": float(rx),
            "rmse_y": float(ry),
            "rmse_horizontal": float(math.hypot(rx, ry)),
            "mean_x": float(np.mean(d[:, 0])),
            "mean_y": float(np.mean(d[:, 1])),
        }


# --- true roads ----------------------------------------------------------------------
@dataclass
class _TrueRoads:
    """True road features as flat arrays: parts are polylines, grouped by feature."""

    coords: np.ndarray  # (m, 2) vertices of all parts
    part_ptr: np.ndarray  # (n_parts + 1,) offsets into coords
    part_feature: np.ndarray  # (n_parts,) feature of each part (non-decreasing)
    part_curved: np.ndarray  # (n_parts,) bool
    name: list  # per feature, str or None
    highway: list  # per feature


def _grid_roads(cx, cy, grid, block, x_west_limit) -> _TrueRoads:
    """The default scene: street grid split at intersections, a curve, a two-part road."""
    n_ew, n_ns = int(grid[0]), int(grid[1])
    ext = 0.4 * block
    ys = cy + (np.arange(n_ew) - (n_ew - 1) / 2.0) * block
    xs = cx + (np.arange(n_ns) - (n_ns - 1) / 2.0) * block
    ew_names = [f"{_ordinal(i + 1)} Street" for i in range(n_ew)]
    ns_names = [f"{t} Avenue" for t in _tree_names(n_ns)]
    parts: list[np.ndarray] = []
    curved: list[bool] = []
    feat_of_part: list[int] = []
    names: list = []
    highways: list = []

    def add(pieces, name, highway, is_curved=False):
        f = len(names)
        names.append(name)
        highways.append(highway)
        for p in pieces:
            parts.append(np.asarray(p, float))
            curved.append(is_curved)
            feat_of_part.append(f)

    mid_ew, mid_ns = n_ew // 2, n_ns // 2
    for i, y in enumerate(ys):
        west = x_west_limit if (i == mid_ew and n_ew > 0) else xs[0] - ext
        stops = np.concatenate([[west], xs, [xs[-1] + ext]])
        hw = "tertiary" if i == mid_ew else "residential"
        for a, b in zip(stops[:-1], stops[1:]):
            add([[[a, y], [b, y]]], ew_names[i], hw)
    for j, x in enumerate(xs):
        stops = np.concatenate([[ys[0] - ext], ys, [ys[-1] + ext]])
        hw = "tertiary" if j == mid_ns else "residential"
        for a, b in zip(stops[:-1], stops[1:]):
            add([[[x, a], [x, b]]], ns_names[j], hw)
    # curved residential street: an S-curve from the east end of the southern street
    # to beyond the east edge of the stereo overlap (its far vertices are not measured)
    t = np.linspace(0.0, 1.0, 461)
    x0, y0 = xs[-1] + ext, ys[0]
    curve = np.column_stack([x0 + 230.0 * t, y0 - 120.0 * t + 35.0 * np.sin(2.0 * np.pi * t)])
    curve[0] = (x0, y0)
    add([curve], "Crescent Drive", "residential", True)
    # a two-part feature (MultiLineString): two parallel parking aisles, unnamed (null)
    ya = ys[0] - ext - 90.0
    xa, xb = cx - 120.0, cx + 60.0
    add([[[xa, ya], [xb, ya]], [[xb, ya - 12.0], [xa, ya - 12.0]]], None, "service")
    return _flatten(parts, feat_of_part, curved, names, highways)


def _dense_roads(x_lo, x_hi, y_lo, y_hi, b) -> _TrueRoads:
    """A street grid with spacing ``b`` filling a rectangle, split at intersections."""
    ys = y_lo + b / 2.0 + b * np.arange(max(1, int((y_hi - y_lo) // b)))
    xs = x_lo + b / 2.0 + b * np.arange(max(1, int((x_hi - x_lo) // b)))
    xstops = np.concatenate([[x_lo], xs, [x_hi]])
    ystops = np.concatenate([[y_lo], ys, [y_hi]])
    ne, nn = len(ys), len(xs)
    # E-W segments: street i, segment k
    ew_a = np.column_stack([np.tile(xstops[:-1], ne), np.repeat(ys, nn + 1)])
    ew_b = np.column_stack([np.tile(xstops[1:], ne), np.repeat(ys, nn + 1)])
    ns_a = np.column_stack([np.repeat(xs, ne + 1), np.tile(ystops[:-1], nn)])
    ns_b = np.column_stack([np.repeat(xs, ne + 1), np.tile(ystops[1:], nn)])
    a = np.concatenate([ew_a, ns_a])
    bb = np.concatenate([ew_b, ns_b])
    nseg = len(a)
    coords = np.empty((2 * nseg, 2))
    coords[0::2] = a
    coords[1::2] = bb
    ew_names = [f"Street {i + 1:03d}" for i in range(ne)]
    ns_names = [f"Avenue {j + 1:03d}" for j in range(nn)]
    names = list(np.repeat(ew_names, nn + 1)) + list(np.repeat(ns_names, ne + 1))
    names = [str(s) for s in names]
    return _TrueRoads(
        coords=coords,
        part_ptr=np.arange(0, 2 * nseg + 1, 2),
        part_feature=np.arange(nseg),
        part_curved=np.zeros(nseg, bool),
        name=names,
        highway=["residential"] * nseg,
    )


def _flatten(parts, feat_of_part, curved, names, highways) -> _TrueRoads:
    sizes = np.array([len(p) for p in parts])
    return _TrueRoads(
        coords=np.concatenate(parts),
        part_ptr=np.concatenate([[0], np.cumsum(sizes)]),
        part_feature=np.asarray(feat_of_part, np.int64),
        part_curved=np.asarray(curved, bool),
        name=names,
        highway=highways,
    )


def _ordinal(n: int) -> str:
    words = ["First", "Second", "Third", "Fourth", "Fifth", "Sixth", "Seventh", "Eighth",
             "Ninth", "Tenth"]
    return words[n - 1] if n <= len(words) else f"{n}th"


def _tree_names(n: int) -> list:
    trees = ["Oak", "Elm", "Maple", "Cedar", "Ash", "Birch", "Walnut", "Cherry", "Pine"]
    return [trees[i] if i < len(trees) else f"Tree {i + 1}" for i in range(n)]


def _part_lengths(roads: _TrueRoads):
    seg = np.hypot(*np.diff(roads.coords, axis=0).T)
    # cumulative arc with a gap of 1 m at every part start keeps parts apart
    d = np.concatenate([[0.0], seg])
    starts = roads.part_ptr[:-1]
    d[starts] = 1.0
    g = np.cumsum(d)
    ends = roads.part_ptr[1:] - 1
    lengths = g[ends] - g[starts]
    return g, lengths


def _sample_roads(roads: _TrueRoads, spacing: float, curve_factor: float,
                  rng: np.random.Generator, jitter: float = 0.3, nseg=None):
    """Vertices of one database: points along every true part.

    ``nseg`` (per part, optional) overrides the number of intervals that ``spacing``
    gives.

    Returns
    -------
    xy : (n, 2) true positions of the sampled vertices
    part : (n,) part index of each vertex
    """
    g, lengths = _part_lengths(roads)
    starts = roads.part_ptr[:-1]
    ends = roads.part_ptr[1:] - 1
    step = spacing * np.where(roads.part_curved, curve_factor, 1.0)
    if nseg is None:
        nseg = np.maximum(1, np.rint(lengths / step)).astype(np.int64)
    nsamp = nseg + 1
    part = np.repeat(np.arange(len(lengths)), nsamp)
    first = np.repeat(np.cumsum(nsamp) - nsamp, nsamp)
    k = np.arange(len(part)) - first
    n_of = nseg[part]
    t = k / n_of
    interior = (k > 0) & (k < n_of)
    t = t + np.where(interior, rng.uniform(-jitter, jitter, len(t)) / n_of, 0.0)
    query = g[starts[part]] + t * lengths[part]
    idx = np.searchsorted(g, query, side="right") - 1
    idx = np.clip(idx, starts[part], np.maximum(ends[part] - 1, starts[part]))
    den = g[idx + 1] - g[idx]
    frac = np.where(den > 0, (query - g[idx]) / np.where(den > 0, den, 1.0), 0.0)
    xy = roads.coords[idx] + frac[:, None] * (roads.coords[idx + 1] - roads.coords[idx])
    # exact end points, so that vertices shared by features have identical coordinates
    xy[k == 0] = roads.coords[starts[part[k == 0]]]
    xy[k == n_of] = roads.coords[ends[part[k == n_of]]]
    return xy, part


def _truth_lines(roads: _TrueRoads, center) -> tuple[list, dict]:
    lines = []
    g, lengths = _part_lengths(roads)
    for p in range(len(lengths)):
        c = roads.coords[roads.part_ptr[p]:roads.part_ptr[p + 1]]
        if len(c) == 2 and lengths[p] > 5.0:
            n = int(math.ceil(lengths[p] / 5.0))
            t = np.linspace(0.0, 1.0, n + 1)[:, None]
            c = c[0] + t * (c[1] - c[0])
            c[-1] = roads.coords[roads.part_ptr[p + 1] - 1]
        z = terrain_height(c[:, 0], c[:, 1], center)
        lines.append(np.column_stack([c, z]))
    part_index = np.arange(len(lengths)) - np.searchsorted(roads.part_feature,
                                                           roads.part_feature, side="left")
    attrs = {
        "road_id": [int(f) + 1 for f in roads.part_feature],
        "part": [int(p) for p in part_index],
        "name": [roads.name[f] for f in roads.part_feature],
        "highway": [roads.highway[f] for f in roads.part_feature],
    }
    return lines, attrs


# --- databases -----------------------------------------------------------------------
_MTFCC = {"tertiary": "S1400", "residential": "S1400", "service": "S1640"}
_ABBREV = (("Street", "St"), ("Avenue", "Ave"), ("Drive", "Dr"))


def _feature_ids(model: DatabaseModel, n: int, rng: np.random.Generator):
    """Feature id values (typed as in the source database) in distinct ranges."""
    steps = rng.integers(1, 90, n)
    if model.stem == "osm":
        return (40_000_000 + int(rng.integers(0, 5_000_000)) + np.cumsum(steps)).astype(np.int64)
    if model.stem == "tiger":
        return (610_000_000 + int(rng.integers(0, 5_000_000)) + np.cumsum(steps)).astype(np.int64)
    if model.stem == "tnm":
        nums = int(rng.integers(0, 10_000)) + np.cumsum(steps)
        return np.char.add("TNM-", np.char.zfill(nums.astype(str), 6)).astype(object)
    nums = np.cumsum(steps)
    return np.char.add(f"{model.stem.upper()}-", nums.astype(str)).astype(object)


def _attributes(model: DatabaseModel, ids, roads: _TrueRoads) -> dict:
    if model.stem == "osm":
        return {"osm_id": [int(v) for v in ids], "name": list(roads.name),
                "highway": list(roads.highway)}
    full = []
    for nm in roads.name:
        if nm is not None and model.stem == "tiger":
            for long, short in _ABBREV:
                nm = nm.replace(long, short)
        full.append(nm)
    mtfcc = [_MTFCC.get(h, "S1400") for h in roads.highway]
    id_values = [int(v) for v in ids] if model.stem == "tiger" else [str(v) for v in ids]
    return {model.id_field: id_values, "fullname": full, "mtfcc": mtfcc}


def _make_database(model: DatabaseModel, roads: _TrueRoads, seed: int, spacing, crs,
                   nseg=None):
    rng = _rng(seed, f"database:{model.name}")
    sp = model.spacing if spacing is None else float(spacing)
    true_xy, part = _sample_roads(roads, sp, model.curve_factor, rng, nseg=nseg)
    feat = roads.part_feature[part]
    n_feat = len(roads.name)
    ids = _feature_ids(model, n_feat, rng)
    # vertex index along the feature (continuing across parts) and part within feature
    feat_first_vertex = np.searchsorted(feat, feat, side="left")
    vertex_index = np.arange(len(feat)) - feat_first_vertex
    first_part_of_feat = np.searchsorted(roads.part_feature, roads.part_feature, side="left")
    vertex_part = part - first_part_of_feat[part]
    # object points: vertices at the same true XY (shared ends) are one point
    _, group_first, group = np.unique(true_xy, axis=0, return_index=True, return_inverse=True)
    group = np.asarray(group).reshape(-1)
    # number the object points in the order of their first vertex
    order = np.argsort(group_first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    group = rank[group]
    group_first = group_first[order]
    n_group = len(group_first)
    mag = np.abs(rng.normal(model.shift_mean, model.shift_sd, n_feat))
    ang = rng.uniform(0.0, 2.0 * np.pi, n_feat)
    shift = np.column_stack([mag * np.cos(ang), mag * np.sin(ang)])
    noise = rng.normal(0.0, model.noise, (n_group, 2))
    disp = np.asarray(model.bias, float) + shift[feat[group_first[group]]] + noise[group]
    db_xy = np.round(true_xy + disp, 3)
    fid = np.asarray([str(v) for v in ids], dtype=str)
    point_ids = np.char.add(np.char.add(fid[feat], "_"), vertex_index.astype(str))
    layer = LineLayer(
        name=model.name,
        feature_ids=fid,
        attributes=_attributes(model, ids, roads),
        coords=np.column_stack([db_xy, np.full(len(db_xy), np.nan)]),
        vertex_feature=feat,
        vertex_index=vertex_index,
        vertex_part=vertex_part,
        crs=crs,
        source=f"{model.stem}_roads.shp",
        geometry_type="LineString",
    )
    return layer, point_ids.astype(object).astype(str), true_xy, group, group_first


# --- images and measurements ---------------------------------------------------------
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
    xy = project(true_eo[None, :, :], xyz[:, None, :], camera.focal_length,
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


def _make_dem(true_eo, center, seed, dem_noise):
    margin = 60.0
    x_lo = math.floor((true_eo[:, 0].min() - GROUND_HALF - margin) / DEM_CELL) * DEM_CELL
    x_hi = math.ceil((true_eo[:, 0].max() + GROUND_HALF + margin) / DEM_CELL) * DEM_CELL
    y_lo = math.floor((true_eo[:, 1].min() - GROUND_HALF - margin) / DEM_CELL) * DEM_CELL
    y_hi = math.ceil((true_eo[:, 1].max() + GROUND_HALF + margin) / DEM_CELL) * DEM_CELL
    cols = int(round((x_hi - x_lo) / DEM_CELL))
    rows = int(round((y_hi - y_lo) / DEM_CELL))
    transform = (float(x_lo), DEM_CELL, 0.0, float(y_hi), 0.0, -DEM_CELL)
    xc = x_lo + (np.arange(cols) + 0.5) * DEM_CELL
    yc = y_hi - (np.arange(rows) + 0.5) * DEM_CELL
    z = terrain_height(xc[None, :], yc[:, None], center)
    z = z + _rng(seed, "dem").normal(0.0, dem_noise, z.shape)
    grid = z.astype(np.float32)
    grid[:4, :4] = DEM_NODATA  # a nodata patch in the north-west margin, outside every image
    return grid, transform


# --- the scenario --------------------------------------------------------------------
def make_scenario(
    seed: int = 0,
    *,
    n_images: int = 2,
    grid: tuple[int, int] = (3, 3),
    block_size: float = 150.0,
    vertex_spacing: float | None = None,
    n_control: int = 24,
    n_check: int = 6,
    n_tie: int = 10,
    sigma_image: float = 0.015,
    databases: Sequence[str | DatabaseModel] = ("OSM", "TNM", "TIGER"),
    n_shape_points: int | None = None,
    shape_sigma: tuple[float, float, float] = (10.0, 10.0, 10.0),
    position_noise: float = 3.0,
    attitude_noise: float = 0.3,
    dem_noise: float = 0.15,
    sigma_position: float | None = 100.0,
    sigma_attitude: float | None = 5.0,
    date: str | None = DEFAULT_DATE,
    image_distortion: Callable[[np.ndarray], np.ndarray] | None = None,
    pointing_sigma: float = 0.0,
    center: tuple[float, float] = CENTER,
    calibration: CameraCalibration | None = None,
    effects: Sequence[str] = (),
    scan: bool = False,
    fiducial_sigma: float = FIDUCIAL_SIGMA,
) -> Scenario:
    """Simulate the dissertation's set-up, deterministically from ``seed``.

    Parameters
    ----------
    seed : int
        Seed of every random stream.
    n_images : int
        Images in the east-west strip (>= 2), 80 % forward overlap; ids ``L, R`` for
        two, ``I01, I02, ...`` otherwise.
    grid : (int, int)
        Number of east-west and north-south streets of the default scene.
    block_size : float
        Street spacing (m) of the default scene; upper bound in dense mode.
    vertex_spacing : float, optional
        Vertex spacing (m) on straight roads for every database (default: each
        database's own, :data:`DATABASES`). Ignored in dense mode.
    n_control, n_check, n_tie : int
        Control points (in the adjustment), check points (independent) and tie points.
    sigma_image : float
        Standard deviation of the image coordinates (mm).
    databases : sequence of str or DatabaseModel
        Road databases to simulate (names from :data:`DATABASES` or custom models).
    n_shape_points : int, optional
        Dense mode: a street grid filling the stereo overlap with about this many
        measured shape points in total (all databases), for benchmarks.
    shape_sigma : (float, float, float)
        Prior sigma of shape points written to each ``[[vectors]]`` entry (m).
    position_noise : float
        Standard deviation (m) of the true exposure stations around the flight plan
        (X, Y; half of it in Z).
    attitude_noise : float
        Standard deviation (degrees) of the true omega, phi, kappa.
    dem_noise : float
        Standard deviation (m) of the DEM heights about the true terrain.
    sigma_position, sigma_attitude : float or None
        Priors of the approximate exterior orientation (m, degrees); None = free.
    date : str or None
        Acquisition date written for every image (provenance).
    image_distortion : callable, optional
        ``xy_mm (k, 2) -> xy (k, 2)`` applied to the ideal projections before the
        noise (lens distortion, refraction, ...); the format test uses its output.
    pointing_sigma : float
        Horizontal error (m, per axis) of the analyst's identification of a shape point:
        the point measured on the images is the true point moved by ``N(0,
        pointing_sigma)`` (the same on every image, Z = terrain there). Default 0: the
        images show exactly the true point. Control and tie points are unaffected.
    center : (float, float)
        Model centre (UTM 16N).
    calibration : vectoradjust.sensor.camera.CameraCalibration, optional
        The camera: its focal length and principal point make the image coordinates
        (photo coordinates in the fiducial frame = ideal coordinates about the
        principal point + the principal point); its distortion model, fiducials and
        pixel size serve ``effects`` and ``scan``. Default: f = 152.4 mm, principal
        point (0, 0), nothing else (the image coordinates are exactly as without it).
    effects : sequence of str
        Physical effects put into the image coordinates, a subset of :data:`EFFECTS`:
        ``"distortion"`` (the calibration's lens distortion), ``"refraction"`` (ARDC
        1959) and ``"earth_curvature"``, each the exact inverse of its correction in
        :mod:`vectoradjust.sensor.refine`, with each image's TRUE flying height and each
        point's TRUE terrain height (the correction uses the approximate ZL and the mean
        terrain height). They are applied after the format test and before the
        noise, so the points measured and the noise drawn are those of the same seed
        without effects. Needs ``calibration``.
    scan : bool
        Measure in scanner pixels: every image gets a random scanner affine (film
        rotation ~0.3 deg, placement ~40 px, scale 1e-4, shear 1e-4 rad) with the
        calibration's ``pixel_size``; the image coordinates (with their noise) are
        converted to pixels and the calibrated fiducials are measured in pixels with
        ``N(0, fiducial_sigma)`` (mm) noise. Needs ``calibration`` with fiducials and
        pixel size. ``measurements`` and their sigmas are then in pixels.
    fiducial_sigma : float
        Pointing precision of a fiducial (mm) when ``scan``.

    Returns
    -------
    Scenario
    """
    if int(n_images) < 2:
        raise ProjectError(f"n_images = {n_images} cannot form a stereo model",
                           "Simulate at least 2 images")
    if n_shape_points is not None and int(n_shape_points) < 1:
        raise ProjectError(f"n_shape_points = {n_shape_points} must be positive",
                           "Give the number of measured shape points wanted, e.g. 100000")
    models = []
    for d in databases:
        if isinstance(d, DatabaseModel):
            models.append(d)
        elif str(d) in DATABASES:
            models.append(DATABASES[str(d)])
        else:
            raise ProjectError(f"unknown simulated database {d!r}",
                               f"Use {', '.join(DATABASES)} or a DatabaseModel")
    if len({m.name for m in models}) != len(models):
        raise ProjectError("a simulated database is named twice", "Give every database once")
    cx, cy = float(center[0]), float(center[1])
    n_images = int(n_images)
    effects = _check_effects(effects, calibration, scan)
    if calibration is None:
        camera = Camera(FOCAL_LENGTH, (0.0, 0.0))
    else:
        camera = Camera(calibration.focal_length, tuple(calibration.principal_point),
                        calibration=calibration)
    # the projection about the principal point; physics adds it (and the effects)
    view = Camera(camera.focal_length, (0.0, 0.0))

    # exterior orientation
    rng = _rng(seed, "eo")
    plan_x = cx + (np.arange(n_images) - (n_images - 1) / 2.0) * BASE
    true_eo = np.zeros((n_images, 6))
    true_eo[:, 0] = plan_x + rng.normal(0.0, position_noise, n_images)
    true_eo[:, 1] = cy + rng.normal(0.0, position_noise, n_images)
    true_eo[:, 2] = TERRAIN_LEVEL + FLYING_HEIGHT + rng.normal(0.0, position_noise / 2.0, n_images)
    true_eo[:, 3:] = np.radians(rng.normal(0.0, attitude_noise, (n_images, 3)))
    ids = ["L", "R"] if n_images == 2 else [f"I{i + 1:02d}" for i in range(n_images)]
    physics = None if calibration is None else _physics(calibration, effects, true_eo, ids)
    images = [
        ImageSpec(ids[i], np.round(true_eo[i, :3]), np.zeros(3), sigma_position, sigma_attitude,
                  date)
        for i in range(n_images)
    ]

    # the stereo overlap (seen on >= 2 images) of the flight plan, and an inset
    ov_x = (plan_x[0] + BASE - GROUND_HALF, plan_x[-1] - BASE + GROUND_HALF)
    ov_y = (cy - GROUND_HALF, cy + GROUND_HALF)
    in_x = (ov_x[0] + _INSET, ov_x[1] - _INSET)
    in_y = (ov_y[0] + _INSET, ov_y[1] - _INSET)

    dem_grid, dem_transform = _make_dem(true_eo, (cx, cy), seed, dem_noise)

    # true roads
    if n_shape_points is None:
        roads = _grid_roads(cx, cy, grid, float(block_size), ov_x[0] - 60.0)
        spacing_override = vertex_spacing
        dense_nseg = None
    else:
        w, h = in_x[1] - in_x[0], in_y[1] - in_y[0]
        per_block = 8.0  # vertices per block edge
        b = math.sqrt(len(models) * 2.0 * w * h * per_block / float(n_shape_points))
        b = float(min(max(b, 2.0), block_size, w, h))
        roads = _dense_roads(in_x[0], in_x[1], in_y[0], in_y[1], b)
        _, lengths = _part_lengths(roads)
        n_nodes = len(np.unique(roads.coords, axis=0))
        # object points per database = nodes + interior vertices; spread the intervals
        # over the parts in proportion to their length, rounding cumulatively
        intervals = max(float(n_shape_points) / len(models) - n_nodes, 0.0) + len(lengths)
        ideal = np.cumsum(lengths) * intervals / lengths.sum()
        dense_nseg = np.maximum(1, np.diff(np.concatenate([[0], np.rint(ideal)]))).astype(
            np.int64)
        spacing_override = float(lengths.sum() / dense_nseg.sum())

    # control, check and tie points
    rng = _rng(seed, "control")
    cand = np.column_stack([rng.uniform(*in_x, 4000), rng.uniform(*in_y, 4000)])
    pick = _farthest_points(cand, n_control + n_check, (cx, cy))
    cxy = cand[pick]
    control_true = np.round(
        np.column_stack([cxy, terrain_height(cxy[:, 0], cxy[:, 1], (cx, cy))]), 4)
    nc = min(n_control, len(pick))
    role = np.array(["control"] * nc + ["check"] * (len(pick) - nc), dtype=object)
    width_c = max(2, len(str(max(n_control, 1))))
    width_k = max(2, len(str(max(n_check, 1))))
    cid = [f"GCP{i + 1:0{width_c}d}" for i in range(nc)]
    cid += [f"CHK{i + 1:0{width_k}d}" for i in range(len(pick) - nc)]
    surveyed = np.round(control_true + rng.normal(0.0, CONTROL_SIGMA, control_true.shape), 3)
    control = ControlPoints(np.array(cid, dtype=object), surveyed,
                            np.tile(CONTROL_SIGMA, (len(cid), 1)), role, source="gcps.csv")
    rng = _rng(seed, "ties")
    txy = np.column_stack([rng.uniform(*in_x, n_tie), rng.uniform(*in_y, n_tie)])
    tie_true = np.round(np.column_stack([txy, terrain_height(txy[:, 0], txy[:, 1], (cx, cy))]),
                        4)
    width_t = max(2, len(str(max(n_tie, 1))))
    tie_ids = np.array([f"T{i + 1:0{width_t}d}" for i in range(n_tie)], dtype=object).astype(str)

    # databases
    layers, specs, truth, measured = {}, {}, {}, {}
    meas_parts = []
    rng_img = _rng(seed, "image")
    pi, ii, obs, _ = _observe(control_true, true_eo, view, sigma_image, rng_img,
                              image_distortion, physics=physics)
    meas_parts.append((np.asarray(cid, dtype=str)[pi], ii, obs))
    pi, ii, obs, _ = _observe(tie_true, true_eo, view, sigma_image, rng_img, image_distortion,
                              physics=physics)
    meas_parts.append((tie_ids[pi], ii, obs))
    for model in models:
        layer, pids, true_xy, group, group_first = _make_database(
            model, roads, seed, spacing_override, CRS, dense_nseg)
        true_xyz = np.round(
            np.column_stack([true_xy, terrain_height(true_xy[:, 0], true_xy[:, 1], (cx, cy))]), 4)
        layers[model.name] = layer
        truth[model.name] = (pids, true_xyz)
        specs[model.name] = VectorSpec(
            name=model.name, path=f"{model.stem}_roads.shp", id_field=model.id_field,
            sigma=tuple(float(s) for s in shape_sigma), dem="dem.tif",
            truth=f"truth_{model.stem}.csv")
        rng_db = _rng(seed, f"image:{model.name}")
        seen_xyz = true_xyz[group_first]
        if pointing_sigma > 0:
            pxy = seen_xyz[:, :2] + _rng(seed, f"pointing:{model.name}").normal(
                0.0, pointing_sigma, (len(seen_xyz), 2))
            seen_xyz = np.column_stack([pxy, terrain_height(pxy[:, 0], pxy[:, 1], (cx, cy))])
        gp, ii, obs, seen = _observe(seen_xyz, true_eo, view, sigma_image, rng_db,
                                     image_distortion, physics=physics)
        measured[model.name] = seen[group]
        meas_parts.append((pids[group_first[gp]], ii, obs))

    point_id = np.concatenate([p[0].astype(str) for p in meas_parts])
    img_index = np.concatenate([p[1] for p in meas_parts]).astype(np.int64)
    image_id = np.asarray(ids, dtype=str)[img_index]
    xy = np.concatenate([p[2] for p in meas_parts]).reshape(-1, 2)
    sigma = np.full(xy.shape, float(sigma_image))
    unit, fiducials, scan_affine = "mm", None, None
    if scan:
        scan_affine = _scanner_affines(calibration, n_images, seed)
        xy = _mm_to_pixel(xy, scan_affine[img_index])
        sigma = sigma / _pixel_mean(calibration)
        fiducials = _measure_fiducials(calibration, scan_affine, ids, seed, fiducial_sigma)
        unit = "pixel"
    xy = np.round(xy, 4 if scan else 6)
    measurements = Measurements(point_id, image_id, xy, sigma, source="image_points.csv")
    lines, line_attrs = _truth_lines(roads, (cx, cy))
    options = {
        "seed": int(seed), "n_images": n_images, "grid": list(grid),
        "block_size": float(block_size), "vertex_spacing": vertex_spacing,
        "n_control": n_control, "n_check": n_check, "n_tie": n_tie,
        "sigma_image": sigma_image, "databases": [m.name for m in models],
        "n_shape_points": n_shape_points, "shape_sigma": list(shape_sigma),
        "position_noise": position_noise, "attitude_noise": attitude_noise,
        "dem_noise": dem_noise, "image_distortion": image_distortion is not None,
        "pointing_sigma": float(pointing_sigma),
        "dense_spacing": spacing_override if n_shape_points is not None else None,
        "camera": None if calibration is None else (calibration.name or "calibrated camera"),
        "camera_file": None if calibration is None or calibration.source is None
        else Path(calibration.source).name,
        "effects": list(effects), "scan": bool(scan),
        "fiducial_sigma": float(fiducial_sigma) if scan else None,
    }
    return Scenario(
        seed=int(seed), crs=CRS, camera=camera, images=images, true_eo=true_eo,
        measurements=measurements, control=control, control_true=control_true,
        tie_ids=tie_ids, tie_true=tie_true, layers=layers, vector_specs=specs, truth=truth,
        measured=measured, truth_lines=lines, truth_line_attributes=line_attrs,
        dem_grid=dem_grid, dem_transform=dem_transform, dem_nodata=DEM_NODATA,
        center=(cx, cy), databases={m.name: m for m in models}, sigma_image=float(sigma_image),
        options=options, unit=unit, fiducials=fiducials, scan_affine=scan_affine,
        effects=tuple(effects),
    )


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
    """``(xy about the principal point, xyz, point index, image index) -> recorded mm``."""
    switches = {"affine": False, "principal_point": True}
    switches.update({e: e in effects for e in EFFECTS})
    heights = bool({"refraction", "earth_curvature"} & set(effects))

    def apply(xy, xyz, pi, ii):
        out = np.array(xy, float, copy=True)
        for j in np.unique(ii):
            sel = ii == j
            out[sel] = distort(
                xy[sel], calibration, unit="mm", corrections=switches, image_id=ids[int(j)],
                flying_height=float(true_eo[j, 2]) if heights else None,
                terrain_height=np.asarray(xyz, float)[pi[sel], 2] if heights else None)
        return out

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


# --- writing -------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def _project_toml(sc: Scenario, layer_ext: str, camera_file: str | None = None,
                  reweight: str = "none") -> str:
    out = [
        f"# Simulated project written by vectoradjust.simulate (seed {sc.seed}); see README.md",
        f"name = {_toml_value('vectoradjust simulated scenario, seed ' + str(sc.seed))}",
        f"crs = {_toml_value(sc.crs)}",
        "",
        "[camera]",
    ]
    if camera_file is None:
        out += [f"focal_length = {_toml_value(sc.camera.focal_length)}",
                f"principal_point = {_toml_value(list(sc.camera.principal_point))}",
                "", "[corrections]", "refraction = false", "earth_curvature = false"]
    else:
        out += [f"path = {_toml_value(camera_file)}          # calibration (SIMULATED)",
                "", "[corrections]                   # undo the simulated effects"]
        out += [f"{k} = {_toml_value(v)}" for k, v in sc.default_corrections().items()]
    for im in sc.images:
        out += ["", "[[images]]", f"id = {_toml_value(im.id)}",
                f"position = {_toml_value([float(v) for v in im.position])}",
                f"attitude = {_toml_value([float(v) for v in im.attitude])}"]
        if im.sigma_position is not None:
            out.append(f"sigma_position = {_toml_value(float(im.sigma_position))}")
        if im.sigma_attitude is not None:
            out.append(f"sigma_attitude = {_toml_value(float(im.sigma_attitude))}")
        if im.date is not None:
            out.append(f"date = {_toml_value(im.date)}")
    out += ["", "[measurements]", 'path = "image_points.csv"']
    if sc.unit == "pixel":
        out += ['unit = "pixel"                  # x = column, y = row (scanner pixels)',
                f"sigma = {_toml_value(round(float(sc.measurements.sigma[0, 0]), 6))}"
                "          # pixels",
                'fiducials = "fiducials.csv"']
    else:
        out += [f"sigma = {_toml_value(sc.sigma_image)}"]
    out += ["", "[control]", 'path = "gcps.csv"']
    for name, spec in sc.vector_specs.items():
        stem = sc.databases[name].stem
        out += ["", "[[vectors]]", f"name = {_toml_value(name)}",
                f"path = {_toml_value(stem + '_roads.' + layer_ext)}",
                f"id_field = {_toml_value(spec.id_field)}",
                f"sigma = {_toml_value([float(s) for s in spec.sigma])}",
                f"dem = {_toml_value(spec.dem)}", f"truth = {_toml_value(spec.truth)}"]
    rw = f"reweight = {_toml_value(reweight)}"
    if reweight == "two-pass":
        rw += "   # shape-point accuracy unknown: sigma <- RMS of pass-1 residuals"
    out += ["", "[adjustment]", "max_iterations = 20", rw, "alpha = 0.05"]
    out += ["", "[truth]   # simulated true centrelines: buffer test before/after the adjustment",
            f"path = {_toml_value('truth_roads.' + layer_ext)}", "widths = [1.0, 2.0]", ""]
    return "\n".join(out)


def _camera_toml(cal: CameraCalibration) -> str:
    """A camera file for a calibration that has no file of its own."""
    d = cal.to_dict()
    fid = d.pop("fiducials", None)
    dist = d.pop("distortion", None)
    out = ["# Camera calibration written by vectoradjust.simulate (SIMULATED values)"]
    out += [f"{k} = {_toml_value(v)}" for k, v in d.items()]
    if fid:
        out += ["", "[fiducials]"] + [f"{json.dumps(k)} = {_toml_value(v)}"
                                      for k, v in fid.items()]
    if dist:
        out += ["", "[distortion]"] + [f"{k} = {_toml_value(v)}" for k, v in dist.items()]
    return "\n".join(out) + "\n"


def _layer_frame(layer: LineLayer, crs: str):
    import geopandas as gpd
    import shapely

    xy = layer.coords[:, :2]
    key = layer.vertex_feature * (int(layer.vertex_part.max(initial=0)) + 1) + layer.vertex_part
    _, line_index = np.unique(key, return_inverse=True)
    line_index = np.asarray(line_index).reshape(-1)
    lines = shapely.linestrings(xy, indices=line_index)
    starts = np.searchsorted(line_index, np.arange(len(lines)))
    line_feature = layer.vertex_feature[starts]
    parts = np.bincount(line_feature, minlength=layer.n_features)
    geoms = np.empty(layer.n_features, dtype=object)
    single = parts == 1
    first_line = np.searchsorted(line_feature, np.arange(layer.n_features))
    geoms[single] = lines[first_line[single]]
    multi = np.nonzero(parts > 1)[0]
    if len(multi):
        sel = np.isin(line_feature, multi)
        # multi is sorted: consecutive indices 0..len(multi)-1 for shapely
        geoms[multi] = shapely.multilinestrings(
            lines[sel], indices=np.searchsorted(multi, line_feature[sel]))
    return gpd.GeoDataFrame(dict(layer.attributes), geometry=list(geoms), crs=crs)


def _write_csv(path: Path, header: str, columns: list, formats: list) -> None:
    import pandas as pd

    frame = pd.DataFrame({f"c{i}": c for i, c in enumerate(columns)})
    for i, fmt in enumerate(formats):
        if fmt is not None:
            frame[f"c{i}"] = np.char.mod(fmt, np.asarray(columns[i], float))
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(header + "\n")
        frame.to_csv(fh, header=False, index=False, lineterminator="\n")


def write_project(scenario: Scenario, out_dir, *, format: str = "shp",
                  reweight: str = "none") -> Path:
    """Write the scenario as a project following the file contract (``DESIGN.md`` 9).

    Files: ``project.toml``, ``image_points.csv``, ``gcps.csv``, ``<stem>_roads.shp``
    per database (2D LineStrings / MultiLineStrings with every attribute),
    ``truth_roads.shp`` (true centrelines, 3D), ``truth_<stem>.csv`` per database
    (``point_id,X,Y,Z`` of every vertex; referenced as ``truth =`` in ``[[vectors]]``),
    ``truth_eo.csv`` and ``truth_points.csv`` (true EO, control/check/tie truth),
    ``dem.tif`` (float32 GeoTIFF, deflate) and ``README.md``. A scenario with a
    calibration also gets its camera file (``[camera] path``: a copy of the
    calibration's own file, or ``camera.toml`` written from it) and ``[corrections]``
    that undo the simulated effects; a scanned one ``fiducials.csv``
    (``image_id,fiducial_id,x,y`` in pixels) and ``[measurements] unit = "pixel"``.

    Parameters
    ----------
    scenario : Scenario
    out_dir : str or pathlib.Path
        Created if missing; existing files of the same names are overwritten.
    format : {"shp", "gpkg"}
        Format of the road layers.
    reweight : {"none", "two-pass", "vce"}
        ``[adjustment] reweight`` written to the project file.

    Returns
    -------
    pathlib.Path
        The written ``project.toml``.
    """
    import geopandas as gpd
    import rasterio
    import shapely
    from rasterio.transform import Affine

    if format not in ("shp", "gpkg"):
        raise ProjectError(f"unknown layer format {format!r}", "Use format 'shp' or 'gpkg'")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = scenario
    driver = "ESRI Shapefile" if format == "shp" else "GPKG"

    camera_file = _write_camera(sc, out)
    (out / "project.toml").write_text(_project_toml(sc, format, camera_file, reweight),
                                      encoding="utf-8")
    m = sc.measurements
    xf = "%.4f" if sc.unit == "pixel" else "%.6f"
    _write_csv(out / "image_points.csv", "point_id,image_id,x,y,sigma_x,sigma_y",
               [m.point_id, m.image_id, m.xy[:, 0], m.xy[:, 1], m.sigma[:, 0], m.sigma[:, 1]],
               [None, None, xf, xf, "%.6f", "%.6f"])
    if sc.fiducials is not None:
        f = sc.fiducials
        _write_csv(out / "fiducials.csv", "image_id,fiducial_id,x,y",
                   [f.image_id, f.fiducial_id, f.xy[:, 0], f.xy[:, 1]],
                   [None, None, "%.4f", "%.4f"])
    c = sc.control
    _write_csv(out / "gcps.csv", "point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role",
               [c.point_id, c.xyz[:, 0], c.xyz[:, 1], c.xyz[:, 2], c.sigma[:, 0], c.sigma[:, 1],
                c.sigma[:, 2], c.role],
               [None, "%.3f", "%.3f", "%.3f", "%.3f", "%.3f", "%.3f", None])
    for name, layer in sc.layers.items():
        stem = sc.databases[name].stem
        frame = _layer_frame(layer, sc.crs)
        frame.to_file(out / f"{stem}_roads.{format}", driver=driver)
        ids, xyz = sc.truth[name]
        _write_csv(out / f"truth_{stem}.csv", "point_id,X,Y,Z",
                   [ids, xyz[:, 0], xyz[:, 1], xyz[:, 2]], [None, "%.4f", "%.4f", "%.4f"])
    lines = sc.truth_lines
    sizes = np.array([len(a) for a in lines])
    geom = shapely.linestrings(np.concatenate(lines), indices=np.repeat(np.arange(len(lines)),
                                                                          sizes))
    gpd.GeoDataFrame(dict(sc.truth_line_attributes), geometry=list(geom), crs=sc.crs).to_file(
        out / f"truth_roads.{format}", driver=driver)
    eo = sc.true_eo
    _write_csv(out / "truth_eo.csv", "image_id,XL,YL,ZL,omega,phi,kappa",
               [[im.id for im in sc.images], eo[:, 0], eo[:, 1], eo[:, 2],
                np.degrees(eo[:, 3]), np.degrees(eo[:, 4]), np.degrees(eo[:, 5])],
               [None, "%.4f", "%.4f", "%.4f", "%.6f", "%.6f", "%.6f"])
    pts_id = np.concatenate([c.point_id, sc.tie_ids]).astype(str)
    pts = np.concatenate([sc.control_true, sc.tie_true]).reshape(-1, 3)
    kind = np.concatenate([c.role, np.full(len(sc.tie_ids), "tie", dtype=object)])
    _write_csv(out / "truth_points.csv", "point_id,X,Y,Z,role",
               [pts_id, pts[:, 0], pts[:, 1], pts[:, 2], kind],
               [None, "%.4f", "%.4f", "%.4f", None])
    rows, cols = sc.dem_grid.shape
    with rasterio.open(
        out / "dem.tif", "w", driver="GTiff", height=rows, width=cols, count=1,
        dtype="float32", crs=sc.crs, transform=Affine.from_gdal(*sc.dem_transform),
        nodata=sc.dem_nodata, compress="deflate", predictor=3,
    ) as dst:
        dst.write(sc.dem_grid.astype(np.float32), 1)
    (out / "README.md").write_text(describe(sc, layer_ext=format, reweight=reweight),
                                   encoding="utf-8")
    return out / "project.toml"


def _write_camera(sc: Scenario, out: Path) -> str | None:
    """Write (or copy) the scenario's camera file into ``out``; its name, or None."""
    cal = sc.calibration
    if cal is None:
        return None
    src = Path(cal.source) if cal.source else None
    if (src is not None and src.is_file()
            and CameraCalibration.from_file(src).to_dict() == cal.to_dict()):
        dst = out / src.name
        if not (dst.exists() and dst.resolve() == src.resolve()):
            dst.write_bytes(src.read_bytes())
        return src.name
    (out / "camera.toml").write_text(_camera_toml(cal), encoding="utf-8")
    return "camera.toml"


def describe(scenario: Scenario, layer_ext: str = "shp", reweight: str = "none") -> str:
    """A Markdown description of the scenario (the written project's README).

    Parameters
    ----------
    scenario : Scenario
    layer_ext : str
        Extension of the road layer files named in the text.
    reweight : str
        ``[adjustment] reweight`` of the written project (for the regenerate command).

    Returns
    -------
    str
    """
    sc = scenario
    o = sc.options
    m = sc.measurements
    n_ctrl = int(np.sum(sc.control.role == "control"))
    n_chk = int(np.sum(sc.control.role == "check"))
    shape_ids = set()
    for ids, _ in sc.truth.values():
        shape_ids.update(ids.tolist())
    is_shape = np.isin(m.point_id, np.asarray(sorted(shape_ids), dtype=str))
    z = np.where(sc.dem_grid == sc.dem_nodata, np.nan, sc.dem_grid.astype(float))
    lines = [
        f"# Simulated vectoradjust project (seed {sc.seed})",
        "",
        "Written by `python -m vectoradjust.simulate` (module `vectoradjust.simulate`). A",
        "synthetic re-creation of the set-up of the dissertation \"A photogrammetric approach",
        "for geopositioning OpenStreetMap roads\": every number below is simulated, nothing",
        "is measured. The image coordinates are projections of the TRUE points with the TRUE",
        "exterior orientation plus Gaussian noise; the road databases store displaced",
        "vertices; the truth is in the `truth_*` files.",
        "",
        "## Set-up",
        f"- CRS {sc.crs}; model centre E {sc.center[0]:.0f}, N {sc.center[1]:.0f}.",
        f"- Camera: {_camera_text(sc)}, "
        f"23 x 23 cm format; photo scale 1:{PHOTO_SCALE:.0f}, flying height "
        f"{FLYING_HEIGHT:.1f} m above a terrain at about {TERRAIN_LEVEL:.0f} m, "
        f"{FORWARD_OVERLAP * 100:.0f} % forward overlap (base {BASE:.0f} m), "
        "east-west flight line.",
        f"- {len(sc.images)} images; image coordinate sigma {sc.sigma_image} mm; a point is "
        f"measured on every image whose format (|x|, |y| < {FORMAT_HALF:.0f} mm) holds it, "
        "if at least two do.",
    ]
    lines += _physics_text(sc)
    lines += [
        f"- Approximate exterior orientation in project.toml: true positions rounded to "
        f"metres, zero attitude, sigma_position {sc.images[0].sigma_position} m, "
        f"sigma_attitude {sc.images[0].sigma_attitude} deg.",
        "",
        "True exterior orientation (also in `truth_eo.csv`):",
        "",
        "| image | XL | YL | ZL | omega (deg) | phi (deg) | kappa (deg) |",
        "|---|---|---|---|---|---|---|",
    ]
    for im, eo in zip(sc.images, sc.true_eo):
        a = np.degrees(eo[3:])
        lines.append(f"| {im.id} | {eo[0]:.3f} | {eo[1]:.3f} | {eo[2]:.3f} | {a[0]:.4f} | "
                     f"{a[1]:.4f} | {a[2]:.4f} |")
    lines += [
        "",
        "## Terrain and DEM",
        "- True terrain: `terrain_height` in `vectoradjust.simulate` (a gentle plane, a 6 m "
        "hill and a 2.5 m hollow).",
        f"- `dem.tif`: {sc.dem_grid.shape[0]} x {sc.dem_grid.shape[1]} cells of "
        f"{DEM_CELL:.0f} m, float32, deflate, nodata {sc.dem_nodata:g} (a 4 x 4 cell patch in "
        f"the north-west corner, outside every image); heights {np.nanmin(z):.2f} to "
        f"{np.nanmax(z):.2f} m = true terrain at the cell centres + N(0, {o['dem_noise']} m).",
        "",
        "## Control",
        f"- `gcps.csv`: {n_ctrl} control points (GCP..) and {n_chk} check points (CHK..), "
        "well spread over the stereo overlap; surveyed = true + N(0, "
        f"{CONTROL_SIGMA[0]}, {CONTROL_SIGMA[1]}, {CONTROL_SIGMA[2]} m); true coordinates in "
        "`truth_points.csv`.",
        f"- {len(sc.tie_ids)} tie points (T..), measured on the images only.",
        "",
        "## Roads",
    ]
    if o.get("n_shape_points") is None:
        lines += [
            f"- True centrelines (`truth_roads.{layer_ext}`): {o['grid'][0]} east-west and "
            f"{o['grid'][1]} north-south streets {o['block_size']:g} m apart, split into "
            "features at the intersections; the middle east-west street runs west out of "
            "the stereo overlap; a curved residential street (Crescent Drive, an S-curve) "
            "leaves it to the east (vertices outside the overlap are not measured); an "
            "unnamed two-part service road (a MultiLineString, null name).",
        ]
    else:
        lines += [
            f"- Dense mode: a street grid filling the stereo overlap, about "
            f"{o['n_shape_points']} measured shape points in all, vertex spacing "
            f"{o['dense_spacing']:.2f} m.",
        ]
    lines += [
        "- Vertices shared by features (intersections) have identical XY in a database and "
        "are one object point; the measurements name the first of their ids.",
        "- Z of every database is taken from `dem.tif` (2D layers); true Z = terrain.",
        f"- Analyst's identification error of shape points on the images: "
        f"{o.get('pointing_sigma', 0.0):g} m per axis (0: the images show the true point).",
        "",
        "| database | file | id field | vertices | measured | vertex spacing (m) | "
        "bias (m) | feature shift (m) | noise per axis (m) | expected RMSE (m) | "
        "RMSE all (m) | RMSE measured (m) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, model in sc.databases.items():
        e_all = sc.database_errors(name)
        e_m = sc.database_errors(name, measured_only=True)
        sp = o["dense_spacing"] or o["vertex_spacing"] or model.spacing
        lines.append(
            f"| {name} | {model.stem}_roads.{layer_ext} | {model.id_field} | "
            f"{len(sc.layers[name].coords)} | {int(sc.measured[name].sum())} | {sp:g} | "
            f"({model.bias[0]:.2f}, {model.bias[1]:.2f}) | {model.shift_mean:g} +- "
            f"{model.shift_sd:g} | {model.noise:g} | {model.expected_rmse:.2f} | "
            f"{e_all['rmse_horizontal']:.2f} | {e_m['rmse_horizontal']:.2f} |")
    per_image = ", ".join(f"{i}: {int(np.sum(m.image_id == i))}"
                          for i in [im.id for im in sc.images])
    lines += [
        "",
        "Error model: stored XY = true XY + database bias + per-feature shift (random "
        "direction) + per-vertex noise. Dissertation head-to-head RMSE for comparison: "
        "TNM 2.89 m, OSM 4.35 m, TIGER 19.17 m.",
        "",
        "## Measurements",
        f"- `image_points.csv`: {len(m.point_id)} rows ({per_image}); "
        f"{int(is_shape.sum())} of shape points, the rest control, check and tie points. "
        "One CSV serves all databases (their ids differ); when a database is adjusted "
        "alone, the other databases' shape points should be left out rather than treated "
        "as tie points.",
        "",
        "## Regenerate",
        "```",
        f"python -m vectoradjust.simulate OUT_DIR --seed {sc.seed} --images {len(sc.images)}"
        + (f" --shape-points {o['n_shape_points']}" if o.get("n_shape_points") else "")
        + _regenerate_options(sc, reweight),
        "```",
        "",
    ]
    return "\n".join(lines)


def _camera_text(sc: Scenario) -> str:
    cal = sc.calibration
    if cal is None:
        return f"Wild RC10, f = {sc.camera.focal_length} mm, principal point (0, 0)"
    name = cal.name or "calibrated camera (SIMULATED)"
    x0, y0 = cal.principal_point
    return (f"{name}, camera file `{sc.options.get('camera_file') or 'camera.toml'}`, "
            f"f = {cal.focal_length} mm, principal point ({x0:g}, {y0:g}) mm")


def _physics_text(sc: Scenario) -> list:
    cal = sc.calibration
    if cal is None:
        return []
    labels = {"distortion": f"lens distortion ({cal.distortion_model})",
              "refraction": "atmospheric refraction (ARDC 1959)",
              "earth_curvature": "earth curvature"}
    eff = ", ".join(labels[e] for e in sc.effects) or "none"
    out = [
        "- Image coordinates are in the fiducial frame: ideal coordinates about the "
        "principal point, plus the principal point, plus the simulated effects: "
        f"{eff}. Each effect is the exact inverse of its correction, with each image's "
        "true flying height and each point's true terrain height; `[corrections]` in "
        "project.toml switches on the corrections that undo them (using the approximate "
        "ZL and the mean control height).",
    ]
    if sc.unit == "pixel":
        o = sc.options
        out.append(
            "- Measured in scanner pixels (`[measurements] unit = \"pixel\"`, x = column, "
            "y = row): every image has its own random scanner affine (film rotation, "
            "placement, scale, shear); the calibrated fiducials are measured in pixels "
            f"(`fiducials.csv`, noise {o.get('fiducial_sigma')} mm) and the image sigma is "
            f"{float(sc.measurements.sigma[0, 0]):.4f} px.")
    return out


def _regenerate_options(sc: Scenario, reweight: str) -> str:
    o = sc.options
    text = ""
    if sc.calibration is not None:
        text += f" --camera {o.get('camera_file') or 'camera.toml'}"
    if sc.effects:
        text += f" --effects {','.join(sc.effects)}"
    if sc.unit == "pixel":
        text += " --scan"
    if reweight != "none":
        text += f" --reweight {reweight}"
    return text


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
    parser.add_argument("--reweight", choices=("none", "two-pass", "vce"), default="none",
                        help="[adjustment] reweight written to the project (default none)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        cal = CameraCalibration.from_file(args.camera) if args.camera else None
        sc = make_scenario(args.seed, n_images=args.images, n_shape_points=args.shape_points,
                           calibration=cal, effects=args.effects, scan=args.scan)
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
