"""``[[vectors]] where`` (an attribute filter) applied when the plugin reads a project entry's
layer from its file; OGR SQL ``IS NOT NULL`` / ``IN (...)`` are valid QGIS expressions."""

from types import SimpleNamespace

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis


def entry(sample, where=None, **kw):
    import dataclasses

    from vectoradjust.model import VectorSpec

    spec = VectorSpec(name="OSM", path=str(sample / "osm_roads.shp"), id_field="osm_id", **kw)
    # until the project-file parser reads ``where`` the plugin reads it with getattr
    return dataclasses.replace(spec, where=where) if where is not None else spec


def read(sample, spec):
    from qgis.core import QgsCoordinateReferenceSystem, QgsProcessingContext, QgsProcessingFeedback

    from qgis_plugin.algorithms.inputs import read_project_entry

    prj = SimpleNamespace(crs=QgsCoordinateReferenceSystem("EPSG:32616"), source="project.toml")
    _, layer, _ = read_project_entry(prj, spec, QgsProcessingContext(), QgsProcessingFeedback())
    return layer


def file_ids(sample, expression=None):
    from qgis.core import QgsExpression, QgsExpressionContext, QgsVectorLayer

    lyr = QgsVectorLayer(str(sample / "osm_roads.shp"), "o", "ogr")
    out = []
    for f in lyr.getFeatures():
        if expression:
            ctx = QgsExpressionContext()
            ctx.setFeature(f)
            if not QgsExpression(expression).evaluate(ctx):
                continue
        out.append(str(f["osm_id"]))
    return out


def test_no_filter_reads_every_feature(qgis_app, sample):
    assert read(sample, entry(sample)).feature_ids.tolist() == file_ids(sample)


@pytest.mark.parametrize("where", ["highway IN ('tertiary', 'secondary')",
                                   "name IS NOT NULL AND highway = 'residential'",
                                   "osm_id IN (41341773, 41341950)"])
def test_where_filters_the_entry(qgis_app, sample, where):
    ids = read(sample, entry(sample, where)).feature_ids.tolist()
    assert ids == file_ids(sample, where)
    assert 0 < len(ids) < len(file_ids(sample))


def test_where_with_an_unknown_field(qgis_app, sample):
    from vectoradjust.errors import LayerError

    with pytest.raises(LayerError,
                       match=r"names 'road_class', not a field.*Correct the field") as exc:
        read(sample, entry(sample, "road_class = 'primary'"))
    assert "'road_class'" in str(exc.value) and "osm_id" in str(exc.value)


def test_where_that_is_not_an_expression(qgis_app, sample):
    from vectoradjust.errors import LayerError

    with pytest.raises(LayerError,
                       match=r"(?s)not a valid attribute filter.*Write an SQL") as exc:
        read(sample, entry(sample, "highway IN ('primary'"))
    assert "not a valid attribute filter" in str(exc.value)


def test_where_selecting_nothing(qgis_app, sample):
    from vectoradjust.errors import LayerError

    with pytest.raises(LayerError, match=r"selects no feature.*Correct the where filter") as exc:
        read(sample, entry(sample, "highway = 'motorway'"))
    assert "selects no feature" in str(exc.value)


def test_where_limits_the_ids_a_selection_is_matched_against(qgis_app, sample):
    """Roads the entry's filter leaves out are not "missing" from a layer of that entry."""
    from qgis_plugin.algorithms.matching import missing_features

    where = "highway = 'tertiary'"
    kept = file_ids(sample, where)
    assert missing_features(entry(sample, where), "osm_id", kept) == set()
    assert missing_features(entry(sample), "osm_id", kept) == set(file_ids(sample)) - set(kept)
