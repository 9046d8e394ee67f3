"""Parameters and input assembly shared by "Adjust road vectors" and "Compare road databases".

The camera, images, measurements, control and settings come from a project file
(TOML, the contract of ``DESIGN.md`` section 9) and/or from parameters. A parameter
that is set wins over the project file; what neither gives is an error with the
core's message. The project file is validated by the core
(:func:`vectoradjust.project.parse_project`), and a parameter-only set-up is validated
the same way, so both routes give the same checks and the same numbers.

A road layer whose file is the ``path`` of a ``[[vectors]]`` entry of the project file
takes that entry's name, id field, sigma, DEM and truth unless parameters say
otherwise.
"""

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from qgis.core import (
    QgsProcessing,
    QgsProcessingParameterCrs,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterFile,
    QgsProcessingParameterMatrix,
    QgsProcessingParameterNumber,
    QgsRasterLayer,
)

from .. import qgis_io

PROJECT = "PROJECT"
MEASUREMENTS = "MEASUREMENTS"
MEASUREMENT_SIGMA = "MEASUREMENT_SIGMA"
CONTROL = "CONTROL"
FOCAL_LENGTH = "FOCAL_LENGTH"
PP_X = "PRINCIPAL_POINT_X"
PP_Y = "PRINCIPAL_POINT_Y"
IMAGES = "IMAGES"
GROUND_CRS = "GROUND_CRS"
REWEIGHT = "REWEIGHT"
ALPHA = "ALPHA"
MAX_ITERATIONS = "MAX_ITERATIONS"

IMAGE_HEADERS = ["id", "XL", "YL", "ZL", "omega", "phi", "kappa", "sigma_position",
                 "sigma_attitude", "date"]
REWEIGHT_OPTIONS = ["as in the project file (none if not given)", "none", "two-pass"]
_REWEIGHT_VALUES = [None, "none", "two-pass"]

PROJECT_HELP = """
<h3>Camera, images, measurements and control</h3>
<p>Give a <b>project file</b> (TOML, as for the <code>vectoradjust</code> command line:
<code>crs</code>, <code>[camera]</code>, <code>[[images]]</code>, <code>[measurements]</code>,
<code>[control]</code>, <code>[corrections]</code>, <code>[adjustment]</code>) and/or the
parameters below; a parameter that
is set overrides the project file.</p>
<ul>
<li><b>Image measurements</b>: a CSV file or table with <code>point_id, image_id, x, y</code>
and optionally <code>sigma_x, sigma_y</code> (photo coordinates in mm, or pixels with
<code>[measurements] unit = "pixel"</code>; they are refined as the project's [camera] and
[corrections] say: fiducial affine, principal point, lens distortion, refraction, earth
curvature, as the command line does). Shape point
ids are <code>&lt;feature id&gt;_&lt;vertex index&gt;</code> (see Extract shape points); ids
that are neither control points nor shape points are tie points.</li>
<li><b>Control points</b>: a CSV file, table or point layer with <code>point_id, X, Y, Z,
sigma_x, sigma_y, sigma_z</code> and optionally <code>role</code> (control or check) in the
ground CRS; a point layer without X/Y fields gives X, Y (and Z) by its geometry.</li>
<li><b>Focal length</b> (mm) and <b>principal point</b> replace the project's [camera];
<b>Images</b> (a table: id, XL, YL, ZL in m, omega, phi, kappa in degrees, optional
sigma_position in m and sigma_attitude in degrees: empty = free, date) replace its
[[images]]. The positions and attitudes are approximations that start the iteration.</li>
<li><b>Ground CRS</b>: projected, metres; default the project's crs, else the road layer's
CRS.</li>
</ul>
"""


