"""Road databases and tables: every ``[[vectors]]`` entry of the project is read (so that
the other databases' measurements are left out, as on the command line), a road layer that
is not in the project is one more database, and table layers go through
``vectoradjust.files.csv_tables`` without a temporary CSV, their rows named in messages."""

import json

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .util import (  # noqa: E402
    assert_same_values,
    close,
    columns,
    project_copy,
    reorder,
)

pytestmark = pytest.mark.qgis

SHAPE = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ",
         "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "NImages", "Adjusted", "Database"]


def run(alg, params, feedback=None):
    import processing

    return processing.run(f"vectoradjust:{alg}", params, feedback=feedback)


def error(alg, params, match):
    """Run ``alg``; it must fail with a message matching the regular expression ``match``."""
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match=match) as exc:
        run(alg, params)
    return str(exc.value)


def _memory_copy(path, name):
    """A file layer copied into a memory layer (no file path: not a project entry)."""
    from qgis.core import QgsFeatureRequest, QgsVectorLayer

    src = QgsVectorLayer(str(path), name, "ogr")
    lyr = src.materialize(QgsFeatureRequest())
    lyr.setName(name)
    return lyr


def test_layer_not_in_the_project_is_one_more_database(qgis_app, sample, headless_adjust,
                                                       tmp_path):
    """A project listing TNM and TIGER only, OSM given as a layer outside it (DEM and id
    field as parameters): the adjustment of ``vectoradjust adjust --vectors OSM`` of the
    whole project, since TNM's and TIGER's measurements are recognised either way."""
    project = project_copy(sample, tmp_path / "two.toml", drop=("OSM",))
    out = run("adjustroadvectors", {
        "INPUT": _memory_copy(sample / "osm_roads.shp", "osm in memory"), "ID_FIELD": "osm_id",
        "NAME": "OSM", "DEM": str(sample / "dem.tif"), "PROJECT": str(project),
        "IDENTIFICATION_SIGMA_XY": 0.5,  # as the sample's [[vectors]] OSM entry states
        "SIGMA_XY": 10.0, "SIGMA_Z": 0.15,  # the entry's sigma (Z: the DEM's accuracy)
        "SHAPE_POINTS": "TEMPORARY_OUTPUT"})
    s = headless_adjust["summary"]
    assert close(out["SIGMA0_SQUARED"], s["sigma0_squared"])
    assert out["DEGREES_OF_FREEDOM"] == s["degrees_of_freedom"]
    from qgis.core import QgsVectorLayer

    ref = columns(QgsVectorLayer(f"{headless_adjust['gpkg']}|layername=shape_points", "r",
                                 "ogr"))
    mine = columns(out["SHAPE_POINTS"])
    ref = reorder(ref, "point_id", mine["point_id"])
    for f in SHAPE:
        assert_same_values(mine[f], ref[f], f)


def test_other_databases_are_left_out_not_tied(qgis_app, sample):
    """Without the other [[vectors]] entries their 706 measurements would become tie points;
    with them, the run says they were left out."""
    from qgis.core import QgsProcessingFeedback

    warnings = []

    class Recorder(QgsProcessingFeedback):
        def pushWarning(self, text):
            warnings.append(text)
            super().pushWarning(text)

    run("adjustroadvectors", {"INPUT": str(sample / "tnm_roads.shp"),
                              "PROJECT": str(sample / "project.toml"),
                              "SHAPE_POINTS": "TEMPORARY_OUTPUT"}, feedback=Recorder())
    left_out = [w for w in warnings if "were left out" in w]
    assert len(left_out) == 1
    # OSM's and TIGER's measured vertices: every measurement of an id of those databases
    from vectoradjust.files.csv_tables import read_measurements

    from .plain_reference import read_lines

    meas = read_measurements(str(sample / "image_points.csv"), 0.015)
    ids = set()
    for name, field in (("osm", "osm_id"), ("tiger", "tlid")):
        layer = read_lines(sample / f"{name}_roads.shp", name, field)
        ids |= {f"{layer.feature_ids[f]}_{v}" for f, v in zip(layer.vertex_feature,
                                                               layer.vertex_index)}
    n = int(np.isin(meas.point_id, list(ids)).sum())
    assert left_out[0].startswith(f"{n} measurement(s)") and n > 0


