"""Accuracy control, uncertainty bands, the equal-error map and the HTML reports through
``processing.run``, checked against the headless command line run in its venv (the same
numbers to 1e-9; the bands' areas to 1e-6 relative, their union being formed by a
different GEOS wrapper) and against definitions."""

import json
import re
import sys

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .conftest import run_headless  # noqa: E402
from .util import (  # noqa: E402
    ATOL,
    as_float,
    assert_same_values,
    close,
    columns,
    compare_summaries,
    project_copy,
    reorder,
)

pytestmark = pytest.mark.qgis

QA_OPTIONS = {"PRODUCT": 0, "SCALE": 2000.0, "CONTOUR_INTERVAL": 1.0}  # topographic map
QA_TABLE = ('\n[qa]\nproduct = "orthomosaic"\northophoto_scale = 5000\nterrain = "hilly"\n'
            "pixel_size = 0.015\n")


def run(alg, params, context=None, feedback=None):
    import processing

    return processing.run(f"vectoradjust:{alg}", params, context=context, feedback=feedback)


def error(alg, params, match):
    """Run ``alg``; it must fail with a message matching the regular expression ``match``."""
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match=match) as exc:
        run(alg, params)
    return str(exc.value)


def _load_json(path):
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def headless_qa(sample, tmp_path_factory):
    """``vectoradjust qa`` of the sample project as a 1:2000 map with 1 m contours."""
    out = tmp_path_factory.mktemp("headless_qa")
    run_headless(["-m", "vectoradjust.cli", "qa", str(sample / "project.toml"), "--out",
                  str(out), "--product", "topographic map", "--scale", "2000",
                  "--contour-interval", "1", "-q"])
    return _load_json(out / "qa.json")


@pytest.fixture(scope="module")
def qa_project(sample, tmp_path_factory):
    """The sample project with a [qa] table (an orthomosaic 1:5000, hilly terrain)."""
    return project_copy(sample, tmp_path_factory.mktemp("qa_project") / "project.toml",
                        extra=QA_TABLE)


@pytest.fixture(scope="module")
def headless_qa_table(qa_project, tmp_path_factory):
    out = tmp_path_factory.mktemp("headless_qa_table")
    run_headless(["-m", "vectoradjust.cli", "qa", str(qa_project), "--out", str(out), "-q"])
    return _load_json(out / "qa.json")


@pytest.fixture(scope="module")
def headless_equal_error(sample, tmp_path_factory):
    """``vectoradjust equal-error`` with the project's DEM and with ``--flat``."""
    out = {}
    for key, extra in (("dem", []), ("flat", ["--flat"])):
        d = tmp_path_factory.mktemp(f"headless_ee_{key}")
        run_headless(["-m", "vectoradjust.cli", "equal-error", str(sample / "project.toml"),
                      "--out", str(d), "-q", *extra])
        out[key] = d / "equal_error.tif"
    return out


# --------------------------------------------------------------------------- accuracy control
def _expected_rows(doc):
    rows = []
    for s in doc["stages"]:
        rows.append((s["name"], None, s["measured"], s["tolerance"], s["passed"], s["status"]))
        for p in s["points"]:
            rows.append((s["name"], str(p["id"]), p["value"], p["tolerance"], p["passed"],
                         {None: "n/a", True: "pass", False: "fail"}[p["passed"]]))
    return rows


def _check_qa_outputs(out, ref, qa_json):
    compare_summaries(_load_json(qa_json), ref, "qa.json")
    assert out["PASSED"] == ref["passed"]
    assert out["VERDICT"] == ref["verdict"]
    table = columns(out["OUTPUT"])
    expected = _expected_rows(ref)
    assert len(table["stage"]) == len(expected) > 0
    for k, name in enumerate(("stage", "id", "value", "tolerance", "passed", "status")):
        assert_same_values(table[name], [r[k] for r in expected], f"qa table.{name}")
    cp = columns(out["CONTROL_POINTS"])
    by_id = {c["id"]: c["qa"] for c in ref["control_points"]}
    assert by_id, "the reference judged no control point"
    for pid, qa in zip(cp["point_id"], cp["QA"]):
        assert (qa or "") == by_id.get(pid, ""), pid


