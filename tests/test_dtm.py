"""Tests of vectoradjust.accuracy.dtm (DTM and contour accuracy) against independent truth.

Truth: scipy's interpolators (LinearNDInterpolator, RegularGridInterpolator), Monte Carlo
(correlated errors drawn with the stated covariance, the surface interpolated again from
the perturbed points or nodes, the empirical sigma compared), the published constants
(Li's b = 17/3072, Torlegard's per-mille ranges) and a simulated terrain with known
heights (coverage of the LE90).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator, RegularGridInterpolator

from vectoradjust.accuracy import dtm
from vectoradjust.accuracy.propagate import bilinear_coefficients, dtm_bilinear


def _terrain(x, y, amp=1.0):
    return (100.0 + amp * 5.0 * np.sin(2 * np.pi * x / 200.0)
            + amp * 4.0 * np.cos(2 * np.pi * y / 260.0) + 0.02 * x)


def _points(seed=0, n=200, extent=300.0, corr=150.0, amp=1.0, sigma=(0.1, 0.1, 0.2)):
    """Points on the terrain and a covariance: half common (exp(-d/corr)), half own."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, extent, (n, 2))
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    r = 0.5 * np.exp(-d / corr) + 0.5 * np.eye(n)
    s = np.asarray(sigma, float)
    s_point = np.diag(s**2)
    s_point[0, 1] = s_point[1, 0] = 0.3 * s[0] * s[1]
    cov = np.kron(r, s_point)
    return np.column_stack([xy, _terrain(*xy.T, amp)]), cov


def _barycentric_heights(xyz, simplices, s, query):
    """Linear interpolation in the given triangles (indices fixed), vectorised over draws."""
    v = xyz[..., simplices[s], :]  # (..., q, 3, 3)
    a, b, c = v[..., 0, :], v[..., 1, :], v[..., 2, :]
    det = ((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1])
           - (c[..., 0] - a[..., 0]) * (b[..., 1] - a[..., 1]))
    l1 = ((query[:, 0] - a[..., 0]) * (c[..., 1] - a[..., 1])
          - (c[..., 0] - a[..., 0]) * (query[:, 1] - a[..., 1])) / det
    l2 = ((b[..., 0] - a[..., 0]) * (query[:, 1] - a[..., 1])
          - (query[:, 0] - a[..., 0]) * (b[..., 1] - a[..., 1])) / det
    return a[..., 2] + l1 * (b[..., 2] - a[..., 2]) + l2 * (c[..., 2] - a[..., 2])


# --------------------------------------------------------------------------- TIN
def test_tin_heights_match_scipy_linear_interpolator():
    xyz, cov = _points()
    m = dtm.points_model(xyz, cov)
    q = np.random.default_rng(1).uniform(20, 280, (300, 2))
    op = dtm.interpolation_operator(m, q, "tin")
    ref = LinearNDInterpolator(xyz[:, :2], xyz[:, 2])(q)
    np.testing.assert_allclose(op.h, ref, atol=1e-9)
    # the Jacobian's Z columns are the barycentric weights: h = F_z z exactly
    fz = op.jacobian[:, 2::3]
    np.testing.assert_allclose(fz @ xyz[:, 2], op.h, atol=1e-9)


def test_tin_sigma_with_xy_and_z_errors_matches_monte_carlo():
    xyz, cov = _points(seed=2)
    m = dtm.points_model(xyz, cov)
    q = np.array([[100.0, 120.0], [150.0, 150.0], [152.0, 151.0], [230.0, 60.0]])
    op, sigma, full = dtm.interpolate(m, q, "tin", full=True)
    rng = np.random.default_rng(3)
    n = 20000
    draws = xyz.ravel() + rng.multivariate_normal(np.zeros(cov.shape[0]), cov, size=n,
                                                  method="cholesky")
    s = m.tin.find_simplex(q)
    h_mc = _barycentric_heights(draws.reshape(n, -1, 3), m.tin.simplices, s, q)
    np.testing.assert_allclose(sigma, h_mc.std(axis=0), rtol=0.03)
    np.testing.assert_allclose(full, np.cov(h_mc.T), rtol=0.08, atol=2e-4)
    # the horizontal errors matter on this slope: without them the sigma is smaller
    cov_z = cov.copy()
    xy_cols = np.r_[0:cov.shape[0]:3, 1:cov.shape[0]:3]
    cov_z[xy_cols, :] = 0.0
    cov_z[:, xy_cols] = 0.0
    _, sigma_z = dtm.interpolate(dtm.points_model(xyz, cov_z), q, "tin")
    assert np.all(sigma_z < sigma)


