"""Tests of the scenario simulator (vectoradjust.simulate).

The checks use independent truth: the collinearity equations (re-projection with the
true exterior orientation), the camera format, the dissertation's head-to-head RMSE of
the three road databases (TNM 2.89 m, OSM 4.35 m, TIGER 19.17 m; docs/method.md section 1),
the survey sigmas, and the files read back with csv / tomllib / geopandas / rasterio.
"""

from __future__ import annotations

import csv
import sys

import numpy as np
import pytest

from vectoradjust.adjust.dem import bilinear
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.collinearity import project
from vectoradjust.simulate import EFFECTS, make_scenario, terrain_height, write_project
from vectoradjust.simulate import scenario as simulate

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PAPER_RMSE = {"TNM": 2.89, "OSM": 4.35, "TIGER": 19.17}  # dissertation, head-to-head


@pytest.fixture(scope="module")
def sc0():
    return make_scenario(0)


def _truth_lookup(sc):
    ids = [sc.control.point_id, sc.tie_ids] + [sc.truth[n][0] for n in sc.truth]
    xyz = [sc.control_true, sc.tie_true] + [sc.truth[n][1] for n in sc.truth]
    return dict(zip(np.concatenate(ids).tolist(), np.concatenate(xyz)))


def _reprojection_residuals(sc):
    truth = _truth_lookup(sc)
    m = sc.measurements
    xyz = np.array([truth[p] for p in m.point_id])
    img = {im.id: i for i, im in enumerate(sc.images)}
    eo = sc.true_eo[[img[i] for i in m.image_id]]
    xy = project(eo, xyz, sc.camera.focal_length, sc.camera.principal_point)
    return (m.xy - xy) / m.sigma


def test_determinism():
    a, b = make_scenario(7), make_scenario(7)
    np.testing.assert_array_equal(a.true_eo, b.true_eo)
    np.testing.assert_array_equal(a.measurements.xy, b.measurements.xy)
    np.testing.assert_array_equal(a.measurements.point_id, b.measurements.point_id)
    np.testing.assert_array_equal(a.control.xyz, b.control.xyz)
    np.testing.assert_array_equal(a.dem_grid, b.dem_grid)
    for name in a.layers:
        np.testing.assert_array_equal(a.layers[name].coords, b.layers[name].coords)
        np.testing.assert_array_equal(a.truth[name][1], b.truth[name][1])
        np.testing.assert_array_equal(a.layers[name].feature_ids, b.layers[name].feature_ids)
    c = make_scenario(8)
    assert not np.array_equal(a.true_eo, c.true_eo)
    assert not np.array_equal(a.layers["OSM"].coords[:5], c.layers["OSM"].coords[:5])


def test_streams_are_independent():
    # changing the number of tie points must not change the road databases
    a, b = make_scenario(3), make_scenario(3, n_tie=4)
    np.testing.assert_array_equal(a.layers["TIGER"].coords, b.layers["TIGER"].coords)
    np.testing.assert_array_equal(a.control.xyz, b.control.xyz)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_measurements_are_projections_of_the_truth(seed):
    sc = make_scenario(seed)
    w = _reprojection_residuals(sc)
    n = w.size
    chi2 = float(np.sum(w**2)) / n
    assert abs(chi2 - 1.0) < 5.0 * np.sqrt(2.0 / n)
    # no systematic offset on either axis
    assert np.all(np.abs(w.mean(axis=0)) < 5.0 / np.sqrt(len(w)))
    assert np.max(np.abs(w)) < 5.5


def test_measurements_inside_format_and_stereo(sc0):
    m = sc0.measurements
    assert np.all(np.abs(m.xy) < 115.0)
    pairs = np.char.add(np.char.add(m.point_id.astype(str), "|"), m.image_id.astype(str))
    assert len(np.unique(pairs)) == len(pairs)  # one measurement per point and image
    _, counts = np.unique(m.point_id, return_counts=True)
    assert np.all(counts == 2)  # two images: every measured point on both
    np.testing.assert_allclose(m.sigma, 0.015)


