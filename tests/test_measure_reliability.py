"""Measurement that holds on real images (issue 28): texture checks, honest LSM precision,
the anisotropy check and back-matching, search windows from the joint covariance of the
orientation, the decoded image cache, and the pixel convention end to end."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from vectoradjust.measure.geometry import ImageGeometry, pixel_covariance, window_axes
from vectoradjust.measure.matching import FLAGS, texture_measures
from vectoradjust.measure.transfer import MatchSettings, match_batch
from vectoradjust.sensor.camera import CameraCalibration

#: every check of issue 28 off: the matching as it was before
OLD = MatchSettings(max_anisotropy=np.inf, min_grey_levels=0, min_entropy=0.0,
                    max_blockiness=np.inf, min_roundness=0.0, grey_step=0.0, min_sigma=0.0,
                    back_tolerance=np.inf, max_ray_misfit=np.inf)


def _match(img: np.ndarray, shift=(0.0, 0.0), st: MatchSettings | None = None,
           at=(100.0, 100.0), target: np.ndarray | None = None):
    """Match the point ``at`` of ``img`` on ``target`` (default the same image) with a
    prediction ``shift`` px off (a 6 px search window)."""
    ref = np.asarray(at, float)[None]
    chips = img[None].astype(float)
    tgt = chips if target is None else target[None].astype(float)
    zero = np.zeros((1, 2))
    cov = np.eye(2)[None] * (6.0 / 3.7169) ** 2
    return match_batch(chips, zero, ref, tgt, zero, ref + np.asarray(shift)[None],
                       np.eye(2)[None], cov, st or MatchSettings())


def _texture(n=200, seed=0, blur=1.5):
    rng = np.random.default_rng(seed)
    return 128 + 60 * gaussian_filter(rng.normal(size=(n, n)), blur) / 0.2


def _jpeg_blocks(n=200, seed=0):
    """8 x 8 blocks, each one of two grey values (a flat, heavily compressed JPEG)."""
    rng = np.random.default_rng(seed)
    b = rng.integers(0, 2, size=(n // 8, n // 8)) * 6.0 + 120.0
    return np.kron(b, np.ones((8, 8)))


def test_flat_two_grey_jpeg_block_is_rejected():
    img = _jpeg_blocks()
    tex = texture_measures(img[None], np.zeros((1, 2)), np.array([[100.0, 100.0]]), 20)
    assert tex["levels"][0] == 2 and tex["blockiness"][0] > 2.0
    old = _match(img, (2.0, -1.0), OLD)
    new = _match(img, (2.0, -1.0))
    assert old.ncc[0] > 0.98  # correlates perfectly: accepted before
    assert new.flags[0] & FLAGS["no_texture"] and not new.accepted[0]
    assert not np.any(new.sigma[0] < 0.01)  # never 0 (NaN where LSM failed)


def test_blockiness_alone_rejects_jpeg_blocks_with_many_levels():
    # many grey levels and a high entropy, but flat inside each 8 x 8 block
    rng = np.random.default_rng(3)
    img = np.kron(rng.uniform(60, 200, size=(25, 25)).round(), np.ones((8, 8)))
    tex = texture_measures(img[None], np.zeros((1, 2)), np.array([[100.0, 100.0]]), 20)
    assert tex["levels"][0] >= 20 and tex["entropy"][0] > 3.0
    assert tex["blockiness"][0] > 10.0
    assert _match(img, (1.0, 1.0)).flags[0] & FLAGS["no_texture"]
    # the same blocks shifted off the 8 x 8 grid are texture (no JPEG structure)
    tex4 = texture_measures(img[None], np.full((1, 2), 4.0), np.array([[104.0, 104.0]]), 20)
    assert tex4["blockiness"][0] < 1.0


def test_straight_edge_is_rejected():
    rng = np.random.default_rng(1)
    x = np.arange(200.0)
    clean = 128 + 50 * np.tanh((x - 100.0) / 3.0)[None, :] * np.ones((200, 1))
    img = clean + rng.normal(0, 1.0, clean.shape)  # a straight edge with noise
    tgt = clean + rng.normal(0, 1.0, clean.shape)  # the other image's own noise
    tex = texture_measures(img[None], np.zeros((1, 2)), np.array([[100.0, 100.0]]), 20)
    assert tex["roundness"][0] < 0.1
    res = _match(img, (0.0, 2.5), target=tgt)  # the prediction 2.5 px off along the edge
    assert res.flags[0] & FLAGS["no_texture"] and not res.accepted[0]
    # before (where the NCC ridge's noise leaves one peak): accepted, slid about 3 px
    # along the edge with a sigma below 0.07 px
    import dataclasses

    old = _match(img, (0.0, 2.5), dataclasses.replace(OLD, ambiguity=-1.0), target=tgt)
    assert old.accepted[0] and abs(old.px[0, 1] - 100.0) > 1.0


def test_good_texture_still_passes_with_an_honest_sigma():
    img = _texture()
    tex = texture_measures(img[None], np.zeros((1, 2)), np.array([[100.0, 100.0]]), 20)
    assert tex["roundness"][0] > 0.5 and tex["entropy"][0] > 3.5
    assert 0.5 < tex["blockiness"][0] < 1.5
    res = _match(img, (1.7, -2.2))
    assert res.accepted[0], res.flags
    assert np.hypot(*(res.px[0] - 100.0)) < 0.05
    # identical patches fit without residuals: the sigma is the floor, not 0
    assert np.all(res.sigma[0] >= 0.01) and np.all(res.sigma[0] < 0.07)
    assert np.all(_match(img, (1.7, -2.2), OLD).sigma[0] < 1e-3)  # before: nearly 0


def _vertical_geometry(cov_eo=None, sigma=None):
    cam = CameraCalibration(focal_length=100.0, pixel_size=(0.01, 0.01),
                            image_size=(2000, 2000))
    eo = np.r_[1000.0, 2000.0, 1500.0, 0.001, -0.002, 0.3]
    return ImageGeometry("A", eo, cam, sigma_eo=np.zeros(6) if sigma is None else sigma,
                         cov_eo=cov_eo)


def test_correlated_position_and_attitude_shrink_the_window():
    from vectoradjust.sensor.collinearity import partials

    s = np.r_[0.5, 0.5, 0.2, np.radians([0.02, 0.02, 0.01])]
    indep = _vertical_geometry(sigma=s)
    xyz = np.array([[1000.0, 2000.0, 0.0], [1040.0, 1980.0, 10.0]])
    a_eo = partials(np.broadcast_to(indep.eo, (1, 6)), xyz[:1], 100.0)[0][0]
    corr = np.eye(6)
    # X with phi, Y with omega: 99.9 % correlated, with the sign that cancels on the image
    for p, q in ((0, 4), (1, 3)):
        sign = -np.sign(a_eo[0, p] * a_eo[0, q] + a_eo[1, p] * a_eo[1, q])
        corr[p, q] = corr[q, p] = 0.999 * sign
    joint = _vertical_geometry(cov_eo=corr * np.outer(s, s))
    assert np.allclose(joint.sigma_eo, s)
    zero = np.zeros((2, 3))
    w_ind = window_axes(pixel_covariance(indep, xyz, zero))[:, 0]
    w_joint = window_axes(pixel_covariance(joint, xyz, zero))[:, 0]
    assert np.all(w_joint < 0.3 * w_ind), (w_joint, w_ind)
    # Monte Carlo: the joint covariance is the scatter of the projected points
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal(joint.eo, joint.cov_eo, size=4000)
    px = np.array([ImageGeometry("A", e, joint.camera).to_pixel(xyz[:1])[0] for e in draws])
    mc = np.cov(px.T)
    pc = pixel_covariance(joint, xyz[:1], zero[:1])[0]
    assert np.allclose(np.sqrt(np.diag(mc)), np.sqrt(np.diag(pc)), rtol=0.1)


def test_point_and_orientation_cross_covariance_enters():
    g = _vertical_geometry(sigma=np.r_[0.5, 0.5, 0.2, 0.0, 0.0, 0.0])
    xyz = np.array([[1000.0, 2000.0, 0.0]])
    cpt = np.diag([0.25, 0.25, 0.04])[None]
    cross = np.zeros((1, 6, 3))
    cross[0, :3, :] = np.diag([0.25, 0.25, 0.04])  # the point moves with the camera
    alone = pixel_covariance(g, xyz, cpt)
    joint = pixel_covariance(g, xyz, cpt, cross)
    assert np.trace(joint[0]) < 1e-6 * np.trace(alone[0])


# ------------------------------------------------------------------------ image cache
def _write(path, a, **kw):
    import rasterio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", width=a.shape[2], height=a.shape[1], count=a.shape[0],
                           dtype="uint8", **kw) as ds:
            ds.write(a)


@pytest.mark.io  # writes a JPEG and a GeoTIFF through rasterio
def test_a_jpeg_is_decoded_once_into_the_cache(tmp_path):
    from vectoradjust.files.images import RasterioImage

    rgb = np.clip(np.stack([_texture(300, s) for s in (1, 2, 3)]), 0, 255).astype(np.uint8)
    _write(tmp_path / "a.jpg", rgb, driver="JPEG", QUALITY=40)
    _write(tmp_path / "t.tif", rgb, driver="GTiff", tiled=True, blockxsize=64,
           blockysize=64)
    jpg = RasterioImage(tmp_path / "a.jpg", "a")
    direct = RasterioImage(tmp_path / "a.jpg", "a", cache=False)
    tif = RasterioImage(tmp_path / "t.tif", "t")
    assert jpg.cached and not direct.cached and not tif.cached
    for c0, r0, w, h in ((10, 20, 41, 41), (-5, 280, 30, 30), (290, -3, 20, 9)):
        a, b = jpg.read(c0, r0, w, h), direct.read(c0, r0, w, h)
        assert np.array_equal(np.isnan(a), np.isnan(b))
        assert np.nanmax(np.abs(a - b)) < 1e-4
    assert jpg._cache is not None
    t0 = time.perf_counter()
    for k in range(200):
        jpg.read(k, k, 81, 81)
    assert (time.perf_counter() - t0) / 200 < 0.01  # a window: a slice, not a decoding
    for r in (jpg, direct, tif):
        r.close()
    assert jpg._cache is None and jpg._cache_file is None


# ------------------------------------------------------------------- pixel convention
def _rendered(origin: str, rotate: bool):
    """An image of an analytic ground texture seen by a vertical camera (array element
    ``[r, c]`` sampled at its pixel centre in ``origin``'s convention) and, rotated 180
    degrees in the array, the same with kappa + pi."""
    from vectoradjust.measure.ties import ArrayReader

    cam = CameraCalibration(focal_length=50.0, pixel_size=(0.01, 0.01),
                            image_size=(160, 120), pixel_origin=origin)
    sig = np.r_[0.05, 0.05, 0.05, 1e-5, 1e-5, 1e-5]
    eo = np.r_[0.0, 0.0, 500.0, 0.0, 0.0, 0.2]
    g = ImageGeometry("A", eo, cam, sigma_eo=sig)
    rr, cc = np.mgrid[0:120, 0:160].astype(float)
    px = np.column_stack([cc.ravel(), rr.ravel()]) + g.index_offset
    xyz = g.to_ground(px, 0.0)  # rendered through A; B is its array turned 180 degrees
    if rotate:
        g = ImageGeometry("B", eo + np.r_[0, 0, 0, 0, 0, np.pi], cam, sigma_eo=sig)
    x, y = xyz[:, 0], xyz[:, 1]
    v = (100 + 40 * np.sin(x / 1.3 + 0.4) * np.cos(y / 1.7) + 30 * np.sin(0.7 * x - 0.9 * y)
         + 20 * np.cos(x / 0.9 + y / 2.1) + 15 * np.sin(3.1 * x + 2.3 * y)
         + 12 * np.cos(4.7 * x - 1.9 * y))
    a = v.reshape(120, 160)
    return g, ArrayReader(np.rot90(a, 2) if rotate else a)


@pytest.mark.parametrize("origin", ["center", "corner"])
def test_pixel_convention_on_an_image_rotated_180_degrees(origin):
    from vectoradjust.files.measuring import transfer

    ga, ra = _rendered(origin, False)
    gb, rb = _rendered(origin, True)
    assert ga.index_offset == (0.5 if origin == "corner" else 0.0)
    pts = np.array([[50.0, 40.0], [80.3, 60.7], [110.0, 75.5], [65.5, 50.0]])
    measured = {"point_id": np.array(["p1", "p2", "p3", "p4"]), "image_id": np.full(4, "A"),
                "col": pts[:, 0], "row": pts[:, 1]}
    st = MatchSettings(half_template=10, max_radius=8.0)
    res = transfer({"A": ga, "B": gb}, {"A": ra, "B": rb}, measured, 0.0, st,
                   sigma_height=0.1)
    pred = np.column_stack([res["pred_col"], res["pred_row"]])
    got = np.column_stack([res["col"], res["row"]])
    # the rotated image's pixel of a point is the mirrored one: predicted exactly
    size = np.array([160.0, 120.0])
    mirror = (size - 1.0 if origin == "center" else size) - pts
    assert np.allclose(pred, mirror, atol=1e-3)
    assert res["accepted"].all(), res["flag_text"]
    assert np.abs(got - pred).max() < 0.05, got - pred


# ------------------------------------------------------------- multi-image consistency
def _view(name: str, x0: float, roll: int = 0):
    """A vertical image from ``x0`` m east of the others' (kappa 0: the base along the
    columns) of the analytic ground texture; ``roll`` shifts its content by columns."""
    from vectoradjust.measure.ties import ArrayReader

    cam = CameraCalibration(focal_length=50.0, pixel_size=(0.01, 0.01),
                            image_size=(200, 120))
    g = ImageGeometry(name, np.r_[x0, 0.0, 500.0, 0.0, 0.0, 0.0], cam,
                      sigma_eo=np.r_[0.02, 0.02, 0.02, 1e-6, 1e-6, 1e-6])
    rr, cc = np.mgrid[0:120, 0:200].astype(float)
    xyz = g.to_ground(np.column_stack([cc.ravel(), rr.ravel()]), 0.0)
    x, y = xyz[:, 0], xyz[:, 1]
    v = (100 + 40 * np.sin(x / 1.3 + 0.4) * np.cos(y / 1.7) + 30 * np.sin(0.7 * x - 0.9 * y)
         + 20 * np.cos(x / 0.9 + y / 2.1) + 15 * np.sin(3.1 * x + 2.3 * y)
         + 12 * np.cos(4.7 * x - 1.9 * y))
    return g, ArrayReader(np.roll(v.reshape(120, 200), roll, axis=1))


def test_a_match_off_its_epipolar_place_is_inconsistent_on_three_images():
    from vectoradjust.files.measuring import transfer

    pts = np.array([[100.0, 60.0], [90.5, 50.0], [110.0, 70.5]])
    measured = {"point_id": np.array(["p1", "p2", "p3"]), "image_id": np.full(3, "A"),
                "col": pts[:, 0], "row": pts[:, 1]}
    st = MatchSettings(half_template=10, max_radius=20.0)
    out = {}
    for roll in (0, 3):  # C's content 3 px along the base: a wrong height's place
        views = dict(A=_view("A", 0.0), B=_view("B", 20.0), C=_view("C", -20.0, roll))
        geoms = {k: v[0] for k, v in views.items()}
        readers = {k: v[1] for k, v in views.items()}
        # 20 m of height uncertainty: the windows reach 3 px along the epipolar lines
        out[roll] = transfer(geoms, readers, measured, 0.0, st, sigma_height=20.0)
        unchecked = transfer(geoms, readers, measured, 0.0,
                             MatchSettings(half_template=10, max_radius=20.0,
                                           max_ray_misfit=np.inf), sigma_height=20.0)
        assert unchecked["accepted"].all(), unchecked["flag_text"]
    assert out[0]["accepted"].all(), out[0]["flag_text"]
    on_c = out[3]["image_id"] == "C"
    assert np.all(out[3]["flags"][on_c] & FLAGS["inconsistent"])
    assert not out[3]["accepted"][on_c].any()


def test_summary_correlation_gives_the_joint_orientation_covariance():
    from vectoradjust.errors import MeasurementError
    from vectoradjust.files.measuring import _eo_covariance

    sig = np.r_[0.5, 0.5, 0.2, 1e-4, 1e-4, 5e-5]
    entry = {"id": "A", "correlation": {"parameters": ["X", "phi"],
                                        "matrix": [[1.0, -0.999], [-0.999, 1.0]]}}
    c = _eo_covariance(entry, sig)
    assert np.allclose(np.sqrt(np.diag(c)), sig)
    assert np.isclose(c[0, 4], -0.999 * sig[0] * sig[4]) and c[0, 3] == 0.0
    assert _eo_covariance({"id": "A"}, sig) is None
    with pytest.raises(MeasurementError, match="correlation names bias_a0"):
        _eo_covariance({"id": "A", "correlation": {"parameters": ["bias_a0"],
                                                   "matrix": [[1.0]]}}, sig)


def test_adjusted_summary_carries_each_frame_images_joint_orientation_covariance():
    """summary.json -> measure: the windows get the adjustment's own joint EO covariance."""
    from vectoradjust.accuracy.summary import run_summary
    from vectoradjust.files.measuring import _eo_covariance
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    out = run(make_scenario(0, n_images=3, sigma_image=0.003).to_project_data())
    images = {str(e["id"]): e for e in run_summary(out)["images"]}
    for j, iid in enumerate(out.image_ids):
        e = images[str(iid)]
        sig = np.r_[e["sigma_position"], np.radians(e["sigma_attitude"])]
        c = _eo_covariance(e, sig)
        np.testing.assert_allclose(c, out.result.eo_cov[j], rtol=1e-6,
                                   atol=1e-8 * np.abs(out.result.eo_cov[j]).max())
        corr = np.asarray(e["correlation"]["matrix"])
        assert np.abs(corr - np.eye(6)).max() > 0.05  # the correlations are really there


