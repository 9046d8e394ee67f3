"""Measurement on the images (issue 15) against independent truth.

Geometry: the ray of a predicted pixel returns to the object point; the propagated
pixel covariance agrees with a Monte Carlo of the orientation and database errors;
the search windows hold the true position. Matching: NCC + LSM recover a known affine
shift with changed radiometry; on a rendered stereo pair (real texture, lens distortion,
different gain/offset/gamma and noise) transferred points land on the true pixels
(which follow from the true orientation, not from the matcher). Roads: junction
crossings on the rendered pair against the true road intersections.
"""

from __future__ import annotations

import numpy as np
import pytest
from measure_pair import rendered_pair

from vectoradjust.files.measuring import PointSet, measure_roads, predict, transfer
from vectoradjust.measure.geometry import (
    WINDOW_K,
    ImageGeometry,
    inside_window,
    pixel_covariance,
)
from vectoradjust.measure.matching import FLAGS, lsm, ncc_search, sample
from vectoradjust.measure.roads import measurable, vertex_arms
from vectoradjust.measure.transfer import MatchSettings
from vectoradjust.simulate.measure_scene import ArrayImage
from vectoradjust.simulate.render import camera


def _geom(seed=0, sigma=(0.5, 0.05)):
    rng = np.random.default_rng(seed)
    cam = camera(1000, pixel_size=0.06, focal_length=50.0)
    eo = np.r_[500000.0, 4400000.0, 500.0, np.radians(rng.normal(0, 1.0, 3))]
    sig = np.r_[np.full(3, sigma[0]), np.radians(np.full(3, sigma[1]))]
    return ImageGeometry("L", eo, cam, {"distortion": True}, None, None, sig)


def _ground(n, seed=1):
    rng = np.random.default_rng(seed)
    xy = np.c_[500000.0 + rng.uniform(-150, 150, n), 4400000.0 + rng.uniform(-150, 150, n)]
    return np.c_[xy, 200.0 + rng.uniform(-10, 10, n)]


def test_ray_of_predicted_pixel_returns_to_the_point():
    g = _geom()
    xyz = _ground(200)
    px = g.to_pixel(xyz)
    back = g.to_ground(px, lambda xy: np.interp(np.arange(len(xy)), np.arange(len(xy)),
                                                 xyz[:, 2]) if len(xy) == len(xyz)
                       else np.full(len(xy), 200.0))
    assert np.max(np.abs(back - xyz)) < 1e-4


def test_pixel_covariance_matches_monte_carlo():
    g = _geom()
    xyz = _ground(5)
    sig_xyz = np.array([2.0, 1.0, 3.0])
    cov = pixel_covariance(g, xyz, np.broadcast_to(sig_xyz, (5, 3)))
    rng = np.random.default_rng(7)
    draws = []
    for _ in range(3000):
        ge = ImageGeometry("L", g.eo + rng.normal(0, 1, 6) * g.sigma_eo, g.camera,
                           g.corrections)
        draws.append(ge.to_pixel(xyz + rng.normal(0, 1, (5, 3)) * sig_xyz))
    d = np.array(draws)
    emp = np.einsum("kni,knj->nij", d - d.mean(0), d - d.mean(0)) / (len(d) - 1)
    rel = np.abs(np.sqrt(np.diagonal(emp, axis1=1, axis2=2)) /
                 np.sqrt(np.diagonal(cov, axis1=1, axis2=2)) - 1)
    assert rel.max() < 0.06


def test_prediction_windows_hold_the_truth():
    """>= 99 % of true positions inside the windows (predicted 99.9 %)."""
    true = _geom(seed=3, sigma=(1.0, 0.05))
    xyz_true = _ground(300, seed=4)
    sig_db = np.array([3.0, 3.0, 2.0])
    rng = np.random.default_rng(11)
    inside = []
    for _ in range(40):
        approx = ImageGeometry("L", true.eo + rng.normal(0, 1, 6) * true.sigma_eo,
                               true.camera, true.corrections, None, None, true.sigma_eo)
        db = xyz_true + rng.normal(0, 1, xyz_true.shape) * sig_db
        pts = PointSet(np.arange(300).astype(str), db, np.broadcast_to(sig_db, (300, 3)),
                       np.full(300, "shape"))
        tab = predict({"L": approx}, pts)
        idx = tab["point_id"].astype(int)
        cov = pixel_covariance(approx, db[idx], pts.sigma[idx])
        d = true.to_pixel(xyz_true[idx]) - np.c_[tab["col"], tab["row"]]
        inside.append(inside_window(cov, d, WINDOW_K))
    rate = np.concatenate(inside).mean()
    assert rate >= 0.99


