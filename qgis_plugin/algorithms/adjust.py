"""Adjust road vectors: the photogrammetric adjustment of one road database."""

import os
import time

from qgis.core import (
    QgsFeatureSink,
    QgsProcessing,
    QgsProcessingOutputBoolean,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from .. import results
from ..styles import style_output
from . import inputs
from .base import VectorAdjustAlgorithm, cancel_callback, check_cancelled, progress_callback
from .buffer_test import project_truth_buffer, project_truth_lines

HELP = """
<p>Adjusts a road line layer (OSM, TIGER, TNM, any centrelines) with a photogrammetric
bundle adjustment: the vertices of the roads (<i>shape points</i>) measured on a stereo pair
or block of aerial images are adjusted together with the images' exterior orientation, tied to
surveyed control points. The result tells, for every measured vertex, how far the database is
from where the road really is (the residual), the adjusted position, and how sure that is
(CE90/LE90 from the a-posteriori covariance).</p>
<h3>Needs</h3>
<ul>
<li><b>Road line layer</b> (projected or any CRS; transformed to the ground CRS) and its
<b>id field</b> (unique feature ids; empty = the 0-based feature index). Shape point ids are
<code>&lt;feature id&gt;_&lt;vertex index&gt;</code>, the vertex index 0-based along the feature and
continuing across parts (the ids <i>Extract shape points</i> writes).</li>
<li><b>DEM</b> (optional): heights of the shape points by bilinear interpolation; without it
the layer's Z values are used.</li>
<li><b>Prior sigma</b> of the shape points (m, horizontal and vertical; default 10 m).</li>
<li>Camera, images, measurements and control: see below.</li>
</ul>
{project_help}
{road_help}<h3>Writes</h3>
<ul>
<li><b>Adjusted shape points</b> (Point Z at the adjusted position): point_id, feature_id,
database X, Y, Z, residuals Vx, Vy, Vz (adjusted - database), AdjX, AdjY, AdjZ, SigmaX/Y/Z,
CE90, LE90, NImages, Adjusted (1 = measured on the images) and Source: <i>measured</i>,
or for the other vertices <i>interpolated</i> / <i>extrapolated</i> (corrected by the
conflation: the database's offset plus the displacement field predicted from the measured
vertices, with its CE90/LE90; the project's <code>[conflation]</code> table) or
<i>unchanged</i> (too few measured points, or conflation disabled: <b>Correct every
vertex (conflation)</b> unchecked replaces the project's <code>[conflation] enabled</code>).
The log says how many vertices were measured, interpolated, extrapolated and unchanged.</li>
<li><b>Adjusted road features</b>: every input feature with all its attributes and the adjusted
(conflated) geometry, plus NPts, NAdj, RMSE_X/Y/Z, RMSE (horizontal), Length with its standard
deviation LengthSD (from the joint covariance of the vertices) and LengthSDnc (covariances
between vertices ignored; LengthSDOf says whether they cover all vertices or the measured
ones only, the conflated ones counting as fixed), first/last point, Images, ImgDate.</li>
<li><b>Control and check points</b>: surveyed and adjusted (check points: intersected from the
adjusted images, not used in the adjustment) coordinates, residuals, CE90, LE90, and QA
(pass/fail against the product tolerances) when the project has a <code>[qa]</code>
table.</li>
<li><b>Residual vectors</b>: a line from each measured vertex's database position to its
adjusted position (the map view of a quiver plot; <i>Residual vector scale</i> exaggerates
them).</li>
<li>Numbers: sigma0^2 (variance factor), whether the chi-square test passed, RMSE of the
residuals (horizontal) and of the check points; optionally the whole summary as JSON (the
<code>summary.json</code> of the command line, with reliability and accuracy statements; with
a project <code>[truth]</code> table of true centrelines also the share of the road lines
within 1 m and 2 m of them before and after the adjustment).</li>
<li><b>Report (HTML)</b> (optional): the <code>report.html</code> of the command line, one
self-contained file with tables and figures (needs matplotlib in QGIS's Python).</li>
</ul>
<p>The same numbers as <code>vectoradjust adjust PROJECT --vectors NAME</code>.</p>
""".replace("{project_help}", inputs.PROJECT_HELP).replace("{road_help}", inputs.ROAD_HELP)


class AdjustRoadVectors(VectorAdjustAlgorithm):
    NAME = "adjustroadvectors"
    DISPLAY = "Adjust road vectors"
    SHORT = "Bundle adjustment of a road line layer: residuals, adjusted positions, CE90/LE90."
    HELP = HELP

    INPUT = "INPUT"
    ID_FIELD = "ID_FIELD"
    NAME_PARAM = "NAME"
    DEM = "DEM"
    SIGMA_XY = "SIGMA_XY"
    SIGMA_Z = "SIGMA_Z"
    RESIDUAL_SCALE = "RESIDUAL_SCALE"
    CONFLATION = "CONFLATION"
    DATUM = "DATUM"
    #: the DATUM choices and the project's [adjustment] datum each stands for
    DATUM_OPTIONS = (("as the project says (control points, camera priors, control "
                      "databases; checked before the solve)", None),
                     ("free network (no priors: relative precision only)", "free"))
    SHAPE_POINTS = "SHAPE_POINTS"
    FEATURES = "FEATURES"
    CONTROL_POINTS = "CONTROL_POINTS"
    RESIDUALS = "RESIDUALS"
    SUMMARY = "SUMMARY"
    REPORT = "REPORT"

    def initAlgorithm(self, config=None):
        inputs.add_road_parameters(self)
        inputs.add_project_parameters(self)
        p = QgsProcessingParameterNumber(self.RESIDUAL_SCALE, "Residual vector scale",
                                         QgsProcessingParameterNumber.Double, defaultValue=1.0,
                                         minValue=0.0)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        self.addParameter(QgsProcessingParameterBoolean(
            self.CONFLATION, "Correct every vertex (conflation)", defaultValue=True))
        p = QgsProcessingParameterEnum(self.DATUM, "Datum", [o for o, _ in self.DATUM_OPTIONS],
                                       defaultValue=0)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        # optional sinks, created by default in the dialog: qgis_process and models write
        # only those that are given
        for key, label, kind in (
                (self.SHAPE_POINTS, "Adjusted shape points", QgsProcessing.TypeVectorPoint),
                (self.FEATURES, "Adjusted road features", QgsProcessing.TypeVectorLine),
                (self.CONTROL_POINTS, "Control and check points",
                 QgsProcessing.TypeVectorPoint),
                (self.RESIDUALS, "Residual vectors", QgsProcessing.TypeVectorLine)):
            self.addParameter(QgsProcessingParameterFeatureSink(
                key, label, kind, optional=True, createByDefault=True))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.SUMMARY, "Summary (JSON)", "JSON files (*.json)", optional=True,
            createByDefault=False))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.REPORT, "Report (HTML)", "HTML files (*.html *.htm)", optional=True,
            createByDefault=False))
        for name, label in (("SIGMA0_SQUARED", "Variance factor sigma0^2"),
                            ("DEGREES_OF_FREEDOM", "Degrees of freedom"),
                            ("RMSE", "RMSE of the shape point residuals, horizontal [m]"),
                            ("RMSE_CHECK", "RMSE of the check points, horizontal [m]"),
                            ("MEAN_CE90", "Mean CE90 of the adjusted shape points [m]"),
                            ("ITERATIONS", "Iterations")):
            self.addOutput(QgsProcessingOutputNumber(name, label))
        self.addOutput(QgsProcessingOutputBoolean("CHI_SQUARE_PASSED", "Chi-square test passed"))

    # ------------------------------------------------------------------ run
    #: the outputs written to files or layers: a run needs at least one of them
    WRITTEN = ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS", "SUMMARY", "REPORT")

    def check_outputs(self, parameters):
        """Stop at once (before anything is read) when no output is requested, e.g.
        ``qgis_process run vectoradjust:adjustroadvectors -- INPUT=... PROJECT=...``: the
        sinks are created by default only in the dialog, so nothing would be written."""
        if any(parameters.get(k) not in (None, "") for k in self.WRITTEN):
            return
        from vectoradjust.errors import VectorAdjustError

        names = ", ".join(f"{k} ({self.parameterDefinition(k).description()})"
                          for k in self.WRITTEN)
        raise VectorAdjustError(
            f"No output is requested, so the adjustment would write nothing. The outputs "
            f"are the parameters {names}",
            "Give at least one, e.g. qgis_process run vectoradjust:adjustroadvectors -- "
            "INPUT=roads.shp PROJECT=project.toml SHAPE_POINTS=shape_points.gpkg "
            "SUMMARY=summary.json (TEMPORARY_OUTPUT for a temporary layer); in the dialog, "
            "keep at least one output (not all set to Skip output)")

    def run_algorithm(self, parameters, context, feedback):
        t0 = time.perf_counter()
        self.check_outputs(parameters)
        adj = inputs.run_adjustment(
            self, parameters, context, feedback, span=70.0,
            conflation=self.parameterAsBoolean(parameters, self.CONFLATION, context),
            datum=self.DATUM_OPTIONS[self.parameterAsEnum(parameters, self.DATUM, context)][1])
        out = adj.run
        # true centrelines ([truth]): buffer shares before/after, into the summary
        truth = project_truth_buffer(adj.prj, [out], context, feedback)  # read once
        project_truth_lines(adj.prj, [out], context, feedback, truth)  # as vectoradjust adjust
        rpc_files = self._corrected_rpcs(parameters, context, feedback, out)
        outputs = self._write(parameters, context, feedback, out, adj.road.fields,
                              adj.road.wkb, adj.prj.crs)
        report = write_html_report(self, parameters, context, feedback, self.REPORT, out)
        if report:
            outputs[self.REPORT] = report
        s = out.summary
        outputs.update({
            "SIGMA0_SQUARED": s["sigma0_squared"],
            "DEGREES_OF_FREEDOM": s["degrees_of_freedom"],
            "ITERATIONS": s["iterations"],
            "CHI_SQUARE_PASSED": s["chi_square"].get("passed"),
            "RMSE": s["shape_points"].get("rmse_horizontal"),
            "RMSE_CHECK": s["check_points"].get("rmse_horizontal"),
            "MEAN_CE90": s.get("mean_ce90"),
        })
        report_summary(feedback, s)
        for path in rpc_files:
            feedback.pushInfo(f"wrote the corrected RPCs {path}")
        feedback.setProgress(100)
        feedback.pushInfo(f"done in {time.perf_counter() - t0:.1f} s")
        return outputs

    def _corrected_rpcs(self, parameters, context, feedback, out):
        """RPC images: their RPCs with the bias folded in, ``<name>_rpc.txt`` beside the
        summary (else the report), as ``vectoradjust adjust`` writes them into its folder.
        Without either, none is written and the summary names none."""
        if not any(im.model == "rpc" for im in out.data.images):
            return []
        from ..rpc_io import write_corrected_rpcs

        paths = [self.parameterAsFileOutput(parameters, key, context)
                 for key in (self.SUMMARY, self.REPORT)]
        folder = next((os.path.dirname(os.path.abspath(p)) for p in paths if p), None)
        if folder is None:
            for entry in out.summary.get("images", []):
                entry.pop("corrected_rpc", None)
            feedback.pushInfo("the corrected RPCs (bias folded in) are written beside the "
                              "summary or the report: give one of them to have them")
            return []
        return write_corrected_rpcs(out, folder, feedback.pushWarning)

    def _write(self, parameters, context, feedback, out, in_fields, source_wkb, crs):
        feedback.setProgressText("writing the outputs")
        outputs = {}
        scale = self.parameterAsDouble(parameters, self.RESIDUAL_SCALE, context)
        specs = [
            (self.SHAPE_POINTS, results.shape_fields(), QgsWkbTypes.PointZ,
             results.shape_point_features, "shape_points"),
            (self.FEATURES, results.feature_fields(in_fields),
             results.feature_wkb_type(source_wkb), None, "features"),
            (self.CONTROL_POINTS, results.control_fields(out), QgsWkbTypes.PointZ,
             results.control_point_features, "control_points"),
            (self.RESIDUALS, results.residual_fields(), QgsWkbTypes.LineStringZ, None,
             "residuals"),
        ]
        for k, (key, fields, wkb, make, kind) in enumerate(specs):
            check_cancelled(feedback)
            if key == self.FEATURES:  # what the destination's format cannot hold: warned
                fields = self._feature_fields(parameters, context, feedback, out, in_fields)
            sink, dest = self.parameterAsSink(parameters, key, context, fields, wkb, crs,
                                              QgsFeatureSink.RegeneratePrimaryKey)
            if sink is None:
                continue
            if key == self.FEATURES:
                feats = results.feature_features(out, fields,
                                                 QgsWkbTypes.isMultiType(wkb))
            elif key == self.RESIDUALS:
                feats = results.residual_features(out, fields, scale)
            else:
                feats = make(out, fields)
            results.add_all(sink, feats, feedback, 85 + 3.5 * k, 3.5)
            style_output(context, dest, kind)
            outputs[key] = dest
        summary_path = self.parameterAsFileOutput(parameters, self.SUMMARY, context)
        if summary_path:  # per-feature statements beside it, as the command line does
            from vectoradjust.files.jsonfile import move_feature_statements

            summary, _ = move_feature_statements(out.summary, os.path.dirname(summary_path)
                                                 or ".")
            results.write_json(summary_path, summary)
            outputs[self.SUMMARY] = summary_path
        return outputs


    def _feature_fields(self, parameters, context, feedback, out, in_fields):
        """The features sink's fields for its destination's format; each field the format
        cannot hold as it is is a warning (in the log and the summary's warnings)."""
        dest = self.parameterAsOutputLayer(parameters, self.FEATURES, context)
        fields, notes = results.feature_fields_for(
            in_fields, out, results.sink_format(dest),
            f"features ({os.path.basename(str(dest).split('|')[0])})")
        for note in notes:
            feedback.pushWarning(note)
            out.summary["warnings"] = list(out.summary.get("warnings") or []) + [note]
        return fields


