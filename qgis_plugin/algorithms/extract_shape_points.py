"""Extract shape points: the vertices of a road layer to be measured on the images."""

import numpy as np
from qgis.core import (
    QgsFeatureSink,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterCrs,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsWkbTypes,
)

from .. import qgis_io
from ..styles import style_output
from .base import VectorAdjustAlgorithm, check_cancelled

HELP = """
<p>Lists the vertices (<i>shape points</i>) of a road line layer as points, with the ids the
image measurements must use and heights from a DEM, ready to be measured on the stereo images.
</p>
<h3>Needs</h3>
<ul>
<li><b>Road line layer</b> (LineString or MultiLineString; it must have a CRS).</li>
<li><b>Feature id field</b> (optional; unique values; empty = the 0-based feature index).</li>
<li><b>DEM</b> (optional): Z by bilinear interpolation between cell centres (band 1; vertices
it does not cover get an empty Z); without a DEM the layer's own Z is used.</li>
<li><b>Ground CRS</b> (optional): the CRS of the output (default the layer's CRS).</li>
</ul>
<h3>Writes</h3>
<p>A Point Z layer with <code>point_id</code> = <code>&lt;feature id&gt;_&lt;vertex index&gt;</code>
(vertex index 0-based along the feature, continuing across the parts of a multi-line),
<code>feature_id</code>, <code>vertex</code>, <code>part</code>, <code>X</code>, <code>Y</code>,
<code>Z</code>, <code>object_id</code> (vertices at the same XY, within the merge tolerance,
are one object point: the id of its first vertex) and <code>NShared</code> (how many vertices
share it). With <i>One point per object point</i> (default) shared vertices such as
intersections are written once, under the first of their ids, which is the id to measure.</p>
<p>Features with null or empty geometry have no shape points; they are reported in the log.</p>
"""


class ExtractShapePoints(VectorAdjustAlgorithm):
    NAME = "extractshapepoints"
    DISPLAY = "Extract shape points"
    SHORT = "Vertices of a road layer with contract ids and DEM heights, to be measured."
    HELP = HELP

    INPUT = "INPUT"
    ID_FIELD = "ID_FIELD"
    DEM = "DEM"
    GROUND_CRS = "GROUND_CRS"
    UNIQUE = "UNIQUE"
    TOLERANCE = "MERGE_TOLERANCE"
    OUTPUT = "OUTPUT"

    FIELDS = ["point_id", "feature_id", "vertex", "part", "X", "Y", "Z", "object_id", "NShared"]
    TYPES = {"point_id": "s", "feature_id": "s", "vertex": "i", "part": "i", "object_id": "s",
             "NShared": "i"}

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterFeatureSource(
            self.INPUT, "Road line layer", [QgsProcessing.TypeVectorLine]))
        self.addParameter(QgsProcessingParameterField(
            self.ID_FIELD, "Feature id field (empty: feature index)",
            parentLayerParameterName=self.INPUT, optional=True))
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.DEM, "DEM for the heights", optional=True))
        self.addParameter(QgsProcessingParameterCrs(
            self.GROUND_CRS, "Ground CRS of the output (default: layer CRS)", optional=True))
        self.addParameter(QgsProcessingParameterBoolean(
            self.UNIQUE, "One point per object point (shared vertices once)", defaultValue=True))
        p = QgsProcessingParameterNumber(self.TOLERANCE, "Merge tolerance [CRS units]",
                                         QgsProcessingParameterNumber.Double,
                                         defaultValue=0.001, minValue=0.0)
        p.setFlags(p.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        self.addParameter(p)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Shape points", QgsProcessing.TypeVectorPoint))
        self.addOutput(QgsProcessingOutputNumber("COUNT", "Number of shape points written"))
        self.addOutput(QgsProcessingOutputNumber("UNCOVERED", "Shape points without height"))

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.adjust.shapepoints import extract_shape_points

        source = self.parameterAsSource(parameters, self.INPUT, context)
        if source is None:
            raise QgsProcessingException(self.invalidSourceError(parameters, self.INPUT))
        where = f"road layer {source.sourceName()!r}"
        crs = self.parameterAsCrs(parameters, self.GROUND_CRS, context) if parameters.get(
            self.GROUND_CRS) not in (None, "") else source.sourceCrs()
        if not crs.isValid():
            crs = source.sourceCrs()
        id_field = self.parameterAsString(parameters, self.ID_FIELD, context).strip() or None
        layer, _ = qgis_io.read_line_source(source, source.sourceName(), id_field, crs, context,
                                            where)
        if crs.isGeographic():
            feedback.pushWarning(f"The CRS {crs.authid()} is geographic: the merge tolerance is "
                                 "in degrees, and the adjustment needs a projected CRS")
        check_cancelled(feedback)
        feedback.setProgress(20)
        dem = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem is not None:
            feedback.setProgressText(f"sampling the DEM {dem.name()}")
            layer.coords[:, 2] = qgis_io.dem_heights(dem, layer.coords[:, :2], crs, context,
                                                     f"DEM {dem.name()!r}")
        feedback.setProgress(40)
        tol = self.parameterAsDouble(parameters, self.TOLERANCE, context)
        sp = extract_shape_points(layer, tol)
        for i, why in sorted(layer.problems.items()):
            feedback.pushWarning(f"{where}: feature {layer.feature_ids[i]!r} has no shape points "
                                 f"({why})")
        unique = self.parameterAsBoolean(parameters, self.UNIQUE, context)
        rows = sp.object_vertex if unique else np.arange(len(sp.vertex_ids))
        shared = np.bincount(sp.vertex_object, minlength=sp.n_objects)
        fields = qgis_io.fields_for(self.FIELDS, self.TYPES)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.PointZ, crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        xyz = layer.coords
        obj_ids = sp.object_ids
        fids = layer.feature_ids[layer.vertex_feature]
        feats = []
        for v in rows:
            o = sp.vertex_object[v]
            values = [sp.vertex_ids[v], fids[v], layer.vertex_index[v], layer.vertex_part[v],
                      xyz[v, 0], xyz[v, 1], xyz[v, 2], obj_ids[o], shared[o]]
            feats.append(qgis_io.new_feature(fields, values,
                                             qgis_io.point_z(xyz[v, 0], xyz[v, 1], xyz[v, 2])))
        from ..results import add_all

        add_all(sink, feats, feedback, 50, 50)
        style_output(context, dest, "extracted")
        uncovered = int(np.count_nonzero(~np.isfinite(xyz[rows, 2]))) if len(rows) else 0
        if uncovered:
            feedback.pushWarning(f"{uncovered} shape point(s) have no height ("
                                 + ("the DEM does not cover them" if dem is not None else
                                    "the layer has no Z") + "); their Z is empty")
        feedback.pushInfo(f"{len(rows)} shape points of {layer.n_features} features "
                          f"({len(sp.vertex_ids)} vertices, {sp.n_objects} object points)")
        return {self.OUTPUT: dest, "COUNT": len(rows), "UNCOVERED": uncovered}
