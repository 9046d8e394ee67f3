"""Measurement on satellite images with RPCs: prediction windows and transfer.

Geometry against independent code: :class:`RpcGeometry` projects as
:func:`vectoradjust.simulate.satellite.biased_project` (the bias written out separately)
and its inverse returns to the point; its pixel covariance agrees with a Monte Carlo of
the bias and the point errors; the a-priori bias sigmas (``bias_sigma``, ``ERR_BIAS`` in
pixels, the 10 px default). Prediction: the search windows of ``predict`` (read back from
the ellipse columns of the template) hold the true pixel with the stated probability
(the Mahalanobis distances follow chi-square with 2 degrees of freedom). Transfer: a
rendered RPC pair (every output pixel localized through its RPC and a true shift bias to
the terrain, which gives it the albedo there; GDAL's corner convention, so a pixel's
centre is at +0.5) and a frame image of the same ground: points measured on one image are
found on the others within 0.3 px of the truth. The real Pléiades pair (skipped when
absent): well-textured points of img_01 transferred to img_02 and back.
"""

from __future__ import annotations

import dataclasses
import warnings
from functools import cache
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from vectoradjust.files.measuring import (
    PointSet,
    image_geometries,
    image_points,
    measure_roads,
    predict,
    transfer,
)
from vectoradjust.measure.geometry import (
    WINDOW_K,
    ImageGeometry,
    RpcGeometry,
    height_parallax,
    pixel_covariance,
    rpc_bias_prior,
)
from vectoradjust.sensor.ground import EnuFrame
from vectoradjust.sensor.rpc import RpcModel
from vectoradjust.simulate.measure_scene import ArrayImage
from vectoradjust.simulate.render import camera, make_scene, render
from vectoradjust.simulate.satellite import biased_project

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rpc"
LON0, LAT0, H0 = -87.0, 40.4, 200.0
SIZE = 520
GSD = 0.5
#: true shift biases (a0, b0) of the rendered images (px)
TRUE_SHIFT = {"A": (1.7, -2.2), "B": (-2.6, 1.1)}


def synthetic_rpc(view: float, yaw: float, size: int = SIZE) -> RpcModel:
    """A rational RPC00B of a 0.5 m image: rotated by ``yaw``, ``view`` m of row per
    metre of height (along-track stereo), with quadratic terms and denominators != 1."""
    ls_lon, ls_lat, hs = 0.0025, 0.002, 100.0
    a_e = ls_lon * np.cos(np.radians(LAT0)) * 111320.0   # metres per unit L
    a_n = ls_lat * 110950.0                               # metres per unit P
    sc = size / 2.0
    samp = np.zeros(20)
    line = np.zeros(20)
    samp[1], samp[2] = a_e * np.cos(yaw) / (GSD * sc), a_n * np.sin(yaw) / (GSD * sc)
    line[1], line[2] = a_e * np.sin(yaw) / (GSD * sc), -a_n * np.cos(yaw) / (GSD * sc)
    line[3] = view * hs / (GSD * sc)
    samp[3] = 0.05 * view * hs / (GSD * sc)
    samp[7], samp[10], line[8], line[5] = 0.004, 0.002, -0.003, 0.002
    den_s = np.zeros(20)
    den_l = np.zeros(20)
    den_s[:4] = (1.0, 0.012, -0.006, 0.003)
    den_l[:4] = (1.0, -0.008, 0.01, -0.002)
    return RpcModel(line_off=sc, samp_off=sc, lat_off=LAT0, long_off=LON0, height_off=H0,
                    line_scale=sc, samp_scale=sc, lat_scale=ls_lat, long_scale=ls_lon,
                    height_scale=hs, line_num=line, line_den=den_l, samp_num=samp,
                    samp_den=den_s, source="<synthetic>")


def _ground_of_pixels(rpc, frame, scene, corner_px, shift, iterations=12):
    """Object points seen at GDAL pixels ``corner_px`` of an image with a shift bias: the
    RPC inverted (``RpcModel.localize``) at the terrain height, iterated."""
    raw = corner_px - 0.5 - np.asarray(shift, float)
    h = np.full(len(raw), H0)
    for _ in range(iterations):
        ll = rpc.localize(raw[:, 0], raw[:, 1], h, origin="center")
        xyz = frame.from_geodetic(np.column_stack([ll, h]))
        h = h + scene.height(xyz[:, :2]) - xyz[:, 2]
    return xyz