def test_ncc_and_lsm_recover_a_known_affine_patch():
    rng = np.random.default_rng(2)
    from scipy.ndimage import gaussian_filter

    n = 50
    chips = gaussian_filter(rng.normal(size=(n, 90, 90)), (0, 1.6, 1.6)) * 40 + 100
    true = rng.uniform(40, 50, (n, 2))
    a = np.eye(2) + rng.normal(0, 0.03, (n, 2, 2))
    off = np.arange(-10, 11.0)
    vv, uu = np.meshgrid(off, off, indexing="ij")
    cols = true[:, 0, None, None] + a[:, 0, 0, None, None] * uu + a[:, 0, 1, None, None] * vv
    rows = true[:, 1, None, None] + a[:, 1, 0, None, None] * uu + a[:, 1, 1, None, None] * vv
    templ = 0.7 * sample(chips, cols, rows) + 12.0
    nc = ncc_search(templ, chips)
    assert np.median(np.hypot(*(nc.pos - true).T)) < 1.0
    res = lsm(templ, chips, nc.pos)
    assert res.converged.all()
    assert np.abs(res.pos - true).max() < 0.01
    assert np.abs(res.affine - a).max() < 1e-3
    assert np.allclose(res.radiometry[:, 1], 0.7, atol=1e-3)


@pytest.fixture(scope="module")
def pair():
    return rendered_pair(1)


def _overlap_points(pair, n=300, seed=5):
    rng = np.random.default_rng(seed)
    xy = np.c_[rng.uniform(500160, 500340, n), rng.uniform(4399600, 4399900, n)]
    xyz = np.c_[xy, pair.scene.height(xy)]
    pl, pr = pair.true["L"].to_pixel(xyz), pair.true["R"].to_pixel(xyz)
    ok = (np.minimum(pl.min(1), pr.min(1)) > 40) & (np.maximum(pl.max(1), pr.max(1)) < 960)
    return pl[ok], pr[ok]


def test_transfer_on_a_rendered_pair(pair):
    pl, pr = _overlap_points(pair)
    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    meas = {"point_id": np.arange(len(pl)).astype(str), "image_id": np.full(len(pl), "L"),
            "col": pl[:, 0], "row": pl[:, 1]}
    out = transfer(pair.approx, readers, meas, pair.scene.height, sigma_height=2.0)
    err = np.hypot(out["col"] - pr[:, 0], out["row"] - pr[:, 1])
    acc = out["accepted"]
    assert acc.mean() > 0.6
    assert (err[acc] < 0.3).mean() >= 0.95
    assert err[acc].max() < 1.0
    # flagged matches carry a reason
    assert all(out["flag_text"][~acc] != "")


def test_transfer_reports_progress_and_honours_cancel(pair):
    from vectoradjust.errors import CancelledError

    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    meas = {"point_id": np.array(["a"]), "image_id": np.array(["L"]),
            "col": np.array([500.0]), "row": np.array([500.0])}
    seen = []
    transfer(pair.approx, readers, meas, pair.scene.height,
             progress=lambda f, m: seen.append(f))
    assert seen and seen[-1] == 1.0
    with pytest.raises(CancelledError, match="measurement was cancelled"):
        transfer(pair.approx, readers, meas, pair.scene.height, is_cancelled=lambda: True)


def test_flat_template_is_flagged_not_accepted(pair):
    flat = np.full((1000, 1000), 120.0)
    readers = {"L": ArrayImage(flat), "R": ArrayImage(pair.images["R"])}
    meas = {"point_id": np.array(["a"]), "image_id": np.array(["L"]),
            "col": np.array([500.0]), "row": np.array([500.0])}
    out = transfer(pair.approx, readers, meas, pair.scene.height)
    assert not out["accepted"][0]
    assert out["flags"][0] & FLAGS["no_texture"]


