"""Accuracy control of adjustment runs (qa_run, cli_qa): simulated blocks with planted errors.

The truth is what was planted: a GCP surveyed 1 m off, an image coordinate moved by a
known amount, a fiducial measured 30 micrometres off. Vertical parallax is checked
against a computation from the bundle's image residuals (a different path to the
same quantity), triplet discrepancies against the parallax equation and the
simulation's true points.
"""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from vectoradjust.errors import ProjectError
from vectoradjust.model import Camera
from vectoradjust.pipeline import run
from vectoradjust.qa.tolerances import QASpec
from vectoradjust.qa.verdict import (
    accuracy_control,
    control_qa_field,
    html_section,
    observation_pairs,
    pair_parallax,
    resolve_pixel_size,
    spec_from_table,
    triplet_discrepancies,
    working_radius_mm,
)
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.simulate import make_scenario

MAP_2000 = QASpec("topographic map", map_scale=2000, contour_interval=1.0)
PIXEL = 0.012  # mm
_ZONES = ("tie-point zones", "triplet zones")  # coverage stages (tests/test_qa_zones.py)


def _central_gcp(sc) -> int:
    """Index of the control point nearest the centroid of the control points."""
    ctrl = np.flatnonzero(sc.control.role == "control")
    xy = sc.control.xyz[ctrl, :2]
    return int(ctrl[np.argmin(np.hypot(*(xy - xy.mean(axis=0)).T))])


@pytest.fixture(scope="module")
def block_sc():
    # 3 images (one triplet), image coordinates to 3 micrometres
    return make_scenario(0, n_images=3, sigma_image=0.003)


@pytest.fixture(scope="module")
def clean_run(block_sc):
    return run(block_sc.to_project_data())


@pytest.fixture(scope="module")
def shifted(block_sc):
    j = _central_gcp(block_sc)
    data = block_sc.to_project_data()
    data.control.xyz[j, 0] += 1.0  # the surveyed coordinates are 1 m off
    return j, run(data)


# ------------------------------------------------------------------- the block
def test_clean_block_fails_no_control_point(clean_run):
    rep = accuracy_control(clean_run, MAP_2000)
    block = [s for s in rep.stages if s.name.startswith("block:")]
    assert {s.name for s in block} == {"block: GCP XY", "block: GCP Z", "block: check XY",
                                       "block: check Z"}
    assert all(s.status == "pass" for s in block)
    used = clean_run.control_points["Used"] == 1
    field = control_qa_field(clean_run, MAP_2000)
    assert set(field[used]) == {"pass"} and set(field[~used]) <= {""}
    # the simulated block has few tie points: only the zone coverage (qa/zones.py) fails
    assert [n for n in rep.nonconformities if not n["stage"].startswith(_ZONES)] == []
    assert rep.remeasure == []


def test_gcp_shifted_by_1m_fails_exactly_that_gcp(shifted, block_sc):
    j, r = shifted
    gid = str(block_sc.control.point_id[j])
    rep = accuracy_control(r, MAP_2000)
    assert not rep.passed
    assert rep.remeasure == [gid]
    points = [n for n in rep.nonconformities if not n["stage"].startswith(_ZONES)]
    assert [n["stage"] for n in points] == ["block: GCP XY"]
    assert points[0]["ids"] == [gid]
    failed = [s.name for s in rep.stages if s.status == "fail"]
    assert rep.stages[len(failed) - 1].status == "fail"  # non-conformities come first
    gcp_xy = next(s for s in rep.stages if s.name == "block: GCP XY")
    assert gcp_xy.status == "fail"
    # the tolerance from the formula: 0.2 mm at 1:2000 (mean), twice that for one point
    assert gcp_xy.tolerance == pytest.approx(0.2e-3 * 2000)
    assert gcp_xy.point_tolerance == pytest.approx(0.8)
    field = control_qa_field(r, MAP_2000)
    cp = r.control_points
    assert list(cp["point_id"][field == "fail"]) == [gid]
    # the strict reading (a point against the mean tolerance, 0.4 m) flags it too
    strict = accuracy_control(r, MAP_2000, point_rule="mean")
    assert gid in strict.remeasure


