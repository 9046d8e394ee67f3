"""Assembling a project's inputs (as read) into :class:`~vectoradjust.model.ProjectData`.

Reading files is the readers' business (:mod:`vectoradjust.files.readers` with geopandas and
rasterio; the QGIS plugin with the QGIS API; :mod:`vectoradjust.files.tables` for the CSV
tables). Everything after the reading is here, once, so that every route gives the
same arrays:

* the image coordinate refinement (``DESIGN.md`` section 5:
  :func:`vectoradjust.sensor.interior.refine_measurements` with the fiducials, the camera
  and the ``[corrections]`` switches);
* the :class:`~vectoradjust.model.Camera` the collinearity equations use with the
  refined coordinates (principal point ``(0, 0)`` once reduced);
* an empty control table when the project has none;
* the ``[qa]`` table, the truth tables and the interior orientation report.

A "heart" module: numpy and vectoradjust heart modules only, no file I/O.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.model import Camera, ControlPoints, Measurements, ProjectData
from vectoradjust.sensor.interior import FiducialMeasurements, refine_measurements

__all__ = ["project_data", "empty_control"]


def empty_control(source: str = "<control>") -> ControlPoints:
    """A control table without points (a project without ``[control]``).

    Parameters
    ----------
    source : str
        How messages name the (missing) table.

    Returns
    -------
    ControlPoints
    """
    return ControlPoints(np.zeros(0, str), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, str),
                         source=source)


def project_data(
    spec,
    measurements: Measurements,
    control: Optional[ControlPoints],
    vectors: list,
    *,
    crs: Optional[str] = None,
    truth: Optional[dict] = None,
    fiducials: Optional[FiducialMeasurements] = None,
    map_projection: bool = True,
    source: Optional[str] = None,
) -> ProjectData:
    """The adjustment's inputs from a parsed project and the tables as read.

    Parameters
    ----------
    spec : vectoradjust.files.project.ProjectSpec
        The parsed project (camera, images, ``[measurements] unit``, corrections,
        settings, and ``raw["qa"]``).
    measurements : Measurements
        The image measurements as read (``unit`` of ``[measurements]``, not refined).
    control : ControlPoints or None
        Control and check points; None for a project without ``[control]``.
    vectors : list of (VectorSpec, LineLayer)
        The road databases, Z already filled (DEM or geometry).
    crs : str, optional
        The ground CRS as the caller names it (checked projected, in metres, by the
        caller); default ``spec.crs``.
    truth : dict, optional
        Database name -> (point ids, (n, 3) true coordinates) (simulations).
    fiducials : FiducialMeasurements, optional
        Measured fiducials (``[measurements] fiducials``).
    map_projection : bool
        Whether the ground CRS is a map projection (earth curvature is corrected only
        then, when switched on in ``[corrections]``).
    source : str, optional
        The project, for messages; default the project file or ``"<project>"``.

    Returns
    -------
    ProjectData
        ``measurements`` refined to photo mm with sigmas in mm, ``camera`` with the
        principal point the collinearity equations must use with them and the
        calibration, ``interior`` the refinement report, ``qa`` the ``[qa]`` table.

    Raises
    ------
    VectorAdjustError
        From the refinement (unknown image, missing fiducials or calibration ...).
    """
    where = source if source is not None else (str(spec.path) if spec.path else "<project>")
    unit = spec.measurements.get("unit", "mm")
    if control is None:
        control = empty_control(f"{where} [control]")
    interior = refine_measurements(
        measurements, spec.images, spec.camera, spec.corrections, unit=unit,
        fiducials=fiducials, control=control, map_projection=bool(map_projection))
    camera = Camera(spec.camera.focal_length, interior.principal_point,
                    calibration=spec.camera.calibration)
    return ProjectData(
        crs=crs if crs is not None else spec.crs, camera=camera, images=spec.images,
        measurements=interior.measurements, control=control, vectors=list(vectors),
        settings=spec.settings, truth=dict(truth or {}), corrections=spec.corrections,
        source=where, qa=(spec.raw or {}).get("qa"),
        conflation=(spec.raw or {}).get("conflation"), interior=interior.report,
    )
