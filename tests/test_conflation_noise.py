"""Conflation: the database's white noise ``n_db`` against the truth over seeds.

``n_db`` is the difference of two similar variances (the measured points' white
scatter and their stated own noise ``D_i``), so one run's estimate scatters by 15-40 %;
the CE90 of a predicted vertex mixes over its distribution given the data
(:func:`_nugget_posterior`, :func:`ce90_factor`). That mixing is honest only when the
estimate is unbiased and its stated uncertainty (``nugget_sd``) is the scatter's:
``z = (true - estimate) / nugget_sd`` about 0 with SD about 1 over seeds. Checked on
a smooth field plus white noise with known ``D_i``, and that the check fails when
``D_i`` is misstated (then the split between the two noises is wrong).
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.conflation import fit_covariance
from vectoradjust.simulate.conflation import smooth_field

N_DB = 0.09  # the database's white noise variance per axis (0.3 m)


def _case(seed: int, n: int = 160):
    """Measured points in a 1 km square: a smooth field (2 m, length 150 m) plus the
    database's white noise plus each point's own noise ``D_i`` (0.05-0.15 m^2)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 1000.0, (n, 2))
    d = rng.uniform(0.05, 0.15, n)
    resid = (smooth_field(xy, 2.0, 150.0, seed + 1000)
             + rng.normal(0.0, np.sqrt(N_DB), (n, 2))
             + rng.normal(0.0, 1.0, (n, 2)) * np.sqrt(d)[:, None])
    return xy, resid, d


def _z_scores(seeds, misstate: float = 0.0) -> tuple:
    est, z = [], []
    for seed in seeds:
        xy, resid, d = _case(seed)
        cov = fit_covariance(xy, resid, d + misstate, kind="gaussian")
        sd = cov.as_dict()["nugget_sd"]
        assert sd > 0, f"seed {seed}: no posterior SD"
        est.append(cov.nugget)
        z.append((N_DB - cov.nugget) / sd)
    return np.array(est), np.array(z)


def test_the_database_noise_is_unbiased_and_its_stated_sd_its_scatter():
    """16 seeds: the estimates' mean within 3 standard errors of the truth, ``z`` mean
    within +-0.8 (3 SE of 16 standard normals 0.75) and SD 0.5-1.3 (measured 1.17; the
    likelihood without the sandwich ratio of :func:`_nugget_temper` gave 1.36)."""
    est, z = _z_scores(range(1, 17))
    se = est.std(ddof=1) / np.sqrt(len(est))
    assert abs(est.mean() - N_DB) < 3.0 * se, (est.mean(), se)
    assert abs(z.mean()) < 0.8, z
    assert 0.5 < z.std(ddof=1) < 1.3, z


@pytest.mark.parametrize("misstate", [0.04, -0.04])
def test_a_misstated_own_noise_moves_the_split(misstate):
    """``D_i`` stated 0.04 m^2 too large (too small): ``n_db`` comes out that much too
    small (large), several posterior SDs: the check above can fail."""
    est, z = _z_scores(range(1, 9), misstate)
    assert est.mean() == pytest.approx(N_DB - misstate, abs=0.025)
    assert abs(z.mean()) > 1.0, z


def test_the_sandwich_ratio_is_one_without_a_signal_and_wider_with_one():
    """No signal (the white-noise model): the held-out errors are the points' own, the
    likelihood is exact and the ratio 1; with the smooth field the neighbours' shared
    noise makes it larger (1.0-2.5 over 8 seeds, mean 1.8 measured)."""
    from vectoradjust.conflation.covariance import _loo_setup, _nugget_temper

    field = []
    for seed in range(1, 9):
        xy, resid, d = _case(seed)
        setup = _loo_setup(xy, 12, 1000)
        assert _nugget_temper((N_DB, 0.0, 0.0), N_DB, "gaussian", setup, resid, d) == 1.0
        field.append(_nugget_temper((N_DB, 4.0, 212.0), N_DB, "gaussian", setup, resid, d))
    assert np.mean(field) > 1.4, field
    assert max(field) <= 9.0, field
