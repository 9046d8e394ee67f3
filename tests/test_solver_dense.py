"""The blocked Schur-complement solver against a straightforward dense Gauss-Newton.

The reference below builds the full design matrix ``A`` (observation rows from the
per-observation :func:`~vectoradjust.sensor.collinearity.partials`, unit rows for the
point and EO priors), solves ``A'PA dx = A'Pl`` densely at every iteration and inverts
the full ``N`` for the covariances: no Schur complement, no blocks, no grouping. The
problems are simulated blocks with known truth (:func:`vectoradjust.simulate.block.make_block`).
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.adjust import bundle
from vectoradjust.adjust.bundle import BundleProblem, adjust
from vectoradjust.sensor.collinearity import (
    partials,
    project,
    rotation_derivatives,
    rotation_matrix,
)
from vectoradjust.simulate.block import make_block


def _dense_system(prob: BundleProblem, eo: np.ndarray, xyz: np.ndarray):
    """``A``, ``P`` (diagonal as a vector or full) and misclosure ``l`` of the whole model."""
    n, m, k = prob.n_images, prob.n_points, len(prob.obs_point)
    u = 6 * n + 3 * m
    has = prob.has_prior
    we = prob.eo_weight.ravel()
    sel = np.flatnonzero(we > 0)
    pri = np.flatnonzero(has)
    rows = 2 * k + 3 * len(pri) + len(sel)
    a = np.zeros((rows, u))
    p = np.zeros((rows, rows))
    ell = np.zeros(rows)
    a_eo, a_pt = partials(eo[prob.obs_image], xyz[prob.obs_point], prob.focal_length)
    pred = project(eo[prob.obs_image], xyz[prob.obs_point], prob.focal_length,
                   prob.principal_point)
    r = np.arange(2 * k).reshape(k, 2)
    a[r[:, :, None], 6 * prob.obs_image[:, None, None] + np.arange(6)] = a_eo
    a[r[:, :, None], 6 * n + 3 * prob.obs_point[:, None, None] + np.arange(3)] = a_pt
    p[np.arange(2 * k), np.arange(2 * k)] = (1.0 / prob.obs_sigma**2).ravel()
    ell[: 2 * k] = (prob.obs_xy - pred).ravel()
    o = 2 * k
    for j in pri:  # a small problem: a loop over the prior points is fine in a test
        a[o:o + 3, 6 * n + 3 * j: 6 * n + 3 * j + 3] = np.eye(3)
        p[o:o + 3, o:o + 3] = prob.prior_weight[j]
        ell[o:o + 3] = prob.prior_xyz[j] - xyz[j]
        o += 3
    a[o + np.arange(len(sel)), sel] = 1.0
    p[o + np.arange(len(sel)), o + np.arange(len(sel))] = we[sel]
    ell[o:] = (prob.eo0 - eo).ravel()[sel]
    return a, p, ell


def _dense_adjust(prob: BundleProblem, max_iterations=20, tol_pos=1e-4, tol_ang=1e-8):
    """Plain dense Gauss-Newton with the same stopping rule as :func:`adjust`."""
    n = prob.n_images
    eo, xyz = prob.eo0.copy(), prob.xyz0.copy()
    for _ in range(max_iterations):
        a, p, ell = _dense_system(prob, eo, xyz)
        nmat = a.T @ p @ a
        dx = np.linalg.solve(nmat, a.T @ p @ ell)
        de, dp = dx[: 6 * n].reshape(n, 6), dx[6 * n:].reshape(-1, 3)
        eo, xyz = eo + de, xyz + dp
        if max(np.abs(de[:, :3]).max(), np.abs(dp).max()) < tol_pos \
                and np.abs(de[:, 3:]).max() < tol_ang:
            break
    a_f, p_f, ell_f = _dense_system(prob, eo, xyz)
    vtpv = float(ell_f @ p_f @ ell_f)
    dof = a_f.shape[0] - a_f.shape[1]
    return eo, xyz, vtpv / dof, np.linalg.inv(nmat), a, p


def _with_lonely_point(prob: BundleProblem) -> BundleProblem:
    """The problem plus a point that has a prior but no image measurement."""
    w = np.diag([1 / 4.0, 1 / 4.0, 1.0])[None]
    xyz = prob.xyz0[:1] + 5.0
    return BundleProblem(
        prob.focal_length, prob.principal_point, prob.eo0, prob.eo_sigma,
        np.vstack([prob.xyz0, xyz]), np.vstack([prob.prior_xyz, xyz + 0.7]),
        np.concatenate([prob.prior_weight, w]), prob.obs_point, prob.obs_image, prob.obs_xy,
        prob.obs_sigma)


@pytest.fixture(scope="module")
def block_and_reference():
    blk = make_block(2, 3, n_shape_points=70, n_control=8, n_tie=14, seed=5)
    prob = _with_lonely_point(blk.problem)
    # shuffle the observations: the solver must not rely on their order
    perm = np.random.default_rng(2).permutation(len(prob.obs_point))
    prob = BundleProblem(prob.focal_length, prob.principal_point, prob.eo0, prob.eo_sigma,
                         prob.xyz0, prob.prior_xyz, prob.prior_weight, prob.obs_point[perm],
                         prob.obs_image[perm], prob.obs_xy[perm], prob.obs_sigma[perm])
    return blk, prob, adjust(prob), _dense_adjust(prob)


def test_parameters_and_sigma0_equal_the_dense_solution(block_and_reference):
    _, prob, res, (eo, xyz, s0sq, _, _, _) = block_and_reference
    # relative to the corrections the adjustment made (positions ~1e5 m would hide errors)
    step_e = np.abs(eo - prob.eo0).max(axis=0)
    assert np.all(np.abs(res.eo - eo) <= 1e-9 * step_e + 1e-12)
    assert np.abs(res.xyz - xyz).max() <= 1e-9 * np.abs(xyz - prob.xyz0).max()
    assert res.sigma0_squared == pytest.approx(s0sq, rel=1e-9)
    assert res.dof == _dense_system(prob, eo, xyz)[0].shape[0] - 6 * prob.n_images \
        - 3 * prob.n_points


def test_covariances_are_the_blocks_of_the_dense_inverse(block_and_reference):
    _, prob, res, (_, _, s0sq, q, _, _) = block_and_reference
    n, m = prob.n_images, prob.n_points
    qp = q[6 * n:, 6 * n:].reshape(m, 3, m, 3)[np.arange(m), :, np.arange(m), :]
    np.testing.assert_allclose(res.point_cov, s0sq * qp, rtol=1e-9, atol=0)
    qe = q[:6 * n, :6 * n]
    np.testing.assert_allclose(res.s_inv, qe, rtol=1e-9, atol=1e-9 * np.abs(qe).max())
    np.testing.assert_allclose(res.eo_cov, s0sq * qe.reshape(n, 6, n, 6)[np.arange(n), :,
                                                                          np.arange(n), :],
                               rtol=1e-9, atol=1e-9 * s0sq * np.abs(qe).max())


def test_kept_factorisation_equals_the_dense_pieces(block_and_reference):
    """``a_eo, a_pt, nep_obs, npp_inv`` (used by reliability and derived outputs)."""
    _, prob, res, (_, _, _, _, a, p) = block_and_reference
    n, k = prob.n_images, len(prob.obs_point)
    nmat = a.T @ p @ a
    a_img = a[: 2 * k].reshape(k, 2, -1)
    rows_e = 6 * prob.obs_image[:, None] + np.arange(6)
    rows_p = 6 * n + 3 * prob.obs_point[:, None] + np.arange(3)
    a_eo = np.take_along_axis(a_img, rows_e[:, None, :], axis=2)
    a_pt = np.take_along_axis(a_img, rows_p[:, None, :], axis=2)
    np.testing.assert_allclose(res.a_eo, a_eo, rtol=1e-9, atol=1e-12 * np.abs(a_eo).max())
    np.testing.assert_allclose(res.a_pt, a_pt, rtol=1e-9, atol=1e-12 * np.abs(a_pt).max())
    w = 1.0 / prob.obs_sigma**2
    nep = np.einsum("kri,kr,krj->kij", a_eo, w, a_pt)
    np.testing.assert_allclose(res.nep_obs, nep, rtol=1e-9, atol=1e-12 * np.abs(nep).max())
    m = prob.n_points
    npp = nmat[6 * n:, 6 * n:].reshape(m, 3, m, 3)[np.arange(m), :, np.arange(m), :]
    np.testing.assert_allclose(res.npp_inv, np.linalg.inv(npp), rtol=1e-9, atol=0)


def test_recovers_the_simulated_truth_within_its_covariance(block_and_reference):
    blk, prob, res, _ = block_and_reference
    m0 = blk.true_xyz.shape[0]  # the added point has no truth
    err = res.xyz[:m0] - blk.true_xyz
    z = np.einsum("mi,mij,mj->m", err, np.linalg.inv(res.point_cov[:m0]), err)
    # chi-square with 3 dof: mean 3; a broken covariance or solution is far off
    assert 1.5 < z.mean() < 5.0
    assert 0.6 < res.sigma0_squared < 1.6


def test_rotation_derivatives_against_central_differences():
    rng = np.random.default_rng(4)
    ang = rng.uniform(-0.5, 0.5, (5, 3))
    d = rotation_derivatives(ang[:, 0], ang[:, 1], ang[:, 2])
    h = 1e-6
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        fd = (rotation_matrix(*(ang + e).T) - rotation_matrix(*(ang - e).T)) / (2 * h)
        np.testing.assert_allclose(d[:, i], fd, atol=1e-9)


def test_image_set_groups_with_and_without_integer_keys():
    rng = np.random.default_rng(7)
    img = np.sort(rng.choice(40, size=(300, 3)), axis=1)
    keys, inverse = bundle._image_set_keys(img)
    ref_keys, ref_inv = np.unique(img, axis=0, return_inverse=True)
    assert np.array_equal(keys, ref_keys)
    assert np.array_equal(inverse, np.asarray(ref_inv).reshape(-1))
    big = img.astype(np.int64) * 10**7  # keys would overflow int64: the row-unique path
    keys_b, inverse_b = bundle._image_set_keys(np.tile(big, (1, 3)))
    assert np.array_equal(keys_b // 10**7, np.tile(ref_keys, (1, 3)))
    assert np.array_equal(inverse_b, inverse)


def test_stereo_pair_matches_the_dense_solution_with_a_point_seen_twice_on_one_image():
    blk = make_block(1, 2, n_shape_points=25, n_control=6, n_tie=4, seed=9)
    prob = blk.problem
    # measure point 0 a second time on its first image (a repeated image in its set)
    k0 = int(np.flatnonzero(prob.obs_point == 0)[0])
    extra = prob.obs_xy[k0] + np.array([0.004, -0.003])
    prob = BundleProblem(prob.focal_length, prob.principal_point, prob.eo0, prob.eo_sigma,
                         prob.xyz0, prob.prior_xyz, prob.prior_weight,
                         np.append(prob.obs_point, 0), np.append(prob.obs_image,
                                                                  prob.obs_image[k0]),
                         np.vstack([prob.obs_xy, extra]),
                         np.vstack([prob.obs_sigma, prob.obs_sigma[k0]]))
    res = adjust(prob)
    eo, xyz, s0sq, q, _, _ = _dense_adjust(prob)
    assert np.abs(res.xyz - xyz).max() <= 1e-9 * np.abs(xyz - prob.xyz0).max()
    assert res.sigma0_squared == pytest.approx(s0sq, rel=1e-9)
    n, m = prob.n_images, prob.n_points
    qp = q[6 * n:, 6 * n:].reshape(m, 3, m, 3)[np.arange(m), :, np.arange(m), :]
    np.testing.assert_allclose(res.point_cov, s0sq * qp, rtol=1e-9, atol=0)


def test_one_blas_thread_inside_the_adjustment_and_restored_after():
    controls = bundle._openblas_controls()
    before = [int(get()) for _, get in controls]
    with bundle._single_blas_thread():
        assert all(int(get()) == 1 for _, get in controls)
    assert [int(get()) for _, get in controls] == before


def test_simulated_block_layout_overlaps_and_truth():
    blk = make_block(2, 4, n_shape_points=400, n_control=8, n_tie=20, seed=3)
    prob = blk.problem
    counts = np.bincount(prob.obs_point, minlength=prob.n_points)
    assert counts.min() >= 2  # every point is seen on two images at least
    strips = blk.strip[prob.obs_image]
    per_point = np.zeros((prob.n_points, 2), bool)
    per_point[prob.obs_point, strips] = True
    assert per_point.all(axis=1).any()  # the 30 % side overlap: points on both strips
    # image coordinates are the truth projected plus noise of the stated sigma
    pred = project(blk.true_eo[prob.obs_image], blk.true_xyz[prob.obs_point],
                   prob.focal_length)
    noise = prob.obs_xy - pred
    assert 0.8 * 0.015 < noise.std() < 1.2 * 0.015
    assert np.all(np.abs(prob.obs_xy) < 115.0)


def test_blas_controls_are_scanned_once_until_a_module_is_imported(monkeypatch):
    """The scan of /proc/self/maps runs once per process and set of imported modules
    (it cost 3 ms per adjustment, 8 adjustments per pipeline.run)."""
    from vectoradjust.adjust.bundle import blas

    calls = []
    monkeypatch.setattr(blas, "_scan_openblas", lambda: calls.append(1) or ["c"])
    monkeypatch.setattr(blas, "_CONTROLS_CACHE", {})
    assert blas._openblas_controls() == ["c"] and blas._openblas_controls() == ["c"]
    assert len(calls) == 1
    import sys
    import types

    monkeypatch.setitem(sys.modules, "vectoradjust_test_new_module", types.ModuleType("x"))
    assert blas._openblas_controls() == ["c"] and len(calls) == 2  # a new import: again
