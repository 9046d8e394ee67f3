"""Compare road databases: each adjusted alone against the same images and control."""

import csv
import json
import os
from types import SimpleNamespace

from qgis.core import (
    QgsFeatureSink,
    QgsProcessing,
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
    QgsVectorLayer,
    QgsWkbTypes,
)

from .. import qgis_io, results
from ..styles import style_output
from . import inputs
from .adjust import write_html_report
from .base import VectorAdjustAlgorithm, cancel_callback, check_cancelled, progress_callback
from .buffer_test import project_truth_buffer, project_truth_lines

HELP = """
<p>Adjusts several road databases (e.g. OSM, TNM and TIGER) of the same area <b>one at a
time</b> with the same images, measurements and control, and tabulates their positional
accuracy side by side: the RMSE of the residuals (how far each database is from where the
images put the roads), mean CE90/LE90, the variance factor and chi-square test, the check
point RMSE, and, when the truth is known, the true RMSE, the recovery rate and the
improvement. Measurements of the other databases' shape points are left out of each run.</p>
<h3>Needs</h3>
<ul>
<li><b>Road line layers</b>: the databases to compare.</li>
<li><b>Id fields</b>: one field name per layer, in the order of the layers, separated by
commas (one name for all layers, or empty: the feature index).</li>
<li><b>Names</b> (optional): database names in the same order (default: the project file's
[[vectors]] name for that file, else the layer name).</li>
<li><b>DEM</b> (optional, for all layers), prior sigma of the shape points.</li>
<li><b>Truth tables</b> (optional): <code>point_id, X, Y, Z</code> of the true shape point
positions (simulations): one per layer in the same order, or one for all.</li>
<li>Camera, images, measurements and control: see below.</li>
</ul>
{project_help}
{road_help}<h3>Writes</h3>
<ul>
<li><b>Comparison table</b>: one row per database (the columns of the command line's
<code>compare.csv</code>, with the buffer shares <code>in_1m_before</code>,
<code>in_1m_after</code> ... when the project has a <code>[truth]</code> table of true
centrelines).</li>
<li><b>Adjusted shape points</b> and <b>Residual vectors</b> of all databases (field
<code>Database</code>).</li>
<li><b>Output folder</b> (optional): per database <code>NAME/adjusted.gpkg</code> (layers
shape_points, features, control_points) and <code>NAME/summary.json</code>, and
<code>compare.csv</code> / <code>compare.json</code>, as <code>vectoradjust compare</code>
writes them.</li>
<li><b>Comparison report (HTML)</b> (optional): the comparison table, the RMSE chart and one
set of sections per database (the <code>report.html</code> of <code>vectoradjust
compare</code>; needs matplotlib in QGIS's Python).</li>
</ul>
""".replace("{project_help}", inputs.PROJECT_HELP).replace("{road_help}", inputs.ROAD_HELP)

_TABLE_TYPES = {"database": "s", "adjusted": "i", "points": "i", "chi_square_passed": "b",
                "vce": "s", "offset": "s"}


def _split(text):
    return [t.strip() for t in str(text or "").split(",")]


