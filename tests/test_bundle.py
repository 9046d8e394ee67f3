"""The Schur-complement bundle adjustment against a dense textbook solution."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.adjust.bundle import BundleProblem, adjust, intersect, inv3x3
from vectoradjust.pipeline import run
from vectoradjust.sensor.collinearity import partials, project
from vectoradjust.simulate import make_scenario


def _small_problem(seed=3, n_images=3):
    sc = make_scenario(seed, n_images=n_images, grid=(2, 2), databases=("OSM",), n_tie=6)
    data = sc.to_project_data()  # the plain bundle: no database offset (test_offsets.py)
    # covariances scaled by sigma0^2 (the contract's a-posteriori), compared with the dense
    # inverse; the default "auto" scale is tested in test_offsets.py
    data = replace(data, settings=replace(data.settings, covariance_scale="a-posteriori"))
    r = run(replace(data, vectors=[(replace(s, offset="none"), lay) for s, lay in data.vectors]))
    return r.problem, r.result, sc


def _dense(prob: BundleProblem, eo, xyz):
    """A, P and misclosure of the full linearised model, built observation by observation."""
    n, m = prob.n_images, prob.n_points
    u = 6 * n + 3 * m
    k = len(prob.obs_point)
    a_eo, a_pt = partials(eo[prob.obs_image], xyz[prob.obs_point], prob.focal_length)
    rows = []
    for i in range(k):
        for c in range(2):
            row = np.zeros(u)
            row[6 * prob.obs_image[i]: 6 * prob.obs_image[i] + 6] = a_eo[i, c]
            row[6 * n + 3 * prob.obs_point[i]: 6 * n + 3 * prob.obs_point[i] + 3] = a_pt[i, c]
            rows.append(row)
    p_diag = list((1.0 / prob.obs_sigma**2).ravel())
    a = np.array(rows)
    p = np.diag(p_diag)
    blocks = [(a, p)]
    # point priors as observations of the point coordinates
    has = prob.has_prior
    ap = np.zeros((3 * has.sum(), u))
    pp = np.zeros((3 * has.sum(), 3 * has.sum()))
    for r_, j in enumerate(np.flatnonzero(has)):
        ap[3 * r_: 3 * r_ + 3, 6 * n + 3 * j: 6 * n + 3 * j + 3] = np.eye(3)
        pp[3 * r_: 3 * r_ + 3, 3 * r_: 3 * r_ + 3] = prob.prior_weight[j]
    blocks.append((ap, pp))
    we = prob.eo_weight.ravel()
    sel = np.flatnonzero(we > 0)
    ae = np.zeros((len(sel), u))
    ae[np.arange(len(sel)), sel] = 1.0
    blocks.append((ae, np.diag(we[sel])))
    big_a = np.vstack([b[0] for b in blocks])
    big_p = np.zeros((big_a.shape[0],) * 2)
    o = 0
    for b in blocks:
        s = b[0].shape[0]
        big_p[o:o + s, o:o + s] = b[1]
        o += s
    return big_a, big_p


def test_covariances_equal_the_dense_inverse():
    prob, res, _ = _small_problem()
    a, p = _dense(prob, res.eo, res.xyz)
    n_mat = a.T @ p @ a
    q = np.linalg.inv(n_mat)
    s0 = res.sigma0_squared
    n = prob.n_images
    for i in range(n):
        assert np.allclose(res.eo_cov[i], s0 * q[6 * i:6 * i + 6, 6 * i:6 * i + 6], rtol=1e-6,
                           atol=1e-14)
    for j in range(prob.n_points):
        o = 6 * n + 3 * j
        assert np.allclose(res.point_cov[j], s0 * q[o:o + 3, o:o + 3], rtol=1e-6, atol=1e-12)
    pts = [0, 5, prob.n_points - 1]
    joint = res.joint_covariance(pts)
    idx = np.concatenate([6 * n + 3 * j + np.arange(3) for j in pts])
    assert np.allclose(joint, s0 * q[np.ix_(idx, idx)], rtol=1e-6, atol=1e-12)


def test_converged_solution_satisfies_the_normal_equations():
    """At the solution A'P(l - f(x)) = 0 for the dense model (first-order optimality)."""
    prob, res, _ = _small_problem()
    a, p = _dense(prob, res.eo, res.xyz)
    ell = -res.v_image.ravel()
    has = prob.has_prior
    lp = -(res.xyz - prob.prior_xyz)[has].ravel()
    we = prob.eo_weight.ravel()
    le = -(res.eo - prob.eo0).ravel()[we > 0]
    g = a.T @ p @ np.concatenate([ell, lp, le])
    n_mat = a.T @ p @ a
    step = np.linalg.solve(n_mat, g)
    assert np.abs(step[: 6 * prob.n_images].reshape(-1, 6)[:, :3]).max() < 1e-5
    assert np.abs(step[6 * prob.n_images:]).max() < 1e-5
    # the residuals are those of the collinearity equations at the solution
    pred = project(res.eo[prob.obs_image], res.xyz[prob.obs_point], prob.focal_length,
                   prob.principal_point)
    assert np.allclose(res.v_image, pred - prob.obs_xy)


