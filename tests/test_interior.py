"""Image coordinate refinement in projects (sensor.interior, docs/method.md sections 5, 7, 9).

Independent truth: the simulator's TRUE ideal image coordinates (a scenario simulated
with the same seed but without any physical effect draws the same noise), the truth
of the simulated ground points, Monte Carlo propagation of pixel errors through a
known scanner affine, the algebraic identity "reduce the principal point = put it in
the collinearity equations", and the files read back.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import CameraError, CSVError, MeasurementError, ProjectError
from vectoradjust.model import Camera, ControlPoints, ImageSpec, Measurements
from vectoradjust.pipeline import run
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.interior import (
    FiducialMeasurements,
    describe_interior,
    parse_corrections,
    refine_measurements,
)
from vectoradjust.simulate import EFFECTS, make_scenario

# A scanned-film camera whose lens has the SMAC coefficients of the sample USGS
# calibration report (Wolf & Dewitt's example, also in tests/test_refine.py): about
# 17 um of distortion at the format corners. Fiducials and pixel size are made up.
LENS_TOML = """\
name = "test camera (SMAC sample lens)"
focal_length = 152.4
principal_point = [0.003, -0.001]
pixel_size = 0.012

[fiducials]
1 = [-105.997, -105.995]
2 = [106.004, 106.001]
3 = [-106.002, 106.003]
4 = [105.998, -105.999]
5 = [-112.001, 0.002]
6 = [112.003, -0.001]
7 = [0.001, 112.002]
8 = [-0.002, -111.998]

