"""Systematic database offsets as nuisance parameters of the adjustment (docs/method.md section 10).

A road database's vertices are ``X_db = X_true + T_db + s(x) + e_db``: besides the random
error, a database may be shifted as a whole (a datum or digitising bias ``T_db``). Left
out, that shift pulls the exterior orientation towards the database (thousands of
shape points outweigh a few control points) and the shape points' residuals are read as
random when they are not. Here each database gets a shift (horizontal ``[dX, dY]`` or
3D ``[dX, dY, dZ]``) estimated jointly with the bundle: the shape point prior becomes
``X_db = X + E T_db``.

The joint least-squares solution is found without changing the bundle's structure. For
a given ``T`` the bundle adjustment with prior means ``X_db - E T`` gives the points
``X(T)``; the normal equations of ``T`` then have the misclosure
``g = sum_j E' P_j (X_db,j - E T - X_j)`` and the reduced normal matrix
``W - B' Q_xx B`` (``W = sum E' P_j E``, ``B_j = P_j E``, ``Q_xx`` the bundle's point
cofactor matrix ``D + Z S^-1 Z'``), so ``T <- T + (W - B' Q_xx B)^-1 g`` is Newton's step
on the joint problem; it is exact for the linearised problem and repeated until ``g``
vanishes. ``B' Q_xx B`` and ``Q_xx B`` are computed from the bundle's factorisation in
time linear in the number of points (no dense matrix over points). The covariances then
include the offsets' uncertainty: ``Q_x <- Q_x + (Q_xx B) Q_TT (Q_xx B)'`` for each point
and ``Q_ee <- S^-1 + (S^-1 Z' B) Q_TT (S^-1 Z' B)'`` for the exterior orientation.
Numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem, BundleResult, _block_sum

__all__ = ["OffsetModel", "OffsetEstimate", "offset_normals", "newton_step",
           "apply_offsets", "shifted_problem", "OFFSET_KINDS"]

#: offset kinds and their parameters: shifts in m; rotation in rad and scale (unitless)
#: about the database's centroid (small-angle similarity); affine terms unitless
OFFSET_KINDS = {
    "none": (),
    "shift": ("X", "Y"),
    "shift3d": ("X", "Y", "Z"),
    "height": ("Z",),
    "similarity": ("X", "Y", "rotation", "scale"),
    "affine": ("X", "Y", "a11", "a12", "a21", "a22"),
}


def _kind_design(kind: str, xyz: np.ndarray, center: np.ndarray) -> np.ndarray:
    """``G`` (p, 3, q_kind) of one database's points: their offset is ``G T``."""
    params = OFFSET_KINDS[kind]
    g = np.zeros((len(xyz), 3, len(params)))
    dx = xyz[:, 0] - center[0]
    dy = xyz[:, 1] - center[1]
    for c, name in enumerate(params):
        if name == "X":
            g[:, 0, c] = 1.0
        elif name == "Y":
            g[:, 1, c] = 1.0
        elif name == "Z":
            g[:, 2, c] = 1.0
        elif name == "rotation":  # dX = -r dy, dY = r dx
            g[:, 0, c], g[:, 1, c] = -dy, dx
        elif name == "scale":  # dX = s dx, dY = s dy
            g[:, 0, c], g[:, 1, c] = dx, dy
        else:  # affine a11 a12 / a21 a22
            row = 0 if name in ("a11", "a12") else 1
            g[:, row, c] = dx if name in ("a11", "a21") else dy
    return g


def _columns(kinds) -> list:
    """Parameter indices of each database of the given offset kinds."""
    cols, k = [], 0
    for kind in kinds:
        n = len(OFFSET_KINDS[kind])
        cols.append(list(range(k, k + n)))
        k += n
    return cols


