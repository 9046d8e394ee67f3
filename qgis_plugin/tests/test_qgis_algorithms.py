"""The four algorithms through ``processing.run`` on the sample project, checked against
the headless core in its venv and against the core run in this process on arrays read
without the QGIS layer API: the same numbers to 1e-9.

(Not bit for bit: two runs of the same adjustment in one process already differ by
~1e-13, numpy's SIMD sums depending on memory alignment.)"""

import json
import math

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .util import (  # noqa: E402
    ATOL,
    as_float,
    assert_same_values,
    close,
    columns,
    compare_summaries,
    reorder,
    vertices,
)

pytestmark = pytest.mark.qgis

SINKS = ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS")
SHAPE_KEYS = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ",
              "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "NImages", "Adjusted", "Database"]


def run(alg, params, context=None, feedback=None):
    import processing

    return processing.run(f"vectoradjust:{alg}", params, context=context, feedback=feedback)


def adjust_params(sample, **extra):
    p = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml")}
    for k in SINKS:
        p[k] = "TEMPORARY_OUTPUT"
    p.update(extra)
    return p


@pytest.fixture(scope="module")
def adjusted(qgis_app, sample, tmp_path_factory):
    summary = tmp_path_factory.mktemp("qgis_adjust") / "summary.json"
    out = run("adjustroadvectors", adjust_params(sample, SUMMARY=str(summary)))
    out["_summary_file"] = summary
    return out


# --------------------------------------------------------------------------- extract
def _plain_extract(sample, unique_tol=0.001):
    from vectoradjust.adjust.shapepoints import extract_shape_points

    from .plain_reference import dem_heights, read_lines

    layer = read_lines(sample / "osm_roads.shp", "OSM", "osm_id")
    layer.coords[:, 2] = dem_heights(sample / "dem.tif", layer.coords[:, :2])
    return layer, extract_shape_points(layer, unique_tol)


def test_extract_shape_points_matches_core(qgis_app, sample, headless_reference):
    out = run("extractshapepoints", {
        "INPUT": str(sample / "osm_roads.shp"), "ID_FIELD": "osm_id",
        "DEM": str(sample / "dem.tif"), "UNIQUE": False, "OUTPUT": "TEMPORARY_OUTPUT"})
    cols = columns(out["OUTPUT"])
    layer, sp = _plain_extract(sample)
    assert out["COUNT"] == len(sp.vertex_ids) == 225
    assert out["UNCOVERED"] == 0
    assert cols["point_id"] == sp.vertex_ids.tolist()
    assert cols["feature_id"] == layer.feature_ids[layer.vertex_feature].tolist()
    assert cols["vertex"] == layer.vertex_index.tolist()
    assert cols["part"] == layer.vertex_part.tolist()
    assert cols["object_id"] == sp.object_ids[sp.vertex_object].tolist()
    for k, c in zip("XYZ", range(3)):
        # same arrays as the plain reader: identical
        assert np.array_equal(as_float(cols[k]), layer.coords[:, c]), k
    geo = np.array([vertices(g)[0] for g in cols["_geom"]])
    assert np.array_equal(geo, layer.coords)

    ref = headless_reference("extract", sample / "osm_roads.shp", "osm_id", sample / "dem.tif",
                             "EPSG:32616", 0.001)
    assert cols["point_id"] == ref["vertex_ids"]
    assert cols["object_id"] == ref["object_ids"]
    assert cols["vertex"] == ref["vertex_index"]
    for k, c in zip("XYZ", range(3)):
        assert_same_values(cols[k], [r[c] for r in ref["coords"]], k)


def test_extract_one_point_per_object(qgis_app, sample):
    out = run("extractshapepoints", {
        "INPUT": str(sample / "tiger_roads.shp"), "ID_FIELD": "tlid",
        "DEM": str(sample / "dem.tif"), "OUTPUT": "TEMPORARY_OUTPUT"})
    cols = columns(out["OUTPUT"])
    assert len(cols["point_id"]) == len(set(cols["object_id"]))
    assert cols["point_id"] == cols["object_id"]
    assert sum(cols["NShared"]) == 155  # every vertex of the layer once
    assert max(cols["NShared"]) >= 2  # intersections are shared