[distortion]
model = "smac"
convention = "correction"
K0 = -0.2165e-3
K1 = 0.4230e-7
K2 = -0.1652e-11
K3 = 0.2860e-19
K4 = 0.5690e-26
P1 = -0.1483e-6
P2 = 0.1558e-6
P3 = -0.1464e-18
P4 = 0.1233e-38
"""
SEED = 1
SIGMA_IMAGE = 0.004  # mm: a good scan, so that 10-20 um effects are not lost in noise
FIDUCIAL_SIGMA = 0.001  # mm
OFF = {"distortion": False, "refraction": False, "earth_curvature": False}


@pytest.fixture(scope="module")
def lens_file(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("camera") / "lens.toml"
    p.write_text(LENS_TOML, encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def lens(lens_file) -> CameraCalibration:
    return CameraCalibration.from_file(lens_file)


@pytest.fixture(scope="module")
def clean():
    return make_scenario(SEED, sigma_image=SIGMA_IMAGE)


@pytest.fixture(scope="module")
def distorted(lens):
    """Same seed, image coordinates WITH distortion, refraction, earth curvature, in
    scanner pixels with a random scanner affine per image and measured fiducials."""
    return make_scenario(SEED, sigma_image=SIGMA_IMAGE, calibration=lens, effects=EFFECTS,
                         scan=True, fiducial_sigma=FIDUCIAL_SIGMA)


def _truth_errors(sc, adjustment) -> dict:
    """RMSE (m) of adjusted - TRUE: shape points and check points, horizontal, Z, 3D."""
    err = []
    for d in adjustment.databases:
        adj = d.vertices["Adjusted"] == 1
        t = sc.truth[d.name][1][adj]
        err.append(np.column_stack([d.vertices["AdjX"][adj] - t[:, 0],
                                    d.vertices["AdjY"][adj] - t[:, 1],
                                    d.vertices["AdjZ"][adj] - t[:, 2]]))
    shape = np.concatenate(err)
    cp = adjustment.control_points
    chk = np.asarray(cp["role"]) == "check"
    true = dict(zip(sc.control.point_id.tolist(), sc.control_true))
    t = np.array([true[i] for i in np.asarray(cp["point_id"])[chk]])
    check = np.column_stack([np.asarray(cp[k], float)[chk] - t[:, j]
                             for j, k in enumerate(("AdjX", "AdjY", "AdjZ"))])

    def rmse(e):
        h = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
        z = float(np.sqrt(np.mean(e[:, 2] ** 2)))
        return {"n": len(e), "h": h, "z": z, "3d": float(np.hypot(h, z))}

    return {"shape": rmse(shape), "check": rmse(check)}


@pytest.fixture(scope="module")
def recovery(clean, distorted):
    out = {
        "clean": _truth_errors(clean, run(clean.to_project_data())),
        "on": _truth_errors(distorted, run(distorted.to_project_data())),
        "off": _truth_errors(distorted, run(distorted.to_project_data(corrections=OFF))),
    }
    print("\nRMSE adjusted - truth (cm), shape points and check points, h / z / 3d:")
    for k, v in out.items():
        print(f"  {k:5s} shape {v['shape']['h'] * 100:.2f} / {v['shape']['z'] * 100:.2f} / "
              f"{v['shape']['3d'] * 100:.2f}   check {v['check']['h'] * 100:.2f} / "
              f"{v['check']['z'] * 100:.2f} / {v['check']['3d'] * 100:.2f}")
    return out


# ============================================================ the distorted simulation
def test_refined_coordinates_are_the_ideal_ones(clean, distorted):
    """Refinement undoes scanner affine, principal point, distortion, refraction, curvature.

    The clean scenario of the same seed has the ideal coordinates plus the SAME noise,
    so the refined coordinates must match it up to the fiducial affine's error (1 um
    fiducials) and the mean-terrain / approximate-ZL approximations of the corrections.
    """
    on = distorted.to_project_data()
    off = distorted.to_project_data(corrections=OFF)
    ref = clean.measurements
    assert np.array_equal(on.measurements.point_id, ref.point_id)
    assert np.array_equal(on.measurements.image_id, ref.image_id)
    d_on = np.hypot(*(on.measurements.xy - ref.xy).T) * 1000.0
    d_off = np.hypot(*(off.measurements.xy - ref.xy).T) * 1000.0
    assert np.sqrt(np.mean(d_on**2)) < 1.0 and d_on.max() < 2.5  # um
    assert np.sqrt(np.mean(d_off**2)) > 5.0 and d_off.max() > 15.0  # the effects are real
    assert on.camera.principal_point == (0.0, 0.0)
    # the sigmas (pixels in the scenario) come back in mm
    np.testing.assert_allclose(on.measurements.sigma, SIGMA_IMAGE, rtol=2e-3)
    rep = on.interior
    assert rep["corrections"]["applied"] == ["affine", "principal_point", "distortion",
                                             "refraction", "earth_curvature"]
    assert rep["io_check"]["passed"] is True and rep["io_check"]["images_checked"] == 2
    assert rep["terrain_height"]["value"] == pytest.approx(
        np.mean(distorted.control.xyz[:, 2]))


def test_corrections_on_recover_truth_like_a_clean_scenario(recovery):
    on, clean = recovery["on"], recovery["clean"]
    for kind in ("shape", "check"):
        assert on[kind]["3d"] == pytest.approx(clean[kind]["3d"], rel=0.05, abs=0.003), kind
    assert on["shape"]["n"] == clean["shape"]["n"] > 300


def test_corrections_off_are_measurably_worse(recovery):
    on, off = recovery["on"], recovery["off"]
    assert off["shape"]["3d"] > 1.10 * on["shape"]["3d"]
    assert off["shape"]["z"] > 1.10 * on["shape"]["z"]
    assert off["check"]["3d"] > 1.20 * on["check"]["3d"]


def test_corrections_off_leave_a_systematic_image_residual(distorted):
    s_on = run(distorted.to_project_data()).summary["sigma0_squared"]
    s_off = run(distorted.to_project_data(corrections=OFF)).summary["sigma0_squared"]
    assert s_off > 1.03 * s_on


# ============================================================ in-memory API
def _tiny(sigma=1.5):
    """One image of three points, measured through a known scanner affine."""
    ang = np.radians(30.0)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    lin = rot @ np.array([[0.012, 0.0], [0.0, -0.012]])  # mm per pixel, rows down
    off = np.array([1.5, -2.0])
    cal = CameraCalibration(152.4, (0.0, 0.0), fiducials={
        "a": (-100.0, -100.0), "b": (100.0, -100.0), "c": (100.0, 100.0), "d": (-100.0, 100.0)},
        pixel_size=0.012)
    ids = list(cal.fiducials)
    cal_xy = np.array([cal.fiducials[i] for i in ids])
    fid_px = (cal_xy - off) @ np.linalg.inv(lin).T
    fids = FiducialMeasurements(["I"] * 4, ids, fid_px)
    pts_mm = np.array([[10.0, 20.0], [-50.0, 30.0], [80.0, -70.0]])
    meas = Measurements(["p", "q", "r"], ["I"] * 3, (pts_mm - off) @ np.linalg.inv(lin).T,
                        sigma)
    img = [ImageSpec("I", np.array([0.0, 0.0, 800.0]), np.zeros(3))]
    return meas, img, cal, fids, lin, pts_mm


def test_pixel_sigmas_follow_the_scanner_affine_monte_carlo():
    meas, img, cal, fids, lin, pts = _tiny(sigma=np.array([[2.0, 0.5]] * 3))
    res = refine_measurements(meas, img, cal, unit="pixel", fiducials=fids)
    np.testing.assert_allclose(res.measurements.xy, pts, atol=1e-9)
    rng = np.random.default_rng(7)
    e = rng.normal(0.0, 1.0, (200_000, 2)) * np.array([2.0, 0.5])  # pixel errors
    mc = np.std(e @ lin.T, axis=0)  # the same errors in mm
    np.testing.assert_allclose(res.measurements.sigma[0], mc, rtol=0.01)
    assert res.report["sigma"]["unit"] == "pixel"
    # isotropic sigma: rotation does not matter, sigma_mm = sigma_px * pixel size
    meas, img, cal, fids, *_ = _tiny(sigma=1.5)
    res = refine_measurements(meas, img, cal, unit="pixel", fiducials=fids)
    np.testing.assert_allclose(res.measurements.sigma, 1.5 * 0.012, rtol=1e-9)


def test_digital_frame_sigma_and_coordinates():
    cal = CameraCalibration(50.0, (0.0, 0.0), pixel_size=0.005, image_size=(4001, 3001))
    meas = Measurements(["p"], ["I"], [[2000.0 + 100.0, 1500.0 - 200.0]], 0.8)
    img = [ImageSpec("I", np.array([0.0, 0.0, 500.0]), np.zeros(3))]
    res = refine_measurements(meas, img, cal, unit="pixel")
    np.testing.assert_allclose(res.measurements.xy, [[0.5, 1.0]], atol=1e-12)  # y up
    np.testing.assert_allclose(res.measurements.sigma, 0.8 * 0.005)
    assert res.report["corrections"]["applied"][0] == "pixel_to_photo"


def test_principal_point_reduction_equals_principal_point_in_collinearity(clean):
    """Reducing x0, y0 in the image coordinates or giving them to the bundle is the same."""
    cal = CameraCalibration(152.4, (0.020, -0.015))
    data = clean.to_project_data(vectors=["OSM"])
    reduced = refine_measurements(data.measurements, data.images, cal, {}, control=data.control)
    kept = refine_measurements(data.measurements, data.images, cal,
                               {"principal_point": False}, control=data.control)
    assert reduced.principal_point == (0.0, 0.0)
    assert kept.principal_point == (0.020, -0.015)
    np.testing.assert_allclose(reduced.measurements.xy, data.measurements.xy - [0.020, -0.015])
    np.testing.assert_allclose(kept.measurements.xy, data.measurements.xy)
    results = []
    for r in (reduced, kept):
        d = clean.to_project_data(vectors=["OSM"])
        d.measurements = r.measurements
        d.camera = Camera(152.4, r.principal_point, calibration=cal)
        results.append(run(d).databases[0].vertices)
    for k in ("AdjX", "AdjY", "AdjZ"):
        np.testing.assert_allclose(results[0][k], results[1][k], atol=1e-6)


def test_earth_curvature_only_for_a_map_projection(distorted):
    d = distorted.to_project_data(vectors=["OSM"])  # to get the raw inputs' companions
    sc = distorted
    res = refine_measurements(sc.measurements, sc.images, sc.camera, {"earth_curvature": True},
                              unit="pixel", fiducials=sc.fiducials, control=sc.control,
                              map_projection=False)
    assert "earth_curvature" not in res.report["corrections"]["applied"]
    assert any("map projection" in n for n in res.report["notes"])
    assert d.interior["corrections"]["max_um"]["earth_curvature"] > 5.0


def test_terrain_height_key_wins_over_control(distorted):
    sc = distorted
    res = refine_measurements(sc.measurements, sc.images, sc.camera,
                              {"refraction": True, "terrain_height": 150.0}, unit="pixel",
                              fiducials=sc.fiducials, control=sc.control)
    assert res.report["terrain_height"] == {"value": 150.0,
                                            "source": "[corrections] terrain_height"}


def test_describe_interior_names_sizes_and_verdict(distorted):
    rep = distorted.to_project_data().interior
    lines = describe_interior(rep)
    assert len(lines) == 2
    d = rep["corrections"]["max_um"]["distortion"]
    assert f"lens distortion {d:.1f} um" in lines[0] and "pixel" in lines[0]
    assert "pass" in lines[1] and "2 image(s)" in lines[1]
    assert describe_interior(None) == [] and describe_interior({}) == []


def test_in_memory_errors():
    meas, img, cal, fids, *_ = _tiny()
    with pytest.raises(ProjectError, match="terrain_height"):
        refine_measurements(meas, img, cal, {"refraction": True}, unit="pixel", fiducials=fids)
    ctrl = ControlPoints(["g"], [[0.0, 0.0, 900.0]], 0.05, ["control"])
    with pytest.raises(CameraError, match="image 'I': flying height ZL = 800.0 m"):
        refine_measurements(meas, img, cal, {"refraction": True}, unit="pixel", fiducials=fids,
                            control=ctrl)
    with pytest.raises(ProjectError, match="unknown key 'refractoin'"):
        parse_corrections({"refractoin": True})
    with pytest.raises(ProjectError, match="must be true or false"):
        parse_corrections({"refraction": "yes"})
    with pytest.raises(ProjectError, match="unit = 'inch'"):
        refine_measurements(meas, img, cal, unit="inch")
    with pytest.raises(MeasurementError, match="image 'X' is not defined"):
        refine_measurements(meas, img, cal, unit="pixel",
                            fiducials=FiducialMeasurements(["X"] * 4, list("abcd"), fids.xy))


def test_simulation_options_are_checked(lens):
    with pytest.raises(ProjectError, match="need a camera calibration"):
        make_scenario(0, effects=("refraction",))
    with pytest.raises(ProjectError, match="unknown simulated effect"):
        make_scenario(0, calibration=lens, effects=("smog",))
    with pytest.raises(ProjectError, match="fiducials and pixel_size"):
        make_scenario(0, calibration=CameraCalibration(152.4), scan=True)


# ============================================================ through project files
@pytest.fixture(scope="module")
def scan_project(distorted, lens_file, tmp_path_factory):
    pytest.importorskip("geopandas")
    pytest.importorskip("rasterio")
    from vectoradjust.simulate import write_project

    d = tmp_path_factory.mktemp("scan")
    write_project(distorted, d)
    return d


@pytest.fixture()
def broken(scan_project, tmp_path) -> Path:
    d = tmp_path / "p"
    shutil.copytree(scan_project, d)
    return d


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text, (old, path)
    path.write_text(text.replace(old, new, 1), encoding="utf-8")


def _load(d: Path):
    from vectoradjust.files.readers import load_project_data

    return load_project_data(d / "project.toml")


@pytest.mark.io
def test_scanned_project_files_give_the_in_memory_result(scan_project, distorted):
    text = (scan_project / "project.toml").read_text()
    assert 'path = "lens.toml"' in text and 'unit = "pixel"' in text
    assert (scan_project / "lens.toml").read_text() == LENS_TOML  # a copy of the camera file
    data = _load(scan_project)
    mem = distorted.to_project_data()
    assert isinstance(data.camera.calibration, CameraCalibration)
    assert data.camera.calibration.name == "test camera (SMAC sample lens)"
    assert data.camera.principal_point == (0.0, 0.0)
    # pixels written with 4 decimals (1.2 nm), mm sigmas from the pixel sigma
    np.testing.assert_allclose(data.measurements.xy, mem.measurements.xy, atol=5e-6)
    np.testing.assert_allclose(data.measurements.sigma, mem.measurements.sigma, rtol=1e-5)
    rep = data.interior
    assert rep["input_unit"] == "pixel" and rep["fiducial_source"].endswith("fiducials.csv")
    assert [im["fiducials"]["redundancy"] for im in rep["images"]] == [10, 10]
    for im in rep["images"]:
        f = im["fiducials"]
        assert set(f["fiducials"]) == set("12345678")
        assert f["io_check"]["passed"] is True and f["max_px"] < 1.0
        # the residual statistics are those of the per-fiducial residuals
        v = np.array([[r["vx_um"], r["vy_um"]] for r in f["fiducials"].values()])
        assert f["rms_um"] == pytest.approx(np.sqrt(np.mean(v**2)))
        assert f["max_px"] == pytest.approx(np.max(np.hypot(*v.T)) / 12.0)
    json.dumps(rep)  # JSON-ready


@pytest.mark.io
def test_summary_carries_the_interior_orientation(scan_project, tmp_path, capsys):
    from vectoradjust.cli.commands import main

    assert main(["adjust", str(scan_project / "project.toml"), "--out", str(tmp_path / "o"),
                 "--vectors", "OSM", "-q"]) == 0
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    io = s["interior_orientation"]
    assert io["corrections"]["applied"][-1] == "earth_curvature"
    assert io["io_check"]["passed"] is True


@pytest.mark.io
def test_camera_file_by_path_with_inline_override(broken):
    _edit(broken / "project.toml", 'path = "lens.toml"',
          'path = "lens.toml"\nprincipal_point = [0.0, 0.0]')
    data = _load(broken)
    assert data.camera.calibration.principal_point == (0.0, 0.0)
    assert data.camera.calibration.distortion_model == "smac"  # the rest from the file
    assert "principal_point" not in data.interior["corrections"]["max_um"] or \
        data.interior["corrections"]["max_um"]["principal_point"] == 0.0


@pytest.mark.io
def test_pixel_sigma_from_the_project_file(broken):
    # drop the CSV's sigma columns: [measurements] sigma (pixels) applies
    p = broken / "image_points.csv"
    rows = [",".join(r.split(",")[:4]) for r in p.read_text().splitlines()]
    p.write_text("\n".join(rows) + "\n")
    _edit(broken / "project.toml", "sigma = 0.333333", "sigma = 1.5")
    data = _load(broken)
    np.testing.assert_allclose(data.measurements.sigma, 1.5 * 0.012, rtol=2e-3)
    assert data.interior["sigma"]["input_max"] == 1.5


def _drop_lines(path: Path, keep) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0]] + [r for r in lines[1:] if keep(r)]) + "\n")


@pytest.mark.io
def test_fewer_than_three_fiducials(broken):
    _drop_lines(broken / "fiducials.csv", lambda r: not (r.startswith("L,") and
                                                         r.split(",")[1] not in ("1", "2")))
    with pytest.raises(CameraError, match=r"fiducials.csv: image 'L': only 2 fiducial\(s\)"):
        _load(broken)


@pytest.mark.io
def test_fiducial_ids_not_in_the_calibration(broken):
    _edit(broken / "fiducials.csv", "R,3,", "R,9,")
    with pytest.raises(CameraError, match=r"image 'R': measured fiducial id\(s\) '9' are not "
                                          "in the calibration"):
        _load(broken)


@pytest.mark.io
def test_pixels_without_fiducials_or_pixel_size(broken):
    _edit(broken / "project.toml", 'fiducials = "fiducials.csv"', "")
    with pytest.raises(CameraError, match="image 'L': image coordinates are in pixels but there "
                                          "are no fiducial measurements.*no image_size"):
        _load(broken)
    _edit(broken / "lens.toml", "pixel_size = 0.012", "")
    with pytest.raises(CameraError, match="no pixel_size and no image_size"):
        _load(broken)


@pytest.mark.io
def test_unknown_distortion_model(broken):
    _edit(broken / "lens.toml", 'model = "smac"', 'model = "kannala"')
    with pytest.raises(CameraError, match="lens.toml.*unknown distortion model 'kannala'.*'smac'"):
        _load(broken)


@pytest.mark.io
def test_measured_fiducials_but_none_calibrated(broken):
    text = (broken / "lens.toml").read_text()
    start, end = text.index("[fiducials]"), text.index("[distortion]")
    (broken / "lens.toml").write_text(text[:start] + text[end:])
    with pytest.raises(CameraError, match="camera has no calibrated fiducials"):
        _load(broken)


@pytest.mark.io
def test_fiducial_file_errors(broken):
    _edit(broken / "fiducials.csv", "R,3,", "Q,3,")
    with pytest.raises(MeasurementError, match="fiducials.csv, line .*image 'Q' is not defined"):
        _load(broken)
    _edit(broken / "fiducials.csv", "Q,3,", "R,2,")
    with pytest.raises(CSVError, match="fiducial '2' is measured on image 'R' more than once"):
        _load(broken)


@pytest.mark.io
def test_project_key_errors(broken):
    _edit(broken / "project.toml", 'unit = "pixel"', 'unit = "inch"')
    with pytest.raises(ProjectError, match=r"\[measurements\]: unit = 'inch' is not known"):
        _load(broken)
    _edit(broken / "project.toml", 'unit = "inch"', 'unit = "px"\nfiducial = "x.csv"')
    with pytest.raises(ProjectError,
                       match=r"\[measurements\]: unknown key .fiducial. \(did you mean .fiducials"):
        _load(broken)
    _edit(broken / "project.toml", 'fiducial = "x.csv"', "")
    _edit(broken / "project.toml", "refraction = true", "refraction = 1")
    with pytest.raises(ProjectError, match=r"\[corrections\]: refraction must be true or false"):
        _load(broken)
    _edit(broken / "project.toml", "refraction = 1", "refraction = true\nterrain_height = 5000.0")
    with pytest.raises(CameraError, match="image 'L': flying height ZL = .* is not above the "
                                          "terrain height 5000.0 m"):
        _load(broken)


@pytest.mark.io
def test_sample_project_camera_file_and_corrections(sample_dir):
    pytest.importorskip("geopandas")
    pytest.importorskip("rasterio")
    from vectoradjust.files.readers import load_project_data

    if not (sample_dir / "rc10.toml").is_file():
        pytest.skip("sample without camera file")
    data = load_project_data(sample_dir / "project.toml")
    cal = data.camera.calibration
    assert cal.source.endswith("rc10.toml") and cal.focal_length == 152.4
    assert len(cal.fiducials) == 8 and cal.distortion_model == "smac"
    rep = data.interior
    assert rep["corrections"]["applied"] == ["principal_point", "distortion", "refraction",
                                             "earth_curvature"]
    sizes = rep["corrections"]["max_um"]
    # independent orders of magnitude: |principal point|, ARDC at ~800 m, r^3 H'/(2 R f^2)
    assert sizes["principal_point"] == pytest.approx(np.hypot(0.006, 0.004) * 1000.0)
    assert 1.0 < sizes["refraction"] < 4.0 and 5.0 < sizes["earth_curvature"] < 9.0
    assert 2.0 < sizes["distortion"] < 6.0
