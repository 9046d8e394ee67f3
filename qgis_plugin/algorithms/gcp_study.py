"""GCP study: the project adjusted with subsets of its control points (dissertation
Table 17, Fig 5.11, Tables 18-21, Fig 5.12), as ``vectoradjust study gcp`` does."""

import os

from qgis.core import (
    QgsFeatureSink,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
    QgsWkbTypes,
)

from .. import qgis_io, results
from . import inputs
from .base import VectorAdjustAlgorithm, cancel_callback, check_cancelled, progress_callback

HELP = """
<p>Adjusts the project (every <code>[[vectors]]</code> entry together) several times, each
time with a subset of its ground control points (role control); the control points held out
become <b>check points</b>: they are not in the adjustment, they are intersected from the
adjusted orientation and scored. The dissertation found 3 well-placed GCPs almost as good as
24 (1.04 m against 1.03 m).</p>
<h3>Needs</h3>
<ul>
<li><b>Project file</b> (and/or the parameters below, as for <i>Adjust road vectors</i>).</li>
<li><b>Numbers of GCPs</b>: a sweep with well-spread subsets, e.g. <code>24,12,6,3</code>
(empty: all, half, quarter ... down to 3, unless configurations or random numbers are
given).</li>
<li><b>Configurations</b> (optional): <code>3-North, 3-East, 3-SW</code> (the points of that
part of the block, well spread among themselves; also South, West, NE, NW, SE, Center,
Spread) or <code>NAME=ID1;ID2;ID3</code>.</li>
<li><b>Random numbers</b> (optional), with repetitions and a seed: random subsets.</li>
</ul>
{project_help}
<h3>Writes</h3>
<ul>
<li><b>GCP study table</b>: one row per run (the columns of <code>gcp_study.csv</code>): the
control points kept, the check point RMSE (held-out and the project's check points), the
held-out RMSE, and per database the residual RMSE and, with truth, the adjusted - truth
RMSE.</li>
<li><b>GCP configurations</b> (optional): the control and check points once per
configuration, with fields <code>config</code> and <code>kept</code> (1: in the adjustment),
to map the configurations.</li>
<li><b>Output folder</b> (optional): <code>gcp_study.csv</code>, <code>gcp_summary.csv</code>,
the figures and <code>report.html</code> as the command line writes them (figures need
matplotlib in QGIS's Python).</li>
</ul>
""".replace("{project_help}", inputs.PROJECT_HELP)

_TYPES = {"label": "s", "group": "s", "n_control": "i", "repeat": "i", "control_ids": "s",
          "n_check": "i", "n_held_out": "i", "error": "s"}


def _numbers(text, what):
    from vectoradjust.errors import ProjectError

    parts = [t.strip() for t in str(text or "").replace(";", ",").split(",") if t.strip()]
    try:
        out = [int(t) for t in parts]
    except ValueError:
        raise ProjectError(f"{what} {text!r} is not a list of whole numbers",
                           "Write e.g. 24,12,6,3") from None
    return out


