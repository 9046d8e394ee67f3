"""The project file and the parameters that override it, as :class:`ProjectInputs`.

A parameter that is set wins over the project file; the result is validated by the core
(:func:`vectoradjust.files.project.parse_project`) either way. Also the parameter
readers shared by the algorithms (:func:`_is_set`, :func:`_number`) and
:func:`raster_from_path`.
"""

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from qgis.core import (
    QgsRasterLayer,
)
from qgis.PyQt.QtCore import QVariant

from ... import qgis_io
from .parameters import (
    _REWEIGHT_VALUES,
    ALPHA,
    CONTROL,
    FOCAL_LENGTH,
    GROUND_CRS,
    IMAGE_HEADERS,
    IMAGES,
    MAX_ITERATIONS,
    MEASUREMENT_SIGMA,
    MEASUREMENTS,
    PP_X,
    PP_Y,
    PROJECT,
    REWEIGHT,
)

__all__ = [
    "ProjectInputs",
    "project_inputs",
    "matching_vector_spec",
    "raster_from_path",
]


@dataclass
class ProjectInputs:
    """What the shared parameters gave (everything but the road layers).

    ``measurements`` and ``control`` are as read; :meth:`project_data` refines the
    measurements and assembles the core's ProjectData exactly as the command line does
    (:func:`vectoradjust.files.assemble.project_data`).
    """

    spec: object  # vectoradjust.files.project.ProjectSpec
    crs: object  # QgsCoordinateReferenceSystem
    measurements: object
    control: object
    source: str
    fiducials: object = None
    vectors: list = field(default_factory=list)

    def project_data(self, vectors, truth, context=None, feedback=None):
        """The core's ProjectData for these road databases.

        With RPC images (``[[images]] model = "rpc"``) their RPCs are read and the ground
        frame set, as :func:`vectoradjust.files.readers.read_rpc_images` does on the
        command line, through QGIS's GDAL and coordinate transformations
        (:func:`qgis_plugin.rpc_io.read_rpc_images`); ``context`` gives the project's
        datum transformations, ``feedback`` the warnings.
        """
        from vectoradjust.files.assemble import project_data

        # the ground CRS is projected (checked): earth curvature applies when switched on
        data = project_data(self.spec, self.measurements, self.control, vectors,
                            crs=self.crs.authid() or self.crs.toWkt(), truth=truth,
                            fiducials=self.fiducials, map_projection=True, source=self.source)
        if self.spec.has_rpc:
            from ...rpc_io import read_rpc_images

            if feedback is not None:
                feedback.setProgressText("reading the RPCs of the satellite images")
            read_rpc_images(data, self.spec, self.crs,
                            context.transformContext() if context is not None else None,
                            feedback.pushWarning if feedback is not None else None)
            if feedback is not None:
                feedback.pushInfo(f"ground frame: {data.ground_frame.description}")
        return data


def _blank(v):
    """True for None, a NULL QVariant and an empty or blank string."""
    if v is None or (isinstance(v, str) and not v.strip()):
        return True
    return isinstance(v, QVariant) and v.isNull()


def _is_set(parameters, name):
    """True when the parameter has a value: not None/NULL/empty, nor a list of such
    (the dialog gives an untouched table as ``[NULL]``)."""
    v = parameters.get(name)
    if isinstance(v, (list, tuple)):
        return not all(_blank(x) for x in v)
    return not _blank(v)


def _number(alg, parameters, name, context) -> Optional[float]:
    if not _is_set(parameters, name):
        return None
    return alg.parameterAsDouble(parameters, name, context)