# --------------------------------------------------------------------- grid models
def _node_cov(grid: dtm.NodeGrid, sigma: float, length: float) -> np.ndarray:
    xy = grid.xy()
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    return sigma**2 * np.exp(-d / length)


@pytest.mark.parametrize("method", ["bilinear", "bicubic"])
def test_dem_sigma_matches_monte_carlo_of_correlated_nodes(method):
    rows, cols, cell = 8, 9, 5.0
    gt = (1000.0, cell, 0.0, 2000.0, 0.0, -cell)
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    h = 50 + 0.3 * c + 0.1 * r**2
    m = dtm.dem_model(h, gt, node_sigma=0.4, correlation_length=12.0)
    q = np.array([[1013.3, 1982.1], [1021.0, 1975.5], [1017.5, 1987.5]])
    op, sigma, full = dtm.interpolate(m, q, method, full=True)
    rng = np.random.default_rng(5)
    c_nodes = _node_cov(m.grid, 0.4, 12.0)
    draws = h.ravel() + rng.multivariate_normal(np.zeros(rows * cols), c_nodes, size=20000)
    h_mc = draws @ op.jacobian.toarray().T  # the same linear operator ...
    np.testing.assert_allclose(sigma, h_mc.std(axis=0), rtol=0.03)
    np.testing.assert_allclose(full, np.cov(h_mc.T), rtol=0.06, atol=1e-3)
    if method == "bilinear":  # ... and it is scipy's bilinear interpolation
        xs = m.grid.x0 + np.arange(cols) * cell
        ys = m.grid.y0 + np.arange(rows) * -cell
        f = RegularGridInterpolator((ys[::-1], xs), draws[:50].reshape(50, rows, cols)[:, ::-1]
                                    .transpose(1, 2, 0))
        np.testing.assert_allclose(f(q[:, ::-1]).T, h_mc[:50], atol=1e-9)


