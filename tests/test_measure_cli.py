"""``vectoradjust measure`` end to end on a rendered project, then ``vectoradjust adjust``.

A stereo pair is rendered (known orientation), written as GeoTIFF images with a DEM,
a road layer and surveyed control points; ``measure predict --roads`` locates the road
junctions, ``measure transfer`` carries the control points measured on the left image
to the right one, and the ``image_points.csv`` it writes is adjusted: the adjusted
orientation must come back to the true one.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from measure_pair import rendered_pair

from vectoradjust.cli.commands import main

pytestmark = pytest.mark.io  # writes and reads GeoTIFF images and geodata


def _write_project(tmp, pair):
    import geopandas as gpd
    import rasterio
    import rasterio.errors
    from rasterio.transform import from_origin
    from shapely.geometry import LineString

    for iid, img in pair.images.items():
        with warnings.catch_warnings():  # aerial images have no georeferencing
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(tmp / f"{iid}.tif", "w", driver="GTiff", width=img.shape[1],
                               height=img.shape[0], count=1, dtype="uint8") as ds:
                ds.write(img, 1)
    o = pair.scene.origin
    xs = o[0] + 2.5 + 5.0 * np.arange(100)
    ys = o[1] - 2.5 - 5.0 * np.arange(100)
    gx, gy = np.meshgrid(xs, ys)
    z = pair.scene.height(np.c_[gx.ravel(), gy.ravel()]).reshape(gx.shape)
    with rasterio.open(tmp / "dem.tif", "w", driver="GTiff", width=100, height=100, count=1,
                       dtype="float64", crs="EPSG:32616",
                       transform=from_origin(o[0], o[1], 5.0, 5.0)) as ds:
        ds.write(z, 1)
    lines = []
    shift = np.array([1.5, -1.0])  # the database is off the real roads
    for r in pair.scene.roads:
        d = r[1] - r[0]
        t = (pair.junctions[:, :2] - r[0]) @ d / (d @ d)
        rel = pair.junctions[:, :2] - r[0]
        near = np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]) / np.hypot(*d) < 1e-6
        inner = r[0] + np.sort(t[near])[:, None] * d
        lines.append(LineString(np.vstack([r[0], inner, r[1]]) + shift))
    gpd.GeoDataFrame({"rid": np.arange(len(lines))}, geometry=lines,
                     crs="EPSG:32616").to_file(tmp / "roads.shp")
    rng = np.random.default_rng(3)
    xy = np.c_[rng.uniform(500165, 500335, 12), rng.uniform(4399600, 4399900, 12)]
    gcp = np.c_[xy, pair.scene.height(xy)]
    with open(tmp / "gcps.csv", "w") as fh:
        fh.write("point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role\n")
        for i, p in enumerate(gcp):
            fh.write(f"G{i},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},0.05,0.05,0.08,control\n")
    px = pair.true["L"].to_pixel(gcp)
    with open(tmp / "measured.csv", "w") as fh:
        fh.write("point_id,image_id,col,row\n")
        for i, p in enumerate(px):
            fh.write(f"G{i},L,{p[0]:.3f},{p[1]:.3f}\n")
    cam = pair.true["L"].camera
    imgs = ""
    for iid, g in pair.approx.items():
        pos = [float(v) for v in g.eo[:3]]
        imgs += (f'[[images]]\nid = "{iid}"\npath = "{iid}.tif"\nposition = {pos}\n'
                 f"attitude = {[float(v) for v in np.degrees(g.eo[3:])]}\nsigma_position = 1.0\n"
                 "sigma_attitude = 0.05\n\n")
    dist = ", ".join(f"{k} = {float(v)!r}" for k, v in cam.distortion_coefficients.items())
    (tmp / "project.toml").write_text(
        f'crs = "EPSG:32616"\n[camera]\nfocal_length = {cam.focal_length}\n'
        f"principal_point = {[float(v) for v in cam.principal_point]}\n"
        f"pixel_size = {cam.pixel_size[0]}\n"
        f"image_size = {[int(v) for v in cam.image_size]}\n"
        f'distortion = {{ model = "smac", {dist} }}\n\n{imgs}'
        '[measurements]\npath = "out/image_points.csv"\n\n[control]\npath = "gcps.csv"\n\n'
        '[[vectors]]\nname = "roads"\npath = "roads.shp"\nid_field = "rid"\n'
        'sigma = [3.0, 3.0, 3.0]\ndem = "dem.tif"\n')
    return tmp / "project.toml"


def test_measure_then_adjust(tmp_path):
    pair = rendered_pair(1)
    proj = _write_project(tmp_path, pair)
    out = tmp_path / "out"
    assert main(["measure", "predict", str(proj), "--out", str(out), "--roads", "-q",
                 "--chips", "png", "--chip-size", "16"]) == 0
    assert (out / "measurement_template.csv").is_file()
    assert any((out / "chips" / "L").iterdir())
    assert main(["measure", "transfer", str(proj), "--out", str(out), "-q", "--measured",
                 str(tmp_path / "measured.csv"), "--automatic",
                 str(out / "automatic_points.csv")]) == 0
    assert (out / "image_points.csv").read_text().splitlines()[0] == \
        "point_id,image_id,x,y,sigma_x,sigma_y"
    text = (out / "image_points_quality.csv").read_text().splitlines()
    assert text[0].startswith("point_id,image_id,x,y,sigma_x,sigma_y,source")
    sources = {line.split(",")[6] for line in text[1:]}
    assert {"manual", "transferred", "automatic"} <= sources
    assert main(["adjust", str(proj), "--out", str(tmp_path / "adj"), "-q"]) == 0
    summary = json.loads((tmp_path / "adj" / "summary.json").read_text())
    for im in summary["images"]:
        true = pair.true[im["id"]].eo
        assert np.abs(np.asarray(im["position"]) - true[:3]).max() < 0.5
        assert np.abs(np.radians(im["attitude"]) - true[3:]).max() < np.radians(0.05)
    # the automatic measurements are not worse than the sigmas written for them
    assert summary["sigma0_squared"] < 2.0
    # a second round with the adjusted orientation: much smaller search windows for the
    # control points (those of the shape points stay dominated by the database's 3 m)
    assert main(["measure", "predict", str(proj), "--out", str(tmp_path / "m2"), "-q",
                 "--chips", "none", "--orientation", str(tmp_path / "adj" / "summary.json")]) == 0
    before = _column(out / "measurement_template.csv", "win_major")
    after = _column(tmp_path / "m2" / "measurement_template.csv", "win_major")
    assert np.median(after) < 0.25 * np.median(before)


def _column(path, name):
    import csv

    with open(path, newline="") as fh:
        return np.array([float(r[name]) for r in csv.DictReader(fh) if r["kind"] == "control"])


def test_missing_image_file_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "p.toml").write_text(
        'crs = "EPSG:32616"\n[camera]\nfocal_length = 50.0\npixel_size = 0.04\n'
        'image_size = [100, 100]\n[[images]]\nid = "L"\nposition = [0.0, 0.0, 300.0]\n'
        '[measurements]\npath = "image_points.csv"\n')
    assert main(["measure", "predict", str(tmp_path / "p.toml"), "--out", str(tmp_path),
                 "-q"]) == 1
    err = capsys.readouterr().err
    assert "no image file for L" in err and "path =" in err
    assert main(["measure", "predict", str(tmp_path / "p.toml"), "--out", str(tmp_path),
                 "-q", "--image", "L=nothing.tif"]) == 1
    assert "nothing.tif does not exist" in capsys.readouterr().err
