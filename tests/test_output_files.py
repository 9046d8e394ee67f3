"""Output files: field names that never clash with the input's, quiet writing, file modes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.io
gpd = pytest.importorskip("geopandas")

from vectoradjust.cli.commands import main  # noqa: E402
from vectoradjust.files.outputs import (  # noqa: E402
    FEATURE_FIELDS,
    renamed_input_fields,
    write_outputs,
)
from vectoradjust.files.readers import load_project_data  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario, write_project  # noqa: E402


@pytest.fixture(scope="module")
def project_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("project")
    write_project(make_scenario(0), d)
    return d


@pytest.fixture(scope="module")
def clashing(project_dir, tmp_path_factory) -> Path:
    """The project with OSMnx-like input fields ``length``, ``RMSE`` and ``npts`` in OSM."""
    d = tmp_path_factory.mktemp("clash") / "p"
    shutil.copytree(project_dir, d)
    g = gpd.read_file(d / "osm_roads.shp")
    g["length"] = g.geometry.length
    g["RMSE"] = 1.5
    g["npts"] = 7
    g.to_file(d / "osm_roads.shp")
    return d


def test_renaming_rule():
    assert renamed_input_fields(["name", "length", "RMSE", "npts", "geometry"]) == {
        "length": "in_length", "RMSE": "in_RMSE", "npts": "in_npts",
        "geometry": "in_geometr"}
    # shapefile-safe (<= 10 characters) and unique, case-insensitively
    got = renamed_input_fields(["lengthsdnc", "LengthSDnc", "in_lengths", "IN_LENGTH1"])
    new = list(got.values())
    assert all(len(n) <= 10 for n in new)
    lowered = [n.lower() for n in new] + ["in_lengths", "in_length1"]
    assert len(set(lowered)) == len(lowered)
    assert not {n.lower() for n in new} & {f.lower() for f in FEATURE_FIELDS}
    assert renamed_input_fields(["name", "highway"]) == {}


@pytest.mark.parametrize("fmt", ["gpkg", "shp"])
def test_input_fields_named_like_ours_are_kept_renamed(clashing, tmp_path, fmt):
    data = load_project_data(clashing / "project.toml", vectors=["OSM"])
    r = run(data, vectors=["OSM"])
    src = gpd.read_file(clashing / "osm_roads.shp")
    out = write_outputs(r, tmp_path / "o", fmt=fmt, bands=False)
    feats = gpd.read_file(out["adjusted.gpkg"], layer="features") if fmt == "gpkg" else \
        gpd.read_file(out["features.shp"])
    cols = list(feats.columns)
    for f in FEATURE_FIELDS:  # the product's names are fixed
        assert f in cols
    assert "Length_1" not in cols
    assert list(feats["in_length"]) == pytest.approx(list(src["length"]))
    assert set(feats["in_RMSE"]) == {1.5} and set(feats["in_npts"]) == {7}
    assert list(feats["NPts"]) == list(r.databases[0].features["NPts"])
    summary = json.loads(Path(out["summary.json"]).read_text())
    assert summary["renamed_input_fields"] == {"length": "in_length", "RMSE": "in_RMSE",
                                               "npts": "in_npts"}


def test_compare_with_clashing_input_fields(clashing, tmp_path, capsys):
    assert main(["compare", str(clashing / "project.toml"), "--out", str(tmp_path), "-q"]) == 0
    assert (tmp_path / "compare.csv").is_file()
    feats = gpd.read_file(tmp_path / "OSM" / "adjusted.gpkg", layer="features")
    assert {"in_length", "Length", "in_RMSE", "RMSE", "in_npts", "NPts"} <= set(feats.columns)


# --------------------------------------------------------------------------- quiet writing
@pytest.fixture(scope="module")
def long_names(project_dir, tmp_path_factory) -> Path:
    """OSM roads as a GeoPackage with field names and texts a shapefile cannot hold."""
    d = tmp_path_factory.mktemp("long") / "p"
    shutil.copytree(project_dir, d)
    g = gpd.read_file(d / "osm_roads.shp")
    g["a_very_long_field_name"] = "x"
    g["another_long_field"] = "y" * 300
    g.to_file(d / "osm_roads.gpkg", driver="GPKG")
    text = (d / "project.toml").read_text()
    assert '"osm_roads.shp"' in text
    (d / "project.toml").write_text(text.replace('"osm_roads.shp"', '"osm_roads.gpkg"'))
    return d


def _adjust_recording(args):
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(args) == 0
    return [str(w.message) for w in caught]


def test_gdal_warnings_become_run_warnings(long_names, tmp_path, capfd):
    out = tmp_path / "o"
    caught = _adjust_recording(["adjust", str(long_names / "project.toml"), "--out", str(out),
                                "--format", "shp", "--vectors", "OSM", "-q"])
    assert caught == []
    assert capfd.readouterr().err == ""
    warn = json.loads((out / "summary.json").read_text())["warnings"]
    assert any("'a_very_long_field_name' is written as 'a_very_lon'" in w for w in warn)
    assert any("cut to 254 characters" in w for w in warn)
    assert all(len(w) < 1000 for w in warn)


def test_normal_run_writes_only_the_progress_bar_to_stderr(project_dir, tmp_path, capfd):
    for fmt in ("gpkg", "shp"):
        caught = _adjust_recording(["adjust", str(project_dir / "project.toml"), "--out",
                                    str(tmp_path / fmt), "--format", fmt])
        assert caught == []
        err = capfd.readouterr().err
        lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]
        bars = ("adjust [", "truth [", "truth tables [", "write [", "report [")
        assert lines and all(ln.startswith(bars) for ln in lines), err


# --------------------------------------------------------------------------- no height
def test_unmeasured_vertices_outside_the_dem_get_a_problem(project_dir, tmp_path):
    import shapely
    from shapely.geometry import LineString

    d = tmp_path / "p"
    shutil.copytree(project_dir, d)
    g = gpd.read_file(d / "osm_roads.shp")
    n = len(g)
    x0, y0 = g.total_bounds[2] + 5000.0, g.total_bounds[3]
    extra = g.iloc[[0, 0]].copy()
    extra["osm_id"] = [999001, 999002]
    # one road wholly east of the DEM, one from inside it to 2 vertices outside
    inside = np.asarray(g.geometry.iloc[0].coords)[0]
    extra["geometry"] = [LineString([(x0, y0), (x0 + 10, y0), (x0 + 20, y0 + 5)]),
                         LineString([tuple(inside), (x0, y0), (x0 + 10, y0)])]
    gpd.GeoDataFrame(gpd.pd.concat([g, extra], ignore_index=True), crs=g.crs).to_file(
        d / "osm_roads.shp")
    data = load_project_data(d / "project.toml", vectors=["OSM"])
    r = run(data, vectors=["OSM"])
    out = write_outputs(r, tmp_path / "o", bands=False)
    feats = gpd.read_file(out["adjusted.gpkg"], layer="features")
    assert len(feats) == n + 2
    assert feats.loc[n, "Problem"] == ("3 vertices without height (outside the DEM); their Z is "
                                       "written as 0")
    assert feats.loc[n + 1, "Problem"] == ("2 vertices without height (outside the DEM); their "
                                           "Z is written as 0")
    assert (feats.loc[:n - 1, "Problem"].fillna("") == "").all()
    geoms = feats.geometry.iloc[n:]
    assert shapely.is_valid(geoms).all() and shapely.has_z(geoms).all()
    z = shapely.get_coordinates(geoms, include_z=True)[:, 2]
    assert np.isfinite(z).all() and (z[:3] == 0).all()
    # the shape points say it too, vertex by vertex: the 5 without a height, no other
    pts = gpd.read_file(out["adjusted.gpkg"], layer="shape_points")
    noz = pts["AdjZ"].isna()
    assert noz.sum() == 5 and pts["feature_id"][noz].isin(["999001", "999002", 999001,
                                                            999002]).all()
    assert pts["Problem"][noz].str.startswith("no height").all()
    assert (pts["Problem"][~noz].fillna("") == "").all()


# --------------------------------------------------------------------------- file modes
@pytest.mark.parametrize("umask", [0o022, 0o027])
@pytest.mark.slow
def test_output_files_get_a_new_files_usual_mode(project_dir, tmp_path, umask):
    import os
    import stat

    old = os.umask(umask)
    try:
        out = tmp_path / "o"
        assert main(["adjust", str(project_dir / "project.toml"), "--out", str(out),
                     "--vectors", "OSM", "-q"]) == 0
        cmp_out = tmp_path / "c"
        assert main(["compare", str(project_dir / "project.toml"), "--out", str(cmp_out),
                     "-q"]) == 0
    finally:
        os.umask(old)
    files = [p for p in list(out.iterdir()) + list(cmp_out.rglob("*")) if p.is_file()]
    assert {"report.html", "summary.json", "adjusted.gpkg", "compare.csv"} <= {
        p.name for p in files}
    for p in files:
        assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask, p.name
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left


def test_single_database_residual_figure_is_not_clipped(sample_dir):
    from vectoradjust.files.report import figure_png, residual_vector_figure

    data = load_project_data(sample_dir / "project.toml")
    fig = residual_vector_figure(run(data, vectors=["OSM"]))
    figure_png(fig)  # lays the figure out and draws it
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    for artist in [fig._suptitle, *fig.legends]:
        bb = artist.get_window_extent(renderer)
        assert bb.x0 >= -1 and bb.x1 <= width + 1, artist
        assert bb.y0 >= -1 and bb.y1 <= height + 1, artist


# --------------------------------------------------------------------------- truth buffer
@pytest.fixture(scope="module")
def sample_run(sample_dir):
    from vectoradjust.files.project import load_project
    from vectoradjust.files.truth import project_truth

    spec = load_project(sample_dir / "project.toml")
    return run(load_project_data(spec)), project_truth(spec)


def test_truth_buffer_reports_progress_per_chunk(sample_run, monkeypatch):
    from vectoradjust.accuracy.buffer import buffer_test
    from vectoradjust.files import truth as truth_mod

    r, (path, widths) = sample_run
    monkeypatch.setattr(truth_mod, "TRUTH_CHUNK", 5)
    calls = []
    got = truth_mod.truth_buffer(r, path, widths, progress=lambda f, m="": calls.append((f, m)),
                                 is_cancelled=lambda: False)
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert len(calls) > 3 * 2 * 2  # per database and per chunk of 5 lines
    assert {f"buffer test: {d.name}" for d in r.databases} <= {m for _, m in calls}
    # the same shares as buffer_test on all lines at once
    truth_lines, _ = truth_mod.read_lines(path, r.data.crs)
    d = r.databases[0]
    layer = d.shape.layer
    keep = np.isin(layer.vertex_feature,
                   layer.vertex_feature[d.vertices["Adjusted"] == 1])
    lines = truth_mod._lines(d.adjusted_coords[keep, :2], layer.vertex_feature[keep],
                             layer.vertex_part[keep])
    ref = [row["share"] for row in buffer_test(lines, truth_lines, widths, method="exact")]
    assert got[d.name]["after"] == pytest.approx(ref, abs=1e-12)
    # and those of the union-of-all-lines polygon buffer, within its chord error
    poly = [row["share"] for row in buffer_test(lines, truth_lines, widths)]
    assert got[d.name]["after"] == pytest.approx(poly, abs=1e-5)


def test_truth_buffer_can_be_cancelled(sample_run, monkeypatch):
    from vectoradjust.errors import CancelledError
    from vectoradjust.files import truth as truth_mod

    r, (path, widths) = sample_run
    monkeypatch.setattr(truth_mod, "TRUTH_CHUNK", 5)
    polls = []

    def is_cancelled():
        polls.append(1)
        return len(polls) > 6

    with pytest.raises(CancelledError, match="cancelled"):
        truth_mod.truth_buffer(r, path, widths, is_cancelled=is_cancelled)
    assert len(polls) == 7


def test_cli_shows_the_truth_buffer_stage(sample_dir, tmp_path, capfd):
    assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(tmp_path / "o"),
                 "--vectors", "OSM", "--no-bands"]) == 0
    err = capfd.readouterr().err
    assert "truth [" in err and "buffer test: OSM" in err and "buffer test: done" in err


@pytest.mark.parametrize("fmt", ["gpkg", "shp"])
@pytest.mark.slow
def test_shape_points_through_arrow_equal_the_frame(sample_dir, tmp_path, fmt, monkeypatch):
    """The shape_points layer written from Arrow columns and WKB points is the layer of
    the GeoDataFrame (schema, geometries, attributes; shapefiles byte for byte)."""
    pytest.importorskip("pyarrow")
    import pyogrio

    from vectoradjust.files import outputs

    made = []
    real = outputs.shape_points_table  # looked up, and patched, in outputs.writing
    monkeypatch.setattr(outputs.writing, "shape_points_table",
                        lambda r: made.append(1) or real(r))
    for name in ("arrow", "frame"):
        if name == "frame":  # no Arrow writing: the frame of every layer
            monkeypatch.setattr(outputs.writing, "_arrow_writing", lambda: {})
        assert main(["adjust", str(sample_dir / "project.toml"), "-o", str(tmp_path / name),
                     "-q", "--no-bands", "--format", fmt]) == 0
    assert made == [1]  # the Arrow table in the first run only
    path, layer = (("adjusted.gpkg", "shape_points") if fmt == "gpkg"
                   else ("shape_points.shp", None))
    a, b = (pyogrio.read_info(tmp_path / n / path, layer=layer) for n in ("arrow", "frame"))
    for key in ("fields", "dtypes", "geometry_type", "crs", "features"):
        assert np.array_equal(np.asarray(a[key]), np.asarray(b[key])), key
    assert a["geometry_type"] == "Point Z" and a["features"] > 500
    fa, fb = (pyogrio.read_dataframe(tmp_path / n / path, layer=layer) for n in ("arrow", "frame"))
    assert fa.geometry.geom_equals_exact(fb.geometry, 0.0).all()
    assert fa.drop(columns="geometry").equals(fb.drop(columns="geometry"))
    if fmt == "shp":
        assert ((tmp_path / "arrow" / "shape_points.dbf").read_bytes()
                == (tmp_path / "frame" / "shape_points.dbf").read_bytes())


def test_shape_points_table_has_the_frame_s_values_and_nulls(sample_dir):
    """Without the conflation the unmeasured vertices' V, sigmas and CE90 are null in both."""
    pytest.importorskip("pyarrow")
    from dataclasses import replace

    from vectoradjust.files.outputs import SHAPE_FIELDS, shape_points_frame, shape_points_table
    from vectoradjust.files.project import load_project

    data = load_project_data(load_project(sample_dir / "project.toml"))
    out = run(replace(data, conflation={"enabled": False}))
    frame = shape_points_frame(out)
    table = shape_points_table(out).batches().read_all()
    assert table.num_rows == len(frame) and table.column_names == [*SHAPE_FIELDS, "geometry"]
    for f in SHAPE_FIELDS:
        a, b = table.column(f).to_pylist(), frame[f].tolist()
        b = [None if (x is None or x is gpd.pd.NA or (isinstance(x, float) and x != x)) else x
             for x in b]
        assert a == b, f
    assert table.column("Vx").null_count > 20  # the unmeasured vertices
    pts = gpd.GeoSeries.from_wkb(table.column("geometry").to_pylist(), crs=frame.crs)
    assert pts.geom_equals_exact(frame.geometry, 0.0).all() and pts.has_z.all()


@pytest.mark.parametrize("before", [None, "NORMAL"])
def test_geopackages_are_written_unsynced_and_the_setting_is_restored(before, tmp_path,
                                                                     monkeypatch):
    """SQLite does not wait for the disk while the layers are written (they are moved
    into place only when whole); the user's own setting is back afterwards, also when
    the writing fails."""
    pyogrio = pytest.importorskip("pyogrio")
    from vectoradjust.files import outputs

    pyogrio.set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": before})
    seen = []

    class Layer:
        def write(self, path, layer, driver):
            seen.append(pyogrio.get_gdal_config_option("OGR_SQLITE_SYNCHRONOUS"))
            raise OSError("disk full")

    try:
        with pytest.raises(OSError, match="disk full"):
            outputs._write_layer(Layer(), tmp_path / "a.gpkg", "x", "gpkg")
        assert seen == [False]  # pyogrio reads "OFF" as False
        assert pyogrio.get_gdal_config_option("OGR_SQLITE_SYNCHRONOUS") == before
    finally:
        pyogrio.set_gdal_config_options({"OGR_SQLITE_SYNCHRONOUS": None})