def test_visibility_rule_from_collinearity(sc0):
    """Measured = inside the format on both images (checked with the true EO)."""
    m = sc0.measurements
    measured_ids = set(m.point_id.tolist())
    for name, (ids, xyz) in sc0.truth.items():
        xy = project(sc0.true_eo[None, :, :], xyz[:, None, :], 152.4)
        stereo = np.all(np.abs(xy) < 115.0, axis=(1, 2))
        np.testing.assert_array_equal(sc0.measured[name], stereo)
        assert (~stereo).sum() >= 3, f"{name}: some vertices must lie outside the overlap"
        assert stereo.sum() > 100
        # ids in the CSV: measured vertices only (one id per shared object point)
        in_csv = np.isin(ids, list(measured_ids))
        assert not np.any(in_csv & ~stereo)
        xy_key = [tuple(v) for v in np.round(xyz[:, :2], 4)]
        named = {xy_key[i] for i in np.nonzero(in_csv)[0]}
        wanted = {xy_key[i] for i in np.nonzero(stereo)[0]}
        assert named == wanted
        assert in_csv.sum() == len(wanted)
    # every control, check and tie point is measured
    for pid in list(sc0.control.point_id) + list(sc0.tie_ids):
        assert pid in measured_ids


def _rmse(sc, name):
    d = sc.layers[name].coords[:, :2] - sc.truth[name][1][:, :2]
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def test_database_rmse_default_seed(sc0):
    assert 4.0 <= _rmse(sc0, "OSM") <= 4.7
    assert 2.6 <= _rmse(sc0, "TNM") <= 3.2
    assert 17.5 <= _rmse(sc0, "TIGER") <= 21.0
    # TIGER is biased towards the south-east; OSM and TNM are not biased
    d = sc0.layers["TIGER"].coords[:, :2] - sc0.truth["TIGER"][1][:, :2]
    assert d[:, 0].mean() > 8.0 and d[:, 1].mean() < -8.0
    for name in ("OSM", "TNM"):
        d = sc0.layers[name].coords[:, :2] - sc0.truth[name][1][:, :2]
        assert np.all(np.abs(d.mean(axis=0)) < 1.5)


def test_database_rmse_average_over_seeds():
    rm = {n: [] for n in PAPER_RMSE}
    for seed in range(8):
        sc = make_scenario(seed, n_control=0, n_check=0, n_tie=0)
        for n in rm:
            rm[n].append(_rmse(sc, n))
    assert abs(np.mean(rm["OSM"]) - PAPER_RMSE["OSM"]) < 0.25
    assert abs(np.mean(rm["TNM"]) - PAPER_RMSE["TNM"]) < 0.15
    assert abs(np.mean(rm["TIGER"]) - PAPER_RMSE["TIGER"]) < 1.0