def add_project_parameters(alg):
    """Add the shared parameters to an algorithm (call from ``initAlgorithm``)."""
    advanced = QgsProcessingParameterDefinition.FlagAdvanced

    alg.addParameter(QgsProcessingParameterFile(
        PROJECT, "Project file (TOML; camera, images, measurements, control, settings)",
        behavior=QgsProcessingParameterFile.File, fileFilter="vectoradjust project (*.toml)",
        optional=True))
    alg.addParameter(QgsProcessingParameterFeatureSource(
        MEASUREMENTS, "Image measurements (CSV or table: point_id, image_id, x, y [mm])",
        [QgsProcessing.TypeVector], optional=True))
    alg.addParameter(QgsProcessingParameterFeatureSource(
        CONTROL, "Control and check points (CSV, table or point layer: point_id, X, Y, Z, "
        "sigma_x, sigma_y, sigma_z, role)", [QgsProcessing.TypeVector], optional=True))
    alg.addParameter(QgsProcessingParameterNumber(
        FOCAL_LENGTH, "Focal length [mm] (replaces the project's camera)",
        QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
    for name, label in ((PP_X, "Principal point x0 [mm]"), (PP_Y, "Principal point y0 [mm]")):
        p = QgsProcessingParameterNumber(name, label, QgsProcessingParameterNumber.Double,
                                         defaultValue=0.0, optional=True)
        p.setFlags(p.flags() | advanced)
        alg.addParameter(p)
    alg.addParameter(QgsProcessingParameterMatrix(
        IMAGES, "Images with approximate exterior orientation (replace the project's images)",
        numberRows=0, hasFixedNumberRows=False, headers=IMAGE_HEADERS, optional=True))
    alg.addParameter(QgsProcessingParameterCrs(
        GROUND_CRS, "Ground CRS (projected, metres; default: project crs or road layer CRS)",
        optional=True))
    p = QgsProcessingParameterNumber(
        MEASUREMENT_SIGMA, "Image coordinate sigma [mm] where the measurements have no sigma "
        "columns", QgsProcessingParameterNumber.Double, optional=True, minValue=0.0)
    p.setFlags(p.flags() | advanced)
    alg.addParameter(p)
    p = QgsProcessingParameterEnum(REWEIGHT, "Reweighting of the shape points",
                                   REWEIGHT_OPTIONS, defaultValue=0)
    p.setFlags(p.flags() | advanced)
    alg.addParameter(p)
    p = QgsProcessingParameterNumber(ALPHA, "Significance level of the chi-square test",
                                     QgsProcessingParameterNumber.Double, optional=True,
                                     minValue=0.0, maxValue=1.0)
    p.setFlags(p.flags() | advanced)
    alg.addParameter(p)
    p = QgsProcessingParameterNumber(MAX_ITERATIONS, "Maximum number of iterations",
                                     QgsProcessingParameterNumber.Integer, optional=True,
                                     minValue=1)
    p.setFlags(p.flags() | advanced)
    alg.addParameter(p)


@dataclass
class ProjectInputs:
    """What the shared parameters gave (everything but the road layers).

    ``measurements`` are refined (interior orientation, as the headless reader does)
    and ``camera`` is the camera the collinearity equations use with them.
    """

    spec: object  # vectoradjust.project.ProjectSpec
    crs: object  # QgsCoordinateReferenceSystem
    camera: object
    measurements: object
    control: object
    source: str
    interior: dict = field(default_factory=dict)
    vectors: list = field(default_factory=list)

    def project_data(self, vectors, truth):
        """The core's ProjectData for these road databases."""
        from vectoradjust.model import ProjectData

        return ProjectData(
            crs=self.crs.authid() or self.crs.toWkt(), camera=self.camera,
            images=self.spec.images, measurements=self.measurements, control=self.control,
            vectors=vectors, settings=self.spec.settings, truth=truth,
            corrections=self.spec.corrections, source=self.source,
            qa=self.spec.raw.get("qa"), interior=self.interior)


def _is_set(parameters, name):
    v = parameters.get(name)
    return v is not None and v != "" and not (isinstance(v, (list, tuple)) and len(v) == 0)


def _number(alg, parameters, name, context) -> Optional[float]:
    if not _is_set(parameters, name):
        return None
    return alg.parameterAsDouble(parameters, name, context)


def _images_from_matrix(values, where):
    from vectoradjust.errors import ProjectError

    values = ["" if v is None else str(v).strip() for v in values]
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
    from vectoradjust.project import tomllib

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


def project_inputs(alg, parameters, context, feedback, fallback_crs) -> ProjectInputs:
    """Assemble camera, images, measurements, control and settings.

    Parameters
    ----------
    fallback_crs : QgsCoordinateReferenceSystem
        Ground CRS when neither the parameter nor the project file gives one (the road
        layer's CRS).
    """
    import numpy as np

    from vectoradjust.errors import ProjectError
    from vectoradjust.interior import refine_measurements
    from vectoradjust.model import Camera, ControlPoints
    from vectoradjust.project import parse_project
    from vectoradjust.tables import read_control, read_fiducials, read_measurements

    project_path = alg.parameterAsFile(parameters, PROJECT, context) if _is_set(
        parameters, PROJECT) else ""
    meas_given = _is_set(parameters, MEASUREMENTS)
    ctrl_given = _is_set(parameters, CONTROL)
    if project_path:
        raw = dict(_read_toml(project_path))
        base_dir = Path(project_path).parent.resolve()
        where = str(project_path)
    else:
        raw = {}
        base_dir = Path.cwd()
        where = "the algorithm parameters"

    # parameters override the project file
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

    if "camera" not in raw:
        raise ProjectError(f"{where}: no camera is given",
                           "Give a project file with [camera] or the focal length parameter")
    if not raw.get("images"):
        raise ProjectError(f"{where}: no images are given",
                           "Give a project file with [[images]] or fill in the Images table "
                           "(id, XL, YL, ZL, omega, phi, kappa)")
    if "measurements" not in raw:
        raise ProjectError(f"{where}: no image measurements are given",
                           "Choose the image measurements (CSV file or table) or give a "
                           "project file with [measurements] path")
    spec = parse_project(raw, base_dir=base_dir, path=project_path or None)
    crs = qgis_io.ground_crs(spec.crs, f"{where}: crs")

    unit = spec.measurements.get("unit", "mm")
    if meas_given:
        src = alg.parameterAsSource(parameters, MEASUREMENTS, context)
        raw_meas = qgis_io.read_measurements_source(
            parameters.get(MEASUREMENTS), src, spec.measurements.get("sigma"),
            f"measurements table {src.sourceName()!r}", unit=unit)
    else:
        raw_meas = read_measurements(spec.measurements["path"], spec.measurements.get("sigma"),
                                     unit=unit)
    if ctrl_given:
        src = alg.parameterAsSource(parameters, CONTROL, context)
        control = qgis_io.read_control_source(parameters.get(CONTROL), src, crs, context,
                                              f"control table {src.sourceName()!r}")
    elif spec.control is not None:
        control = read_control(spec.control["path"])
    else:
        control = ControlPoints(np.zeros(0, str), np.zeros((0, 3)), np.zeros((0, 3)),
                                np.zeros(0, str), source=f"{where} [control]")
    # image coordinate refinement (DESIGN 5), exactly as vectoradjust.io.load_project_data
    fid_path = spec.measurements.get("fiducials")
    fiducials = read_fiducials(fid_path, unit) if fid_path else None
    interior = refine_measurements(
        raw_meas, spec.images, spec.camera, spec.corrections, unit=unit, fiducials=fiducials,
        control=control, map_projection=True)  # the ground CRS is projected (checked)
    camera = Camera(spec.camera.focal_length, interior.principal_point,
                    calibration=spec.camera.calibration)
    return ProjectInputs(spec=spec, crs=crs, camera=camera, measurements=interior.measurements,
                         control=control, source=where, interior=interior.report,
                         vectors=list(spec.vectors))


def matching_vector_spec(inputs, layer):
    """The project's ``[[vectors]]`` entry whose path is ``layer``'s file, or None."""
    path = qgis_io.layer_path(layer)
    if not path or inputs is None:
        return None
    real = os.path.realpath(path)
    for v in inputs.vectors:
        if v.path and os.path.realpath(v.path) == real:
            return v
    return None


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
