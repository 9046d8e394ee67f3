"""Accuracy control: the QA verdict of an adjustment against production tolerances."""

import time
from types import SimpleNamespace

import numpy as np
from qgis.core import (
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputBoolean,
    QgsProcessingOutputString,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QVariant

from .. import qgis_io, results
from ..styles import style_output
from . import inputs
from .base import VectorAdjustAlgorithm

HELP = """
<p>Runs the adjustment and judges every stage against the tolerances that follow from the
product specification (as <code>vectoradjust qa</code>): the interior orientation (fiducial
residuals), the relative orientation of every stereo pair (vertical parallax left after the
adjustment), the triplets (discrepancies between adjacent models), the tie-point zones of
every overlap (3 rows x 2 columns, at least 3 points per zone, 2 a warning) and of every
triple overlap, the ties between adjacent strips (points and vertical parallax; n/a with one
strip), the free model (image measurements alone before control: sigma0 and image residual
RMS; blocks of up to 200 images), and the control and check
points of the block (mean error, a single point against twice the tolerance). The verdict is
PASS when no evaluated stage failed; the non-conformities name the points to re-measure.</p>
<h3>Needs</h3>
<ul>
<li><b>Project file</b> (and/or the parameters below, as for <i>Adjust road vectors</i>).</li>
<li><b>Road line layer</b> (optional): adjust that database (as <i>Adjust road vectors</i>);
empty: every <code>[[vectors]]</code> entry of the project is adjusted together (as
<code>vectoradjust qa PROJECT</code>).</li>
<li><b>Product specification</b>: the product (topographic map, orthophoto or orthomosaic),
its scale denominator (e.g. 2000), the contour interval (m, topographic map), the terrain
(flat, hilly, mountainous; orthomosaic) and the pixel size (mm; default the project's
<code>[qa] pixel_size</code> or the camera's). A parameter that is set overrides the
project's <code>[qa]</code> table; without either the algorithm stops and says so.</li>
</ul>
{project_help}
{road_help}
<h3>Writes</h3>
<ul>
<li><b>QA table</b>: one row per stage (id empty: the stage statistic, its tolerance,
passed) and one row per point of the stage (id, value, point tolerance, passed); fields
stage, id, value, tolerance, passed, status (pass, fail, n/a), statistic, unit.</li>
<li><b>QA report (JSON)</b> (optional): the <code>qa.json</code> of the command line
(verdict, non-conformities, points to re-measure, tolerances, stereo pairs, triplets,
tie-point zones, triplet zones, strips, inter-strip ties, free model, control points,
stages, notes).</li>
<li><b>Control and check points</b> with the <code>QA</code> field (pass / fail; empty for
points not used).</li>
<li><b>PASSED</b> (boolean) and <b>VERDICT</b> (pass or fail).</li>
</ul>
<p>The same numbers as <code>vectoradjust qa PROJECT --product ... --scale ...</code>.</p>
"""

PRODUCT_OPTIONS = ["topographic map", "orthophoto", "orthomosaic"]
TERRAIN_OPTIONS = ["flat", "hilly", "mountainous"]
PAIR_OPTIONS = ["consecutive", "all"]
POINT_RULE_OPTIONS = ["limit", "mean"]

QA_COLUMNS = ["stage", "id", "value", "tolerance", "passed", "status", "statistic", "unit"]


def qa_table_fields():
    """Fields of the QA table."""
    fields = QgsFields()
    for name in QA_COLUMNS:
        if name in ("value", "tolerance"):
            fields.append(QgsField(name, QVariant.Double, "double"))
        elif name == "passed":
            fields.append(QgsField(name, QVariant.Bool))
        else:
            fields.append(QgsField(name, QVariant.String))
    return fields


def qa_table_rows(doc):
    """Rows of the QA table from ``qa.json`` content: each stage, then its points."""
    rows = []
    for s in doc["stages"]:
        rows.append([s["name"], None, s["measured"], s["tolerance"], s["passed"], s["status"],
                     s["statistic"], s["unit"]])
        for p in s["points"]:
            passed = p["passed"]
            status = "n/a" if passed is None else ("pass" if passed else "fail")
            rows.append([s["name"], str(p["id"]), p["value"], p["tolerance"], passed, status,
                         "point", s["unit"]])
    return rows


class AccuracyControl(VectorAdjustAlgorithm):
    NAME = "accuracycontrol"
    DISPLAY = "Accuracy control"
    SHORT = "QA verdict of the adjustment against the tolerances of a map or orthophoto product."
    HELP = HELP.replace("{project_help}", inputs.PROJECT_HELP).replace("{road_help}",
                                                                       inputs.ROAD_HELP)

    PRODUCT = "PRODUCT"
    SCALE = "SCALE"
    CONTOUR_INTERVAL = "CONTOUR_INTERVAL"
    TERRAIN = "TERRAIN"
    PIXEL_SIZE = "PIXEL_SIZE"
    PAIRS = "PAIRS"
    POINT_RULE = "POINT_RULE"
    OUTPUT = "OUTPUT"
    QA_JSON = "QA_JSON"
    CONTROL_POINTS = "CONTROL_POINTS"
    CLI_FLAGS = {"--product": PRODUCT, "--scale": SCALE, "--contour-interval": CONTOUR_INTERVAL,
                 "--terrain": TERRAIN, "--pixel-size": PIXEL_SIZE}

    def initAlgorithm(self, config=None):
        advanced = QgsProcessingParameterDefinition.FlagAdvanced
        inputs.add_road_parameters(self, optional=True)
        self.addParameter(QgsProcessingParameterEnum(
            self.PRODUCT, "Product (default: [qa] product of the project)", PRODUCT_OPTIONS,
            optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.SCALE, "Scale denominator of the product, e.g. 2000 (default: [qa])",
            QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.CONTOUR_INTERVAL, "Contour interval [m] (topographic map; default: [qa])",
            QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
        self.addParameter(QgsProcessingParameterEnum(
            self.TERRAIN, "Terrain (orthomosaic; default: [qa] terrain, else flat)",
            TERRAIN_OPTIONS, optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.PIXEL_SIZE, "Pixel size [mm] (default: [qa] pixel_size or the camera's)",
            QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
        p = QgsProcessingParameterEnum(self.PAIRS, "Stereo pairs", PAIR_OPTIONS,
                                       defaultValue=0)
        p.setFlags(p.flags() | advanced)
        self.addParameter(p)
        p = QgsProcessingParameterEnum(
            self.POINT_RULE, "Control/check point rule (limit: fail over twice the tolerance; "
            "mean: over the tolerance)", POINT_RULE_OPTIONS, defaultValue=0)
        p.setFlags(p.flags() | advanced)
        self.addParameter(p)
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "QA table", QgsProcessing.TypeVector))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.QA_JSON, "QA report (JSON, qa.json)", "JSON files (*.json)", optional=True,
            createByDefault=False))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.CONTROL_POINTS, "Control and check points (with QA)",
            QgsProcessing.TypeVectorPoint, optional=True, createByDefault=True))
        self.addOutput(QgsProcessingOutputBoolean("PASSED", "Accuracy control passed"))
        self.addOutput(QgsProcessingOutputString("VERDICT", "Verdict (pass or fail)"))

    def _spec(self, parameters, context, qa_table, source):
        """The product specification: [qa] of the project overridden by the parameters."""
        from vectoradjust.errors import ProjectError
        from vectoradjust.qa.verdict import spec_from_table

        def number(name):
            return inputs._number(self, parameters, name, context)

        product = (PRODUCT_OPTIONS[self.parameterAsEnum(parameters, self.PRODUCT, context)]
                   if inputs._is_set(parameters, self.PRODUCT) else None)
        terrain = (TERRAIN_OPTIONS[self.parameterAsEnum(parameters, self.TERRAIN, context)]
                   if inputs._is_set(parameters, self.TERRAIN) else None)
        scale = number(self.SCALE)
        if scale is not None and not scale > 0:
            raise ProjectError(f"The scale denominator {scale:g} is not a scale",
                               "Give the scale denominator of the product, e.g. 2000 for "
                               "1:2000")
        pixel = number(self.PIXEL_SIZE)
        if pixel is not None and not pixel > 0:
            raise ProjectError(f"The pixel size {pixel:g} mm is not a pixel size",
                               "Give the pixel size in millimetres, e.g. 0.012")
        spec = spec_from_table(qa_table, product=product, scale=scale,
                               contour_interval=number(self.CONTOUR_INTERVAL), terrain=terrain,
                               source=source)
        return spec, pixel

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.qa.text import format_report
        from vectoradjust.qa.verdict import accuracy_control, strips_from_project

        t0 = time.perf_counter()
        # the specification is checked before the (possibly long) adjustment, as the
        # command line does
        if inputs._is_set(parameters, inputs.PROJECT):
            path = self.parameterAsFile(parameters, inputs.PROJECT, context)
            self._spec(parameters, context, inputs._read_toml(path).get("qa"), path)
        else:
            self._spec(parameters, context, None, "the algorithm parameters")
        adj = inputs.run_adjustment(self, parameters, context, feedback, road_optional=True,
                                    start=10.0, span=70.0)
        spec, pixel = self._spec(parameters, context, adj.prj.spec.raw.get("qa"),
                                 adj.prj.source)
        run = adj.run
        feedback.setProgressText("accuracy control")
        report = accuracy_control(
            run, spec, pixel_size=pixel,
            pairs=PAIR_OPTIONS[self.parameterAsEnum(parameters, self.PAIRS, context)],
            point_rule=POINT_RULE_OPTIONS[self.parameterAsEnum(parameters, self.POINT_RULE,
                                                               context)],
            strips=strips_from_project(adj.prj.spec.raw))
        doc = report.as_dict()
        feedback.setProgress(85)
        outputs = self._write(parameters, context, feedback, run, report, doc, adj.prj)
        for line in format_report(doc).splitlines():
            feedback.pushInfo(line)
        outputs["PASSED"] = bool(doc["passed"])
        outputs["VERDICT"] = doc["verdict"]
        feedback.setProgress(100)
        feedback.pushInfo(f"done in {time.perf_counter() - t0:.1f} s")
        return outputs

    def _write(self, parameters, context, feedback, run, report, doc, prj):
        outputs = {}
        fields = qa_table_fields()
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.NoGeometry, prj.crs)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        results.add_all(sink, [qgis_io.new_feature(fields, r) for r in qa_table_rows(doc)])
        outputs[self.OUTPUT] = dest
        path = self.parameterAsFileOutput(parameters, self.QA_JSON, context)
        if path:
            extra = {"project": prj.source}
            results.write_json(path, {**doc, **extra})
            outputs[self.QA_JSON] = path
        # the QA field as the report judged the points (the specification given here)
        cp = dict(run.control_points)
        qa = np.full(len(cp["point_id"]), "", dtype=object)
        if report.control is not None and len(report.control_rows):
            qa[report.control_rows] = np.where(report.control.passed, "pass", "fail")
        cp["QA"] = qa
        view = SimpleNamespace(control_points=cp)
        cfields = results.control_fields(view)
        sink, dest = self.parameterAsSink(parameters, self.CONTROL_POINTS, context, cfields,
                                          QgsWkbTypes.PointZ, prj.crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is not None:
            results.add_all(sink, results.control_point_features(view, cfields), feedback)
            style_output(context, dest, "control_points")
            outputs[self.CONTROL_POINTS] = dest
        return outputs