def test_compare_a_subset_reads_the_other_databases(qgis_app, sample, headless_compare):
    """Comparing OSM alone gives the OSM row of ``vectoradjust compare`` (all databases)."""
    out = run("compareroaddatabases", {"LAYERS": [str(sample / "osm_roads.shp")],
                                       "PROJECT": str(sample / "project.toml"),
                                       "OUTPUT": "TEMPORARY_OUTPUT"})
    table = columns(out["OUTPUT"])
    with open(headless_compare / "compare.json", encoding="utf-8") as fh:
        ref = [r for r in json.load(fh) if r["database"] == "OSM"]
    assert table["database"] == ["OSM"]
    for key in ref[0]:
        assert_same_values(table[key], [ref[0][key]], key)


def test_database_name_clash(qgis_app, sample):
    msg = error("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"), "NAME": "TNM",
                                      "PROJECT": str(sample / "project.toml"),
                                      "SHAPE_POINTS": "TEMPORARY_OUTPUT"},
                r"both called 'TNM'.*Give the road layer another database name")
    assert "both called 'TNM'" in msg and "tnm_roads.shp" in msg


def test_copy_of_a_project_database_takes_its_place(qgis_app, sample):
    """A renamed copy of a project database stands for its entry (by its ids): its
    measurements are its own, not ambiguous with the entry's file."""
    out = run("adjustroadvectors", {
        "INPUT": _memory_copy(sample / "osm_roads.shp", "osm copy"), "ID_FIELD": "osm_id",
        "NAME": "OSM2", "PROJECT": str(sample / "project.toml"),
        "SHAPE_POINTS": "TEMPORARY_OUTPUT"})
    cols = columns(out["SHAPE_POINTS"])
    assert set(cols["Database"]) == {"OSM2"} and any(cols["NImages"])


def test_missing_project_database_file(qgis_app, sample, tmp_path):
    project = project_copy(sample, tmp_path / "p.toml")
    text = project.read_text(encoding="utf-8").replace(str(sample / "tiger_roads.shp"),
                                                       str(tmp_path / "gone.shp"))
    project.write_text(text, encoding="utf-8")
    msg = error("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                      "PROJECT": str(project),
                                      "SHAPE_POINTS": "TEMPORARY_OUTPUT"},
                r"gone\.shp' does not exist.*Check the path in the \[\[vectors\]\] entry")
    assert "gone.shp" in msg and "does not exist" in msg and "[[vectors]]" in msg


# --------------------------------------------------------------------------- tables
def test_tables_from_rows_equal_the_csv_readers(sample):
    """``*_from_rows`` on a CSV's cells give the CSV readers' arrays."""
    import csv

    from vectoradjust.files import csv_tables as tables

    def cells(path):
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        return rows[0], rows[1:]

    h, r = cells(sample / "image_points.csv")
    a = tables.measurements_from_rows(h, r, "m", 0.015)
    b = tables.read_measurements(str(sample / "image_points.csv"), 0.015)
    assert a.point_id.tolist() == b.point_id.tolist()
    assert np.array_equal(a.xy, b.xy) and np.array_equal(a.sigma, b.sigma)
    assert np.array_equal(a.rows, b.rows)  # line numbers of the file
    h, r = cells(sample / "gcps.csv")
    c = tables.control_from_rows(h, r, "c", lines=range(1, len(r) + 1), line_word="row")
    d = tables.read_control(str(sample / "gcps.csv"))
    assert c.point_id.tolist() == d.point_id.tolist() and np.array_equal(c.xyz, d.xyz)
    assert c.role.tolist() == d.role.tolist() and c.rows.tolist() == list(range(1, len(r) + 1))


def _memory_table(name, spec, rows):
    from qgis.core import QgsFeature, QgsVectorLayer

    lyr = QgsVectorLayer("None?" + "&".join(f"field={f}" for f in spec), name, "memory")
    feats = []
    for values in rows:
        f = QgsFeature(lyr.fields())
        f.setAttributes(values)
        feats.append(f)
    lyr.dataProvider().addFeatures(feats)
    return lyr


