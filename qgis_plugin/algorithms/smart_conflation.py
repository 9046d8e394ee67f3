"""Smart conflation: the more accurate feature of each match of adjusted road databases."""

from qgis.core import (
    QgsFeatureRequest,
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsGeometry,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsVectorLayer,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QVariant

from .. import qgis_io
from .base import VectorAdjustAlgorithm, check_cancelled

HELP = """
<p>Smart conflation (the dissertation's future work 6.2): two or more <b>adjusted</b> road
databases are matched feature by feature, and per match the feature with the smaller
adjusted uncertainty prevails (its CE90; where the CE90s are equal within 1 %, the smaller
mean adjusted displacement RMSE). Unmatched features of every database are carried
through. The same computation as <code>vectoradjust conflate</code>.</p>
<h3>Needs</h3>
<ul>
<li><b>Adjusted feature layers</b>: the <code>features</code> layer of an adjustment
(one database per value of its <code>Database</code> field) or several layers of
adjusted features, each with a <code>CE90</code> field (one database per layer).</li>
<li><b>Maximum distance</b> (optional): the largest distance in metres at which two
lines count as the same road; default per pair 2 x the larger CE90, at least 5 m.</li>
<li><b>Minimum overlap</b>: the least share of each line within that distance of the
other (default 0.5).</li>
<li><b>Decide by</b>: CE90 (default) or RMSE (the mean adjusted displacement).</li>
</ul>
<p>Matching: points sampled along the lines, a KD-tree for the candidate pairs, per pair
the mean and Hausdorff distances, the overlap and the distance of the ends; equal names
(name/fullname) and classes (highway/mtfcc) add a bonus but are never required; one to
one by the Hungarian method. With three or more databases the first two are matched, then
their product against the third, and so on.</p>
<h3>Writes</h3>
<p>One line layer: the winner's attributes and line with <code>Source</code> (the winning
database), <code>Loser</code> (the databases it prevailed over), <code>LoserOffset</code>
(mean distance of the losers' lines to the winner's, m), <code>LoserCE90</code>,
<code>LoserRMSE</code>, <code>MatchScore</code> (0-1; empty: unmatched) and
<code>NSources</code>. The summary (matched and unmatched features, wins and mean CE90
per database) is written to the log.</p>
"""

BY = ["ce90", "rmse"]
#: the conflation's own fields and their types (f: real, s: text, i: integer)
OWN = (("Loser", "s"), ("LoserOffset", "f"), ("LoserCE90", "f"), ("LoserRMSE", "f"),
       ("MatchScore", "f"), ("NSources", "i"))


def _databases(layer, crs, context, feedback):
    """``[(name, xy list, columns dict, geometries, fields)]`` of one layer: one database
    per value of its Database field, else the layer."""
    from vectoradjust.errors import LayerError
    from vectoradjust.files.smart_outputs import join_parts

    names = layer.fields().names()
    if "CE90" not in names:
        raise LayerError(f"layer {layer.name()!r}: no CE90 field",
                         "Give adjusted features (the features layer of an adjustment), "
                         "which have CE90 per feature")
    request = QgsFeatureRequest()
    if layer.crs() != crs:
        request.setDestinationCrs(crs, context.transformContext())
    groups: dict = {}
    for k, f in enumerate(layer.getFeatures(request)):
        if k % 500 == 0:
            check_cancelled(feedback)
        g = f.geometry()
        if g is None or g.isNull() or g.isEmpty():
            continue
        attrs = [qgis_io.py_value(v) for v in f.attributes()]
        db = str(attrs[names.index("Database")]) if "Database" in names else layer.name()
        xy = join_parts(qgis_io._line_parts(g))
        grp = groups.setdefault(db, ([], {n: [] for n in names}, []))
        grp[0].append(xy)
        for n, v in zip(names, attrs):
            grp[1][n].append(v)
        grp[2].append(QgsGeometry(g))
    return [(db, xy, cols, geoms, layer.fields()) for db, (xy, cols, geoms) in groups.items()]


def _output_fields(dbs):
    """The output fields and, per database, its field -> output field name."""
    fields = QgsFields()
    fields.append(QgsField("Source", QVariant.String))
    kinds: dict = {}
    for _, _, _, _, flds in dbs:
        for f in flds:
            kinds.setdefault(f.name(), set()).add(f.type())
    rename = []
    for db, _, _, _, flds in dbs:
        names = {}
        for f in flds:
            if f.name() in ("Database",) or f.name() in dict(OWN):
                continue
            out = f.name() if len(kinds[f.name()]) == 1 else f"{db}_{f.name()}"
            names[f.name()] = out
            if fields.indexOf(out) < 0:
                fields.append(QgsField(out, f.type(), f.typeName(), f.length(),
                                       f.precision()))
        rename.append(names)
    for name, t in OWN:
        fields.append(qgis_io.fields_for([name], {name: t}).at(0))
    return fields, rename


class SmartConflation(VectorAdjustAlgorithm):
    NAME = "smartconflation"
    DISPLAY = "Smart conflation"
    SHORT = "Per matched road feature the database with the smaller adjusted CE90 prevails"
    HELP = HELP
    CLI_FLAGS = {"--max-distance": "MAX_DISTANCE", "--min-overlap": "MIN_OVERLAP",
                 "--databases": "LAYERS"}

    LAYERS, MAX_DISTANCE, MIN_OVERLAP, BY, OUTPUT = (
        "LAYERS", "MAX_DISTANCE", "MIN_OVERLAP", "BY", "OUTPUT")

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterMultipleLayers(
            self.LAYERS, "Adjusted feature layers (two or more databases)",
            QgsProcessing.TypeVectorLine))
        self.addParameter(QgsProcessingParameterNumber(
            self.MAX_DISTANCE, "Maximum distance of matching lines, m (default: 2 x the "
            "larger CE90, at least 5 m)", QgsProcessingParameterNumber.Double,
            optional=True, minValue=0.0))
        self.addParameter(QgsProcessingParameterNumber(
            self.MIN_OVERLAP, "Minimum overlap (share of each line along the other)",
            QgsProcessingParameterNumber.Double, defaultValue=0.5, minValue=0.01,
            maxValue=1.0))
        self.addParameter(QgsProcessingParameterEnum(
            self.BY, "Decide by", options=["CE90 (tie: RMSE)", "RMSE (tie: CE90)"],
            defaultValue=0))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Conflated", QgsProcessing.TypeVectorLine))

    def _read(self, parameters, context, feedback):
        from vectoradjust.errors import CRSError, ProjectError

        layers = [lyr for lyr in self.parameterAsLayerList(parameters, self.LAYERS, context)
                  if isinstance(lyr, QgsVectorLayer)]
        if not layers:
            raise ProjectError("no adjusted feature layer is given",
                               "Choose two or more databases' adjusted features")
        crs = layers[0].crs()
        if not crs.isValid() or crs.isGeographic():
            raise CRSError(f"layer {layers[0].name()!r}: the CRS is missing or geographic",
                           "Give adjusted features in a projected CRS (metres)")
        dbs = [d for lyr in layers for d in _databases(lyr, crs, context, feedback)]
        if len(dbs) < 2:
            raise ProjectError(f"smart conflation needs two or more databases; the layers "
                               f"hold {len(dbs)}", "Choose the features layer of an "
                               "adjustment of two or more databases, or more layers")
        return dbs, crs

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.conflation.smart import smart_conflate, summarise
        from vectoradjust.files.smart_outputs import feature_set, summary_table

        dbs, crs = self._read(parameters, context, feedback)
        feedback.setProgress(20)
        sets = [feature_set(db, xy, cols) for db, xy, cols, _, _ in dbs]
        dmax = parameters.get(self.MAX_DISTANCE)
        dmax = (None if dmax is None or qgis_io.is_null(dmax)
                else self.parameterAsDouble(parameters, self.MAX_DISTANCE, context))
        if dmax is not None and dmax <= 0:
            dmax = None
        result, steps = smart_conflate(
            sets, dmax, self.parameterAsDouble(parameters, self.MIN_OVERLAP, context),
            BY[self.parameterAsEnum(parameters, self.BY, context)],
            progress=lambda k, n: feedback.setProgress(20 + 60 * k / n))
        check_cancelled(feedback)
        fields, rename = _output_fields(dbs)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.multiType(QgsWkbTypes.LineStringZ),
                                          crs, QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        own = [result.loser_names(), result.loser_offset, result.loser_values("ce90"),
               result.loser_values("rmse"), result.score,
               [1 + len(ls) for ls in result.losers]]
        for row, (s, f) in enumerate(zip(result.source, result.feature)):
            db, _, cols, geoms, _ = dbs[s]
            values = [None] * fields.count()
            values[0] = db
            for name, out in rename[s].items():
                values[fields.indexOf(out)] = cols[name][f]
            for (name, _), v in zip(OWN, own):
                values[fields.indexOf(name)] = v[row]
            g = QgsGeometry(geoms[f])
            g.convertToMultiType()
            sink.addFeature(qgis_io.new_feature(fields, values, g), QgsFeatureSink.FastInsert)
        summary = summarise(result)
        feedback.pushInfo(summary_table(summary))
        feedback.setProgress(100)
        return {self.OUTPUT: dest, "MATCHED": summary["matched"],
                "FEATURES": summary["features"]}
