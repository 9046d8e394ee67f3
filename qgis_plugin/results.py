"""The adjustment's tables as QGIS features, mirroring :mod:`vectoradjust.files.outputs`.

The layers have the contract's fields (``docs/method.md`` section 9; the field lists are
imported from :mod:`vectoradjust.files.outputs`, whose geopandas writers are never called
here) and the same nulls: floats that are NaN become NULL, and the per-point
statistics of unmeasured vertices are NULL. Geometries are Z-aware; an unknown Z is
written as 0, as the headless writer does.
"""

import json
import math
import os
import re

import numpy as np
from qgis.core import (
    QgsCoordinateTransformContext,
    QgsFeatureSink,
    QgsField,
    QgsFields,
    QgsVectorFileWriter,
    QgsWkbTypes,
)
from qgis.PyQt.QtCore import QVariant

from .qgis_io import SHAPEFILE_INTEGER_WIDTH, fields_for, is_null, line_z, new_feature, point_z

_SHAPE_TYPES = {"point_id": "s", "feature_id": "s", "Database": "s", "NImages": "i",
                "Adjusted": "i", "Source": "s", "Problem": "s"}
_FEATURE_TYPES = {"NPts": "i", "NAdj": "i", "Images": "s", "ImgDate": "s", "Database": "s",
                  "Problem": "s", "LengthSDOf": "s"}
_CONTROL_TYPES = {"point_id": "s", "role": "s", "NImages": "i", "Used": "i"}
_MASKED = ("Vx", "Vy", "Vz", "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "CE90_meas",
           "LE90_meas")

RESIDUAL_FIELDS = ["point_id", "feature_id", "Database", "Vx", "Vy", "Vz", "V", "Azimuth",
                   "CE90", "LE90", "Scale"]
_RESIDUAL_TYPES = {"point_id": "s", "feature_id": "s", "Database": "s"}


def _outputs_module():
    from vectoradjust.files import outputs

    return outputs


# --------------------------------------------------------------------------- fields
def shape_fields():
    """Fields of the ``shape_points`` layer."""
    return fields_for(_outputs_module().SHAPE_FIELDS, _SHAPE_TYPES)


def _control_columns(run=None):
    """The ``control_points`` columns: the contract's, plus ``QA`` when the run has it
    (as the headless writer adds it)."""
    cols = list(_outputs_module().CONTROL_FIELDS)
    if run is not None and "QA" in run.control_points:
        cols.append("QA")
    return cols


def _kind(values):
    kind = np.asarray(values).dtype.kind
    return "f" if kind == "f" else "i" if kind in "iub" else "s"


def control_fields(run=None):
    """Fields of the ``control_points`` layer."""
    types = dict(_CONTROL_TYPES)
    if run is not None and "QA" in run.control_points:
        types["QA"] = _kind(run.control_points["QA"])
    return fields_for(_control_columns(run), types)


def residual_fields():
    """Fields of the residual vectors layer."""
    return fields_for(RESIDUAL_FIELDS, _RESIDUAL_TYPES)


def feature_fields(input_fields):
    """Fields of the ``features`` layer: every input field, then the contract's.

    Input fields whose names clash with ours case-insensitively (or ``geometry``/``fid``)
    are renamed as the headless writer renames them
    (:func:`vectoradjust.files.outputs.renamed_input_fields`: ``length`` -> ``in_length``).
    """
    outputs = _outputs_module()
    ours = outputs.FEATURE_FIELDS
    renamed = outputs.renamed_input_fields([f.name() for f in input_fields])
    fields = QgsFields()
    for f in input_fields:
        g = QgsField(f)
        if f.name() in renamed:
            g.setName(renamed[f.name()])
        fields.append(g)
    for f in fields_for(ours, _FEATURE_TYPES):
        fields.append(f)
    return fields


#: the :data:`vectoradjust.files.outputs.FIELD_KINDS` name of a QGIS field type
_QT_KINDS = {QVariant.LongLong: "int64", QVariant.Int: "int32", QVariant.ULongLong: "uint64",
             QVariant.UInt: "uint32", QVariant.Double: "float64", QVariant.String: "string",
             QVariant.Bool: "bool", QVariant.Date: "date", QVariant.DateTime: "datetime",
             QVariant.Time: "time", QVariant.ByteArray: "binary", QVariant.List: "list",
             QVariant.StringList: "list", QVariant.Map: "struct"}
