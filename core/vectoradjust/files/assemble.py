"""Assembling a project's inputs (as read) into :class:`~vectoradjust.model.ProjectData`.

Reading files is the readers' business (:mod:`vectoradjust.files.readers` with geopandas and
rasterio; the QGIS plugin with the QGIS API; :mod:`vectoradjust.files.csv_tables` for the CSV
tables). Everything after the reading is here, once, so that every route gives the
same arrays:

* the image coordinate refinement (``docs/method.md`` section 5:
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

from vectoradjust.errors import ProjectError
from vectoradjust.model import Camera, ControlPoints, Measurements, ProjectData
from vectoradjust.sensor.interior import FiducialMeasurements, refine_measurements

__all__ = ["project_data", "empty_control", "read_image_rpcs"]


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
    if any(im.model == "rpc" for im in spec.images):
        meas, camera, report = _split_rpc(spec, measurements, unit, fiducials, control,
                                          map_projection, where)
    else:
        interior = refine_measurements(
            measurements, spec.images, spec.camera, spec.corrections, unit=unit,
            fiducials=fiducials, control=control, map_projection=bool(map_projection))
        camera = Camera(spec.camera.focal_length, interior.principal_point,
                        calibration=spec.camera.calibration)
        meas, report = interior.measurements, interior.report
    return ProjectData(
        crs=crs if crs is not None else spec.crs, camera=camera, images=spec.images,
        measurements=meas, control=control, vectors=list(vectors),
        settings=spec.settings, truth=dict(truth or {}), corrections=spec.corrections,
        source=where, qa=(spec.raw or {}).get("qa"),
        conflation=(spec.raw or {}).get("conflation"), interior=report,
    )


def _subset(meas: Measurements, sel: np.ndarray) -> Measurements:
    return Measurements(meas.point_id[sel], meas.image_id[sel], meas.xy[sel], meas.sigma[sel],
                        source=meas.source, rows=np.asarray(meas.rows)[sel])


def _split_rpc(spec, measurements: Measurements, unit: str, fiducials, control,
               map_projection: bool, where: str):
    """Measurements of a block with RPC images: the rows on RPC images stay pixels
    (column, row; GDAL's convention), the frame images' rows are refined as usual."""
    rpc_ids = [im.id for im in spec.images if im.model == "rpc"]
    frames = [im for im in spec.images if im.model != "rpc"]
    written = ((spec.raw or {}).get("measurements") or {}).get("unit")
    if not frames and written is not None and unit != "pixel":
        raise ProjectError(f"{where}: [measurements] unit = {unit!r}, but every image is an "
                           "RPC image, measured in pixels", 'Write [measurements] unit = '
                           '"pixel" (column, row; 0 at the corner of the first pixel)',
                           path=where)
    on_rpc = np.isin(measurements.image_id, rpc_ids)
    out = _subset(measurements, np.arange(len(on_rpc)))
    report = {"input_unit": unit, "rpc_images": rpc_ids,
              "notes": ["measurements on RPC images are pixels (column, row), used as read"]}
    if not frames:
        return out, Camera(float("nan")), report
    sel = np.flatnonzero(~on_rpc)
    interior = refine_measurements(
        _subset(measurements, sel), frames, spec.camera, spec.corrections, unit=unit,
        fiducials=fiducials, control=control, map_projection=bool(map_projection))
    out.xy[sel] = interior.measurements.xy
    out.sigma[sel] = interior.measurements.sigma
    camera = Camera(spec.camera.focal_length, interior.principal_point,
                    calibration=spec.camera.calibration)
    return out, camera, {**interior.report, "rpc_images": rpc_ids}


def read_image_rpcs(images: list, read) -> Optional[tuple[float, float]]:
    """Fill the RPCs of the RPC images that have none yet, with ``read(path)``.

    The command line reads them with rasterio (:func:`vectoradjust.files.rpc.read_rpc`),
    QGIS with its own GDAL; both go through here.

    Returns
    -------
    (float, float) or None
        The mean longitude and latitude offset of the RPCs (where the project is, for
        choosing a transformation); None without RPC images.
    """
    rpcs = []
    for im in images:
        if im.model == "rpc":
            if im.rpc.rpc is None:
                im.rpc.rpc = read(im.rpc.path)
            rpcs.append(im.rpc.rpc)
    if not rpcs:
        return None
    return (float(np.mean([r.long_off for r in rpcs])),
            float(np.mean([r.lat_off for r in rpcs])))