@dataclass
class OffsetModel:
    """Which bundle points belong to which database's offset, and how.

    Attributes
    ----------
    names : list of str
        Databases with an offset, in parameter order.
    kinds : list of str
        Offset kind of each (a key of :data:`OFFSET_KINDS`).
    points : list of numpy.ndarray of int
        Bundle point indices (shape points) of each.
    centers : list of numpy.ndarray
        Centroid (X, Y) of each database's points: the origin of rotation and scale.
    g : numpy.ndarray, shape (m, 3, q)
        The design matrix per bundle point (zero for points without offset).
    dems : list
        Per database: the :class:`~vectoradjust.model.DemGrid` its heights came from,
        or None. A database shifted horizontally by ``T`` takes its prior heights from
        the DEM at ``X_db - T`` (:func:`shifted_problem`): on sloping ground the height
        at the wrong position is wrong by the slope times the shift.
    """

    names: list
    kinds: list
    points: list
    centers: list
    g: np.ndarray
    dems: list = field(default_factory=list)
    #: (q,) prior weight of each parameter (1/sigma^2; 0: estimated freely): a control
    #: database's stated systematic part, carried with the datum, not estimated
    prior_weight: Optional[np.ndarray] = None
    #: databases whose height offset is their DEM's systematic error (added because the
    #: heights come from a DEM): the conflation leaves it to its own height rule
    dem_height: list = field(default_factory=list)

    @classmethod
    def build(cls, names, kinds, points, db_xyz: np.ndarray, dems=None,
              prior_sigma=None) -> OffsetModel:
        """The model of the given databases from the points' database coordinates;
        ``prior_sigma``: per database None (free) or the sigma of each parameter."""
        q = sum(len(OFFSET_KINDS[k]) for k in kinds)
        g = np.zeros((len(db_xyz), 3, q))
        centers, c0 = [], 0
        for kind, pts in zip(kinds, points):
            center = db_xyz[pts, :2].mean(axis=0)
            qk = len(OFFSET_KINDS[kind])
            g[pts, :, c0:c0 + qk] = _kind_design(kind, db_xyz[pts], center)
            centers.append(center)
            c0 += qk
        pw = np.zeros(q)
        for cols, sig in zip(_columns(kinds), prior_sigma or [None] * len(kinds)):
            if sig is not None:
                sig = np.broadcast_to(np.asarray(sig, float), (len(cols),))
                pw[cols] = np.where(sig > 0, 1.0 / np.where(sig > 0, sig, 1.0) ** 2, 0.0)
        return cls(list(names), list(kinds), list(points), centers, g,
                   list(dems) if dems is not None else [None] * len(names), pw)

    @property
    def n_params(self) -> int:
        """Number of offset parameters."""
        return int(self.g.shape[2])

    def columns(self) -> list:
        """Parameter indices of each database."""
        return _columns(self.kinds)

    @property
    def weights(self) -> np.ndarray:
        """(q,) prior weights of the parameters (zeros: all free)."""
        if self.prior_weight is None:
            return np.zeros(self.n_params)
        return np.asarray(self.prior_weight, float)

    def displacement(self, values: np.ndarray) -> np.ndarray:
        """The offset ``G T`` of every bundle point (m, 3)."""
        return np.einsum("miq,q->mi", self.g, values)


@dataclass
class OffsetEstimate:
    """Estimated offsets of the databases.

    Attributes
    ----------
    values : numpy.ndarray, shape (q,)
        All offset parameters (m), in the order of :meth:`OffsetModel.columns`.
    cofactor : numpy.ndarray, shape (q, q)
        Their cofactor matrix ``Q_TT`` (multiply by the variance factor).
    iterations : int
        Newton steps taken.
    gradient : float
        Largest remaining misclosure of the offsets' normal equations (m-weighted).
    history : list of dict
    """

    values: np.ndarray
    cofactor: np.ndarray
    iterations: int = 0
    gradient: float = float("nan")
    history: list = field(default_factory=list)


def _b_blocks(prob: BundleProblem, model: OffsetModel) -> np.ndarray:
    """``B_j = P_j G_j`` for every bundle point, (m, 3, q); zero for points without offset."""
    return np.matmul(prob.prior_weight, model.g)