def test_bicubic_reproduces_a_quadratic_surface_and_keys_weights_sum_to_one():
    w, dw = dtm.keys_weights(np.linspace(0, 1, 11))
    np.testing.assert_allclose(w.sum(axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(dw.sum(axis=-1), 0.0, atol=1e-12)
    c, r = np.meshgrid(np.arange(10), np.arange(10))
    x, y = c * 2.0, -r * 2.0

    def quad(x, y):
        return 3 + 0.5 * x - 0.2 * y + 0.01 * x * x + 0.02 * x * y - 0.03 * y * y

    m = dtm.dem_model(quad(x, y), (-1.0, 2.0, 0.0, 1.0, 0.0, -2.0), node_sigma=0.1)
    q = np.random.default_rng(0).uniform(3, 14, (50, 2)) * [1, -1]
    op = dtm.interpolation_operator(m, q, "bicubic")
    np.testing.assert_allclose(op.h, quad(q[:, 0], q[:, 1]), atol=1e-9)
    gx = 0.5 + 0.02 * q[:, 0] + 0.02 * q[:, 1]
    np.testing.assert_allclose(op.gradient[:, 0], gx, atol=1e-9)


def test_independent_nodes_give_the_known_bilinear_factor():
    # sigma^2 sum w^2 = sigma^2 / 4 at a cell centre, sigma^2 at a node
    m = dtm.dem_model(np.zeros((3, 3)), (0.0, 1.0, 0.0, 3.0, 0.0, -1.0), node_sigma=0.2)
    _, s = dtm.interpolate(m, [[1.0, 1.0], [1.5, 1.5]], "bilinear")
    np.testing.assert_allclose(s, [0.2 / 2, 0.2], rtol=1e-12)


def test_points_bilinear_equals_dtm_bilinear_of_the_tin_nodes():
    """Nodes from the TIN, bilinear in between: the existing dtm_bilinear on one cell."""
    xyz, cov = _points(seed=4)
    m = dtm.points_model(xyz, cov)
    nodes = dtm.NodeGrid(100.0, 110.0, 10.0, 10.0, 2, 2)
    corners = nodes.xy()  # (100,110) (110,110) (100,120) (110,120): h00 h10 h01 h11
    at, _, c_nodes = dtm.interpolate(m, corners, "tin", full=True)
    q = np.array([[103.0, 114.0], [108.0, 111.0]])
    op, sigma, full = dtm.interpolate(m, q, "bilinear", nodes=nodes, full=True)
    ref = dtm_bilinear(at.h, c_nodes, (100.0, 110.0), 10.0, q)
    np.testing.assert_allclose(op.h, ref.h, atol=1e-9)
    np.testing.assert_allclose(full, ref.covariance, rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------- the paper's slope share
@pytest.mark.parametrize("slope, share", [(0.05, 0.0025), (0.25, 0.0625)])
def test_horizontal_error_share_on_a_slope(slope, share):
    """Filin & Doytsher: a planimetric error sigma_xy = sigma moves the height of a cell on
    a slope by tan(a) sigma_xy: 0.0025 sigma^2 at 5 %, 0.0625 sigma^2 at 25 %."""
    heights = np.array([0.0, 10 * slope, 0.0, 10 * slope])
    sigma = 0.3
    res = dtm_bilinear(heights, np.eye(4) * sigma**2, (0, 0), 10.0, (5.0, 5.0),
                       cov_origin=np.eye(2) * sigma**2)
    extra = res.sigma**2 - res.sigma_heights_only**2
    assert extra / sigma**2 == pytest.approx(share, rel=1e-12)
    b = bilinear_coefficients(heights, 10.0)[1]
    assert b == pytest.approx(slope)


# ------------------------------------------------------------------- added terms
def test_sampling_and_terrain_terms():
    assert dtm.sampling_per_mille(0.0) == pytest.approx(0.3e-3)
    assert dtm.sampling_per_mille(0.8) == pytest.approx(1.5e-3)
    assert dtm.sampling_per_mille(0.275) == pytest.approx(0.9e-3)
    assert dtm.sampling_sigma(1000.0, 0.02) == pytest.approx(0.3)
    assert dtm.LI_B == pytest.approx(0.005533854166666667)
    v = dtm.terrain_variance(20.0, 0.1, 400.0)
    assert v == pytest.approx(17 / 3072 * 1.2 * 4.0)
    assert dtm.terrain_variance(20.0, 0.1, np.inf) == pytest.approx(17 / 3072 * 4.0)


def test_mean_wavelength_of_a_sine():
    x = np.arange(0, 1000, 5.0)
    h = np.sin(2 * np.pi * x / 250.0 + 0.3)[None, :] + np.zeros((40, 1))
    w = dtm.mean_wavelength(h, 5.0)
    # the rows cross twice per wavelength (8 times); the columns are constant (no
    # crossing) and count as length: twice the run over all pairs of neighbours
    assert w == pytest.approx(2 * (40 * 199 + 39 * 200) * 5.0 / (40 * 8), rel=1e-9)


@pytest.mark.parametrize("method", ["tin", "bilinear", "bicubic"])
@pytest.mark.slow
def test_le90_coverage_on_a_simulated_terrain(method):
    """Simulated terrain, points with correlated XYZ errors: the true height lies inside
    the LE90 (interpolation covariance + Li's terrain term) in 85-95 % of the cells."""
    inside = []
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        xyz, cov = _points(seed=100 + seed, n=400, extent=500.0, amp=0.3)
        e = (np.linalg.cholesky(cov) @ rng.standard_normal(cov.shape[0])).reshape(-1, 3)
        measured = xyz + e  # XY moved, Z the true position's height plus its error
        p = dtm.dtm_product(dtm.points_model(measured, cov), 10.0, method,
                            bounds=(50, 50, 450, 450))
        err = p.height.ravel() - _terrain(*p.centres().T, 0.3)
        ok = np.isfinite(err)
        inside.append(np.mean(np.abs(err[ok]) <= p.le90.ravel()[ok]))
    assert 0.85 <= np.mean(inside) <= 0.95, np.mean(inside)


# ----------------------------------------------------------------------- products
@pytest.fixture(scope="module")
def product():
    xyz, cov = _points(seed=7, n=250, extent=400.0)
    return dtm.dtm_product(dtm.points_model(xyz, cov), 10.0, "tin", flying_height=800.0)


def test_product_terms_are_added_to_the_variance(product):
    s = product.summary
    assert s["sampling"]["per_mille"] == pytest.approx(
        1e3 * dtm.sampling_per_mille(s["mean_tan_slope"]))
    ok = np.isfinite(product.sigma)
    assert s["sampling"]["sigma"] == pytest.approx(np.median(product.sampling_cells[ok]))
    tot = np.sqrt(product.sigma_interpolation**2 + product.sampling_cells**2
                  + product.terrain_cells**2)
    np.testing.assert_allclose(product.sigma, tot, rtol=1e-12)
    np.testing.assert_allclose(product.le90, 1.6448536 * product.sigma, rtol=1e-6)
    assert s["sigma"]["n"] == int(np.isfinite(product.sigma).sum()) > 1000


def test_contours_lie_on_their_levels_with_sigma_over_slope(product):
    c = dtm.contour_segments(product, 1.0)
    assert len(c.level) > 100
    gt = product.transform
    ys = gt[3] + (np.arange(product.height.shape[0]) + 0.5) * gt[5]
    xs = gt[0] + (np.arange(product.height.shape[1]) + 0.5) * gt[1]
    f = RegularGridInterpolator((ys[::-1], xs), product.height[::-1], bounds_error=False)
    for k in range(2):
        h = f(c.xy[:, k, ::-1])
        ok = np.isfinite(h)
        np.testing.assert_allclose(h[ok], c.level[ok], atol=1e-6)
    free = ~c.capped
    np.testing.assert_allclose(c.sigma_xy[free], (c.sigma_z / c.tan_slope)[free], rtol=1e-12)
    assert np.all(c.sigma_xy[c.capped] == 5 * gt[1])


def test_contour_saddle_cell():
    h = np.array([[0.9, 0.1], [0.1, 0.9]])
    gt = (0.0, 1.0, 0.0, 2.0, 0.0, -1.0)
    m = dtm.dem_model(h, gt, node_sigma=0.1)
    p = dtm.DTMProduct(gt, h, np.full((2, 2), 0.1), np.full((2, 2), 0.1),
                       np.full((2, 2), 0.16), np.ones((2, 2)), 0.0, 0.0, {}, m, "bilinear")
    c = dtm.contour_segments(p, 0.5)
    assert len(c.level) == 2 and np.all(c.level == 0.5)
    # the centre (0.5) is high: each segment cuts off one of the low corners
    low = np.array([[1.5, 1.5], [0.5, 0.5]])  # corners (0, 1) and (1, 0)
    for seg in c.xy:
        d = np.hypot(*(seg[:, None, :] - low[None]).transpose(2, 0, 1))
        assert np.all(d.argmin(axis=1) == d.argmin(axis=1)[0])
        assert np.all(d.min(axis=1) == pytest.approx(0.5))


def test_profile_step_sigma_matches_monte_carlo(product):
    pr = dtm.profile_accuracy(product, [[60.0, 80.0], [200.0, 150.0], [330.0, 120.0]], 15.0)
    assert pr.chainage[-1] == pytest.approx(np.hypot(140, 70) + np.hypot(130, 30))
    op = dtm.interpolation_operator(product.model, pr.xy, "tin")
    rng = np.random.default_rng(9)
    f = op.jacobian.toarray()
    cov_h = f @ product.model.covariance @ f.T
    h = rng.multivariate_normal(pr.h, cov_h, size=20000)
    np.testing.assert_allclose(pr.sigma_step, np.diff(h, axis=1).std(axis=0), rtol=0.03)
    assert pr.sigma_rise == pytest.approx((h[:, -1] - h[:, 0]).std(), rel=0.03)
    # neighbouring samples share points: their difference is far better than sqrt(2) sigma
    assert np.all(pr.sigma_step < pr.sigma_step_no_cov)


def test_volume_of_a_plane_with_independent_nodes():
    gt = (0.0, 2.0, 0.0, 20.0, 0.0, -2.0)
    m = dtm.dem_model(np.full((10, 10), 12.0), gt, node_sigma=0.5)
    p = dtm.dtm_product(m, 2.0, "bilinear", bounds=(1.0, 1.0, 19.0, 19.0))
    poly = [[1.0, 1.0], [19.0, 1.0], [19.0, 19.0], [1.0, 19.0]]
    v = dtm.volume_accuracy(p, poly, 10.0)
    # 9 x 9 cells of 4 m^2, 2 m high, each centred between four independent nodes: the
    # summed weights are 1 for the 8 x 8 inner nodes, 1/2 on the edges, 1/4 at corners
    assert v.cells == 81 and v.area == pytest.approx(324.0)
    assert v.volume == pytest.approx(648.0)
    assert v.sigma == pytest.approx(4.0 * 0.5 * np.sqrt(64 + 32 * 0.25 + 4 * 0.0625))
    # each cell alone: sigma / 2 (mean of 4 nodes); summed as if independent
    assert v.sigma_no_cov == pytest.approx(4.0 * np.sqrt(81 * 0.25**2))
    corr = dtm.dem_model(np.full((10, 10), 12.0), gt, node_sigma=0.5, correlation_length=50.0)
    vc = dtm.volume_accuracy(dtm.dtm_product(corr, 2.0, "bilinear",
                                             bounds=(1.0, 1.0, 19.0, 19.0)), poly, 10.0)
    assert vc.sigma > 3 * vc.sigma_no_cov


def test_points_in_polygon_even_odd():
    poly = [[0, 0], [4, 0], [4, 4], [2, 1], [0, 4]]
    inside = dtm.points_in_polygon([[1, 0.5], [2, 3], [3.5, 3], [5, 1]], poly)
    assert inside.tolist() == [True, False, True, False]


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="at least 3 points"):
        dtm.points_model(np.zeros((2, 3)), np.eye(6))
    with pytest.raises(ValueError, match="interpolation 'spline'"):
        dtm.interpolation_operator(dtm.points_model(*_points(n=10)), [[1, 1]], "spline")
    m = dtm.dem_model(np.zeros((3, 3)), (0, 1, 0, 3, 0, -1), 0.1)
    with pytest.raises(ValueError, match="TIN interpolation needs"):
        dtm.interpolation_operator(m, [[1, 1]], "tin")


def test_contour_buffer_rings_reach_sigma_xy_across(product):
    c = dtm.contour_segments(product, 2.0)
    rings = c.buffer_rings()
    d = c.xy[:, 1] - c.xy[:, 0]
    u = d / np.hypot(*d.T)[:, None]
    # corners 0 and 3 at the start, 1 and 2 at the end: across the segment by sigma_xy
    np.testing.assert_allclose(np.hypot(*(rings[:, 0] - rings[:, 3]).T), 2 * c.sigma_xy[:, 0])
    np.testing.assert_allclose(np.hypot(*(rings[:, 1] - rings[:, 2]).T), 2 * c.sigma_xy[:, 1])
    np.testing.assert_allclose(np.einsum("mi,mi->m", rings[:, 0] - c.xy[:, 0], u), 0.0,
                               atol=1e-9)


@pytest.mark.parametrize("slope, printed", [(0.05, 0.003), (0.25, 0.08)])
def test_paper_slope_examples_with_corner_and_point_planimetric_errors(slope, printed):
    """Filin & Doytsher's slope examples (0.003 sigma^2 at 5 %, 0.08 sigma^2 at 25 %) at
    their printed precision: sigma_xy = sigma at the four corners (independent) and at the
    query point, a cell centre on a plane: (1 + sum w_i^2) tan^2 a = 1.25 tan^2 a."""
    heights = np.array([0.0, 10 * slope, 0.0, 10 * slope])
    s2 = 0.3**2
    res = dtm_bilinear(heights, np.eye(4) * s2, (0, 0), 10.0, (5.0, 5.0),
                       cov_point=np.eye(2) * s2, cov_corners_xy=np.eye(2) * s2)
    extra = (res.sigma**2 - res.sigma_heights_only**2) / s2
    assert extra == pytest.approx(1.25 * slope**2, rel=1e-12)
    digits = 3 if slope < 0.1 else 2  # the paper prints one significant figure
    assert round(extra, digits) == printed


def test_corner_planimetric_errors_match_monte_carlo():
    """Corners sampled off their nominal positions on a sloped bilinear surface."""
    def surface(x, y):
        return 2.0 + 0.2 * x - 0.1 * y + 0.004 * x * y

    cell = 10.0
    nodes = np.array([[0.0, 0.0], [cell, 0.0], [0.0, cell], [cell, cell]])
    q = np.array([[2.0, 3.0], [7.5, 6.0]])
    cov_c = np.array([[0.09, 0.02], [0.02, 0.04]])
    res = dtm_bilinear(surface(*nodes.T), np.zeros((4, 4)), (0, 0), cell, q,
                       cov_corners_xy=cov_c)
    rng = np.random.default_rng(11)
    e = rng.multivariate_normal([0, 0], cov_c, size=(40000, 4))
    h_corners = surface(nodes[:, 0] + e[..., 0], nodes[:, 1] + e[..., 1])
    h_mc = h_corners @ res.jacobian[:, :4].T
    np.testing.assert_allclose(res.covariance, np.cov(h_mc.T), rtol=0.04, atol=1e-5)
    assert res.sigma_heights_only == pytest.approx([0.0, 0.0])


def _two_slopes(x, y):
    """Flat (1 %) west of x = 300, steep and rough (35 % and waves) east of it."""
    east = np.clip((x - 300.0) / 20.0, 0.0, 1.0)
    return 100.0 + 0.01 * x + east * (0.35 * (x - 300.0) + 6.0 * np.sin(2 * np.pi * y / 90.0))


def test_local_terms_follow_the_slope_and_area_terms_do_not():
    rng = np.random.default_rng(21)
    xy = rng.uniform(0, 600, (700, 2))
    xyz = np.column_stack([xy, _two_slopes(*xy.T)])
    m = dtm.points_model(xyz, np.eye(3 * len(xyz)) * 0.01)
    local = dtm.dtm_product(m, 10.0, "tin", flying_height=1000.0, bounds=(20, 20, 580, 580))
    area = dtm.dtm_product(m, 10.0, "tin", flying_height=1000.0, bounds=(20, 20, 580, 580),
                           terms="area")
    x = local.centres()[:, 0].reshape(local.height.shape)
    west, east = x < 200, x > 400
    # local: 0.3 per mille of H (0.30 m) on the flat part, much more on the steep one
    assert np.nanmedian(local.sampling_cells[west]) == pytest.approx(0.30, abs=0.01)
    assert np.nanmedian(local.sampling_cells[east]) > 0.5
    assert np.nanmedian(local.terrain_cells[east]) > 3 * np.nanmedian(local.terrain_cells[west])
    # area: one value everywhere, the mean slope's
    one = area.sampling_cells[np.isfinite(area.sigma)]
    assert np.ptp(one) == 0.0
    assert one[0] == pytest.approx(1000.0 * dtm.sampling_per_mille(area.summary["mean_tan_slope"]))
    with pytest.raises(ValueError, match="terms 'cells'"):
        dtm.dtm_product(m, 10.0, "tin", terms="cells")


def test_local_mean_slope_averages_over_one_wavelength_and_skips_nan():
    t = np.zeros((21, 21))
    t[:, 11:] = 0.4
    t[0, 0] = np.nan
    loc = dtm.local_mean_slope(t, 10.0, 50.0)  # 5 x 5 cells
    assert loc[10, 2] == 0.0 and loc[10, 18] == pytest.approx(0.4)
    assert loc[10, 10] == pytest.approx(0.4 * 2 / 5)  # two of five columns are steep
    assert np.isnan(loc[0, 0]) and np.isfinite(loc[0, 1])