def test_accuracy_control_matches_headless(qgis_app, sample, headless_qa, tmp_path):
    out = run("accuracycontrol", dict(QA_OPTIONS, PROJECT=str(sample / "project.toml"),
                                      OUTPUT="TEMPORARY_OUTPUT", QA_JSON=str(tmp_path / "qa.json"),
                                      CONTROL_POINTS="TEMPORARY_OUTPUT"))
    assert headless_qa["specification"]["product"] == "topographic map"
    _check_qa_outputs(out, headless_qa, tmp_path / "qa.json")


def test_accuracy_control_from_the_project_qa_table(qgis_app, qa_project, headless_qa_table,
                                                    tmp_path):
    """No product parameters: the project's [qa] table (an orthomosaic) is used."""
    out = run("accuracycontrol", {"PROJECT": str(qa_project), "OUTPUT": "TEMPORARY_OUTPUT",
                                  "QA_JSON": str(tmp_path / "qa.json"),
                                  "CONTROL_POINTS": "TEMPORARY_OUTPUT"})
    assert headless_qa_table["specification"]["product"] == "orthomosaic"
    assert headless_qa_table["pixel_size_source"] == "[qa] pixel_size"
    _check_qa_outputs(out, headless_qa_table, tmp_path / "qa.json")


def test_accuracy_control_parameters_override_the_qa_table(qgis_app, qa_project, headless_qa,
                                                           tmp_path):
    """The product parameters win over [qa] (the map spec of the reference; [qa] pixel_size
    0.015 stays, so only the pixel-independent stages are compared)."""
    out = run("accuracycontrol", dict(QA_OPTIONS, PROJECT=str(qa_project),
                                      PIXEL_SIZE=0.012, OUTPUT="TEMPORARY_OUTPUT",
                                      QA_JSON=str(tmp_path / "qa.json")))
    mine = _load_json(tmp_path / "qa.json")
    assert mine["specification"]["product"] == "topographic map"
    assert mine["specification"]["map_scale"] == 2000
    assert mine["pixel_size_mm"] == pytest.approx(0.012)
    compare_summaries(mine["tolerances"]["block"], headless_qa["tolerances"]["block"])
    compare_summaries(mine["control_points"], headless_qa["control_points"])
    assert out["VERDICT"] == mine["verdict"]


def test_accuracy_control_of_a_road_layer(qgis_app, sample):
    """With a road layer the adjustment is Adjust's; the block stage is the mean horizontal
    error of the control points, by definition."""
    params = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml")}
    out = run("accuracycontrol", dict(params, **QA_OPTIONS, OUTPUT="TEMPORARY_OUTPUT",
                                      CONTROL_POINTS="TEMPORARY_OUTPUT"))
    adj = run("adjustroadvectors", dict(params, CONTROL_POINTS="TEMPORARY_OUTPUT"))
    a, b = columns(out["CONTROL_POINTS"]), columns(adj["CONTROL_POINTS"])
    for f in ("point_id", "role", "AdjX", "AdjY", "AdjZ", "Vx", "Vy", "Vz", "CE90", "Used"):
        assert_same_values(a[f], b[f], f)
    ctrl = [i for i, (r, u) in enumerate(zip(b["role"], b["Used"])) if r == "control" and u == 1]
    e_xy = np.hypot(as_float(b["Vx"])[ctrl], as_float(b["Vy"])[ctrl])
    table = columns(out["OUTPUT"])
    row = [i for i, (s, pid) in enumerate(zip(table["stage"], table["id"]))
           if s == "block: GCP XY" and pid is None]
    assert len(row) == 1
    assert close(table["value"][row[0]], float(e_xy.mean()))
    pts = {pid: v for s, pid, v in zip(table["stage"], table["id"], table["value"])
           if s == "block: GCP XY" and pid is not None}
    assert_same_values([pts[b["point_id"][i]] for i in ctrl], e_xy.tolist(), "e_xy")


