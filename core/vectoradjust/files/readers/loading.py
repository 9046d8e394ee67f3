"""A project's files read into :class:`~vectoradjust.model.ProjectData`.

:func:`load_project_data` reads every file a project refers to (tables, line layers,
control, DEM, trajectory) and :func:`read_rpc_images` the RPCs of its RPC images and
their ground frame.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.files.csv_tables import read_control, read_measurements, read_truth_points
from vectoradjust.files.project import ProjectSpec, load_project
from vectoradjust.files.readers.crs import (
    _parts,
    _project_target,
    _user_crs,
    _with_vertical,
    check_projected_crs,
    control_to_project_crs,
    same_crs,
    transform_points,
)
from vectoradjust.files.readers.elevation import dem_heights, sample_dem
from vectoradjust.files.readers.layers import read_line_layer
from vectoradjust.model import ProjectData

__all__ = [
    "load_project_data",
    "read_rpc_images",
]


def load_project_data(project, vectors: Optional[list] = None,
                      progress=None) -> ProjectData:
    """Read every file a project refers to.

    Parameters
    ----------
    project : str, os.PathLike or ProjectSpec
    vectors : list of str, optional
        Only these ``[[vectors]]`` entries are read (default: all).
    progress : callable, optional
        ``progress(fraction, message)`` before each file is read.

    Returns
    -------
    ProjectData
        The image measurements are already refined
        (:func:`vectoradjust.sensor.interior.refine_measurements`: fiducial affine or pixel
        size, principal point, lens distortion, refraction, earth curvature as switched
        in ``[corrections]``): ``measurements`` are photo mm with sigmas in mm,
        ``camera.principal_point`` is the one the collinearity equations must use with
        them (``(0, 0)`` once reduced), ``camera.calibration`` the
        :class:`~vectoradjust.sensor.camera.CameraCalibration` and ``interior`` the report.
        The control points are in the project CRS (:func:`control_to_project_crs`), the
        DEM heights in its vertical datum (:func:`dem_heights`).
    """
    from vectoradjust.files.assemble import project_data
    from vectoradjust.files.csv_tables import read_fiducials

    spec = project if isinstance(project, ProjectSpec) else load_project(project)
    where = str(spec.path) if spec.path else "<project>"
    crs = check_projected_crs(spec.crs, f"{where}: crs")
    unit = spec.measurements.get("unit", "mm")
    steps = 3 + 3 * len(spec.vectors)
    done = [0]

    def say(message: str) -> None:
        if progress is not None:
            progress(min(done[0] / steps, 1.0), message)
        done[0] += 1

    say("reading the image measurements")
    raw_meas = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"),
                                 unit=unit)
    say("reading the control points")
    control = read_control(spec.control["path"]) if spec.control is not None else None
    if control is not None:
        control = control_to_project_crs(control, spec, crs, where)
    fid_path = spec.measurements.get("fiducials")
    fiducials = read_fiducials(fid_path, unit) if fid_path else None
    trajectory_warnings = _trajectory(spec, crs, where)
    names = vectors or [v.name for v in spec.vectors]
    layers, truth = _read_vectors(spec, crs, where, names, say)
    for n in names:
        spec.vector(n)  # raises a clear error for an unknown name
    say("refining the image coordinates")
    # refinement (docs/method.md section 5), camera, [qa], truth: vectoradjust.files.assemble,
    # shared with QGIS;
    # the project CRS is projected (checked above): earth curvature applies when asked
    data = project_data(spec, raw_meas, control, layers, crs=crs.to_string(), truth=truth,
                        fiducials=fiducials, map_projection=bool(crs.is_projected),
                        source=where)
    if spec.has_rpc:
        say("reading the RPCs of the satellite images")
        read_rpc_images(data, spec, crs.to_string())
    data.reading_warnings.extend(trajectory_warnings)
    return data


def _read_vectors(spec: ProjectSpec, crs, where: str, names: list, say) -> tuple:
    """The ``[[vectors]]`` entries named in ``names``: their line layers (with the heights
    of their DEM in the project's vertical datum) and truth points; ``say(message)``
    before each step. Returns ``([(entry, LineLayer), ...], {name: truth table})``."""
    layers = []
    truth = {}
    for v in spec.vectors:
        if v.name not in names:
            continue
        say(f"reading the road layer {v.name}")
        layer = read_line_layer(v.path, v.name, v.id_field, _parts(crs)[0], v.layer, v.where)
        say(f"heights of {v.name} from the DEM")
        if v.dem:
            dem_report: dict = {}
            z = sample_dem(v.dem, layer.coords[:, :2], _parts(crs)[0], dem_report)
            layer.coords[:, 2], heights = dem_heights(z, layer.coords[:, :2], spec, crs,
                                                      f"{where} [[vectors]] {v.name!r} dem")
            layer.reading["dem"] = {"source": v.dem, "crs": dem_report.get("crs"),
                                    "heights": heights}
            layer.dem = dem_report.get("grid")
        layers.append((v, layer))
        say(f"reading the truth of {v.name}")
        if v.truth:
            truth[v.name] = read_truth_points(v.truth)
    return layers, truth


def _trajectory(spec: ProjectSpec, project_crs, where: str) -> list:
    """``[trajectory]``: GNSS/INS positions (and attitudes, sigmas) into the
    ``[[images]]`` entries, transformed to the project CRS like the control points;
    returns the warnings (images without a row, the transformation's)."""
    if not spec.trajectory:
        return []
    from vectoradjust.files.trajectory import apply_trajectory, read_trajectory

    table = spec.trajectory
    w = f"{where} [trajectory]"
    cols = read_trajectory(table["path"])
    xyz = np.column_stack([cols["X"], cols["Y"], cols["Z"]])
    source = _user_crs(table["crs"], f"{w} crs") if table.get("crs") else project_crs
    vname = table.get("vertical_crs") or spec.vertical_crs
    if vname:
        source = _with_vertical(source, _user_crs(vname, f"{w} vertical_crs"), w)
    target = _project_target(project_crs, spec, where)
    warnings: list = []
    if not same_crs(source, target):
        xyz, info = transform_points(xyz, source, target, f"{w} ({table['path']})")
        if info.get("warning"):
            warnings.append(info["warning"])
    apply_trajectory(spec.images, cols, xyz, str(table["path"]), warnings)
    return warnings


def read_rpc_images(data: ProjectData, spec: ProjectSpec, crs: str) -> None:
    """Read the RPCs of the project's RPC images into their ``ImageSpec.rpc`` and give
    ``data`` the ground frame (project CRS and heights to WGS84 longitude, latitude and
    ellipsoidal height, :func:`vectoradjust.files.rpc.crs_frame`)."""
    from vectoradjust.files.assemble import read_image_rpcs
    from vectoradjust.files.rpc import crs_frame, read_rpc

    near = read_image_rpcs(data.images, read_rpc)
    data.ground_frame = crs_frame(crs, heights=spec.heights or "ellipsoidal",
                                  geoid=spec.vertical_crs if spec.heights == "orthometric"
                                  else None, near=near)
