"""Road layers of the dialog that are not literally the file of a ``[[vectors]]`` entry (a
memory copy, a reprojected copy, a layer named like the entry, a selection) still stand for
that entry: their measurements are found, and a selection adjusts exactly its roads."""

import re

import pytest

pytest.importorskip("qgis.core")

from .util import close, columns  # noqa: E402

pytestmark = pytest.mark.qgis

OUTPUTS = ("SHAPE_POINTS", "FEATURES")


def run(params, feedback=None):
    import processing

    return processing.run("vectoradjust:adjustroadvectors", params, feedback=feedback)


def params(sample, layer, **extra):
    p = {"INPUT": layer, "PROJECT": str(sample / "project.toml")}
    p.update({k: "TEMPORARY_OUTPUT" for k in OUTPUTS})
    p.update(extra)
    return p


def measured(out):
    """Sorted point ids of the measured shape points (NImages > 0)."""
    cols = columns(out["SHAPE_POINTS"])
    return sorted(p for p, n in zip(cols["point_id"], cols["NImages"]) if n)


def osm_layer(sample, name="osm_roads"):
    from qgis.core import QgsVectorLayer

    lyr = QgsVectorLayer(str(sample / "osm_roads.shp"), name, "ogr")
    assert lyr.isValid()
    return lyr


def memory_copy(sample, name):
    from qgis.core import QgsFeatureRequest

    lyr = osm_layer(sample).materialize(QgsFeatureRequest())
    lyr.setName(name)
    return lyr


@pytest.fixture(scope="module")
def file_run(qgis_app, sample):
    """The OSM file itself (the reference)."""
    return run(params(sample, str(sample / "osm_roads.shp")))


def assert_same_run(out, ref, atol=1e-9):
    assert measured(out) and measured(out) == measured(ref)
    assert out["DEGREES_OF_FREEDOM"] == ref["DEGREES_OF_FREEDOM"]
    assert close(out["SIGMA0_SQUARED"], ref["SIGMA0_SQUARED"],
                 atol * max(1.0, ref["SIGMA0_SQUARED"]))
    assert set(columns(out["SHAPE_POINTS"])["Database"]) == {"OSM"}


def test_memory_copy_matched_by_ids(file_run, sample):
    """A memory copy with another name, no id field chosen: the entry by its ids."""
    assert_same_run(run(params(sample, memory_copy(sample, "my roads"))), file_run)


def test_memory_copy_named_like_the_entry(file_run, sample):
    """A copy called like the entry ("OSM") takes its place (no "both called")."""
    assert_same_run(run(params(sample, memory_copy(sample, "OSM"))), file_run)


def test_memory_copy_with_an_id_field_is_not_ambiguous(file_run, sample):
    out = run(params(sample, memory_copy(sample, "osm copy"), ID_FIELD="osm_id"))
    assert_same_run(out, file_run)


def test_reprojected_copy(file_run, sample):
    """A copy reprojected to WGS 84 (transformed back to the ground CRS when read)."""
    import processing

    reproj = processing.run("native:reprojectlayer", {
        "INPUT": str(sample / "osm_roads.shp"), "TARGET_CRS": "EPSG:4326",
        "OUTPUT": "TEMPORARY_OUTPUT"})["OUTPUT"]
    assert reproj.name() != "OSM"
    assert_same_run(run(params(sample, reproj)), file_run, atol=1e-6)


