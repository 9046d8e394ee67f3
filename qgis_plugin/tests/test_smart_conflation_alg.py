"""The "Smart conflation" algorithm through ``processing.run``: its dialog's defaults, the
product the core computes from the same arrays, the split of a features layer by its
Database field, and its messages."""

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .test_qgis_dialogs import dialog_parameters  # noqa: E402

pytestmark = pytest.mark.qgis

#: the CE90 given to each sample database's (unadjusted) features in :func:`adjusted_layers`
CE90 = {"osm_roads": 1.0, "tnm_roads": 2.0, "tiger_roads": 3.0}


def adjusted_layer(sample, name, ce90=None, database=None):
    """A memory layer of the sample's ``name`` roads with ``CE90`` (``CE90[name]``),
    ``LE90`` and ``RMSE`` fields (and a ``Database`` field when given): adjusted
    features as far as the algorithm can tell."""
    from qgis.core import QgsFeature, QgsField, QgsVectorLayer
    from qgis.PyQt.QtCore import QVariant

    src = QgsVectorLayer(str(sample / f"{name}.shp"), name, "ogr")
    assert src.isValid(), name
    crs = src.crs().authid()
    lyr = QgsVectorLayer(f"LineString?crs={crs}", f"adjusted_{name}", "memory")
    extra = [QgsField("CE90", QVariant.Double), QgsField("LE90", QVariant.Double),
             QgsField("RMSE", QVariant.Double)]
    if database is not None:
        extra.append(QgsField("Database", QVariant.String))
    lyr.dataProvider().addAttributes(list(src.fields()) + extra)
    lyr.updateFields()
    ce = CE90[name] if ce90 is None else ce90
    feats = []
    for f in src.getFeatures():
        g = QgsFeature(lyr.fields())
        g.setAttributes(list(f.attributes()) + [ce, ce / 2, 1.0] +
                        ([database] if database is not None else []))
        g.setGeometry(f.geometry())
        feats.append(g)
    lyr.dataProvider().addFeatures(feats)
    return lyr


def adjusted_layers(sample, names=("osm_roads", "tnm_roads")):
    """:func:`adjusted_layer` of each name, added to the QGIS project."""
    from qgis.core import QgsProject

    layers = [adjusted_layer(sample, n) for n in names]
    QgsProject.instance().addMapLayers(layers)
    return layers


def run(params):
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback, QgsProject

    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    out = processing.run("vectoradjust:smartconflation", params, context=context,
                         feedback=QgsProcessingFeedback())
    layer = out["OUTPUT"]
    if isinstance(layer, str):
        layer = context.getMapLayer(layer)
    rows = [dict(zip(layer.fields().names(), [None if v is None or (
        hasattr(v, "isNull") and v.isNull()) else v for v in f.attributes()]))
        for f in layer.getFeatures()]
    return out, rows


def _core(layers):
    """The core's product from the layers' arrays (as the algorithm reads them)."""
    from qgis.core import QgsCoordinateTransformContext, QgsProcessingContext

    from vectoradjust.conflation.smart import smart_conflate
    from vectoradjust.files.smart_outputs import feature_set

    from ..algorithms.smart_conflation import _databases

    context = QgsProcessingContext()
    context.setTransformContext(QgsCoordinateTransformContext())
    dbs = [d for lyr in layers for d in _databases(lyr, layers[0].crs(), context, None)]
    return smart_conflate([feature_set(db, xy, cols) for db, xy, cols, _, _ in dbs])[0]


def test_dialog_defaults(qgis_app, sample):
    layers = adjusted_layers(sample)
    params = dialog_parameters("smartconflation", {"LAYERS": layers})
    assert params["MIN_OVERLAP"] == 0.5 and params["BY"] == 0
    assert params.get("MAX_DISTANCE") is None
    out, rows = run(params)
    r = _core(layers)
    assert out["FEATURES"] == len(rows) == len(r.source) and out["MATCHED"] > 0
    assert [row["Source"] for row in rows] == [r.sets[s].name for s in r.source]
    assert np.allclose([np.nan if row["MatchScore"] is None else row["MatchScore"]
                        for row in rows], r.score, equal_nan=True)
    # CE90 1 (OSM) against 2 (TNM): OSM wins every match; TNM's unmatched ones are carried
    matched = [row for row in rows if row["Loser"]]
    assert matched and all(row["Source"] == "adjusted_osm_roads" and row["NSources"] == 2
                           and row["LoserCE90"] == 2.0 for row in matched)
    assert len(rows) == 2 * 26 - len(matched)
    assert {"osm_id", "permanent_", "name", "fullname", "LoserOffset"} <= set(rows[0])


def test_by_rmse_and_max_distance(qgis_app, sample):
    layers = adjusted_layers(sample)
    params = dialog_parameters("smartconflation", {"LAYERS": layers})
    params.update(MAX_DISTANCE=0.01)
    out, rows = run(params)
    assert out["MATCHED"] == 0 and len(rows) == 52
    params.update(MAX_DISTANCE=None, BY=1)  # RMSE equal (1.0): the CE90 decides
    out, rows = run(params)
    assert all(row["Source"] == "adjusted_osm_roads" for row in rows if row["Loser"])


def test_a_database_field_splits_one_layer(qgis_app, sample):
    """One layer holding two databases (as an adjustment's features layer does)."""
    from qgis.core import QgsFeature, QgsFields, QgsProject, QgsVectorLayer

    parts = [adjusted_layer(sample, "osm_roads", ce90=3.0, database="OSM"),
             adjusted_layer(sample, "tnm_roads", ce90=1.5, database="TNM")]
    fields = QgsFields()
    for p in parts:
        for f in p.fields():
            if fields.indexOf(f.name()) < 0:
                fields.append(f)
    both = QgsVectorLayer(f"LineString?crs={parts[0].crs().authid()}", "features", "memory")
    both.dataProvider().addAttributes(list(fields))
    both.updateFields()
    feats = []
    for p in parts:
        for f in p.getFeatures():
            g = QgsFeature(both.fields())
            for name in p.fields().names():
                g[name] = f[name]
            g.setGeometry(f.geometry())
            feats.append(g)
    both.dataProvider().addFeatures(feats)
    QgsProject.instance().addMapLayer(both)
    out, rows = run(dict(dialog_parameters("smartconflation", {"LAYERS": [both]})))
    sources = {row["Source"] for row in rows}
    assert sources <= {"OSM", "TNM"} and out["MATCHED"] > 0
    assert all(row["Source"] == "TNM" for row in rows if row["Loser"])


def test_messages(qgis_app, sample):
    from qgis.core import QgsProcessingException, QgsProject, QgsVectorLayer

    raw = QgsVectorLayer(str(sample / "osm_roads.shp"), "raw_osm", "ogr")
    QgsProject.instance().addMapLayer(raw)
    params = dialog_parameters("smartconflation", {"LAYERS": [raw] + adjusted_layers(sample)})
    # the layer is named by its map-layer name or (QGIS 3.22 loads the dialog's value
    # again from its source) by its file's name
    with pytest.raises(QgsProcessingException, match="(raw_osm|osm_roads).*no CE90 field"):
        run(params)
    params = dialog_parameters("smartconflation", {"LAYERS": adjusted_layers(
        sample, ("osm_roads",))})
    with pytest.raises(QgsProcessingException, match="two or more databases"):
        run(params)
