"""Equal-error map: sigma X, Y, Z of a ground point intersected from a stereo pair."""

import time

import numpy as np
from qgis.core import (
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
)

from .. import qgis_io
from . import inputs
from .base import VectorAdjustAlgorithm
from .gdal_raster import write_float_bands

HELP = """
<p>Adjusts the project (every <code>[[vectors]]</code> entry together, as
<code>vectoradjust equal-error</code> does) and maps how precisely a new ground point would be
intersected from the stereo pair: at every node of a grid over the pair's overlap the point is
projected into both images and intersected back, with the adjusted exterior orientation's
joint covariance of the two images and the image coordinate sigma of the pair's measurements
scaled by the variance factor. The result is the a-posteriori standard deviation of X, Y and Z
in metres (Z is the weak direction: it grows with the height-to-base ratio).</p>
<h3>Needs</h3>
<ul>
<li><b>Project file</b> (and/or the parameters below, as for <i>Adjust road vectors</i>).</li>
<li><b>DEM</b> (optional): terrain heights of the grid nodes; default the DEM of the first
<code>[[vectors]]</code> entry that has one, else the mean height of the adjusted points
(<b>Flat terrain</b> forces the mean height).</li>
<li><b>Grid spacing</b> (m, default 10) and the <b>stereo pair</b> (two image ids; default the
first two images of the adjustment).</li>
</ul>
{project_help}
<h3>Writes</h3>
<ul>
<li><b>Equal-error map</b>: a 3-band Float32 GeoTIFF (band 1 sigma X, band 2 sigma Y, band 3
sigma Z, in m) in the ground CRS, nodata -9999 outside the stereo overlap: the
<code>equal_error.tif</code> of the command line.</li>
<li>Numbers: the nodes inside the overlap and the range of sigma H (horizontal,
sqrt(sx<sup>2</sup> + sy<sup>2</sup>)) and sigma Z (m).</li>
</ul>
"""

BAND_NAMES = ("sigma X (m)", "sigma Y (m)", "sigma Z (m)")
QUANTITY = ("a-posteriori standard deviation of a point intersected from the stereo pair "
            "(equal-error map)")


def write_equal_error_raster(grid, path, crs, nodata=None):
    """Write an equal-error grid as a 3-band Float32 raster with QGIS's GDAL.

    The same file as :func:`vectoradjust.files.derived_outputs.write_equal_error_map` (which uses
    rasterio and must not run inside QGIS): bands sigma X, Y, Z with their descriptions,
    nodata outside the overlap, the grid's geotransform, DEFLATE compression for a
    GeoTIFF, and the ``units`` / ``quantity`` metadata.

    Parameters
    ----------
    grid : vectoradjust.accuracy.derived.EqualErrorGrid
    path : str
        Output file; the format follows the extension (GeoTIFF by default).
    crs : QgsCoordinateReferenceSystem
    nodata : float, optional
        Default :data:`vectoradjust.files.derived_outputs.EQUAL_ERROR_NODATA`.

    Returns
    -------
    str
    """
    from vectoradjust.files.derived_outputs import EQUAL_ERROR_NODATA

    nodata = EQUAL_ERROR_NODATA if nodata is None else float(nodata)
    bands = np.stack([grid.sigma_x, grid.sigma_y, grid.sigma_z])
    a, b, c, dd, e, f = grid.transform  # Affine order -> GDAL geotransform
    return write_float_bands(path, bands, (c, a, b, f, dd, e), crs, BAND_NAMES, nodata,
                             {"units": "m", "quantity": QUANTITY}, "the equal-error map")