class CompareRoadDatabases(VectorAdjustAlgorithm):
    NAME = "compareroaddatabases"
    DISPLAY = "Compare road databases"
    SHORT = "Adjust several road layers alone with the same images and control; one table."
    HELP = HELP

    LAYERS = "LAYERS"
    ID_FIELDS = "ID_FIELDS"
    NAMES = "NAMES"
    DEM = "DEM"
    SIGMA_XY = "SIGMA_XY"
    SIGMA_Z = "SIGMA_Z"
    TRUTH = "TRUTH"
    OUTPUT = "OUTPUT"
    SHAPE_POINTS = "SHAPE_POINTS"
    RESIDUALS = "RESIDUALS"
    OUTPUT_FOLDER = "OUTPUT_FOLDER"
    REPORT = "REPORT"

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.LAYERS, "Road line layers (databases)", QgsProcessing.TypeVectorLine))
        self.addParameter(QgsProcessingParameterString(
            self.ID_FIELDS, "Id fields, one per layer in order (comma-separated; default: "
            "each layer's [[vectors]] entry's id_field, else the feature index)",
            optional=True))
        self.addParameter(QgsProcessingParameterString(
            self.NAMES, "Database names, one per layer in order (comma-separated; default: "
            "each layer's [[vectors]] entry's name, else the layer name)",
            optional=True))
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.DEM, "DEM for the shape point heights (default: each layer's [[vectors]] "
            "entry's dem, else the layer's Z)", optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.SIGMA_XY, "Prior sigma of the shape points, horizontal [m] (default: each "
            "layer's [[vectors]] entry's sigma, else 10)",
            QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.SIGMA_Z, "Prior sigma of the shape points, vertical [m] (default: each "
            "layer's [[vectors]] entry's sigma, else 10)",
            QgsProcessingParameterNumber.Double, optional=True, minValue=0.0))
        p = QgsProcessingParameterMultipleLayers(
            self.TRUTH, "Truth tables (point_id, X, Y, Z), one per layer or one for all",
            QgsProcessing.TypeVector, optional=True)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Comparison table", QgsProcessing.TypeVector))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.SHAPE_POINTS, "Adjusted shape points (all databases)",
            QgsProcessing.TypeVectorPoint, optional=True, createByDefault=False))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.RESIDUALS, "Residual vectors (all databases)", QgsProcessing.TypeVectorLine,
            optional=True, createByDefault=False))
        self.addParameter(QgsProcessingParameterFolderDestination(
            self.OUTPUT_FOLDER, "Output folder for the per-database GeoPackages", optional=True,
            createByDefault=False))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.REPORT, "Comparison report (HTML)", "HTML files (*.html *.htm)", optional=True,
            createByDefault=False))

    # ------------------------------------------------------------------ helpers
    def _layers(self, parameters, context, key):
        layers = self.parameterAsLayerList(parameters, key, context)
        return [lyr for lyr in layers if isinstance(lyr, QgsVectorLayer)]

    def _truth(self, parameters, context, n_layers):
        from vectoradjust.errors import ProjectError

        tables = self._layers(parameters, context, self.TRUTH)
        if not tables:
            return None
        if len(tables) not in (1, n_layers):
            raise ProjectError(f"{len(tables)} truth tables for {n_layers} road layers",
                               "Give one truth table per road layer (same order) or one for all")
        out = []
        for t in tables:
            path = qgis_io.layer_path(t)
            value = path if qgis_io.is_csv_path(path) else None
            out.append(qgis_io.read_truth_source(value, t, f"truth table {t.name()!r}"))
        return out * n_layers if len(out) == 1 else out

    # ------------------------------------------------------------------ run
    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.accuracy.summary import compare_columns, compare_row
        from vectoradjust.errors import ProjectError
        from vectoradjust.pipeline import run as run_pipeline

        layers = self._layers(parameters, context, self.LAYERS)
        if not layers:
            raise QgsProcessingException("Choose at least one road line layer to compare.")
        feedback.setProgressText("reading the inputs")
        prj = inputs.project_inputs(self, parameters, context, feedback, layers[0].crs())
        n = len(layers)
        id_fields = _split(self.parameterAsString(parameters, self.ID_FIELDS, context))
        names = _split(self.parameterAsString(parameters, self.NAMES, context))
        for label, lst in (("id fields", id_fields), ("names", names)):
            if len(lst) not in (1, n):
                raise ProjectError(f"{len(lst)} {label} for {n} road layers",
                                   f"Give one of the {label} per layer, in the order of the "
                                   "layers, separated by commas (or one for all)")
        if len(id_fields) == 1:
            id_fields = id_fields * n
        if len(names) == 1 and n > 1:
            if names[0]:
                raise ProjectError(f"one database name for {n} road layers",
                                   "Give one name per layer, separated by commas")
            names = [""] * n
        sxy = inputs._number(self, parameters, self.SIGMA_XY, context)
        sz = inputs._number(self, parameters, self.SIGMA_Z, context)
        dem_param = self.parameterAsRasterLayer(parameters, self.DEM, context)
        truth_param = self._truth(parameters, context, n)

        given = []
        for k, lyr in enumerate(layers):
            check_cancelled(feedback)
            db = inputs.read_road_layer(
                prj, lyr, lyr, context, feedback, name=names[k], id_field=id_fields[k],
                sigma_xy=sxy, sigma_z=sz, dem=dem_param,
                truth=truth_param[k] if truth_param is not None else None)
            if db.spec.name in [g.spec.name for g in given]:
                raise ProjectError(f"two road layers are both called {db.spec.name!r}",
                                   "Give distinct database names (parameter Names)")
            given.append(db)
        # every [[vectors]] entry of the project is read too (as vectoradjust compare
        # does): measurements of the databases not compared are recognised and left out
        data = inputs.project_data_with(prj, given, context, feedback)
        in_fields = [(g.fields, g.wkb) for g in given]
        vectors = [(g.spec, g.layer) for g in given]
        feedback.setProgress(5)

        runs = []
        span = 75.0 / n  # 5 .. 80 %; the [truth] buffer test 80 .. 85 %
        for k, (spec, _) in enumerate(vectors):
            feedback.pushInfo(f"adjusting {spec.name} ({k + 1}/{n})")
            out = run_pipeline(data, vectors=[spec.name],
                               progress=progress_callback(feedback, 5 + k * span, span),
                               is_cancelled=cancel_callback(feedback))
            for w in out.warnings:
                feedback.pushWarning(f"{spec.name}: {w}")
            runs.append(out)
        check_cancelled(feedback)
        # true centrelines ([truth]): buffer shares and point distances, as vectoradjust
        # compare writes them into each database's summary
        truth = project_truth_buffer(prj, runs, context, feedback)
        project_truth_lines(prj, runs, context, feedback, truth)
        rows = [compare_row(r.summary) for r in runs]
        outputs = self._write(parameters, context, feedback, runs, rows, in_fields, prj.crs,
                              [k for k, _ in compare_columns(rows)])
        report = write_html_report(self, parameters, context, feedback, self.REPORT,
                                   runs=runs, rows=rows)
        if report:
            outputs[self.REPORT] = report
        feedback.setProgress(100)
        return outputs

    def _write(self, parameters, context, feedback, runs, rows, in_fields, crs, columns):
        feedback.setProgressText("writing the outputs")
        outputs = {}
        fields = results.table_fields(columns, _TABLE_TYPES)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.NoGeometry, crs)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        results.add_all(sink, [qgis_io.new_feature(fields, [r.get(c) for c in columns])
                               for r in rows])
        outputs[self.OUTPUT] = dest
        for r in rows:
            feedback.pushInfo(", ".join(f"{c} {_fmt(r.get(c))}" for c in columns))

        every = SimpleNamespace(databases=[d for r in runs for d in r.databases])

        sfields = results.shape_fields()
        sink, dest = self.parameterAsSink(parameters, self.SHAPE_POINTS, context, sfields,
                                          QgsWkbTypes.PointZ, crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is not None:
            results.add_all(sink, results.shape_point_features(every, sfields), feedback, 85, 5)
            style_output(context, dest, "shape_points")
            outputs[self.SHAPE_POINTS] = dest
        rfields = results.residual_fields()
        sink, dest = self.parameterAsSink(parameters, self.RESIDUALS, context, rfields,
                                          QgsWkbTypes.LineStringZ, crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is not None:
            results.add_all(sink, results.residual_features(every, rfields), feedback, 90, 5)
            style_output(context, dest, "residuals")
            outputs[self.RESIDUALS] = dest
        folder = self.parameterAsString(parameters, self.OUTPUT_FOLDER, context)
        if folder:
            self._write_folder(folder, runs, rows, in_fields, crs, columns, context, feedback)
            outputs[self.OUTPUT_FOLDER] = folder
        feedback.setProgress(100)
        return outputs

    def _write_folder(self, folder, runs, rows, in_fields, crs, columns, context, feedback):
        os.makedirs(folder, exist_ok=True)
        tc = context.transformContext()
        for out, (fields_in, wkb_in) in zip(runs, in_fields):
            check_cancelled(feedback)
            name = out.databases[0].name if out.databases else "database"
            d = os.path.join(folder, name)
            os.makedirs(d, exist_ok=True)
            gpkg = os.path.join(d, "adjusted.gpkg")
            ff = results.feature_fields(fields_in)
            fwkb = results.feature_wkb_type(wkb_in)
            cfields = results.control_fields(out)
            results.write_gpkg(gpkg, [
                ("shape_points", results.shape_fields(), QgsWkbTypes.PointZ,
                 results.shape_point_features(out, results.shape_fields())),
                ("features", ff, fwkb,
                 results.feature_features(out, ff, QgsWkbTypes.isMultiType(fwkb))),
                ("control_points", cfields, QgsWkbTypes.PointZ,
                 results.control_point_features(out, cfields)),
            ], crs, tc, feedback)
            from vectoradjust.files.jsonfile import move_feature_statements

            summary, _ = move_feature_statements(out.summary, d)  # as the command line
            results.write_json(os.path.join(d, "summary.json"), summary)
            self._load_on_completion(context, gpkg, name)
        with open(os.path.join(folder, "compare.csv"), "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=columns)
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in columns})
        with open(os.path.join(folder, "compare.json"), "w", encoding="utf-8") as fh:
            json.dump(results.clean_json(rows), fh, indent=2)
        feedback.pushInfo(f"wrote {folder}")

    @staticmethod
    def _load_on_completion(context, gpkg, name):
        """In the desktop, add the per-database features layer to the project, styled."""
        project = context.project()
        if project is None:
            return
        from ..styles import StylePostProcessor, style_path

        uri = f"{gpkg}|layername=features"
        details = QgsProcessingContext.LayerDetails(f"{name} adjusted features", project,
                                                    "OUTPUT_FOLDER")
        qml = style_path("features")
        if qml:
            details.setPostProcessor(StylePostProcessor.create(qml))
        context.addLayerToLoadOnCompletion(uri, details)


def _fmt(v):
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3f}"
    return str(v)
