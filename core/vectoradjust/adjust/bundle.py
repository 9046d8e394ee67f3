"""Weighted least-squares bundle adjustment over the reduced camera system.

Unknowns are the exterior orientation (6 per image) and the ground coordinates of
every object point (3 per point). Observations are image coordinates, optional priors
on object points (control points heavy, road shape points light, tie points none) and
optional priors on the exterior orientation. Gauss-Newton iterates on the normal
equations ``N dx = t`` with ``N = [[N_ee, N_ep], [N_pe, N_pp]]``; the point blocks are
eliminated (Schur complement) so that only the small reduced camera system
``S = N_ee - N_ep N_pp^-1 N_pe`` is solved (``DESIGN.md`` section 3).

Nothing here loops over points: observations are processed as arrays, and points that
are seen by the same set of images form a group whose Schur update is one matrix
product.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import scipy.linalg

from vectoradjust.errors import CancelledError, NonConvergenceError, SingularityError
from vectoradjust.sensor.collinearity import partials, project, rotation_matrix

__all__ = [
    "BundleProblem",
    "BundleResult",
    "adjust",
    "intersect",
    "ray_intersection",
    "inv3x3",
]

ProgressCallback = Callable[[float, str], None]


def inv3x3(a: np.ndarray) -> np.ndarray:
    """Closed-form inverse of a stack of 3x3 matrices ``(..., 3, 3)``.

    Singular blocks give ``inf``/``nan`` entries; callers check the determinant.
    """
    a = np.asarray(a, float)
    c00 = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    c01 = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    c02 = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    c10 = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    c11 = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    c12 = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    c20 = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    c21 = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    c22 = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    det = a[..., 0, 0] * c00 + a[..., 0, 1] * c10 + a[..., 0, 2] * c20
    out = np.stack(
        [np.stack([c00, c01, c02], -1), np.stack([c10, c11, c12], -1),
         np.stack([c20, c21, c22], -1)],
        -2,
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        return out / det[..., None, None]


def _block_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum ``values`` (k, ...) into ``n`` bins by ``index`` (k,), vectorised."""
    k = values.shape[0]
    inner = values.shape[1:]
    size = int(np.prod(inner)) if inner else 1
    flat = values.reshape(k, size)
    idx = (index[:, None] * size + np.arange(size)[None, :]).ravel()
    out = np.bincount(idx, weights=flat.ravel(), minlength=n * size)
    return out.reshape((n,) + inner)