def test_extract_without_dem_keeps_layer_z(qgis_app, sample):
    out = run("extractshapepoints", {"INPUT": str(sample / "osm_roads.shp"),
                                     "OUTPUT": "TEMPORARY_OUTPUT", "UNIQUE": False})
    cols = columns(out["OUTPUT"])
    assert out["UNCOVERED"] == out["COUNT"] == 225  # a 2D layer has no heights
    assert all(v is None for v in cols["Z"])
    assert cols["point_id"][0] == "0_0"  # no id field: the 0-based feature index


def test_layer_in_another_crs_is_transformed(qgis_app, sample):
    """A road layer in Web Mercator comes back to the ground CRS (UTM) to within a micrometre."""
    import processing

    merc = processing.run("native:reprojectlayer", {
        "INPUT": str(sample / "osm_roads.shp"), "TARGET_CRS": "EPSG:3857",
        "OUTPUT": "TEMPORARY_OUTPUT"})["OUTPUT"]
    assert merc.crs().authid() == "EPSG:3857"
    out = run("extractshapepoints", {"INPUT": merc, "ID_FIELD": "osm_id",
                                     "GROUND_CRS": "EPSG:32616", "DEM": str(sample / "dem.tif"),
                                     "UNIQUE": False, "OUTPUT": "TEMPORARY_OUTPUT"})
    assert out["OUTPUT"].crs().authid() == "EPSG:32616"
    cols = columns(out["OUTPUT"])
    layer, sp = _plain_extract(sample)
    assert cols["point_id"] == sp.vertex_ids.tolist()
    for k, c in zip("XYZ", range(3)):
        assert np.abs(as_float(cols[k]) - layer.coords[:, c]).max() < 1e-6, k


def test_dem_window_read_matches_full_read(qgis_app, sample, monkeypatch):
    from qgis.core import QgsCoordinateReferenceSystem, QgsProcessingContext, QgsRasterLayer

    from qgis_plugin import qgis_io

    from .plain_reference import dem_heights, read_lines

    layer = read_lines(sample / "osm_roads.shp", "OSM", "osm_id")
    xy = np.vstack([layer.coords[:, :2], [[505790.0, 4475515.0], [0.0, 0.0]]])  # nodata, out
    dem = QgsRasterLayer(str(sample / "dem.tif"), "dem", "gdal")
    crs = QgsCoordinateReferenceSystem("EPSG:32616")
    ctx = QgsProcessingContext()
    full = qgis_io.dem_heights(dem, xy, crs, ctx, "dem")
    assert np.array_equal(full, dem_heights(sample / "dem.tif", xy), equal_nan=True)
    assert np.isnan(full[-2:]).all()
    monkeypatch.setattr(qgis_io, "FULL_READ_MAX_CELLS", 0)
    window = qgis_io.dem_heights(dem, xy, crs, ctx, "dem")
    assert np.array_equal(np.isnan(window), np.isnan(full))
    assert np.nanmax(np.abs(window - full)) <= ATOL


# --------------------------------------------------------------------------- adjust
def test_adjust_numbers_match_headless(adjusted, headless_adjust):
    s = headless_adjust["summary"]
    assert close(adjusted["SIGMA0_SQUARED"], s["sigma0_squared"])
    assert adjusted["DEGREES_OF_FREEDOM"] == s["degrees_of_freedom"]
    assert adjusted["ITERATIONS"] == s["iterations"]
    assert adjusted["CHI_SQUARE_PASSED"] == s["chi_square"]["passed"]
    assert close(adjusted["RMSE"], s["shape_points"]["rmse_horizontal"])
    assert close(adjusted["RMSE_CHECK"], s["check_points"]["rmse_horizontal"])
    assert close(adjusted["MEAN_CE90"], s["mean_ce90"])
    with open(adjusted["_summary_file"], encoding="utf-8") as fh:
        mine = json.load(fh)
    compare_summaries(mine, s)


