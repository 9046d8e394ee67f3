"""DTM accuracy: sigma Z and LE90 per cell, contours with their uncertainty buffers."""

import time

import numpy as np
from qgis.core import (
    QgsFeatureSink,
    QgsGeometry,
    QgsLineString,
    QgsPointXY,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsWkbTypes,
)

from .. import qgis_io
from . import inputs
from .base import VectorAdjustAlgorithm
from .gdal_raster import write_float_bands

HELP = """
<p>Adjusts the project (as <code>vectoradjust dtm</code> does) and gives the accuracy of a DTM
built from it, cell by cell: the height of every cell is interpolated from the adjusted points
(control, tie and shape points) and its standard deviation propagated with the FULL
a-posteriori covariance of those points (Filin &amp; Doytsher), or from the project's DEM with
a stated node sigma and correlation length. The sampling term (Torlegard: 0.3 per mille of the
flying height on flat terrain, 1.5 per mille in mountains, by the mean slope) and the terrain
term (Li: b (1 + 4S/W) (S tan a)<sup>2</sup>, b = 17/3072) are added to the variance.</p>
<h3>Needs</h3>
<ul>
<li><b>Project file</b> (and/or the parameters below, as for <i>Adjust road vectors</i>).</li>
<li><b>Cell size</b> (m, default 5), <b>interpolation</b> (TIN, bilinear or bicubic),
<b>source</b> (the adjusted points, or the project's DEM: bilinear or bicubic only) and the
<b>contour interval</b> (m, default 1).</li>
</ul>
{project_help}
<h3>Writes</h3>
<ul>
<li><b>DTM accuracy</b>: a 5-band Float32 GeoTIFF (height, sigma Z, LE90, sigma Z of the
interpolation alone, tan slope), nodata -9999 outside the DTM: the
<code>dtm_accuracy.tif</code> of the command line.</li>
<li><b>Contours</b>: one line per contour segment with <code>level</code>, <code>sigma_z</code>,
<code>sigma_xy</code> = sigma Z / tan(slope) (capped at 5 cells where flat) and
<code>capped</code>; <b>Contour buffers</b>: per level the area within sigma_xy of its
contour.</li>
<li>Numbers: the cells, the median sigma Z and LE90, the contour segments.</li>
</ul>
"""

INTERPOLATIONS = ["tin", "bilinear", "bicubic"]
SOURCES = ["points", "dem"]


def write_dtm_raster(product, path, crs):
    """Write a DTM product with QGIS's GDAL (the bands of ``files.dtm_outputs``).

    Parameters
    ----------
    product : vectoradjust.accuracy.dtm.DTMProduct
    path : str
    crs : QgsCoordinateReferenceSystem

    Returns
    -------
    str
    """
    from vectoradjust.files.dtm_outputs import _BANDS, DTM_NODATA

    bands = np.stack([product.height, product.sigma, product.le90,
                      product.sigma_interpolation, product.tan_slope])
    return write_float_bands(path, bands, product.transform, crs, _BANDS, DTM_NODATA,
                             {"method": product.method, "source": product.model.kind,
                              "units": "m"}, "the DTM accuracy raster")