def test_control_spread_and_survey_noise(sc0):
    from scipy.spatial import ConvexHull

    ctrl = sc0.control_true[sc0.control.role == "control"]
    assert len(ctrl) == 24 and np.sum(sc0.control.role == "check") == 6
    xy = ctrl[:, :2] - ctrl[:, :2].mean(axis=0)
    s = np.linalg.svd(xy, compute_uv=False)
    assert s[1] / s[0] > 0.5  # far from collinear
    # the stereo overlap of the true images at terrain level: ~ 736 m x 920 m
    xl = sc0.true_eo[:, 0]
    overlap = (xl.min() + 460.0 - (xl.max() - 460.0)) * 920.0
    assert ConvexHull(ctrl[:, :2]).volume > 0.7 * overlap
    d = np.hypot(*(ctrl[:, None, :2] - ctrl[None, :, :2]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert d.min() > 60.0  # no clusters
    chk = sc0.control_true[sc0.control.role == "check"]
    dc = np.hypot(*(chk[:, None, :2] - ctrl[None, :, :2]).transpose(2, 0, 1))
    assert dc.min() > 20.0
    # surveyed = true + N(0, 5 cm / 8 cm), and true Z = terrain
    e = sc0.control.xyz - sc0.control_true
    rms = np.sqrt(np.mean(e**2, axis=0))
    assert 0.025 < rms[0] < 0.08 and 0.025 < rms[1] < 0.08 and 0.04 < rms[2] < 0.13
    np.testing.assert_allclose(sc0.control.sigma, [[0.05, 0.05, 0.08]] * 30)
    np.testing.assert_allclose(
        sc0.control_true[:, 2], terrain_height(sc0.control_true[:, 0], sc0.control_true[:, 1]),
        atol=1e-4)


def test_layers_ids_parts_and_shared_vertices(sc0):
    all_ids = np.concatenate([sc0.truth[n][0] for n in sc0.truth])
    assert len(np.unique(all_ids)) == len(all_ids)  # unique across databases
    for name, layer in sc0.layers.items():
        ids = sc0.truth[name][0]
        expect = np.char.add(np.char.add(layer.feature_ids[layer.vertex_feature], "_"),
                             layer.vertex_index.astype(str))
        np.testing.assert_array_equal(ids, expect)
        assert np.all(np.isnan(layer.coords[:, 2]))  # 2D layers
        # vertex index runs 0..n-1 along each feature, across parts
        for f in range(layer.n_features):
            vi = layer.vertex_index[layer.vertex_feature == f]
            np.testing.assert_array_equal(vi, np.arange(len(vi)))
        multi = [f for f in range(layer.n_features)
                 if layer.vertex_part[layer.vertex_feature == f].max() >= 1]
        assert len(multi) >= 1
        # vertices at the same stored XY belong to different features (intersections)
        _, inv, cnt = np.unique(layer.coords[:, :2], axis=0, return_inverse=True,
                                return_counts=True)
        inv = np.asarray(inv).reshape(-1)
        shared = np.nonzero(cnt[inv] > 1)[0]
        assert len(shared) >= 4
        for g in np.unique(inv[shared]):
            feats = layer.vertex_feature[inv == g]
            assert len(np.unique(feats)) == len(feats)
            # the same true point too
            np.testing.assert_array_equal(np.ptp(sc0.truth[name][1][inv == g], axis=0), 0.0)
        id_values = layer.attributes[sc0.vector_specs[name].id_field]
        assert all(v is not None for v in id_values)
        np.testing.assert_array_equal(layer.feature_ids, [str(v) for v in id_values])
        assert sum(v is None for col in layer.attributes.values() for v in col) >= 1  # a null
    osm = np.asarray(sc0.layers["OSM"].attributes["osm_id"])
    assert np.all((osm >= 40_000_000) & (osm < 50_000_000))
    assert all(len(v) <= 10 for v in sc0.layers["TNM"].attributes["permanent_"])
    assert all(len(s.id_field) <= 10 for s in sc0.vector_specs.values())


def test_images_and_approximations(sc0):
    assert [im.id for im in sc0.images] == ["L", "R"]
    eo = sc0.true_eo
    assert np.all(np.abs(np.degrees(eo[:, 3:])) < 2.0)
    assert abs(np.mean(eo[:, 2]) - 797.6) < 10.0
    assert 165.0 < eo[1, 0] - eo[0, 0] < 205.0  # base 184 m, 80 % overlap
    for im, e in zip(sc0.images, eo):
        assert np.all(np.abs(im.position - e[:3]) <= 0.5)
        np.testing.assert_array_equal(im.attitude, 0.0)
        assert im.sigma_position == 100.0 and im.sigma_attitude == 5.0


def test_dem_is_terrain_plus_noise(sc0):
    g = sc0.dem_grid.astype(float)
    x0, dx, _, y0, _, dy = sc0.dem_transform
    rows, cols = g.shape
    xc = x0 + (np.arange(cols) + 0.5) * dx
    yc = y0 + (np.arange(rows) + 0.5) * dy
    valid = g != sc0.dem_nodata
    assert (~valid).sum() > 0  # a nodata patch exists
    e = (g - terrain_height(xc[None, :], yc[:, None]))[valid]
    assert abs(e.mean()) < 0.01 and 0.13 < e.std() < 0.17
    for layer in sc0.layers.values():
        assert np.all(np.isfinite(bilinear(g, sc0.dem_transform, layer.coords[:, :2],
                                           nodata=sc0.dem_nodata)))


def test_to_project_data(sc0):
    pd = sc0.to_project_data()
    assert [s.name for s, _ in pd.vectors] == ["OSM", "TNM", "TIGER"]
    for spec, layer in pd.vectors:
        z = bilinear(sc0.dem_grid, sc0.dem_transform, layer.coords[:, :2], nodata=sc0.dem_nodata)
        np.testing.assert_array_equal(layer.coords[:, 2], z)
        # close to the true terrain at the stored XY (DEM noise 0.15 m)
        zt = terrain_height(layer.coords[:, 0], layer.coords[:, 1])
        assert np.sqrt(np.mean((layer.coords[:, 2] - zt) ** 2)) < 0.2
        assert np.all(np.isnan(sc0.layers[spec.name].coords[:, 2]))  # not modified
    assert set(pd.truth) == {"OSM", "TNM", "TIGER"}
    assert len(pd.measurements.point_id) == len(sc0.measurements.point_id)
    one = sc0.to_project_data(vectors=["TNM"])
    assert [s.name for s, _ in one.vectors] == ["TNM"]
    others = np.concatenate([sc0.truth["OSM"][0], sc0.truth["TIGER"][0]])
    assert not np.any(np.isin(one.measurements.point_id, others))
    assert np.any(np.isin(one.measurements.point_id, sc0.truth["TNM"][0]))
    assert np.all(np.isin(sc0.control.point_id, one.measurements.point_id))


def test_distortion_hook():
    offset = np.array([0.004, -0.007])
    a = make_scenario(4)
    b = make_scenario(4, image_distortion=lambda xy: xy + offset)
    np.testing.assert_array_equal(a.measurements.point_id, b.measurements.point_id)
    np.testing.assert_allclose(b.measurements.xy - a.measurements.xy,
                               np.broadcast_to(offset, a.measurements.xy.shape), atol=2e-6)


def test_pointing_error_moves_only_shape_points():
    a = make_scenario(6)
    b = make_scenario(6, pointing_sigma=0.5)
    ma, mb = a.measurements, b.measurements
    ka = dict(zip(np.char.add(ma.point_id, ma.image_id).tolist(), ma.xy))
    kb = dict(zip(np.char.add(mb.point_id, mb.image_id).tolist(), mb.xy))
    common = sorted(set(ka) & set(kb))
    d = np.array([kb[k] - ka[k] for k in common])
    ctrl = np.isin([k[:-1] for k in common], a.control.point_id)
    np.testing.assert_array_equal(d[ctrl], 0.0)
    # 0.5 m on the ground at 1:4000 is 0.125 mm on the photo
    rms = np.sqrt(np.mean(d[~ctrl] ** 2, axis=0))
    assert np.all((rms > 0.09) & (rms < 0.16))
    for name in a.layers:  # databases and truth unchanged
        np.testing.assert_array_equal(a.layers[name].coords, b.layers[name].coords)


def test_strip_of_images():
    sc = make_scenario(5, n_images=4)
    assert [im.id for im in sc.images] == ["I01", "I02", "I03", "I04"]
    base = np.diff(sc.true_eo[:, 0])
    assert np.all(np.abs(base - 184.0) < 20.0)
    m = sc.measurements
    _, counts = np.unique(m.point_id, return_counts=True)
    assert counts.min() >= 2 and counts.max() >= 3
    assert set(m.image_id.tolist()) == {"I01", "I02", "I03", "I04"}
    w = _reprojection_residuals(sc)
    assert abs(np.mean(w**2) - 1.0) < 5.0 * np.sqrt(2.0 / w.size)


def test_dense_mode_size():
    # its speed (target < 10 s) is measured by benchmarks/bench_unit_speed.py, not here
    sc = make_scenario(1, n_shape_points=100_000)
    shape_ids = np.concatenate([sc.truth[n][0] for n in sc.truth])
    measured = np.unique(sc.measurements.point_id[np.isin(sc.measurements.point_id,
                                                          shape_ids)])
    assert abs(len(measured) - 100_000) < 5_000
    assert np.all(np.abs(sc.measurements.xy) < 115.0)
    for name in sc.layers:
        assert abs(_rmse(sc, name) - PAPER_RMSE[name]) < 0.1 * PAPER_RMSE[name]


def _read_csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_write_project_reads_back(tmp_path, sc0):
    gpd = pytest.importorskip("geopandas")
    rasterio = pytest.importorskip("rasterio")
    toml_path = write_project(sc0, tmp_path)
    with open(toml_path, "rb") as fh:
        proj = tomllib.load(fh)
    assert proj["crs"] == "EPSG:32616"
    assert proj["camera"]["focal_length"] == 152.4
    assert [im["id"] for im in proj["images"]] == ["L", "R"]
    for im, spec in zip(proj["images"], sc0.images):
        np.testing.assert_array_equal(im["position"], spec.position)
        assert im["sigma_position"] == 100.0 and im["sigma_attitude"] == 5.0
    assert proj["measurements"]["sigma"] == 0.015
    for entry in proj["vectors"]:
        for key in ("path", "dem", "truth"):
            assert (tmp_path / entry[key]).is_file()
        assert entry["id_field"] == sc0.vector_specs[entry["name"]].id_field
    assert (tmp_path / proj["measurements"]["path"]).is_file()
    assert (tmp_path / "README.md").read_text().startswith("# Simulated")

    rows = _read_csv(tmp_path / "image_points.csv")
    assert list(rows[0]) == ["point_id", "image_id", "x", "y", "sigma_x", "sigma_y"]
    m = sc0.measurements
    assert [r["point_id"] for r in rows] == m.point_id.tolist()
    assert [r["image_id"] for r in rows] == m.image_id.tolist()
    xy = np.array([[float(r["x"]), float(r["y"])] for r in rows])
    np.testing.assert_allclose(xy, m.xy, atol=5e-7)

    rows = _read_csv(tmp_path / "gcps.csv")
    assert list(rows[0]) == ["point_id", "X", "Y", "Z", "sigma_x", "sigma_y", "sigma_z", "role"]
    xyz = np.array([[float(r[k]) for k in "XYZ"] for r in rows])
    np.testing.assert_allclose(xyz, sc0.control.xyz, atol=5e-4)
    assert [r["role"] for r in rows] == sc0.control.role.tolist()

    for entry in proj["vectors"]:
        name = entry["name"]
        layer = sc0.layers[name]
        frame = gpd.read_file(tmp_path / entry["path"])
        assert frame.crs.to_epsg() == 32616
        assert len(frame) == layer.n_features
        assert not frame.has_z.any()
        got = np.array([c for g in frame.geometry
                        for c in (g.coords if g.geom_type == "LineString"
                                  else [p for part in g.geoms for p in part.coords])])
        np.testing.assert_allclose(got, layer.coords[:, :2], atol=1e-9)
        assert "MultiLineString" in set(frame.geom_type)
        for col, values in layer.attributes.items():
            read = frame[col].tolist()
            for a, b in zip(read, values):
                if b is None:
                    assert a is None or a != a  # null (None or NaN)
                else:
                    assert a == b
        rows = _read_csv(tmp_path / entry["truth"])
        ids, txyz = sc0.truth[name]
        assert [r["point_id"] for r in rows] == ids.tolist()
        np.testing.assert_allclose([[float(r[k]) for k in "XYZ"] for r in rows], txyz,
                                   atol=5e-5)

    truth = gpd.read_file(tmp_path / "truth_roads.shp")
    assert truth.has_z.all() and len(truth) == len(sc0.truth_lines)
    with rasterio.open(tmp_path / "dem.tif") as dem:
        assert dem.crs.to_epsg() == 32616
        assert dem.nodata == sc0.dem_nodata
        assert dem.profile["compress"].lower() == "deflate"
        assert dem.dtypes[0] == "float32"
        np.testing.assert_allclose(dem.transform.to_gdal(), sc0.dem_transform)
        np.testing.assert_array_equal(dem.read(1), sc0.dem_grid)
    eo = _read_csv(tmp_path / "truth_eo.csv")
    np.testing.assert_allclose([float(r["XL"]) for r in eo], sc0.true_eo[:, 0], atol=5e-5)


def test_write_gpkg(tmp_path):
    gpd = pytest.importorskip("geopandas")
    sc = make_scenario(2, n_shape_points=600)
    path = write_project(sc, tmp_path, format="gpkg")
    with open(path, "rb") as fh:
        proj = tomllib.load(fh)
    assert proj["vectors"][0]["path"] == "osm_roads.gpkg"
    frame = gpd.read_file(tmp_path / "osm_roads.gpkg")
    assert len(frame) == sc.layers["OSM"].n_features


def test_cli(tmp_path, capsys):
    pytest.importorskip("geopandas")
    pytest.importorskip("rasterio")
    assert simulate.main([str(tmp_path / "p"), "--seed", "3", "--shape-points", "900"]) == 0
    assert (tmp_path / "p" / "project.toml").is_file()
    assert "wrote" in capsys.readouterr().out
    assert simulate.main([str(tmp_path / "q"), "--images", "1"]) == 2


def test_sample_project_is_small_and_consistent():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "resources" / "sample"
    if not (root / "project.toml").is_file():
        pytest.skip("resources/sample not generated")
    total = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    assert total < 2_000_000
    with open(root / "project.toml", "rb") as fh:
        proj = tomllib.load(fh)
    seed = int(proj["name"].rsplit(" ", 1)[1])
    # the sample's camera file and the effects its [corrections] undo
    cal = CameraCalibration.from_dict(proj["camera"], root) if "path" in proj["camera"] else None
    effects = [e for e in EFFECTS if proj.get("corrections", {}).get(e)] if cal else []
    scan = proj["measurements"].get("unit", "mm") == "pixel"
    ident = proj["vectors"][0].get("identification_sigma")  # the simulated pointing error
    sc = make_scenario(seed, calibration=cal, effects=effects, scan=scan,
                       pointing_sigma=float(ident[0]) if ident else 0.0)
    rows = _read_csv(root / "image_points.csv")
    np.testing.assert_allclose([float(r["x"]) for r in rows], sc.measurements.xy[:, 0],
                               atol=5e-7)
    np.testing.assert_allclose([float(r["y"]) for r in rows], sc.measurements.xy[:, 1],
                               atol=5e-7)


def test_real_true_roads_are_split_at_shared_vertices_and_centred():
    """``true_roads``: lines (here in UTM-like coordinates far from the model) become the
    true roads; a vertex shared by two lines (one of them 0.4 mm off) is an intersection,
    the lines are split there, and the databases are projected like the grid's."""
    x0, y0 = 385_000.0, 6_672_000.0
    ew = np.array([[x0 - 200.0, y0], [x0, y0], [x0 + 200.0, y0]])  # crossing at (x0, y0)
    ns = np.array([[x0, y0 - 150.0], [x0 + 0.0004, y0], [x0, y0 + 150.0]])
    bend = np.array([[x0 + 200.0, y0], [x0 + 230.0, y0 + 60.0], [x0 + 200.0, y0 + 120.0]])
    sc = make_scenario(2, databases=("OSM", "TNM"), true_roads=[ew, ns, bend],
                       vertex_spacing=10.0)
    real = sc.options["true_roads"]
    assert real["lines"] == 3 and real["features"] == 5  # ew, ns split at the crossing
    # the bounding box (x0-200 .. x0+230, y0-150 .. y0+150) is centred on the model
    assert real["shift"] == pytest.approx([sc.center[0] - (x0 + 15.0), sc.center[1] - y0])
    cross = np.array([x0, y0]) + real["shift"]
    for name in ("OSM", "TNM"):
        ids, xyz = sc.truth[name]
        at = np.flatnonzero(np.all(np.abs(xyz[:, :2] - cross) < 1e-3, axis=1))
        assert len(at) == 4  # four features meet: one object point, four vertices
        layer = sc.layers[name]
        assert len(np.unique(layer.vertex_feature[at])) == 4
        assert len(np.unique(layer.coords[at, :2], axis=0)) == 1
        assert sc.measured[name].all()
    lengths = [np.hypot(*np.diff(c[:, :2], axis=0).T).sum() for c in sc.truth_lines]
    assert sum(lengths) == pytest.approx(400.0 + 300.0 + 2 * np.hypot(30.0, 60.0), abs=1e-3)
    w = _reprojection_residuals(sc)
    assert np.sqrt(np.mean(w**2)) < 1.3
    # n_shape_points sets the spacing for about that many measured shape points
    sc = make_scenario(2, databases=("OSM",), true_roads=[ew, ns, bend], n_shape_points=200)
    assert abs(len(np.unique(sc.truth["OSM"][1], axis=0)) - 200) <= 3