def test_low_threshold_matters(pair):
    """A stricter correlation threshold accepts fewer matches (the flag is live)."""
    pl, _ = _overlap_points(pair, 120, seed=9)
    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    meas = {"point_id": np.arange(len(pl)).astype(str), "image_id": np.full(len(pl), "L"),
            "col": pl[:, 0], "row": pl[:, 1]}
    # distinct_factor = 1: min_ncc alone (a distinct peak is otherwise accepted down to
    # 1 - 2 (1 - min_ncc), which the clear rendered peaks pass)
    lo = transfer(pair.approx, readers, meas, pair.scene.height,
                  MatchSettings(min_ncc=0.5, distinct_factor=1.0))
    hi = transfer(pair.approx, readers, meas, pair.scene.height,
                  MatchSettings(min_ncc=0.97, distinct_factor=1.0))
    assert hi["accepted"].sum() < lo["accepted"].sum()


def test_road_junctions_on_a_rendered_pair(pair):
    j = pair.junctions
    n = len(j)
    rng = np.random.default_rng(2)
    db = j + np.c_[rng.normal(0, 1.0, (n, 2)), np.zeros(n)]
    arms = db[:, None, :] + np.array([[0, 40, 0], [40, 0, 0], [0, -40, 0], [-40, 0, 0.0]])
    pts = PointSet(np.arange(n).astype(str), db, np.ones((n, 3)), np.full(n, "shape"), arms,
                   np.full(n, 4))
    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    out = measure_roads(pair.true, readers, pts)
    truth = np.concatenate([pair.true[i].to_pixel(j)[out["point_id"][out["image_id"] == i]
                                                     .astype(int)] for i in ("L", "R")])
    order = np.argsort(out["image_id"], kind="stable")
    err = np.hypot(*(np.c_[out["col"], out["row"]][order] - truth).T)
    acc = out["accepted"][order]
    assert acc.mean() >= 0.8
    assert err[acc].max() < 1.5
    assert np.median(err[acc]) < 0.6


def test_vertex_arms_and_measurable():
    # a cross (two features through one vertex), a dead end and a corner
    coords = np.array([[0, -10, 0], [0, 0, 0], [0, 10, 0],      # feature 0 (N-S)
                       [-10, 0, 0], [0, 0, 0], [10, 0, 0],      # feature 1 (E-W)
                       [50, 0, 0], [60, 0, 0], [60, 10, 0.0]])  # feature 2 (corner at 60,0)
    feat = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2])
    part = np.zeros(9, int)
    obj = np.array([0, 1, 2, 3, 1, 4, 5, 6, 7])
    arms, deg = vertex_arms(coords, feat, part, obj, 8)
    assert deg.tolist() == [1, 4, 1, 1, 1, 1, 2, 1]
    xyz = coords[[0, 1, 2, 3, 5, 6, 7, 8]]
    assert measurable(xyz, arms, deg).tolist() == [False, True, False, False, False, False,
                                                    True, False]


def test_window_axes_and_batched_solve_against_numpy():
    from vectoradjust.measure.geometry import inv2, window_axes
    from vectoradjust.measure.matching import batched_solve

    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 2, 3))
    c = a @ np.swapaxes(a, 1, 2)
    w = window_axes(c, 2.0)
    ev, vec = np.linalg.eigh(c)
    assert np.allclose(w[:, 0], 2.0 * np.sqrt(ev[:, 1]))
    assert np.allclose(w[:, 1], 2.0 * np.sqrt(ev[:, 0]))
    u = np.c_[np.cos(np.radians(w[:, 2])), np.sin(np.radians(w[:, 2]))]
    assert np.allclose(np.abs(np.einsum("ni,ni->n", u, vec[:, :, 1])), 1.0)
    assert np.allclose(inv2(c) @ c, np.eye(2))
    m = rng.normal(size=(40, 9, 20))
    m = m @ np.swapaxes(m, 1, 2)
    b = rng.normal(size=(40, 9))
    x = batched_solve(m, b)
    assert np.allclose(np.einsum("nij,nj->ni", m, x), b)
    m[3] = 0.0
    assert np.isnan(batched_solve(m, b)[3]).all()