@dataclass
class BundleProblem:
    """Arrays that define one adjustment.

    Attributes
    ----------
    focal_length : float
        mm.
    principal_point : numpy.ndarray, shape (2,)
        mm.
    eo0 : numpy.ndarray, shape (n, 6)
        Approximate exterior orientation (m, rad); also the prior mean where priors exist.
    eo_sigma : numpy.ndarray, shape (n, 6)
        Prior sigmas (m, rad); ``inf`` (or NaN) for a free parameter.
    xyz0 : numpy.ndarray, shape (m, 3)
        Approximate point coordinates (start of the iteration).
    prior_xyz : numpy.ndarray, shape (m, 3)
        Prior point coordinates (ignored where ``prior_weight`` is zero).
    prior_weight : numpy.ndarray, shape (m, 3, 3)
        Weight matrix (inverse covariance) of the prior; zero for tie points.
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
        Point and image index of each image observation.
    obs_xy : numpy.ndarray, shape (k, 2)
        Observed photo coordinates (mm).
    obs_sigma : numpy.ndarray, shape (k, 2)
        Their standard deviations (mm).
    """

    focal_length: float
    principal_point: np.ndarray
    eo0: np.ndarray
    eo_sigma: np.ndarray
    xyz0: np.ndarray
    prior_xyz: np.ndarray
    prior_weight: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray
    obs_sigma: np.ndarray
    #: where the iteration starts for the exterior orientation (default ``eo0``, which
    #: is also the prior mean); a warm start for repeated adjustments
    eo_start: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.principal_point = np.asarray(self.principal_point, float).reshape(2)
        self.eo0 = np.asarray(self.eo0, float).reshape(-1, 6)
        self.eo_sigma = np.asarray(self.eo_sigma, float).reshape(-1, 6)
        self.xyz0 = np.asarray(self.xyz0, float).reshape(-1, 3)
        self.prior_xyz = np.asarray(self.prior_xyz, float).reshape(-1, 3)
        self.prior_weight = np.asarray(self.prior_weight, float).reshape(-1, 3, 3)
        self.obs_point = np.asarray(self.obs_point, np.int64)
        self.obs_image = np.asarray(self.obs_image, np.int64)
        self.obs_xy = np.asarray(self.obs_xy, float).reshape(-1, 2)
        self.obs_sigma = np.asarray(self.obs_sigma, float).reshape(-1, 2)

    @property
    def n_images(self) -> int:
        """Number of images."""
        return self.eo0.shape[0]

    @property
    def n_points(self) -> int:
        """Number of object points."""
        return self.xyz0.shape[0]

    @property
    def eo_weight(self) -> np.ndarray:
        """Diagonal prior weights of the exterior orientation (0 for free parameters)."""
        s = self.eo_sigma
        with np.errstate(divide="ignore"):
            w = np.where(np.isfinite(s) & (s > 0), 1.0 / np.where(s > 0, s, 1.0) ** 2, 0.0)
        return w

    @property
    def has_prior(self) -> np.ndarray:
        """Points with a coordinate prior (control and shape points)."""
        return np.abs(self.prior_weight).reshape(-1, 9).sum(axis=1) > 0

    def counts(self) -> tuple[int, int]:
        """Number of observations ``n`` and of unknowns ``u`` (DESIGN section 3)."""
        n = 2 * len(self.obs_point) + 3 * int(self.has_prior.sum())
        n += int((self.eo_weight > 0).sum())
        u = 6 * self.n_images + 3 * self.n_points
        return n, u


@dataclass
class _Groups:
    """Observations arranged by points that share the same set of images."""

    images: list  # per group: (c,) image indices
    points: list  # per group: (g,) point indices
    obs: list  # per group: (g, c) observation indices


def _group_observations(obs_point: np.ndarray, obs_image: np.ndarray, n_points: int) -> _Groups:
    order = np.lexsort((obs_image, obs_point))
    counts = np.bincount(obs_point, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    groups = _Groups([], [], [])
    for c in np.unique(counts[counts > 0]):
        pts = np.flatnonzero(counts == c)
        obs_mat = order[starts[pts][:, None] + np.arange(c)[None, :]]
        img_mat = obs_image[obs_mat]
        keys, inverse = np.unique(img_mat, axis=0, return_inverse=True)
        inverse = np.asarray(inverse).reshape(-1)
        sort = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[sort], np.arange(len(keys) + 1))
        for g in range(len(keys)):
            sel = sort[bounds[g] : bounds[g + 1]]
            groups.images.append(keys[g])
            groups.points.append(pts[sel])
            groups.obs.append(obs_mat[sel])
    return groups


