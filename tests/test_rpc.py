"""The RPC00B sensor model (``vectoradjust.sensor.rpc``).

Most tests use synthetic models built here: one from a perspective camera over a
curved-earth local frame (exactly a ratio of quadratic polynomials, so the RPC must
reproduce the camera) and one with every one of the 20 terms perturbed (to exercise the
cubic terms in the partials). The real RPCs in ``../shared/data/rpc`` (QuickBird-2 with
five GCPs, a Pleiades pair) are compared with GDAL's RPC transformer through rasterio;
those tests skip when the data or rasterio are absent.

Measured when written (GDAL 3.10.3, rasterio 1.4.4): forward ground -> pixel agrees with
GDAL to 2e-11 px; the inverse agrees to 1e-6 px with ``RPC_PIXEL_ERROR_THRESHOLD=1e-6``
(1.5e-9 px with 1e-9), while GDAL's default threshold of 0.1 px leaves up to 0.0999 px.
GDAL's pixel = raw RPC formula + 0.5 (its (0, 0) is the corner of the first pixel).
"""

from __future__ import annotations

import doctest
import json
import math
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import InputFileError
from vectoradjust.sensor import rpc as rpc_module
from vectoradjust.sensor.rpc import BIAS_MODELS, RpcModel, biased_partials, fold_bias

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rpc"
REAL_IMAGES = ["quickbird2/qb2_basic1b.tif", "pleiades_pair/img_01.tif",
               "pleiades_pair/img_02.tif"]
R_EARTH = 6378137.0


# ---------------------------------------------------------------------- synthetic models
def _look_at(c: np.ndarray) -> np.ndarray:
    """Rows: image column direction (east-ish), row direction (south-ish), view direction."""
    r3 = -c / np.linalg.norm(c)
    r1 = np.cross(r3, [0.0, 1.0, 0.0])
    r1 /= np.linalg.norm(r1)
    return np.array([r1, np.cross(r3, r1), r3])


CAM = dict(long_off=24.4, lat_off=-33.7, height_off=500.0, long_scale=0.05,
           lat_scale=0.04, height_scale=500.0, samp_off=2400.0, line_off=2200.0,
           samp_scale=2500.0, line_scale=2300.0, f=325000.0,
           centre=np.array([-150e3, 80e3, 620e3]))


def _metres_per_unit():
    a = R_EARTH * math.cos(math.radians(CAM["lat_off"])) * math.radians(CAM["long_scale"])
    b = R_EARTH * math.radians(CAM["lat_scale"])
    return a, b


def camera(lon, lat, h):
    """Centre-convention column, row of a perspective camera over a curved local frame."""
    a, b = _metres_per_unit()
    L = (np.asarray(lon) - CAM["long_off"]) / CAM["long_scale"]
    P = (np.asarray(lat) - CAM["lat_off"]) / CAM["lat_scale"]
    x, y = a * L, b * P
    z = np.asarray(h) - (x * x + y * y) / (2 * R_EARTH)
    d = np.stack([x, y, z], axis=-1) - CAM["centre"]
    q = d @ _look_at(CAM["centre"]).T
    return np.stack([CAM["samp_off"] + CAM["f"] * q[..., 0] / q[..., 2],
                     CAM["line_off"] + CAM["f"] * q[..., 1] / q[..., 2]], axis=-1)


def camera_rpc() -> RpcModel:
    """The RPC00B coefficients of :func:`camera`, expanded analytically (exact)."""
    a, b = _metres_per_unit()
    comp = np.zeros((3, 20))
    comp[:, 0] = -CAM["centre"]
    comp[0, 1] = a                       # x = a L
    comp[1, 2] = b                       # y = b P
    comp[2, 0] += CAM["height_off"]      # z = h0 + hs H - (a^2 L^2 + b^2 P^2) / 2R
    comp[2, 3] = CAM["height_scale"]
    comp[2, 7] = -a * a / (2 * R_EARTH)
    comp[2, 8] = -b * b / (2 * R_EARTH)
    q = _look_at(CAM["centre"]) @ comp
    den = q[2] / q[2, 0]
    keys = ("long_off", "lat_off", "height_off", "long_scale", "lat_scale", "height_scale",
            "samp_off", "line_off", "samp_scale", "line_scale")
    return RpcModel(**{k: CAM[k] for k in keys},
                    samp_num=CAM["f"] * q[0] / q[2, 0] / CAM["samp_scale"], samp_den=den,
                    line_num=CAM["f"] * q[1] / q[2, 0] / CAM["line_scale"], line_den=den,
                    source="camera.rpc")


