"""Which ``[[vectors]]`` entry of the project a road layer of the dialog stands for.

A road layer in the dialog is often not literally the file an entry names: a memory
copy, a reprojected layer, a GeoPackage export, a filtered or edited layer, or only its
selected features. It still stands for the entry (so that the measurements of its shape
points are found, and the entry is not read a second time) when

1. its file is the entry's ``path`` (filtered, edited and selected layers of that file);
2. its name is the entry's ``name`` or the name of the entry's file (``osm_roads``);
3. it has the entry's id field (or the id field chosen in the dialog) and every one of
   its ids is an id of the entry's file (copies, reprojections, exports).

When the layer holds fewer roads than the entry's file (a selection, a filter, deleted
features), the measurements of the roads it does not hold are left out of the run
(:func:`vertex_renames`, :func:`apply_renames`): they are neither shape points nor tie
points - except at a vertex shared with a road it holds (a junction), which stays measured.
"""

import os
from pathlib import Path

import numpy as np
from qgis.core import QgsFeatureRequest, QgsVectorLayer

from .. import qgis_io


def entry_layer(entry):
    """The QgsVectorLayer of an entry's file with its ``where`` filter, or None if unreadable."""
    path = entry.path
    if not path or not os.path.exists(path):
        return None
    sub = entry.layer or ("lines" if str(path).lower().endswith(".pbf") else None)
    layer = QgsVectorLayer(qgis_io.shapefile_uri(path, sub), entry.name, "ogr")
    return layer if layer.isValid() else None


def entry_request(entry, where_text):
    """A QgsFeatureRequest with the entry's ``where`` filter (an attribute expression).

    Raises
    ------
    LayerError
        The filter is not a valid expression.
    """
    from vectoradjust.errors import LayerError

    request = QgsFeatureRequest()
    where = getattr(entry, "where", None)
    if where:
        from qgis.core import QgsExpression

        expr = QgsExpression(where)
        if expr.hasParserError():
            raise LayerError(f"{where_text}: where = {where!r} is not a valid attribute filter "
                             f"({expr.parserErrorString()})",
                             "Write an SQL-like condition on the layer's fields, e.g. "
                             "\"highway IN ('primary', 'secondary')\" or \"name IS NOT NULL\"")
        request.setFilterExpression(where)
    return request


def source_ids(source, id_field):
    """The id texts of ``source``'s features in field ``id_field`` (None: no such field)."""
    idx = source.fields().indexFromName(id_field) if id_field else -1
    if idx < 0:
        return None
    request = QgsFeatureRequest()
    request.setFlags(QgsFeatureRequest.NoGeometry)
    request.setSubsetOfAttributes([idx])
    return [qgis_io.id_text(f.attributes()[idx]) for f in source.getFeatures(request)
            if not qgis_io.is_null(f.attributes()[idx])]


def entry_ids(entry, id_field=None):
    """The ids of an entry's file (its ``where`` filter applied), or None if unreadable."""
    id_field = id_field or entry.id_field
    layer = entry_layer(entry)
    if layer is None or not id_field:
        return None
    idx = layer.fields().indexFromName(id_field)
    if idx < 0:
        return None
    request = entry_request(entry, f"[[vectors]] entry {entry.name!r}")
    request.setFlags(QgsFeatureRequest.NoGeometry)
    return [qgis_io.id_text(f.attributes()[idx]) for f in layer.getFeatures(request)
            if not qgis_io.is_null(f.attributes()[idx])]


def _by_ids(vectors, source, id_field):
    for entry in vectors:
        field = id_field or entry.id_field
        ids = source_ids(source, field)
        if not ids:
            continue
        known = entry_ids(entry, field)
        if known and set(ids) <= set(known):
            return entry
    return None


def matching_vector_spec(inputs, layer, source=None, id_field=""):
    """The project's ``[[vectors]]`` entry ``layer`` stands for, or None (see the module).

    Parameters
    ----------
    inputs : ProjectInputs or None
    layer : QgsVectorLayer or None
        The road layer of the dialog.
    source : QgsFeatureSource, optional
        Its features as used (the selection); default ``layer``.
    id_field : str
        The id field chosen in the dialog (empty: each entry's).
    """
    if inputs is None or not inputs.vectors:
        return None
    path = qgis_io.layer_path(layer)
    if path:
        real = os.path.realpath(path)
        for v in inputs.vectors:
            if v.path and os.path.realpath(v.path) == real:
                return v
    names = {n for n in (layer.name() if layer is not None else None,
                         source.sourceName() if source is not None else None) if n}
    for v in inputs.vectors:
        if v.name in names or (v.path and Path(v.path).stem in names):
            return v
    source = source if source is not None else layer
    return _by_ids(inputs.vectors, source, id_field) if source is not None else None