@dataclass
class BundleResult:
    """Result of :func:`adjust`.

    Attributes
    ----------
    eo : numpy.ndarray, shape (n, 6)
        Adjusted exterior orientation (m, rad).
    xyz : numpy.ndarray, shape (m, 3)
        Adjusted object points.
    eo_cov : numpy.ndarray, shape (n, 6, 6)
        A-posteriori covariance of each image's EO (``sigma0^2 S^-1`` blocks).
    point_cov : numpy.ndarray, shape (m, 3, 3)
        A-posteriori covariance of each object point (cameras' uncertainty included).
    v_image : numpy.ndarray, shape (k, 2)
        Image residuals, adjusted minus observed (mm).
    v_point : numpy.ndarray, shape (m, 3)
        Point prior residuals, adjusted minus prior (m); NaN for points without prior.
    v_eo : numpy.ndarray, shape (n, 6)
        EO prior residuals; NaN for free parameters.
    vtpv : float
    n_obs, n_unknowns, dof : int
    sigma0_squared : float
        ``v'Pv / dof`` (NaN when dof = 0).
    iterations : int
    converged : bool
    history : list of dict
        Per iteration: vtpv before the step and the largest corrections.
    """

    eo: np.ndarray
    xyz: np.ndarray
    eo_cov: np.ndarray
    point_cov: np.ndarray
    v_image: np.ndarray
    v_point: np.ndarray
    v_eo: np.ndarray
    vtpv: float
    n_obs: int
    n_unknowns: int
    dof: int
    sigma0_squared: float
    iterations: int
    converged: bool
    history: list = field(default_factory=list)
    # factorisation kept for reliability and joint covariances (cofactors, no sigma0^2)
    s_inv: Optional[np.ndarray] = None
    npp_inv: Optional[np.ndarray] = None
    nep_obs: Optional[np.ndarray] = None
    a_eo: Optional[np.ndarray] = None
    a_pt: Optional[np.ndarray] = None
    problem: Optional[BundleProblem] = None

    #: "a-posteriori" (cofactors times sigma0^2), "a-priori" (times 1) or "groups" (times
    #: ``group_factor``: the variance factor of the groups whose sigma is known or estimated)
    covariance_scale: str = "a-posteriori"
    group_factor: float = 1.0
    # database offsets estimated with the adjustment (adjust/offsets.py), None without:
    # their cofactor Q_TT (q, q), Q_xx B per point (m, 3, q), S^-1 Z' B (6n, q) and the
    # offsets' design matrix G per point (m, 3, q)
    offset_cofactor: Optional[np.ndarray] = None
    offset_qb: Optional[np.ndarray] = None
    offset_u: Optional[np.ndarray] = None
    offset_g: Optional[np.ndarray] = None

    def eo_cofactor(self) -> np.ndarray:
        """Cofactor matrix (6n, 6n) of the exterior orientation, offsets included."""
        if self.offset_cofactor is None:
            return self.s_inv
        u = self.offset_u
        q = self.s_inv + u @ self.offset_cofactor @ u.T
        return 0.5 * (q + q.T)

    def offset_cross(self, pa, pb) -> np.ndarray:
        """The offsets' share ``(Q B)_a Q_TT (Q B)_b'`` of point cofactors, (p, 3, 3)."""
        pa = np.asarray(pa, np.int64).reshape(-1)
        pb = np.asarray(pb, np.int64).reshape(-1)
        if self.offset_cofactor is None:
            return np.zeros((len(pa), 3, 3))
        qb = self.offset_qb
        return np.einsum("piq,qr,pjr->pij", qb[pa], self.offset_cofactor, qb[pb])

    @property
    def variance_factor(self) -> float:
        """The factor applied to cofactors: sigma0^2 (1 when dof = 0, or a-priori)."""
        if self.covariance_scale == "a-priori":
            return 1.0
        if self.covariance_scale == "groups":
            return float(self.group_factor)
        s = self.sigma0_squared
        return float(s) if np.isfinite(s) else 1.0

    def set_covariance_scale(self, scale: str, factor: float = 1.0) -> None:
        """Scale the covariances a posteriori (by sigma0^2), a priori (by 1) or by the
        groups' variance factor ``factor`` (``scale = "groups"``), in place."""
        if scale not in ("a-posteriori", "a-priori", "groups"):
            raise ValueError(f"covariance scale {scale!r}: use 'a-posteriori' or 'a-priori'")
        old = self.variance_factor
        self.covariance_scale = scale
        self.group_factor = float(factor)
        ratio = self.variance_factor / old
        self.eo_cov = self.eo_cov * ratio
        if self.point_cov is not None:
            self.point_cov = self.point_cov * ratio

    def joint_covariance(self, points) -> np.ndarray:
        """Full a-posteriori covariance of a set of object points.

        Parameters
        ----------
        points : array_like of int
            Point indices (length ``p``).

        Returns
        -------
        numpy.ndarray, shape (3p, 3p)
            ``sigma0^2 [D + Z S^-1 Z']`` with ``D`` block-diagonal ``N_pp^-1`` and
            ``Z = N_pp^-1 N_pe``; no full inverse of ``N`` is formed.
        """
        pts_in = np.asarray(points, np.int64).reshape(-1)
        pts, inverse = np.unique(pts_in, return_inverse=True)
        if len(pts) != len(pts_in):  # repeated points: compute once, then expand
            full = self.joint_covariance(pts)
            idx = (3 * np.asarray(inverse).reshape(-1)[:, None] + np.arange(3)).ravel()
            return full[np.ix_(idx, idx)]
        pts = pts_in
        prob = self.problem
        n = prob.n_images
        p = len(pts)
        # Z_j = Npp_inv_j sum_k (Nep_k)^T placed at the image of k  -> (p, 3, 6n)
        pos = np.full(prob.n_points, -1, np.int64)
        pos[pts] = np.arange(p)
        sel = np.flatnonzero(pos[prob.obs_point] >= 0)
        contrib = np.einsum("kab,kbc->kac", self.npp_inv[prob.obs_point[sel]],
                            np.transpose(self.nep_obs[sel], (0, 2, 1)))  # (s, 3, 6)
        z = np.zeros((p, 3, n, 6))
        np.add.at(z, (pos[prob.obs_point[sel]], slice(None), prob.obs_image[sel]),
                  contrib)
        z = z.reshape(3 * p, 6 * n)
        cov = z @ self.s_inv @ z.T
        d = np.zeros((3 * p, 3 * p))
        for a in range(3):
            for b in range(3):
                d[a::3, b::3] += np.diag(self.npp_inv[pts, a, b])
        if self.offset_cofactor is not None:  # the database offsets' share
            qb = self.offset_qb[pts].reshape(3 * p, -1)
            cov = cov + qb @ self.offset_cofactor @ qb.T
        return self.variance_factor * (d + cov)


