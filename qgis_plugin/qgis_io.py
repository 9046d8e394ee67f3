"""QGIS layers, tables and rasters -> the core's arrays; core tables -> QGIS features.

This is the QGIS twin of :mod:`vectoradjust.files.readers` (which uses geopandas and rasterio and
must never be imported inside QGIS: they bring a second GDAL). Everything is read
through the QGIS API and handed to the numerical core as numpy arrays, with the same
semantics as the headless reader:

* a road layer becomes a :class:`vectoradjust.model.LineLayer`: vertices of all
  features in order, the vertex index 0-based along a feature and continuing across
  parts, null/empty geometries kept as features without vertices (``problems``),
  ids from the id field (integral floats written without ``.0``) or the 0-based
  feature index;
* DEM heights by :func:`vectoradjust.adjust.dem.bilinear` on band 1 read with
  ``QgsRasterDataProvider.block``;
* measurement and control tables through :mod:`vectoradjust.files.csv_tables` (a CSV file is
  read by it directly; a table layer's contract columns go to its ``*_from_rows``
  functions, the same checks, with messages naming the layer and the row).

User mistakes raise the core's :class:`~vectoradjust.errors.VectorAdjustError`
subclasses, naming the layer, field or feature; the algorithms turn them into
``QgsProcessingException``.
"""

import math
import os