def test_selected_features_only(file_run, sample):
    """Only the selected roads are in the run: their measurements are found (also at a
    junction measured under the id of a road not selected) and the other OSM roads'
    measurements are left out (not taken for tie points: the degrees of freedom drop by
    exactly two per left-out measurement)."""
    from qgis.core import QgsProcessingFeatureSourceDefinition, QgsProcessingFeedback, QgsProject

    from vectoradjust.files.csv_tables import read_measurements

    layer = osm_layer(sample)
    QgsProject.instance().addMapLayer(layer)
    try:
        ids = [f["osm_id"] for f in layer.getFeatures()]
        chosen = {str(i) for i in ids[: len(ids) // 2]}
        layer.selectByExpression(f"osm_id IN ({', '.join(map(str, sorted(map(int, chosen))))})")
        assert layer.selectedFeatureCount() == len(chosen)
        infos = []

        class Recorder(QgsProcessingFeedback):
            def pushInfo(self, text):
                infos.append(text)
                super().pushInfo(text)

        source = QgsProcessingFeatureSourceDefinition(layer.id(), True)
        out = run(params(sample, source), feedback=Recorder())
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
    feats = columns(out["FEATURES"])
    assert len(feats["osm_id"]) == len(chosen)
    assert {str(v) for v in feats["osm_id"]} == chosen
    mine = measured(out)
    assert mine and mine == [p for p in measured(file_run) if p.rsplit("_", 1)[0] in chosen]
    meas = read_measurements(str(sample / "image_points.csv"), 0.015)
    other = {p for p in measured(file_run) if p.rsplit("_", 1)[0] not in chosen}
    rows_of_others = sum(1 for p in meas.point_id if p in other)
    said = [int(re.match(r"OSM: (\d+) image measurements", t).group(1)) for t in infos
            if re.match(r"OSM: \d+ image measurements", t)]
    assert len(said) == 1 and 0 < said[0] <= rows_of_others
    assert out["DEGREES_OF_FREEDOM"] == file_run["DEGREES_OF_FREEDOM"] - 2 * said[0]

def test_geopackage_export(file_run, sample, tmp_path):
    """A GeoPackage export of the entry's file (another file, another name): by its ids."""
    from qgis.core import QgsCoordinateTransformContext, QgsVectorFileWriter, QgsVectorLayer

    opts = QgsVectorFileWriter.SaveVectorOptions()
    opts.driverName = "GPKG"
    opts.layerName = "exported"
    path = str(tmp_path / "export.gpkg")
    err = QgsVectorFileWriter.writeAsVectorFormatV3(osm_layer(sample), path,
                                                    QgsCoordinateTransformContext(), opts)
    assert err[0] == QgsVectorFileWriter.NoError, err
    layer = QgsVectorLayer(f"{path}|layername=exported", "exported", "ogr")
    assert layer.isValid()
    assert_same_run(run(params(sample, layer)), file_run)


def test_filtered_layer_adjusts_its_roads(file_run, sample):
    """The entry's file with a layer filter: its roads, the others' measurements left out;
    a junction with a filtered-out road measured under that road's vertex id stays
    measured."""
    layer = osm_layer(sample)
    assert layer.setSubsetString("\"highway\" = 'tertiary'")
    kept = {str(f["osm_id"]) for f in layer.getFeatures()}
    assert 0 < len(kept) < 26
    out = run(params(sample, layer))
    assert {str(v) for v in columns(out["FEATURES"])["osm_id"]} == kept
    mine = measured(out)
    assert mine and mine == [p for p in measured(file_run) if p.rsplit("_", 1)[0] in kept]
    assert out["DEGREES_OF_FREEDOM"] < file_run["DEGREES_OF_FREEDOM"]


def test_compare_with_a_copy_named_like_the_entry(qgis_app, sample):
    """Compare: a memory copy called "OSM" takes the OSM entry's place (the OSM row of the
    file itself), instead of "two road databases are both called 'OSM'"."""
    import processing

    def compare(layer):
        out = processing.run("vectoradjust:compareroaddatabases", {
            "LAYERS": [layer], "PROJECT": str(sample / "project.toml"),
            "OUTPUT": "TEMPORARY_OUTPUT"})
        return columns(out["OUTPUT"])

    mine, ref = compare(memory_copy(sample, "OSM")), compare(str(sample / "osm_roads.shp"))
    assert mine["database"] == ["OSM"]
    for key in ref:
        if key != "_geom":
            assert mine[key] == ref[key] or all(
                close(a, b, 1e-9 * max(1.0, abs(b))) for a, b in zip(mine[key], ref[key])), key


def _infos():
    from qgis.core import QgsProcessingFeedback

    class Recorder(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.infos = []

        def pushInfo(self, text):  # noqa: N802 - the QGIS name
            self.infos.append(text)
            super().pushInfo(text)

    return Recorder()


def test_the_matched_entry_and_its_settings_are_logged(qgis_app, sample):
    """A layer matched to a [[vectors]] entry: one log line names the entry and the
    settings taken from it; those given as parameters are not among them."""
    fb = _infos()
    run(params(sample, str(sample / "osm_roads.shp")), feedback=fb)
    said = [t for t in fb.infos if "[[vectors]] entry" in t]
    assert len(said) == 1, said
    line = said[0]
    assert "road layer 'osm_roads' is the project's [[vectors]] entry 'OSM'" in line
    for part in ("name 'OSM'", "id field 'osm_id'", "horizontal sigma 10 m",
                 "vertical sigma 0.15 m", "DEM ", "identification sigma 0.5, 0 m"):
        assert part in line, (part, line)
    fb = _infos()
    run(params(sample, str(sample / "osm_roads.shp"), SIGMA_XY=3.0, NAME="OSM"), feedback=fb)
    line = next(t for t in fb.infos if "[[vectors]] entry" in t)
    assert "horizontal sigma" not in line and "name 'OSM'" not in line
    assert "vertical sigma 0.15 m" in line


def test_a_layer_outside_the_project_is_not_said_to_match(qgis_app, sample, tmp_path):
    from .util import project_copy

    project = project_copy(sample, tmp_path / "two.toml", drop=("OSM",))
    fb = _infos()
    run({"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(project), "ID_FIELD": "osm_id",
         "DEM": str(sample / "dem.tif"), "SHAPE_POINTS": "TEMPORARY_OUTPUT"}, feedback=fb)
    assert not [t for t in fb.infos if "is the project's [[vectors]] entry" in t]


def test_dialog_labels_say_where_the_defaults_come_from(qgis_app):
    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById("vectoradjust:adjustroadvectors")
    labels = {k: alg.parameterDefinition(k).description()
              for k in ("ID_FIELD", "SIGMA_XY", "SIGMA_Z", "NAME", "DEM")}
    for key, text in labels.items():
        assert "[[vectors]] entry" in text, (key, text)
    assert labels["ID_FIELD"].endswith("else the feature index)")
    assert labels["NAME"].endswith("else the layer name)")
    assert labels["SIGMA_XY"].endswith("else 10)")


def test_the_entry_file_itself_is_read_once(qgis_app, sample, monkeypatch, file_run):
    """The road layer that is the entry's whole file: its ids are not read a second time
    to look for roads it lacks (a selection of it still is, see above)."""
    from qgis_plugin.algorithms import matching

    calls = []
    real = matching.entry_ids
    monkeypatch.setattr(matching, "entry_ids", lambda *a, **k: calls.append(a) or real(*a, **k))
    out = run(params(sample, str(sample / "osm_roads.shp")))
    assert calls == []
    assert_same_run(out, file_run)
    layer = osm_layer(sample)
    assert matching.holds_whole_entry(_entry(sample), layer, layer.featureCount())
    assert not matching.holds_whole_entry(_entry(sample), layer, layer.featureCount() - 1)
    layer.setSubsetString('"osm_id" IS NOT NULL')
    assert not matching.holds_whole_entry(_entry(sample), layer, layer.featureCount())


def _entry(sample):
    from vectoradjust.files.project import load_project

    return next(v for v in load_project(str(sample / "project.toml")).vectors
                if v.name == "OSM")
