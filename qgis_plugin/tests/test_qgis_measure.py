"""Measure on the images through ``processing.run`` on a rendered stereo pair (fractal
texture, lens distortion, different radiometry): the points measured on the left image are
found on the right one within a pixel of their true position (from the true orientation),
flagged ones are not accepted, and image_points.csv is written in the contract format.
Runs the core under QGIS's numpy/scipy and reads the images with QGIS's GDAL."""

import csv

import numpy as np
import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis


def _write(tmp, pair):
    from osgeo import gdal

    for iid, img in pair.images.items():
        ds = gdal.GetDriverByName("GTiff").Create(str(tmp / f"{iid}.tif"), img.shape[1],
                                                  img.shape[0], 1, gdal.GDT_Byte)
        ds.GetRasterBand(1).WriteArray(img)
        ds = None
    rng = np.random.default_rng(3)
    c = pair.scene.origin + [250.0, -250.0]
    xy = np.c_[rng.uniform(c[0] - 80, c[0] + 80, 40), rng.uniform(c[1] - 140, c[1] + 140, 40)]
    xyz = np.c_[xy, pair.scene.height(xy)]
    pl, pr = pair.true["L"].to_pixel(xyz), pair.true["R"].to_pixel(xyz)
    size = pair.images["L"].shape[0]
    ok = (np.minimum(pl.min(1), pr.min(1)) > 40) & (np.maximum(pl.max(1), pr.max(1)) < size - 40)
    with open(tmp / "gcps.csv", "w") as fh:
        fh.write("point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role\n")
        for i in np.flatnonzero(ok):
            fh.write(f"P{i},{xyz[i, 0]:.4f},{xyz[i, 1]:.4f},{xyz[i, 2]:.4f},0.05,0.05,0.08,"
                     "control\n")
    with open(tmp / "measured.csv", "w") as fh:
        fh.write("point_id,image_id,col,row\n")
        for i in np.flatnonzero(ok):
            fh.write(f"P{i},L,{pl[i, 0]:.4f},{pl[i, 1]:.4f}\n")
    cam = pair.true["L"].camera
    dist = ", ".join(f"{k} = {float(v)!r}" for k, v in cam.distortion_coefficients.items())
    imgs = ""
    for iid, g in pair.approx.items():
        imgs += (f'[[images]]\nid = "{iid}"\npath = "{iid}.tif"\n'
                 f"position = {[float(v) for v in g.eo[:3]]}\n"
                 f"attitude = {[float(v) for v in np.degrees(g.eo[3:])]}\n"
                 "sigma_position = 0.5\nsigma_attitude = 0.02\n\n")
    (tmp / "project.toml").write_text(
        f'crs = "EPSG:32616"\n[camera]\nfocal_length = {cam.focal_length}\n'
        f"principal_point = {[float(v) for v in cam.principal_point]}\n"
        f"pixel_size = {cam.pixel_size[0]}\nimage_size = {[int(v) for v in cam.image_size]}\n"
        f'distortion = {{ model = "smac", {dist} }}\n\n{imgs}'
        '[measurements]\npath = "image_points.csv"\n\n[control]\npath = "gcps.csv"\n')
    return {f"P{i}": pr[i] for i in np.flatnonzero(ok)}


def test_transfer_in_qgis(qgis_app, tmp_path):
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback

    from vectoradjust.simulate.measure_scene import stereo_pair

    pair = stereo_pair(400, seed=2, texture="fractal", sigma_position=0.5,
                       sigma_attitude=0.02)
    truth = _write(tmp_path, pair)
    context = QgsProcessingContext()
    out = processing.run("vectoradjust:measureonimages", {
        "PROJECT": str(tmp_path / "project.toml"), "MEASURED": str(tmp_path / "measured.csv"),
        "OUTPUT": "memory:", "IMAGE_POINTS": str(tmp_path / "image_points.csv")},
        context=context, feedback=QgsProcessingFeedback())
    layer = context.getMapLayer(out["OUTPUT"]) if isinstance(out["OUTPUT"], str) \
        else out["OUTPUT"]
    feats = [f for f in layer.getFeatures() if f["source"] == "transferred"]
    assert len(feats) == len(truth)
    accepted = [f for f in feats if f["accepted"] == 1]
    assert len(accepted) >= 0.6 * len(feats)
    for f in accepted:
        err = np.hypot(f["col"] - truth[f["point_id"]][0], f["row"] - truth[f["point_id"]][1])
        assert err < 1.0, (f["point_id"], err)
        assert f["flags"] in (None, "")
        pt = f.geometry().asPoint()
        assert abs(pt.x() - f["col"]) < 1e-9 and abs(pt.y() + f["row"]) < 1e-9
    assert all(f["flags"] for f in feats if f["accepted"] == 0)
    with open(tmp_path / "image_points.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["point_id", "image_id", "x", "y", "sigma_x", "sigma_y"]
    assert len(rows) - 1 == len(truth) + len(accepted)
    assert out["ACCEPTED"] == len(accepted)