def write_html_report(alg, parameters, context, feedback, key, run=None, runs=None,
                      rows=None):
    """Write the HTML report (``report.html`` of the command line) when ``key`` is given.

    One run: :func:`vectoradjust.files.report.write_report`; a comparison (``runs`` and
    ``rows``): :func:`vectoradjust.files.report.write_compare_report`. Figures are drawn with
    matplotlib's Agg canvas (no pyplot). Returns the path or None.
    """
    path = alg.parameterAsFileOutput(parameters, key, context)
    if not path:
        return None
    feedback.setProgressText("writing the report")
    check_cancelled(feedback)
    try:
        from vectoradjust.files import report
    except ImportError as exc:  # pragma: no cover - depends on the machine
        from qgis.core import QgsProcessingException

        raise QgsProcessingException(
            f"The HTML report needs matplotlib in QGIS's Python ({exc}); install it "
            "(Debian/Ubuntu: apt install python3-matplotlib; OSGeo4W: python3-matplotlib) or "
            "leave the report output empty") from exc
    try:
        hooks = {"progress": progress_callback(feedback, 95.0, 5.0),
                 "is_cancelled": cancel_callback(feedback)}
        if runs is not None:
            written = report.write_compare_report(runs, rows, path, **hooks)
        else:
            written = report.write_report(run, path, reliability=run.reliability, **hooks)
    except ImportError as exc:  # matplotlib is imported when the figures are drawn
        from qgis.core import QgsProcessingException

        raise QgsProcessingException(
            f"The HTML report needs matplotlib in QGIS's Python ({exc}); install it "
            "(Debian/Ubuntu: apt install python3-matplotlib; OSGeo4W: python3-matplotlib) or "
            "leave the report output empty") from exc
    feedback.pushInfo(f"wrote the report {written}")
    return str(written)