def test_table_layer_errors_name_the_row(qgis_app, sample):
    base = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml"),
            "SHAPE_POINTS": "TEMPORARY_OUTPUT"}
    meas = _memory_table("badx", ["point_id:string", "image_id:string", "x:string",
                                  "y:double"],
                         [["GCP01", "L", "1.0", 2.0], [None, None, None, None],
                          ["GCP01", "R", "abc", 2.0]])
    msg = error("adjustroadvectors", dict(base, MEASUREMENTS=meas),
                r"'badx', row 3: column x is 'abc', not a finite number\. Enter a number")
    assert "measurements table 'badx', row 3: column x is 'abc'" in msg  # blank row 2 skipped
    ctrl = _memory_table("dupctrl", ["point_id:string", "X:double", "Y:double", "Z:double",
                                     "sigma_x:double", "sigma_y:double", "sigma_z:double"],
                         [["A", 1.0, 2.0, 3.0, 0.1, 0.1, 0.1], ["A", 1.0, 2.0, 3.0, 0.1, 0.1,
                                                                 0.1]])
    msg = error("adjustroadvectors", dict(base, CONTROL=ctrl),
                r"point id 'A' appears more than once.*Give every control and check point")
    assert "control table 'dupctrl': point id 'A' appears more than once (rows 1, 2)" in msg


def test_reweight_vce_parameter(qgis_app, sample, tmp_path):
    """REWEIGHT = variance component estimation: the command line's run of the project with
    ``reweight = "vce"``."""
    from qgis.core import QgsVectorLayer

    from qgis_plugin.algorithms.inputs import _REWEIGHT_VALUES

    from .conftest import run_headless

    project = project_copy(sample, tmp_path / "vce.toml")
    text = project.read_text(encoding="utf-8")
    assert 'reweight = "two-pass"' in text
    project.write_text(text.replace('reweight = "two-pass"', 'reweight = "vce"'),
                       encoding="utf-8")
    run_headless(["-m", "vectoradjust.cli", "adjust", str(project), "--out",
                  str(tmp_path / "ref"), "--vectors", "OSM", "--no-bands", "-q"])
    with open(tmp_path / "ref" / "summary.json", encoding="utf-8") as fh:
        ref_summary = json.load(fh)
    assert ref_summary["reweight"] == "vce"
    out = run("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                    "PROJECT": str(sample / "project.toml"),
                                    "REWEIGHT": _REWEIGHT_VALUES.index("vce"),
                                    "SHAPE_POINTS": "TEMPORARY_OUTPUT",
                                    "SUMMARY": str(tmp_path / "mine.json")})
    with open(tmp_path / "mine.json", encoding="utf-8") as fh:
        mine_summary = json.load(fh)
    assert mine_summary["reweight"] == "vce"
    assert close(out["SIGMA0_SQUARED"], ref_summary["sigma0_squared"])
    ref = columns(QgsVectorLayer(f"{tmp_path / 'ref' / 'adjusted.gpkg'}|layername=shape_points",
                                 "r", "ogr"))
    mine = columns(out["SHAPE_POINTS"])
    ref = reorder(ref, "point_id", mine["point_id"])
    for f in SHAPE:
        assert_same_values(mine[f], ref[f], f)


def test_a_project_that_states_a_control_crs_is_refused(qgis_app, sample, tmp_path):
    """The plugin does not transform control points: [control] crs is a clear error, not
    control points read in the wrong datum."""
    from qgis.core import QgsProcessingException

    project = project_copy(sample, tmp_path / "crs.toml")
    text = project.read_text(encoding="utf-8")
    project.write_text(text.replace("[control]\n", '[control]\ncrs = "EPSG:4326"\n', 1),
                       encoding="utf-8")
    with pytest.raises(QgsProcessingException, match="does not transform them"):
        run("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                  "PROJECT": str(project),
                                  "SHAPE_POINTS": "TEMPORARY_OUTPUT"})