class DtmAccuracy(VectorAdjustAlgorithm):
    NAME = "dtmaccuracy"
    DISPLAY = "DTM accuracy"
    SHORT = "Sigma Z / LE90 per DTM cell and contours with their horizontal uncertainty."
    HELP = HELP.replace("{project_help}", inputs.PROJECT_HELP)

    CELL = "CELL"
    INTERPOLATION = "INTERPOLATION"
    SOURCE = "SOURCE"
    NODE_SIGMA = "NODE_SIGMA"
    CORRELATION_LENGTH = "CORRELATION_LENGTH"
    CONTOUR_INTERVAL = "CONTOUR_INTERVAL"
    OUTPUT = "OUTPUT"
    CONTOURS = "CONTOURS"
    BUFFERS = "CONTOUR_BUFFERS"
    CLI_FLAGS = {"--cell": CELL, "--interpolation": INTERPOLATION, "--source": SOURCE,
                 "--node-sigma": NODE_SIGMA, "--correlation-length": CORRELATION_LENGTH,
                 "--contour-interval": CONTOUR_INTERVAL}

    def initAlgorithm(self, config=None):
        advanced = QgsProcessingParameterDefinition.FlagAdvanced
        self.addParameter(QgsProcessingParameterNumber(
            self.CELL, "Cell size [m]", QgsProcessingParameterNumber.Double, defaultValue=5.0,
            minValue=0.0))
        self.addParameter(QgsProcessingParameterEnum(
            self.INTERPOLATION, "Interpolation", INTERPOLATIONS, defaultValue=0))
        self.addParameter(QgsProcessingParameterEnum(
            self.SOURCE, "Heights from (the adjusted points or the project's DEM)", SOURCES,
            defaultValue=0))
        self.addParameter(QgsProcessingParameterNumber(
            self.CONTOUR_INTERVAL, "Contour interval [m]", QgsProcessingParameterNumber.Double,
            defaultValue=1.0, minValue=0.0))
        for name, label, default in (
                (self.NODE_SIGMA, "DEM node sigma [m] (default: the database's Z sigma)", None),
                (self.CORRELATION_LENGTH, "DEM correlation length [m]", 0.0)):
            p = QgsProcessingParameterNumber(name, label, QgsProcessingParameterNumber.Double,
                                             defaultValue=default, optional=default is None,
                                             minValue=0.0)
            p.setFlags(p.flags() | advanced)
            self.addParameter(p)
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterRasterDestination(
            self.OUTPUT, "DTM accuracy (height, sigma Z, LE90, ...)"))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.CONTOURS, "Contours", QgsProcessing.TypeVectorLine))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.BUFFERS, "Contour buffers", QgsProcessing.TypeVectorPolygon, optional=True,
            createByDefault=True))
        for name, label in (("CELLS", "Cells in the DTM"),
                            ("SIGMA_MEDIAN", "Median sigma Z [m]"),
                            ("LE90_MEDIAN", "Median LE90 [m]"),
                            ("SEGMENTS", "Contour segments")):
            self.addOutput(QgsProcessingOutputNumber(name, label))

    def _model(self, parameters, context, adj):
        from vectoradjust.accuracy import dtm
        from vectoradjust.errors import ProjectError

        method = INTERPOLATIONS[self.parameterAsEnum(parameters, self.INTERPOLATION, context)]
        if SOURCES[self.parameterAsEnum(parameters, self.SOURCE, context)] == "points":
            return dtm.run_points_model(adj.run), method
        if method == "tin":
            raise ProjectError("--source dem --interpolation tin: a DEM is a grid",
                               "Use --interpolation bilinear or bicubic with --source dem")
        sigma = inputs._number(self, parameters, self.NODE_SIGMA, context)
        model = dtm.run_dem_model(adj.run, sigma, self.parameterAsDouble(
            parameters, self.CORRELATION_LENGTH, context))
        if model is None:
            raise ProjectError("--source dem: the project has no DEM in its CRS",
                               "Give dem = \"...\" in a [[vectors]] entry, or use "
                               "--source points")
        return model, method

    def _sinks(self, parameters, context, seg, crs):
        fields = qgis_io.fields_for(["level", "sigma_z", "sigma_xy", "capped"], {"capped": "i"})
        sink, dest = self.parameterAsSink(parameters, self.CONTOURS, context, fields,
                                          QgsWkbTypes.LineString, crs,
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.CONTOURS))
        for k in range(len(seg.level)):
            line = QgsLineString([QgsPointXY(*map(float, p)) for p in seg.xy[k]])
            sink.addFeature(qgis_io.new_feature(
                fields, [seg.level[k], seg.sigma_z[k].mean(), seg.sigma_xy[k].mean(),
                         int(seg.capped[k].any())], QgsGeometry(line)),
                QgsFeatureSink.FastInsert)
        out = {self.CONTOURS: dest}
        bfields = qgis_io.fields_for(["level", "segments", "mean_sigma_xy", "max_sigma_xy"],
                                     {"segments": "i"})
        bsink, bdest = self.parameterAsSink(parameters, self.BUFFERS, context, bfields,
                                            QgsWkbTypes.MultiPolygon, crs,
                                            QgsFeatureSink.RegeneratePrimaryKey)
        if bsink is not None:
            rings = seg.buffer_rings()
            for level in np.unique(seg.level):
                k = np.flatnonzero(seg.level == level)
                geom = QgsGeometry.unaryUnion([QgsGeometry.fromPolygonXY(
                    [[QgsPointXY(*map(float, p)) for p in rings[j]]]) for j in k])
                geom.convertToMultiType()
                bsink.addFeature(qgis_io.new_feature(
                    bfields, [level, len(k), seg.sigma_xy[k].mean(), seg.sigma_xy[k].max()],
                    geom), QgsFeatureSink.FastInsert)
            out[self.BUFFERS] = bdest
        return out

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.accuracy import dtm
        from vectoradjust.errors import ProjectError

        t0 = time.perf_counter()
        cell = self.parameterAsDouble(parameters, self.CELL, context)
        interval = self.parameterAsDouble(parameters, self.CONTOUR_INTERVAL, context)
        if not cell > 0 or not interval > 0:
            raise ProjectError(f"--cell {cell:g} / --contour-interval {interval:g} must be "
                               "positive", "Give a positive cell size and contour interval "
                               "in metres")
        adj = inputs.run_adjustment(self, parameters, context, feedback, road_optional=True,
                                    start=5.0, span=70.0)
        feedback.setProgressText("DTM accuracy")
        model, method = self._model(parameters, context, adj)
        product = dtm.dtm_product(model, cell, method,
                                  flying_height=dtm.run_flying_height(adj.run))
        seg = dtm.contour_segments(product, interval)
        path = self.parameterAsOutputLayer(parameters, self.OUTPUT, context)
        write_dtm_raster(product, path, adj.prj.crs)
        out = self._sinks(parameters, context, seg, adj.prj.crs)
        s = product.summary
        feedback.pushInfo(f"{method} from the {s['source']}: {s['cells']} cells of {cell:g} m, "
                          f"median sigma Z {s['sigma']['median']:.4f} m; sampling "
                          f"{product.sigma_sampling:.4f} m, terrain {product.sigma_terrain:.4f} m;"
                          f" {len(seg.level)} contour segments; {time.perf_counter() - t0:.1f} s")
        feedback.setProgress(100)
        return {self.OUTPUT: path, **out, "CELLS": s["cells"],
                "SIGMA_MEDIAN": s["sigma"]["median"], "LE90_MEDIAN": s["le90"]["median"],
                "SEGMENTS": int(len(seg.level))}