def _assemble(prob: BundleProblem, eo: np.ndarray, xyz: np.ndarray):
    """Normal-equation pieces at the current estimate."""
    f = prob.focal_length
    e = eo[prob.obs_image]
    p = xyz[prob.obs_point]
    pred = project(e, p, f, prob.principal_point)
    ell = prob.obs_xy - pred  # misclosure, observed minus computed
    a_eo, a_pt = partials(e, p, f)
    w = 1.0 / prob.obs_sigma**2
    wae = a_eo * w[:, :, None]
    wap = a_pt * w[:, :, None]
    n_img, n_pts = prob.n_images, prob.n_points
    nee = _block_sum(prob.obs_image, np.einsum("kri,krj->kij", a_eo, wae), n_img)
    npp = _block_sum(prob.obs_point, np.einsum("kri,krj->kij", a_pt, wap), n_pts)
    nep = np.einsum("kri,krj->kij", wae, a_pt)
    te = _block_sum(prob.obs_image, np.einsum("kri,kr->ki", wae, ell), n_img)
    tp = _block_sum(prob.obs_point, np.einsum("kri,kr->ki", wap, ell), n_pts)
    # point priors
    npp += prob.prior_weight
    dprior = np.where(prob.has_prior[:, None], prob.prior_xyz - xyz, 0.0)
    tp += np.einsum("mij,mj->mi", prob.prior_weight, dprior)
    # EO priors
    we = prob.eo_weight
    idx = np.arange(6)
    nee[:, idx, idx] += we
    te += we * np.where(we > 0, prob.eo0 - eo, 0.0)
    return pred, ell, a_eo, a_pt, nee, npp, nep, te, tp


def _reduced_system(prob, groups, nee, npp_inv, nep, te, tp):
    n = prob.n_images
    s = np.zeros((n, 6, n, 6))
    s[np.arange(n), :, np.arange(n), :] = nee
    rhs = te.copy()
    ynep = np.einsum("kij,kjl->kil", nep, npp_inv[prob.obs_point])  # Y_k = Nep_k Npp^-1
    rhs -= _block_sum(prob.obs_image, np.einsum("kij,kj->ki", ynep, tp[prob.obs_point]), n)
    for imgs, obs in zip(groups.images, groups.obs):
        c = len(imgs)
        g = obs.shape[0]
        yr = ynep[obs].transpose(1, 2, 0, 3).reshape(c * 6, g * 3)
        er = nep[obs].transpose(1, 2, 0, 3).reshape(c * 6, g * 3)
        block = (yr @ er.T).reshape(c, 6, c, 6)
        s[np.ix_(imgs, np.arange(6), imgs, np.arange(6))] -= block
    return s.reshape(6 * n, 6 * n), rhs.reshape(6 * n), ynep


