"""The conflation's covariance fit in closed form (issue 32): the leave-one-out score's
analytic gradient against central differences, the score from the distinct distances
against the kriging systems built entry by entry, the expected Hessian's start of the
quasi-Newton search against the identity's (same models, fewer scores), the downhill
lattice polish against the full one, the nugget profile from one eigendecomposition
against the score evaluated nugget by nugget, the box-constrained quasi-Newton search
against known minima, and the fit against an independent derivative-free search of the
same score.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.conflation import (
    CovarianceModel,
    _fit_white,
    _loo_score,
    _loo_score_fisher,
    _loo_score_grad,
    _loo_setup,
    _nugget_scores,
    _projected_bfgs,
    fit_covariance,
)
from vectoradjust.conflation import covariance as conf_cov


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


def _score_entry_by_entry(theta, kind, setup, resid, noise):
    """The leave-one-out score as before issue 32's gather: every kriging system built
    from its own distances (:func:`_system`) and solved."""
    tgt, dist, idx, dd, corr = setup[:5]
    cov = CovarianceModel(kind, theta[1], theta[2], theta[0])
    a, c = conf_cov._system(cov, dd, dist, noise[idx], None if corr is None else corr[idx],
                            None if corr is None else corr[tgt])
    w = np.linalg.solve(a, c[:, :, None])[:, :, 0]
    e = resid[tgt] - np.einsum("bk,bkc->bc", w, resid[idx])
    sig = cov.sill - np.einsum("bk,bk->b", w, c)
    s2 = (np.maximum(sig, 0.0) if corr is None else sig) + cov.nugget + noise[tgt]
    if not np.all(s2 > 0):
        return float("inf")
    return float(np.sum(resid.shape[1] * np.log(s2) + (e ** 2).sum(axis=1) / s2))


@pytest.mark.parametrize("kind", ["exponential", "gaussian"])
@pytest.mark.parametrize("shared", [False, True])
def test_the_score_from_distinct_distances_is_the_systems_score(kind, shared):
    xy, resid, noise, corr = _points(4, shared=shared)
    xy[:10] = xy[10:20]  # repeated positions: equal distances, zero distances
    setup = _loo_setup(xy, 12, 1000, corr=corr)
    assert len(setup.lags) < setup.dd.size / 2  # the covariance is evaluated far less often
    finite = 0
    for theta in ([0.3, 1.2, 60.0], [0.5, 4.0, 150.0], [0.2, 0.0, 0.0], [0.05, 2.0, 30.0]):
        fast = _loo_score(theta, kind, setup, resid, noise)
        slow = _score_entry_by_entry(theta, kind, setup, resid, noise)
        assert fast == pytest.approx(slow, rel=1e-11)  # inf alike (not admissible)
        finite += np.isfinite(slow)
    assert finite >= 2


@pytest.mark.parametrize("shared", [False, True])
def test_the_expected_hessian_is_symmetric_and_positive(shared):
    xy, resid, noise, corr = _points(5, shared=shared)
    setup = _loo_setup(xy, 12, 1000, corr=corr)
    for kind in ("exponential", "gaussian"):
        x = np.log([0.3, 1.2, 60.0])
        value, grad, hess = _loo_score_fisher(x, kind, setup, resid, noise)
        v2, g2 = _loo_score_grad(x, kind, setup, resid, noise)
        assert value == v2 and np.array_equal(grad, g2)
        assert np.allclose(hess, hess.T, rtol=1e-12, atol=1e-12)
        assert np.linalg.eigvalsh(hess).min() > 0


def _simulated(seed: int, kind: str, n: int = 200, shared: bool = False):
    rng = np.random.default_rng(seed)
    true = CovarianceModel(kind, 3.0, 100.0, 0.2)
    xy = rng.uniform(0, 700, (n, 2))
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    z = (np.linalg.cholesky(true(r) + 1e-9 * np.eye(n)) @ rng.normal(size=(n, 2))
         + rng.normal(0, 0.45, (n, 2)))
    corr = rng.normal(0, 0.1, (n, 4)) if shared else None
    return xy, z, np.full(n, 0.05), corr


@pytest.mark.parametrize("seed,kind,shared", [(11, "gaussian", False),
                                              (12, "exponential", False),
                                              (13, "gaussian", True),
                                              (14, "exponential", True)])
def test_the_hessian_start_finds_the_identity_starts_model_with_fewer_scores(
        seed, kind, shared, monkeypatch):
    """Issue 32: the quasi-Newton search started from the expected Hessian and the
    downhill lattice polish choose the model that the search started from the identity
    with the full polish chose (the fit before), with fewer scores."""
    xy, z, noise, corr = _simulated(seed, kind, shared=shared)
    calls = {"n": 0}
    real_fisher, real_grad, real_score = (conf_cov._loo_score_fisher,
                                          conf_cov._loo_score_grad, conf_cov._loo_score)

    def counted(fun):
        def wrapped(*a, **kw):
            calls["n"] += 1
            return fun(*a, **kw)
        return wrapped

    monkeypatch.setattr(conf_cov, "_loo_score_grad", counted(real_grad))
    monkeypatch.setattr(conf_cov, "_loo_score", counted(real_score))
    monkeypatch.setattr(conf_cov, "_loo_score_fisher", counted(real_fisher))
    new = fit_covariance(xy, z, noise, kind, corr=corr)
    n_new = calls["n"]
    # before: no Hessian (the identity start), every lattice neighbour scored
    calls["n"] = 0
    monkeypatch.setattr(conf_cov, "_loo_score_fisher", lambda *a: counted(real_grad)(*a))
    plain_lattice = conf_cov._lattice_min
    monkeypatch.setattr(conf_cov, "_lattice_min",
                        lambda f, x, lo, hi, max_moves=200, fg=None:
                        plain_lattice(f, x, lo, hi, max_moves=max_moves))
    old = fit_covariance(xy, z, noise, kind, corr=corr)
    n_old = calls["n"]
    assert new.kind == old.kind and new.fit["status"] == old.fit["status"]
    for a, b in ((new.fit["nugget_best"], old.fit["nugget_best"]), (new.sill, old.sill),
                 (new.length, old.length)):
        assert (a > 0) == (b > 0)
        if a > 0:  # the same lattice point (5 % steps), or its neighbour on the ridge
            assert abs(np.log(a / b)) <= 0.051
    assert abs(new.fit["loo_score"] - old.fit["loo_score"]) <= 0.05
    assert n_new < n_old


def test_the_downhill_lattice_polish_equals_the_full_one():
    rng = np.random.default_rng(3)
    lo, hi = np.full(3, -5.0), np.full(3, 5.0)
    for _ in range(20):
        centre = rng.uniform(-1, 1, 3)
        m = rng.normal(size=(3, 3))
        a = m @ m.T + 0.1 * np.eye(3)

        def fg(x, centre=centre, a=a):
            d = x - centre
            return float(d @ a @ d), 2 * a @ d

        x0 = centre + rng.normal(0, 0.03, 3)
        full = conf_cov._lattice_min(lambda x: fg(x)[0], x0, lo, hi, max_moves=1)
        down = conf_cov._lattice_min(lambda x: fg(x)[0], x0, lo, hi, max_moves=1, fg=fg)
        assert np.allclose(full[0], down[0]) and full[1] == pytest.approx(down[1])