def test_block_stage_values_are_the_control_point_residuals(shifted):
    _, r = shifted
    rep = accuracy_control(r, MAP_2000)
    cp = r.control_points
    used = cp["Used"] == 1
    stages = {s.name: s for s in rep.stages}
    for role, label in (("control", "GCP"), ("check", "check")):
        m = used & (cp["role"] == role)
        exy = np.hypot(cp["Vx"][m], cp["Vy"][m])
        ez = np.abs(cp["Vz"][m])
        assert stages[f"block: {label} XY"].measured == pytest.approx(exy.mean())
        assert stages[f"block: {label} Z"].measured == pytest.approx(ez.mean())
        assert [row["id"] for row in stages[f"block: {label} XY"].rows] == list(cp["point_id"][m])
    # check point tolerances for 1 m contours: 0.3 mm x M and 0.2 h
    assert stages["block: check XY"].tolerance == pytest.approx(0.6)
    assert stages["block: check Z"].tolerance == pytest.approx(0.2)
    assert stages["block: GCP Z"].tolerance == pytest.approx(0.15)


def test_orthophoto_heights_use_dh_dtm_over_3(clean_run):
    spec = QASpec("orthophoto", orthophoto_scale=10000)
    rep = accuracy_control(clean_run, spec)
    prob = clean_run.problem
    r_mm = np.hypot(*(prob.obs_xy - prob.principal_point).T).max()
    assert working_radius_mm(clean_run) == pytest.approx(r_mm)
    dh = 0.3e-3 * 10000 * 152.4 / r_mm
    assert rep.tolerances["orthophoto"]["dh_dtm_m"] == pytest.approx(dh)
    stages = {s.name: s for s in rep.stages}
    assert stages["block: GCP Z"].tolerance == pytest.approx(dh / 3)
    assert stages["block: check Z"].tolerance == pytest.approx(dh / 3)
    # XY at the orthophoto scale: 0.2 / 0.3 mm
    assert stages["block: GCP XY"].tolerance == pytest.approx(2.0)
    assert stages["block: check XY"].tolerance == pytest.approx(3.0)
    # the scenario has a DEM: its heights are checked against dh_DTM (tests/test_dtm_qa.py)
    assert stages["DTM heights"].tolerance == pytest.approx(dh)
    # an explicit working radius wins
    rep2 = accuracy_control(clean_run, spec, working_radius=134.0)
    assert rep2.tolerances["orthophoto"]["dh_dtm_m"] == pytest.approx(0.3e-3 * 1e4 * 152.4 / 134)


# ------------------------------------------------------- relative orientation
def test_observation_pairs_brute_force():
    rng = np.random.default_rng(5)
    op = rng.integers(0, 30, 200)
    oi = rng.integers(0, 6, 200)
    a, b = observation_pairs(op, oi)
    got = sorted(zip(a.tolist(), b.tolist()))
    want = sorted((i, j) if oi[i] < oi[j] else (j, i)
                  for i, j in itertools.combinations(range(200), 2)
                  if op[i] == op[j] and oi[i] != oi[j])
    assert got == want


@pytest.fixture(scope="module")
def noisy_run():
    # the simulator's default 15 micrometres, 3 images
    return run(make_scenario(2, n_images=3).to_project_data())