def test_accuracy_control_bad_inputs(qgis_app, sample, tmp_path):
    base = {"PROJECT": str(sample / "project.toml"), "OUTPUT": "TEMPORARY_OUTPUT"}
    msg = error("accuracycontrol", base, r"no product specification.*give 'Product' and")
    assert "no product specification" in msg and "[qa]" in msg
    # the dialog's parameters are named, not the command line's flags
    assert "--" not in msg and "'Product'" in msg and "'Scale denominator of the product'" in msg
    msg = error("accuracycontrol", dict(base, PRODUCT=0),
                r"\[qa\] map_scale is missing.*add map_scale")
    assert "map_scale is missing" in msg
    assert "--" not in msg and "command line" not in msg and "'Contour interval'" in msg
    msg = error("accuracycontrol", dict(base, **QA_OPTIONS, PIXEL_SIZE=0.0),
                r"pixel size 0 mm is not a pixel size\. Give the pixel size in millimetres")
    assert "not a pixel size" in msg
    msg = error("accuracycontrol", dict(base, PROJECT=str(tmp_path / "nope.toml"), PRODUCT=1,
                                        SCALE=2000.0),
                r"nope\.toml' does not exist\. Give the path of a TOML project file")
    assert "nope.toml" in msg and "does not exist" in msg


def test_adjust_control_points_have_the_qa_field(qgis_app, sample, qa_project, tmp_path):
    """A project with [qa]: the control_points layer of Adjust has QA, as the headless one."""
    from qgis.core import QgsVectorLayer

    out_dir = tmp_path / "headless"
    run_headless(["-m", "vectoradjust.cli", "adjust", str(qa_project), "--out", str(out_dir),
                  "--vectors", "OSM", "--no-bands", "-q"])
    ref = columns(QgsVectorLayer(f"{out_dir / 'adjusted.gpkg'}|layername=control_points", "c",
                                 "ogr"))
    out = run("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                    "PROJECT": str(qa_project),
                                    "CONTROL_POINTS": "TEMPORARY_OUTPUT"})
    mine = columns(out["CONTROL_POINTS"])
    fields = [f for f in ref if f not in ("fid", "_geom")]
    assert [f for f in mine if f != "_geom"] == fields and fields[-1] == "QA"
    ref = reorder(ref, "point_id", mine["point_id"])
    for f in fields:
        assert_same_values(mine[f], ref[f], f)
    assert set(mine["QA"]) <= {"pass", "fail", None, ""} and "pass" in mine["QA"]


# --------------------------------------------------------------------------- uncertainty bands
def test_uncertainty_bands_match_headless(qgis_app, sample, headless_adjust):
    from qgis.core import QgsGeometry, QgsPointXY, QgsVectorLayer, QgsWkbTypes

    out = run("uncertaintybands", {"INPUT": str(sample / "osm_roads.shp"),
                                   "PROJECT": str(sample / "project.toml"),
                                   "OUTPUT": "TEMPORARY_OUTPUT"})
    layer = out["OUTPUT"]
    assert QgsWkbTypes.flatType(layer.wkbType()) == QgsWkbTypes.MultiPolygon
    mine = columns(layer)
    ref_layer = QgsVectorLayer(f"{headless_adjust['gpkg']}|layername=uncertainty_bands", "b",
                               "ogr")
    assert ref_layer.isValid()
    ref = columns(ref_layer)
    assert [f for f in mine if f != "_geom"] == ["database", "feature_id", "confidence", "NSeg"]
    assert mine["feature_id"] == ref["feature_id"]  # same features, same order
    assert out["BANDS"] == len(ref["feature_id"]) > 0
    for f in ("database", "confidence", "NSeg"):
        assert_same_values(mine[f], ref[f], f)
    a = np.array([g.area() for g in mine["_geom"]])
    b = np.array([g.area() for g in ref["_geom"]])
    assert np.all(b > 0) and np.max(np.abs(a - b) / b) <= 1e-6
    assert close(out["AREA"], float(a.sum()), 1e-6 * a.sum())
    for g, h in zip(mine["_geom"], ref["_geom"]):
        assert g.symDifference(h).area() <= 1e-6 * h.area()
    # the band of a segment contains the segment: every measured vertex of a feature
    # with a band lies inside it (at its adjusted position)
    pts = columns(run("adjustroadvectors", {
        "INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml"),
        "SHAPE_POINTS": "TEMPORARY_OUTPUT"})["SHAPE_POINTS"])
    band = dict(zip(mine["feature_id"], mine["_geom"]))
    inside = 0
    for fid, x, y, adj in zip(pts["feature_id"], pts["AdjX"], pts["AdjY"], pts["Adjusted"]):
        if adj == 1 and fid in band:
            assert band[fid].distance(QgsGeometry.fromPointXY(QgsPointXY(x, y))) <= 1e-6, fid
            inside += 1
    assert inside > 100


