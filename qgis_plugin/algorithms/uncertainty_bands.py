"""Uncertainty bands: the G-band of every adjusted road feature as a polygon."""

import time

import numpy as np
from qgis.core import (
    QgsFeatureSink,
    QgsGeometry,
    QgsMultiPolygon,
    QgsPointXY,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from .. import qgis_io, results
from ..styles import style_output
from . import inputs
from .base import VectorAdjustAlgorithm, check_cancelled

HELP = """
<p>Adjusts a road line layer (as <i>Adjust road vectors</i>) and draws, for every feature, the
area in which the true road lies with the given probability: the <i>G-band</i> of Shi and Liu
(2000) of each segment whose two vertices were measured, from the joint a-posteriori covariance
of its end points (their own 2x2 blocks and the cross-covariance of the adjustment), the
segments' bands united per feature. It is the uncertainty band of the
<code>uncertainty_bands</code> layer that <code>vectoradjust adjust</code> writes into
<code>adjusted.gpkg</code>.</p>
<h3>Needs</h3>
<ul>
<li><b>Road line layer</b>, id field, DEM and prior sigma as for <i>Adjust road
vectors</i>.</li>
<li><b>Confidence</b>: the probability of the error ellipses the band is swept from (default
0.9 = 90 %).</li>
<li>Camera, images, measurements and control: see below.</li>
</ul>
{project_help}
{road_help}
<h3>Writes</h3>
<ul>
<li><b>Uncertainty bands</b>: one MultiPolygon per feature with at least one measured segment
(fields <code>database</code>, <code>feature_id</code>, <code>confidence</code>,
<code>NSeg</code> = the number of segments united), in the ground CRS. Segments with an
unmeasured end point have no band.</li>
<li>Numbers: the number of bands and their total area (m<sup>2</sup>).</li>
</ul>
"""

BAND_TYPES = {"database": "s", "feature_id": "s", "NSeg": "i"}


def band_fields():
    """Fields of the bands layer (:data:`vectoradjust.files.derived_outputs.BAND_FIELDS`)."""
    from vectoradjust.files.derived_outputs import BAND_FIELDS

    return qgis_io.fields_for(BAND_FIELDS, BAND_TYPES)


def _polygon(ring):
    """A valid polygon geometry of a closed ring (as shapely.make_valid would mend it)."""
    g = QgsGeometry.fromPolygonXY([[QgsPointXY(float(x), float(y)) for x, y in ring]])
    return g if g.isGeosValid() else g.makeValid()


def _polygon_parts(geom):
    """The non-empty polygons of a geometry (a union may hold lines or points too)."""
    out = []
    for part in geom.constParts():
        if QgsWkbTypes.flatType(part.wkbType()) == QgsWkbTypes.Polygon and not part.isEmpty():
            out.append(part.clone())
        elif QgsWkbTypes.isMultiType(part.wkbType()):
            out += _polygon_parts(QgsGeometry(part.clone()))
    return out


def band_features(run, fields, confidence, feedback=None):
    """Features of the bands layer: one MultiPolygon per feature with a band.

    The segment rings come from :func:`vectoradjust.accuracy.derived.uncertainty_bands`; they are
    made valid and united per feature with QGIS's GEOS (``QgsGeometry.unaryUnion``).
    """
    from vectoradjust.accuracy.derived import uncertainty_bands

    out = []
    for d in run.databases:
        rings = uncertainty_bands(run, d, confidence)
        if not rings:
            continue
        feature = np.array([f for f, _ in rings], np.int64)
        order = np.argsort(feature, kind="stable")
        feats, starts, counts = np.unique(feature[order], return_index=True,
                                          return_counts=True)
        fids = d.shape.layer.feature_ids
        for f, s, c in zip(feats, starts, counts):
            check_cancelled(feedback)
            polys = [_polygon(rings[i][1]) for i in order[s:s + c]]
            union = QgsGeometry.unaryUnion(polys)
            mp = QgsMultiPolygon()
            for part in _polygon_parts(union):
                mp.addGeometry(part)
            out.append(qgis_io.new_feature(fields, [d.name, str(fids[f]), float(confidence),
                                                    int(c)], QgsGeometry(mp)))
    return out


class UncertaintyBands(VectorAdjustAlgorithm):
    NAME = "uncertaintybands"
    DISPLAY = "Uncertainty bands"
    SHORT = "The 90 % G-band of every adjusted road feature (Shi & Liu 2000) as polygons."
    HELP = HELP.replace("{project_help}", inputs.PROJECT_HELP).replace("{road_help}",
                                                                       inputs.ROAD_HELP)

    CONFIDENCE = "CONFIDENCE"
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config=None):
        inputs.add_road_parameters(self)
        self.addParameter(QgsProcessingParameterNumber(
            self.CONFIDENCE, "Confidence (probability of the band)",
            QgsProcessingParameterNumber.Double, defaultValue=0.9, minValue=0.0, maxValue=1.0))
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Uncertainty bands", QgsProcessing.TypeVectorPolygon))
        self.addOutput(QgsProcessingOutputNumber("BANDS", "Number of bands (features)"))
        self.addOutput(QgsProcessingOutputNumber("AREA", "Total area of the bands [m2]"))

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.errors import ProjectError

        t0 = time.perf_counter()
        confidence = self.parameterAsDouble(parameters, self.CONFIDENCE, context)
        if not 0.0 < confidence < 1.0:
            raise ProjectError(f"The confidence {confidence:g} is not a probability between 0 "
                               "and 1", "Give e.g. 0.9 for 90 % bands")
        adj = inputs.run_adjustment(self, parameters, context, feedback, start=5.0, span=65.0)
        feedback.setProgressText("uncertainty bands")
        fields = band_fields()
        feats = band_features(adj.run, fields, confidence, feedback)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.MultiPolygon, adj.prj.crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        results.add_all(sink, feats, feedback, 90.0, 10.0)
        style_output(context, dest, "bands")
        area = float(sum(f.geometry().area() for f in feats))
        feedback.pushInfo(f"{len(feats)} uncertainty bands ({confidence:g}), total area "
                          f"{area:.1f} m2; done in {time.perf_counter() - t0:.1f} s")
        feedback.setProgress(100)
        return {self.OUTPUT: dest, "BANDS": len(feats), "AREA": area}