def test_vertical_parallax_agrees_with_the_image_residuals(noisy_run):
    """py from observed coordinates and adjusted EO = -(v_y,left - v_y,right) to first order.

    The adjusted projections of a point intersect exactly, so the observed parallax is
    what the residuals took away; for near-vertical photos with the base along x the
    epipolar y is the photo y.
    """
    r = noisy_run
    prob = r.problem
    v = r.result.v_image
    pairs, skipped = pair_parallax(r)
    assert [(d["left"], d["right"]) for d in pairs] == [("I01", "I02"), ("I02", "I03")]
    assert skipped == []
    rep = accuracy_control(r, MAP_2000, pixel_size=PIXEL)
    stats = {(p["left"], p["right"]): p for p in rep.stereo_pairs}
    for d in pairs:
        il, ir = r.image_ids.index(d["left"]), r.image_ids.index(d["right"])
        pl = prob.obs_point[prob.obs_image == il]
        pr = prob.obs_point[prob.obs_image == ir]
        common = np.intersect1d(pl, pr)
        assert sorted(d["point_ids"]) == sorted(r.point_ids[common])
        vy = np.full((prob.n_points, 2), np.nan)
        vy[prob.obs_point[prob.obs_image == il], 0] = v[prob.obs_image == il, 1]
        vy[prob.obs_point[prob.obs_image == ir], 1] = v[prob.obs_image == ir, 1]
        idx = {p: k for k, p in enumerate(r.point_ids)}
        k = np.array([idx[p] for p in d["point_ids"]])
        py_res = -(vy[k, 0] - vy[k, 1])
        assert np.abs(d["py_mm"] - py_res).max() < 0.002  # mm; sigma of py ~ 0.021 mm
        a = np.abs(py_res)
        s = stats[(d["left"], d["right"])]
        assert s["n"] == len(k)
        assert s["mean_um"] == pytest.approx(a.mean() * 1e3, rel=0.01)
        assert s["rms_um"] == pytest.approx(np.sqrt(np.mean(a**2)) * 1e3, rel=0.01)
        assert s["max_um"] == pytest.approx(a.max() * 1e3, rel=0.05)
        assert s["mean_px"] == pytest.approx(s["mean_um"] / 1e3 / PIXEL)
        # noise of 15 um on each image: py ~ N(0, sqrt(2) 15 um) less what the adjustment took
        assert 0.6 * math.sqrt(2) * 15 < s["rms_um"] < 1.1 * math.sqrt(2) * 15


def test_planted_y_error_on_the_middle_image_fails_that_point_in_both_pairs():
    sc = make_scenario(0, n_images=3, sigma_image=0.002)
    data = sc.to_project_data()
    meas = data.measurements
    pid = "T01"
    on = set(meas.image_id[meas.point_id == pid])
    assert on == {"I01", "I02", "I03"}
    data.measurements.xy[(meas.point_id == pid) & (meas.image_id == "I02"), 1] += 0.030
    r = run(data)
    rep = accuracy_control(r, MAP_2000, pixel_size=PIXEL)
    ro = [s for s in rep.stages if s.name.startswith("relative orientation")]
    assert len(ro) == 4
    for s in ro:
        assert s.failed_ids == [pid], s.name
    pairs, _ = pair_parallax(r)
    for d in pairs:
        py = d["py_mm"][list(d["point_ids"]).index(pid)]
        # the adjustment hardly moves the EO for one ray: the parallax is the planted 30 um
        assert abs(abs(py) - 0.030) < 0.006
    assert pid in rep.remeasure


def test_unknown_pixel_size_reports_parallax_but_does_not_judge_it(noisy_run):
    rep = accuracy_control(noisy_run, MAP_2000)
    assert rep.pixel_size is None
    ro = [s for s in rep.stages if s.name.startswith("relative orientation")]
    assert ro and all(s.status == "n/a" for s in ro)
    assert all(np.isfinite(s.measured) and s.unit == "um" for s in ro)
    assert all(p["mean_um"] is not None and p["mean_px"] is None for p in rep.stereo_pairs)
    assert any("pixel size unknown" in n for n in rep.notes)
    assert set(rep.as_dict()["not_evaluated"]) >= {s.name for s in ro}