def _q_times(result: BundleResult, b: np.ndarray):
    """``Q_xx B`` per point (m, 3, q) and ``S^-1 Z' B`` (6n, q) from the factorisation.

    With ``D = N_pp^-1`` (per point) and ``Y_k = N_ep,k D_j`` (observation ``k`` of point
    ``j`` on image ``i``): ``Z' B`` of image ``i`` is ``sum_k N_ep,k (D B)_j`` and
    ``Q_xx B = D B + D sum_k N_ep,k' (S^-1 Z' B)_i`` per point. Both sums are one matrix
    product per image (the observations of an image side by side); no (k, 6, 3) stack of
    ``Y_k`` and no gather of the images' blocks per observation.
    """
    prob = result.problem
    n = prob.n_images
    q = b.shape[2]
    npp_inv = result.npp_inv
    nep = result.nep_obs  # (k, 6, 3)
    db = np.matmul(npp_inv, b)  # D B (matmul: ~10x einsum on stacks of small blocks)
    order = np.argsort(prob.obs_image, kind="stable")
    starts = np.searchsorted(prob.obs_image[order], np.arange(n + 1))
    ztb = np.zeros((n, 6, q))
    for i in range(n):  # per image: (6, 3 k_i) @ (3 k_i, q)
        sel = order[starts[i]:starts[i + 1]]
        if sel.size:
            ztb[i] = np.tensordot(nep[sel], db[prob.obs_point[sel]], axes=([0, 2], [0, 1]))
    s_ztb = result.s_inv @ ztb.reshape(6 * n, q)  # (6n, q)
    s3 = s_ztb.reshape(n, 6, q)
    back = np.empty((len(order), 3, q))  # N_ep,k' (S^-1 Z' B)_i, observations by image
    for i in range(n):
        lo, hi = starts[i], starts[i + 1]
        if hi > lo:
            back[lo:hi] = np.tensordot(nep[order[lo:hi]], s3[i], axes=([1], [0]))
    zsz = np.matmul(np.swapaxes(npp_inv, 1, 2),
                    _block_sum(prob.obs_point[order], back, prob.n_points))
    return db + zsz, s_ztb, ztb.reshape(6 * n, q)


def offset_normals(result: BundleResult, model: OffsetModel, offsets: np.ndarray):
    """Reduced normal matrix and misclosure of the offsets at the bundle solution.

    Parameters
    ----------
    result : BundleResult
        A converged adjustment of :func:`shifted_problem` ``(..., offsets)``.
    model : OffsetModel
    offsets : numpy.ndarray, shape (q,)
        The offsets that problem was built with.

    Returns
    -------
    n_red : numpy.ndarray, shape (q, q)
        ``W - B' Q_xx B``.
    g : numpy.ndarray, shape (q,)
        ``sum_j E' P_j (X_db,j - E T - X_j)``; zero at the joint solution.
    qb : numpy.ndarray, shape (m, 3, q)
        ``Q_xx B`` per point.
    s_ztb : numpy.ndarray, shape (6n, q)
        ``S^-1 Z' B``.
    """
    prob = result.problem
    b = _b_blocks(prob, model)
    q = b.shape[2]
    qb, s_ztb, ztb = _q_times(result, b)
    # prior_xyz = X_db - G T, so X_db - G T - X = prior_xyz - X
    d = np.where(prob.has_prior[:, None], prob.prior_xyz - result.xyz, 0.0)
    w = model.g.reshape(-1, q).T @ b.reshape(-1, q)
    g = b.reshape(-1, q).T @ d.reshape(-1)
    btqb = b.reshape(-1, q).T @ qb.reshape(-1, q)
    pw = model.weights  # a prior on an offset (a control database's systematic part)
    n_red = w - btqb + np.diag(pw)
    g = g - pw * np.asarray(offsets, float)
    return 0.5 * (n_red + n_red.T), g, qb, s_ztb


def misclosure(result: BundleResult, model: OffsetModel,
               offsets: Optional[np.ndarray] = None) -> np.ndarray:
    """``g`` of :func:`offset_normals` alone (no ``Q_xx B``): the offsets' gradient at a
    bundle solution, zero at the joint solution (``offsets``: the values the problem was
    built with, needed where offsets have priors)."""
    prob = result.problem
    b = _b_blocks(prob, model)
    d = np.where(prob.has_prior[:, None], prob.prior_xyz - result.xyz, 0.0)
    g = b.reshape(-1, b.shape[2]).T @ d.reshape(-1)
    if offsets is not None:
        g = g - model.weights * np.asarray(offsets, float)
    return g