def test_a_transfer_rejected_for_precision_is_retried_with_a_larger_template():
    """``retry_template`` (issue 28, JPEG precision): 9 x 9 templates give an LSM sigma
    above ``max_sigma`` (``poor_precision``); with ``retry_template`` 3 those transfers
    are matched again with 25 x 25 templates, and the rows are exactly those of a run
    with ``half_template`` 12 (position, sigma, texture), accepted."""
    from vectoradjust.files.measuring import transfer

    pts = np.array([[100.0, 60.0], [90.5, 50.0], [110.0, 70.5], [70.0, 40.0]])
    measured = {"point_id": np.array(["p1", "p2", "p3", "p4"]), "image_id": np.full(4, "A"),
                "col": pts[:, 0], "row": pts[:, 1]}
    views = dict(A=_view("A", 0.0), B=_view("B", 2.0))
    geoms = {k: v[0] for k, v in views.items()}
    readers = {k: v[1] for k, v in views.items()}
    out = {}
    for h, retry in ((4, 1.0), (12, 1.0), (4, 3.0)):
        st = MatchSettings(half_template=h, retry_template=retry, max_radius=10.0,
                           min_grey_levels=0, min_entropy=0.0, max_sigma=0.02)
        out[h, retry] = transfer(geoms, readers, measured, 0.0, st, sigma_height=2.0)
    assert all(f == FLAGS["poor_precision"] for f in out[4, 1.0]["flags"])
    assert out[12, 1.0]["accepted"].all() and out[4, 3.0]["accepted"].all()
    for key in ("col", "row", "sigma_col", "sigma_row", "entropy", "back_error"):
        assert np.array_equal(out[4, 3.0][key], out[12, 1.0][key]), key