#: width of a 32-bit integer field that a shapefile reads back as 32-bit
_SHAPEFILE_INT32_WIDTH = 9


def sink_format(destination):
    """``"shp"`` for a shapefile destination, ``"gpkg"`` for a GeoPackage, else None
    (a memory layer or another format: the field types are left to QGIS)."""
    text = str(destination or "").lower()
    for fmt in ("shp", "gpkg"):
        if re.search(rf"\.{fmt}($|[|'\"\s])", text):
            return fmt
    return None


def plain_value(v):
    """A QGIS attribute value as plain Python: None for NULL, ``datetime.date``,
    ``datetime.datetime``, ``datetime.time``, ``bytes``; others as they are."""
    from qgis.PyQt.QtCore import QByteArray, QDate, QDateTime, QTime

    if is_null(v):
        return None
    if isinstance(v, QVariant):
        v = v.value()
    if isinstance(v, QDateTime):
        return v.toPyDateTime()
    if isinstance(v, QDate):
        return v.toPyDate()
    if isinstance(v, QTime):
        return v.toPyTime()
    if isinstance(v, QByteArray):
        return bytes(v)
    return v


def feature_fields_for(input_fields, run, fmt, where):
    """:func:`feature_fields` for a sink of format ``fmt``, and a warning per field the
    format cannot hold as it is.

    For a shapefile (``fmt == "shp"``) the input fields go through
    :func:`vectoradjust.files.outputs.field_change`, as the command line's writer does:
    a date and time, a time, integers wider than 18 characters, binary and lists become
    text fields (their values written as :func:`feature_features` converts them); 64-bit
    integer fields get the width 18 and 32-bit ones 9, so that GDAL reads them back as
    integers of their size (QGIS's default widths, 20 and 10, read back as real numbers
    and 64-bit integers); booleans are written as 1 and 0.

    Parameters
    ----------
    input_fields : QgsFields
    run : AdjustmentRun
    fmt : {"shp", "gpkg"} or None
        :func:`sink_format` of the destination; None: the fields of
        :func:`feature_fields`, no warning.
    where : str
        How the warnings name the output (``"features (roads.shp)"``).

    Returns
    -------
    fields : QgsFields
    notes : list of str
    """
    outputs = _outputs_module()
    fields = feature_fields(input_fields)
    if fmt is None:
        return fields, []
    out, notes = QgsFields(), []
    for k in range(fields.count()):
        g = QgsField(fields.at(k))
        if k < input_fields.count():
            f = input_fields.at(k)
            kind = _QT_KINDS.get(f.type(), "other")
            values = [plain_value(v) for d in run.databases
                      for v in d.shape.layer.attributes.get(f.name(), [])]
            change = outputs.field_change(kind, values, fmt, hint="write a GeoPackage")
            if change is None and fmt == "shp" and kind == "bool":
                change = (False, "(boolean) is written as the integers 1 and 0: QGIS writes "
                                 "no logical field into a shapefile")
            if change is not None:
                notes.append(f"{where}: field {g.name()!r} {change[1]}")
            if change is not None and change[0]:
                g = QgsField(g.name(), QVariant.String, "string", 254 if fmt == "shp" else 0)
            elif fmt == "shp":
                _shapefile_width(g, kind, values)
        out.append(g)
    return out, notes


def _shapefile_width(field, kind, values):
    """Integer fields of a shapefile as wide as GDAL reads back as integers of their size."""
    if kind == "int64" and not 0 < field.length() <= SHAPEFILE_INTEGER_WIDTH:
        field.setLength(SHAPEFILE_INTEGER_WIDTH)
    elif kind == "int32" and not 0 < field.length() <= _SHAPEFILE_INT32_WIDTH:
        wide = max((len(str(int(v))) for v in values if v is not None), default=1)
        field.setLength(_SHAPEFILE_INT32_WIDTH if wide <= _SHAPEFILE_INT32_WIDTH
                        else SHAPEFILE_INTEGER_WIDTH)