def perturbed_rpc(seed: int = 3) -> RpcModel:
    """:func:`camera_rpc` with every term of every polynomial perturbed."""
    m = camera_rpc()
    rng = np.random.default_rng(seed)
    m.samp_num = m.samp_num + rng.normal(0, 2e-3, 20)
    m.line_num = m.line_num + rng.normal(0, 2e-3, 20)
    # denominators: about as far from 1 as real ones (QuickBird-2: 2e-3 in the linear
    # terms, at most 4e-5 in the quadratic and cubic ones)
    sigma = np.r_[0.0, [1e-3] * 3, [5e-5] * 6, [2e-5] * 10]
    m.samp_den = m.samp_den + rng.normal(0, 1, 20) * sigma
    m.line_den = m.line_den + rng.normal(0, 1, 20) * sigma
    return m


def ground(m: RpcModel, n: int, seed: int = 0, extent: float = 1.0):
    """``n`` random ground points over ``extent`` times the RPC's normalised domain."""
    u = np.random.default_rng(seed).uniform(-extent, extent, (n, 3))
    return (m.long_off + m.long_scale * u[:, 0], m.lat_off + m.lat_scale * u[:, 1],
            m.height_off + m.height_scale * u[:, 2])


# ---------------------------------------------------------------------- the formula
def test_term_order_is_rpc00b():
    hand = [lambda L, P, H: np.ones_like(L), lambda L, P, H: L, lambda L, P, H: P,
            lambda L, P, H: H, lambda L, P, H: L * P, lambda L, P, H: L * H,
            lambda L, P, H: P * H, lambda L, P, H: L ** 2, lambda L, P, H: P ** 2,
            lambda L, P, H: H ** 2, lambda L, P, H: P * L * H, lambda L, P, H: L ** 3,
            lambda L, P, H: L * P ** 2, lambda L, P, H: L * H ** 2,
            lambda L, P, H: L ** 2 * P, lambda L, P, H: P ** 3, lambda L, P, H: P * H ** 2,
            lambda L, P, H: L ** 2 * H, lambda L, P, H: P ** 2 * H, lambda L, P, H: H ** 3]
    L, P, H = np.random.default_rng(1).uniform(-1, 1, (3, 50))
    one = np.eye(20)[0]
    for k in range(20):
        m = RpcModel(0, 0, 0, 0, 0, 1, 1, 1, 1, 1, line_num=np.eye(20)[k], line_den=one,
                     samp_num=np.eye(20)[k], samp_den=one)
        xy = m.project(L, P, H, origin="center")
        np.testing.assert_allclose(xy[:, 0], hand[k](L, P, H), rtol=0, atol=1e-15,
                                   err_msg=f"term {k}")
        np.testing.assert_allclose(xy[:, 1], hand[k](L, P, H), rtol=0, atol=1e-15)


def test_camera_rpc_reproduces_the_camera():
    m = camera_rpc()
    lon, lat, h = ground(m, 2000, extent=1.1)
    np.testing.assert_allclose(m.project(lon, lat, h, origin="center"), camera(lon, lat, h),
                               rtol=0, atol=1e-7)
    # the image covers a few thousand pixels and the height moves points (oblique view)
    xy = m.project(lon, lat, h, origin="center")
    assert np.ptp(xy[:, 0]) > 4000 and np.ptp(xy[:, 1]) > 3000
    assert np.abs(m.project(lon, lat, h + 100.0) - m.project(lon, lat, h)).max() > 10


