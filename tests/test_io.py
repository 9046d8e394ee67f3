"""Files in, files out: the project file, CSVs, shapefiles, DEM and the outputs (contract 9)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.io
gpd = pytest.importorskip("geopandas")

from vectoradjust.cli.commands import main  # noqa: E402
from vectoradjust.errors import (  # noqa: E402
    ControlError,
    CRSError,
    CSVError,
    DEMError,
    LayerError,
    MeasurementError,
    ProjectError,
    VectorAdjustError,
)
from vectoradjust.files.outputs import CONTROL_FIELDS, write_outputs  # noqa: E402
from vectoradjust.files.readers import load_project_data  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario, write_project  # noqa: E402

CONTRACT_SHAPE = ["point_id", "feature_id", "X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY",
                  "AdjZ", "SigmaX", "SigmaY", "SigmaZ", "CE90", "LE90", "NImages", "Adjusted"]
CONTRACT_FEATURES = ["NPts", "NAdj", "RMSE_X", "RMSE_Y", "RMSE_Z", "RMSE", "Length", "FirstX",
                     "FirstY", "LastX", "LastY", "Images", "ImgDate"]
CONTRACT_CONTROL = ["point_id", "role", "X", "Y", "Z", "AdjX", "AdjY", "AdjZ", "Vx", "Vy", "Vz",
                    "CE90", "LE90", "NImages"]


@pytest.fixture(scope="module")
def project_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("project")
    write_project(make_scenario(0), d)
    return d


@pytest.fixture()
def copy(project_dir, tmp_path) -> Path:
    """A private copy of the project to break."""
    d = tmp_path / "p"
    shutil.copytree(project_dir, d)
    return d


@pytest.fixture(scope="module")
def shp_run(project_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("out_shp")
    assert main(["adjust", str(project_dir / "project.toml"), "--out", str(out), "--format",
                 "shp", "--vectors", "OSM", "-q"]) == 0
    return out


def test_shapefile_round_trip_keeps_every_feature_and_attribute(project_dir, shp_run):
    src = gpd.read_file(project_dir / "osm_roads.shp")
    feats = gpd.read_file(shp_run / "features.shp")
    assert len(feats) == len(src)
    for col in src.columns.drop("geometry"):
        assert col in feats.columns
        a = src[col].astype(object).where(src[col].notna(), None).tolist()
        b = feats[col].astype(object).where(feats[col].notna(), None).tolist()
        assert a == b, col
    assert set(CONTRACT_FEATURES) <= set(feats.columns)
    assert all(len(c) <= 10 for c in feats.columns)
    assert feats.crs.to_epsg() == 32616
    assert feats.geometry.has_z.all()


def test_shape_points_fields_and_values(project_dir, shp_run):
    pts = gpd.read_file(shp_run / "shape_points.shp")
    assert set(CONTRACT_SHAPE) <= set(pts.columns)
    src = gpd.read_file(project_dir / "osm_roads.shp")
    n_vertices = sum(len(g.coords) if g.geom_type == "LineString"
                     else sum(len(p.coords) for p in g.geoms) for g in src.geometry)
    assert len(pts) == n_vertices
    adj = pts["Adjusted"] == 1
    assert 0 < adj.sum() < len(pts)
    assert np.allclose(pts.loc[adj, "Vx"], pts.loc[adj, "AdjX"] - pts.loc[adj, "X"], atol=1e-6)
    # unmeasured vertices: corrected by the conflation (with their CE90), or unchanged
    conf = pts["Source"].isin(["interpolated", "extrapolated"])
    assert (conf == ~adj).all()
    assert np.allclose(pts.loc[conf, "Vx"], pts.loc[conf, "AdjX"] - pts.loc[conf, "X"], atol=1e-6)
    assert pts.loc[conf, "CE90"].notna().all()
    unc = pts["Source"] == "unchanged"
    assert pts.loc[unc, "Vx"].isna().all() and pts.loc[unc, "CE90"].isna().all()
    assert np.allclose(pts.loc[unc, "AdjX"], pts.loc[unc, "X"])
    # point geometry sits at the adjusted position
    assert np.allclose(pts.geometry.x, pts["AdjX"]) and np.allclose(pts.geometry.y, pts["AdjY"])
    # ids are <feature id>_<vertex index>
    fid = pts["point_id"].str.rsplit("_", n=1).str[0]
    assert (fid == pts["feature_id"].astype(str)).all()


def test_gpkg_output_and_summary(project_dir, tmp_path):
    out = tmp_path / "out"
    assert main(["adjust", str(project_dir / "project.toml"), "--out", str(out), "-q"]) == 0
    import pyogrio

    layers = {name for name, _ in pyogrio.list_layers(out / "adjusted.gpkg")}
    assert layers == {"shape_points", "features", "control_points", "uncertainty_bands"}
    cp = gpd.read_file(out / "adjusted.gpkg", layer="control_points")
    assert set(CONTRACT_CONTROL) <= set(cp.columns) and set(CONTROL_FIELDS) <= set(cp.columns)
    s = json.loads((out / "summary.json").read_text())
    for key in ("sigma0_squared", "degrees_of_freedom", "iterations", "converged", "chi_square",
                "shape_points", "check_points", "images"):
        assert key in s
    assert set(s["chi_square"]) >= {"statistic", "lower", "upper", "alpha", "passed"}
    assert set(s["shape_points"]) == {"count", "rmse_x", "rmse_y", "rmse_z", "rmse_horizontal"}
    assert [im["id"] for im in s["images"]] == ["L", "R"]
    truth = np.loadtxt(project_dir / "truth_eo.csv", delimiter=",", skiprows=1, usecols=(1, 2, 3))
    for im, t in zip(s["images"], truth):
        assert np.allclose(im["position"], t, atol=0.5)  # adjusted, not the approximation
        assert len(im["sigma_position"]) == 3 and len(im["attitude"]) == 3


@pytest.mark.slow
def test_compare_writes_a_table(project_dir, tmp_path, capsys):
    assert main(["compare", str(project_dir / "project.toml"), "--out", str(tmp_path), "-q"]) == 0
    text = (tmp_path / "compare.csv").read_text().splitlines()
    assert text[0].startswith("database,")
    assert [r.split(",")[0] for r in text[1:]] == ["OSM", "TNM", "TIGER"]
    assert "recovery" in capsys.readouterr().out
    for name in ("OSM", "TNM", "TIGER"):
        assert (tmp_path / name / "adjusted.gpkg").is_file()


def test_layer_in_another_crs_is_transformed(project_dir, copy, tmp_path):
    g = gpd.read_file(copy / "osm_roads.shp")
    g.to_crs(4326).to_file(copy / "osm_roads.shp")
    assert gpd.read_file(copy / "osm_roads.shp").crs.to_epsg() == 4326
    data = load_project_data(copy / "project.toml", vectors=["OSM"])
    ref = load_project_data(project_dir / "project.toml", vectors=["OSM"])
    assert np.allclose(data.vectors[0][1].coords, ref.vectors[0][1].coords, atol=1e-3)
    r = run(data, vectors=["OSM"])
    out = write_outputs(r, tmp_path / "o")
    assert gpd.read_file(out["adjusted.gpkg"], layer="features").crs.to_epsg() == 32616


# --------------------------------------------------------------------------- bad input
def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def _fails(copy, exc, match, tmp_path=None):
    out = (tmp_path or copy) / "never"
    with pytest.raises(exc, match=match):
        data = load_project_data(copy / "project.toml")
        r = run(data)
        write_outputs(r, out)
    assert not out.exists() or not any(out.iterdir())


def test_missing_csv_column(copy):
    _edit(copy / "image_points.csv", "point_id,image_id,x,y", "point_id,image_id,x,yy")
    _fails(copy, CSVError, r"image_points.csv: missing column\(s\) y")


def test_extra_csv_column(copy):
    _edit(copy / "gcps.csv", "sigma_z,role", "sigma_z,role,comment")
    text = (copy / "gcps.csv").read_text().splitlines()
    (copy / "gcps.csv").write_text("\n".join([text[0]] + [r + ",x" for r in text[1:]]) + "\n")
    _fails(copy, CSVError, r"gcps.csv: unexpected column\(s\) comment")


def test_nan_coordinate_names_the_line(copy):
    lines = (copy / "gcps.csv").read_text().splitlines()
    parts = lines[3].split(",")
    parts[2] = "nan"
    lines[3] = ",".join(parts)
    (copy / "gcps.csv").write_text("\n".join(lines) + "\n")
    _fails(copy, CSVError, r"gcps.csv, line 4: column Y is 'nan', not a finite number")


def test_duplicate_control_id(copy):
    lines = (copy / "gcps.csv").read_text().splitlines()
    (copy / "gcps.csv").write_text("\n".join(lines + [lines[1]]) + "\n")
    _fails(copy, CSVError, r"point id 'GCP01' appears more than once \(lines 2, \d+\)")


def test_duplicate_measurement(copy):
    lines = (copy / "image_points.csv").read_text().splitlines()
    (copy / "image_points.csv").write_text("\n".join(lines + [lines[1]]) + "\n")
    _fails(copy, CSVError, r"is measured on image 'L' more than once")


def test_unknown_image_id_in_file(copy):
    lines = (copy / "image_points.csv").read_text().splitlines()
    lines[4] = lines[4].replace(",L,", ",Q,").replace(",R,", ",Q,")
    (copy / "image_points.csv").write_text("\n".join(lines) + "\n")
    _fails(copy, MeasurementError, r"image_points.csv, line 5: image 'Q' is not defined")


def test_no_control_and_no_camera_priors_from_file(copy):
    """No control point and no camera prior: the shifts of the roads are estimated, so
    nothing fixes X and Y (a DatumError that names the fixes), before any output."""
    lines = (copy / "gcps.csv").read_text().splitlines()
    keep = [lines[0]] + [r for r in lines[1:] if r.endswith("check")]
    (copy / "gcps.csv").write_text("\n".join(keep) + "\n")
    text = (copy / "project.toml").read_text()
    text = "\n".join(t for t in text.splitlines() if not t.startswith(("sigma_position",
                                                                         "sigma_attitude")))
    (copy / "project.toml").write_text(text + "\n")
    _fails(copy, ControlError, r"datum is not fixed: the block can move freely in X and Y")


def test_geographic_project_crs(copy):
    _edit(copy / "project.toml", 'crs = "EPSG:32616"', 'crs = "EPSG:4326"')
    _fails(copy, CRSError, "is geographic")


def test_layer_without_crs(copy):
    (copy / "tnm_roads.prj").unlink()
    _fails(copy, CRSError, "tnm_roads.shp: the layer has no coordinate reference system")


def test_point_layer_is_rejected(copy):
    g = gpd.read_file(copy / "osm_roads.shp")
    g.set_geometry(g.geometry.centroid).to_file(copy / "osm_roads.shp")
    _fails(copy, LayerError, "holds Point geometries, not lines")


def test_missing_id_field(copy):
    _edit(copy / "project.toml", 'id_field = "osm_id"', 'id_field = "osm_idx"')
    _fails(copy, LayerError, "id_field 'osm_idx' is not a field of the layer")


def test_dem_not_covering_a_measured_vertex(copy):
    import rasterio

    with rasterio.open(copy / "dem.tif") as ds:
        profile = ds.profile
        grid = ds.read(1)
    grid[:, : grid.shape[1] // 2] = profile["nodata"]  # western half missing
    with rasterio.open(copy / "dem.tif", "w", **profile) as ds:
        ds.write(grid, 1)
    _fails(copy, DEMError, r"dem.tif: measured shape point '.+' \(feature '.+' of .+\) has no "
           "height: the DEM does not cover it")


def test_empty_and_null_geometries_are_flagged_not_dropped(copy, tmp_path):
    from shapely.geometry import LineString

    g = gpd.read_file(copy / "osm_roads.shp")
    n = len(g)
    g.loc[0, "geometry"] = None
    g.loc[1, "geometry"] = LineString()
    g.to_file(copy / "osm_roads.shp")
    data = load_project_data(copy / "project.toml", vectors=["OSM"])
    r = run(data, vectors=["OSM"])
    out = write_outputs(r, tmp_path / "o", fmt="shp")
    feats = gpd.read_file(out["features.shp"])
    assert len(feats) == n
    assert feats.loc[0, "Problem"] == "null geometry"
    # a shapefile stores an empty line as a null shape
    assert feats.loc[1, "Problem"] in ("empty geometry", "null geometry")
    assert feats.loc[0, "NPts"] == 0


def test_project_file_errors(copy):
    with pytest.raises(ProjectError, match="does not exist"):
        load_project_data(copy / "nope.toml")
    _edit(copy / "project.toml", 'reweight = "none"', 'reweight = "sometimes"')
    with pytest.raises(ProjectError, match="reweight = 'sometimes' is not known"):
        load_project_data(copy / "project.toml")


def test_cli_reports_user_errors_without_traceback(copy, capsys):
    (copy / "gcps.csv").unlink()
    assert main(["adjust", str(copy / "project.toml"), "--out", str(copy / "o"), "-q"]) == 1
    err = capsys.readouterr().err
    assert "vectoradjust: error:" in err and "gcps.csv" in err and "Traceback" not in err


def test_every_error_class_is_a_vectoradjust_error():
    for cls in (CSVError, CRSError, DEMError, LayerError, ControlError, MeasurementError):
        assert issubclass(cls, VectorAdjustError)


def test_adjust_with_qa_table_writes_verdict_and_qa_field(copy):
    text = (copy / "project.toml").read_text()
    (copy / "project.toml").write_text(
        text + '\n[qa]\nproduct = "topographic map"\nmap_scale = 2000\ncontour_interval = 1.0\n')
    out = copy / "out"
    assert main(["adjust", str(copy / "project.toml"), "--out", str(out), "-q",
                 "--no-bands"]) == 0
    qa = json.loads((out / "qa.json").read_text())
    assert "verdict" in qa
    cp = gpd.read_file(out / "adjusted.gpkg", layer="control_points")
    assert set(cp["QA"]) <= {"pass", "fail", "", None}
    assert (cp["QA"] == "pass").sum() > 20
    assert "Quality assurance" in (out / "report.html").read_text()


@pytest.mark.slow
def test_buffer_test_cli_and_truth_comparison(project_dir, tmp_path, capsys):
    """Shares inside buffers of the true centrelines rise after the adjustment."""
    out = tmp_path / "buf.csv"
    assert main(["buffer-test", str(project_dir / "osm_roads.shp"),
                 str(project_dir / "truth_roads.shp"), "--widths", "1,2,500",
                 "--out", str(out)]) == 0
    rows = out.read_text().splitlines()
    assert rows[0] == "width,share,length_inside,length_total"
    assert float(rows[3].split(",")[1]) == pytest.approx(1.0)  # everything within 500 m
    assert main(["buffer-test", str(project_dir / "osm_roads.shp"),
                 str(project_dir / "gcps.csv")]) == 1
    cmp_dir = tmp_path / "cmp"
    assert main(["compare", str(project_dir / "project.toml"), "--out", str(cmp_dir), "-q"]) == 0
    s = json.loads((cmp_dir / "OSM" / "summary.json").read_text())
    buf = s["databases"][0]["truth"]["buffer"]
    assert buf["widths"] == [1.0, 2.0]
    assert buf["after"][0] > 0.8 > buf["before"][0]
    header = (cmp_dir / "compare.csv").read_text().splitlines()[0]
    assert header.endswith("in_1m_before,in_1m_after,in_2m_before,in_2m_after")


def test_csv_line_numbers_survive_blank_lines(copy):
    lines = (copy / "gcps.csv").read_text().splitlines()
    parts = lines[3].split(",")
    parts[1] = "abc"
    lines[3] = ",".join(parts)
    lines.insert(2, "")  # a blank line before the bad row: it is now line 5 of the file
    (copy / "gcps.csv").write_text("\n".join(lines) + "\n")
    _fails(copy, CSVError, r"gcps.csv, line 5: column X is 'abc'")


def test_osm_pbf_input_gives_the_same_adjustment(sample_dir, tmp_path):
    """An OpenStreetMap PBF (GDAL's OSM driver, layer = "lines") as road layer.

    tests/data/osm/sample_roads.osm.pbf holds the sample project's single-part OSM-like
    ways with their osm_id as way id (made by make_sample_pbf.py). PBF stores degrees to
    1e-7, so positions agree with the shapefile to about a centimetre.
    """
    pbf = Path(__file__).resolve().parent / "data" / "osm" / "sample_roads.osm.pbf"
    proj = tmp_path / "sample"
    shutil.copytree(sample_dir, proj)
    shutil.copy(pbf, proj / "roads.osm.pbf")
    # a PBF holds two layers with lines (ways and route relations): the entry names one
    _edit(proj / "project.toml", 'path = "osm_roads.shp"',
          'path = "roads.osm.pbf"\nlayer = "lines"')
    got = run(load_project_data(proj / "project.toml"), vectors=["OSM"])
    ref = run(load_project_data(sample_dir / "project.toml"), vectors=["OSM"])
    layer = got.databases[0].shape.layer
    assert layer.source.endswith("roads.osm.pbf") and layer.n_features == 25
    assert {"highway", "name"} <= set(layer.attributes)
    a, b = got.databases[0].vertices, ref.databases[0].vertices
    ib = {pid: i for i, pid in enumerate(b["point_id"])}
    common = [(i, ib[pid]) for i, pid in enumerate(a["point_id"]) if pid in ib]
    ia, jb = np.array(common).T
    assert len(ia) == len(a["point_id"])  # every PBF vertex id exists in the shapefile run
    assert np.array_equal(a["Adjusted"][ia], b["Adjusted"][jb])
    m = a["Adjusted"][ia] == 1
    assert m.sum() > 150
    assert np.abs(a["X"][ia] - b["X"][jb]).max() < 0.02
    # the multi-part feature is not in the PBF (its measurements become tie points, without
    # the 0.15 m height prior of its shape points), and the two-pass sigmas differ a little:
    # adjusted positions agree well within their 6 cm photogrammetric sigma (max 2.2 cm;
    # each run estimates its own offsets, the DEM heights' height offset included)
    assert np.abs(a["AdjX"][ia][m] - b["AdjX"][jb][m]).max() < 0.03
    assert np.abs(a["Vx"][ia][m] - b["Vx"][jb][m]).max() < 0.03
    out = write_outputs(got, tmp_path / "o", bands=False)
    feats = gpd.read_file(out["adjusted.gpkg"], layer="features")
    assert len(feats) == 25 and "osm_id" in feats.columns
