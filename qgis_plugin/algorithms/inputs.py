"""Parameters and input assembly shared by "Adjust road vectors" and "Compare road databases".

The camera, images, measurements, control and settings come from a project file
(TOML, the contract of ``DESIGN.md`` section 9) and/or from parameters. A parameter
that is set wins over the project file; what neither gives is an error with the
core's message. The project file is validated by the core
(:func:`vectoradjust.files.project.parse_project`), and a parameter-only set-up is validated
the same way, so both routes give the same checks and the same numbers.

Every ``[[vectors]]`` entry of the project file is read through QGIS (as the command
line reads them all), so that measurements of the databases that are not adjusted are
recognised and left out rather than taken for tie points. A road layer that stands for an
entry (its file, its name or its ids: :mod:`.matching`) takes that entry's place, name, id
field, sigma, DEM and truth unless parameters say otherwise; a road layer that is not in
the project is one more database. The tables are assembled into the core's ProjectData by
:func:`vectoradjust.files.assemble.project_data`, the function the command line uses.
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
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterMatrix,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
    QgsRasterLayer,
    QgsVectorLayer,
)
from qgis.PyQt.QtCore import QVariant

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
REWEIGHT_OPTIONS = ["as in the project file (none if not given)", "none", "two-pass",
                    "variance component estimation (vce)"]
_REWEIGHT_VALUES = [None, "none", "two-pass", "vce"]

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
<li><b>Satellite images with RPCs</b> (<code>[[images]] model = "rpc"</code>, <code>rpc =
"image.tif"</code> or its <code>_rpc.txt</code> / <code>.RPB</code>; no [camera] needed):
the RPCs are read with QGIS's GDAL, the measurements are pixels (column, row), and the
project's <code>heights</code> says what the heights are: <code>"ellipsoidal"</code>, or
<code>"orthometric"</code> with <code>vertical_crs</code> (the geoid grid must be in QGIS's
PROJ). Each image's estimated bias (px) is in the log and the summary; the RPCs with the bias
folded in (<code>&lt;name&gt;_rpc.txt</code>) are written beside the summary or the
report.</li>
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
            from ..rpc_io import read_rpc_images

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
    from vectoradjust.files.tables import read_control, read_fiducials, read_measurements

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
    from .matching import matching_vector_spec as match

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


# --------------------------------------------------------------------------- road databases
ROAD_HELP = """
<p>When the project file lists <code>[[vectors]]</code>, every listed road database is read
(through QGIS) as the command line does, so that measurements of the other databases' shape
points are recognised and left out instead of being taken for tie points. A road layer that
stands for a <code>[[vectors]]</code> entry takes that entry's place (and its name, id field,
sigma, DEM and truth unless set here): the entry's file itself (also filtered, edited or only
its selected features), a layer named like the entry or its file, or a copy (memory,
reprojected, exported) whose ids are ids of the entry's file. When it holds only some of the
entry's roads (a selection), the measurements of the other roads are left out. A road layer
that is not in the project is one more database.</p>
"""


@dataclass
class RoadDatabase:
    """A road layer given as a parameter, read for the adjustment.

    ``spec`` and ``layer`` are the core's VectorSpec and LineLayer (vertices in the
    ground CRS, Z from the DEM or the geometry); ``fields`` and ``wkb`` describe the
    source for the features output; ``entry`` is the project's ``[[vectors]]`` entry
    for the layer's file (or None); ``truth`` the truth table, if any.
    """

    spec: object
    layer: object
    fields: object
    wkb: int
    entry: object = None
    truth: object = None
    where: str = ""
    renames: dict = field(default_factory=dict)


def shape_point_sigma(base, sigma_xy, sigma_z):
    """Prior sigma (x, y, z) of the shape points: parameters over ``base``; positive."""
    from vectoradjust.errors import ProjectError

    sigma = (sigma_xy if sigma_xy is not None else base[0],
             sigma_xy if sigma_xy is not None else base[1],
             sigma_z if sigma_z is not None else base[2])
    for s in sigma:
        if not s > 0:
            raise ProjectError(f"The prior sigma of the shape points must be positive, not {s}",
                               "Enter a sigma in metres (e.g. 10)")
    return tuple(float(s) for s in sigma)


def read_road_layer(prj, source, vlayer, context, feedback, *, name="", id_field="",
                    sigma_xy=None, sigma_z=None, dem=None, truth=None, error_model=None):
    """Read a road layer parameter (a feature source) for the adjustment.

    Parameters
    ----------
    prj : ProjectInputs
    source : QgsFeatureSource
        The layer's features (the selection when only selected features are used).
    vlayer : QgsVectorLayer or None
        The layer (matched to a ``[[vectors]]`` entry by :func:`matching_vector_spec`).
    name, id_field : str
        Database name and id field; empty = the entry's, else the layer name / the
        feature index.
    sigma_xy, sigma_z : float or None
        Prior sigma of the shape points (default the entry's, else 10 m).
    dem : QgsRasterLayer or None
        DEM for the heights (default the entry's DEM).
    truth : tuple or None
        Truth table (ids, xyz) (default the entry's).
    error_model : dict or None
        ``{"identification": (h, v) or None, "offset": str or None}`` from the dialog
        (None: the entry's identification_sigma and offset).

    Returns
    -------
    RoadDatabase
    """
    from vectoradjust.files.tables import read_truth_points
    from vectoradjust.model import VectorSpec

    from .matching import holds_whole_entry, vertex_renames

    entry = matching_vector_spec(prj, vlayer, source, (id_field or "").strip())
    if entry is not None:
        feedback.pushInfo(entry_settings_text(source.sourceName(), entry, name=name,
                                              id_field=id_field, sigma=(sigma_xy, sigma_z),
                                              dem=dem, truth=truth, error_model=error_model))
    name = (name or "").strip() or (entry.name if entry else source.sourceName())
    id_field = (id_field or "").strip() or (entry.id_field if entry else None)
    sigma = shape_point_sigma(entry.sigma if entry else (10.0, 10.0, 10.0), sigma_xy, sigma_z)
    where = f"road layer {source.sourceName()!r}"
    line_layer, fields = qgis_io.read_line_source(source, name, id_field, prj.crs, context,
                                                  where, feedback)
    if dem is None and entry is not None and entry.dem:
        dem = raster_from_path(entry.dem, prj.source)
    if dem is not None:
        feedback.setProgressText(f"{name}: sampling the DEM {dem.name()}")
        dem_report: dict = {}
        line_layer.coords[:, 2] = qgis_io.dem_heights(
            dem, line_layer.coords[:, :2], prj.crs, context, f"DEM {dem.name()!r}",
            report=dem_report)
        line_layer.dem = dem_report.get("grid")
    if truth is None and entry is not None and entry.truth:
        truth = read_truth_points(entry.truth)
    em = error_model or {}
    ident = em.get("identification") or (entry.identification_sigma if entry else None)
    offset = em.get("offset") or (entry.offset if entry else "shift")
    spec = VectorSpec(name=name, path=qgis_io.layer_path(vlayer) or where, id_field=id_field,
                      sigma=sigma, dem=dem.source() if dem is not None else None,
                      truth=entry.truth if entry else None, identification_sigma=ident,
                      offset=offset)
    # roads of the entry's file the layer does not hold (selection, filter, deletions)
    renames = (vertex_renames(prj, entry, id_field, line_layer, context)
               if entry is not None and id_field
               and not holds_whole_entry(entry, vlayer, len(line_layer.feature_ids)) else {})
    return RoadDatabase(spec, line_layer, fields, source.wkbType(), entry, truth, where,
                        renames)


def open_vector_entry(entry, where):
    """The QgsVectorLayer of a ``[[vectors]]`` entry's file (layer name as the headless
    reader picks it: ``layer``, or ``lines`` of an OSM PBF)."""
    from vectoradjust.errors import InputFileError, LayerError

    path = entry.path
    if not path or not os.path.exists(path):
        raise InputFileError(f"Road layer {path!r} does not exist ({where})",
                             "Check the path in the [[vectors]] entry", path=path)
    sub = entry.layer or ("lines" if str(path).lower().endswith(".pbf") else None)
    uri = qgis_io.shapefile_uri(path, sub)  # wide shapefile integers: exact, not reals
    layer = QgsVectorLayer(uri, entry.name, "ogr")
    if not layer.isValid():
        raise LayerError(f"{path}: cannot be read as a vector layer ({where})",
                         "Give a shapefile, GeoPackage, GeoJSON or OSM PBF with line features",
                         path=path)
    return layer


def filtered_entry_layer(layer, entry, where):
    """``layer`` with the entry's ``where`` attribute filter applied (a memory copy of the
    features it selects), or ``layer`` itself without a filter.

    Raises
    ------
    LayerError
        The filter is not a valid expression, names a field the layer does not have, or
        selects no feature.
    """
    from vectoradjust.errors import LayerError

    from .matching import entry_request

    text = getattr(entry, "where", None)
    if not text:
        return layer
    request = entry_request(entry, where)
    unknown = sorted(c for c in request.filterExpression().referencedColumns()
                     if layer.fields().lookupField(c) < 0)
    if unknown:
        raise LayerError(f"{where}: where = {text!r} names {', '.join(map(repr, unknown))}, not a "
                         f"field of {entry.path} (fields: {', '.join(layer.fields().names())})",
                         "Correct the field name in the where filter of the [[vectors]] entry",
                         path=entry.path)
    out = layer.materialize(request)
    if out.featureCount() == 0:
        raise LayerError(f"{where}: where = {text!r} selects no feature of {entry.path}",
                         "Correct the where filter of the [[vectors]] entry", path=entry.path)
    out.setName(layer.name())
    return out


def read_project_entry(prj, entry, context, feedback, dems=None):
    """A ``[[vectors]]`` entry read from its file through QGIS, as the command line reads it.

    Returns
    -------
    (VectorSpec, LineLayer, truth or None)
    """
    from vectoradjust.files.tables import read_truth_points

    where = f"[[vectors]] entry {entry.name!r} of {prj.source}"
    feedback.setProgressText(f"reading {entry.name} ({entry.path})")
    layer = filtered_entry_layer(open_vector_entry(entry, where), entry, where)
    line_layer, _ = qgis_io.read_line_source(layer, entry.name, entry.id_field, prj.crs,
                                             context, f"{where} ({entry.path})", feedback)
    if entry.dem:
        dems = {} if dems is None else dems
        if entry.dem not in dems:
            dems[entry.dem] = raster_from_path(entry.dem, where)
        dem = dems[entry.dem]
        dem_report: dict = {}
        line_layer.coords[:, 2] = qgis_io.dem_heights(
            dem, line_layer.coords[:, :2], prj.crs, context, f"DEM {dem.name()!r}",
            report=dem_report)
        line_layer.dem = dem_report.get("grid")
    truth = read_truth_points(entry.truth) if entry.truth else None
    return entry, line_layer, truth


def project_data_with(prj, given, context, feedback):
    """The core's ProjectData: the given road layers and every other ``[[vectors]]`` entry.

    A given layer that matches an entry takes its place (project order is kept); the
    other given layers follow. Like ``vectoradjust adjust --vectors NAME`` /
    ``compare``, every database of the project is read so that the measurements of
    databases that are not adjusted are recognised as theirs (and left out).

    Parameters
    ----------
    prj : ProjectInputs
    given : list of RoadDatabase

    Returns
    -------
    ProjectData
    """
    from vectoradjust.errors import ProjectError

    from .base import check_cancelled

    taken = {}
    extra = []
    for g in given:
        if g.entry is not None and id(g.entry) not in taken:
            taken[id(g.entry)] = g
        else:
            extra.append(g)
    items = []  # (spec, layer, truth, where)
    dems = {}
    for entry in prj.vectors:
        check_cancelled(feedback)
        g = taken.get(id(entry))
        if g is not None:
            items.append((g.spec, g.layer, g.truth, g.where))
        else:
            spec, layer, truth = read_project_entry(prj, entry, context, feedback, dems)
            items.append((spec, layer, truth, f"the project's [[vectors]] entry ({spec.path})"))
    items += [(g.spec, g.layer, g.truth, g.where) for g in extra]
    seen = {}
    for spec, _, _, where in items:
        if spec.name in seen:
            raise ProjectError(
                f"two road databases are both called {spec.name!r}: {seen[spec.name]} and "
                f"{where}",
                "Give the road layer another database name (parameter Database name / "
                "Names), or choose the file of the project's [[vectors]] entry")
        seen[spec.name] = where
    truth = {spec.name: t for spec, _, t, _ in items if t is not None}
    prj = _without_missing_roads(prj, given, feedback)
    return prj.project_data([(spec, layer) for spec, layer, _, _ in items], truth, context,
                            feedback)


def _without_missing_roads(prj, given, feedback):
    """``prj`` without the measurements of roads of a matched entry's file that its layer
    does not hold (they are not in the run: neither shape points nor tie points)."""
    import dataclasses

    from .matching import apply_renames

    meas = prj.measurements
    for g in given:
        if g.entry is None or not g.renames:
            continue
        meas, n = apply_renames(meas, g.spec.name, g.renames)
        if n:
            feedback.pushInfo(f"{g.spec.name}: {n} image measurements of roads of "
                              f"{g.entry.path} that {g.where} does not hold (not selected, "
                              "filtered or deleted) are left out")
    return prj if meas is prj.measurements else dataclasses.replace(prj, measurements=meas)


# --------------------------------------------------------------------------- one adjustment
INPUT = "INPUT"
ID_FIELD = "ID_FIELD"
NAME = "NAME"
DEM = "DEM"
SIGMA_XY = "SIGMA_XY"
SIGMA_Z = "SIGMA_Z"
IDENT_XY = "IDENTIFICATION_SIGMA_XY"
IDENT_Z = "IDENTIFICATION_SIGMA_Z"
OFFSET = "OFFSET"
def entry_settings_text(layer_name, entry, *, name="", id_field="", sigma=(None, None),
                        dem=None, truth=None, error_model=None):
    """The log line saying that the road layer ``layer_name`` stands for the project's
    ``[[vectors]]`` entry and which of its settings are taken from the entry (those not
    given as parameters)."""
    em = error_model or {}
    taken = []
    if not (name or "").strip():
        taken.append(f"name {entry.name!r}")
    if not (id_field or "").strip() and entry.id_field:
        taken.append(f"id field {entry.id_field!r}")
    if sigma[0] is None:
        taken.append(f"horizontal sigma {entry.sigma[0]:g} m")
    if sigma[1] is None:
        taken.append(f"vertical sigma {entry.sigma[2]:g} m")
    if dem is None and entry.dem:
        taken.append(f"DEM {entry.dem}")
    if truth is None and entry.truth:
        taken.append(f"truth {entry.truth}")
    if em.get("identification") is None and entry.identification_sigma is not None:
        taken.append("identification sigma "
                     f"{', '.join(f'{v:g}' for v in entry.identification_sigma)} m")
    if em.get("offset") is None and entry.offset:
        taken.append(f"offset {entry.offset!r}")
    return (f"road layer {layer_name!r} is the project's [[vectors]] entry {entry.name!r} "
            f"({entry.path}); from the entry: "
            + (", ".join(taken) if taken else "nothing (every setting given here)"))


#: the Database offset choices; the first takes the project's [[vectors]] entry
OFFSET_CHOICES = ["as in the project (default: shift)", "none", "shift", "shift3d"]


def add_road_parameters(alg, optional=False):
    """The road layer parameters of Adjust (INPUT, ID_FIELD, DEM, SIGMA_XY, SIGMA_Z, NAME).

    ``optional``: the road layer may be left empty (then the project's ``[[vectors]]``
    are adjusted together).
    """
    label = "Road line layer" + (" (optional: default every [[vectors]] entry of the "
                                 "project)" if optional else "")
    alg.addParameter(QgsProcessingParameterFeatureSource(
        INPUT, label, [QgsProcessing.TypeVectorLine], optional=optional))
    alg.addParameter(QgsProcessingParameterField(
        ID_FIELD, "Feature id field (empty: the project's [[vectors]] entry's id_field, else "
        "the feature index)", parentLayerParameterName=INPUT,
        optional=True))
    alg.addParameter(QgsProcessingParameterRasterLayer(
        DEM, "DEM for the shape point heights (default: the project's [[vectors]] entry's "
        "dem, else the layer's Z)", optional=True))
    alg.addParameter(QgsProcessingParameterNumber(
        SIGMA_XY, "Prior sigma of the shape points, horizontal [m] (default: the project's "
        "[[vectors]] entry's sigma, else 10)",
        QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
    alg.addParameter(QgsProcessingParameterNumber(
        SIGMA_Z, "Prior sigma of the shape points, vertical [m] (default: the project's "
        "[[vectors]] entry's sigma, else 10)",
        QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
    alg.addParameter(QgsProcessingParameterNumber(
        IDENT_XY, "Identification sigma, horizontal [m]: where the measured point is relative "
        "to the real road vertex (default: the project's identification_sigma, else none)",
        QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
    p = QgsProcessingParameterNumber(
        IDENT_Z, "Identification sigma, vertical [m] (default: the project's, else 0)",
        QgsProcessingParameterNumber.Double, optional=True, minValue=0.0)
    p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    alg.addParameter(p)
    alg.addParameter(QgsProcessingParameterEnum(
        OFFSET, "Database offset estimated with the adjustment (shift: a horizontal shift "
        "of the whole database)", options=OFFSET_CHOICES, defaultValue=0))
    p = QgsProcessingParameterString(NAME, "Database name (default: the project's [[vectors]] "
                                     "entry's name, else the layer name)",
                                     optional=True)
    p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    alg.addParameter(p)


def road_error_model(alg, parameters, context) -> dict:
    """Identification sigma and offset chosen in the dialog (None: the project's)."""
    h = _number(alg, parameters, IDENT_XY, context)
    v = _number(alg, parameters, IDENT_Z, context)
    choice = alg.parameterAsEnum(parameters, OFFSET, context) if OFFSET in parameters else 0
    return {"identification": None if h is None and v is None else (h or 0.0, v or 0.0),
            "offset": None if choice == 0 else OFFSET_CHOICES[choice]}


@dataclass
class Adjusted:
    """One adjustment run by :func:`run_adjustment`."""

    run: object  # vectoradjust.pipeline.AdjustmentRun
    prj: ProjectInputs
    road: Optional[RoadDatabase]


def run_adjustment(alg, parameters, context, feedback, *, road_optional=False, start=10.0,
                   span=75.0, conflation: Optional[bool] = None,
                   datum: Optional[str] = None):
    """Read the road layer (if any) and the project, and run the adjustment.

    With a road layer, that database is adjusted (``pipeline.run(data,
    vectors=[name])``) with every other ``[[vectors]]`` entry of the project read
    too; without one (``road_optional``), every ``[[vectors]]`` entry is adjusted
    together (as ``vectoradjust qa PROJECT`` / ``equal-error`` do). ``conflation``
    (not None) replaces the project's ``[conflation] enabled``, ``datum`` (not None)
    its ``[adjustment] datum`` (``"free"``: a free network).

    Returns
    -------
    Adjusted
    """
    from qgis.core import QgsProcessingException

    from vectoradjust.pipeline import run as run_pipeline

    from .base import cancel_callback, check_cancelled, progress_callback

    source = None
    if _is_set(parameters, INPUT) or not road_optional:
        source = alg.parameterAsSource(parameters, INPUT, context)
        if source is None:
            raise QgsProcessingException(alg.invalidSourceError(parameters, INPUT))
    feedback.setProgressText("reading the inputs")
    prj = project_inputs(alg, parameters, context, feedback,
                         source.sourceCrs() if source is not None else None)
    road = None
    given = []
    if source is not None:
        vlayer = alg.parameterAsVectorLayer(parameters, INPUT, context)
        road = read_road_layer(
            prj, source, vlayer, context, feedback,
            name=alg.parameterAsString(parameters, NAME, context),
            id_field=alg.parameterAsString(parameters, ID_FIELD, context),
            sigma_xy=_number(alg, parameters, SIGMA_XY, context),
            sigma_z=_number(alg, parameters, SIGMA_Z, context),
            dem=alg.parameterAsRasterLayer(parameters, DEM, context),
            error_model=road_error_model(alg, parameters, context))
        given.append(road)
    check_cancelled(feedback)
    data = project_data_with(prj, given, context, feedback)
    if conflation is not None:
        from dataclasses import replace

        data = replace(data, conflation={**(data.conflation or {}), "enabled": bool(conflation)})
    if datum is not None:
        from dataclasses import replace

        data = replace(data, settings=replace(data.settings, datum=datum))
        feedback.pushInfo(f"datum: {datum} (instead of the project's)")
    feedback.setProgress(start)
    out = run_pipeline(data, vectors=[road.spec.name] if road is not None else None,
                       progress=progress_callback(feedback, start, span),
                       is_cancelled=cancel_callback(feedback))
    check_cancelled(feedback)
    for w in out.warnings:
        feedback.pushWarning(w)
    return Adjusted(out, prj, road)