import numpy as np
from qgis.core import (
    Qgis,
    QgsCoordinateReferenceSystem,
    QgsCoordinateTransform,
    QgsFeature,
    QgsFeatureRequest,
    QgsField,
    QgsFields,
    QgsGeometry,
    QgsLineString,
    QgsMultiLineString,
    QgsPoint,
    QgsPointXY,
    QgsProviderRegistry,
    QgsRectangle,
    QgsUnitTypes,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QDate, QDateTime, QTime, QVariant

from vectoradjust.errors import CRSError, DEMError, LayerError
from vectoradjust.model import LineLayer

__all__ = [
    "ground_crs",
    "check_ground_crs",
    "layer_path",
    "read_line_source",
    "dem_heights",
    "table_rows",
    "read_measurements_source",
    "read_control_source",
    "read_truth_source",
    "fields_for",
    "FULL_READ_MAX_CELLS",
]

#: rasters with at most this many cells are read whole; larger ones only in the window
#: around the vertices (same heights up to rounding of the window origin, ~1e-12 m)
FULL_READ_MAX_CELLS = 1 << 24


# --------------------------------------------------------------------------- values
def is_null(v):
    """Whether a QGIS attribute value is NULL (QVariant NULL or None)."""
    if v is None:
        return True
    if isinstance(v, QVariant):
        return v.isNull()
    return False


def py_value(v):
    """An attribute value as plain Python (None for NULL, ISO text for dates)."""
    if is_null(v):
        return None
    if isinstance(v, QVariant):
        v = v.value()
    if isinstance(v, QDateTime):
        return v.toString("yyyy-MM-ddTHH:mm:ss")
    if isinstance(v, QDate):
        return v.toString("yyyy-MM-dd")
    if isinstance(v, QTime):
        return v.toString("HH:mm:ss")
    return v


def id_text(v):
    """Feature id text as the headless reader writes it (``12.0`` -> ``"12"``)."""
    v = py_value(v)
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return str(v)


#: reals at or beyond this magnitude are not every integer
_EXACT_REAL_INTEGER = 2 ** 53


def _check_exact_id(v, where, id_field):
    """An id that QGIS gives as a real beyond 2^53 may not be the one in the file (a
    shapefile integer field wider than 18 digits, read as reals): a clear error."""
    v = py_value(v)
    if isinstance(v, float) and abs(v) >= _EXACT_REAL_INTEGER:
        raise LayerError(
            f"{where}: the ids of field {id_field!r} are read as real numbers beyond 2^53 "
            f"(e.g. {v:.17g}), where a real cannot hold every integer: the ids read may not "
            "be those in the file",
            "Store the ids as text or as integers in a GeoPackage; a shapefile whose id field "
            "is wider than 18 digits can be opened with the OGR option ADJUST_TYPE=YES "
            "(path|option:ADJUST_TYPE=YES), which reads it as 64-bit integers")


def shapefile_uri(path, layer=None):
    """The OGR URI of a vector file: a shapefile with an integer field wider than 18
    digits (which GDAL reads as reals) opened with ``ADJUST_TYPE=YES``, so that its ids
    come as exact 64-bit integers, as the command line reads them."""
    from qgis.core import QgsVectorLayer

    uri = f"{path}|layername={layer}" if layer else str(path)
    if not str(path).lower().endswith(".shp"):
        return uri
    probe = QgsVectorLayer(uri, "probe", "ogr")
    wide = [f for f in probe.fields() if f.type() == QVariant.Double and f.precision() == 0
            and f.length() > 18]
    return f"{uri}|option:ADJUST_TYPE=YES" if wide else uri


def cell_text(v):
    """An attribute value as the text a CSV cell would hold (floats round-trip exactly)."""
    v = py_value(v)
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else str(v)
    return str(v)


# --------------------------------------------------------------------------- CRS
def check_ground_crs(crs, where):
    """Require a valid projected CRS in metres (the adjustment's ground frame).

    Returns the CRS; raises :class:`CRSError` naming ``where`` otherwise.
    """
    if crs is None or not crs.isValid():
        raise CRSError(f"{where}: no valid coordinate reference system",
                       'Give a projected CRS in metres, e.g. "EPSG:32616"')
    if crs.isGeographic():
        raise CRSError(
            f"{where}: the CRS {crs.authid() or crs.description()!r} is geographic (degrees); "
            "the adjustment needs a projected CRS in metres",
            "Choose the local projected CRS (e.g. the UTM zone) as the ground CRS",
        )
    if crs.mapUnits() != QgsUnitTypes.DistanceMeters:
        raise CRSError(
            f"{where}: the CRS {crs.authid() or crs.description()!r} has units of "
            f"{QgsUnitTypes.toString(crs.mapUnits())}, not metres",
            "Choose a projected CRS in metres as the ground CRS",
        )
    return crs


def ground_crs(text, where):
    """Parse a CRS string of a project file (``"EPSG:32616"``, WKT, PROJ)."""
    crs = QgsCoordinateReferenceSystem(str(text))
    if not crs.isValid():
        raise CRSError(f"{where}: the CRS {str(text)[:80]!r} is not understood",
                       'Give an EPSG code such as "EPSG:32616"')
    return check_ground_crs(crs, where)


def layer_path(layer):
    """File path of a file-based layer (None for memory/database layers)."""
    if layer is None:
        return None
    try:
        parts = QgsProviderRegistry.instance().decodeUri(layer.providerType(), layer.source())
    except Exception:  # providers without decodeUri support
        parts = {}
    path = parts.get("path") if parts else None
    if not path:
        src = layer.source().split("|")[0]
        path = src if os.path.exists(src) else None
    return path


def _transform(src_crs, dst_crs, context):
    if src_crs == dst_crs:
        return None
    return QgsCoordinateTransform(src_crs, dst_crs, context.transformContext())


# --------------------------------------------------------------------------- lines
def _line_parts(geom):
    """The line parts of a geometry as (n, 3) arrays (Z NaN for 2D)."""
    g = geom.constGet()
    if QgsWkbTypes.isMultiType(g.wkbType()):
        parts = [g.geometryN(k) for k in range(g.numGeometries())]
    else:
        parts = [g]
    out = []
    for p in parts:
        if not isinstance(p, QgsLineString):
            p = p.curveToLine() if hasattr(p, "curveToLine") else None
            if p is None:
                out.append(None)
                continue
        n = p.numPoints()
        xyz = np.empty((n, 3))
        has_z = QgsWkbTypes.hasZ(p.wkbType())
        for k in range(n):
            xyz[k, 0] = p.xAt(k)
            xyz[k, 1] = p.yAt(k)
            xyz[k, 2] = p.zAt(k) if has_z else np.nan
        out.append(xyz)
    return out


def read_line_source(source, name, id_field, target_crs, context, where, feedback=None):
    """Flatten a line feature source to a :class:`LineLayer` in ``target_crs``.

    Parameters
    ----------
    source : QgsProcessingFeatureSource or QgsVectorLayer
    name : str
        Database name.
    id_field : str or None
        Field holding the feature ids; None for the 0-based feature index.
    target_crs : QgsCoordinateReferenceSystem
        Ground CRS (the vertices are transformed to it).
    context : QgsProcessingContext
    where : str
        How messages name the layer.

    Returns
    -------
    layer : LineLayer
    fields : QgsFields
        The source's fields (for the features output).

    Raises
    ------
    LayerError
        Not a line layer, unknown id field, empty or duplicate ids.
    CRSError
        Layer without CRS.
    """
    wkb = source.wkbType()
    src_crs, fields, id_idx = _check_line_source(source, wkb, id_field, where)
    request = QgsFeatureRequest()
    if src_crs != target_crs:
        request.setDestinationCrs(target_crs, context.transformContext())
    names = fields.names()
    attributes = {n: [] for n in names}
    ids = []
    problems = {}
    vertices = ([], [], [], [])  # coordinates, feature, vertex index, part of each vertex
    for i, f in enumerate(source.getFeatures(request)):
        if feedback is not None and i % 1000 == 0:
            _check_cancelled(feedback)
        attrs = f.attributes()
        for n, v in zip(names, attrs):
            attributes[n].append(None if is_null(v) else v)  # NULL -> None, as headless
        if id_idx >= 0:
            v = attrs[id_idx]
            if is_null(v):
                raise LayerError(f"{where}: feature {i} (fid {f.id()}) has no value in id field "
                                 f"{id_field!r}",
                                 "Give every feature an id, or leave the id field empty to use "
                                 "the feature index")
            _check_exact_id(v, where, id_field)
            ids.append(id_text(v))
        else:
            ids.append(str(i))
        problem = _feature_vertices(i, f.geometry(), vertices)
        if problem:
            problems[i] = problem
    if id_idx >= 0 and ids:
        u, c = np.unique(np.asarray(ids, dtype=object).astype(str), return_counts=True)
        if np.any(c > 1):
            raise LayerError(f"{where}: the id {u[c > 1][0]!r} of field {id_field!r} is used by "
                             f"{int(c[c > 1][0])} features",
                             "Use a field with unique values as the id field")
    layer = LineLayer.from_parts(name, np.asarray(ids, dtype=object).astype(str), attributes,
                                 *vertices, problems, target_crs.toWkt(), where,
                                 QgsWkbTypes.displayString(wkb))
    return layer, fields


def _check_line_source(source, wkb, id_field, where):
    """The source's CRS, fields and the index of ``id_field`` (-1 for none); a source
    without lines or CRS, or an unknown id field, is an error."""
    if QgsWkbTypes.geometryType(wkb) != QgsWkbTypes.LineGeometry:
        raise LayerError(
            f"{where}: the layer holds {QgsWkbTypes.displayString(wkb) or 'no'} geometries, "
            "not lines",
            "Give the road centrelines as a line layer (LineString or MultiLineString)")
    src_crs = source.sourceCrs()
    if not src_crs.isValid():
        raise CRSError(f"{where}: the layer has no coordinate reference system",
                       "Set the layer's CRS (Layer Properties > Source, or a .prj file) and "
                       "run again")
    fields = source.fields()
    id_idx = -1
    if id_field:
        id_idx = fields.indexFromName(id_field)
        if id_idx < 0:
            raise LayerError(
                f"{where}: id field {id_field!r} is not a field of the layer (fields: "
                f"{', '.join(fields.names()) or 'none'})",
                "Choose an existing field with unique values as the id field, or leave it empty "
                "to use the feature index")
    return src_crs, fields, id_idx


def _feature_vertices(i, geom, vertices):
    """Append the vertices of feature ``i`` (coordinates, feature, vertex index along the
    feature across its parts, part) to the four lists of ``vertices``; returns the
    feature's problem (null, not a line, empty) or None."""
    if geom is None or geom.isNull():
        return "null geometry"
    if QgsWkbTypes.geometryType(geom.wkbType()) != QgsWkbTypes.LineGeometry:
        return f"geometry type {QgsWkbTypes.displayString(geom.wkbType())} is not a line"
    if geom.isEmpty():
        return "empty geometry"
    coords, vf, vi, vp = vertices
    count = 0
    for pnum, xyz in enumerate(_line_parts(geom)):
        if xyz is None or len(xyz) == 0:
            continue
        coords.append(xyz)
        vf.append(np.full(len(xyz), i))
        vi.append(count + np.arange(len(xyz)))
        vp.append(np.full(len(xyz), pnum))
        count += len(xyz)
    return None if count else "empty geometry"


def _check_cancelled(feedback):
    from .algorithms.base import check_cancelled

    check_cancelled(feedback)


# --------------------------------------------------------------------------- DEM
def _numpy_dtype(qgis_type):
    table = {
        Qgis.DataType.Byte: np.uint8,
        Qgis.DataType.UInt16: np.uint16,
        Qgis.DataType.Int16: np.int16,
        Qgis.DataType.UInt32: np.uint32,
        Qgis.DataType.Int32: np.int32,
        Qgis.DataType.Float32: np.float32,
        Qgis.DataType.Float64: np.float64,
    }
    return table.get(qgis_type)


def _read_block(provider, band, extent, ncol, nrow, where):
    block = provider.block(band, extent, ncol, nrow)
    if block is None or not block.isValid() or block.width() != ncol or block.height() != nrow:
        raise DEMError(f"{where}: band {band} could not be read",
                       "Check that the raster file is readable (open it in QGIS)")
    dtype = _numpy_dtype(block.dataType())
    if dtype is None:
        raise DEMError(f"{where}: band {band} has the data type {int(block.dataType())}, which is "
                       "not a plain integer or float type",
                       "Convert the DEM to Float32 (Raster > Conversion > Translate)")
    raw = bytes(block.data())
    return np.frombuffer(raw, dtype=dtype, count=ncol * nrow).reshape(nrow, ncol).astype(float)


def dem_heights(raster, xy, xy_crs, context, where, band=1, report=None):
    """Heights of a DEM raster layer at ``xy`` by bilinear interpolation.

    Mirrors :func:`vectoradjust.files.readers.sample_dem`: points are transformed to the DEM's
    CRS when it differs, and uncovered points (outside, next to nodata) get NaN.

    Parameters
    ----------
    raster : QgsRasterLayer
    xy : numpy.ndarray, shape (n, 2)
        Points in ``xy_crs``.
    xy_crs : QgsCoordinateReferenceSystem
    context : QgsProcessingContext
    where : str
        How messages name the DEM.
    band : int
        Band number (1-based).
    report : dict, optional
        Receives ``"grid"``, the block read as a :class:`vectoradjust.model.DemGrid`, when
        the DEM is in ``xy_crs`` (heights at an estimated offset's shifted positions).

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    from vectoradjust.adjust.dem import bilinear

    if raster is None or not raster.isValid():
        raise DEMError(f"{where}: the raster cannot be read", "Give a readable DEM (GeoTIFF)")
    provider = raster.dataProvider()
    if band < 1 or band > provider.bandCount():
        raise DEMError(f"{where}: the raster has {provider.bandCount()} band(s), no band {band}",
                       "Use band 1 of a single-band DEM")
    dem_crs = raster.crs()
    if not dem_crs.isValid():
        raise CRSError(f"{where}: the DEM has no coordinate reference system",
                       "Assign the CRS to the raster (Layer Properties > Source, or "
                       "gdal_edit.py -a_srs)")
    pts = np.asarray(xy, float).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros(0)
    ct = _transform(xy_crs, dem_crs, context)
    if ct is not None:
        pts = _points_to(ct, pts)
    window = _dem_window(provider, band, pts, where)
    if window is None:  # no finite point in a large raster
        return np.full(len(pts), np.nan)
    grid, transform, nodata = window
    if report is not None and ct is None:
        from vectoradjust.model import DemGrid

        report["grid"] = DemGrid(grid, transform, nodata)
    return bilinear(grid, transform, pts, nodata=nodata)


def _points_to(ct, pts):
    """``pts`` transformed by the QgsCoordinateTransform ``ct``; NaN where a point is not
    finite or cannot be transformed (uncovered)."""
    out = np.full_like(pts, np.nan)
    for k, (x, y) in enumerate(pts):
        if np.isfinite(x) and np.isfinite(y):
            try:
                p = ct.transform(QgsPointXY(float(x), float(y)))
            except Exception:  # QgsCsException: leave NaN (uncovered)
                continue
            out[k] = (p.x(), p.y())
    return out


def _dem_window(provider, band, pts, where):
    """The DEM cells around ``pts`` (DEM CRS): the whole raster up to
    :data:`FULL_READ_MAX_CELLS` cells, else the window around the finite points (None when
    there is none). Returns ``(grid, GDAL-order transform, nodata)``: the source's nodata
    value, as rasterio reports it to the headless reader; user nodata ranges set in QGIS
    are NaN in ``grid``."""
    ext = provider.extent()
    ncol, nrow = provider.xSize(), provider.ySize()
    if ncol < 1 or nrow < 1:
        raise DEMError(f"{where}: the raster is empty", "Give a DEM with cells")
    x0, y0 = ext.xMinimum(), ext.yMaximum()
    dx = (ext.xMaximum() - x0) / ncol
    dy = (y0 - ext.yMinimum()) / nrow
    if ncol * nrow <= FULL_READ_MAX_CELLS:
        r_lo, r_hi, c_lo, c_hi = 0, nrow - 1, 0, ncol - 1
    else:
        from vectoradjust.adjust.dem import cell_window

        window = cell_window((x0, dx, 0.0, y0, 0.0, -dy), (nrow, ncol), pts)
        if window is None:
            return None
        r_lo, r_hi, c_lo, c_hi = window
    wc, wr = c_hi - c_lo + 1, r_hi - r_lo + 1
    wx0 = x0 + c_lo * dx if c_lo else x0
    wy0 = y0 - r_lo * dy if r_lo else y0
    extent = QgsRectangle(wx0, y0 - (r_hi + 1) * dy if r_hi < nrow - 1 else ext.yMinimum(),
                          x0 + (c_hi + 1) * dx if c_hi < ncol - 1 else ext.xMaximum(), wy0)
    grid = _read_block(provider, band, extent, wc, wr, where)
    nodata = None
    if provider.sourceHasNoDataValue(band):
        nodata = float(provider.sourceNoDataValue(band))
    for rng in provider.userNoDataValues(band):
        grid[(grid >= rng.min()) & (grid <= rng.max())] = np.nan
    return grid, (wx0, dx, 0.0, wy0, 0.0, -dy), nodata


# --------------------------------------------------------------------------- tables
def table_rows(source, columns=None):
    """Header and text rows of a feature source's attribute table.

    Parameters
    ----------
    source : QgsFeatureSource
    columns : sequence of str, optional
        Keep only these columns (matched case-insensitively, as the CSV readers do);
        other attributes of a layer are ignored.

    Returns
    -------
    header : list of str
    rows : list of list of str
    """
    names = source.fields().names()
    keep = list(range(len(names)))
    if columns is not None:
        wanted = {c.lower() for c in columns}
        keep = [j for j, n in enumerate(names) if n.lower() in wanted]
    header = [names[j] for j in keep]
    rows = []
    for f in source.getFeatures():
        a = f.attributes()
        rows.append([cell_text(a[j]) for j in keep])
    return header, rows


def _row_numbers(rows):
    """Row numbers of a layer's rows in messages: 1 = the first feature."""
    return range(1, len(rows) + 1)


def is_csv_path(value):
    """Whether a parameter value is a path to a CSV/text file (read by the core directly)."""
    return (isinstance(value, str) and os.path.isfile(value)
            and value.lower().endswith((".csv", ".txt")))


def read_measurements_source(value, source, default_sigma, where, unit="mm"):
    """Measurements from a CSV path (``tables.read_measurements``) or a table source
    (as read: not refined yet; ``unit`` as ``[measurements] unit``)."""
    from vectoradjust.files import csv_tables as tables

    if is_csv_path(value):
        return tables.read_measurements(value, default_sigma, unit=unit)
    header, rows = table_rows(source, tables.MEASUREMENT_COLUMNS + tables.MEASUREMENT_OPTIONAL)
    return tables.measurements_from_rows(header, rows, where, default_sigma, unit,
                                         lines=_row_numbers(rows), line_word="row")


def read_control_source(value, source, target_crs, context, where):
    """Control/check points from a CSV path or a table/point layer.

    A layer's ``X``, ``Y`` (and ``Z``) fields are used when present (surveyed
    coordinates in the ground CRS); without ``X``/``Y`` fields the point geometry is
    transformed to the ground CRS and used (Z from the geometry when the layer has no
    ``Z`` field).
    """
    from vectoradjust.files import csv_tables as tables

    if is_csv_path(value):
        return tables.read_control(value)
    cols = tables.CONTROL_COLUMNS + tables.CONTROL_OPTIONAL
    lower = {n.lower() for n in source.fields().names()}
    if {"x", "y"} <= lower:
        header, rows = table_rows(source, cols)
        return tables.control_from_rows(header, rows, where, lines=_row_numbers(rows),
                                        line_word="row")
    if QgsWkbTypes.geometryType(source.wkbType()) != QgsWkbTypes.PointGeometry:
        raise LayerError(f"{where}: the control table has no X and Y fields and no point "
                         "geometry", "Add X, Y, Z fields (ground CRS) or give a point layer")
    if not source.sourceCrs().isValid():
        raise CRSError(f"{where}: the layer has no coordinate reference system",
                       "Set the layer's CRS and run again, or add X, Y fields")
    names = source.fields().names()
    keep = [j for j, n in enumerate(names) if n.lower() in {c.lower() for c in cols}]
    use_z_field = "z" in lower
    header = [names[j] for j in keep] + ["X", "Y"] + ([] if use_z_field else ["Z"])
    request = QgsFeatureRequest()
    if source.sourceCrs() != target_crs:
        request.setDestinationCrs(target_crs, context.transformContext())
    rows = []
    for i, f in enumerate(source.getFeatures(request)):
        g = f.geometry()
        if g is None or g.isNull() or g.isEmpty():
            raise LayerError(f"{where}: feature {i} (fid {f.id()}) has no geometry",
                             "Give every control point a position")
        p = g.constGet()
        if QgsWkbTypes.isMultiType(p.wkbType()):
            p = p.geometryN(0)
        a = f.attributes()
        row = [cell_text(a[j]) for j in keep] + [repr(float(p.x())), repr(float(p.y()))]
        if not use_z_field:
            z = p.z() if QgsWkbTypes.hasZ(p.wkbType()) else float("nan")
            row.append(repr(float(z)) if math.isfinite(z) else "")
        rows.append(row)
    return tables.control_from_rows(header, rows, where, lines=_row_numbers(rows),
                                    line_word="row")


def read_truth_source(value, source, where):
    """Truth points ``point_id,X,Y,Z`` from a CSV path or a table layer."""
    from vectoradjust.files import csv_tables as tables

    if is_csv_path(value):
        return tables.read_truth_points(value)
    header, rows = table_rows(source, ("point_id", "X", "Y", "Z"))
    return tables.truth_from_rows(header, rows, where, lines=_row_numbers(rows),
                                  line_word="row")


# --------------------------------------------------------------------------- output
_FLOAT, _INT, _TEXT = QVariant.Double, QVariant.LongLong, QVariant.String
#: width of a 64-bit integer field: GDAL reads a wider shapefile field as real numbers
SHAPEFILE_INTEGER_WIDTH = 18


def fields_for(columns, types):
    """QgsFields with the given names; ``types`` maps name -> 'f', 'i' or 's'."""
    fields = QgsFields()
    for c in columns:
        t = types.get(c, "f")
        if t == "i":  # 18 digits: a shapefile reads the field back as 64-bit integers
            fields.append(QgsField(c, _INT, "int8", SHAPEFILE_INTEGER_WIDTH))
        elif t == "s":
            fields.append(QgsField(c, _TEXT))
        else:
            fields.append(QgsField(c, _FLOAT, "double"))
    return fields


def variant(v):
    """A numpy value as an attribute value (NaN -> NULL)."""
    if v is None:
        return None
    if isinstance(v, (np.floating, float)):
        v = float(v)
        return v if math.isfinite(v) else None
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return int(bool(v))
    if isinstance(v, np.str_):
        return str(v)
    return v


def point_z(x, y, z):
    """A Point Z geometry (Z 0 where unknown, as the headless writer does)."""
    z = float(z)
    return QgsGeometry(QgsPoint(float(x), float(y), z if math.isfinite(z) else 0.0))


def line_z(xyz_parts, multi):
    """A LineString Z / MultiLineString Z geometry from (n, 3) arrays (Z NaN -> 0)."""
    lines = []
    for xyz in xyz_parts:
        if len(xyz) < 2:
            continue
        z = np.nan_to_num(xyz[:, 2], nan=0.0)
        lines.append(QgsLineString([QgsPoint(float(a), float(b), float(c))
                                    for a, b, c in zip(xyz[:, 0], xyz[:, 1], z)]))
    if not lines:
        return QgsGeometry()
    if multi:
        mls = QgsMultiLineString()
        for ls in lines:
            mls.addGeometry(ls)
        return QgsGeometry(mls)
    return QgsGeometry(lines[0])


def new_feature(fields, values, geometry=None):
    """A QgsFeature with the given attribute values (converted) and geometry."""
    f = QgsFeature(fields)
    f.setAttributes([variant(v) for v in values])
    if geometry is not None:
        f.setGeometry(geometry)
    return f