def feature_wkb_type(source_wkb):
    """Output type of the adjusted features: (Multi)LineString Z like the input."""
    if QgsWkbTypes.isMultiType(source_wkb):
        return QgsWkbTypes.MultiLineStringZ
    return QgsWkbTypes.LineStringZ


# --------------------------------------------------------------------------- values
def _column(col, mask=None):
    arr = np.asarray(col)
    out = arr.astype(object)
    if arr.dtype.kind == "f":
        out[~np.isfinite(arr)] = None
    if mask is not None:
        out[~mask] = None
    return out


def shape_point_features(run, fields):
    """Features of the ``shape_points`` layer (every vertex of every database)."""
    from vectoradjust.accuracy.tables import shape_point_column

    names = _outputs_module().SHAPE_FIELDS
    out = []
    for d in run.databases:
        v = d.vertices
        adj = v["Adjusted"] == 1
        if "Source" in v:  # vertices corrected by the conflation carry values too
            adj = adj | np.isin(v["Source"], ("interpolated", "extrapolated"))
        cols = [_column(shape_point_column(v, f), adj if f in _MASKED else None)
                for f in names]
        for i in range(len(adj)):
            out.append(new_feature(fields, [c[i] for c in cols],
                                   point_z(v["AdjX"][i], v["AdjY"][i], v["AdjZ"][i])))
    return out


def _feature_parts(d):
    """Adjusted vertex arrays per feature and part (as the headless writer splits them)."""
    layer = d.shape.layer
    parts = {}
    if len(layer.coords) == 0:
        return parts
    adj = d.adjusted_coords
    fi, part = layer.vertex_feature, layer.vertex_part
    key = fi * 100000 + part
    brk = np.flatnonzero(np.diff(key)) + 1
    for s, e in zip(np.r_[0, brk], np.r_[brk, len(key)]):
        parts.setdefault(int(fi[s]), []).append(adj[s:e])
    return parts


def feature_features(run, fields, multi):
    """Features of the ``features`` layer: input attributes, contract fields, adjusted line.

    The renamed input fields go into ``run.summary["renamed_input_fields"]`` (as in the
    headless ``summary.json``).
    """
    outputs = _outputs_module()
    ours = outputs.FEATURE_FIELDS
    run.summary["renamed_input_fields"] = outputs.renamed_input_fields(
        outputs.run_input_fields(run))
    out = []
    text = [fields.at(k).type() == QVariant.String for k in range(fields.count())]
    for d in run.databases:
        layer = d.shape.layer
        in_cols = [_fitted(values, text[k]) if k < len(text) else values
                   for k, values in enumerate(layer.attributes.values())]
        cols = []
        for f in ours:
            if f == "Database":
                cols.append([d.name] * layer.n_features)
            else:
                cols.append(_column(d.features[f]))
        parts = _feature_parts(d)
        for i in range(layer.n_features):
            values = [c[i] for c in in_cols] + [c[i] for c in cols]
            geom = line_z(parts.get(i, []), multi)
            out.append(new_feature(fields, values, geom))
    return out


def _fitted(values, as_text):
    """An input column for its output field: text where the field is text and the value
    is not (a date and time as ISO 8601, a list as JSON, :func:`field_change`)."""
    if not as_text:
        return values
    text_value = _outputs_module().text_value
    out = []
    for v in values:
        p = plain_value(v)
        out.append(p if p is None or isinstance(p, str) else text_value(
            p, "list" if isinstance(p, (list, tuple, dict)) else "other"))
    return out


def control_point_features(run, fields):
    """Features of the ``control_points`` layer (adjusted position, else surveyed)."""
    c = run.control_points
    names = _control_columns(run)
    cols = [_column(c[f]) for f in names]
    used = c["Used"] == 1
    out = []
    for i in range(len(used)):
        if used[i]:
            g = point_z(c["AdjX"][i], c["AdjY"][i], c["AdjZ"][i])
        else:
            g = point_z(c["X"][i], c["Y"][i], c["Z"][i])
        out.append(new_feature(fields, [col[i] for col in cols], g))
    return out