def render_rpc(scene, rpc, frame, shift, gain=1.0, offset=0.0, gamma=1.0, noise=0.0,
               seed=0, supersample=2, node=2):
    """Render an RPC image: the ground of every sub-pixel sample (pixel ``[r, c]`` spans
    ``c .. c + 1``, ``r .. r + 1`` in GDAL's coordinates) from the exact inverse on a node
    grid every ``node`` px, interpolated cubically (smooth terrain: error << 0.01 px)."""
    nodes = np.arange(-2 * node, SIZE + 2 * node + 1, node, dtype=float)
    nc, nr = np.meshgrid(nodes, nodes)
    g = _ground_of_pixels(rpc, frame, scene, np.c_[nc.ravel(), nr.ravel()], shift)
    sub = (np.arange(supersample) + 0.5) / supersample
    rr, cc = np.mgrid[0:SIZE, 0:SIZE]
    out = np.zeros((SIZE, SIZE))
    for su in sub:
        for sv in sub:
            ic, ir = (cc + su - nodes[0]) / node, (rr + sv - nodes[0]) / node
            xy = [map_coordinates(g[:, k].reshape(nc.shape), [ir, ic], order=3)
                  for k in (0, 1)]
            out += scene.value(np.c_[xy[0].ravel(), xy[1].ravel()]).reshape(SIZE, SIZE)
    out /= supersample**2
    rng = np.random.default_rng(seed)
    img = 255.0 * (gain * np.clip(out, 0, 1) ** gamma + offset) + rng.normal(0, noise,
                                                                            out.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def true_pixel(rpc, frame, xyz, shift):
    """GDAL pixels of object points on an image with a shift bias (independent code)."""
    llh, _ = frame.to_geodetic(np.asarray(xyz, float).reshape(-1, 3))
    return biased_project(rpc, [shift[0], 0, 0, shift[1], 0, 0], llh[:, 0], llh[:, 1],
                          llh[:, 2])


def _enu():
    return EnuFrame(LON0, LAT0, 0.0)


def _utm():
    pytest.importorskip("pyproj")
    from vectoradjust.files.rpc import crs_frame

    return crs_frame("EPSG:32616", "ellipsoidal", near=(LON0, LAT0))


@cache
def rendered_rpc_scene():
    """Two RPC images and a frame image of one textured, hilly ground (UTM 16N)."""
    frame = _utm()
    e0, n0, _ = frame.from_geodetic(np.array([[LON0, LAT0, H0]]))[0]
    c = np.array([e0, n0])
    roads = [np.array([[c[0] + x + 2.0, c[1] - 190], [c[0] + x - 2.0, c[1] + 190]])
             for x in (-45.0, 40.0)]
    roads += [np.array([[c[0] - 190, c[1] + y - 1.5], [c[0] + 190, c[1] + y + 1.5]])
              for y in (-35.0, 50.0)]
    scene = make_scene(400.0, 0.25, 3, "hopper", roads, (e0 - 200.0, n0 + 200.0))
    scene = dataclasses.replace(scene, relief=20.0)
    rpcs = {"A": synthetic_rpc(0.3, 0.03), "B": synthetic_rpc(-0.3, -0.05)}
    radiometry = {"A": (1.0, 0.0, 1.0, 2.0), "B": (0.8, 0.1, 1.25, 3.0)}
    images = {k: render_rpc(scene, rpcs[k], frame, TRUE_SHIFT[k], *radiometry[k], seed=i)
              for i, k in enumerate(rpcs)}
    rng = np.random.default_rng(4)
    cam = camera(600, pixel_size=0.1, focal_length=50.0)
    eo = np.r_[e0 + 4.0, n0 - 3.0, H0 + 250.0, np.radians(rng.normal(0, 1.0, 3))]
    f_true = ImageGeometry("F", eo, cam)
    images["F"] = render(scene, f_true, 0.9, 0.05, 1.1, 2.5, 7, 2)
    return SimpleNamespace(frame=frame, scene=scene, rpcs=rpcs, images=images,
                           f_true=f_true, centre=c)


def _rpc_geoms(sc, sigma_shift=3.0):
    cov = np.diag([sigma_shift**2, 0, 0, sigma_shift**2, 0, 0])
    return {k: RpcGeometry(k, r, sc.frame, np.zeros(6), cov, (SIZE, SIZE))
            for k, r in sc.rpcs.items()}


def _frame_approx(sc, sig=(0.3, 0.01)):
    s = np.r_[np.full(3, sig[0]), np.radians(np.full(3, sig[1]))]
    eo = sc.f_true.eo + np.random.default_rng(8).normal(0, 1, 6) * s
    return ImageGeometry("F", eo, sc.f_true.camera, sigma_eo=s)


def _overlap(sc, n=260, seed=5, margin=45.0):
    """Ground points seen inside every image with a margin, and their true pixels."""
    rng = np.random.default_rng(seed)
    xy = sc.centre + rng.uniform(-95.0, 95.0, (n, 2))
    xyz = np.c_[xy, sc.scene.height(xy)]
    px = {k: true_pixel(r, sc.frame, xyz, TRUE_SHIFT[k]) for k, r in sc.rpcs.items()}
    px["F"] = sc.f_true.to_pixel(xyz) + 0.0  # frame pixels are array indices
    ok = np.ones(len(xyz), bool)
    for k, p in px.items():
        lim = SIZE if k != "F" else 600
        ok &= (p.min(axis=1) > margin) & (p.max(axis=1) < lim - margin)
    return xyz[ok], {k: p[ok] for k, p in px.items()}


# --------------------------------------------------------------------------- geometry
def test_rpc_geometry_projects_as_independent_code_and_inverts():
    fr = _enu()
    rpc = synthetic_rpc(0.3, 0.03)
    bias = np.array([1.5, -0.8, 0.6, -2.0, 0.4, 0.9])
    g = RpcGeometry("A", rpc, fr, bias)
    rng = np.random.default_rng(0)
    xyz = np.c_[rng.uniform(-120, 120, (200, 2)), rng.uniform(180, 220, 200)]
    llh, _ = fr.to_geodetic(xyz)
    want = biased_project(rpc, bias, llh[:, 0], llh[:, 1], llh[:, 2])
    px = g.to_pixel(xyz)
    assert np.abs(px - want).max() < 1e-9
    # the raw pixel removes the affine bias exactly (centre convention, no bias)
    raw = rpc.project(llh[:, 0], llh[:, 1], llh[:, 2], origin="center")
    assert np.abs(g.raw_pixel(px) - raw).max() < 1e-9
    # to the ground over a terrain and back; a point at a given height
    hfun = lambda xy: 200.0 + 15.0 * np.sin(xy[:, 0] / 60.0) * np.cos(xy[:, 1] / 80.0)  # noqa: E731
    xyz[:, 2] = hfun(xyz[:, :2])
    back = g.to_ground(g.to_pixel(xyz), hfun)
    assert np.abs(back - xyz).max() < 1e-3
    at = g.at_height(g.to_pixel(xyz), xyz[:, 2])
    assert np.abs(at - xyz).max() < 1e-6
    # measured pixels of an RPC image are written as they are (pixels)
    assert np.array_equal(g.pixel_to_measured_mm(px), px)
    assert RpcGeometry.index_offset == 0.5 and ImageGeometry.index_offset == 0.0


def test_rpc_pixel_covariance_matches_monte_carlo():
    fr = _enu()
    rpc = synthetic_rpc(-0.3, -0.05)
    cov_b = np.diag([4.0, 0.25, 0.16, 2.25, 0.09, 0.36])
    cov_b[0, 3] = cov_b[3, 0] = 1.2
    g = RpcGeometry("B", rpc, fr, np.zeros(6), cov_b)
    xyz = np.array([[10.0, -20.0, 205.0], [-90.0, 70.0, 190.0], [60.0, 95.0, 215.0]])
    sig = np.array([2.0, 1.0, 3.0])
    cov = pixel_covariance(g, xyz, np.broadcast_to(sig, (3, 3)))
    rng = np.random.default_rng(3)
    n = 4000
    draws = np.empty((n, 3, 2))
    chol = np.linalg.cholesky(cov_b)
    for i in range(n):
        gi = RpcGeometry("B", rpc, fr, chol @ rng.normal(size=6))
        draws[i] = gi.to_pixel(xyz + rng.normal(size=(3, 3)) * sig)
    d = draws - draws.mean(0)
    emp = np.einsum("kni,knj->nij", d, d) / (n - 1)
    sd_emp = np.sqrt(np.diagonal(emp, axis1=1, axis2=2))
    sd = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    assert np.abs(sd_emp / sd - 1).max() < 0.05
    corr = lambda c: c[:, 0, 1] / np.sqrt(c[:, 0, 0] * c[:, 1, 1])  # noqa: E731
    assert np.abs(corr(emp) - corr(cov)).max() < 0.05


def test_bias_prior_sigmas():
    fr = _enu()
    rpc = synthetic_rpc(0.3, 0.03)
    cov, src = rpc_bias_prior(rpc, fr, "shift")
    assert np.allclose(np.sqrt(np.diag(cov)), [10, 0, 0, 10, 0, 0]) and "default" in src
    cov, _ = rpc_bias_prior(rpc, fr, "affine", np.array([1.0, 0.2, 0.3, 1.5, np.inf, 0.4]))
    assert np.allclose(np.sqrt(np.diag(cov)), [1.0, 0.2, 0.3, 1.5, 2.0, 0.4])
    cov, src = rpc_bias_prior(rpc, fr, "none", np.full(6, 3.0))
    assert not cov.any() and "exact" in src
    # ERR_BIAS (m per horizontal axis) through the RPC's 0.5 m pixels: about 2 px / m
    cov, src = rpc_bias_prior(dataclasses.replace(rpc, err_bias=3.0), fr, "shift+drift")
    sd = np.sqrt(np.diag(cov))
    assert 5.6 < sd[0] < 6.4 and 5.6 < sd[3] < 6.4 and "ERR_BIAS" in src
    assert np.allclose(sd[[2, 5]], 2.0) and sd[1] == sd[4] == 0.0
    # GDAL's "unknown" (-1) falls back to the default
    cov, _ = rpc_bias_prior(dataclasses.replace(rpc, err_bias=-1.0), fr, "shift")
    assert np.isclose(cov[0, 0], 100.0)


def test_prediction_windows_hold_the_truth_with_the_stated_probability():
    """Road vertices (database sigma) on an RPC image whose bias is known only by its
    prior: the template's ellipses hold the true pixel 99.9 % of the time, and the
    Mahalanobis distances follow chi-square(2) (90 % inside the 90 % ellipse)."""
    fr = _enu()
    rpc = synthetic_rpc(0.3, 0.03)
    prior = np.diag([3.0**2, 0.5**2, 0.4**2, 2.0**2, 0.3**2, 0.6**2])
    g = RpcGeometry("A", rpc, fr, np.zeros(6), prior, (SIZE, SIZE))
    rng = np.random.default_rng(21)
    trials, per = 1500, 20
    n = trials * per
    xy = rng.uniform(-100, 100, (n, 2))
    xyz_true = np.c_[xy, 200.0 + 10.0 * np.sin(xy[:, 0] / 50.0)]
    sig_db = np.array([2.0, 2.0, 1.5])
    db = xyz_true + rng.normal(size=(n, 3)) * sig_db
    pts = PointSet(np.arange(n).astype(str), db, np.broadcast_to(sig_db, (n, 3)),
                   np.full(n, "shape"))
    tab = predict({"A": g}, pts)
    assert len(tab["col"]) == n and np.array_equal(tab["x"], tab["col"])
    bias = (np.linalg.cholesky(prior) @ rng.normal(size=(6, trials))).T
    truth = np.empty((n, 2))
    for t in range(trials):  # one true bias per trial, shared by its points
        s = slice(t * per, (t + 1) * per)
        truth[s] = RpcGeometry("A", rpc, fr, bias[t]).to_pixel(xyz_true[s])
    d = truth - np.c_[tab["col"], tab["row"]]
    ang = np.radians(tab["win_angle"])
    u = np.c_[np.cos(ang), np.sin(ang)]
    v = np.c_[-np.sin(ang), np.cos(ang)]
    m2 = ((np.sum(d * u, 1) / (tab["win_major"] / WINDOW_K)) ** 2
          + (np.sum(d * v, 1) / (tab["win_minor"] / WINDOW_K)) ** 2)
    inside = (m2 <= WINDOW_K**2).mean()
    in90 = (m2 <= 4.6052).mean()
    print(f"RPC windows: {inside:.4f} inside (stated 0.999), {in90:.4f} inside the 90 % "
          f"ellipse; median window {np.median(tab['win_major']):.1f} x "
          f"{np.median(tab['win_minor']):.1f} px")
    assert inside >= 0.995
    assert 0.88 <= in90 <= 0.92


def test_geometries_of_a_project_with_rpc_images():
    """``image_geometries``: prior sigmas before an adjustment, its bias and covariance
    after (a summary.json entry), and a clear error without the ground frame."""
    from vectoradjust.errors import MeasurementError
    from vectoradjust.model import ImageSpec
    from vectoradjust.sensor.models import RpcImage

    fr = _enu()
    rpc = synthetic_rpc(0.3, 0.03)
    im = ImageSpec("A", np.zeros(3), np.zeros(3), model="rpc",
                   rpc=RpcImage(rpc, "shift", np.full(6, 2.5), "A_rpc.txt"))
    spec = SimpleNamespace(corrections={}, camera=None, images=[im])
    g = image_geometries(spec, image_sizes={"A": (SIZE, SIZE)}, ground_frame=fr)["A"]
    assert isinstance(g, RpcGeometry) and g.image_size == (SIZE, SIZE)
    assert np.allclose(np.diag(g.bias_cov), [6.25, 0, 0, 6.25, 0, 0]) and not g.bias.any()
    summary = {"images": [{"id": "A", "model": "rpc", "bias": {"a0": 1.25, "b0": -0.5},
                           "sigma_bias": {"a0": 0.1, "b0": 0.2},
                           "correlation": {"parameters": ["a0", "b0"],
                                           "matrix": [[1.0, 0.5], [0.5, 1.0]]}}]}
    g = image_geometries(spec, summary, ground_frame=fr)["A"]
    assert np.allclose(g.bias, [1.25, 0, 0, -0.5, 0, 0])
    assert np.isclose(g.bias_cov[0, 0], 0.01) and np.isclose(g.bias_cov[0, 3], 0.01)
    with pytest.raises(MeasurementError, match="ground frame"):
        image_geometries(spec)


# --------------------------------------------------------------------------- transfer
@pytest.fixture(scope="module")
def scene():
    return rendered_rpc_scene()


def _errors(out, truth_px, ids):
    t = truth_px[ids]
    return np.hypot(out["col"] - t[:, 0], out["row"] - t[:, 1])


def test_rendered_rpc_pixels_follow_gdal_convention(scene):
    """A painted road's centre across the array rows lies on the RPC's corner-convention
    prediction: array element ``[i, j]`` is centred on ``(j + 0.5, i + 0.5)``."""
    a = scene.images["A"].astype(float)
    g = _rpc_geoms(scene)["A"]
    g.bias = np.r_[TRUE_SHIFT["A"][0], 0, 0, TRUE_SHIFT["A"][1], 0, 0]
    road = scene.scene.roads[0]  # north-south
    t = np.linspace(0.3, 0.7, 400)
    pts = road[0] + t[:, None] * (road[1] - road[0])
    p = g.to_pixel(np.c_[pts, scene.scene.height(pts)])
    p = p[np.argsort(p[:, 1])]
    off = []
    for i in range(int(p[0, 1]) + 2, int(p[-1, 1]) - 2, 7):  # array rows
        col = np.interp(i + 0.5, p[:, 1], p[:, 0])  # the road centre at the row's centre
        j = np.arange(int(col) - 16, int(col) + 17)
        prof = a[i, j] - np.median(a[i, j])
        w = np.where(prof > 0.5 * prof.max(), prof, 0.0)
        off.append(np.sum(w * (j + 0.5)) / np.sum(w) - col)
    off = np.array(off)
    print(f"road centre across the rows - prediction: median {np.median(off):.3f} px "
          f"({len(off)} rows)")
    assert len(off) >= 20
    assert abs(np.median(off)) < 0.15  # a half-pixel slip would be 0.5


@pytest.mark.slow
def test_transfer_between_rendered_rpc_images(scene):
    xyz, px = _overlap(scene)
    geoms = _rpc_geoms(scene)
    readers = {k: ArrayImage(scene.images[k]) for k in ("A", "B")}
    n = len(xyz)
    ids = np.arange(n)
    meas = {"point_id": ids.astype(str), "image_id": np.full(n, "A"),
            "col": px["A"][:, 0], "row": px["A"][:, 1]}
    out = transfer(geoms, readers, meas, scene.scene.height, sigma_height=2.0)
    err = _errors(out, px["B"], out["point_id"].astype(int))
    acc = out["accepted"]
    within = (err[acc] < 0.3).mean()
    print(f"RPC A -> B: {acc.sum()} of {len(acc)} accepted, {within:.3f} within 0.3 px, "
          f"worst {err[acc].max():.3f} px, median {np.median(err[acc]):.3f} px")
    assert acc.mean() >= 0.6
    assert within >= 0.95
    assert err[acc].max() < 1.0
    # prediction and window: the true pixel is inside (prediction without the bias)
    pred = np.c_[out["pred_col"], out["pred_row"]]
    assert np.abs(pred - px["B"][out["point_id"].astype(int)]).max() > 2.0
    # back: B -> A lands on the measured pixel
    back_in = {"point_id": out["point_id"][acc], "image_id": np.full(acc.sum(), "B"),
               "col": out["col"][acc], "row": out["row"][acc]}
    back = transfer(geoms, readers, back_in, scene.scene.height, sigma_height=2.0)
    e_back = _errors(back, px["A"], back["point_id"].astype(int))
    ok = back["accepted"]
    print(f"RPC B -> A back: {ok.sum()} of {len(ok)} accepted, "
          f"{(e_back[ok] < 0.5).mean():.3f} within 0.5 px")
    assert ok.mean() >= 0.9 and (e_back[ok] < 0.5).all()
    # image_points: RPC rows are pixels with pixel sigmas
    ip = image_points(geoms, meas, out)
    tr = ip["source"] == "transferred"
    assert np.array_equal(ip["x"][tr], ip["col"][tr])
    assert (ip["sigma_x"][tr] >= 0.3).all() and (ip["sigma_x"][tr] < 0.4).all()


@pytest.mark.slow
def test_transfer_between_rpc_and_frame_images(scene):
    """Through the sensor seam: RPC -> frame and frame -> RPC (the frame's pixels are
    array indices, the RPC's GDAL's: a half-pixel slip would fail)."""
    xyz, px = _overlap(scene, 300, seed=6)
    geoms = {**_rpc_geoms(scene), "F": _frame_approx(scene)}
    readers = {k: ArrayImage(v) for k, v in scene.images.items()}
    n = len(xyz)
    for src, dst in (("A", "F"), ("F", "B")):
        meas = {"point_id": np.arange(n).astype(str), "image_id": np.full(n, src),
                "col": px[src][:, 0], "row": px[src][:, 1]}
        out = transfer({src: geoms[src], dst: geoms[dst]},
                       {src: readers[src], dst: readers[dst]}, meas, scene.scene.height,
                       sigma_height=2.0)
        err = _errors(out, px[dst], out["point_id"].astype(int))
        acc = out["accepted"]
        within = (err[acc] < 0.3).mean()
        print(f"{src} -> {dst}: {acc.sum()} of {len(acc)} accepted, {within:.3f} within "
              f"0.3 px, worst {err[acc].max():.3f} px, median {np.median(err[acc]):.3f} px")
        assert acc.mean() >= 0.6
        assert within >= 0.95
        assert err[acc].max() < 1.0


def test_height_parallax_is_the_epipolar_direction(scene):
    """The window's height term: ``d px_B / dZ`` along A's line of sight, checked against
    two ground points on that line (independent inverse) projected into B."""
    geoms = _rpc_geoms(scene)
    xyz, px = _overlap(scene, 40, seed=9)
    e = height_parallax(geoms["A"], geoms["B"], px["A"], xyz)
    r = scene.rpcs
    lo = _ground_of_pixels(r["A"], scene.frame, SimpleNamespace(
        height=lambda xy: scene.scene.height(xy) - 1.0), px["A"], (0.0, 0.0))
    hi = _ground_of_pixels(r["A"], scene.frame, SimpleNamespace(
        height=lambda xy: scene.scene.height(xy) + 1.0), px["A"], (0.0, 0.0))
    d = true_pixel(r["B"], scene.frame, hi, (0, 0)) - true_pixel(r["B"], scene.frame, lo,
                                                                 (0, 0))
    dz = hi[:, 2] - lo[:, 2]
    assert np.abs(e - d / dz[:, None]).max() < 1e-3
    assert 1.1 < np.median(np.hypot(*e.T)) < 1.3  # 2 x 0.3 m per m over 0.5 m pixels


def _junctions(roads):
    """Crossings of the two north-south with the two east-west roads, ``(4, 2)``."""
    j = []
    for a in roads[:2]:
        for b in roads[2:]:
            p, r = a[0], a[1] - a[0]
            q, s = b[0], b[1] - b[0]
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / (r[0] * s[1] - r[1] * s[0])
            j.append(p + t * r)
    return np.array(j)


def test_road_junctions_on_rpc_images(scene):
    """Junctions located on the RPC images in GDAL pixels (chips read at index - 0.5)."""
    j = _junctions(scene.scene.roads)
    xyz = np.c_[j, scene.scene.height(j)]
    rng = np.random.default_rng(2)
    db = xyz + np.c_[rng.normal(0, 1.0, (len(j), 2)), np.zeros(len(j))]
    arms = db[:, None, :] + np.array([[0, 40, 0], [40, 0, 0], [0, -40, 0], [-40, 0, 0.0]])
    pts = PointSet(np.arange(len(j)).astype(str), db, np.ones((len(j), 3)),
                   np.full(len(j), "shape"), arms, np.full(len(j), 4))
    geoms = _rpc_geoms(scene)
    for k, g in geoms.items():
        g.bias = np.r_[TRUE_SHIFT[k][0], 0, 0, TRUE_SHIFT[k][1], 0, 0]
    readers = {k: ArrayImage(scene.images[k]) for k in ("A", "B")}
    out = measure_roads(geoms, readers, pts)
    errs = []
    for k in ("A", "B"):
        m = out["image_id"] == k
        t = true_pixel(scene.rpcs[k], scene.frame, xyz, TRUE_SHIFT[k])
        t = t[out["point_id"][m].astype(int)]
        errs.append(np.hypot(out["col"][m] - t[:, 0], out["row"][m] - t[:, 1])[
            out["accepted"][m]])
    err = np.concatenate(errs)
    print(f"RPC road junctions: {len(err)} of {len(out['accepted'])} located, median "
          f"{np.median(err):.2f} px, worst {err.max():.2f} px")
    assert len(err) >= 6
    assert np.median(err) < 0.45 and err.max() < 1.5


# --------------------------------------------------------------------------- real data
def _pleiades():
    folder = DATA / "pleiades_pair"
    need = [folder / f for f in ("img_01.tif", "img_02.tif", "dsm_s2p.tif")]
    missing = [str(p) for p in need if not p.is_file()]
    if missing:
        pytest.skip(f"real Pléiades pair not found: {', '.join(missing)}")
    pytest.importorskip("rasterio")
    return folder


def _filled_dsm(path):
    """The s2p DSM (holes filled with the nearest valid cell) as a height function, and
    the unfilled grid's heights (NaN in holes)."""
    from scipy.ndimage import distance_transform_edt

    from vectoradjust.adjust.dem import bilinear
    from vectoradjust.files.readers import read_dem

    grid, gt, nodata, _ = read_dem(path)
    bad = ~np.isfinite(grid) | ((grid == nodata) if nodata is not None else False)
    idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
    filled = grid[tuple(idx)]
    mean = float(filled.mean())

    def height(xy):  # outside the DSM: its mean height
        z = bilinear(filled, gt, np.asarray(xy, float).reshape(-1, 2))
        return np.where(np.isfinite(z), z, mean)

    def raw(xy):
        return bilinear(np.where(bad, np.nan, grid), gt, np.asarray(xy, float).reshape(-1, 2))
    return height, raw


def _textured_points(img, cell=60, lo=170, hi=830, window=15):
    """The pixel of largest Foerstner weight per grid cell (GDAL coordinates)."""
    from scipy.ndimage import sobel, uniform_filter

    gx, gy = sobel(img, 1), sobel(img, 0)
    sxx, syy, sxy = (uniform_filter(v, window) for v in (gx * gx, gy * gy, gx * gy))
    w = (sxx * syy - sxy**2) / (sxx + syy + 1e-9)
    pts = []
    for r0 in range(lo, hi, cell):
        for c0 in range(lo, hi, cell):
            blk = w[r0:r0 + cell, c0:c0 + cell]
            i = np.unravel_index(np.argmax(blk), blk.shape)
            pts.append((c0 + i[1] + 0.5, r0 + i[0] + 0.5))
    return np.array(pts)


@pytest.mark.io
def test_transfer_on_the_real_pleiades_pair():
    """Well-textured points of img_01 (where the s2p DSM has a height) found on img_02
    and back; bias_sigma = 2 px (the pair's relative pointing error is below a pixel)."""
    import time

    from vectoradjust.files.images import RasterioImage
    from vectoradjust.files.rpc import crs_frame, read_rpc

    folder = _pleiades()
    rpcs = {k: read_rpc(folder / f"img_0{k}.tif") for k in ("1", "2")}
    fr = crs_frame("EPSG:32740", "ellipsoidal", near=(rpcs["1"].long_off, rpcs["1"].lat_off))
    readers = {k: RasterioImage(folder / f"img_0{k}.tif", k) for k in rpcs}
    geoms = {}
    for k, r in rpcs.items():
        cov, src = rpc_bias_prior(r, fr, "shift", np.full(6, 2.0))
        geoms[k] = RpcGeometry(k, r, fr, np.zeros(6), cov, readers[k].size, None, src)
    height, raw_height = _filled_dsm(folder / "dsm_s2p.tif")
    pts = _textured_points(readers["1"].read(0, 0, *readers["1"].size))
    ground = geoms["1"].to_ground(pts, height)
    pts = pts[np.isfinite(raw_height(ground[:, :2]))]
    n = len(pts)
    meas = {"point_id": np.arange(n).astype(str), "image_id": np.full(n, "1"),
            "col": pts[:, 0], "row": pts[:, 1]}
    t0 = time.perf_counter()
    out = transfer(geoms, readers, meas, height, sigma_height=2.0)
    took = time.perf_counter() - t0
    acc = out["accepted"]
    d = np.c_[out["col"] - out["pred_col"], out["row"] - out["pred_row"]][acc]
    back_in = {"point_id": out["point_id"][acc], "image_id": np.full(acc.sum(), "2"),
               "col": out["col"][acc], "row": out["row"][acc]}
    back = transfer(geoms, readers, back_in, height, sigma_height=2.0)
    ok = back["accepted"]
    e = np.hypot(*(np.c_[back["col"], back["row"]] - pts[back["point_id"].astype(int)]).T)
    print(f"Pleiades img_01 -> img_02: {acc.sum()} of {n} accepted ({acc.mean():.2f}) in "
          f"{took:.1f} s; matched - predicted median {np.median(d, 0).round(2)} px, sd "
          f"{d.std(0).round(2)} px; back: {ok.sum()} accepted, {(e[ok] < 0.5).sum()} within "
          f"0.5 px (median {np.median(e[ok]):.3f}, worst {e[ok].max():.3f} px)")
    assert n >= 36
    assert acc.mean() >= 0.6
    assert ok.mean() >= 0.9 and (e[ok] < 0.5).mean() >= 0.95
    # the relative pointing error is below a pixel: the window held every match
    assert np.all(np.abs(np.median(d, 0)) < 1.5)


# --------------------------------------------------------------------------- command line
def _write_rpc_project(tmp, sc):
    """The rendered RPC pair as GeoTIFFs with ``_rpc.txt`` side files, a DEM, roads
    (off by 1.5 m), surveyed control points and their pixels measured on A."""
    import geopandas as gpd
    import rasterio
    import rasterio.errors
    from rasterio.transform import from_origin
    from shapely.geometry import LineString

    from vectoradjust.files.rpc import write_rpc

    for k in ("A", "B"):
        with warnings.catch_warnings():  # the images carry RPCs, not a geotransform
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(tmp / f"{k}.tif", "w", driver="GTiff", width=SIZE,
                               height=SIZE, count=1, dtype="uint8") as ds:
                ds.write(sc.images[k], 1)
        write_rpc(sc.rpcs[k], tmp / f"{k}.tif")
    o = sc.scene.origin
    xs, ys = o[0] + 1.0 + 2.0 * np.arange(200), o[1] - 1.0 - 2.0 * np.arange(200)
    gx, gy = np.meshgrid(xs, ys)
    z = sc.scene.height(np.c_[gx.ravel(), gy.ravel()]).reshape(gx.shape)
    with rasterio.open(tmp / "dem.tif", "w", driver="GTiff", width=200, height=200, count=1,
                       dtype="float64", crs="EPSG:32616",
                       transform=from_origin(o[0], o[1], 2.0, 2.0)) as ds:
        ds.write(z, 1)
    junctions = _junctions(sc.scene.roads)
    lines = []
    for r in sc.scene.roads:  # a vertex at every crossing (the junctions' shape points)
        d = r[1] - r[0]
        t = np.sort([(j - r[0]) @ d / (d @ d) for j in junctions
                     if abs(d[0] * (j - r[0])[1] - d[1] * (j - r[0])[0]) / np.hypot(*d) < 1e-6])
        lines.append(LineString(np.vstack([r[0], r[0] + t[:, None] * d, r[1]]) + [1.5, -1.0]))
    gpd.GeoDataFrame({"rid": np.arange(len(lines))}, geometry=lines,
                     crs="EPSG:32616").to_file(tmp / "roads.shp")
    rng = np.random.default_rng(3)
    xy = sc.centre + rng.uniform(-90.0, 90.0, (10, 2))
    gcp = np.c_[xy, sc.scene.height(xy)]
    with open(tmp / "gcps.csv", "w") as fh:
        fh.write("point_id,X,Y,Z,sigma_x,sigma_y,sigma_z,role\n")
        for i, p in enumerate(gcp):
            fh.write(f"G{i},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},0.05,0.05,0.08,control\n")
    px = true_pixel(sc.rpcs["A"], sc.frame, gcp, TRUE_SHIFT["A"])
    with open(tmp / "measured.csv", "w") as fh:
        fh.write("point_id,image_id,col,row\n")
        for i, p in enumerate(px):
            fh.write(f"G{i},A,{p[0]:.3f},{p[1]:.3f}\n")
    (tmp / "project.toml").write_text(
        'crs = "EPSG:32616"\nheights = "ellipsoidal"\n\n'
        '[[images]]\nid = "A"\nmodel = "rpc"\npath = "A.tif"\nrpc = "A_rpc.txt"\n'
        'bias = "shift"\nbias_sigma = 3.0\n\n'
        '[[images]]\nid = "B"\nmodel = "rpc"\nrpc = "B.tif"\nbias = "shift"\n'
        'bias_sigma = 3.0\n\n'
        '[measurements]\npath = "out/image_points.csv"\nunit = "pixel"\n\n'
        '[control]\npath = "gcps.csv"\n\n'
        '[[vectors]]\nname = "roads"\npath = "roads.shp"\nid_field = "rid"\n'
        'sigma = [3.0, 3.0, 3.0]\ndem = "dem.tif"\n')
    return tmp / "project.toml", gcp


def _table(path):
    import csv

    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.io
def test_measure_cli_on_rpc_images_then_adjust(tmp_path, scene, capsys):
    """predict (GeoTIFF chips in GDAL's pixel grid, road junctions), transfer of the
    control points measured on A to B, adjust: the biases come back; a second predict
    with the adjusted biases gives much smaller windows."""
    import json

    import rasterio

    from vectoradjust.cli.commands import main

    proj, gcp = _write_rpc_project(tmp_path, scene)
    out = tmp_path / "out"
    assert main(["measure", "predict", str(proj), "--out", str(out), "--roads", "-q",
                 "--chips", "tif", "--chip-size", "8"]) == 0
    said = capsys.readouterr().out
    assert "RPC image A" in said and "bias_sigma 3 px" in said
    rows = _table(out / "measurement_template.csv")
    g0 = next(r for r in rows if r["point_id"] == "G0" and r["image_id"] == "B")
    col, row = float(g0["col"]), float(g0["row"])
    assert float(g0["x"]) == col
    with rasterio.open(out / "chips" / "B" / "G0.tif") as ds:
        chip, tr = ds.read(1), ds.transform
    c0, r0 = int(tr.c), int(-tr.f)
    assert np.array_equal(chip, scene.images["B"][r0:r0 + 17, c0:c0 + 17].astype(np.float32))
    assert c0 + 8 <= col < c0 + 9 and r0 + 8 <= row < r0 + 9  # on the chip's centre pixel
    auto = _table(out / "automatic_points.csv")
    assert sum(r["accepted"] == "True" for r in auto) >= 6
    assert main(["measure", "transfer", str(proj), "--out", str(out), "-q", "--measured",
                 str(tmp_path / "measured.csv"), "--automatic",
                 str(out / "automatic_points.csv")]) == 0
    tr_rows = [r for r in _table(out / "transfer.csv") if r["accepted"] == "True"]
    ids = np.array([int(r["point_id"][1:]) for r in tr_rows])
    got = np.array([[float(r["col"]), float(r["row"])] for r in tr_rows])
    truth = true_pixel(scene.rpcs["B"], scene.frame, gcp[ids], TRUE_SHIFT["B"])
    err = np.hypot(*(got - truth).T)
    assert len(ids) >= 8 and err.max() < 0.3
    assert main(["adjust", str(proj), "--out", str(tmp_path / "adj"), "-q"]) == 0
    summary = json.loads((tmp_path / "adj" / "summary.json").read_text())
    for im in summary["images"]:
        est = np.array([im["bias"]["a0"], im["bias"]["b0"]])
        print(f"adjusted bias of {im['id']}: {est.round(3)} px, true {TRUE_SHIFT[im['id']]}")
        assert np.abs(est - TRUE_SHIFT[im["id"]]).max() < 0.3
    assert main(["measure", "predict", str(proj), "--out", str(tmp_path / "m2"), "-q",
                 "--chips", "none", "--orientation",
                 str(tmp_path / "adj" / "summary.json")]) == 0
    before = [float(r["win_major"]) for r in rows if r["kind"] == "control"]
    after = [float(r["win_major"]) for r in _table(tmp_path / "m2" / "measurement_template.csv")
             if r["kind"] == "control"]
    assert np.median(after) < 0.25 * np.median(before)
    # the predictions with the adjusted bias are on the true pixels of the control points
    m2 = [r for r in _table(tmp_path / "m2" / "measurement_template.csv")
          if r["kind"] == "control" and r["image_id"] == "B"]
    p = np.array([[float(r["col"]), float(r["row"])] for r in m2])
    t = true_pixel(scene.rpcs["B"], scene.frame,
                   gcp[[int(r["point_id"][1:]) for r in m2]], TRUE_SHIFT["B"])
    assert np.abs(p - t).max() < 0.3
