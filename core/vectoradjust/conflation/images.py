"""What the images say: the measured shape points' image-only positions and covariance
(:func:`image_only`), their shared orientation error, the variance of a mean and the
sill's prior.

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.conflation.covariance import CovarianceModel
from vectoradjust.conflation.settings import SILL_PRIOR_DOF

__all__ = ["image_only"]


def _measured_objects(d):
    """Bundle point of every object point (-1: not measured), measured vertex mask."""
    sp = d.shape
    meas_v = np.asarray(d.vertex_point) >= 0
    obj_pt = np.full(sp.n_objects, -1, np.int64)
    obj_pt[sp.vertex_object[meas_v]] = d.vertex_point[meas_v]
    return obj_pt, meas_v


def _image_weights(q: np.ndarray, prior_weight: np.ndarray) -> tuple:
    """``Q^-1``, ``P_img = Q^-1 - P_prior``, where ``Q`` is usable (finite, positive
    definite) and where ``P_img`` is positive definite (a point on one image only has
    rank 2: not ok)."""
    usable = np.isfinite(q).all(axis=(1, 2))
    usable[usable] = np.linalg.eigvalsh(q[usable])[:, 0] > 0
    q_inv = np.broadcast_to(np.eye(3), q.shape).copy()
    q_inv[usable] = np.linalg.inv(q[usable])
    p_img = q_inv - prior_weight
    p_img = 0.5 * (p_img + np.swapaxes(p_img, 1, 2))
    ev = np.linalg.eigvalsh(p_img)
    ok = usable & (ev[:, 0] > 1e-6 * np.maximum(ev[:, 2], 1e-300))
    return q_inv, p_img, usable, ok


def image_only(result, problem, pts: np.ndarray, min_share: float = 0.1,
               scale: Optional[float] = None):
    """What the images alone say about measured shape points: position and covariance.

    The adjusted shape point is a weighted mean of the images' intersection and the
    database prior ``X_prior = X_db - G T``: ``X_hat - X_prior = Q P_img (X_img -
    X_prior)`` with ``Q = (P_img + P_prior)^-1`` its cofactor, so its displacement is
    shrunk towards the database by the prior's weight. The collocation needs the
    unshrunk observation ``X_img = X_prior + P_img^-1 Q^-1 (X_hat - X_prior)`` with
    covariance ``scale P_img^-1``, ``P_img = Q^-1 - P_prior`` (per point; the
    correlation with other points through the orientation is left out).

    Parameters
    ----------
    result : BundleResult
    problem : BundleProblem
        The final problem (priors).
    pts : numpy.ndarray of int
        Bundle points.
    min_share : float
        An axis where the images carry less than this share of the weight is NaN
        (the images say next to nothing there).
    scale : float, optional
        Variance factor of the images' share (default: the run's). An a-posteriori
        sigma0^2 driven by the databases' residuals (a correlated error the prior
        does not know) says nothing about the images; :func:`conflate_database` passes
        the image group's ``v'Pv / r``.

    Returns
    -------
    xyz : numpy.ndarray, shape (p, 3)
    var : numpy.ndarray, shape (p, 3)
        Variances per axis (m^2).
    """
    vf = result.variance_factor
    scale = vf if scale is None or not np.isfinite(scale) else float(scale)
    q_inv, p_img, usable, ok = _image_weights(result.point_cov[pts] / vf, problem
                                              .prior_weight[pts])
    npp_inv = getattr(result, "npp_inv", None)
    redo = usable & ~ok
    if redo.any() and npp_inv is not None:
        # the marginal covariance holds the orientation's (and offsets') shared error;
        # where it exceeds what the prior allows (weak control: P_img not positive),
        # take the point given the adjusted orientation (N_pp^-1), whose weight is the
        # images' and the prior's alone
        qi2, pi2, us2, ok2 = _image_weights(np.asarray(npp_inv, float)[pts[redo]],
                                            problem.prior_weight[pts[redo]])
        q_inv[redo], p_img[redo], ok[redo] = qi2, pi2, ok2 & us2
    share = np.einsum("nii->ni", p_img) / np.einsum("nii->ni", q_inv)
    q_img = np.full_like(p_img, np.nan)
    q_img[ok] = np.linalg.inv(p_img[ok])
    prior = problem.prior_xyz[pts]
    shift = np.einsum("nij,njk,nk->ni", q_img, q_inv, result.xyz[pts] - prior)
    var = scale * np.einsum("nii->ni", q_img)
    bad = (share < min_share) | ~ok[:, None]
    xyz = np.where(bad, np.nan, prior + shift)
    return xyz, np.where(bad, np.nan, var)


def _orientation_basis(result, problem, pts: np.ndarray, scale: float, axis: int = 2,
                       max_rank: int = 40) -> Optional[np.ndarray]:
    """The images' shared error of the image-only positions (:func:`image_only`) of the
    points ``pts`` on one axis, as a basis ``U`` (p, r): covariance ``U U'``.

    The adjusted points share the orientation's error: ``Z S^-1 Z'`` of their joint
    covariance (:meth:`BundleResult.joint_covariance`, ``Z = N_pp^-1 N_pe`` per point);
    the image-only position carries it through ``T = P_img^-1 Q^-1`` (the undoing of
    the prior's pull). Its rank is at most the orientation's 6 parameters per image:
    with at most ``max_rank`` of them ``U = Z L`` (``S^-1 = L L'``) exactly; with more,
    the directions above ``1e-6`` of the largest eigenvalue, at most ``max_rank``.
    Scaled by the images' variance factor ``scale``. None when the run kept no
    factorisation (nothing shared is then modelled).
    """
    if any(getattr(result, a, None) is None for a in ("s_inv", "npp_inv", "nep_obs")):
        return None
    import scipy.sparse as sps

    prob = result.problem
    pts = np.asarray(pts, np.int64)
    p, n6 = len(pts), 6 * prob.n_images
    q = result.point_cov[pts] / result.variance_factor
    good = np.isfinite(q).all(axis=(1, 2))
    q_inv = np.linalg.pinv(np.where(good[:, None, None], q, np.eye(3)), hermitian=True)
    row = np.einsum("nj,njk->nk", np.linalg.pinv(q_inv - problem.prior_weight[pts],
                                                 hermitian=True)[:, axis], q_inv)  # T[axis]
    pos = np.full(prob.n_points, -1, np.int64)
    pos[pts] = np.arange(p)
    sel = np.flatnonzero(pos[prob.obs_point] >= 0)
    i = pos[prob.obs_point[sel]]
    contrib = np.einsum("kab,kcb->kac", result.npp_inv[prob.obs_point[sel]],
                        result.nep_obs[sel])  # (s, 3, 6): N_pp^-1 N_pe
    vals = np.einsum("kc,kcj->kj", row[i], contrib)
    z = sps.coo_matrix((vals.ravel(), (np.repeat(i, 6), (6 * prob.obs_image[sel][:, None]
                                                          + np.arange(6)).ravel())),
                       shape=(p, n6)).tocsr()
    s_inv = 0.5 * (result.s_inv + result.s_inv.T)
    try:  # S^-1 = half half' (Cholesky: unique, the same on every numpy build)
        half = np.linalg.cholesky(s_inv)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(s_inv)
        half = vec * np.sqrt(np.maximum(lam, 0.0))
    if n6 <= max_rank:  # few images: exact, no eigen-decomposition
        u = np.asarray(z @ half)
    else:
        ev, ew = np.linalg.eigh(half.T @ (z.T @ z).toarray() @ half)  # (6n, 6n)
        keep = np.flatnonzero(ev > 1e-6 * max(float(ev[-1]), 1e-300))[::-1][:max_rank]
        u = np.asarray(z @ (half @ ew[:, keep]))
    u = u * np.sqrt(scale)
    u[~good] = 0.0
    return u


def _image_scale(out) -> float:
    """Variance factor of the images' share: 1 with ``covariance_scale = "a-priori"``,
    else the image coordinates' ``v'Pv / r`` (summary ``variance_factors``), at least 1."""
    if getattr(out.result, "covariance_scale", "") == "a-priori":
        return 1.0
    groups = (out.summary.get("variance_factors") or {}).get("groups") or {}
    f = (groups.get("image") or {}).get("factor")
    return max(float(f), 1.0) if f is not None and np.isfinite(f) else float("nan")


def _mean_variance(result, pts: np.ndarray) -> np.ndarray:
    """Variance per axis (3,) of the mean of the adjusted points ``pts``.

    ``1' C 1 / p^2`` of their joint covariance ``s0^2 [D + Z S^-1 Z' + (QB) Q_TT (QB)']``
    (:meth:`BundleResult.joint_covariance`) without forming it: the sums of the
    per-point blocks ``D``, of the rows ``Z_j`` and of ``(QB)_j`` are enough. The errors
    the points share (the orientation, the offsets) count in full, each point's own
    error (its intersection) by ``1/p``. Without the factorisation: the mean of the
    points' variances (every error taken as shared, an upper bound).
    """
    pts = np.unique(np.asarray(pts, np.int64))
    if not len(pts):
        return np.zeros(3)
    if any(getattr(result, a, None) is None for a in ("s_inv", "npp_inv", "nep_obs")):
        return np.nanmean(np.einsum("nii->ni", result.point_cov[pts]), axis=0)
    prob = result.problem
    n, p = prob.n_images, len(pts)
    inset = np.zeros(prob.n_points, bool)
    inset[pts] = True
    sel = np.flatnonzero(inset[prob.obs_point])
    contrib = np.einsum("kab,kcb->kac", result.npp_inv[prob.obs_point[sel]],
                        result.nep_obs[sel])  # (s, 3, 6): N_pp^-1 N_pe per observation
    z = np.zeros((n, 3, 6))
    np.add.at(z, prob.obs_image[sel], contrib)
    z = np.transpose(z, (1, 0, 2)).reshape(3, 6 * n)
    total = result.npp_inv[pts].sum(axis=0) + z @ result.s_inv @ z.T
    if result.offset_cofactor is not None:
        qb = result.offset_qb[pts].sum(axis=0)
        total = total + qb @ result.offset_cofactor @ qb.T
    return result.variance_factor * np.diagonal(total).copy() / p ** 2


def _sill_prior(spec, cov: CovarianceModel) -> tuple:
    """``(S0, nu0)``: the database's statement about its field's variance, the prior of
    the horizontal sill (:func:`_ce90_table`).

    The database's stated horizontal sigma (``[[vectors]] sigma``, its error once the
    offset is removed) less its stated systematic part and the fitted white noise:
    ``S0 = max(sigma_h^2 - systematic_h^2 - n_db, 0)``, with :data:`SILL_PRIOR_DOF`
    degrees of freedom (the statement known to about +-50 % in variance). Where the
    measured points see the field on a few patches only (``sill_dof`` of a few: e.g.
    the images cover a part of the database) the data cannot tell how large the field
    is elsewhere; the statement then carries the far vertices' variance.
    """
    sig = np.asarray(spec.sigma, float)[:2]
    s0 = float(np.mean(sig ** 2) - spec.systematic_variance[0] - cov.nugget)
    return max(s0, 0.0), SILL_PRIOR_DOF