def residual_features(run, fields, scale=1.0):
    """Residual vectors: a line from the database position to the adjusted position.

    ``scale`` exaggerates the vectors (end = database + scale * V) for a readable map;
    the ``V*`` fields hold the true residuals. The lines, lengths and azimuths are the
    core's (:func:`vectoradjust.accuracy.residual_vectors.residual_vectors`); this only
    makes features of them.
    """
    from qgis.core import QgsGeometry, QgsLineString, QgsPoint

    from vectoradjust.accuracy.residual_vectors import residual_vectors

    out = []
    for d in run.databases:
        v = d.vertices
        rows = np.flatnonzero(v["Adjusted"] == 1)
        r = residual_vectors(*(np.asarray(v[c])[rows] for c in ("X", "Y", "Z", "Vx", "Vy", "Vz")),
                             scale=scale)
        for k, i in enumerate(rows):
            line = QgsLineString([QgsPoint(*r.start[k].tolist()), QgsPoint(*r.end[k].tolist())])
            values = [v["point_id"][i], v["feature_id"][i], d.name, float(v["Vx"][i]),
                      float(v["Vy"][i]), float(v["Vz"][i]), float(r.length[k]),
                      float(r.azimuth[k]), v["CE90"][i], v["LE90"][i], float(scale)]
            out.append(new_feature(fields, values, QgsGeometry(line)))
    return out


def add_all(sink, features, feedback=None, start=0.0, span=0.0):
    """Add features to a sink (or file writer) in batches; Cancel in ``feedback`` raises
    :class:`vectoradjust.errors.CancelledError` between batches."""
    n = len(features)
    step = 5000
    for k in range(0, n, step):
        if feedback is not None and feedback.isCanceled():
            from .algorithms.base import check_cancelled

            check_cancelled(feedback)  # CancelledError: the algorithm stops, no result
        ok = sink.addFeatures(features[k:k + step], QgsFeatureSink.FastInsert)
        if ok is False:
            from vectoradjust.errors import InputFileError

            msg = sink.lastError() if hasattr(sink, "lastError") else ""
            raise InputFileError(f"Could not write the output features ({msg})",
                                 "Choose another output file or format")
        if feedback is not None and span:
            feedback.setProgress(start + span * min(1.0, (k + step) / max(n, 1)))


# --------------------------------------------------------------------------- files
def clean_json(obj):
    """NaN/inf -> None and numpy scalars -> Python, recursively (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def write_json(path, obj):
    """Write ``obj`` as indented strict JSON."""
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(clean_json(obj), fh, indent=2)


def write_gpkg(path, layers, crs, transform_context=None, feedback=None):
    """Write several layers into one GeoPackage (replacing the file).

    Parameters
    ----------
    layers : list of (name, QgsFields, wkb type, list of QgsFeature)
    crs : QgsCoordinateReferenceSystem
    """
    from vectoradjust.errors import InputFileError

    if os.path.exists(path):
        os.remove(path)
    tc = transform_context or QgsCoordinateTransformContext()
    for k, (name, fields, wkb, feats) in enumerate(layers):
        opts = QgsVectorFileWriter.SaveVectorOptions()
        opts.driverName = "GPKG"
        opts.layerName = name
        opts.fileEncoding = "UTF-8"
        opts.actionOnExistingFile = (QgsVectorFileWriter.CreateOrOverwriteFile if k == 0 else
                                     QgsVectorFileWriter.CreateOrOverwriteLayer)
        writer = QgsVectorFileWriter.create(path, fields, wkb, crs, tc, opts)
        if writer.hasError() != QgsVectorFileWriter.NoError:
            raise InputFileError(f"Cannot write {path} (layer {name}): {writer.errorMessage()}",
                                 "Choose a writable output folder")
        add_all(writer, feats, feedback)
        del writer


def table_fields(columns, types):
    """Fields of a plain table; ``types``: name -> 'f', 'i', 's' or 'b'."""
    fields = QgsFields()
    for c in columns:
        t = types.get(c, "f")
        if t == "b":
            fields.append(QgsField(c, QVariant.Bool))
        else:
            fields.append(fields_for([c], {c: t})[0])
    return fields