class EqualErrorMap(VectorAdjustAlgorithm):
    NAME = "equalerrormap"
    DISPLAY = "Equal-error map"
    SHORT = "Raster of sigma X, Y, Z of a point intersected from the stereo pair."
    HELP = HELP.replace("{project_help}", inputs.PROJECT_HELP)

    DEM = "DEM"
    FLAT = "FLAT"
    SPACING = "SPACING"
    IMAGE_PAIR = "IMAGE_PAIR"
    CLI_FLAGS = {"--images": IMAGE_PAIR, "--spacing": SPACING}
    OUTPUT = "OUTPUT"

    def initAlgorithm(self, config=None):
        advanced = QgsProcessingParameterDefinition.FlagAdvanced
        self.addParameter(QgsProcessingParameterRasterLayer(
            self.DEM, "DEM for the heights of the grid (default: the project's DEM)",
            optional=True))
        self.addParameter(QgsProcessingParameterNumber(
            self.SPACING, "Grid spacing [m]", QgsProcessingParameterNumber.Double,
            defaultValue=10.0, minValue=0.0))
        p = QgsProcessingParameterString(
            self.IMAGE_PAIR, "Stereo pair: two image ids, comma-separated (default: the first "
            "two images)", optional=True)
        p.setFlags(p.flags() | advanced)
        self.addParameter(p)
        p = QgsProcessingParameterBoolean(
            self.FLAT, "Flat terrain (the mean height of the adjusted points, no DEM)",
            defaultValue=False)
        p.setFlags(p.flags() | advanced)
        self.addParameter(p)
        inputs.add_project_parameters(self)
        self.addParameter(QgsProcessingParameterRasterDestination(
            self.OUTPUT, "Equal-error map (sigma X, Y, Z)"))
        for name, label in (("NODES", "Grid nodes inside the stereo overlap"),
                            ("SIGMA_H_MIN", "Smallest sigma H [m]"),
                            ("SIGMA_H_MAX", "Largest sigma H [m]"),
                            ("SIGMA_Z_MIN", "Smallest sigma Z [m]"),
                            ("SIGMA_Z_MAX", "Largest sigma Z [m]")):
            self.addOutput(QgsProcessingOutputNumber(name, label))

    def _pair(self, parameters, context):
        from vectoradjust.errors import ProjectError

        text = self.parameterAsString(parameters, self.IMAGE_PAIR, context).strip()
        if not text:
            return None
        pair = [t.strip() for t in text.replace(";", ",").split(",") if t.strip()]
        if len(pair) != 2:
            raise ProjectError(f"Stereo pair {text!r}: give two image ids",
                               "Write the two image ids separated by a comma, e.g. L,R")
        return pair

    def _heights(self, parameters, context, feedback, adj):
        """z(X, Y) for the grid: the DEM parameter, else the project's first DEM, or None."""
        if self.parameterAsBool(parameters, self.FLAT, context):
            return None, "the mean height of the adjusted points"
        dem = self.parameterAsRasterLayer(parameters, self.DEM, context)
        if dem is None:
            paths = [d.spec.dem for d in adj.run.databases if getattr(d.spec, "dem", None)]
            if not paths:
                return None, "the mean height of the adjusted points"
            dem = inputs.raster_from_path(paths[0], adj.prj.source)
        crs = adj.prj.crs

        def z(x, y):
            xy = np.column_stack([np.ravel(x), np.ravel(y)])
            return qgis_io.dem_heights(dem, xy, crs, context,
                                       f"DEM {dem.name()!r}").reshape(np.shape(x))

        return z, f"the DEM {dem.source()}"

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.accuracy import derived
        from vectoradjust.errors import ProjectError

        t0 = time.perf_counter()
        spacing = self.parameterAsDouble(parameters, self.SPACING, context)
        if not spacing > 0:
            raise ProjectError(f"Grid spacing {spacing:g} m is not positive",
                               "Give a spacing in metres, e.g. 10")
        pair = self._pair(parameters, context)
        adj = inputs.run_adjustment(self, parameters, context, feedback, road_optional=True,
                                    start=5.0, span=75.0)
        feedback.setProgressText("equal-error map")
        z, heights = self._heights(parameters, context, feedback, adj)
        grid = derived.equal_error_grid(adj.run, spacing, pair, z)
        rng = derived.equal_error_range(grid)
        path = self.parameterAsOutputLayer(parameters, self.OUTPUT, context)
        write_equal_error_raster(grid, path, adj.prj.crs)
        used = pair or adj.run.image_ids[:2]
        feedback.pushInfo(f"images {used[0]} and {used[1]}, {rng['nodes']} nodes at "
                          f"{spacing:g} m, heights from {heights}")
        for name in ("sigma_x", "sigma_y", "sigma_h", "sigma_z"):
            s = rng[name]
            feedback.pushInfo(f"{name}: min {_f(s['min'])}, max {_f(s['max'])}, mean "
                              f"{_f(s['mean'])} m")
        feedback.pushInfo(f"wrote {path} in {time.perf_counter() - t0:.1f} s")
        feedback.setProgress(100)
        return {self.OUTPUT: path, "NODES": rng["nodes"],
                "SIGMA_H_MIN": rng["sigma_h"]["min"], "SIGMA_H_MAX": rng["sigma_h"]["max"],
                "SIGMA_Z_MIN": rng["sigma_z"]["min"], "SIGMA_Z_MAX": rng["sigma_z"]["max"]}


def _f(v, nd=4):
    return "-" if v is None or not np.isfinite(v) else f"{float(v):.{nd}f}"
