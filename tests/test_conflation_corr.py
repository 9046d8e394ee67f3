"""Conflation: the images' height error that the measured points share.

The image-only heights of the measured points share the orientation's error (a tilt of
the stereo model, ``Z S^-1 Z'`` of the joint covariance); modelled as white noise, the
vertical field took such a tilt for the database's and moved good DEM heights. Checked
against the joint covariance (definition) and by a Monte Carlo of a field under a
shared tilt with known covariance.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.conflation import (
    LE90,
    CovarianceModel,
    _krige_many,
    _measured_objects,
    _orientation_basis,
    fit_covariance,
)
from vectoradjust.pipeline import run
from vectoradjust.simulate.conflation import conflation_scenario


def test_orientation_basis_is_the_shared_part_of_the_joint_covariance():
    """``U U'`` = ``T (Z S^-1 Z') T'`` on the height axis, from the joint covariance less
    the points' own blocks and the offsets' share (``T = P_img^-1 Q^-1``)."""
    out = run(conflation_scenario(4, amplitude=0.0))
    res = out.result
    obj_pt, _ = _measured_objects(out.databases[0])
    pts = obj_pt[obj_pt >= 0][:40]
    u = _orientation_basis(res, out.problem, pts, 1.3)
    p = len(pts)
    j = res.joint_covariance(pts) / res.variance_factor
    own = np.zeros_like(j)
    for a in range(3):
        for b in range(3):
            own[a::3, b::3] += np.diag(res.npp_inv[pts, a, b])
    qb = res.offset_qb[pts].reshape(3 * p, -1)
    shared = (j - own - qb @ res.offset_cofactor @ qb.T).reshape(p, 3, p, 3)
    q = res.point_cov[pts] / res.variance_factor
    q_inv = np.linalg.inv(q)
    t = np.linalg.inv(q_inv - out.problem.prior_weight[pts]) @ q_inv
    want = 1.3 * np.einsum("ia,iajb,jb->ij", t[:, 2], shared, t[:, 2])
    assert u.shape[1] == 12  # two images: their 12 orientation parameters
    assert np.allclose(u @ u.T, want, rtol=0, atol=1e-5 * np.abs(want).max())
    assert np.abs(want).max() > 1e-3  # a real shared error (m^2)


def test_a_shared_tilt_of_the_measured_heights_is_not_taken_for_the_field():
    """Monte Carlo: a weak field (sill 0.02 m^2, L 200 m) + white noise (0.01) at 500
    points, 250 measured with white image noise (0.08) and a shared tilt of known
    covariance ``U U'``. With the true covariance and ``U`` in the system the LE90 of
    the other 250 points covers the truth 90 % (the system is right); fitted with ``U``
    the field stays weak and the predictions are closer to the truth than when the tilt
    is taken as white noise, which makes it a field (larger sill) and moves the
    predictions with it."""
    rng = np.random.default_rng(5)
    true = CovarianceModel("gaussian", 0.02, 200.0, 0.01)
    n_m = 250
    xy = rng.uniform(0, 1000, (2 * n_m, 2))
    r = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    chol = np.linalg.cholesky(true(r) + 1e-9 * np.eye(len(xy)))
    u = 0.3 * (xy[:n_m] - 500.0) / 500.0
    known = 0.08 + (u ** 2).sum(axis=1)
    res: dict = {"true": [], "with U": [], "white": []}
    for _ in range(16):
        truth = chol @ rng.normal(size=(len(xy), 1)) + rng.normal(0, 0.1, (len(xy), 1))
        d = truth[:n_m] + rng.normal(0, np.sqrt(0.08), (n_m, 1)) + u @ rng.normal(size=(2, 1))
        for key, corr in (("true", u), ("with U", u), ("white", None)):
            f = true if key == "true" else fit_covariance(xy[:n_m], d, known, "gaussian", 12,
                                                          corr=corr)
            ((p, kv, _),), _ = _krige_many([(f, d, known, None, corr)], xy[:n_m], xy[n_m:], 12)
            e = p[:, 0] - truth[n_m:, 0]
            res[key].append((np.mean(e ** 2), np.mean(np.abs(e) <= LE90 * np.sqrt(kv + f.nugget)),
                             f.sill))
    known_model, with_u, white = (np.mean(res[k], axis=0) for k in ("true", "with U", "white"))
    assert known_model[1] == pytest.approx(0.90, abs=0.02)
    assert with_u[0] < 0.75 * white[0] and with_u[2] < 0.5 * white[2]
    assert with_u[1] > white[1] + 0.1


def test_leave_one_out_with_shared_noise_is_the_dense_conditional():
    """Definition: a held-out measured point whose noise it shares with the others is
    predicted by ``w = A^-1 (c + U u_0)``; its error variance is
    ``C0 + n + D_0 - w'(c + U u_0)`` (the caller adds ``n + D_0``)."""
    rng = np.random.default_rng(9)
    cov = CovarianceModel("exponential", 1.0, 120.0, 0.05)
    m = 14
    xy = rng.uniform(0, 400, (m, 2))
    resid = rng.normal(size=(m, 1))
    u = rng.normal(0, 0.3, (m, 2))
    noise = 0.1 + (u ** 2).sum(axis=1)
    ((pred, var, _),), _ = _krige_many([(cov, resid, noise, None, u)], xy, xy, m - 1,
                                       skip_self=True)
    r = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    full = cov(r) + np.diag(np.full(m, cov.nugget) + noise - (u ** 2).sum(1)) + u @ u.T
    for i in (0, 5, 13):
        o = np.arange(m) != i
        rhs = full[o, i]  # C(r) + U u_i: off the diagonal of the full covariance
        w = np.linalg.solve(full[np.ix_(o, o)], rhs)
        assert pred[i, 0] == pytest.approx(w @ resid[o, 0])
        assert var[i] == pytest.approx(cov.sill - w @ rhs)


def test_a_signal_must_earn_its_parameters():
    """White noise (with and without shared noise) is fitted as white noise in most
    draws (AIC: a signal's two parameters must lower the leave-one-out score by more
    than 4; by chance about ``exp(-2)`` of the time); a real field keeps its signal."""
    rng = np.random.default_rng(17)
    white = []
    for i in range(24):
        xy = rng.uniform(0, 700, (80, 2))
        u = 0.2 * (xy - 350.0) / 350.0 if i % 2 else None
        z = rng.normal(0, np.sqrt(0.05 + 0.1), (80, 1))
        if u is not None:
            z = z + u @ rng.normal(size=(2, 1))
        known = 0.1 + (0.0 if u is None else (u ** 2).sum(axis=1))
        f = fit_covariance(xy, z, np.broadcast_to(known, (80,)).copy(), corr=u)
        white.append(f.sill == 0.0 and f.fit["status"] == "white noise (AIC)")
    assert np.mean(white) >= 0.75
    true = CovarianceModel("gaussian", 1.0, 120.0, 0.05)
    xy = rng.uniform(0, 700, (150, 2))
    r = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    z = np.linalg.cholesky(true(r) + 1e-9 * np.eye(150)) @ rng.normal(size=(150, 1))
    f = fit_covariance(xy, z + rng.normal(0, 0.2, z.shape), np.full(150, 0.01))
    assert f.sill > 0 and f.fit["status"] == "fitted"
