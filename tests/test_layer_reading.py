"""Reading the road layers: ``where`` filters, multi-layer sources, ids that match no
measurement, and the CRS transformation of each layer (the sample project, copied)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.io
gpd = pytest.importorskip("geopandas")

from vectoradjust.errors import LayerError, NothingAdjustedError  # noqa: E402
from vectoradjust.files.outputs import write_outputs  # noqa: E402
from vectoradjust.files.readers import load_project_data, read_line_layer  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402

PBF = Path(__file__).resolve().parent / "data" / "osm" / "sample_roads.osm.pbf"


@pytest.fixture()
def sample(sample_dir, tmp_path) -> Path:
    """A private copy of the sample project."""
    d = tmp_path / "sample"
    shutil.copytree(sample_dir, d)
    return d


@pytest.fixture(scope="module")
def osm_alone(sample_dir):
    """The sample's OSM database adjusted alone, unfiltered."""
    return run(load_project_data(sample_dir / "project.toml"), vectors=["OSM"])


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def _osm_entry(sample: Path, *lines: str, path: str = "osm_roads.shp") -> None:
    """Replace the OSM entry's path and add ``lines`` to it."""
    _edit(sample / "project.toml", 'path = "osm_roads.shp"',
          "\n".join([f"path = {path!r}".replace("'", '"')] + list(lines)))


# --------------------------------------------------------------------------- where
def test_where_keeps_the_chosen_features_of_a_geopackage(sample, osm_alone, tmp_path):
    gpd.read_file(sample / "osm_roads.shp").to_file(sample / "osm.gpkg", layer="roads")
    _osm_entry(sample, "where = \"highway = 'tertiary'\"", path="osm.gpkg")
    data = load_project_data(sample / "project.toml")  # every database, as the CLI reads
    layer = data.vectors[0][1]
    assert layer.n_features == 8
    r = run(data, vectors=["OSM"])
    entry = r.summary["databases"][0]
    assert entry["input"]["where"] == "highway = 'tertiary'"
    assert (entry["input"]["features_in_layer"], entry["input"]["features_kept"],
            entry["input"]["features_filtered"]) == (26, 8, 18)
    assert "excluded_feature_ids" not in entry["input"]
    # the measurements of the 18 filtered roads are left out, not made tie points
    left = [w for w in r.summary["warnings"] if "where = \"highway = 'tertiary'\" excluded" in w]
    assert len(left) == 1 and left[0].startswith("OSM: ")
    assert (r.point_kind == "tie").sum() == (osm_alone.point_kind == "tie").sum()
    assert 0 < entry["adjusted_vertices"] < osm_alone.summary["databases"][0]["adjusted_vertices"]
    # the same feature, the same shape point ids and adjusted positions (nearly)
    a, b = r.databases[0].vertices, osm_alone.databases[0].vertices
    ib = {p: i for i, p in enumerate(b["point_id"])}
    assert all(p in ib for p in a["point_id"])
    feats = gpd.read_file(write_outputs(r, tmp_path / "o", bands=False)["adjusted.gpkg"],
                          layer="features")
    assert len(feats) == 8 and set(feats["highway"]) == {"tertiary"}


def test_without_id_field_a_filtered_feature_keeps_its_index(sample_dir):
    from pyproj import CRS

    crs = CRS("EPSG:32616")
    path = str(sample_dir / "tnm_roads.shp")
    full = read_line_layer(path, "TNM", None, crs)
    some = read_line_layer(path, "TNM", None, crs, where="mtfcc <> 'S1400'")
    mtfcc = np.asarray(full.attributes["mtfcc"])
    assert 0 < some.n_features < full.n_features
    assert list(some.feature_ids) == list(full.feature_ids[mtfcc != "S1400"])
    assert some.reading["excluded_feature_ids"] == list(full.feature_ids[mtfcc == "S1400"])


@pytest.mark.parametrize("expr", ["highwy IS NOT NULL", "highway ==== 'x'"])
def test_a_bad_where_names_the_entry_and_the_expression(sample, expr):
    _osm_entry(sample, f'where = "{expr}"')
    with pytest.raises(LayerError, match=r"is not a valid attribute filter.*OGR SQL WHERE") as exc:
        load_project_data(sample / "project.toml")
    msg = str(exc.value)
    assert "[[vectors]] 'OSM'" in msg and f"where = {expr!r}" in msg
    assert "osm_id, name, highway" in msg  # the fields it may use


# --------------------------------------------------------------------------- layers
def _gpkg(sample: Path, layers: dict) -> Path:
    out = sample / "roads.gpkg"
    for name, stem in layers.items():
        g = gpd.read_file(sample / f"{stem}_roads.shp")
        if name == "crossings":
            g = g.set_geometry(g.geometry.centroid)
        g.to_file(out, layer=name)
    return out