def test_scanned_film_geometry_through_the_fiducial_affine():
    """Pixels of a scan with a known (rotated, sheared) pixel -> mm affine."""
    from vectoradjust.sensor.camera import CameraCalibration
    from vectoradjust.sensor.collinearity import project
    from vectoradjust.sensor.refine import fit_fiducial_affine

    fid = {"1": (-106.0, -106.0), "2": (106.0, 106.0), "3": (-106.0, 106.0),
           "4": (106.0, -106.0)}
    cal = CameraCalibration(focal_length=152.4, fiducials=fid, pixel_size=0.02)
    a = np.array([[0.0201, 0.0004], [0.0003, -0.0199]])   # pixel -> mm (row axis down)
    t = np.array([-115.0, 114.0])
    ainv = np.linalg.inv(a)
    measured = {k: tuple(ainv @ (np.array(v) - t)) for k, v in fid.items()}
    fit = fit_fiducial_affine(measured, cal, unit="pixel", image_id="L")
    eo = np.r_[1000.0, 2000.0, 800.0, 0.01, -0.02, 0.3]
    g = ImageGeometry("L", eo, cal, {"distortion": False}, None, fit)
    xyz = np.c_[np.random.default_rng(0).uniform(800, 1200, (20, 2)) + [0, 1000],
                np.full(20, 200.0)]
    px = g.to_pixel(xyz)
    mm = project(eo, xyz, 152.4)
    assert np.allclose(px @ a.T + t, mm, atol=1e-9)
    assert np.allclose(g.pixel_to_measured_mm(px), mm, atol=1e-9)


def test_transfer_without_any_height_is_a_clear_error(pair):
    from vectoradjust.errors import MeasurementError

    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    meas = {"point_id": np.array(["a"]), "image_id": np.array(["L"]),
            "col": np.array([500.0]), "row": np.array([500.0])}
    with pytest.raises(MeasurementError, match="terrain height"):
        transfer(pair.approx, readers, meas, None)
    meas["image_id"] = np.array(["X"])
    with pytest.raises(MeasurementError, match="'X' is not in"):
        transfer(pair.approx, readers, meas, 200.0)


def test_rough_orientation_clips_the_window_and_flags_it(pair):
    rough = {k: ImageGeometry(k, g.eo, g.camera, g.corrections, None, None,
                              np.r_[np.full(3, 20.0), np.radians(np.full(3, 2.0))])
             for k, g in pair.approx.items()}
    pl, _ = _overlap_points(pair, 20, seed=4)
    readers = {k: ArrayImage(v) for k, v in pair.images.items()}
    meas = {"point_id": np.arange(len(pl)).astype(str), "image_id": np.full(len(pl), "L"),
            "col": pl[:, 0], "row": pl[:, 1]}
    out = transfer(rough, readers, meas, pair.scene.height)
    assert np.all(out["flags"] & FLAGS["window_clipped"])
    assert not out["accepted"].any()


def test_lsm_gather_of_stacked_layers_equals_separate_sampling():
    """The LSM samples grey values and gradients in one gather of a stacked array
    (issue 28, speed): the values are those of ``sample_many`` per layer, bit for bit,
    NaN outside the chips."""
    from vectoradjust.measure.matching import _gather, sample_many

    rng = np.random.default_rng(3)
    a, b, c = (rng.normal(size=(4, 9, 11)) for _ in range(3))
    cols = rng.uniform(-1.0, 11.0, size=(4, 50))
    rows = rng.uniform(-1.0, 9.0, size=(4, 50))
    batch = np.arange(4)[:, None]
    want = sample_many([a, b, c], batch, cols, rows)
    got = _gather(np.stack([a, b, c], axis=-1), batch, cols, rows)
    outside = (cols < 0) | (rows < 0) | (cols > 10) | (rows > 8)
    assert outside.any() and (~outside).any()
    for w, g in zip(want, got):
        assert np.array_equal(np.isnan(g), outside)
        assert np.array_equal(w[~outside], g[~outside])