def test_uncertainty_bands_grow_with_confidence(qgis_app, sample):
    params = {"INPUT": str(sample / "tiger_roads.shp"), "PROJECT": str(sample / "project.toml"),
              "OUTPUT": "TEMPORARY_OUTPUT"}
    small = columns(run("uncertaintybands", dict(params, CONFIDENCE=0.5))["OUTPUT"])
    large = columns(run("uncertaintybands", dict(params, CONFIDENCE=0.99))["OUTPUT"])
    assert small["feature_id"] == large["feature_id"] and small["feature_id"]
    assert set(small["confidence"]) == {0.5} and set(large["confidence"]) == {0.99}
    for g, h in zip(small["_geom"], large["_geom"]):
        assert g.area() < h.area()
        assert g.difference(h).area() <= 1e-9 * g.area()  # nested


def test_uncertainty_bands_bad_inputs(qgis_app, sample):
    params = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml"),
              "OUTPUT": "TEMPORARY_OUTPUT"}
    for c in (1.0, 0.0):
        msg = error("uncertaintybands", dict(params, CONFIDENCE=c),
                    r"confidence [01] is not a probability between 0 and 1\. Give e\.g\. 0\.9")
        assert "not a probability" in msg
    msg = error("uncertaintybands", dict(params, ID_FIELD="no_such_field"),
                r"'no_such_field' is not a field of the layer.*Choose an existing field")
    assert "'no_such_field' is not a field" in msg


# --------------------------------------------------------------------------- equal-error map
def _raster(path):
    from osgeo import gdal  # QGIS's own GDAL

    ds = gdal.Open(str(path))
    assert ds is not None, path
    bands = [ds.GetRasterBand(i) for i in (1, 2, 3)]
    return {
        "gt": ds.GetGeoTransform(), "wkt": ds.GetProjection(), "count": ds.RasterCount,
        "desc": [b.GetDescription() for b in bands], "nodata": [b.GetNoDataValue() for b in bands],
        "dtype": [gdal.GetDataTypeName(b.DataType) for b in bands],
        "meta": ds.GetMetadata(), "data": np.stack([b.ReadAsArray() for b in bands]),
        "compress": ds.GetMetadata("IMAGE_STRUCTURE").get("COMPRESSION"),
    }


