"""The conflation's variance calibration per distance band (issue 30): leave-one-out
errors at each band's distance ("h-block" cross-validation) widen the predicted
vertices' variances where the fitted covariance understates them, never narrow them.
"""

from __future__ import annotations

import numpy as np

from vectoradjust.conflation import CovarianceModel
from vectoradjust.conflation.coverage import DISTANCE_BANDS
from vectoradjust.conflation.kriging import band_factors
from vectoradjust.conflation.prediction import _calibrated


def _field(seed: int, model: CovarianceModel, n: int = 400, side: float = 1500.0,
           noise: float = 0.05):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, side, (n, 2))
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    z = (np.linalg.cholesky(model(r) + 1e-9 * np.eye(n)) @ rng.normal(size=(n, 2))
         + rng.normal(0, np.sqrt(model.nugget + noise), (n, 2)))
    return xy, z, np.full(n, noise)


def test_the_true_covariance_needs_no_widening():
    """Data drawn from the covariance that predicts them: every band's mean standardised
    square error is about 1, so the factors stay at (or near) 1."""
    true = CovarianceModel("gaussian", 4.0, 150.0, 0.1)
    out = []
    for seed in (1, 2, 3):
        xy, z, noise = _field(seed, true)
        out.append(band_factors(true, xy, z, noise, 12, DISTANCE_BANDS))
    out = np.array(out)
    assert out.shape == (3, 4)
    assert np.all(out >= 1.0)
    assert out.mean() <= 1.25


def test_a_too_small_sill_is_widened_most_far_from_the_measured_points():
    """The fitted covariance states a tenth of the real sill: predictions far from the
    measured points (where the sill dominates) err far more than stated; the far
    bands' factors are large, the nearest band's smaller."""
    true = CovarianceModel("gaussian", 4.0, 300.0, 0.1)
    wrong = CovarianceModel("gaussian", 0.4, 300.0, 0.1)
    xy, z, noise = _field(4, true)
    f = band_factors(wrong, xy, z, noise, 12, DISTANCE_BANDS)
    assert f[2] > 1.5 and f[3] > 3.0
    assert f[0] < f[3]


def test_a_band_without_enough_predictions_takes_the_factor_before_it():
    true = CovarianceModel("exponential", 1.0, 100.0, 0.1)
    xy, z, noise = _field(5, true, n=60, side=150.0)  # nothing is 200 m from 12 others
    wrong = CovarianceModel("exponential", 0.1, 100.0, 0.1)
    f = band_factors(wrong, xy, z, noise, 12, DISTANCE_BANDS, min_count=30)
    assert f[3] == f[2]
    assert f[0] > 1.0


def test_no_signal_means_no_calibration():
    xy, z, noise = _field(6, CovarianceModel("gaussian", 1.0, 100.0, 0.1), n=50)
    assert np.array_equal(band_factors(CovarianceModel("exponential", 0.0, 0.0, 0.5), xy, z,
                                       noise, 12), np.ones(4))


def test_the_horizontal_block_is_scaled_by_its_band():
    rng = np.random.default_rng(7)
    m = rng.normal(size=(4, 3, 3))
    cov = m @ np.swapaxes(m, 1, 2)
    near = np.array([10.0, 60.0, 150.0, 900.0])
    f = np.array([1.0, 2.0, 3.0, 4.0])
    out = _calibrated(cov, f, near)
    for i in range(4):
        s = np.diag([np.sqrt(f[i]), np.sqrt(f[i]), 1.0])
        assert np.allclose(out[i], s @ cov[i] @ s)
    assert _calibrated(cov, None, near) is cov