def newton_step(result: BundleResult, model: OffsetModel, offsets: np.ndarray):
    """One Newton step on the offsets; returns (new offsets, cofactor, |g|max, qb, s_ztb)."""
    n_red, g, qb, s_ztb = offset_normals(result, model, offsets)
    try:
        cof = np.linalg.inv(n_red)
    except np.linalg.LinAlgError:
        cof = np.linalg.pinv(n_red)
    return offsets + cof @ g, cof, float(np.abs(g).max(initial=0.0)), qb, s_ztb


def shifted_problem(base: BundleProblem, db_xyz: np.ndarray, model: OffsetModel,
                    offsets: np.ndarray, xyz0=None, eo_start=None) -> BundleProblem:
    """The bundle problem whose shape point priors are ``X_db - G T``.

    Parameters
    ----------
    base : BundleProblem
    db_xyz : numpy.ndarray, shape (m, 3)
        Database (unshifted) prior of every point.
    model : OffsetModel
    offsets : numpy.ndarray, shape (q,)
    xyz0, eo_start : numpy.ndarray, optional
        Start values of the points and the exterior orientation (a warm start; default:
        the base problem's).

    Notes
    -----
    A database whose heights came from a DEM (``model.dems``) gets its prior heights
    from the DEM at the shifted position ``X_db - T`` (minus a 3D shift's ``dZ``); where
    the shifted position leaves the DEM the database height is kept.
    """
    from vectoradjust.adjust.dem import bilinear

    shift = model.displacement(offsets)
    prior = db_xyz - shift
    for pts, dem in zip(model.points, model.dems or []):
        if dem is None or not len(pts):
            continue
        z = bilinear(dem.grid, dem.transform, prior[pts, :2], nodata=dem.nodata)
        prior[pts, 2] = np.where(np.isfinite(z), z - shift[pts, 2], prior[pts, 2])
    return BundleProblem(base.focal_length, base.principal_point,
                         base.eo0, base.eo_sigma,
                         base.xyz0 if xyz0 is None else xyz0, prior, base.prior_weight,
                         base.obs_point, base.obs_image, base.obs_xy, base.obs_sigma,
                         eo_start=eo_start, sensors=base.sensors, free_datum=base.free_datum)


def apply_offsets(result: BundleResult, model: OffsetModel, estimate: OffsetEstimate,
                  qb: np.ndarray, s_ztb: np.ndarray) -> None:
    """Put the offsets' unknowns and uncertainty into ``result`` (in place).

    The degrees of freedom lose one per offset parameter and sigma0^2 is recomputed;
    point and EO covariances get the offsets' share ``(Q B) Q_TT (Q B)'``; the result
    keeps ``Q_TT``, ``Q B``, ``S^-1 Z' B`` and ``G`` so that joint covariances,
    check points and reliability include the offsets too.
    """
    q = model.n_params
    cof = estimate.cofactor
    old_vf = result.variance_factor
    pw = model.weights  # offsets with a prior are observed too (their prior mean is 0)
    n_prior = int((pw > 0).sum())
    result.vtpv = float(result.vtpv + (pw * np.asarray(estimate.values, float) ** 2).sum())
    result.n_obs += n_prior
    result.n_unknowns += q
    result.dof -= q - n_prior
    result.sigma0_squared = (float(result.vtpv / result.dof) if result.dof > 0
                             else float("nan"))
    new_vf = result.variance_factor
    n = result.problem.n_images
    result.offset_cofactor = cof
    result.offset_qb = qb
    result.offset_u = s_ztb
    result.offset_g = model.g
    q_ee = result.eo_cofactor()
    result.eo_cov = new_vf * q_ee.reshape(n, 6, n, 6)[np.arange(n), :, np.arange(n), :]
    if result.point_cov is not None:
        extra = np.matmul(np.matmul(qb, cof), np.swapaxes(qb, 1, 2))
        result.point_cov = result.point_cov * (new_vf / old_vf) + new_vf * extra
