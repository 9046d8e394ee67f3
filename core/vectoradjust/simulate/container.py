"""The simulated project and its truth (:class:`Scenario`), as ``make_scenario`` returns it.

:meth:`Scenario.to_project_data` turns it into in-memory project data (no files), the
way ``load_project_data`` would read the written project.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from vectoradjust.adjust.dem import bilinear
from vectoradjust.errors import ProjectError
from vectoradjust.model import (
    AdjustmentSettings,
    Camera,
    ControlPoints,
    DemGrid,
    LineLayer,
    Measurements,
    ProjectData,
)
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.interior import FiducialMeasurements, refine_measurements
from vectoradjust.simulate.imaging import EFFECTS


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
        names = _database_names(self, vectors)
        pairs = [(replace(self.vector_specs[name]), _layer_with_dem_z(self, name))
                 for name in names]
        meas = _measurements_of(self, names)
        images = [replace(im, position=im.position.copy(), attitude=im.attitude.copy())
                  for im in self.images]
        camera = replace(self.camera)
        corr = {"refraction": False, "earth_curvature": False}
        interior: dict = {}
        if self.calibration is not None:
            meas, camera, corr, interior = _refined(self, meas, images, corrections)
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


# --- to_project_data, step by step ---------------------------------------------------
def _database_names(sc: Scenario, vectors: Sequence[str] | None) -> list:
    """The database names asked for (default: all); unknown names are an error."""
    names = list(sc.layers) if vectors is None else [str(v) for v in vectors]
    unknown = [n for n in names if n not in sc.layers]
    if unknown:
        raise ProjectError(
            f"the scenario has no database named {', '.join(map(repr, unknown))}",
            f"Choose from {', '.join(sc.layers)}",
        )
    return names


def _layer_with_dem_z(sc: Scenario, name: str) -> LineLayer:
    """A copy of a database layer, Z of every vertex interpolated in the DEM."""
    layer = sc.layers[name]
    coords = layer.coords.copy()
    coords[:, 2] = bilinear(sc.dem_grid, sc.dem_transform, coords[:, :2], nodata=sc.dem_nodata)
    dem = DemGrid(np.asarray(sc.dem_grid, float), tuple(sc.dem_transform), sc.dem_nodata)
    return replace(layer, coords=coords, dem=dem)


def _measurements_of(sc: Scenario, names: list) -> Measurements:
    """A copy of the measurements without the shape points of the databases not in ``names``."""
    meas = sc.measurements
    dropped = [n for n in sc.layers if n not in names]
    if not dropped:
        return replace(meas, xy=meas.xy.copy(), sigma=meas.sigma.copy())
    other = np.concatenate([sc.truth[n][0] for n in dropped])
    keep = ~np.isin(meas.point_id, other)
    return Measurements(meas.point_id[keep], meas.image_id[keep], meas.xy[keep],
                        meas.sigma[keep], source=meas.source, rows=meas.rows[keep])


def _refined(sc: Scenario, meas: Measurements, images: list, corrections: dict | None):
    """Refine the image coordinates as the project reader would (calibrated camera).

    Returns the refined measurements, the camera with the calibration's principal
    point, the ``[corrections]`` used and the refinement report.
    """
    corr = sc.default_corrections()
    corr.update(corrections or {})
    res = refine_measurements(meas, images, sc.camera, corr, unit=sc.unit,
                              fiducials=sc.fiducials, control=sc.control)
    camera = Camera(sc.camera.focal_length, res.principal_point, calibration=sc.calibration)
    return res.measurements, camera, corr, res.report
