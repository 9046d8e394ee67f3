"""The shared Processing parameters: their names, help texts and definitions.

:func:`add_project_parameters` (project file, measurements, control, camera, images,
ground CRS, adjustment settings) and :func:`add_road_parameters` (the road layer, its id
field, DEM, sigmas, name, identification error and offset), with the help texts
:data:`PROJECT_HELP` and :data:`ROAD_HELP`.
"""


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
)

__all__ = [
    "PROJECT",
    "MEASUREMENTS",
    "MEASUREMENT_SIGMA",
    "CONTROL",
    "FOCAL_LENGTH",
    "PP_X",
    "PP_Y",
    "IMAGES",
    "GROUND_CRS",
    "REWEIGHT",
    "ALPHA",
    "MAX_ITERATIONS",
    "IMAGE_HEADERS",
    "REWEIGHT_OPTIONS",
    "PROJECT_HELP",
    "add_project_parameters",
    "ROAD_HELP",
    "INPUT",
    "ID_FIELD",
    "NAME",
    "DEM",
    "SIGMA_XY",
    "SIGMA_Z",
    "IDENT_XY",
    "IDENT_Z",
    "OFFSET",
    "OFFSET_CHOICES",
    "add_road_parameters",
]


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


INPUT = "INPUT"
ID_FIELD = "ID_FIELD"
NAME = "NAME"
DEM = "DEM"
SIGMA_XY = "SIGMA_XY"
SIGMA_Z = "SIGMA_Z"
IDENT_XY = "IDENTIFICATION_SIGMA_XY"
IDENT_Z = "IDENTIFICATION_SIGMA_Z"
OFFSET = "OFFSET"


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