@pytest.mark.parametrize("sink,layer,key", [
    ("SHAPE_POINTS", "shape_points", "point_id"),
    ("CONTROL_POINTS", "control_points", "point_id"),
    ("FEATURES", "features", "osm_id"),
])
def test_adjust_layers_match_headless(adjusted, headless_adjust, sink, layer, key):
    from qgis.core import QgsVectorLayer

    ref_layer = QgsVectorLayer(f"{headless_adjust['gpkg']}|layername={layer}", layer, "ogr")
    assert ref_layer.isValid()
    mine = columns(adjusted[sink])
    ref = columns(ref_layer)
    ref_fields = [f for f in ref if f not in ("fid", "_geom")]
    assert [f for f in mine if f != "_geom"] == ref_fields  # same fields, same order
    assert sorted(map(str, mine[key])) == sorted(map(str, ref[key]))
    ref = reorder(ref, key, mine[key])
    for f in ref_fields:
        assert_same_values(mine[f], ref[f], f"{layer}.{f}")
    for g, h in zip(mine["_geom"], ref["_geom"]):
        a, b = vertices(g), vertices(h)
        assert a.shape == b.shape and np.nanmax(np.abs(a - b)) <= ATOL


def test_adjust_identical_to_core_on_plain_arrays(adjusted, sample):
    """pipeline.run on arrays read without QGIS's layer API gives the same numbers."""
    from vectoradjust.pipeline import run as run_pipeline

    from .plain_reference import project_data

    data = project_data(sample / "project.toml")  # every database, OSM adjusted
    ref = run_pipeline(data, vectors=["OSM"])
    v = ref.databases[0].vertices
    mine = columns(adjusted["SHAPE_POINTS"])
    assert mine["point_id"] == v["point_id"].tolist()
    for f in SHAPE_KEYS[2:-1]:
        x = as_float(mine[f])
        y = np.asarray(v[f], float).copy()
        if f in ("Vx", "Vy", "Vz", "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90"):
            y[v["Source"] == "unchanged"] = np.nan  # conflated vertices carry values
        assert_same_values(x.tolist(), y.tolist(), f)
    assert close(adjusted["SIGMA0_SQUARED"], ref.summary["sigma0_squared"])
    c = columns(adjusted["CONTROL_POINTS"])
    for f in ("AdjX", "AdjY", "AdjZ", "CE90", "LE90"):
        assert_same_values(as_float(c[f]).tolist(), ref.control_points[f].tolist(), f)
    feats = columns(adjusted["FEATURES"])
    for f in ("RMSE", "Length", "NAdj"):
        assert_same_values(as_float(feats[f]).tolist(),
                           np.asarray(ref.databases[0].features[f], float).tolist(), f)


def test_adjust_shape_points_say_how_each_vertex_was_placed(adjusted):
    """The conflation's Source field: measured where Adjusted = 1, else predicted (with its
    CE90) or unchanged (nulls), and the point sits at AdjX/AdjY."""
    c = columns(adjusted["SHAPE_POINTS"])
    src = np.array(c["Source"], dtype=object)
    adj = np.array(c["Adjusted"]) == 1
    assert set(src) <= {"measured", "interpolated", "extrapolated", "unchanged"}
    assert np.array_equal(src == "measured", adj)
    pred = np.isin(src, ["interpolated", "extrapolated"])
    assert pred.any()
    ce = as_float(c["CE90"])
    assert np.isfinite(ce[pred]).all() and np.isnan(ce[src == "unchanged"]).all()
    xy = np.array([[g.asPoint().x(), g.asPoint().y()] for g in c["_geom"]])
    assert np.allclose(xy, np.column_stack([as_float(c["AdjX"]), as_float(c["AdjY"])]))


def test_adjusted_features_keep_attributes_and_geometry(adjusted, sample):
    from qgis.core import QgsVectorLayer

    src = columns(QgsVectorLayer(str(sample / "osm_roads.shp"), "osm", "ogr"))
    feats = columns(adjusted["FEATURES"])
    for f in ("osm_id", "name", "highway"):
        assert feats[f] == src[f], f
    pts = columns(adjusted["SHAPE_POINTS"])
    by_feature = {}
    for fid, x, y in zip(pts["feature_id"], pts["AdjX"], pts["AdjY"]):
        by_feature.setdefault(fid, []).append((x, y))
    for osm_id, g in zip(feats["osm_id"], feats["_geom"]):
        assert np.array_equal(vertices(g)[:, :2], np.array(by_feature[str(osm_id)]))
    assert all(n >= a for n, a in zip(feats["NPts"], feats["NAdj"]))