def test_a_geopackage_with_several_line_layers_needs_layer(sample):
    _gpkg(sample, {"osm": "osm", "tnm": "tnm", "crossings": "osm"})
    _osm_entry(sample, path="roads.gpkg")
    with pytest.raises(LayerError, match=r"roads.gpkg \(\[\[vectors\]\] 'OSM'\) holds 2 layers "
                                         r"with lines: osm \((Multi)?LineString\), tnm "
                                         r'\((Multi)?LineString\)\. Add layer = "osm"'):
        load_project_data(sample / "project.toml")
    _edit(sample / "project.toml", 'path = "roads.gpkg"', 'path = "roads.gpkg"\nlayer = "tnx"')
    with pytest.raises(LayerError, match=r"there is no layer 'tnx' \(layers: osm \(.*LineString\), "
                                         r"tnm \(.*LineString\), crossings \(Point\)\)"):
        load_project_data(sample / "project.toml")
    _edit(sample / "project.toml", 'layer = "tnx"', 'layer = "osm"')
    data = load_project_data(sample / "project.toml", vectors=["OSM"])
    assert data.vectors[0][1].n_features == 26
    assert data.vectors[0][1].reading["layer"] == "osm"


def test_a_source_with_one_line_layer_needs_no_layer(sample, osm_alone):
    _gpkg(sample, {"crossings": "osm", "osm": "osm"})
    _osm_entry(sample, path="roads.gpkg")
    r = run(load_project_data(sample / "project.toml"), vectors=["OSM"])
    assert r.summary["databases"][0]["input"]["layer"] == "osm"
    assert (r.summary["databases"][0]["adjusted_vertices"]
            == osm_alone.summary["databases"][0]["adjusted_vertices"])


def test_an_osm_pbf_without_layer_lists_its_line_layers(sample):
    shutil.copy(PBF, sample / "roads.osm.pbf")
    _osm_entry(sample, path="roads.osm.pbf")
    with pytest.raises(LayerError, match=r"holds 2 layers with lines: lines \(LineString\), "
                                         r"multilinestrings \(MultiLineString\)\. Add layer = "
                                         r'"lines"'):
        load_project_data(sample / "project.toml")


# --------------------------------------------------------------------------- nothing adjusted
def test_no_id_field_while_the_measurements_use_other_ids(sample):
    _edit(sample / "project.toml", 'id_field = "osm_id"\n', "")
    for vectors in (["OSM"], None):
        with pytest.raises(NothingAdjustedError,
                           match=r"no id_field is given.*set id_field = \"osm_id\"") as exc:
            run(load_project_data(sample / "project.toml"), vectors=vectors)
        msg = str(exc.value)
        assert msg.startswith("OSM (") and "image_points.csv" in msg
        assert "no id_field is given" in msg and "e.g. '0_0'" in msg
        assert "such as '4134" in msg  # a measured OSM id
        assert 'set id_field = "osm_id"' in msg
    # a run without OSM does not need its measurements
    r = run(load_project_data(sample / "project.toml"), vectors=["TNM"])
    assert r.summary["databases"][0]["adjusted_vertices"] > 100


def test_ids_that_match_no_measurement(sample):
    g = gpd.read_file(sample / "osm_roads.shp")
    g["wrong_id"] = g["osm_id"] + 7
    g.to_file(sample / "osm_roads.shp")
    _edit(sample / "project.toml", 'id_field = "osm_id"', 'id_field = "wrong_id"')
    with pytest.raises(NothingAdjustedError,
                       match=r"its shape point ids \(id_field = 'wrong_id', e\.g\. '41341780_0'\) "
                             r"match none of the measured ids \(e\.g\. '4134.*'\); the field "
                             r"'osm_id' holds the measured feature ids"):
        run(load_project_data(sample / "project.toml"), vectors=["OSM"])


def test_a_database_without_measurements_only_outside_the_run(sample, osm_alone):
    (sample / "project.toml").write_text(
        (sample / "project.toml").read_text().replace(
            "[adjustment]", '[[vectors]]\nname = "EXTRA"\npath = "truth_roads.shp"\n\n'
                            "[adjustment]"))
    data = load_project_data(sample / "project.toml")
    r = run(data, vectors=["OSM"])
    assert (r.summary["databases"][0]["adjusted_vertices"]
            == osm_alone.summary["databases"][0]["adjusted_vertices"])
    with pytest.raises(NothingAdjustedError, match="^EXTRA .*none of its shape points is "
                                                   "measured"):
        run(data)
    with pytest.raises(NothingAdjustedError, match="^EXTRA "):
        run(data, vectors=["OSM", "EXTRA"])