def test_corner_origin_is_half_a_pixel_more_and_unknown_origin_fails():
    m = perturbed_rpc()
    lon, lat, h = ground(m, 100)
    np.testing.assert_allclose(m.project(lon, lat, h), m.project(lon, lat, h, "center") + 0.5,
                               rtol=0, atol=1e-9)
    xy, _ = m.project_partials(lon, lat, h, origin="corner")
    np.testing.assert_allclose(xy, m.project(lon, lat, h), rtol=0, atol=1e-9)
    ll = m.localize(xy[:, 0] - 0.5, xy[:, 1] - 0.5, h, origin="center")
    np.testing.assert_allclose(ll, np.column_stack([lon, lat]), rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="origin"):
        m.project(lon, lat, h, origin="ul")


def test_shapes_and_broadcasting():
    m = camera_rpc()
    assert m.project(24.4, -33.7, 500.0).shape == (1, 2)
    xy, jac = m.project_partials([24.4, 24.41], -33.7, [[400.0], [600.0]])
    assert xy.shape == (4, 2) and jac.shape == (4, 2, 3)
    assert m.localize(2400.0, [2200.0, 2300.0], 500.0).shape == (2, 2)
    assert m.normalized([24.4, 24.45], -33.7, 500.0).shape == (2, 3)
    # more points than one block of the vectorised evaluation
    lon, lat, h = ground(m, 3 * rpc_module._CHUNK + 7, seed=5)
    xy, jac = m.project_partials(lon, lat, h)
    np.testing.assert_allclose(xy, camera(lon, lat, h) + 0.5, rtol=0, atol=1e-7)


def test_doctests_of_the_module():
    result = doctest.testmod(rpc_module)
    assert result.attempted >= 5 and result.failed == 0


# ---------------------------------------------------------------------- partials
def _central_difference(f, lon, lat, h, steps):
    cols = []
    for axis, step in enumerate(steps):
        x = [np.array(lon, float), np.array(lat, float), np.array(h, float)]
        xp = [a.copy() for a in x]
        xm = [a.copy() for a in x]
        xp[axis] += step
        xm[axis] -= step
        cols.append((f(*xp) - f(*xm)) / (2 * step))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("origin", ["corner", "center"])
def test_ground_partials_against_finite_differences(origin):
    m = perturbed_rpc()
    lon, lat, h = ground(m, 300, seed=2)
    xy, jac = m.project_partials(lon, lat, h, origin=origin)
    np.testing.assert_allclose(xy, m.project(lon, lat, h, origin=origin), rtol=0, atol=1e-9)
    fd = _central_difference(lambda *g: m.project(*g, origin=origin), lon, lat, h,
                             (1e-5, 1e-5, 0.5))
    scale = np.abs(jac).max(axis=0)          # px per degree / per metre, per column
    assert np.all(np.abs(jac - fd) <= 1e-6 * scale + 1e-9)
    # the cubic terms matter: the perturbed model's partials differ from the camera's
    _, jac0 = camera_rpc().project_partials(lon, lat, h, origin=origin)
    assert np.abs(jac - jac0).max() > 1e-3 * np.abs(jac0).max()


@pytest.mark.parametrize("params", [np.zeros(6), [1.5, -2.0, 3.0, -0.7, 2.5, 1.0]])
def test_biased_partials_against_finite_differences(params):
    m = perturbed_rpc()
    lon, lat, h = ground(m, 200, seed=4)
    xy, d_ground, d_params = biased_partials(m, lon, lat, h, params)
    assert xy.shape == (200, 2) and d_ground.shape == (200, 2, 3) and d_params.shape == (200, 2, 6)

    def f(lo, la, hh):
        return biased_partials(m, lo, la, hh, params)[0]

    fd = _central_difference(f, lon, lat, h, (1e-5, 1e-5, 0.5))
    scale = np.abs(d_ground).max(axis=0)
    assert np.all(np.abs(d_ground - fd) <= 1e-6 * scale + 1e-9)
    p = np.asarray(params, float)
    fdp = np.stack([(biased_partials(m, lon, lat, h, p + e)[0]
                     - biased_partials(m, lon, lat, h, p - e)[0]) / 2.0
                    for e in np.eye(6)], axis=-1)
    np.testing.assert_allclose(d_params, fdp, rtol=0, atol=1e-9)


