"""Measure on the images: predicted positions and automatic transfer (NCC + LSM)."""

import os
from types import SimpleNamespace

import numpy as np
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsFeatureSink,
    QgsGeometry,
    QgsPointXY,
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFeatureSink,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterNumber,
    QgsWkbTypes,
)

from .. import qgis_io
from . import inputs
from .base import VectorAdjustAlgorithm, cancel_callback, check_cancelled, progress_callback

HELP = """
<p>Predicts where every control, check and shape point of a project falls on every image and,
given points measured on one image, finds them on the other images automatically, as
<code>vectoradjust measure predict / transfer</code> do. The prediction back-projects the point
through the approximate exterior orientation and the camera model (lens distortion, principal
point, pixel size) and propagates the uncertainty of the database / survey position and of the
orientation into a search ellipse (99.9 %). A transfer correlates the measured point's patch
with the other image resampled into its geometry (normalised cross-correlation inside the
ellipse), refines it by least-squares matching (affine geometry, linear and quadratic
radiometry) and flags every failure: low correlation, not converged, outside the window, poor
precision, edge of the image, no texture, ambiguous. A flagged match is never accepted.</p>
<h3>Needs</h3>
<ul>
<li><b>Project file</b> with the camera (<code>pixel_size</code>; <code>image_size</code> or
the image files give the size), <code>[[images]]</code> (approximate orientation and its
sigmas; <code>path</code> = the image file, needed for the transfer and the road junctions),
<code>[control]</code> and <code>[[vectors]]</code> (optional, with a DEM). Satellite images
with RPCs (<code>model = "rpc"</code>) are predicted through their RPCs (read with QGIS's
GDAL) and the bias priors; their image file is <code>path</code>, else the
<code>rpc</code> file when that is the image.</li>
<li><b>Measured points</b> (optional): a CSV <code>point_id,image_id,col,row</code> (pixels)
or the filled-in measurement template (<code>measured_col, measured_row</code>).</li>
<li><b>Locate road junctions</b>: shape points where three or more road directions meet, or
where a road turns by 30 degrees or more, are located on each image by the crossing of the
arms' centrelines (road width parameter). Vertices along straight roads, dead ends and roads
hidden or without contrast cannot be measured so; they stay predictions.</li>
</ul>
<h3>Writes</h3>
<ul>
<li><b>Points on the images</b>: one point layer in image pixel units (x = column,
y = -row, the way QGIS shows an image without georeferencing; fields <code>col</code>,
<code>row</code> are the pixel position) with <code>image_id</code>, <code>point_id</code>,
<code>kind</code>, <code>source</code> (predicted, manual, transferred, automatic),
<code>x_mm</code>, <code>y_mm</code>, the search ellipse <code>win_major</code>,
<code>win_minor</code>, <code>win_angle</code>, <code>ncc</code>, <code>rho</code>,
<code>sigma_px</code>, <code>flags</code> and <code>accepted</code>. Filter it by
<code>image_id</code> over each image and move the points that need it.</li>
<li><b>image_points.csv</b> (optional): the accepted measurements in the contract format
(photo mm, or pixels when the project's measurements are in pixels with fiducials), ready
for <i>Adjust road vectors</i>.</li>
</ul>
"""

FIELDS = ["image_id", "point_id", "kind", "source", "col", "row", "x_mm", "y_mm", "win_major",
          "win_minor", "win_angle", "ncc", "rho", "sigma_px", "flags", "accepted"]
TYPES = {"image_id": "s", "point_id": "s", "kind": "s", "source": "s", "flags": "s",
         "accepted": "i"}


def _ground_frame(spec, crs, context, feedback):
    """Read the RPCs of the project's RPC images (QGIS's GDAL) and return the ground
    frame (QGIS's transformations; None without RPC images), as ``vectoradjust measure``
    does with rasterio and pyproj."""
    if not spec.has_rpc:
        return None
    from ..rpc_io import read_rpc_images

    holder = SimpleNamespace(images=spec.images, ground_frame=None)
    read_rpc_images(holder, spec, crs, context.transformContext(), feedback.pushWarning)
    return holder.ground_frame


def _say_rpc(geoms, feedback):
    """One log line per RPC image: its bias and where it and the search window come from."""
    from vectoradjust.files.measure_rows import rpc_bias_line
    from vectoradjust.measure.geometry import RpcGeometry

    for iid, g in geoms.items():
        if isinstance(g, RpcGeometry):
            feedback.pushInfo(rpc_bias_line(iid, g))


