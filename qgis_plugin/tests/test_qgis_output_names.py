"""The QGIS sinks keep input fields named like the product's fields under new names
(``length`` -> ``in_length``), as the headless writer does, in every driver."""

import json

import pytest

pytest.importorskip("qgis.core")

from .util import columns  # noqa: E402

pytestmark = pytest.mark.qgis


def _clashing_layer(sample):
    """The sample's OSM roads with OSMnx-like fields ``length``, ``RMSE`` and ``npts``."""
    from qgis.core import QgsFeature, QgsField, QgsVectorLayer
    from qgis.PyQt.QtCore import QVariant

    src = QgsVectorLayer(str(sample / "osm_roads.shp"), "osm", "ogr")
    mem = QgsVectorLayer(f"LineString?crs={src.crs().authid()}", "osm_roads", "memory")
    pr = mem.dataProvider()
    pr.addAttributes(list(src.fields()) + [QgsField("length", QVariant.Double),
                                           QgsField("RMSE", QVariant.Double),
                                           QgsField("npts", QVariant.Int)])
    mem.updateFields()
    feats = []
    for f in src.getFeatures():
        g = QgsFeature(mem.fields())
        g.setGeometry(f.geometry())
        g.setAttributes(list(f.attributes()) + [f.geometry().length(), 1.5, 7])
        feats.append(g)
    pr.addFeatures(feats)
    return mem


@pytest.mark.parametrize("ext", ["gpkg", "shp"])
def test_adjust_sink_renames_clashing_input_fields(qgis_app, sample, tmp_path, ext):
    import processing
    from qgis.core import QgsVectorLayer

    layer = _clashing_layer(sample)
    path = tmp_path / f"features.{ext}"
    summary = tmp_path / "summary.json"
    out = processing.run("vectoradjust:adjustroadvectors", {
        "INPUT": layer, "PROJECT": str(sample / "project.toml"),
        "FEATURES": str(path), "SUMMARY": str(summary)})
    feats = columns(QgsVectorLayer(out["FEATURES"], "f", "ogr"))
    for f in ("in_length", "Length", "in_RMSE", "RMSE", "in_npts", "NPts"):
        assert f in feats, f
    assert "Length_1" not in feats
    assert set(feats["in_RMSE"]) == {1.5} and set(feats["in_npts"]) == {7}
    assert all(n >= 2 for n in feats["NPts"])
    doc = json.loads(summary.read_text())
    assert doc["renamed_input_fields"] == {"length": "in_length", "RMSE": "in_RMSE",
                                           "npts": "in_npts"}