def test_residual_vectors(adjusted, qgis_app, sample):
    pts = columns(adjusted["SHAPE_POINTS"])
    res = columns(adjusted["RESIDUALS"])
    measured = [i for i, a in enumerate(pts["Adjusted"]) if a == 1]
    assert len(res["point_id"]) == len(measured) == 211
    k = {p: i for i, p in enumerate(pts["point_id"])}
    for pid, g, vx, vy, v in zip(res["point_id"], res["_geom"], res["Vx"], res["Vy"], res["V"]):
        i = k[pid]
        xyz = vertices(g)
        assert xyz.shape == (2, 3)
        assert (xyz[0, 0], xyz[0, 1]) == (pts["X"][i], pts["Y"][i])
        assert abs(xyz[1, 0] - pts["AdjX"][i]) <= ATOL and abs(xyz[1, 1] - pts["AdjY"][i]) <= ATOL
        assert close(v, math.hypot(vx, vy))
    # exaggerated vectors: the end moves, the residual fields do not
    out = run("adjustroadvectors", adjust_params(sample, RESIDUAL_SCALE=10.0))
    res10 = columns(out["RESIDUALS"])
    assert_same_values(res10["Vx"], res["Vx"], "Vx")  # two runs: the same to 1e-9
    g0, g10 = vertices(res["_geom"][0]), vertices(res10["_geom"][0])
    assert np.allclose(g10[1, :2] - g10[0, :2], 10 * (g0[1, :2] - g0[0, :2]), atol=1e-6)


