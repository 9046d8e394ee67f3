"""Tests of vectoradjust.accuracy.propagate against independent truth.

Truth: the definition of the derived quantities (distance, mean, length, bilinear
interpolation via scipy's RegularGridInterpolator), finite differences, Monte Carlo
and the paper's worked average-height example (Filin & Doytsher 1998).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.stats import chi2

from vectoradjust.accuracy.propagate import (
    bilinear_coefficients,
    block_diagonal,
    confidence_scale,
    contour_tolerance,
    distance,
    dtm_bilinear,
    g_band,
    g_band_polyline,
    height_profile,
    mean_height,
    point_sigma_grid,
    polyline_length,
    propagate,
)
from vectoradjust.sensor.collinearity import partials, project


def _correlated_points(n, rho=0.95, sigma=(0.3, 0.3, 0.5), seed=0):
    """Covariance of n XYZ points, every pair of points correlated by ``rho`` per axis."""
    rng = np.random.default_rng(seed)
    s = np.asarray(sigma, float)
    c_point = np.diag(s**2)
    c_point[0, 1] = c_point[1, 0] = 0.2 * s[0] * s[1]
    r = np.full((n, n), rho) + (1 - rho) * np.eye(n)
    cov = np.kron(r, c_point)
    xyz = np.column_stack([np.cumsum(rng.uniform(5, 15, n)), rng.uniform(-20, 20, n),
                           rng.uniform(90, 110, n)])
    return xyz, cov


# ---------------------------------------------------------------------------- general
def test_propagate_finite_differences_match_analytic_jacobian():
    def func(p):
        return np.array([p[0] * np.sin(p[1]) + p[2] ** 2, np.hypot(p[3], p[4]) * p[5]])

    def jac(p):
        r = np.hypot(p[3], p[4])
        return np.array([[np.sin(p[1]), p[0] * np.cos(p[1]), 2 * p[2], 0, 0, 0],
                         [0, 0, 0, p[3] / r * p[5], p[4] / r * p[5], r]])

    x = np.array([2.0, 0.7, -1.5, 3.0, 4.0, 1.2])
    a = np.random.default_rng(1).normal(size=(6, 6))
    cov = a @ a.T * 0.01
    fd = propagate(func, x, cov)
    an = propagate(func, x, cov, jacobian=jac)
    np.testing.assert_allclose(fd.jacobian, jac(x), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(fd.covariance, an.covariance, rtol=1e-6)
    np.testing.assert_allclose(an.covariance, jac(x) @ cov @ jac(x).T)
    j = jac(x)
    blk = block_diagonal(cov, 3)
    assert blk[0, 3] == 0 and blk[0, 2] == cov[0, 2]
    np.testing.assert_allclose(an.sigma_variance_only, np.sqrt(np.diag(j @ blk @ j.T)))


def test_propagate_scalar_and_large_coordinates():
    # UTM-sized coordinates: the default step follows the sigma, not |x|
    x = np.array([500000.0, 4000000.0, 500010.0, 4000005.0])
    cov = np.diag([0.01, 0.01, 0.02, 0.02])
    res = propagate(lambda p: np.hypot(p[2] - p[0], p[3] - p[1]), x, cov, block_size=2)
    d = distance(x[:2], x[2:], cov)
    assert isinstance(res.value, float)
    assert res.sigma == pytest.approx(d.sigma, rel=1e-7)


def test_mean_height_paper_example():
    m2 = 0.04
    res = mean_height([100.0, 101.0], [[m2, 0.9 * m2], [0.9 * m2, m2]])
    assert res.value == pytest.approx(100.5)
    assert res.sigma**2 == pytest.approx(0.95 * m2, rel=1e-12)
    assert res.sigma_no_cov**2 == pytest.approx(0.5 * m2, rel=1e-12)


# --------------------------------------------------------------------------- distance
@pytest.mark.parametrize("dims", [2, 3])
def test_distance_sigma_with_and_without_covariance_monte_carlo(dims):
    xyz, cov = _correlated_points(2, rho=0.93, seed=3)
    res = distance(xyz[0], xyz[1], cov, dims=dims)
    rng = np.random.default_rng(42)
    n = 20000
    draws = rng.multivariate_normal(xyz.ravel(), cov, size=n)
    d = np.linalg.norm(draws[:, :dims] - draws[:, 3:3 + dims], axis=1)
    assert res.value == pytest.approx(np.linalg.norm(xyz[0, :dims] - xyz[1, :dims]))
    assert res.sigma == pytest.approx(d.std(), rel=0.03)
    draws_nc = rng.multivariate_normal(xyz.ravel(), block_diagonal(cov, 3), size=n)
    d_nc = np.linalg.norm(draws_nc[:, :dims] - draws_nc[:, 3:3 + dims], axis=1)
    assert res.sigma_no_cov == pytest.approx(d_nc.std(), rel=0.03)
    # strongly correlated points: the distance is far better than the points suggest
    assert res.sigma < 0.4 * res.sigma_no_cov


def test_distance_vectorised_over_pairs():
    xyz, cov = _correlated_points(4, seed=5)
    p1 = xyz[[0, 1, 2]]
    p2 = xyz[[1, 2, 3]]
    covs = np.stack([cov[np.ix_(np.r_[3 * i:3 * i + 6], np.r_[3 * i:3 * i + 6])]
                     for i in range(3)])
    res = distance(p1, p2, covs)
    for i in range(3):
        one = distance(p1[i], p2[i], covs[i])
        assert res.sigma[i] == pytest.approx(one.sigma)
        assert res.value[i] == pytest.approx(one.value)


# ---------------------------------------------------------------------- polyline, profile
@pytest.mark.parametrize("dims", [2, 3])
def test_polyline_length_jacobian_matches_finite_differences(dims):
    xyz, cov = _correlated_points(12, rho=0.9, seed=7)
    res = polyline_length(xyz, cov, dims=dims)

    def length(p):
        q = p.reshape(-1, 3)[:, :dims]
        return np.sum(np.linalg.norm(np.diff(q, axis=0), axis=1))

    assert res.value == pytest.approx(length(xyz.ravel()))
    fd = propagate(length, xyz.ravel(), cov, step=1e-6)
    np.testing.assert_allclose(res.jacobian, fd.jacobian[0], atol=1e-8)
    assert res.sigma == pytest.approx(fd.sigma, rel=1e-6)
    assert res.sigma_no_cov == pytest.approx(fd.sigma_variance_only, rel=1e-6)


def test_polyline_length_monte_carlo():
    xyz, cov = _correlated_points(6, rho=0.95, seed=8)
    res = polyline_length(xyz, cov)
    draws = np.random.default_rng(2).multivariate_normal(xyz.ravel(), cov, size=20000)
    q = draws.reshape(-1, 6, 3)[:, :, :2]
    lengths = np.sum(np.linalg.norm(np.diff(q, axis=1), axis=2), axis=1)
    assert res.sigma == pytest.approx(lengths.std(), rel=0.03)


def test_height_profile():
    xyz, cov = _correlated_points(7, seed=9)
    prof = height_profile(xyz, cov)
    seg = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1)
    np.testing.assert_allclose(prof.chainage, np.r_[0, np.cumsum(seg)])
    np.testing.assert_allclose(prof.sigma_z, np.sqrt(np.diag(cov)[2::3]))
    np.testing.assert_allclose(prof.cov_z, cov[2::3, 2::3])

    def chain(p):
        q = p.reshape(-1, 3)[:, :2]
        return np.r_[0, np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))]

    fd = propagate(chain, xyz.ravel(), cov, step=1e-6)
    np.testing.assert_allclose(prof.sigma_chainage, fd.sigma, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(prof.sigma_chainage_no_cov, fd.sigma_variance_only, rtol=1e-6,
                               atol=1e-12)
    # blocks-only input equals the block-diagonal full matrix
    idx = np.arange(7)
    blocks = cov.reshape(7, 3, 7, 3)[idx, :, idx, :]
    np.testing.assert_allclose(height_profile(xyz, blocks).sigma_chainage,
                               prof.sigma_chainage_no_cov)


# -------------------------------------------------------------------------------- DTM
def _interp(heights, origin, cell, pts):
    """Independent bilinear interpolation (scipy) of one cell."""
    dx, dy = cell
    grid = np.array([[heights[0], heights[2]], [heights[1], heights[3]]])  # [ix, iy]
    f = RegularGridInterpolator(([origin[0], origin[0] + dx], [origin[1], origin[1] + dy]), grid,
                                bounds_error=False, fill_value=None)
    return f(pts)


def test_dtm_bilinear_value_and_sigma_monte_carlo():
    heights = np.array([101.2, 103.9, 100.4, 104.8])
    s = np.array([0.15, 0.2, 0.18, 0.25])
    corr = np.full((4, 4), 0.8) + 0.2 * np.eye(4)
    cov_h = corr * np.outer(s, s)
    origin = (500.0, 800.0)
    cell = (10.0, 12.0)
    cov_o = np.array([[0.04, 0.01], [0.01, 0.09]])
    pts = np.array([[503.0, 805.0], [508.5, 801.0], [500.0, 800.0]])
    res = dtm_bilinear(heights, cov_h, origin, cell, pts, cov_origin=cov_o)
    np.testing.assert_allclose(res.h, _interp(heights, origin, cell, pts), atol=1e-12)
    rng = np.random.default_rng(4)
    n = 20000
    hh = rng.multivariate_normal(heights, cov_h, size=n)
    oo = rng.multivariate_normal(origin, cov_o, size=n)
    # the cell moves with its origin: evaluate at the point relative to the drawn origin
    u = pts[None, :, 0] - oo[:, 0:1]
    v = pts[None, :, 1] - oo[:, 1:2]
    su, sv = u / cell[0], v / cell[1]
    h_mc = (hh[:, 0:1] * (1 - su) * (1 - sv) + hh[:, 1:2] * su * (1 - sv)
            + hh[:, 2:3] * (1 - su) * sv + hh[:, 3:4] * su * sv)
    np.testing.assert_allclose(res.sigma, h_mc.std(axis=0), rtol=0.03)
    emp = np.cov(h_mc.T)
    np.testing.assert_allclose(res.covariance, emp, rtol=0.06, atol=0.002)
    assert np.all(res.sigma_heights_only <= res.sigma)


def test_dtm_bilinear_point_error_adds_slope_term():
    heights = np.array([100.0, 104.0, 101.0, 106.0])
    a, b, c, d = bilinear_coefficients(heights, 10.0)
    cp = np.diag([0.25, 0.16])
    res0 = dtm_bilinear(heights, np.zeros((4, 4)), (0, 0), 10.0, (3.0, 4.0))
    res = dtm_bilinear(heights, np.zeros((4, 4)), (0, 0), 10.0, (3.0, 4.0), cov_point=cp)
    assert res0.sigma == 0
    gx, gy = b + d * 4.0, c + d * 3.0
    assert res.sigma == pytest.approx(np.sqrt(gx**2 * 0.25 + gy**2 * 0.16))


def test_contour_tolerance_matches_interpolated_surface():
    heights = np.array([100.0, 104.0, 101.0, 106.5])
    origin, cell = (0.0, 0.0), (10.0, 10.0)
    a, b, c, d = bilinear_coefficients(heights, cell)
    x = np.array([2.0, 5.0, 7.5])
    y = np.array([1.0, 6.0, 3.0])
    dh = 0.5
    tx, ty = contour_tolerance(b, c, d, x, y, origin[0], origin[1], dh)
    pts = np.column_stack([x, y])
    h0 = _interp(heights, origin, cell, pts)
    hx = _interp(heights, origin, cell, np.column_stack([x + tx, y]))
    hy = _interp(heights, origin, cell, np.column_stack([x, y + ty]))
    np.testing.assert_allclose(np.abs(hx - h0), dh, rtol=1e-9)
    np.testing.assert_allclose(np.abs(hy - h0), dh, rtol=1e-9)
    # and against the finite-difference slope of the surface
    e = 1e-4
    gx = (_interp(heights, origin, cell, pts + [e, 0]) - _interp(heights, origin, cell,
                                                                  pts - [e, 0])) / (2 * e)
    np.testing.assert_allclose(tx, dh / np.abs(gx), rtol=1e-6)


def test_contour_tolerance_flat_is_infinite():
    tx, ty = contour_tolerance(0.0, 0.2, 0.0, 1.0, 1.0, 0.0, 0.0, 0.5)
    assert tx == np.inf
    assert ty == pytest.approx(2.5)


# ----------------------------------------------------------------------------- G-band
try:  # the G-band tests use shapely (not needed by the module itself)
    import shapely
except ImportError:  # pragma: no cover - Debian's QGIS Python
    shapely = None
needs_shapely = pytest.mark.skipif(shapely is None, reason="shapely not installed")


def _local_upper_width(ring, p1, p2, u):
    """Largest normal offset of the band polygon on the normal line at chainage u."""
    e_u = (p2 - p1) / np.linalg.norm(p2 - p1)
    e_n = np.array([-e_u[1], e_u[0]])
    base = p1 + u * e_u
    line = shapely.LineString([base - 1e3 * e_n, base + 1e3 * e_n])
    cut = shapely.Polygon(ring).intersection(line)
    pts = np.array(cut.coords) if cut.geom_type == "LineString" else np.vstack(
        [np.array(g.coords) for g in cut.geoms])
    return np.max((pts - base) @ e_n)


def _pair_cov(seed=0, rho=0.0):
    rng = np.random.default_rng(seed)
    a1 = rng.normal(size=(2, 2))
    a2 = rng.normal(size=(2, 2))
    c1 = a1 @ a1.T * 0.05 + 0.02 * np.eye(2)
    c2 = a2 @ a2.T * 0.05 + 0.02 * np.eye(2)
    cj = np.zeros((4, 4))
    cj[:2, :2] = c1
    cj[2:, 2:] = c2
    cross = rho * np.linalg.cholesky(c1) @ np.linalg.cholesky(c2).T
    cj[:2, 2:] = cross
    cj[2:, :2] = cross.T
    return cj


@needs_shapely
@pytest.mark.parametrize("rho", [0.0, 0.9])
def test_g_band_half_width_equals_normal_sigma(rho):
    p1 = np.array([1000.0, 2000.0])
    p2 = np.array([1080.0, 2035.0])
    cj = _pair_cov(1, rho)
    ring = g_band(p1, p2, cj, confidence=0.9)
    assert shapely.Polygon(ring).is_valid
    k = np.sqrt(chi2.ppf(0.9, 2))
    assert k == pytest.approx(confidence_scale(0.9))
    length = np.linalg.norm(p2 - p1)
    e_u = (p2 - p1) / length
    n = np.array([-e_u[1], e_u[0]])
    for t in np.linspace(0.0, 1.0, 33)[2:-2:3]:
        # direct propagation of P(t) = (1 - t) P1 + t P2
        res = propagate(lambda p, t=t: (1 - t) * p[:2] + t * p[2:], np.r_[p1, p2], cj,
                        block_size=2)
        c_t = res.covariance
        half = k * np.sqrt(n @ c_t @ n)
        # the ellipse of P(t) touches the band where its normal extent is largest
        u_star = t * length + k * (e_u @ c_t @ n) / np.sqrt(n @ c_t @ n)
        assert _local_upper_width(ring, p1, p2, u_star) == pytest.approx(half, rel=2e-3)


@needs_shapely
def test_g_band_fully_correlated_ends_is_a_strip():
    c = np.array([[0.3, 0.1], [0.1, 0.2]])
    cj = np.block([[c, c], [c, c]])  # the segment only translates: C(t) = C
    p1, p2 = np.array([0.0, 0.0]), np.array([50.0, 20.0])
    ring = g_band(p1, p2, cj)
    k = confidence_scale(0.9)
    e_u = (p2 - p1) / np.linalg.norm(p2 - p1)
    n = np.array([-e_u[1], e_u[0]])
    for u in [5.0, 20.0, 40.0]:
        assert _local_upper_width(ring, p1, p2, u) == pytest.approx(k * np.sqrt(n @ c @ n),
                                                                     rel=1e-9)


@needs_shapely
def test_g_band_contains_the_ellipses_and_is_tight():
    p1, p2 = np.array([0.0, 0.0]), np.array([30.0, -10.0])
    cj = _pair_cov(2, 0.3) * 4
    k = confidence_scale(0.9)
    ring = g_band(p1, p2, cj)
    band = shapely.Polygon(ring)
    phi = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ellipses = []
    for t in np.linspace(0, 1, 301):
        f = np.hstack([(1 - t) * np.eye(2), t * np.eye(2)])
        c = f @ cj @ f.T
        w, v = np.linalg.eigh(c)
        pts = ((1 - t) * p1 + t * p2)[:, None] + k * (v * np.sqrt(w)) @ np.vstack([np.cos(phi),
                                                                         np.sin(phi)])
        ellipses.append(shapely.Polygon(pts.T))
    union = shapely.union_all(ellipses)
    assert band.buffer(1e-9).contains(union)
    # outer approximation: only slightly larger than the union of 301 ellipses
    assert band.area == pytest.approx(union.area, rel=5e-3)
    pieces = g_band(p1, p2, cj, pieces=True)
    assert len(pieces) == 32
    assert shapely.union_all([shapely.Polygon(p) for p in pieces]).area == pytest.approx(
        band.area, rel=1e-6)


@needs_shapely
def test_g_band_polyline():
    xyz, cov = _correlated_points(5, seed=10)
    rings = g_band_polyline(xyz, cov)
    assert len(rings) == 4
    for i, r in enumerate(rings):
        poly = shapely.Polygon(r)
        assert poly.is_valid
        assert poly.contains(shapely.Point(*(0.5 * (xyz[i, :2] + xyz[i + 1, :2]))))


# ------------------------------------------------------------------- equal-error grid
F_MM = 152.4
EO = np.array([[1000.0, 2000.0, 700.0, 0.01, -0.008, 0.02],
               [1368.0, 2006.0, 703.0, -0.006, 0.015, 0.018]])


def _cov_eo():
    rng = np.random.default_rng(6)
    s = np.array([0.1, 0.1, 0.08, 2e-5, 2e-5, 1e-5] * 2)
    a = rng.normal(size=(12, 12))
    corr = np.corrcoef(a @ a.T + 12 * np.eye(12))
    return corr * np.outer(s, s)


def _intersect(eo_l, eo_r, xy, start, iterations=6):
    """Forward intersection by Gauss-Newton, vectorised over independent cases."""
    p = np.array(start, float)
    for _ in range(iterations):
        comp = np.concatenate([project(eo_l, p, F_MM), project(eo_r, p, F_MM)], axis=-1)
        _, a0 = partials(eo_l, p, F_MM)
        _, a1 = partials(eo_r, p, F_MM)
        a = np.concatenate([a0, a1], axis=-2)
        r = xy - comp
        n = np.einsum("kij,kil->kjl", a, a)
        p = p + np.linalg.solve(n, np.einsum("kij,ki->kj", a, r)[..., None])[..., 0]
    return p


def test_point_sigma_grid_equals_finite_difference_propagation():
    X, Y = np.meshgrid([1100.0, 1180.0, 1270.0], [1800.0, 2000.0])
    Z = np.full_like(X, 95.0)
    cee = _cov_eo()
    sig = 0.005
    res = point_sigma_grid(EO, cee, F_MM, sig, X, Y, Z)
    assert res.sigma_x.shape == X.shape
    for i, j in [(0, 0), (1, 2), (0, 1)]:
        g = np.array([X[i, j], Y[i, j], Z[i, j]])
        xy = np.concatenate([project(EO[0], g, F_MM), project(EO[1], g, F_MM)])
        theta = np.concatenate([EO.ravel(), xy])

        def f(th, g=g):
            return _intersect(th[None, :6], th[None, 6:12], th[None, 12:], g[None])[0]

        sigma = np.zeros((16, 16))
        sigma[:12, :12] = cee
        sigma[12:, 12:] = sig**2 * np.eye(4)
        steps = np.r_[np.full(3, 1e-3), np.full(3, 1e-7), np.full(3, 1e-3), np.full(3, 1e-7),
                      np.full(4, 1e-5)]
        fd = propagate(f, theta, sigma, step=steps, block_size=1)
        np.testing.assert_allclose(res.cov[i, j], fd.covariance, rtol=1e-5,
                                   atol=1e-6 * np.abs(fd.covariance).max())


def test_point_sigma_grid_monte_carlo():
    g = np.array([1180.0, 2100.0, 95.0])
    cee = _cov_eo()
    sig = 0.006
    res = point_sigma_grid(EO, cee, F_MM, sig, g[0], g[1], g[2])
    rng = np.random.default_rng(9)
    n = 20000
    eos = rng.multivariate_normal(EO.ravel(), cee, size=n)
    xy = np.concatenate([project(EO[0], g, F_MM), project(EO[1], g, F_MM)])
    obs = xy + rng.normal(0, sig, (n, 4))
    pts = _intersect(eos[:, :6], eos[:, 6:], obs, np.broadcast_to(g, (n, 3)))
    sd = pts.std(axis=0)
    np.testing.assert_allclose([res.sigma_x, res.sigma_y, res.sigma_z], sd, rtol=0.03)
    # EO uncertainty matters: image-only sigma is clearly smaller here
    assert np.sqrt(res.cov_images_only[2, 2]) < 0.9 * res.sigma_z