@pytest.mark.parametrize("flat", [False, True])
def test_equal_error_map_matches_headless(qgis_app, sample, headless_equal_error, tmp_path,
                                          flat):
    from osgeo import osr

    path = tmp_path / "ee.tif"
    out = run("equalerrormap", {"PROJECT": str(sample / "project.toml"), "FLAT": flat,
                                "OUTPUT": str(path)})
    assert out["OUTPUT"] == str(path)
    mine, ref = _raster(path), _raster(headless_equal_error["flat" if flat else "dem"])
    assert mine["count"] == ref["count"] == 3
    assert mine["gt"] == ref["gt"]
    a, b = osr.SpatialReference(), osr.SpatialReference()
    a.ImportFromWkt(mine["wkt"])
    b.ImportFromWkt(ref["wkt"])
    assert a.IsSame(b)
    for key in ("desc", "nodata", "dtype", "meta", "compress"):
        assert mine[key] == ref[key], key
    assert mine["desc"] == ["sigma X (m)", "sigma Y (m)", "sigma Z (m)"]
    x, y = mine["data"], ref["data"]
    nodata = ref["nodata"][0]
    assert np.array_equal(x == nodata, y == nodata) and (x != nodata).any()
    ok = x != nodata
    # float32 storage: the same to 1e-9 or, when the 1e-13 of two runs crosses a float32
    # rounding boundary, to one float32 step
    tol = np.maximum(ATOL, np.spacing(np.abs(y[ok]).astype(np.float32)))
    assert np.all(np.abs(x[ok].astype(float) - y[ok]) <= tol)
    assert out["NODES"] == int(ok[2].sum())
    sh = np.hypot(x[0][ok[0]].astype(float), x[1][ok[1]].astype(float))
    assert abs(out["SIGMA_H_MAX"] - sh.max()) <= 1e-6 and abs(out["SIGMA_Z_MIN"]
                                                              - x[2][ok[2]].min()) <= 1e-6
    # a point is intersected worst in height (height-to-base ratio ~ 4)
    assert np.all(x[2][ok[2]] > x[0][ok[0]]) and np.all(x[2][ok[2]] > x[1][ok[1]])


def test_equal_error_map_bad_inputs(qgis_app, sample, tmp_path):
    base = {"PROJECT": str(sample / "project.toml"), "OUTPUT": str(tmp_path / "ee.tif")}
    assert "give two image ids" in error("equalerrormap", dict(base, IMAGE_PAIR="L"),
                                         r"'L': give two image ids\. Write the two image ids")
    msg = error("equalerrormap", dict(base, IMAGE_PAIR="L, X"),
                r"not two different images.*\(unknown: X\)\. Name two of: L, R")
    assert "not two different images" in msg and "unknown: X" in msg
    assert "not positive" in error("equalerrormap", dict(base, SPACING=0.0),
                                   r"spacing 0 m is not positive\. Give a spacing in metres")


# --------------------------------------------------------------------------- HTML reports
def _tokens(path):
    """The report's HTML as tag-level tokens, figures and the time of writing masked."""
    text = path.read_text(encoding="utf-8")
    n_img = text.count("data:image/png;base64,")
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "PNG", text)
    text = re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d", "DATE", text)
    return re.split(r"(?=<)", text), n_img


def test_reports_match_headless(qgis_app, sample, headless_adjust, headless_compare, tmp_path):
    """Adjust's and Compare's REPORT: the command line's report.html, word for word (the
    figures drawn by QGIS's matplotlib are compared by number only), and no pyplot."""
    out = run("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                    "PROJECT": str(sample / "project.toml"),
                                    "REPORT": str(tmp_path / "adjust" / "report.html")})
    assert out["REPORT"] == str(tmp_path / "adjust" / "report.html")
    mine, n_mine = _tokens(tmp_path / "adjust" / "report.html")
    ref, n_ref = _tokens(headless_adjust["dir"] / "report.html")
    assert n_mine == n_ref >= 3
    assert mine == ref
    out = run("compareroaddatabases", {
        "LAYERS": [str(sample / f"{n}_roads.shp") for n in ("osm", "tnm", "tiger")],
        "PROJECT": str(sample / "project.toml"), "OUTPUT": "TEMPORARY_OUTPUT",
        "REPORT": str(tmp_path / "compare.html")})
    mine, n_mine = _tokens(tmp_path / "compare.html")
    ref, n_ref = _tokens(headless_compare / "report.html")
    assert n_mine == n_ref >= 4
    assert mine == ref
    assert "matplotlib.pyplot" not in sys.modules


def test_report_without_matplotlib_says_so(qgis_app, sample, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    msg = error("adjustroadvectors", {"INPUT": str(sample / "osm_roads.shp"),
                                      "PROJECT": str(sample / "project.toml"),
                                      "REPORT": str(tmp_path / "report.html")},
                r"report needs matplotlib.*install it")
    assert "needs matplotlib" in msg and "python3-matplotlib" in msg
    assert not (tmp_path / "report.html").exists()