def test_bias_is_added_as_the_formula_says():
    m = perturbed_rpc()
    lon, lat, h = ground(m, 50, seed=6)
    raw = m.project(lon, lat, h, origin="center")
    u = (raw[:, 0] - m.samp_off) / m.samp_scale
    v = (raw[:, 1] - m.line_off) / m.line_scale
    p = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    xy, _, _ = biased_partials(m, lon, lat, h, p, origin="center")
    np.testing.assert_allclose(xy[:, 0], raw[:, 0] + 1 + 2 * u + 3 * v, rtol=0, atol=1e-9)
    np.testing.assert_allclose(xy[:, 1], raw[:, 1] + 4 + 5 * u + 6 * v, rtol=0, atol=1e-9)
    corner, _, _ = biased_partials(m, lon, lat, h, p)
    np.testing.assert_allclose(corner, xy + 0.5, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="6"):
        biased_partials(m, lon, lat, h, p[:4])
    assert BIAS_MODELS == {"none": (), "shift": (0, 3), "shift+drift": (0, 2, 3, 5),
                           "affine": (0, 1, 2, 3, 4, 5)}


# ---------------------------------------------------------------------- the inverse
@pytest.mark.parametrize("make", [camera_rpc, perturbed_rpc])
def test_localize_inverts_project(make):
    m = make()
    lon, lat, h = ground(m, 5000, seed=7, extent=1.05)
    xy = m.project(lon, lat, h)
    ll = m.localize(xy[:, 0], xy[:, 1], h)
    assert not np.isnan(ll).any()
    # 1e-10 degrees is 1e-5 m on the ground, 5e-6 px here
    np.testing.assert_allclose(ll, np.column_stack([lon, lat]), rtol=0, atol=1e-10)
    np.testing.assert_allclose(m.project(ll[:, 0], ll[:, 1], h), xy, rtol=0, atol=1e-7)


def test_localize_returns_nan_where_it_cannot_converge():
    # col_n = L / (1 + L^2 / 2) never exceeds 1/sqrt(2): columns beyond have no solution
    zero = np.zeros(20)
    den = zero.copy()
    den[0] = 1.0
    sden = den.copy()
    sden[7] = 0.5
    samp = zero.copy()
    samp[1] = 1.0
    line = zero.copy()
    line[2] = -1.0
    m = RpcModel(100.0, 100.0, 0.0, 0.0, 0.0, 100.0, 100.0, 1.0, 1.0, 10.0,
                 line_num=line, line_den=den, samp_num=samp, samp_den=sden)
    ll = m.localize([150.0, 300.0, np.nan, 150.0], [120.0, 120.0, 120.0, 120.0],
                    [0.0, 0.0, 0.0, np.inf], origin="center")
    assert np.isfinite(ll[0]).all() and np.isnan(ll[1:]).all()
    np.testing.assert_allclose(m.project(ll[0, 0], ll[0, 1], 0.0, "center"), [[150, 120]],
                               rtol=0, atol=1e-8)


def test_outside_domain_and_normalized():
    m = camera_rpc()
    lon = m.long_off + m.long_scale * np.array([0.0, 1.05, 1.15, 0.0, 0.0, np.nan])
    lat = m.lat_off + m.lat_scale * np.array([0.0, 0.0, 0.0, -1.2, 0.0, 0.0])
    h = m.height_off + m.height_scale * np.array([0.5, 0.0, 0.0, 0.0, -1.11, 0.0])
    np.testing.assert_allclose(m.normalized(lon, lat, h)[:5],
                               [[0, 0, 0.5], [1.05, 0, 0], [1.15, 0, 0], [0, -1.2, 0],
                                [0, 0, -1.11]], atol=1e-12)
    assert m.outside_domain(lon, lat, h).tolist() == [False, False, True, True, True, True]
    assert m.outside_domain(lon, lat, h, margin=0.0).tolist()[:2] == [False, True]