def _check_points_determined(prob: BundleProblem, npp: np.ndarray) -> None:
    det = np.linalg.det(npp)
    scale = np.einsum("mii->m", npp) ** 3
    bad = np.flatnonzero(~(np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)))
    if bad.size:
        raise SingularityError(
            f"{bad.size} object point(s) cannot be determined (e.g. point index {bad[0]}): "
            "a point without a coordinate prior must be measured on at least two images",
            "Measure tie points on two or more images, or remove them from the measurements",
            details={"points": bad.tolist()},
        )


@dataclass
class _Step:
    """One Gauss-Newton step: the corrections and the normal-equation pieces it used."""

    dx_e: np.ndarray
    dx_p: np.ndarray
    ell: np.ndarray
    a_eo: np.ndarray
    a_pt: np.ndarray
    nep: np.ndarray
    npp_inv: np.ndarray
    ynep: np.ndarray
    factor: tuple


def _solve_reduced(s: np.ndarray, rhs: np.ndarray):
    """Cholesky factor of the reduced camera system and its solution ``(n, 6)``."""
    try:
        factor = scipy.linalg.cho_factor(s, lower=False, check_finite=True)
        dx_e = scipy.linalg.cho_solve(factor, rhs).reshape(-1, 6)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SingularityError(
            "The reduced normal equations are singular: the exterior orientation is not "
            "determined (datum defect)",
            "Give at least 3 well-spread, non-collinear control points measured on the "
            "images, or priors on the exterior orientation",
        ) from exc
    return factor, dx_e


def _gauss_newton_step(prob: BundleProblem, groups: _Groups, eo: np.ndarray, xyz: np.ndarray,
                       check_points: bool) -> _Step:
    """Corrections of one iteration: reduced camera system, then point back-substitution."""
    pred, ell, a_eo, a_pt, nee, npp, nep, te, tp = _assemble(prob, eo, xyz)
    if check_points:
        _check_points_determined(prob, npp)
    npp_inv = inv3x3(npp)
    s, rhs, ynep = _reduced_system(prob, groups, nee, npp_inv, nep, te, tp)
    factor, dx_e = _solve_reduced(s, rhs)
    back = _block_sum(
        prob.obs_point, np.einsum("kji,kj->ki", nep, dx_e[prob.obs_image]), prob.n_points
    )
    dx_p = np.einsum("mij,mj->mi", npp_inv, tp - back)
    return _Step(dx_e=dx_e, dx_p=dx_p, ell=ell, a_eo=a_eo, a_pt=a_pt, nep=nep,
                 npp_inv=npp_inv, ynep=ynep, factor=factor)


def _check_diverged(it: int, max_pos: float, max_ang: float, history: list) -> None:
    """Raise :class:`NonConvergenceError` on non-finite or too large corrections."""
    if not (np.isfinite(max_pos) and np.isfinite(max_ang)) or max_ang > 1.0:
        raise NonConvergenceError(
            f"The adjustment diverged at iteration {it} (corrections of "
            f"{max_pos:.3g} m and {max_ang:.3g} rad)",
            "Check the approximate exterior orientation in [[images]] (position within "
            "a fraction of the flying height, attitude in degrees) and the image measurement "
            "units (mm)",
            details={"iteration": it, "history": history},
        )


def _raise_not_converged(max_iterations: int, history: list) -> None:
    """Raise :class:`NonConvergenceError` for an iteration that ran out of steps."""
    raise NonConvergenceError(
        f"The adjustment did not converge in {max_iterations} iterations (last corrections "
        f"{history[-1]['max_position_correction']:.3g} m, "
        f"{history[-1]['max_angle_correction']:.3g} rad)",
        "Raise [adjustment] max_iterations, improve the approximate exterior orientation, "
        "or look for blunders in the measurements",
        details={"history": history},
    )