# ------------------------------------------------------------------- triplets
@pytest.fixture(scope="module")
def quiet_sc():
    # nearly error-free image coordinates (0.2 micrometres)
    return make_scenario(0, n_images=3, sigma_image=0.0002)


def test_triplet_discrepancies_vanish_on_a_clean_block(quiet_sc):
    r = run(quiet_sc.to_project_data())
    trips, skipped = triplet_discrepancies(r)
    assert len(trips) == 1 and skipped == []
    t = trips[0]
    assert t["images"] == ["I01", "I02", "I03"]
    # the points on all three images
    prob = r.problem
    on = np.zeros((prob.n_points, 3), bool)
    on[prob.obs_point, prob.obs_image] = True
    assert sorted(t["point_ids"]) == sorted(r.point_ids[on.all(axis=1)])
    # both models give the true tie points (datum: GCPs surveyed to 5 cm)
    truth = dict(zip(quiet_sc.tie_ids, quiet_sc.tie_true))
    tie = [k for k, p in enumerate(t["point_ids"]) if p in truth]
    assert len(tie) >= 3
    true_xyz = np.array([truth[t["point_ids"][k]] for k in tie])
    assert np.abs(t["xyz_12"][tie] - true_xyz).max() < 0.1
    assert np.abs(t["xyz_23"][tie] - true_xyz).max() < 0.1
    # photo scale ~1:4000, base 184 m -> ~46 mm
    assert np.mean(t["scale"]) == pytest.approx(4000, rel=0.02)
    assert t["base_mm"] == pytest.approx(184 / 4000 * 1e3, rel=0.05)
    # discrepancies far below the tolerances (8.5 um, 27 um for 12 um pixels)
    assert t["e_xy_mm"].max() < 0.003 and t["e_z_mm"].max() < 0.006
    rep = accuracy_control(r, MAP_2000, pixel_size=PIXEL)
    tr = [s for s in rep.stages if s.name.startswith("triplet I")]
    assert [s.status for s in tr] == ["pass", "pass"]
    txy = math.sqrt(2) * 0.5 * PIXEL * 1e3
    assert tr[0].tolerance == pytest.approx(txy)
    assert tr[1].tolerance == pytest.approx(152.4 / t["base_mm"] * txy)


def test_triplet_detects_a_planted_parallax_error(quiet_sc):
    data = quiet_sc.to_project_data()
    meas = data.measurements
    dx = 0.030  # mm, x (parallax direction) on the last image: model (2, 3) only
    data.measurements.xy[(meas.point_id == "T01") & (meas.image_id == "I03"), 0] += dx
    r = run(data)
    t = triplet_discrepancies(r)[0][0]
    j = list(t["point_ids"]).index("T01")
    # parallax equation: a parallax error dp moves the height by (f / b) dp (image scale)
    assert t["e_z_mm"][j] == pytest.approx(152.4 / t["base_mm"] * dx, rel=0.1)
    assert np.delete(t["e_z_mm"], j).max() < 0.01
    rep = accuracy_control(r, MAP_2000, pixel_size=PIXEL)
    tr = {s.name: s for s in rep.stages if s.name.startswith("triplet")}
    assert tr["triplet I01-I02-I03: E_z"].failed_ids == ["T01"]
    assert "T01" in rep.remeasure


def test_two_images_have_no_triplet(noisy_run):
    sc2 = make_scenario(2, n_images=2)
    r = run(sc2.to_project_data())
    assert triplet_discrepancies(r) == ([], [])
    rep = accuracy_control(r, MAP_2000, pixel_size=PIXEL)
    st = [s for s in rep.stages if s.name == "triplets"]
    assert len(st) == 1 and st[0].status == "n/a"