class GcpStudy(VectorAdjustAlgorithm):
    NAME = "gcpstudy"
    DISPLAY = "GCP study (number and location of control points)"
    SHORT = "Adjust with subsets of the control points; the others are scored as check points."
    HELP = HELP

    NUMBERS = "NUMBERS"
    CONFIGURATIONS = "CONFIGURATIONS"
    RANDOM = "RANDOM"
    REPEATS = "REPEATS"
    SEED = "SEED"
    OUTPUT = "OUTPUT"
    CONFIG_POINTS = "CONFIG_POINTS"
    OUTPUT_FOLDER = "OUTPUT_FOLDER"

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterString(
            self.NUMBERS, "Numbers of GCPs, well spread (e.g. 24,12,6,3; empty: halving to 3)",
            optional=True))
        self.addParameter(QgsProcessingParameterString(
            self.CONFIGURATIONS, "Configurations (e.g. 3-North,3-East,3-SW)", optional=True))
        advanced = QgsProcessingParameterDefinition.FlagAdvanced
        for p in (
            QgsProcessingParameterString(
                self.RANDOM, "Random numbers of GCPs (e.g. 3,6)", optional=True),
            QgsProcessingParameterNumber(
                self.REPEATS, "Random subsets per number", QgsProcessingParameterNumber.Integer,
                defaultValue=10, minValue=1),
            QgsProcessingParameterNumber(
                self.SEED, "Seed of the random subsets", QgsProcessingParameterNumber.Integer,
                defaultValue=0, minValue=0)):
            p.setFlags(p.flags() | advanced)
            self.addParameter(p)
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "GCP study table", QgsProcessing.TypeVector))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.CONFIG_POINTS, "GCP configurations", QgsProcessing.TypeVectorPoint,
            optional=True, createByDefault=False))
        self.addParameter(QgsProcessingParameterFolderDestination(
            self.OUTPUT_FOLDER, "Output folder (CSV tables, figures, report.html)",
            optional=True, createByDefault=False))

    def _plan(self, parameters, context, data):
        from vectoradjust.files.study import gcp_plan

        numbers = _numbers(self.parameterAsString(parameters, self.NUMBERS, context),
                           "Numbers of GCPs")
        configs = [t.strip().replace(";", ",") for t in self.parameterAsString(
            parameters, self.CONFIGURATIONS, context).split(",") if t.strip()]
        # NAME=ID1;ID2 keeps its ids together: "3-North,mine=GCP01;GCP02;GCP03"
        rand = _numbers(self.parameterAsString(parameters, self.RANDOM, context),
                        "Random numbers of GCPs")
        repeats = self.parameterAsInt(parameters, self.REPEATS, context)
        seed = self.parameterAsInt(parameters, self.SEED, context)
        return gcp_plan(data, numbers or (None if not (configs or rand) else []), configs,
                        rand, repeats, seed)

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.files.study import gcp_study

        feedback.setProgressText("reading the inputs")
        prj = inputs.project_inputs(self, parameters, context, feedback, None)
        data = inputs.project_data_with(prj, [], context, feedback)
        check_cancelled(feedback)
        plan = self._plan(parameters, context, data)
        feedback.pushInfo(f"{len(plan)} adjustments")
        rows = gcp_study(data, plan, progress=progress_callback(feedback, 5.0, 85.0),
                         is_cancelled=cancel_callback(feedback))
        check_cancelled(feedback)
        outputs = self._write_table(parameters, context, rows, prj.crs)
        dest = self._write_points(parameters, context, data, plan, prj.crs)
        if dest is not None:
            outputs[self.CONFIG_POINTS] = dest
        folder = self.parameterAsString(parameters, self.OUTPUT_FOLDER, context)
        if folder:
            self._write_folder(folder, data, plan, rows)
            outputs[self.OUTPUT_FOLDER] = folder
        for r in rows:
            feedback.pushInfo(f"{r['label']}: check RMSE h {r.get('check_rmse_h')}"
                              + (f" - {r['error']}" if r.get("error") else ""))
        feedback.setProgress(100)
        return outputs

    def _write_table(self, parameters, context, rows, crs):
        columns = list(dict.fromkeys(k for r in rows for k in r))
        fields = results.table_fields(columns, _TYPES)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.NoGeometry, crs)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        results.add_all(sink, [qgis_io.new_feature(fields, [r.get(c) for c in columns])
                               for r in rows])
        return {self.OUTPUT: dest}

    def _write_points(self, parameters, context, data, plan, crs):
        ctrl = data.control
        columns = ["config", "point_id", "role", "kept"]
        fields = qgis_io.fields_for(columns, {"config": "s", "point_id": "s", "role": "s",
                                              "kept": "i"})
        sink, dest = self.parameterAsSink(parameters, self.CONFIG_POINTS, context, fields,
                                          QgsWkbTypes.PointZ, crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            return None
        feats = []
        seen = set()
        for p in plan:
            if p["label"] in seen:
                continue
            seen.add(p["label"])
            kept = set(int(i) for i in p["rows"])
            for i, pid in enumerate(ctrl.point_id):
                x, y, z = (float(v) for v in ctrl.xyz[i])
                feats.append(qgis_io.new_feature(
                    fields, [p["label"], str(pid), str(ctrl.role[i]), int(i in kept)],
                    qgis_io.point_z(x, y, z)))
        results.add_all(sink, feats)
        return dest

    @staticmethod
    def _write_folder(folder, data, plan, rows):
        from vectoradjust.files.study import gcp_summary, write_csv

        os.makedirs(folder, exist_ok=True)
        summ = gcp_summary(rows)
        write_csv(rows, os.path.join(folder, "gcp_study.csv"))
        write_csv(summ, os.path.join(folder, "gcp_summary.csv"))
        try:
            from vectoradjust.files import study_report as sr

            fmap = sr.gcp_map_figure(data.control.xyz, data.control.role, plan)
            frm = sr.gcp_rmse_figure(summ)
            sr.write_png(fmap, os.path.join(folder, "gcp_map.png"))
            sr.write_png(frm, os.path.join(folder, "gcp_rmse.png"))
            sr.write_study_report(os.path.join(folder, "report.html"), "GCP study", [
                ("gcp", "Control point study", sr.table_html(summ), [
                    (fmap, "GCP configurations", "Control points kept (triangles), held out "
                     "(circles), the project's check points (crosses)."),
                    (frm, "RMSE against the number of GCPs", "Mean over the runs; bars "
                     "from the smallest to the largest run.")])])
        except ImportError:  # no matplotlib in QGIS's Python: the tables only
            pass
