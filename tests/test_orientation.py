"""Tests of vectoradjust.adjust.orientation: relative, absolute and two-step orientation.

Truth: B. Dewitt's published worked examples (relor.c, 3DCONF.c sample data), finite
differences, synthetic data generated with known parameters, an independent
Gauss-Markov formulation (scipy.optimize.least_squares) and Monte Carlo.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from vectoradjust.adjust.orientation import (
    conformal3d,
    relative_orientation,
    rotation_matrix_partials,
    two_step,
)
from vectoradjust.errors import ControlError, MeasurementError, VectorAdjustError
from vectoradjust.sensor.collinearity import project, rotation_matrix

DATA = Path(__file__).resolve().parent / "data" / "dewitt"  # B. Dewitt's public-domain samples


def _read_relor():
    tok = (DATA / "relor.dat").read_text().split()
    f = float(tok[0])
    rows = np.array(tok[1:], dtype=object).reshape(-1, 5)
    return f, rows[:, 0], rows[:, 1:3].astype(float), rows[:, 3:5].astype(float)


def _read_3dconf():
    blocks = (DATA / "3dconf.dat").read_text().split("#")
    b1 = np.array(blocks[0].split(), dtype=object).reshape(-1, 7)
    b2 = np.array(blocks[1].split(), dtype=object).reshape(-1, 4)
    return b1[:, 1:4].astype(float), b1[:, 4:7].astype(float), b2[:, 1:4].astype(float)


needs_data = pytest.mark.skipif(not (DATA / "relor.dat").exists(), reason="Dewitt data missing")


# ----------------------------------------------------------------------------- helpers
def test_rotation_matrix_partials_match_finite_differences():
    ang = np.array([0.3, -0.2, 1.1])
    d = rotation_matrix_partials(*ang)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (rotation_matrix(*(ang + e)) - rotation_matrix(*(ang - e))) / (2 * h)
        np.testing.assert_allclose(d[k], fd, atol=1e-9)


# ------------------------------------------------------------------ relative orientation
@needs_data
@pytest.mark.parametrize("method", ["collinearity", "coplanarity"])
def test_relor_reproduces_dewitt(method):
    f, names, lxy, rxy = _read_relor()
    ro = relative_orientation(lxy, rxy, f, method=method)
    deg = np.degrees(ro.params[:3])
    assert np.round(deg, 4).tolist() == [2.4077, 0.5550, -0.2053]
    assert round(ro.eo_right[0], 4) == 91.9825
    assert round(ro.eo_right[1], 4) == -1.7187
    assert round(ro.eo_right[2], 4) == 148.3025
    assert ro.dof == 1
    assert round(ro.s0, 4) == 0.0045
    assert np.round(ro.model_xyz[0], 4).tolist() == [-4.8433, 1.9618, 1.0824]
    assert np.round(ro.model_xyz[-1], 4).tolist() == [89.3199, -85.9670, -1.2378]
    # the left photo is fixed at (0, 0, f) as in relor.c
    np.testing.assert_array_equal(ro.eo_left, [0, 0, f, 0, 0, 0])


@needs_data
def test_relor_collinearity_and_coplanarity_agree():
    f, _, lxy, rxy = _read_relor()
    a = relative_orientation(lxy, rxy, f, method="collinearity")
    b = relative_orientation(lxy, rxy, f, method="coplanarity")
    np.testing.assert_allclose(a.params, b.params, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.model_xyz, b.model_xyz, atol=1e-9)
    np.testing.assert_allclose(a.residuals, b.residuals, atol=1e-10)
    np.testing.assert_allclose(a.cov_params, b.cov_params, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(a.cov_model, b.cov_model, rtol=1e-6,
                               atol=1e-9 * np.abs(a.cov_model).max())


def test_relor_formulations_agree_with_unequal_weights():
    f, eo_l, eo_r, pts, lxy, rxy = _synthetic_pair(n=10, seed=6)
    rng = np.random.default_rng(8)
    sig = rng.uniform(0.003, 0.012, (10, 4))
    obs = np.hstack([lxy, rxy]) + rng.normal(0, sig)
    a = relative_orientation(obs[:, :2], obs[:, 2:], f, sigma=sig, a_posteriori=False)
    b = relative_orientation(obs[:, :2], obs[:, 2:], f, sigma=sig, a_posteriori=False,
                             method="coplanarity")
    np.testing.assert_allclose(a.params, b.params, atol=1e-10)
    np.testing.assert_allclose(a.residuals, b.residuals, atol=1e-10)
    assert a.s0 == pytest.approx(b.s0, rel=1e-8)
    np.testing.assert_allclose(a.cov_model, b.cov_model, rtol=1e-5,
                               atol=1e-8 * np.abs(a.cov_model).max())
    # new points intersected from the oriented pair
    from vectoradjust.adjust.orientation import model_intersection

    new = model_intersection(a, obs[:3, :2], obs[:3, 2:], f, sigma=sig[:3])
    np.testing.assert_allclose(new, a.model_xyz[:3], atol=1e-9)


def _synthetic_pair(n=12, seed=1, f=152.4):
    """Model-frame pair with known right-photo parameters and exact photo coordinates."""
    rng = np.random.default_rng(seed)
    bx = 90.0
    eo_l = np.array([0.0, 0.0, f, 0.0, 0.0, 0.0])
    eo_r = np.array([bx, 1.3, f - 2.1, np.radians(1.7), np.radians(-0.9), np.radians(0.6)])
    pts = np.column_stack([rng.uniform(-5, 95, n), rng.uniform(-90, 90, n), rng.uniform(-4, 4, n)])
    return f, eo_l, eo_r, pts, project(eo_l, pts, f), project(eo_r, pts, f)


@pytest.mark.parametrize("method", ["collinearity", "coplanarity"])
def test_relor_recovers_known_parameters(method):
    f, eo_l, eo_r, pts, lxy, rxy = _synthetic_pair()
    ro = relative_orientation(lxy, rxy, f, bx=eo_r[0], method=method)
    np.testing.assert_allclose(ro.eo_right, eo_r, atol=1e-9)
    np.testing.assert_allclose(ro.model_xyz, pts, atol=1e-8)
    np.testing.assert_allclose(ro.vertical_parallax, 0.0, atol=1e-10)
    assert ro.s0 < 1e-9


def test_vertical_parallax_is_y_difference_for_normal_case():
    # right photo only shifted along the base: py must be yL - yR for any coordinates
    f, _, _, _, lxy, rxy = _synthetic_pair()
    rng = np.random.default_rng(5)
    rxy2 = rxy + rng.normal(0, 0.01, rxy.shape)
    from vectoradjust.adjust.orientation import _vertical_parallax

    eo_l = np.array([0.0, 0.0, f, 0, 0, 0])
    eo_r = np.array([90.0, 0.0, f, 0, 0, 0])
    py = _vertical_parallax(np.hstack([lxy, rxy2]), eo_l, eo_r, f)
    np.testing.assert_allclose(py, lxy[:, 1] - rxy2[:, 1], atol=1e-12)


def _ro_outputs(obs, f, bx, method):
    ro = relative_orientation(obs[:, :2], obs[:, 2:], f, bx=bx, sigma=0.005, method=method,
                              a_posteriori=False, tol=1e-14)
    return np.concatenate([ro.params, ro.model_xyz.ravel()])


@pytest.mark.parametrize("method", ["collinearity", "coplanarity"])
def test_relor_covariance_equals_finite_difference_propagation(method):
    f, eo_l, eo_r, pts, lxy, rxy = _synthetic_pair(n=8)
    rng = np.random.default_rng(3)
    obs = np.hstack([lxy, rxy]) + rng.normal(0, 0.004, (8, 4))
    ro = relative_orientation(obs[:, :2], obs[:, 2:], f, bx=90.0, sigma=0.005, method=method,
                              a_posteriori=False)
    h = 1e-6
    base = obs.ravel()
    cols = []
    for i in range(base.size):
        e = np.zeros(base.size)
        e[i] = h
        cols.append((_ro_outputs((base + e).reshape(-1, 4), f, 90.0, method)
                     - _ro_outputs((base - e).reshape(-1, 4), f, 90.0, method)) / (2 * h))
    jac = np.column_stack(cols)
    cov_fd = jac @ (0.005**2 * np.eye(base.size)) @ jac.T
    np.testing.assert_allclose(ro.cov_params, cov_fd[:5, :5], rtol=2e-3,
                               atol=1e-4 * np.abs(cov_fd[:5, :5]).max())
    np.testing.assert_allclose(ro.cov_model, cov_fd[5:, 5:], rtol=2e-3,
                               atol=1e-4 * np.abs(cov_fd[5:, 5:]).max())


def test_relor_model_covariance_monte_carlo():
    f, eo_l, eo_r, pts, lxy, rxy = _synthetic_pair(n=7, seed=4)
    sigma = 0.01
    ro = relative_orientation(lxy, rxy, f, bx=90.0, sigma=sigma, a_posteriori=False)
    rng = np.random.default_rng(11)
    draws = []
    for _ in range(1500):
        noise = rng.normal(0, sigma, (7, 4))
        r = relative_orientation(lxy + noise[:, :2], rxy + noise[:, 2:], f, bx=90.0,
                                 method="coplanarity")
        draws.append(r.model_xyz.ravel())
    emp = np.cov(np.array(draws).T)
    sd_emp = np.sqrt(np.diag(emp))
    sd = np.sqrt(np.diag(ro.cov_model))
    # 1500 draws: standard error of a standard deviation ~1.8 %
    np.testing.assert_allclose(sd_emp, sd, rtol=0.08)
    corr = ro.cov_model / np.outer(sd, sd)
    corr_emp = emp / np.outer(sd_emp, sd_emp)
    assert np.max(np.abs(corr - corr_emp)) < 0.1


def test_relor_rejects_too_few_points_and_bad_shapes():
    f, _, _, _, lxy, rxy = _synthetic_pair()
    with pytest.raises(MeasurementError, match="at least 5 points"):
        relative_orientation(lxy[:4], rxy[:4], f)
    with pytest.raises(MeasurementError,
                       match=r"coordinates must both be \(n, 2\) arrays of the same"):
        relative_orientation(lxy, rxy[:-1], f)
    with pytest.raises(MeasurementError, match="image sigmas must be positive and finite"):
        relative_orientation(lxy, rxy, f, sigma=-1.0)
    with pytest.raises(MeasurementError, match=r"air base \(mean x-parallax\) is zero"):
        relative_orientation(lxy, lxy, f)  # no parallax: zero base


# ----------------------------------------------------------------- 3D conformal (3DCONF)
@needs_data
def test_3dconf_reproduces_dewitt():
    x, X, _ = _read_3dconf()
    c = conformal3d(x, X)
    assert c.method == "ols"
    assert round(c.scale, 5) == 0.99674
    assert np.round(c.angles_deg, 4).tolist() == [0.0540, -0.1318, -0.0002]
    assert np.round(c.translation, 3).tolist() == [219.620, 3.687, -0.060]
    assert round(c.s0, 5) == 0.24755
    assert c.dof == 11
    # residuals are adjusted - observed: the model reproduces the ground coordinates
    np.testing.assert_allclose(c.transform(x, full=False)[0], X + c.residuals_ground,
                               atol=1e-9)


@needs_data
def test_3dconf_transform_covariance_vs_finite_differences():
    x, X, new = _read_3dconf()
    c = conformal3d(x, X)
    cov_pts = np.diag(np.tile([0.02, 0.03, 0.05], len(new)) ** 2)
    xyz, cov = c.transform(new, cov_pts)
    from vectoradjust.adjust.orientation import _conf_apply

    theta = np.concatenate([c.params, new.ravel()])
    h = 1e-7
    jac = np.empty((xyz.size, theta.size))
    for i in range(theta.size):
        e = np.zeros(theta.size)
        e[i] = h * max(1.0, abs(theta[i]))
        fp = _conf_apply((theta + e)[:7], (theta + e)[7:].reshape(-1, 3)).ravel()
        fm = _conf_apply((theta - e)[:7], (theta - e)[7:].reshape(-1, 3)).ravel()
        jac[:, i] = (fp - fm) / (2 * e[i])
    sig = np.zeros((theta.size, theta.size))
    sig[:7, :7] = c.cov_params
    sig[7:, 7:] = cov_pts
    np.testing.assert_allclose(cov, jac @ sig @ jac.T, rtol=1e-5, atol=1e-7 * np.abs(cov).max())
    _, blocks = c.transform(new, cov_pts, full=False)
    idx = np.arange(len(new))
    np.testing.assert_allclose(blocks, cov.reshape(len(new), 3, len(new), 3)[idx, :, idx, :])


def _similarity_case(seed=2, n=7, noise=1.0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-100, 100, (n, 3))
    params = np.array([3.7, np.radians(4.0), np.radians(-7.0), np.radians(35.0), 5000.0, 2000.0,
                       120.0])
    from vectoradjust.adjust.orientation import _conf_apply

    X = _conf_apply(params, x)
    cm = rng.uniform(0.05, 0.2, (n, 3))
    cg = rng.uniform(0.2, 0.6, (n, 3))
    return x + noise * rng.normal(0, cm), X + noise * rng.normal(0, cg), cm, cg, params


def test_gauss_helmert_equals_independent_gauss_markov():
    x, X, cm, cg, _ = _similarity_case()
    c = conformal3d(x, X, cov_model=cm, cov_ground=cg)
    assert c.method == "gauss-helmert"
    from vectoradjust.adjust.orientation import _conf_apply

    n = len(x)

    def resid(theta):  # unknowns: 7 params and the true model coordinates
        xt = theta[7:].reshape(n, 3)
        return np.concatenate([((x - xt) / cm).ravel(),
                               ((X - _conf_apply(theta[:7], xt)) / cg).ravel()])

    sol = least_squares(resid, np.concatenate([c.params * 1.0001, x.ravel()]), xtol=1e-15,
                        ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(sol.x[:7], c.params, rtol=1e-8, atol=1e-9)
    cov_gm = np.linalg.inv(sol.jac.T @ sol.jac)[:7, :7]  # jac by finite differences
    sd = np.sqrt(np.diag(cov_gm))
    np.testing.assert_allclose(c.sigma_params, sd, rtol=1e-5)
    np.testing.assert_allclose(c.cov_params / np.outer(sd, sd), cov_gm / np.outer(sd, sd),
                               atol=1e-6)
    vtpv = 2 * sol.cost
    assert c.s0 == pytest.approx(np.sqrt(vtpv / (3 * n - 7)), rel=1e-8)
    # residuals of both coordinate sets reproduce the adjusted (true) model coordinates
    np.testing.assert_allclose(x + c.residuals_model, sol.x[7:].reshape(n, 3), atol=1e-7)


def test_gauss_helmert_without_model_errors_is_ols():
    x, X, _, cg, _ = _similarity_case(seed=3)
    gh = conformal3d(x, X, cov_model=np.zeros((len(x), 3)), cov_ground=cg)
    ols = conformal3d(x, X, cov_ground=cg, method="ols")
    np.testing.assert_allclose(gh.params, ols.params, rtol=1e-12, atol=1e-10)
    np.testing.assert_allclose(gh.cov_params, ols.cov_params, rtol=1e-9)
    assert gh.s0 == pytest.approx(ols.s0, rel=1e-9)


def test_conformal_sensitivity_matches_finite_differences():
    # (nearly) consistent data: the linearised sensitivity is then the exact derivative
    x, X, cm, cg, _ = _similarity_case(seed=4, noise=1e-4)
    c = conformal3d(x, X, cov_model=cm, cov_ground=cg, tol=1e-14)
    obs = np.concatenate([x.ravel(), X.ravel()])
    n = len(x)
    h = 1e-6
    jac = np.empty((7, obs.size))
    for i in range(obs.size):
        e = np.zeros(obs.size)
        e[i] = h
        p = conformal3d((obs + e)[: 3 * n].reshape(n, 3), (obs + e)[3 * n:].reshape(n, 3),
                        cov_model=cm, cov_ground=cg, tol=1e-14).params
        m = conformal3d((obs - e)[: 3 * n].reshape(n, 3), (obs - e)[3 * n:].reshape(n, 3),
                        cov_model=cm, cov_ground=cg, tol=1e-14).params
        jac[:, i] = (p - m) / (2 * h)
    np.testing.assert_allclose(c.sensitivity, jac, rtol=2e-3, atol=1e-6 * np.abs(jac).max())


def test_conformal_rejects_bad_control():
    x, X, *_ = _similarity_case()
    with pytest.raises(ControlError, match="at least 3"):
        conformal3d(x[:2], X[:2])
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(ControlError, match="collinear"):
        conformal3d(line, line * 2)
    with pytest.raises(ControlError, match=r"coordinates must both be \(n, 3\) arrays of the same"):
        conformal3d(x, X[:-1])


# ------------------------------------------------------------------------------ two step
def _ground_pair(seed=7, n=16, offset=(0.0, 0.0)):
    """A vertical stereo pair at 1:4000 over rough terrain, with exact photo coords."""
    rng = np.random.default_rng(seed)
    f = 152.4
    o = np.array([offset[0], offset[1], 0.0])
    eo_l = np.array([1000.0, 2000.0, 700.0, np.radians(0.8), np.radians(-0.5),
                     np.radians(1.5)])
    eo_r = np.array([1368.0, 2006.0, 703.0, np.radians(-0.4), np.radians(0.9),
                     np.radians(1.2)])
    eo_l[:3] += o
    eo_r[:3] += o
    xyz = np.column_stack([rng.uniform(1040, 1330, n), rng.uniform(1700, 2300, n),
                           rng.uniform(80, 110, n)]) + o
    ids = np.array([f"p{i}" for i in range(n)])
    return f, eo_l, eo_r, xyz, ids, project(eo_l, xyz, f), project(eo_r, xyz, f)


def test_two_step_recovers_ground_coordinates():
    f, eo_l, eo_r, xyz, ids, lxy, rxy = _ground_pair()
    ctrl = [0, 3, 7, 11, 14]
    res = two_step(lxy, rxy, ids, f, ids[ctrl], xyz[ctrl], 0.05, 0.005)
    np.testing.assert_allclose(res.ground_xyz, xyz, atol=1e-6)
    assert res.cov.shape == (3 * len(ids),) * 2
    assert np.all(np.linalg.eigvalsh(res.cov) > 0)
    assert res.cov_points.shape == (len(ids), 3, 3)


def test_two_step_with_utm_sized_coordinates():
    f, eo_l, eo_r, xyz, ids, lxy, rxy = _ground_pair(offset=(500000.0, 4400000.0))
    ctrl = [1, 4, 9, 12]
    res = two_step(lxy, rxy, ids, f, ids[ctrl], xyz[ctrl], 0.05, 0.005, method="coplanarity")
    np.testing.assert_allclose(res.ground_xyz, xyz, rtol=0, atol=1e-5)
    ref = two_step(*_ground_pair()[5:], ids, f, ids[ctrl], _ground_pair()[3][ctrl], 0.05, 0.005)
    np.testing.assert_allclose(res.cov, ref.cov, rtol=1e-5, atol=1e-9)


def test_two_step_covariance_equals_finite_difference_propagation():
    f, eo_l, eo_r, xyz, ids, lxy, rxy = _ground_pair(n=9, seed=8)
    ctrl = [0, 2, 5, 8]
    sig_img, sig_ctrl = 0.006, np.array([0.05, 0.05, 0.08])
    res = two_step(lxy, rxy, ids, f, ids[ctrl], xyz[ctrl], sig_ctrl, sig_img)
    n, k = len(ids), len(ctrl)

    def run(theta):
        obs = theta[: 4 * n].reshape(n, 4)
        cx = theta[4 * n:].reshape(k, 3)
        return two_step(obs[:, :2], obs[:, 2:], ids, f, ids[ctrl], cx, sig_ctrl,
                        sig_img).ground_xyz.ravel()

    theta = np.concatenate([np.hstack([lxy, rxy]).ravel(), xyz[ctrl].ravel()])
    steps = np.concatenate([np.full(4 * n, 1e-6), np.full(3 * k, 1e-5)])
    jac = np.empty((3 * n, theta.size))
    for i in range(theta.size):
        e = np.zeros(theta.size)
        e[i] = steps[i]
        jac[:, i] = (run(theta + e) - run(theta - e)) / (2 * steps[i])
    sig = np.diag(np.concatenate([np.full(4 * n, sig_img**2), np.tile(sig_ctrl**2, k)]))
    cov_fd = jac @ sig @ jac.T
    np.testing.assert_allclose(res.cov, cov_fd, rtol=1e-3, atol=1e-5 * np.abs(cov_fd).max())
    # the textbook formula ignores the correlation of the parameters with the model
    # coordinates of the control points; it differs measurably
    assert np.max(np.abs(res.cov_classical - cov_fd)) > 0.05 * np.abs(cov_fd).max()


def test_two_step_reports_missing_control():
    f, eo_l, eo_r, xyz, ids, lxy, rxy = _ground_pair()
    with pytest.raises(ControlError, match="nope"):
        two_step(lxy, rxy, ids, f, ["p0", "p1", "nope"], xyz[:3], 0.05, 0.005)
    with pytest.raises(ControlError, match="at least 3"):
        two_step(lxy, rxy, ids, f, ["p0", "p1"], xyz[:2], 0.05, 0.005)
    dup = ids.copy()
    dup[1] = dup[0]
    with pytest.raises(MeasurementError, match="duplicate"):
        two_step(lxy, rxy, dup, f, ids[2:5], xyz[2:5], 0.05, 0.005)
    assert issubclass(ControlError, VectorAdjustError)