def _memory_measurements(sample):
    """image_points.csv as a memory table with typed (double) fields."""
    import csv

    from qgis.core import QgsFeature, QgsVectorLayer

    lyr = QgsVectorLayer("None?field=point_id:string&field=image_id:string&field=x:double&"
                         "field=y:double&field=sigma_x:double&field=sigma_y:double&"
                         "field=comment:string", "image_points", "memory")
    feats = []
    with open(sample / "image_points.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            f = QgsFeature(lyr.fields())
            f.setAttributes([row["point_id"], row["image_id"], float(row["x"]), float(row["y"]),
                             float(row["sigma_x"]), float(row["sigma_y"]), "extra column"])
            feats.append(f)
    lyr.dataProvider().addFeatures(feats)
    return lyr


def _memory_control(sample):
    """gcps.csv as a point layer: X, Y in the geometry (no X/Y fields)."""
    import csv

    from qgis.core import QgsFeature, QgsGeometry, QgsPointXY, QgsVectorLayer

    lyr = QgsVectorLayer("Point?crs=EPSG:32616&field=point_id:string&field=Z:double&"
                         "field=sigma_x:double&field=sigma_y:double&field=sigma_z:double&"
                         "field=role:string", "gcps", "memory")
    feats = []
    with open(sample / "gcps.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            f = QgsFeature(lyr.fields())
            f.setAttributes([row["point_id"], float(row["Z"]), float(row["sigma_x"]),
                             float(row["sigma_y"]), float(row["sigma_z"]), row["role"]])
            f.setGeometry(QgsGeometry.fromPointXY(QgsPointXY(float(row["X"]), float(row["Y"]))))
            feats.append(f)
    lyr.dataProvider().addFeatures(feats)
    return lyr


def _images_matrix(sample):
    from vectoradjust.files.project import load_project

    spec = load_project(sample / "project.toml")
    m = []
    for im in spec.images:
        m += [im.id, *map(repr, im.position.tolist()), *map(repr, im.attitude.tolist()),
              im.sigma_position, im.sigma_attitude, im.date]
    return m


def _plain_project(sample, path):
    """A project file with the sample's images, tables and settings but a plain camera
    (focal length and principal point only, no corrections): what parameters can say."""
    from vectoradjust.files.project import load_project

    spec = load_project(sample / "project.toml")
    lines = ['crs = "EPSG:32616"', "[camera]", "focal_length = 152.4",
             "principal_point = [0.0, 0.0]"]
    for im in spec.images:
        lines += ["[[images]]", f'id = "{im.id}"', f"position = {im.position.tolist()}",
                  f"attitude = {im.attitude.tolist()}", f"sigma_position = {im.sigma_position}",
                  f"sigma_attitude = {im.sigma_attitude}", f'date = "{im.date}"']
    lines += ["[measurements]", f"path = {json.dumps(str(sample / 'image_points.csv'))}",
              "sigma = 0.015", "[control]", f"path = {json.dumps(str(sample / 'gcps.csv'))}",
              "[adjustment]", f"max_iterations = {spec.settings.max_iterations}",
              f'reweight = "{spec.settings.reweight}"', f"alpha = {spec.settings.alpha}"]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return spec.settings


def test_adjust_from_parameters_and_layers(qgis_app, sample, tmp_path):
    """No project file: camera and images as parameters, measurements as a table layer,
    control as a point layer: the same adjustment as from a project file."""
    from qgis_plugin.algorithms.inputs import REWEIGHT_OPTIONS

    settings = _plain_project(sample, tmp_path / "plain.toml")
    layer = {"INPUT": str(sample / "osm_roads.shp"), "ID_FIELD": "osm_id", "NAME": "OSM",
             "DEM": str(sample / "dem.tif"), "SIGMA_XY": 10.0, "SIGMA_Z": 10.0}
    params = dict(layer, **{
        "REWEIGHT": REWEIGHT_OPTIONS.index(settings.reweight),
        "MAX_ITERATIONS": settings.max_iterations, "ALPHA": settings.alpha,
        "MEASUREMENTS": _memory_measurements(sample), "CONTROL": _memory_control(sample),
        "FOCAL_LENGTH": 152.4, "PRINCIPAL_POINT_X": 0.0, "PRINCIPAL_POINT_Y": 0.0,
        "IMAGES": _images_matrix(sample), "GROUND_CRS": "EPSG:32616",
    })
    for k in SINKS:
        params[k] = "TEMPORARY_OUTPUT"
    out = run("adjustroadvectors", params)
    ref = run("adjustroadvectors", dict(layer, PROJECT=str(tmp_path / "plain.toml"),
                                        **{k: "TEMPORARY_OUTPUT" for k in SINKS}))
    a, b = columns(out["SHAPE_POINTS"]), columns(ref["SHAPE_POINTS"])
    for f in SHAPE_KEYS:
        assert_same_values(a[f], b[f], f)
    assert close(out["SIGMA0_SQUARED"], ref["SIGMA0_SQUARED"])
    c, d = columns(out["CONTROL_POINTS"]), columns(ref["CONTROL_POINTS"])
    for f in ("point_id", "role", "X", "Y", "Z", "AdjX", "AdjY", "AdjZ", "CE90", "Used"):
        assert_same_values(c[f], d[f], f)


def test_adjust_reports_progress(qgis_app, sample):
    from qgis.core import QgsProcessingFeedback

    seen = {"progress": [], "text": []}

    class Recorder(QgsProcessingFeedback):
        def setProgressText(self, text):
            seen["text"].append(text)
            super().setProgressText(text)

    fb = Recorder()
    fb.progressChanged.connect(lambda p: seen["progress"].append(p))
    run("adjustroadvectors", adjust_params(sample), feedback=fb)
    assert seen["progress"][-1] == 100
    assert any("adjustment pass" in t for t in seen["text"])
    assert seen["progress"] == sorted(seen["progress"])


# --------------------------------------------------------------------------- compare
def test_compare_matches_headless(qgis_app, sample, headless_compare, tmp_path):
    from qgis.core import QgsVectorLayer

    folder = tmp_path / "compare"
    out = run("compareroaddatabases", {
        "LAYERS": [str(sample / f"{n}_roads.shp") for n in ("osm", "tnm", "tiger")],
        "PROJECT": str(sample / "project.toml"), "OUTPUT": "TEMPORARY_OUTPUT",
        "SHAPE_POINTS": "TEMPORARY_OUTPUT", "RESIDUALS": "TEMPORARY_OUTPUT",
        "OUTPUT_FOLDER": str(folder)})
    table = columns(out["OUTPUT"])
    with open(headless_compare / "compare.json", encoding="utf-8") as fh:
        ref_rows = json.load(fh)
    assert table["database"] == [r["database"] for r in ref_rows] == ["OSM", "TNM", "TIGER"]
    for key in ref_rows[0]:
        assert_same_values(table[key], [r[key] for r in ref_rows], f"compare.{key}")
    # the truth is known in the sample: recovery and improvement are there
    assert all(r is not None for r in table["recovery"])
    with open(folder / "compare.json", encoding="utf-8") as fh:
        compare_summaries(json.load(fh), ref_rows, "compare.json")
    for name in ("OSM", "TNM", "TIGER"):
        with open(folder / name / "summary.json", encoding="utf-8") as fh:
            mine = json.load(fh)
        with open(headless_compare / name / "summary.json", encoding="utf-8") as fh:
            compare_summaries(mine, json.load(fh), f"{name}/summary.json")
        for layer, key in (("shape_points", "point_id"), ("control_points", "point_id")):
            a = columns(QgsVectorLayer(f"{folder / name / 'adjusted.gpkg'}|layername={layer}",
                                       layer, "ogr"))
            b = columns(QgsVectorLayer(
                f"{headless_compare / name / 'adjusted.gpkg'}|layername={layer}", layer, "ogr"))
            b = reorder(b, key, a[key])
            for f in b:
                if f not in ("fid", "_geom"):
                    assert_same_values(a[f], b[f], f"{name}.{layer}.{f}")
    pts = columns(out["SHAPE_POINTS"])
    assert sorted(set(pts["Database"])) == ["OSM", "TIGER", "TNM"]
    assert len(pts["point_id"]) == 225 + 283 + 155


# --------------------------------------------------------------------------- buffer
def test_buffer_test_matches_core(qgis_app, sample, tmp_path, headless_reference):
    adjusted_file = tmp_path / "features.gpkg"
    run("adjustroadvectors", adjust_params(sample, FEATURES=str(adjusted_file),
                                           SHAPE_POINTS="TEMPORARY_OUTPUT"))
    widths = "0.5,1,2,5,10"
    for tested in (sample / "osm_roads.shp", adjusted_file):
        out = run("bufferaccuracytest", {"INPUT": str(tested),
                                         "REFERENCE": str(sample / "truth_roads.shp"),
                                         "WIDTHS": widths, "OUTPUT": "TEMPORARY_OUTPUT"})
        cols = columns(out["OUTPUT"])
        ref = headless_reference("buffer", tested, sample / "truth_roads.shp", widths)
        assert_same_values(cols["width"], [r["width"] for r in ref], "width")
        assert_same_values(cols["share"], [r["share"] for r in ref], "share")
        assert_same_values(cols["inside"], [r["length_inside"] for r in ref], "inside")
        assert_same_values(cols["total"], [r["length_total"] for r in ref], "total")
        assert all(a <= b + 1e-12 for a, b in zip(cols["share"], cols["share"][1:]))
    # the adjusted roads are much closer to the truth than the database
    assert cols["share"][1] > 0.5


def _memory_lines(wkts, crs="EPSG:32616", name="lines"):
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer

    uri = "LineString" + (f"?crs={crs}" if crs else "")
    lyr = QgsVectorLayer(uri + ("&" if crs else "?") + "field=id:integer", name, "memory")
    feats = []
    for i, w in enumerate(wkts):
        f = QgsFeature(lyr.fields())
        f.setAttributes([i])
        f.setGeometry(QgsGeometry.fromWkt(w))
        feats.append(f)
    lyr.dataProvider().addFeatures(feats)
    if not crs:
        from qgis.core import QgsCoordinateReferenceSystem

        lyr.setCrs(QgsCoordinateReferenceSystem())
    return lyr


def test_buffer_test_parallel_line(qgis_app):
    ref = _memory_lines(["LineString (500000 4000000, 500100 4000000)"], name="ref")
    tst = _memory_lines(["LineString (500000 4000003, 500100 4000003)"], name="tested")
    out = run("bufferaccuracytest", {"INPUT": tst, "REFERENCE": ref, "WIDTHS": "0 2.9; 3.1 10",
                                     "OUTPUT": "TEMPORARY_OUTPUT"})
    cols = columns(out["OUTPUT"])
    assert cols["width"] == [0.0, 2.9, 3.1, 10.0]
    assert cols["share"] == [0.0, 0.0, 1.0, 1.0]
    assert cols["percent"][2] == 100.0 and cols["total"][0] == pytest.approx(100.0)


# --------------------------------------------------------------------------- bad inputs
def _error(alg, params, match):
    """Run ``alg``; it must fail with a message matching the regular expression ``match``."""
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match=match) as exc:
        run(alg, params)
    return str(exc.value)


def _memory_points(crs="EPSG:32616"):
    from qgis.core import QgsFeature, QgsGeometry, QgsPointXY, QgsVectorLayer

    lyr = QgsVectorLayer(f"Point?crs={crs}&field=id:integer", "points", "memory")
    f = QgsFeature(lyr.fields())
    f.setAttributes([1])
    f.setGeometry(QgsGeometry.fromPointXY(QgsPointXY(506400, 4475000)))
    lyr.dataProvider().addFeatures([f])
    return lyr


@pytest.mark.parametrize("alg", ["adjustroadvectors", "extractshapepoints"])
def test_wrong_geometry_type(qgis_app, sample, alg):
    params = adjust_params(sample, INPUT=_memory_points()) if alg == "adjustroadvectors" else {
        "INPUT": _memory_points(), "OUTPUT": "TEMPORARY_OUTPUT"}
    msg = _error(alg, params, r"holds Point geometries, not lines\. Give the road centrelines")
    assert "points" in msg and "not lines" in msg


@pytest.mark.parametrize("alg", ["adjustroadvectors", "extractshapepoints"])
def test_missing_id_field(qgis_app, sample, alg):
    params = adjust_params(sample, ID_FIELD="no_such_field") if alg == "adjustroadvectors" else {
        "INPUT": str(sample / "osm_roads.shp"), "ID_FIELD": "no_such_field",
        "OUTPUT": "TEMPORARY_OUTPUT"}
    msg = _error(alg, params, r"'no_such_field' is not a field.*Choose an existing field")
    assert "'no_such_field' is not a field" in msg and "osm_id" in msg and "osm_roads" in msg


def test_layer_without_crs(qgis_app, sample):
    lines = _memory_lines(["LineString (506300 4474850, 506400 4474850)"], crs=None,
                          name="nocrs")
    assert not lines.crs().isValid()
    for alg, params in (
        ("extractshapepoints", {"INPUT": lines, "OUTPUT": "TEMPORARY_OUTPUT"}),
        ("adjustroadvectors", adjust_params(sample, INPUT=lines)),
        ("bufferaccuracytest", {"INPUT": lines, "REFERENCE": str(sample / "truth_roads.shp"),
                                "OUTPUT": "TEMPORARY_OUTPUT"}),
    ):
        msg = _error(alg, params, r"'nocrs': the layer has no coordinate reference system\. "
                                  r"Set the layer's CRS")
        assert "nocrs" in msg and "no coordinate reference system" in msg, (alg, msg)


GEOGRAPHIC = r"'EPSG:4326' is geographic \(degrees\).*Choose the local projected CRS"


def test_geographic_ground_crs_is_refused(qgis_app, sample):
    msg = _error("adjustroadvectors", adjust_params(sample, GROUND_CRS="EPSG:4326"), GEOGRAPHIC)
    assert "geographic" in msg
    msg = _error("bufferaccuracytest", {"INPUT": str(sample / "osm_roads.shp"),
                                        "REFERENCE": str(sample / "truth_roads.shp"),
                                        "GROUND_CRS": "EPSG:4326", "OUTPUT": "TEMPORARY_OUTPUT"},
                 GEOGRAPHIC)
    assert "geographic" in msg


def test_bad_measurement_table(qgis_app, sample):
    from qgis.core import QgsFeature, QgsVectorLayer

    lyr = QgsVectorLayer("None?field=point_id:string&field=image_id:string&field=x:double",
                         "badmeas", "memory")
    f = QgsFeature(lyr.fields())
    f.setAttributes(["GCP01", "L", 1.0])
    lyr.dataProvider().addFeatures([f])
    msg = _error("adjustroadvectors", adjust_params(sample, MEASUREMENTS=lyr),
                 r"'badmeas': missing column\(s\) y.*header must be point_id,image_id,x,y")
    assert "badmeas" in msg and "missing column(s) y" in msg


def test_missing_camera_and_unknown_image(qgis_app, sample):
    params = {"INPUT": str(sample / "osm_roads.shp"),
              "MEASUREMENTS": str(sample / "image_points.csv"),
              "CONTROL": str(sample / "gcps.csv")}
    for k in SINKS:
        params[k] = "TEMPORARY_OUTPUT"
    assert "no camera" in _error("adjustroadvectors", params,
                                 r"no camera is given\. Give a project file with \[camera\]")
    params.update(FOCAL_LENGTH=152.4, IMAGES=["L", 506303.0, 4475003.0, 799.0, 0, 0, 0, 100, 5,
                                              ""])
    msg = _error("adjustroadvectors", params,
                 r"image 'R' is not defined in \[\[images\]\]\. Add an \[\[images\]\] entry")
    assert "image 'R' is not defined" in msg and "image_points.csv" in msg


def test_cancel(qgis_app, sample):
    from qgis.core import QgsProcessingException, QgsProcessingFeedback

    fb = QgsProcessingFeedback()
    fb.cancel()
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample), feedback=fb)