def test_where_that_excludes_every_measured_feature(sample):
    _osm_entry(sample, "where = \"highway = 'motorway'\"")
    with pytest.raises(NothingAdjustedError, match=r"^OSM .*: the 366 measurement\(s\) of its "
                                                   r"shape points name features that where = "
                                                   r"\"highway = 'motorway'\" excluded"):
        run(load_project_data(sample / "project.toml"), vectors=["OSM"])


# --------------------------------------------------------------------------- CRS
def test_the_transformation_of_each_layer_is_reported(sample, osm_alone):
    gpd.read_file(sample / "osm_roads.shp").to_crs(4326).to_file(sample / "osm_roads.shp")
    g = gpd.read_file(sample / "tnm_roads.shp")
    g.to_crs(4269).to_file(sample / "tnm_nad83.shp")  # NAD83: a datum shift
    _edit(sample / "project.toml", 'path = "tnm_roads.shp"', 'path = "tnm_nad83.shp"')
    data = load_project_data(sample / "project.toml")
    osm = data.vectors[0][1].reading
    assert osm["crs"]["transformation"].endswith("UTM zone 16N")
    assert osm["crs"]["accuracy_m"] == 0.0 and osm["crs"]["warning"] is None
    assert osm["dem"]["crs"] is None  # the DEM is in the project CRS
    nad = data.vectors[1][1].reading["crs"]
    assert "NAD83" in nad["source_crs"] and "NAD83" in nad["transformation"]
    assert nad["accuracy_m"] is None or nad["accuracy_m"] > 1.0
    r = run(data, vectors=["OSM"])
    assert r.summary["databases"][0]["input"]["crs"]["accuracy_m"] == 0.0
    assert not [w for w in r.summary["warnings"] if "transformation" in w]
    r = run(data, vectors=["TNM"])
    warn = [w for w in r.summary["warnings"] if "the transformation of its layer" in w]
    assert len(warn) == 1 and warn[0].startswith("TNM: ") and "NAD83" in warn[0]


def _reference_flatten(geoms):
    """Per feature and part, the obvious way: (coords, feature, index, part, problems)."""
    import shapely

    rows, problems = [], {}
    for i, g in enumerate(geoms):
        if g is None:
            problems[i] = "null geometry"
            continue
        if g.geom_type not in ("LineString", "LinearRing", "MultiLineString"):
            problems[i] = f"geometry type {g.geom_type} is not a line"
            continue
        parts = list(g.geoms) if g.geom_type == "MultiLineString" else [g]
        n = 0
        for p, part in enumerate(parts):
            for c in shapely.get_coordinates(part, include_z=True):
                rows.append((*c, i, n, p))
                n += 1
        if n == 0:
            problems[i] = "empty geometry"
    bad = {int(r[3]) for r in rows if not np.isfinite(r[:2]).all()}
    problems.update({b: "NaN coordinates" for b in bad})
    rows = np.array([r for r in rows if int(r[3]) not in problems]).reshape(-1, 6)
    return rows[:, :3], rows[:, 3], rows[:, 4], rows[:, 5], problems


def test_flattening_lines_matches_a_feature_by_feature_reference():
    from shapely.geometry import LinearRing, LineString, MultiLineString, Point

    from vectoradjust.files.readers import layer_from_geometries

    rng = np.random.default_rng(3)
    geoms = [LineString([(0, 0), (1, 1), (2, 0)]), None, Point(1, 2), LineString(),
             MultiLineString([[(0, 0), (1, 0)], [(5, 5), (6, 6), (7, 7)]]),
             LinearRing([(0, 0), (1, 0), (1, 1)]), MultiLineString([]),
             LineString([(0, 0), (np.nan, 1)])]
    for _ in range(300):
        if rng.random() < 0.3:
            geoms.append(MultiLineString([rng.random((rng.integers(2, 6), 3))
                                          for _ in range(rng.integers(1, 4))]))
        else:
            geoms.append(LineString(rng.random((rng.integers(2, 9), 3))))
    with np.errstate(invalid="ignore"):
        lay = layer_from_geometries("x", geoms, {}, np.arange(len(geoms)).astype(str),
                                    None, "s")
    xyz, vf, vi, vp, problems = _reference_flatten(geoms)
    assert lay.problems == problems and len(problems) == 5
    np.testing.assert_array_equal(lay.coords, xyz)
    np.testing.assert_array_equal(lay.vertex_feature, vf)
    np.testing.assert_array_equal(lay.vertex_index, vi)
    np.testing.assert_array_equal(lay.vertex_part, vp)
