"""The result of an adjustment: :class:`BundleResult`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle.problem import BundleProblem
from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)

__all__ = ["BundleResult"]


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
    # with self-calibration: the image rows' partials by the nuisance parameters (k, 2, q)
    # (zero for the offsets' columns)
    offset_a: Optional[np.ndarray] = None

    #: the kept blocks that :meth:`release_factorisation` lets go
    RELEASABLE = ("npp_inv", "nep_obs", "a_eo", "a_pt", "offset_qb", "offset_g", "offset_a")

    def release_factorisation(self) -> None:
        """Let go of the per-point and per-observation blocks kept for covariances.

        ``npp_inv``, ``nep_obs``, ``a_eo``, ``a_pt``, ``offset_qb``, ``offset_g`` and the
        cached cofactors (about 1 GB at a million shape points). What was computed from
        them stays: ``point_cov``, ``eo_cov``, the reliability of the run, and the small
        ``s_inv``. Covariances between points
        (:func:`vectoradjust.accuracy.derived.cross_covariance`,
        :meth:`joint_covariance`) and reliability can no longer be computed from this
        result; they raise :class:`vectoradjust.errors.ProjectError`. The command line
        calls it when nothing it still has to write needs them.
        """
        for name in self.RELEASABLE:
            setattr(self, name, None)
        self.__dict__.pop("_cofactor_cache", None)

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