def test_adjust_with_identification_sigma_and_offset_from_the_dialog(qgis_app, sample,
                                                                       tmp_path):
    """The error model's parameters reach the core: the dialog's identification sigma
    replaces the project's (CE90 of the real vertex grows with it), the offset choice
    switches the estimated offset off and on."""
    import json

    base = tmp_path / "base.json"
    run("adjustroadvectors", adjust_params(sample, SUMMARY=str(base), OFFSET=1))  # none
    with_em = tmp_path / "em.json"
    run("adjustroadvectors", adjust_params(sample, SUMMARY=str(with_em),
                                           IDENTIFICATION_SIGMA_XY=2.0, OFFSET=2))
    a = json.loads(base.read_text())["databases"][0]
    b = json.loads(with_em.read_text())["databases"][0]
    assert a["identification_sigma"] == [0.5, 0.0]  # the sample project's
    assert "offset" not in a
    assert b["identification_sigma"] == [2.0, 0.0]
    # a shift (and, the heights coming from the DEM, the DEM's own height offset)
    assert b["offset"]["axes"] == ["X", "Y", "Z"] and "of the images" in b["offset"]["statement"]
    assert b["mean_ce90"] > a["mean_ce90"] + 2.0


def test_adjust_conflation_switch_defaults_on_and_the_log_counts_the_vertices(qgis_app, sample,
                                                                             tmp_path):
    """'Correct every vertex (conflation)': on in the dialog (the project's [conflation]
    enabled is replaced by it); off keeps the unmeasured vertices at their database
    position. The log gives the vertices per Source."""
    import json

    from qgis.core import QgsApplication, QgsProcessingFeedback

    alg = QgsApplication.processingRegistry().algorithmById("vectoradjust:adjustroadvectors")
    assert alg.parameterDefinition("CONFLATION").defaultValue() is True
    on, off = tmp_path / "on.json", tmp_path / "off.json"
    fb = QgsProcessingFeedback()
    run("adjustroadvectors", adjust_params(sample, SUMMARY=str(on)), feedback=fb)
    res = run("adjustroadvectors", adjust_params(sample, SUMMARY=str(off), CONFLATION=False))
    a = json.loads(on.read_text())["conflation"]
    b = json.loads(off.read_text())["conflation"]
    assert a["enabled"] is True and b["enabled"] is False
    n = a["databases"][0]["vertices"]
    assert n["interpolated"] + n["extrapolated"] > 0
    assert (f"{n['measured']} measured, {n['interpolated']} interpolated, "
            f"{n['extrapolated']} extrapolated, {n['unchanged']} unchanged vertices"
            in fb.textLog())
    m = b["databases"][0]["vertices"]
    assert m["interpolated"] == m["extrapolated"] == 0 and m["unchanged"] > 0
    c = columns(res["SHAPE_POINTS"])
    src = np.array(c["Source"], dtype=object)[np.array(c["Adjusted"]) == 0]
    assert src.size > 0 and set(src) == {"unchanged"}


def test_adjust_datum_parameter(qgis_app, sample, tmp_path):
    """The dialog's default takes the datum from the project (the sample's control);
    "free network" adjusts without priors and says the precision is relative."""
    import json

    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById("vectoradjust:adjustroadvectors")
    assert alg.parameterDefinition("DATUM").defaultValue() == 0
    default, free = tmp_path / "default.json", tmp_path / "free.json"
    run("adjustroadvectors", adjust_params(sample, SUMMARY=str(default)))
    run("adjustroadvectors", adjust_params(sample, SUMMARY=str(free), DATUM=1))
    a = json.loads(default.read_text())["datum"]
    b = json.loads(free.read_text())["datum"]
    assert a["kind"] == "prior information"
    assert a["sources"][0].startswith("24 measured control point(s)")
    assert b["kind"] == "free network" and "relative" in b["note"]