def _covariances(prob: BundleProblem, groups: _Groups, step: _Step, s0sq: float,
                 compute_covariance: bool):
    """``S^-1``, the EO covariances and (optionally) the point covariances."""
    n = prob.n_images
    s_inv = scipy.linalg.cho_solve(step.factor, np.eye(6 * n))
    s_inv = 0.5 * (s_inv + s_inv.T)
    vf = s0sq if np.isfinite(s0sq) else 1.0
    eo_cov = vf * s_inv.reshape(n, 6, n, 6)[np.arange(n), :, np.arange(n), :]
    point_cov = None
    if compute_covariance:
        point_cov = vf * _point_cofactors(prob, groups, step.npp_inv, step.ynep, s_inv)
    return s_inv, eo_cov, point_cov


def _converged_result(prob: BundleProblem, groups: _Groups, eo: np.ndarray, xyz: np.ndarray,
                      step: _Step, it: int, history: list,
                      compute_covariance: bool) -> BundleResult:
    """Residuals, sigma0 and covariances at the converged estimate, as a BundleResult."""
    pred_final = project(eo[prob.obs_image], xyz[prob.obs_point], prob.focal_length,
                         prob.principal_point)
    ell_final = prob.obs_xy - pred_final
    _check_in_front(prob, eo, xyz)
    vtpv = _vtpv(prob, ell_final, xyz, eo)
    n_obs, n_unk = prob.counts()
    dof = n_obs - n_unk
    s0sq = vtpv / dof if dof > 0 else float("nan")
    s_inv, eo_cov, point_cov = _covariances(prob, groups, step, s0sq, compute_covariance)
    has_prior = prob.has_prior
    v_point = np.where(has_prior[:, None], xyz - prob.prior_xyz, np.nan)
    we = prob.eo_weight
    v_eo = np.where(we > 0, eo - prob.eo0, np.nan)
    return BundleResult(
        eo=eo, xyz=xyz, eo_cov=eo_cov, point_cov=point_cov, v_image=-ell_final,
        v_point=v_point, v_eo=v_eo, vtpv=float(vtpv), n_obs=n_obs, n_unknowns=n_unk, dof=dof,
        sigma0_squared=float(s0sq), iterations=it, converged=True, history=history,
        s_inv=s_inv, npp_inv=step.npp_inv, nep_obs=step.nep, a_eo=step.a_eo, a_pt=step.a_pt,
        problem=prob,
    )


def adjust(
    prob: BundleProblem,
    *,
    max_iterations: int = 20,
    tolerance_position: float = 1e-4,
    tolerance_angle: float = 1e-8,
    progress: Optional[ProgressCallback] = None,
    is_cancelled: Optional[Callable[[], bool]] = None,
    compute_covariance: bool = True,
) -> BundleResult:
    """Run the Gauss-Newton bundle adjustment.

    Parameters
    ----------
    prob : BundleProblem
    max_iterations : int
    tolerance_position : float
        Converged when every position correction (m) is below this ...
    tolerance_angle : float
        ... and every angle correction (rad) below this.
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional
        Polled once per iteration; a true value raises :class:`CancelledError`.
    compute_covariance : bool
        Whether to compute the a-posteriori covariances of the points.

    Returns
    -------
    BundleResult

    Raises
    ------
    NonConvergenceError
        If the iteration diverges or does not converge within ``max_iterations``.
    SingularityError
        If the normal equations are singular (datum defect, undetermined points).
    """
    eo = (prob.eo0 if prob.eo_start is None else np.asarray(prob.eo_start, float)).copy()
    xyz = prob.xyz0.copy()
    groups = _group_observations(prob.obs_point, prob.obs_image, prob.n_points)
    history: list = []
    converged = False
    best = np.inf
    it = 0
    for it in range(1, max_iterations + 1):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("The adjustment was cancelled", "Run it again when ready")
        step = _gauss_newton_step(prob, groups, eo, xyz, check_points=it == 1)
        vtpv_now = _vtpv(prob, step.ell, xyz, eo)
        max_pos = max(np.abs(step.dx_e[:, :3]).max(initial=0.0),
                      np.abs(step.dx_p).max(initial=0.0))
        max_ang = np.abs(step.dx_e[:, 3:]).max(initial=0.0)
        history.append({"iteration": it, "vtpv": vtpv_now, "max_position_correction": max_pos,
                        "max_angle_correction": max_ang})
        _check_diverged(it, max_pos, max_ang, history)
        best = min(best, vtpv_now)
        eo += step.dx_e
        xyz += step.dx_p
        if progress is not None:
            progress(min(0.9, it / max_iterations), f"iteration {it}: v'Pv = {vtpv_now:.6g}")
        if max_pos < tolerance_position and max_ang < tolerance_angle:
            converged = True
            break
    if not converged:
        _raise_not_converged(max_iterations, history)
    result = _converged_result(prob, groups, eo, xyz, step, it, history, compute_covariance)
    if progress is not None:
        progress(1.0, f"converged after {it} iterations")
    return result