# ---------------------------------------------------------------------- GDAL metadata
def test_gdal_dict_round_trip():
    m = perturbed_rpc()
    m.err_bias, m.err_rand = 12.15, 0.3
    d = m.to_gdal()
    assert all(isinstance(v, str) for v in d.values())
    assert len(d["LINE_NUM_COEFF"].split()) == 20 and d["ERR_BIAS"] == "12.15"
    back = RpcModel.from_gdal(d, source="x.tif")
    assert back == m and back.source == "x.tif"
    assert back.to_gdal() == d
    # numbers and lists (as rasterio's RPC object has them), lower-case keys
    plain = {k.lower(): (list(map(float, v.split())) if k.endswith("COEFF") else float(v))
             for k, v in d.items()}
    assert RpcModel.from_gdal(plain) == m
    assert "ERR_BIAS" not in camera_rpc().to_gdal()
    other = perturbed_rpc(seed=4)
    assert other != m


@pytest.mark.parametrize("change, key, what", [
    (lambda d: d.pop("LAT_SCALE"), "LAT_SCALE", "lacks"),
    (lambda d: d.update(SAMP_NUM_COEFF=" ".join(d["SAMP_NUM_COEFF"].split()[:19])),
     "SAMP_NUM_COEFF", "19 coefficients"),
    (lambda d: d.update(LONG_SCALE="0.0"), "LONG_SCALE", "zero"),
    (lambda d: d.update(LINE_OFF="abc"), "LINE_OFF", "not a number"),
    (lambda d: d.update(HEIGHT_OFF="nan"), "HEIGHT_OFF", "not finite"),
    (lambda d: d.update(LINE_DEN_COEFF=" ".join(["0"] * 20)), "LINE_DEN_COEFF", "all zero"),
    (lambda d: d.update(LINE_NUM_COEFF=[1.0, "x"] + [0.0] * 18), "LINE_NUM_COEFF",
     "not a list of numbers"),
])
def test_malformed_gdal_dicts_raise_input_file_errors(change, key, what):
    d = camera_rpc().to_gdal()
    change(d)
    with pytest.raises(InputFileError, match=rf"^scene\.tif: (?=.*{key})(?=.*{what})") as err:
        RpcModel.from_gdal(d, source="scene.tif")
    msg = str(err.value)
    assert "scene.tif" in msg and key in msg and what in msg
    assert err.value.path == "scene.tif" and err.value.mend


def test_from_gdal_rejects_what_is_not_a_mapping():
    with pytest.raises(InputFileError, match="not a mapping"):
        RpcModel.from_gdal(["LINE_OFF"], source="scene.tif")


# ---------------------------------------------------------------------- folding the bias
def _check_points(m: RpcModel, n: int = 3000):
    return ground(m, n, seed=11)