# -------------------------------------------------------- interior orientation
def test_interior_orientation_stage_names_the_bad_fiducial(block_sc):
    from vectoradjust.sensor.interior import FiducialMeasurements, refine_measurements

    cal_fid = {"1": (-106.0, -106.0), "2": (106.0, 106.0), "3": (-106.0, 106.0),
               "4": (106.0, -106.0), "5": (0.0, 110.0), "6": (0.0, -110.0),
               "7": (110.0, 0.0), "8": (-110.0, 0.0)}
    cal = CameraCalibration(152.4, fiducials=cal_fid, pixel_size=PIXEL)
    rows = [(im.id, k, v) for im in block_sc.images for k, v in cal_fid.items()]
    xy = np.array([v for _, _, v in rows], float)
    bad = next(i for i, (im, k, _) in enumerate(rows) if im == "I01" and k == "3")
    xy[bad, 0] += 0.030
    fm = FiducialMeasurements([r[0] for r in rows], [r[1] for r in rows], xy)
    res = refine_measurements(block_sc.measurements, block_sc.images, cal, {}, unit="mm",
                              fiducials=fm)
    data = block_sc.to_project_data()
    data.interior = res.report
    r = run(data)
    rep = accuracy_control(r, MAP_2000)  # pixel size from the fiducial fits
    assert rep.pixel_size == pytest.approx(PIXEL)
    io = {s.name: s for s in rep.stages if s.name.startswith("interior")}
    assert set(io) == {f"interior orientation {i}: max fiducial residual"
                       for i in ("I01", "I02", "I03")}
    s = io["interior orientation I01: max fiducial residual"]
    assert s.status == "fail" and s.failed_ids == ["I01:3"]
    # independent: the largest residual of our own least-squares affine fit, in pixels
    calib = np.array([cal_fid[k] for k in cal_fid])
    meas = xy[[i for i, (im, _, _) in enumerate(rows) if im == "I01"]]
    a = np.column_stack([np.ones(len(meas)), meas])
    coef, *_ = np.linalg.lstsq(a, calib, rcond=None)
    resid = a @ coef - calib
    assert s.measured == pytest.approx(np.hypot(*resid.T).max() / PIXEL, rel=1e-6)
    assert io["interior orientation I02: max fiducial residual"].status == "pass"
    assert "I01:3" in rep.remeasure


# ----------------------------------------------------------------- the spec
def test_spec_from_table_and_overrides():
    t = {"product": "topographic map", "map_scale": 2000, "contour_interval": 1.0}
    assert spec_from_table(t).map_scale == 2000
    s = spec_from_table(t, product="orthophoto", scale="1:10000")
    assert s.product == "orthophoto" and s.product_scale == 10000
    s = spec_from_table(None, product="topographic-map", scale=5000, contour_interval=2.5,
                        pixel_size=0.014)
    assert (s.map_scale, s.contour_interval, s.pixel_size) == (5000, 2.5, 0.014)
    with pytest.raises(ProjectError,
                       match=r"no product specification.*give --product and --scale") as err:
        spec_from_table(None, source="p.toml")
    assert "[qa]" in str(err.value) and "--product" in str(err.value)
    with pytest.raises(ProjectError,
                       match=r"\[qa\] contour_interval is missing.*add map_scale") as err:
        spec_from_table({"product": "topographic map", "map_scale": 2000}, source="p.toml")
    assert "contour_interval" in str(err.value) and "p.toml" in str(err.value)
    with pytest.raises(ProjectError,
                       match=r"pixel_size = 12\.0 mm is implausibly large.* is 0\.012"):
        spec_from_table({"product": "orthophoto", "orthophoto_scale": 2000, "pixel_size": 12})