def _point_cofactors(prob, groups, npp_inv, ynep, s_inv) -> np.ndarray:
    """``N_pp^-1 + N_pp^-1 N_pe S^-1 N_ep N_pp^-1`` per point, by image-set groups."""
    n = prob.n_images
    sinv4 = s_inv.reshape(n, 6, n, 6)
    q = npp_inv.copy()
    for imgs, pts, obs in zip(groups.images, groups.points, groups.obs):
        y = ynep[obs]  # (g, c, 6, 3)
        sg = sinv4[np.ix_(imgs, np.arange(6), imgs, np.arange(6))]  # (c, 6, c, 6)
        t = np.einsum("jaik,aibl->jkbl", y, sg, optimize=True)
        q[pts] += np.einsum("jkbl,jblm->jkm", t, y, optimize=True)
    return 0.5 * (q + np.transpose(q, (0, 2, 1)))


def _vtpv(prob: BundleProblem, ell: np.ndarray, xyz: np.ndarray, eo: np.ndarray) -> float:
    w = 1.0 / prob.obs_sigma**2
    total = float(np.sum(ell * ell * w))
    d = np.where(prob.has_prior[:, None], xyz - prob.prior_xyz, 0.0)
    total += float(np.einsum("mi,mij,mj->", d, prob.prior_weight, d))
    we = prob.eo_weight
    de = np.where(we > 0, eo - prob.eo0, 0.0)
    total += float(np.sum(we * de * de))
    return total


def _check_in_front(prob: BundleProblem, eo: np.ndarray, xyz: np.ndarray) -> None:
    m = rotation_matrix(eo[prob.obs_image, 3], eo[prob.obs_image, 4], eo[prob.obs_image, 5])
    d = xyz[prob.obs_point] - eo[prob.obs_image, :3]
    q = np.einsum("kj,kj->k", m[:, 2, :], d)
    if np.any(q >= 0):
        k = int(np.flatnonzero(q >= 0)[0])
        raise NonConvergenceError(
            f"The adjustment converged to a solution with object points behind the camera "
            f"(observation {k})",
            "Check the approximate exterior orientation and the sign of the photo coordinates "
            "(x right, y up, mm)",
        )


def ray_intersection(
    eo: np.ndarray,
    obs_point: np.ndarray,
    obs_image: np.ndarray,
    obs_xy: np.ndarray,
    n_points: int,
    focal_length: float,
    principal_point=(0.0, 0.0),
) -> np.ndarray:
    """Linear least-squares intersection of image rays (approximations for points).

    Returns the point closest to all of its rays, ``(n_points, 3)``; points with fewer
    than two rays get NaN.
    """
    e = eo[obs_image]
    m = rotation_matrix(e[:, 3], e[:, 4], e[:, 5])
    v = np.column_stack([
        obs_xy[:, 0] - principal_point[0],
        obs_xy[:, 1] - principal_point[1],
        np.full(len(obs_xy), -float(focal_length)),
    ])
    d = np.einsum("kji,kj->ki", m, v)  # M^T v: direction in ground frame
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    a = _block_sum(obs_point, proj, n_points)
    b = _block_sum(obs_point, np.einsum("kij,kj->ki", proj, e[:, :3]), n_points)
    counts = np.bincount(obs_point, minlength=n_points)
    x = np.einsum("mij,mj->mi", inv3x3(a), b)
    x[counts < 2] = np.nan
    return x