def test_free_exterior_orientation_and_a_strip_of_four_images():
    sc = make_scenario(5, n_images=4, databases=("OSM",), sigma_position=None,
                       sigma_attitude=None)
    data = sc.to_project_data()
    assert all(im.sigma_position is None for im in data.images)
    r = run(data)
    assert r.summary["observations"]["eo_priors"] == 0
    true = sc.true_eo
    assert np.abs(r.result.eo[:, :3] - true[:, :3]).max() < 0.5
    assert np.degrees(np.abs(r.result.eo[:, 3:] - true[:, 3:])).max() < 0.01
    assert r.summary["degrees_of_freedom"] > 0 and r.result.converged


def test_check_point_intersection_and_its_covariance_by_monte_carlo():
    """Intersected check points: covariance = image noise + propagated EO covariance."""
    prob, res, sc = _small_problem(seed=7, n_images=2)
    rng = np.random.default_rng(0)
    eo_cov_full = res.variance_factor * res.s_inv
    xyz_true = np.array([[sc.center[0] + 20.0, sc.center[1] - 35.0, 190.0]])
    obs_img = np.array([0, 1])
    obs_pt = np.array([0, 0])
    sigma = np.full((2, 2), 0.015)
    ideal = project(res.eo[obs_img], xyz_true[obs_pt], prob.focal_length)
    _, cov = intersect(res.eo, obs_pt, obs_img, ideal, sigma, 1, prob.focal_length,
                       eo_cov_full=eo_cov_full, variance_factor=1.0)
    draws = []
    chol = np.linalg.cholesky(eo_cov_full + 1e-18 * np.eye(len(eo_cov_full)))
    for _ in range(3000):
        eo_d = res.eo + (chol @ rng.standard_normal(len(eo_cov_full))).reshape(-1, 6)
        xy = ideal + rng.normal(0, 0.015, ideal.shape)
        x, _ = intersect(eo_d, obs_pt, obs_img, xy, sigma, 1, prob.focal_length)
        draws.append(x[0])
    emp = np.cov(np.array(draws).T)
    # the EO in the draws is perturbed around the estimate, the same linearisation
    assert np.allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(cov[0])), rtol=0.06)


def test_inv3x3_matches_numpy():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(500, 3, 3))
    a = a @ np.transpose(a, (0, 2, 1)) + np.eye(3)
    assert np.allclose(inv3x3(a), np.linalg.inv(a))


def test_singular_datum_is_reported():
    """No control, no priors at all: the datum is undefined."""
    prob, _, _ = _small_problem()
    free = BundleProblem(prob.focal_length, prob.principal_point, prob.eo0,
                         np.full_like(prob.eo_sigma, np.inf), prob.xyz0, prob.prior_xyz,
                         np.zeros_like(prob.prior_weight), prob.obs_point, prob.obs_image,
                         prob.obs_xy, prob.obs_sigma)
    from vectoradjust.errors import SingularityError

    with pytest.raises(SingularityError, match="datum"):
        adjust(free)