def report_summary(feedback, s):
    """The run summary in the log, like the command line prints it."""
    chi = s["chi_square"]
    feedback.pushInfo(f"sigma0^2 = {_f(s['sigma0_squared'], 4)} with {s['degrees_of_freedom']} "
                      f"degrees of freedom, {s['iterations']} iterations")
    if chi.get("lower") is not None:
        feedback.pushInfo(f"chi-square test (alpha = {chi['alpha']}): v'Pv = "
                          f"{_f(chi['statistic'], 2)} in [{_f(chi['lower'], 2)}, "
                          f"{_f(chi['upper'], 2)}]: {'passed' if chi['passed'] else 'FAILED'}")
    for key, label in (("shape_points", "shape point residuals"),
                       ("control_points", "control points"), ("check_points", "check points")):
        r = s.get(key) or {}
        if r.get("count"):
            feedback.pushInfo(f"{label}: n = {r['count']}, RMSE x {_f(r['rmse_x'])}, y "
                              f"{_f(r['rmse_y'])}, z {_f(r['rmse_z'])}, horizontal "
                              f"{_f(r['rmse_horizontal'])} m")
    if s.get("mean_ce90") is not None:
        feedback.pushInfo(f"mean CE90 {_f(s['mean_ce90'])} m, mean LE90 {_f(s['mean_le90'])} m")
    for im in s.get("images", []):
        if im.get("model") == "rpc":
            feedback.pushInfo(rpc_bias_text(im))
    for e in (s.get("conflation") or {}).get("databases", []):
        n = e.get("vertices") or {}
        feedback.pushInfo(f"conflation of {e['name']} ({e['status']}): "
                          + ", ".join(f"{n.get(k, 0)} {k}" for k in
                                      ("measured", "interpolated", "extrapolated", "unchanged"))
                          + " vertices")


def rpc_bias_text(im):
    """One log line for an RPC image's estimated bias (the summary's ``images[]`` entry):
    ``S1: bias (shift) a0 = 3.389 +- 0.042 px, b0 = ... px; significant``."""
    sd = im.get("sigma_bias") or {}
    terms = ", ".join(f"{k} = {_f(v)} +- {_f(sd.get(k))}" for k, v in
                      (im.get("bias") or {}).items()) or "no free parameter"
    sig = (im.get("significance") or {}).get("significant")
    verdict = "" if sig is None else "; significant" if sig else "; not significant"
    return f"{im['id']}: bias ({im.get('bias_model')}) {terms} px{verdict}"


def _f(v, nd=3):
    return "-" if v is None else f"{float(v):.{nd}f}"