def intersect(
    eo: np.ndarray,
    obs_point: np.ndarray,
    obs_image: np.ndarray,
    obs_xy: np.ndarray,
    obs_sigma: np.ndarray,
    n_points: int,
    focal_length: float,
    principal_point=(0.0, 0.0),
    *,
    eo_cov_full: Optional[np.ndarray] = None,
    variance_factor: float = 1.0,
    max_iterations: int = 20,
    tolerance: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward intersection of points from fixed (adjusted) exterior orientation.

    Used for check points, which stay out of the adjustment. The covariance includes
    the exterior orientation's uncertainty:
    ``C = s0^2 Npp^-1 + Npp^-1 N_pe C_ee N_ep Npp^-1``.

    Parameters
    ----------
    eo : numpy.ndarray, shape (n, 6)
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
    obs_xy, obs_sigma : numpy.ndarray, shape (k, 2)
    n_points : int
    focal_length : float
    principal_point : (float, float)
    eo_cov_full : numpy.ndarray, shape (6n, 6n), optional
        Full a-posteriori covariance of all exterior orientations.
    variance_factor : float
        sigma0^2 applied to the image weights' cofactors.
    max_iterations : int
    tolerance : float
        Largest coordinate correction (m) at convergence.

    Returns
    -------
    xyz : numpy.ndarray, shape (n_points, 3)
        NaN for points with fewer than two rays.
    cov : numpy.ndarray, shape (n_points, 3, 3)
    """
    pp = np.asarray(principal_point, float)
    xyz = ray_intersection(eo, obs_point, obs_image, obs_xy, n_points, focal_length, pp)
    ok = np.isfinite(xyz).all(axis=1)
    use = ok[obs_point]
    op, oi, oxy, osg = obs_point[use], obs_image[use], obs_xy[use], obs_sigma[use]
    x = np.where(ok[:, None], xyz, 0.0)
    w = 1.0 / osg**2
    for _ in range(max_iterations):
        pred = project(eo[oi], x[op], focal_length, pp)
        ell = oxy - pred
        a_eo, a_pt = partials(eo[oi], x[op], focal_length)
        wap = a_pt * w[:, :, None]
        npp = _block_sum(op, np.einsum("kri,krj->kij", a_pt, wap), n_points)
        npp[~ok] = np.eye(3)
        tp = _block_sum(op, np.einsum("kri,kr->ki", wap, ell), n_points)
        dx = np.einsum("mij,mj->mi", inv3x3(npp), tp)
        x += dx
        if np.abs(dx).max(initial=0.0) < tolerance:
            break
    a_eo, a_pt = partials(eo[oi], x[op], focal_length)
    wap = a_pt * w[:, :, None]
    npp = _block_sum(op, np.einsum("kri,krj->kij", a_pt, wap), n_points)
    npp[~ok] = np.eye(3)
    npp_inv = inv3x3(npp)
    cov = variance_factor * npp_inv
    if eo_cov_full is not None:
        n = eo.shape[0]
        nep = np.einsum("kri,krj->kij", a_eo * w[:, :, None], a_pt)  # (k, 6, 3)
        z = np.zeros((n_points, 3, n, 6))
        np.add.at(z, (op, slice(None), oi), np.transpose(nep, (0, 2, 1)))
        z = np.einsum("mab,mbc->mac", npp_inv, z.reshape(n_points, 3, 6 * n))
        cov = cov + np.einsum("mai,ij,mbj->mab", z, eo_cov_full, z)
    x[~ok] = np.nan
    cov[~ok] = np.nan
    return x, cov
