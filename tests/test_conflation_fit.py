"""The conflation's covariance fit in closed form (issue 32): the leave-one-out score's
analytic gradient against central differences, the nugget profile from one
eigendecomposition against the score evaluated nugget by nugget, the box-constrained
quasi-Newton search against known minima, and the fit against an independent
derivative-free search of the same score.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.accuracy.conflation import (
    CovarianceModel,
    _fit_white,
    _loo_score,
    _loo_score_grad,
    _loo_setup,
    _nugget_scores,
    _projected_bfgs,
    fit_covariance,
)


def _points(seed: int, n: int = 120, shared: bool = False):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 500, (n, 2))
    resid = rng.normal(size=(n, 2))
    noise = rng.uniform(0.05, 0.2, n)
    corr = rng.normal(0, 0.2, (n, 3)) if shared else None
    return xy, resid, noise, corr


@pytest.mark.parametrize("kind", ["exponential", "gaussian"])
@pytest.mark.parametrize("shared", [False, True])
def test_the_gradient_is_that_of_the_score(kind, shared):
    xy, resid, noise, corr = _points(1, shared=shared)
    setup = _loo_setup(xy, 12, 1000, corr=corr)
    for theta in ([0.3, 1.2, 60.0], [0.5, 4.0, 150.0], [1.0, 0.2, 20.0]):
        x = np.log(theta)
        value, grad = _loo_score_grad(x, kind, setup, resid, noise)
        assert np.isfinite(value)
        assert value == pytest.approx(_loo_score(np.exp(x), kind, setup, resid, noise),
                                      rel=1e-12)
        h = 1e-6
        numeric = [(_loo_score(np.exp(x + h * e), kind, setup, resid, noise)
                    - _loo_score(np.exp(x - h * e), kind, setup, resid, noise)) / (2 * h)
                   for e in np.eye(3)]
        assert np.allclose(grad, numeric, rtol=1e-5, atol=1e-4 * max(1.0, abs(value)))


@pytest.mark.parametrize("shared", [False, True])
def test_the_nugget_profile_equals_the_score_nugget_by_nugget(shared):
    xy, resid, noise, corr = _points(2, shared=shared)
    setup = _loo_setup(xy, 12, 1000, corr=corr)
    grid = np.linspace(0.0, 2.0, 17)
    for kind, theta in (("exponential", (0.0, 1.2, 60.0)), ("gaussian", (0.0, 3.0, 90.0)),
                        ("exponential", (0.0, 0.0, 0.0))):
        fast = _nugget_scores(theta, kind, setup, resid, noise)(grid)
        slow = np.array([_loo_score((g, theta[1], theta[2]), kind, setup, resid, noise)
                         for g in grid])
        assert np.array_equal(np.isinf(fast), np.isinf(slow))
        ok = np.isfinite(slow)
        assert ok.sum() >= 15
        assert np.allclose(fast[ok], slow[ok], rtol=1e-10, atol=1e-8)


def test_the_white_noise_model_with_shared_noise_is_the_best_of_its_grid():
    xy, resid, noise, corr = _points(3, shared=True)
    setup = _loo_setup(xy, 12, 1000, corr=corr)
    nug, score = _fit_white("exponential", setup, resid, noise, 2.0)
    assert score == pytest.approx(_loo_score((nug, 0.0, 0.0), "exponential", setup, resid,
                                             noise), rel=1e-10)
    grid = np.geomspace(2e-6, 20.0, 71)
    assert score <= min(_loo_score((g, 0.0, 0.0), "exponential", setup, resid, noise)
                        for g in grid) + 1e-8


def test_projected_quasi_newton_finds_interior_and_boundary_minima():
    centre = np.array([0.5, -1.0, 2.0])
    a = np.array([[4.0, 1.5, 0.0], [1.5, 2.0, 0.3], [0.0, 0.3, 1.0]])

    def fg(x):
        d = x - centre
        return float(d @ a @ d), 2 * a @ d

    lo, hi = np.full(3, -5.0), np.full(3, 5.0)
    assert np.allclose(_projected_bfgs(fg, np.zeros(3), lo, hi, xtol=1e-8, ftol=0.0),
                       centre, atol=1e-5)
    # the minimum outside the box: the third coordinate stops at its bound, the others
    # take the constrained optimum of the quadratic
    hi[2] = 1.0
    x = _projected_bfgs(fg, np.zeros(3), lo, hi, xtol=1e-8, ftol=0.0)
    assert x[2] == 1.0
    sub = np.linalg.solve(a[:2, :2], a[:2, :2] @ centre[:2] - a[:2, 2] * (1.0 - centre[2]))
    assert np.allclose(x[:2], sub, atol=1e-5)


@pytest.mark.parametrize("kind", ["exponential", "gaussian"])
def test_the_fit_scores_as_well_as_a_derivative_free_search(kind):
    """The chosen (nugget, sill, length) - on the 5 % lattice, the nugget before it is
    replaced by its posterior mean - scores within 0.1 (a 0.05 log-likelihood) of the
    optimum an independent Nelder-Mead search finds from the true parameters, and no
    better than it by more than that (the same minimum)."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(7)
    true = CovarianceModel(kind, 4.0, 120.0, 0.25)
    xy = rng.uniform(0, 600, (250, 2))
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    z = (np.linalg.cholesky(true(r) + 1e-9 * np.eye(250)) @ rng.normal(size=(250, 2))
         + rng.normal(0, 0.5, (250, 2)))
    noise = np.full(250, 0.05)
    f = fit_covariance(xy, z, noise, kind)
    assert f.fit["status"] == "fitted"
    setup = _loo_setup(xy, 12, 1000)
    chosen = np.array([f.fit["nugget_best"], f.sill, f.length])
    score = _loo_score(chosen, kind, setup, z, noise)
    assert score == pytest.approx(f.fit["loo_score"], rel=1e-12)
    nm = minimize(lambda x: _loo_score(np.exp(x), kind, setup, z, noise),
                  np.log([0.25, 4.0, 120.0]), method="Nelder-Mead",
                  options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    assert abs(score - nm.fun) <= 0.1
    assert np.allclose(np.log(chosen), nm.x, atol=0.2)  # the same parameters (+-20 %)


@pytest.mark.io
def test_weak_control_still_conflates_with_an_honest_ce90():
    """With 3 of the sample's 24 GCPs the points' marginal covariance holds more shared
    orientation error than the prior allows (P_img not positive definite in Z): the
    image-only positions come from the point given the orientation, and the
    conflation still fits its field, moves the far vertices closer to the truth and
    covers it - before, no point had an image-only position, the status still said
    "conflated" and the CE90 of the moved vertices covered none of the truth."""
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.files.study import with_control
    from vectoradjust.pipeline import run
    from vectoradjust.runner.project_run import sample_project_dir

    d = load_project_data(sample_project_dir() / "project.toml")
    rows = np.flatnonzero(d.control.role == "control")
    r = run(with_control(d, rows[:3]))
    for e in r.summary["conflation"]["databases"]:
        assert e["status"] == "conflated"
        assert e["covariance"]["horizontal"]["model"] in ("gaussian", "exponential")
        t = e["truth"]
        assert t["rmse_conflated_truth_horizontal"] < t["rmse_database_truth_horizontal"]
        assert t["share_within_ce90"] >= 0.8


def test_no_field_means_not_conflated(monkeypatch):
    """No measured point with a position from the images alone (forced here): the status
    says not done and why, no field is kept, the unmeasured vertices stay unchanged."""
    from vectoradjust.accuracy import conflation
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    r = run(make_scenario(3, n_images=2, sigma_image=0.003).to_project_data())
    d = r.databases[0]
    assert d.conflation is not None  # the run itself conflated

    def nothing(result, problem, pts, **kw):
        nan = np.full((len(pts), 3), np.nan)
        return nan, nan

    monkeypatch.setattr(conflation.prediction, "image_only", nothing)
    e = conflation.conflate_database(r, d, None, conflation.ConflationSettings())
    assert e["status"].startswith("not done: 0 of ")
    assert d.conflation is None
    assert not np.isin(d.vertices["Source"], ("interpolated", "extrapolated")).any()