def missing_features(entry, id_field, given_ids):
    """Ids of the entry's file that the given layer does not hold (empty if unknown)."""
    known = entry_ids(entry, id_field)
    if not known:
        return set()
    return set(known) - {str(i) for i in given_ids}


def holds_whole_entry(entry, vlayer, n_features):
    """Whether the road layer is the entry's whole file, known without reading the file
    again: its file is the entry's ``path`` (and layer), neither it nor the entry is
    filtered, it is not being edited, and the ``n_features`` features read are all of
    the layer's (a selection holds fewer)."""
    path = qgis_io.layer_path(vlayer) if vlayer is not None else None
    if not path or not entry.path or os.path.realpath(path) != os.path.realpath(entry.path):
        return False
    if getattr(entry, "where", None) or vlayer.subsetString() or vlayer.isEditable():
        return False
    sub = entry.layer or ("lines" if str(path).lower().endswith(".pbf") else None)
    layername = next((p.split("=", 1)[1] for p in vlayer.source().split("|")[1:]
                      if p.startswith("layername=")), None)
    if layername != sub:  # another layer of the file, or one not named
        return False
    count = vlayer.featureCount()
    return count >= 0 and count == int(n_features)


def vertex_renames(prj, entry, id_field, line_layer, context):
    """What becomes of the measured ids of the entry's roads ``line_layer`` does not hold.

    A vertex of such a road that lies on a vertex of a road that is held (a junction,
    within the merge tolerance) is that vertex: its measurements are renamed to it. The
    other vertices are not in the run: their measurements are left out (None). QGIS
    reads the entry's file; the core decides
    (:func:`vectoradjust.adjust.junctions.junction_renames`).

    Returns
    -------
    dict
        ``{vertex id: vertex id of line_layer, or None}`` (empty: nothing is missing).
    """
    from vectoradjust.adjust.junctions import junction_renames

    missing = missing_features(entry, id_field, line_layer.feature_ids)
    if not missing:
        return {}
    where = f"[[vectors]] entry {entry.name!r} ({entry.path})"
    layer = entry_layer(entry)
    request = entry_request(entry, where)
    if request.filterExpression() is not None:
        layer = layer.materialize(request)
    full, _ = qgis_io.read_line_source(layer, entry.name, id_field, prj.crs, context, where)
    return junction_renames(full, line_layer, missing, prj.spec.settings.merge_tolerance)


def apply_renames(meas, name, renames):
    """``meas`` with the shape point ids of database ``name`` renamed or left out as
    ``renames`` (from :func:`vertex_renames`) says; a (point, image) pair a rename repeats
    is kept once.

    Returns
    -------
    (Measurements, int)
        The measurements and the number of rows left out.
    """
    import dataclasses

    if not renames:
        return meas, 0
    prefix = f"{name}:"
    new_ids = []
    for pid in meas.point_id.tolist():
        bare = pid[len(prefix):] if pid.startswith(prefix) else pid
        if ":" in bare or bare not in renames:
            new_ids.append(pid)
        else:
            new_ids.append(renames[bare])
    seen = set()
    mask = np.zeros(len(new_ids), bool)
    for i, (pid, img) in enumerate(zip(new_ids, meas.image_id.tolist())):
        if pid is not None and (pid, img) not in seen:
            seen.add((pid, img))
            mask[i] = True
    k = len(mask)
    changes = {f.name: getattr(meas, f.name)[mask] for f in dataclasses.fields(meas)
               if isinstance(getattr(meas, f.name), np.ndarray)
               and len(getattr(meas, f.name)) == k}
    changes["point_id"] = np.asarray([p for p, m in zip(new_ids, mask) if m], dtype=object)
    return dataclasses.replace(meas, **changes), int((~mask).sum())