class GdalImage:
    """Windowed reading of an image with QGIS's own GDAL (grey = mean of the bands)."""

    def __init__(self, path, image_id):
        from osgeo import gdal

        from vectoradjust.errors import InputFileError

        if not os.path.isfile(path):
            raise InputFileError(f"image {image_id!r}: file {path} does not exist",
                                 "Set path = in its [[images]] entry", path=path)
        self._ds = gdal.Open(path)
        if self._ds is None:
            raise InputFileError(f"image {image_id!r}: {path} cannot be read as a raster",
                                 "Give a TIFF, JPEG or JPEG 2000 image", path=path)
        self.size = (self._ds.RasterXSize, self._ds.RasterYSize)

    def read(self, col0, row0, width, height):
        out = np.full((height, width), np.nan)
        c0, r0 = max(col0, 0), max(row0, 0)
        c1, r1 = min(col0 + width, self.size[0]), min(row0 + height, self.size[1])
        if c1 > c0 and r1 > r0:
            a = np.asarray(self._ds.ReadAsArray(c0, r0, c1 - c0, r1 - r0), float)
            a = a.mean(axis=0) if a.ndim == 3 else a
            out[r0 - row0:r1 - row0, c0 - col0:c1 - col0] = a
        return out


class MeasureOnImages(VectorAdjustAlgorithm):
    NAME = "measureonimages"
    DISPLAY = "Measure on the images"
    SHORT = "Predicted image positions and automatic transfer of measured points."
    HELP = HELP

    PROJECT = "PROJECT"
    MEASURED = "MEASURED"
    ROADS = "ROADS"
    ROAD_WIDTH = "ROAD_WIDTH"
    MIN_NCC = "MIN_NCC"
    OUTPUT = "OUTPUT"
    IMAGE_POINTS = "IMAGE_POINTS"

    def initAlgorithm(self, config=None):
        self.addParameter(QgsProcessingParameterFile(
            self.PROJECT, "Project file (TOML)", extension="toml"))
        self.addParameter(QgsProcessingParameterFile(
            self.MEASURED, "Measured points (CSV: point_id, image_id, col, row in pixels)",
            extension="csv", optional=True))
        self.addParameter(QgsProcessingParameterBoolean(
            self.ROADS, "Locate road junctions and corners automatically", defaultValue=False))
        self.addParameter(QgsProcessingParameterNumber(
            self.ROAD_WIDTH, "Road surface width [m]", QgsProcessingParameterNumber.Double,
            defaultValue=6.0, minValue=0.5))
        self.addParameter(QgsProcessingParameterNumber(
            self.MIN_NCC, "Correlation threshold (0.8 - 0.95)",
            QgsProcessingParameterNumber.Double, defaultValue=0.8, minValue=0.0, maxValue=1.0))
        self.addParameter(QgsProcessingParameterFeatureSink(
            self.OUTPUT, "Points on the images (pixel units)", QgsProcessing.TypeVectorPoint))
        self.addParameter(QgsProcessingParameterFileDestination(
            self.IMAGE_POINTS, "image_points.csv (accepted measurements, photo mm)",
            "CSV files (*.csv)", optional=True, createByDefault=False))
        self.addOutput(QgsProcessingOutputNumber("PREDICTED", "Predicted positions"))
        self.addOutput(QgsProcessingOutputNumber("ACCEPTED", "Accepted automatic measurements"))
        self.addOutput(QgsProcessingOutputNumber("FLAGGED", "Flagged automatic measurements"))

    def _inputs(self, parameters, context, feedback):
        from vectoradjust.files.csv_tables import read_control
        from vectoradjust.files.measure_rows import control_height, height_from_samples
        from vectoradjust.files.measuring import image_geometries, project_points
        from vectoradjust.files.project import load_project

        spec = load_project(self.parameterAsFile(parameters, self.PROJECT, context))
        where = str(spec.path)
        crs = qgis_io.ground_crs(spec.crs, f"{where}: crs")
        inputs._refuse_datums(spec)
        control = read_control(spec.control["path"]) if spec.control is not None else None
        readers = {}
        for entry in spec.raw.get("images", []):
            if isinstance(entry, dict) and entry.get("path"):
                p = str(entry["path"])
                p = p if os.path.isabs(p) else os.path.join(str(spec.base_dir), p)
                readers[str(entry["id"])] = GdalImage(p, str(entry["id"]))
        for im in spec.images:  # an RPC image's rpc file may be the image itself
            if im.id not in readers and im.model == "rpc" and im.rpc.path and \
                    os.path.splitext(str(im.rpc.path))[1].lower() not in (".txt", ".rpb"):
                readers[im.id] = GdalImage(str(im.rpc.path), im.id)
        frame = _ground_frame(spec, crs, context, feedback)
        prj = SimpleNamespace(crs=crs, source=where)
        layers, dem = [], None
        for entry in spec.vectors:
            check_cancelled(feedback)
            e, layer, _ = inputs.read_project_entry(prj, entry, context, feedback)
            layers.append((e, layer))
            if dem is None and e.dem:
                dem = inputs.raster_from_path(e.dem, where)
        height = None
        if dem is not None:
            height = height_from_samples(
                lambda xy, dem=dem: qgis_io.dem_heights(dem, xy, crs, context,
                                                        f"DEM {dem.name()!r}"))
        points = project_points(control, layers, spec.settings.merge_tolerance)
        fiducials = None
        if spec.measurements.get("fiducials") and spec.measurements.get("unit") == "pixel":
            from vectoradjust.files.csv_tables import read_fiducials

            fiducials = read_fiducials(spec.measurements["fiducials"], "pixel")
        geoms = image_geometries(spec, image_sizes={k: r.size for k, r in readers.items()},
                                 control=control, fiducials=fiducials, ground_frame=frame)
        _say_rpc(geoms, feedback)
        if height is None:
            height = control_height(control)
        return spec, geoms, readers, points, height

    def run_algorithm(self, parameters, context, feedback):
        from vectoradjust.files.images import read_pixel_table
        from vectoradjust.files.measuring import image_points, measure_roads, predict, transfer
        from vectoradjust.measure.transfer import MatchSettings

        spec, geoms, readers, points, height = self._inputs(parameters, context, feedback)
        cancel = cancel_callback(feedback)
        pred = predict(geoms, points, progress=progress_callback(feedback, 10, 20),
                       is_cancelled=cancel)
        measured_path = self.parameterAsFile(parameters, self.MEASURED, context)
        roads = self.parameterAsBoolean(parameters, self.ROADS, context)
        missing = [i for i in geoms if i not in readers]
        if (measured_path or roads) and missing:
            raise QgsProcessingException(
                f"The transfer and the road junctions need the image files; [[images]] "
                f"{', '.join(missing)} have no path = \"image.tif\" in {spec.path}")
        measured = read_pixel_table(measured_path) if measured_path else None
        res = auto = None
        if measured is not None:
            st = MatchSettings(min_ncc=self.parameterAsDouble(parameters, self.MIN_NCC, context))
            res = transfer(geoms, readers, measured, height, st,
                           progress=progress_callback(feedback, 30, 40), is_cancelled=cancel)
        if roads:
            auto = measure_roads(geoms, readers, points,
                                 self.parameterAsDouble(parameters, self.ROAD_WIDTH, context),
                                 progress=progress_callback(feedback, 70, 20),
                                 is_cancelled=cancel)
        dest = self._write_layer(parameters, context, geoms, pred, measured, res, auto)
        out = {self.OUTPUT: dest, "PREDICTED": len(pred["point_id"])}
        n_acc = sum(int(t["accepted"].sum()) for t in (res, auto) if t is not None)
        n_all = sum(len(t["accepted"]) for t in (res, auto) if t is not None)
        out.update({"ACCEPTED": n_acc, "FLAGGED": n_all - n_acc})
        ip_path = self.parameterAsFileOutput(parameters, self.IMAGE_POINTS, context)
        if ip_path:
            from vectoradjust.files.images import write_table

            ip = image_points(geoms, measured, res, auto,
                              unit=spec.measurements.get("unit", "mm"))
            write_table(ip_path, ip, ["point_id", "image_id", "x", "y", "sigma_x", "sigma_y"])
            out[self.IMAGE_POINTS] = ip_path
        feedback.pushInfo(f"{len(pred['point_id'])} predicted positions on {len(geoms)} "
                          f"images; automatic measurements: {n_acc} accepted, "
                          f"{n_all - n_acc} flagged")
        return out

    def _write_layer(self, parameters, context, geoms, pred, measured, res, auto):
        fields = qgis_io.fields_for(FIELDS, TYPES)
        sink, dest = self.parameterAsSink(parameters, self.OUTPUT, context, fields,
                                          QgsWkbTypes.Point, QgsCoordinateReferenceSystem(),
                                          QgsFeatureSink.RegeneratePrimaryKey)
        if sink is None:
            raise QgsProcessingException(self.invalidSinkError(parameters, self.OUTPUT))
        from vectoradjust.files.measure_rows import measurement_rows

        for r in measurement_rows(geoms, pred, measured, res, auto):
            col, row = float(r["col"]), float(r["row"])
            geom = (QgsGeometry.fromPointXY(QgsPointXY(col, -row)) if np.isfinite(col)
                    else QgsGeometry())
            sink.addFeature(qgis_io.new_feature(fields, [r.get(k) for k in FIELDS], geom),
                            QgsFeatureSink.FastInsert)
        return dest