def _images_from_matrix(values, where):
    from vectoradjust.errors import ProjectError

    values = ["" if _blank(v) else str(v).strip() for v in values or []]
    if not any(values):  # an untouched table: the images of the project file
        return []
    ncol = len(IMAGE_HEADERS)
    if len(values) % ncol:
        raise ProjectError(f"{where}: the table has {len(values)} cells, not a multiple of "
                           f"{ncol} columns ({', '.join(IMAGE_HEADERS)})",
                           "Fill in one row per image")
    images = []
    for r in range(len(values) // ncol):
        row = dict(zip(IMAGE_HEADERS, values[r * ncol:(r + 1) * ncol]))
        if not any(row.values()):
            continue
        where_r = f"{where}, row {r + 1}"
        if not row["id"]:
            raise ProjectError(f"{where_r}: the image id is empty", "Give every image an id")
        im = {"id": row["id"]}

        def num(key, required=True, where_r=where_r, row=row):
            txt = row[key]
            if not txt:
                if required:
                    raise ProjectError(f"{where_r}: {key} is empty",
                                       f"Enter {key} (see the algorithm help)")
                return None
            try:
                return float(txt)
            except ValueError:
                raise ProjectError(f"{where_r}: {key} is {txt!r}, not a number",
                                   "Enter a number ('.' as the decimal separator)") from None

        im["position"] = [num("XL"), num("YL"), num("ZL")]
        im["attitude"] = [num("omega", False) or 0.0, num("phi", False) or 0.0,
                          num("kappa", False) or 0.0]
        for key in ("sigma_position", "sigma_attitude"):
            v = num(key, False)
            if v is not None:
                im[key] = v
        if row["date"]:
            im["date"] = row["date"]
        images.append(im)
    return images


def _read_toml(path):
    from vectoradjust.errors import ProjectError
    from vectoradjust.files.project import tomllib

    p = Path(path)
    if not p.is_file():
        raise ProjectError(f"Project file {str(p)!r} does not exist",
                           "Give the path of a TOML project file")
    try:
        with open(p, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ProjectError(f"{p}: not valid TOML ({exc})", "Fix the syntax at the position "
                           "given") from exc


def _project_file(alg, parameters, context) -> tuple:
    """``(raw, base_dir, where, project_path)`` of the project file parameter (empty if unset)."""
    project_path = alg.parameterAsFile(parameters, PROJECT, context) if _is_set(
        parameters, PROJECT) else ""
    if project_path:
        raw = dict(_read_toml(project_path))
        base_dir = Path(project_path).parent.resolve()
        where = str(project_path)
    else:
        raw = {}
        base_dir = Path.cwd()
        where = "the algorithm parameters"
    return raw, base_dir, where, project_path


def _override_camera_images_crs(alg, parameters, context, raw, fallback_crs):
    """Put the camera, images and ground CRS parameters (when set) into ``raw``."""
    focal = _number(alg, parameters, FOCAL_LENGTH, context)
    if focal is not None:
        raw["camera"] = {"focal_length": focal,
                         "principal_point": [_number(alg, parameters, PP_X, context) or 0.0,
                                             _number(alg, parameters, PP_Y, context) or 0.0]}
    if _is_set(parameters, IMAGES):
        images = _images_from_matrix(alg.parameterAsMatrix(parameters, IMAGES, context),
                                     "Images parameter")
        if images:
            raw["images"] = images
    crs_param = alg.parameterAsCrs(parameters, GROUND_CRS, context) if _is_set(
        parameters, GROUND_CRS) else None
    if crs_param is not None and crs_param.isValid():
        raw["crs"] = crs_param.authid() or crs_param.toWkt()
    elif not raw.get("crs") and fallback_crs is not None and fallback_crs.isValid():
        raw["crs"] = fallback_crs.authid() or fallback_crs.toWkt()


def _override_measurements_adjustment(alg, parameters, context, raw, meas_given):
    """Put the measurement sigma and the adjustment parameters (when set) into ``raw``."""
    meas = dict(raw.get("measurements") or {})
    sigma = _number(alg, parameters, MEASUREMENT_SIGMA, context)
    if sigma is not None:
        meas["sigma"] = sigma
    if meas_given:
        meas.setdefault("path", "(Image measurements parameter)")
    if meas or "measurements" in raw:
        raw["measurements"] = meas
    adj = dict(raw.get("adjustment") or {})
    rw = _REWEIGHT_VALUES[alg.parameterAsEnum(parameters, REWEIGHT, context)] if _is_set(
        parameters, REWEIGHT) else None
    if rw is not None:
        adj["reweight"] = rw
    alpha = _number(alg, parameters, ALPHA, context)
    if alpha is not None:
        adj["alpha"] = alpha
    if _is_set(parameters, MAX_ITERATIONS):
        adj["max_iterations"] = alg.parameterAsInt(parameters, MAX_ITERATIONS, context)
    if adj:
        raw["adjustment"] = adj


def _require_sections(raw, where):
    """Raise ProjectError when the camera, the images or the image measurements are missing."""
    from vectoradjust.errors import ProjectError

    images = raw.get("images")
    satellite = bool(images) and isinstance(images, list) and all(
        isinstance(im, dict) and im.get("model") == "rpc" for im in images)
    if "camera" not in raw and not satellite:  # RPC images need no frame camera
        raise ProjectError(f"{where}: no camera is given",
                           "Give a project file with [camera] or the focal length parameter")
    if not images:
        raise ProjectError(f"{where}: no images are given",
                           "Give a project file with [[images]] or fill in the Images table "
                           "(id, XL, YL, ZL, omega, phi, kappa)")
    if "measurements" not in raw:
        raise ProjectError(f"{where}: no image measurements are given",
                           "Choose the image measurements (CSV file or table) or give a "
                           "project file with [measurements] path")


def _refuse_datums(spec) -> None:
    """The plugin does not transform control points: a project that states their CRS or a
    vertical datum is refused rather than read in the wrong datum."""
    from vectoradjust.errors import ProjectError

    stated = [k for k in ("crs", "vertical_crs") if (spec.control or {}).get(k)]
    # orthometric heights of RPC images: the top-level vertical_crs is their datum, for the
    # ground frame only (the control and DEM heights are taken in it, as on the command
    # line with a 2D crs): rpc_io.ground_frame applies the geoid
    rpc_heights = spec.has_rpc and spec.heights == "orthometric"
    if getattr(spec, "vertical_crs", None) and not rpc_heights:
        stated.append("vertical_crs (top level)")
    if stated:
        raise ProjectError(
            f"{spec.path}: the project states {', '.join(stated)} for the control points or "
            "heights; the QGIS plugin does not transform them yet",
            "Run it with the vectoradjust command line (which applies them), or give the "
            "control points and heights in the project CRS and remove those keys")


def _read_tables(alg, parameters, context, spec, crs) -> tuple:
    """``(measurements, control, fiducials)`` from the parameters or the project's files."""
    from vectoradjust.files.csv_tables import read_control, read_fiducials, read_measurements

    unit = spec.measurements.get("unit", "mm")
    if _is_set(parameters, MEASUREMENTS):
        src = alg.parameterAsSource(parameters, MEASUREMENTS, context)
        raw_meas = qgis_io.read_measurements_source(
            parameters.get(MEASUREMENTS), src, spec.measurements.get("sigma"),
            f"measurements table {src.sourceName()!r}", unit=unit)
    else:
        raw_meas = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"),
                                     unit=unit)
    if _is_set(parameters, CONTROL):
        src = alg.parameterAsSource(parameters, CONTROL, context)
        control = qgis_io.read_control_source(parameters.get(CONTROL), src, crs, context,
                                              f"control table {src.sourceName()!r}")
    elif spec.control is not None:
        _refuse_datums(spec)
        control = read_control(spec.control["path"])
    else:
        control = None  # an empty table (vectoradjust.files.assemble)
    fid_path = spec.measurements.get("fiducials")
    fiducials = read_fiducials(fid_path, unit) if fid_path else None
    return raw_meas, control, fiducials


def project_inputs(alg, parameters, context, feedback, fallback_crs) -> ProjectInputs:
    """Assemble camera, images, measurements, control and settings.

    Parameters
    ----------
    fallback_crs : QgsCoordinateReferenceSystem
        Ground CRS when neither the parameter nor the project file gives one (the road
        layer's CRS).
    """
    from vectoradjust.files.project import parse_project

    meas_given = _is_set(parameters, MEASUREMENTS)
    raw, base_dir, where, project_path = _project_file(alg, parameters, context)
    # parameters override the project file
    _override_camera_images_crs(alg, parameters, context, raw, fallback_crs)
    _override_measurements_adjustment(alg, parameters, context, raw, meas_given)
    _require_sections(raw, where)
    spec = parse_project(raw, base_dir=base_dir, path=project_path or None)
    crs = qgis_io.ground_crs(spec.crs, f"{where}: crs")
    raw_meas, control, fiducials = _read_tables(alg, parameters, context, spec, crs)
    return ProjectInputs(spec=spec, crs=crs, measurements=raw_meas, control=control,
                         source=where, fiducials=fiducials, vectors=list(spec.vectors))


def matching_vector_spec(inputs, layer, source=None, id_field=""):
    """The ``[[vectors]]`` entry ``layer`` stands for (see :mod:`.matching`), or None."""
    from ..matching import matching_vector_spec as match

    return match(inputs, layer, source, id_field)


def raster_from_path(path, where):
    """A QgsRasterLayer of a DEM named by a project file."""
    from vectoradjust.errors import DEMError

    if not os.path.isfile(path):
        raise DEMError(f"DEM {path!r} does not exist ({where})", "Check dem = in the "
                       "[[vectors]] entry of the project file", path=path)
    layer = QgsRasterLayer(path, os.path.basename(path), "gdal")
    if not layer.isValid():
        raise DEMError(f"{path}: cannot be read as a raster ({where})", "Give a GeoTIFF DEM",
                       path=path)
    return layer
