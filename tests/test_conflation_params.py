"""Conflation: the CE90 of a predicted vertex accounts for the estimated parameters.

The database noise ``n_db`` and the sill ``C0`` are estimated from the measured points;
the predictive distribution of a vertex's error is the normal mixed over their
distributions (:func:`ce90_factor`). Checked against the Student-t / F distribution
(a variance with ``nu`` degrees of freedom), against a Monte Carlo of the mixture,
the sill's degrees of freedom against a simulation of its estimate, and the coverage
of a far vertex (the sill's estimate alone) by a Monte Carlo with estimated sills.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from vectoradjust.conflation import (
    CE90_CIRCULAR,
    CovarianceModel,
    _ce90_table,
    _gauss_rule,
    _sill_dof,
    ce90_factor,
)


@pytest.mark.parametrize("nu", [3.0, 7.5, 20.0, 45.0, 400.0])
def test_a_sill_estimated_with_nu_degrees_of_freedom_gives_the_f_quantile(nu):
    """Where the sill is the whole variance, ``|e|^2 / (2 C0_hat)`` is ``F(2, nu)``
    (the two-dimensional Student t): the table's corner is ``sqrt(F_0.9 / ln 10)``;
    where nothing is estimated the factor is 1."""
    tab = _ce90_table(CovarianceModel("gaussian", 2.0, 100.0, 0.1, sill_dof=nu))
    want = np.sqrt(stats.f.ppf(0.9, 2, nu) / np.log(10.0))
    assert tab[-1, 0] == pytest.approx(want, rel=2e-5)
    assert tab[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert tab[0, -1] == pytest.approx(1.0, abs=1e-12)  # no nugget posterior: known


def test_the_table_is_the_quantile_of_the_mixture_by_monte_carlo():
    """A vertex whose variance is 1/4 known, 1/2 sill (nu = 8) and 1/4 database noise
    (a skewed distribution given the data): the 90 % radius of 4 million simulated
    errors against the table (bilinear between lattice points)."""
    x = np.linspace(0.2, 2.6, 61)
    w = stats.gamma.pdf(x, 6.0, scale=1 / 6.0)
    w /= w.sum()
    x = x / np.sum(w * x)
    cov = CovarianceModel("gaussian", 2.0, 100.0, 0.1, nugget_posterior=(x, w), sill_dof=8.0)
    rng = np.random.default_rng(5)
    n = 4_000_000
    var = 0.25 + 0.5 * 8.0 / rng.chisquare(8.0, n) + 0.25 * rng.choice(x, n, p=w)
    r2 = var * rng.chisquare(2.0, n)
    want = np.sqrt(np.quantile(r2, 0.9) / (2 * np.log(10.0)))
    got = ce90_factor(cov, np.array([0.5]), np.array([0.25]), np.array([1.0]))[0]
    assert got == pytest.approx(want, rel=3e-3)
    assert got > 1.05


def test_gauss_rule_keeps_the_moments_of_the_distribution():
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(0.0, 3.0, 41))
    w = rng.uniform(0.1, 1.0, 41)
    w /= w.sum()
    nodes, weights = _gauss_rule(x, w, 8)
    for k in range(16):
        assert np.sum(weights * nodes ** k) == pytest.approx(np.sum(w * x ** k), rel=1e-9)


def test_factor_is_one_without_estimated_parameters_and_at_least_one_with_them():
    cov = CovarianceModel("gaussian", 2.0, 100.0, 0.1)
    v = np.array([1.0, 2.0, np.nan, 0.0])
    assert np.all(ce90_factor(cov, 0.5 * v, 0.1 * v, v) == 1.0)
    assert np.all(ce90_factor(None, v, v, v) == 1.0)
    cov = CovarianceModel("gaussian", 2.0, 100.0, 0.1, sill_dof=6.0)
    f = ce90_factor(cov, np.array([0.0, 0.5, 1.0]), np.zeros(3), np.ones(3))
    assert f[0] == pytest.approx(1.0) and 1.0 < f[1] < f[2]


def test_sill_dof_is_that_of_the_simulated_sill_estimate():
    """A Gaussian field (C0 4 m^2, L 150 m) at 80 points on 600 m x 400 m, two
    components: the mean square of its values over 2000 realisations has variance
    ``2 C0^2 / nu``; between ``c = 2`` (one patch) and ``c m`` (uncorrelated)."""
    rng = np.random.default_rng(9)
    xy = rng.uniform(0, [600.0, 400.0], (80, 2))
    cov = CovarianceModel("gaussian", 4.0, 150.0, 0.09)
    nu = _sill_dof(cov, xy, 2)
    r = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    chol = np.linalg.cholesky(cov(r) + 1e-9 * np.eye(80))
    z = np.einsum("ij,sjc->sic", chol, rng.normal(size=(2000, 80, 2)))
    est = np.mean(z ** 2, axis=(1, 2))
    assert est.mean() == pytest.approx(4.0, rel=0.05)
    assert 2 * 16.0 / est.var() == pytest.approx(nu, rel=0.12)
    assert 3.0 < nu < 40.0  # a few correlation lengths: far fewer than 160 values
    assert _sill_dof(CovarianceModel("gaussian", 0.0, 0.0, 0.1), xy, 2) == np.inf
    one_patch = _sill_dof(CovarianceModel("gaussian", 4.0, 1e6, 0.1), xy, 2)
    assert one_patch == pytest.approx(2.0, rel=1e-6)
    assert _sill_dof(CovarianceModel("exponential", 4.0, 1e-3, 0.1), xy, 2) == \
        pytest.approx(160.0, rel=1e-6)


def test_far_vertex_covers_90_percent_with_an_estimated_sill():
    """Monte Carlo: the sill estimated (moment estimate) from a correlated field at 60
    points, a vertex far away (error N(0, C0) per axis, independent). Its CE90 with the
    plug-in sill covers less than 90 %, with the factor for the sill's degrees of
    freedom 90 %."""
    rng = np.random.default_rng(13)
    xy = rng.uniform(0, [500.0, 300.0], (60, 2))
    true = CovarianceModel("gaussian", 4.0, 150.0, 0.0)
    r = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    chol = np.linalg.cholesky(true(r) + 1e-6 * np.eye(60))
    nu = _sill_dof(true, xy, 2)
    sims = 4000
    z = np.einsum("ij,sjc->sic", chol, rng.normal(size=(sims, 60, 2)))
    sill = np.mean(z ** 2, axis=(1, 2))
    far = rng.normal(0.0, 2.0, (sims, 2))
    size = np.hypot(*far.T)
    plug = CE90_CIRCULAR * np.sqrt(sill)
    # far away the whole variance is the sill's: the factor depends on nu alone
    f = ce90_factor(CovarianceModel("gaussian", 4.0, 150.0, 0.0, sill_dof=nu),
                    np.array([4.0]), np.array([0.0]), np.array([4.0]))[0]
    assert np.mean(size <= plug) < 0.86
    assert np.mean(size <= f * plug) == pytest.approx(0.90, abs=0.015)


def test_vertices_and_the_field_map_carry_the_same_factor():
    """A whole run: the predicted vertices' CE90 is the plug-in CE90 of their covariance
    times a factor >= 1, larger far from measured points (where the sill dominates)
    than among them, and :meth:`FieldModel.predict` gives the same factor."""
    from vectoradjust.accuracy import stats as st
    from vectoradjust.pipeline import run
    from vectoradjust.simulate.conflation import conflation_scenario

    out = run(conflation_scenario(13))
    d = out.databases[0]
    v = d.vertices
    u = np.flatnonzero(v["Adjusted"] == 0)
    cov = np.zeros((len(u), 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = v["SigmaX"][u] ** 2, v["SigmaY"][u] ** 2
    factor = v["CE90"][u] / st.ce90(cov)
    assert np.all(factor >= 1.0 - 1e-9)
    obj = d.shape.object_xyz[d.shape.vertex_object[u]]
    _, _, kappa = d.conflation.predict(obj[:, :2], ce90_factor=True)
    assert np.allclose(kappa, factor, rtol=1e-6)
    sig = np.hypot(v["SigmaX"][u], v["SigmaY"][u])
    far, near = sig > np.quantile(sig, 0.95), sig < np.quantile(sig, 0.5)
    assert factor[far].mean() > factor[near].mean() + 0.02
    entry = out.summary["conflation"]["databases"][0]["covariance"]["horizontal"]
    assert entry["sill_dof"] > 2 and entry["nugget_sd"] > 0