def test_pixel_size_sources():
    spec = QASpec("orthophoto", orthophoto_scale=2000, pixel_size=0.02)
    cam = Camera(152.4, calibration=CameraCalibration(152.4, pixel_size=(0.009, 0.016)))
    assert resolve_pixel_size(cam, spec, 0.005) == (0.005, "--pixel-size / argument")
    assert resolve_pixel_size(cam, spec) == (0.02, "[qa] pixel_size")
    spec0 = QASpec("orthophoto", orthophoto_scale=2000)
    p, src = resolve_pixel_size(cam, spec0)
    assert p == pytest.approx(0.012) and src == "camera calibration"
    assert resolve_pixel_size(Camera(152.4, calibration={"pixel_size": 0.007}), spec0)[0] == 0.007
    assert resolve_pixel_size(Camera(152.4), spec0) == (None, "unknown")


def test_report_is_json_and_html(shifted):
    _, r = shifted
    d = accuracy_control(r, MAP_2000).as_dict()
    text = json.dumps(d, allow_nan=False)
    keys = list(d)
    assert keys[:3] == ["verdict", "passed", "nonconformities"]
    assert keys.index("nonconformities") < keys.index("stages")
    assert json.loads(text)["verdict"] == "fail"
    h = html_section(d)
    assert "Verdict: FAIL" in h and d["remeasure"][0] in h


# ------------------------------------------------------------------ the CLI
@pytest.fixture(scope="module")
def written(tmp_path_factory):
    pytest.importorskip("geopandas")
    from vectoradjust.simulate import write_project

    sc = make_scenario(0, n_images=3, sigma_image=0.003)
    j = _central_gcp(sc)
    sc.control.xyz[j, 0] += 1.0
    d = tmp_path_factory.mktemp("qa_project")
    path = write_project(sc, d)
    return path, str(sc.control.point_id[j])


@pytest.mark.io
@pytest.mark.slow
def test_cli_writes_qa_json(written, tmp_path, capsys):
    from vectoradjust.cli.qa import main
    from vectoradjust.files.readers import load_project_data

    path, gid = written
    text = path.read_text()
    qa_path = path.parent / "with_qa.toml"
    qa_path.write_text(text + '\n[qa]\nproduct = "topographic map"\nmap_scale = 2000\n'
                       "contour_interval = 1.0\npixel_size = 0.012\n")
    assert load_project_data(qa_path).qa == {"product": "topographic map", "map_scale": 2000,
                                             "contour_interval": 1.0, "pixel_size": 0.012}
    assert main([str(qa_path), "--out", str(tmp_path / "out"), "-q"]) == 0
    out = capsys.readouterr().out
    assert "VERDICT: FAIL" in out and gid in out
    doc = json.loads((tmp_path / "out" / "qa.json").read_text())
    assert list(doc)[:3] == ["verdict", "passed", "nonconformities"]
    assert doc["verdict"] == "fail"
    gcp = next(n for n in doc["nonconformities"] if n["stage"] == "block: GCP XY")
    assert gcp["ids"] == [gid]
    assert doc["pixel_size_mm"] == 0.012 and doc["pixel_size_source"] == "[qa] pixel_size"
    assert len(doc["stereo_pairs"]) == 2 and len(doc["triplets"]) == 1
    qa = {c["id"]: c["qa"] for c in doc["control_points"]}
    assert [k for k, v in qa.items() if v == "fail"] == [gid]
    # the command line overrides [qa]
    assert main([str(qa_path), "--out", str(tmp_path / "ortho"), "-q", "--product", "orthophoto",
                 "--scale", "10000"]) == 0
    doc = json.loads((tmp_path / "ortho" / "qa.json").read_text())
    assert doc["specification"]["product"] == "orthophoto"
    assert doc["specification"]["orthophoto_scale"] == 10000
    assert doc["tolerances"]["block"]["gcp_xy"] == pytest.approx(2.0)


@pytest.mark.io
def test_cli_without_spec_is_a_clear_error(written, tmp_path, capsys):
    from vectoradjust.cli.qa import main

    path, _ = written
    assert main([str(path), "--out", str(tmp_path / "x"), "-q"]) == 1
    err = capsys.readouterr().err
    assert "[qa]" in err and "--product" in err
    assert not (tmp_path / "x" / "qa.json").exists()