def test_fold_bias_is_exact_for_a_shift():
    m = perturbed_rpc()
    p = [-2.977, 0.0, 0.0, -2.09, 0.0, 0.0]
    folded, misfit = fold_bias(m, p)
    assert misfit == 0.0
    assert folded.samp_off == m.samp_off - 2.977 and folded.line_off == m.line_off - 2.09
    assert np.array_equal(folded.samp_num, m.samp_num) and folded.samp_num is not m.samp_num
    lon, lat, h = _check_points(m)
    np.testing.assert_allclose(folded.project(lon, lat, h),
                               biased_partials(m, lon, lat, h, p)[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("model, params, bound", [
    ("shift+drift", [-3.0, 0.0, 2.0, -2.0, 0.0, -1.5], 1e-3),
    ("affine", [-3.0, 1.5, 2.0, -2.0, -1.0, -1.5], 1e-3),
    ("affine", [4.0, -5.0, 5.0, 1.0, 5.0, 5.0], 1e-3),
])
def test_fold_bias_refits_drift_and_affine(model, params, bound):
    m = perturbed_rpc()
    assert set(np.flatnonzero(params)) <= set(BIAS_MODELS[model])
    folded, misfit = fold_bias(m, params)
    assert 0.0 < misfit < bound
    lon, lat, h = _check_points(m)
    target = biased_partials(m, lon, lat, h, params)[0]
    err = np.hypot(*(folded.project(lon, lat, h) - target).T)
    assert err.max() <= misfit * 1.5
    # the bias itself is several pixels, and the denominators are kept
    assert np.abs(target - m.project(lon, lat, h)).max() > 3.0
    assert np.array_equal(folded.samp_den, m.samp_den)
    with pytest.raises(ValueError, match="grid"):
        fold_bias(m, params, grid=3)


# ---------------------------------------------------------------------- rasterio / GDAL
def _rasterio():
    return pytest.importorskip("rasterio")


def _real(name: str):
    path = DATA / name
    if not path.exists():
        pytest.skip(f"real RPC data not found: {path}")
    rasterio = _rasterio()
    with rasterio.open(path) as src:
        d = src.rpcs.to_gdal()
        return RpcModel.from_gdal(d, source=path.name), d, (src.width, src.height)


def _image_grid(m: RpcModel, size, n: int = 9):
    """Pixels (corner convention) spread over the image, at five heights each."""
    cc, rr = np.meshgrid(np.linspace(0, size[0], n), np.linspace(0, size[1], n))
    hs = m.height_off + m.height_scale * np.array([-0.8, -0.4, 0.0, 0.4, 0.8])
    return np.repeat(cc.ravel(), 5), np.repeat(rr.ravel(), 5), np.tile(hs, cc.size)


def _gdal_forward(d, lon, lat, h, **options):
    from rasterio.transform import RPCTransformer

    with RPCTransformer(d, **options) as t:
        rows, cols = t.rowcol(lon, lat, zs=h, op=np.positive)   # no rounding
    return np.column_stack([cols, rows])


def _gdal_inverse(d, col, row, h, **options):
    from rasterio.transform import RPCTransformer

    with RPCTransformer(d, **options) as t:
        x, y = t.xy(row, col, zs=h, offset="ul")   # "ul": the pixel coordinates as given
    return np.column_stack([x, y])


def _compare_with_gdal(m: RpcModel, d, col, row, h):
    """Largest forward and inverse disagreements with GDAL, in pixels."""
    ll = m.localize(col, row, h)
    assert not np.isnan(ll).any()
    forward = np.abs(_gdal_forward(d, ll[:, 0], ll[:, 1], h) - m.project(ll[:, 0], ll[:, 1], h))
    gdal_ll = _gdal_inverse(d, col, row, h, RPC_PIXEL_ERROR_THRESHOLD=1e-6)
    _, jac = m.project_partials(ll[:, 0], ll[:, 1], h)
    inverse_px = np.einsum("nij,nj->ni", jac[:, :, :2], gdal_ll - ll)  # degrees -> px
    reprojected = m.project(gdal_ll[:, 0], gdal_ll[:, 1], h) - np.column_stack([col, row])
    return forward.max(), np.abs(inverse_px).max(), np.abs(reprojected).max()


def test_agrees_with_gdal_on_the_synthetic_model():
    _rasterio()
    m = perturbed_rpc()
    col, row, h = _image_grid(m, (4800, 4400))
    forward, inverse, reprojected = _compare_with_gdal(m, m.to_gdal(), col, row, h)
    assert forward < 1e-6 and inverse < 1e-3 and reprojected < 1e-3


@pytest.mark.parametrize("name", REAL_IMAGES)
def test_agrees_with_gdal_on_real_rpcs(name):
    m, d, size = _real(name)
    assert m.to_gdal() == d        # rasterio's dictionary back, string for string
    col, row, h = _image_grid(m, size)
    forward, inverse, reprojected = _compare_with_gdal(m, d, col, row, h)
    assert forward < 1e-6 and inverse < 1e-3 and reprojected < 1e-3
    # GDAL's default iteration threshold (0.1 px) is what limits the default agreement
    default = _gdal_inverse(d, col, row, h)
    off = np.abs(m.project(default[:, 0], default[:, 1], h) - np.column_stack([col, row]))
    assert off.max() <= 0.1 + 1e-6


@pytest.mark.parametrize("name", REAL_IMAGES)
def test_gdal_pixel_is_the_raw_formula_plus_half_a_pixel(name):
    m, d, size = _real(name)
    col, row, h = _image_grid(m, size, n=4)
    ll = m.localize(col, row, h, origin="center")
    gdal = _gdal_forward(d, ll[:, 0], ll[:, 1], h)
    raw = m.project(ll[:, 0], ll[:, 1], h, origin="center")
    np.testing.assert_allclose(gdal - raw, 0.5, rtol=0, atol=1e-6)   # + 0.5, not - 0.5
    # rasterio's xy(0, 0) (pixel centre) is the raw formula's (0, 0)
    centre = _gdal_inverse(d, 0.5, 0.5, m.height_off, RPC_PIXEL_ERROR_THRESHOLD=1e-9)
    np.testing.assert_allclose(m.project(*centre[0], m.height_off, origin="center"),
                               [[0.0, 0.0]], rtol=0, atol=1e-6)


def test_quickbird_gcps_show_the_known_bias():
    m, _, size = _real("quickbird2/qb2_basic1b.tif")
    gcps = json.loads((DATA / "quickbird2" / "gcps.geojson").read_text(encoding="utf-8"))
    xyz = np.array([f["geometry"]["coordinates"] for f in gcps["features"]])
    ji = np.array([f["properties"]["ji"] for f in gcps["features"]])
    assert len(ji) == 5 and not m.outside_domain(*xyz.T).any()
    # `ji` is in the raw RPC (centre) convention: orthority evaluates the RPC formula
    # itself and subtracts 0.5 from GDAL's pixels. Measured: ji - RPC = (-2.977, -2.090) px,
    # scatter 0.075 / 0.071 px (std), at most 0.13 px from the mean. In GDAL's corner
    # convention the mean would be (-3.48, -2.59), not the 3.0 / 2.1 px the data's README
    # states; the scatter cannot tell the conventions apart (they differ by a constant).
    miss = ji - m.project(*xyz.T, origin="center")
    mean = miss.mean(axis=0)
    np.testing.assert_allclose(mean, [-2.977, -2.090], atol=0.005)
    assert np.abs(miss - mean).max() < 0.15 and miss.std(axis=0).max() < 0.08
    corner = ji - m.project(*xyz.T)
    np.testing.assert_allclose(corner.mean(axis=0), mean - 0.5, atol=1e-9)
    # the shift model removes it: least squares on the bias partials (linear, one step)
    _, _, dp = biased_partials(m, *xyz.T, np.zeros(6), origin="center")
    cols = list(BIAS_MODELS["shift"])
    a = dp[:, :, cols].reshape(-1, len(cols))
    p = np.zeros(6)
    p[cols] = np.linalg.lstsq(a, miss.ravel(), rcond=None)[0]
    np.testing.assert_allclose(p[cols], mean, atol=1e-9)
    after = ji - biased_partials(m, *xyz.T, p, origin="center")[0]
    assert np.abs(after).max() < 0.15
    folded, misfit = fold_bias(m, p)
    assert misfit == 0.0
    np.testing.assert_allclose(folded.project(*xyz.T, origin="center"), ji - after, atol=1e-9)


@pytest.mark.parametrize("name", REAL_IMAGES[:2])
def test_fold_bias_on_real_rpcs(name):
    # measured: QuickBird-2 1.7e-5 px, Pleiades img_01 4.5e-4 px. The Pleiades crop RPCs
    # keep the full scene's offsets, so u, v are about -39 over the crop and the same
    # parameters make a much larger bias there (up to ~100 px over the domain).
    m, _, _ = _real(name)
    params = [-3.0, 1.5, 2.0, -2.0, -1.0, -1.5]
    folded, misfit = fold_bias(m, params)
    assert 0.0 < misfit < 1e-3
    lon, lat, h = _check_points(m)
    err = folded.project(lon, lat, h) - biased_partials(m, lon, lat, h, params)[0]
    assert np.hypot(*err.T).max() <= misfit * 1.5
