"""The kernel, second half: eliminating the points (Schur complement), solving the reduced
camera system, the Gauss-Newton iteration, its convergence measures and :func:`adjust`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Optional

import numpy as np
import scipy.linalg

from vectoradjust.adjust.bundle.blas import _single_blas_thread
from vectoradjust.adjust.bundle.normals import (
    _add_block,
    _add_point_priors,
    _block_normals,
    _cameras,
    _inv_sym3,
    _Layout,
    _layout,
    _linearise_block,
    _rays,
    _times_cholesky,
    _times_inverse,
    _undetermined,
)
from vectoradjust.adjust.bundle.problem import BundleProblem, ProgressCallback, _group_observations
from vectoradjust.adjust.bundle.result import BundleResult
from vectoradjust.adjust.datum import free_network_correction
from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)
from vectoradjust.errors import CancelledError, NonConvergenceError, SingularityError

__all__ = ["adjust"]


@dataclass
class _Step:
    """One Gauss-Newton step: the corrections and the normal-equation pieces it used."""

    dx_e: np.ndarray
    dx_p: np.ndarray
    vtpv_image: float
    parts: list  # per block: (nep (c, 6, 3, g), npp^-1 (3, 3, g))
    lonely_inv: np.ndarray  # npp^-1 of the points without image observations
    factor: tuple
    eo: np.ndarray  # the linearisation point
    xyz: np.ndarray
    #: free network: what to subtract from the inverse of the regularised system
    free_corr: Optional[np.ndarray] = None


def _eliminate_points(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                      check_points: bool):
    """Reduced camera system ``S dx_e = rhs`` with the points eliminated, block by block."""
    n = prob.n_images
    cams = _cameras(eo)
    s = np.zeros((6 * n, 6 * n))
    rhs = np.zeros(6 * n)
    parts, tps, bad = [], [], []
    vtpv = 0.0
    # every block's N_ep in one buffer: freed in one piece (memory back to the system)
    buf = np.empty(18 * len(prob.obs_point))
    at = 0
    for blk in lay.blocks:
        ell, b, xg = _linearise_block(blk, cams, xyz, prob, eo)
        c, g = len(blk.images), len(blk.points)
        nep = buf[at:at + 18 * c * g].reshape(c, 6, 3, g)
        at += 18 * c * g
        nee, te, npp, tp, vv = _block_normals(blk, ell, b, nep)
        vtpv += vv
        _add_point_priors(blk, xg, npp, tp)
        inv, det = _inv_sym3(npp)
        if check_points:
            bad.append(blk.points[_undetermined(det, npp[0, 0] + npp[1, 1] + npp[2, 2])])
        with np.errstate(invalid="ignore"):  # undetermined points: raised below
            ur = _times_cholesky(nep, inv).reshape(6 * c, 3 * g)
            loc = -(ur @ ur.T)
        diag = loc.reshape(c, 6, c, 6)
        diag[np.arange(c), :, np.arange(c), :] += nee
        itp = (inv * tp[None]).sum(axis=1)  # N_pp^-1 t_p
        _add_block(s, rhs, blk, loc, te.ravel() - nep.reshape(6 * c, 3 * g) @ itp.ravel())
        parts.append((nep, inv))
        tps.append(tp)
    lonely_npp = prob.prior_weight[lay.lonely]
    if check_points:
        det = np.linalg.det(lonely_npp) if len(lay.lonely) else np.zeros(0)
        bad.append(lay.lonely[_undetermined(det, np.einsum("mii->m", lonely_npp))])
        _raise_undetermined(np.concatenate(bad))
    # EO priors
    we = prob.eo_weight
    s[np.arange(6 * n), np.arange(6 * n)] += we.ravel()
    rhs += (we * np.where(we > 0, prob.eo0 - eo, 0.0)).ravel()
    _hold_fixed(s, rhs, prob.eo_fixed.ravel())
    return s, rhs, parts, tps, inv3x3(lonely_npp), vtpv


def _hold_fixed(s: np.ndarray, rhs: np.ndarray, fixed: np.ndarray) -> None:
    """Take fixed parameters out of the reduced system (unit diagonal, no coupling, zero
    right-hand side), so that their corrections are zero."""
    if fixed.any():
        s[fixed, :] = 0.0
        s[:, fixed] = 0.0
        s[fixed, fixed] = 1.0
        rhs[fixed] = 0.0


def _raise_undetermined(bad: np.ndarray) -> None:
    """Raise :class:`SingularityError` naming the points that cannot be determined."""
    if bad.size:
        bad = np.sort(bad)
        raise SingularityError(
            f"{bad.size} object point(s) cannot be determined (e.g. point index {bad[0]}): "
            "a point without a coordinate prior must be measured on at least two images",
            "Measure tie points on two or more images, or remove them from the measurements",
            details={"points": bad.tolist()},
        )


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


def _gauss_newton_step(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                       check_points: bool) -> _Step:
    """Corrections of one iteration: reduced camera system, then point back-substitution."""
    s, rhs, parts, tps, lonely_inv, vtpv = _eliminate_points(prob, lay, eo, xyz, check_points)
    free_corr = None
    if prob.free_datum:  # inner constraints over the cameras (the minimum-norm step)
        g2, a, free_corr = free_network_correction(eo, s)
        s += a * (g2 @ g2.T)
    factor, dx_e = _solve_reduced(s, rhs)
    dx_p = np.zeros((prob.n_points, 3))
    flat = dx_e.ravel()
    for blk, (nep, inv), tp in zip(lay.blocks, parts, tps):
        c, g = len(blk.images), len(blk.points)
        v = tp - (flat[blk.idx6] @ nep.reshape(6 * c, 3 * g)).reshape(3, g)
        dx_p[blk.points] = (inv * v[None]).sum(axis=1).T
    if len(lay.lonely):
        lo = lay.lonely
        d = np.where(lay.has_prior[lo, None], prob.prior_xyz[lo] - xyz[lo], 0.0)
        tp = np.einsum("mij,mj->mi", prob.prior_weight[lo], d)
        dx_p[lo] = np.einsum("mij,mj->mi", lonely_inv, tp)
    return _Step(dx_e=dx_e, dx_p=dx_p, vtpv_image=vtpv, parts=parts, lonely_inv=lonely_inv,
                 factor=factor, eo=eo.copy(), xyz=xyz.copy(), free_corr=free_corr)


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


def _final_residuals(prob: BundleProblem, lay: _Layout, eo: np.ndarray,
                     xyz: np.ndarray) -> np.ndarray:
    """Image residuals (adjusted minus observed, ``(k, 2)``) at the estimate; raises if a
    point ends up behind a camera."""
    cams = _cameras(eo)
    f, pp = float(prob.focal_length), prob.principal_point
    v = np.empty((len(prob.obs_point), 2))
    behind = len(prob.obs_point)
    for blk in lay.blocks:
        if blk.rpc_cols is not None:  # pixels of the RPC images; the frame images below
            ell, _, _ = _linearise_block(blk, cams, xyz, prob, eo)
            v[blk.obs] = -ell.transpose(0, 2, 1)
            fc = np.setdiff1d(np.arange(len(blk.images)), blk.rpc_cols)
            if not fc.size:
                continue
            blk = replace(blk, images=blk.images[fc], xy=blk.xy[fc], obs=blk.obs[fc])
        rr, _ = _rays(blk, cams, xyz, rows=3)
        q = rr[:, 2]
        if np.any(q >= 0):
            behind = min(behind, int(blk.obs[q >= 0].min()))
        v[blk.obs, 0] = (pp[0] - f * (rr[:, 0] / q)) - blk.xy[:, 0]
        v[blk.obs, 1] = (pp[1] - f * (rr[:, 1] / q)) - blk.xy[:, 1]
    if behind < len(prob.obs_point):
        raise NonConvergenceError(
            f"The adjustment converged to a solution with object points behind the camera "
            f"(observation {behind})",
            "Check the approximate exterior orientation and the sign of the photo coordinates "
            "(x right, y up, mm)",
        )
    return v


def _kept_arrays(prob: BundleProblem, lay: _Layout, step: _Step, s_inv: np.ndarray,
                 compute_covariance: bool):
    """The last step's factorisation in observation order, and the point cofactors.

    Returns ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)``, ``nep (k, 6, 3)``, ``npp_inv (m, 3, 3)``
    and ``N_pp^-1 + N_pp^-1 N_pe S^-1 N_ep N_pp^-1`` per point (None without covariances):
    the exact 3x3 blocks of ``N^-1``, from ``S^-1`` restricted to each block's images.
    The step's blocks are released before the partials are recomputed (peak memory).
    """
    k, m = len(prob.obs_point), prob.n_points
    nep_obs, npp_inv = np.empty((k, 6, 3)), np.empty((m, 3, 3))
    q = np.empty((m, 3, 3)) if compute_covariance else None
    nep2, npp_inv2 = nep_obs.reshape(k, 18), npp_inv.reshape(m, 9)
    for i, blk in enumerate(lay.blocks):
        nep, inv = step.parts[i]
        c, g = len(blk.images), len(blk.points)
        nep2[blk.obs.ravel()] = nep.reshape(c, 18, g).transpose(0, 2, 1).reshape(c * g, 18)
        npp_inv2[blk.points] = inv.reshape(9, g).T
        if compute_covariance:
            y = _times_inverse(nep, inv).reshape(6 * c, 3, g)
            # einsum, not BLAS: a wide product that a threaded BLAS splits badly on a busy machine
            t = np.einsum("ab,bmg->amg", s_inv[np.ix_(blk.idx6, blk.idx6)], y)
            qb = inv + (y[:, :, None, :] * t[:, None, :, :]).sum(axis=0)
            q[blk.points] = (0.5 * (qb + qb.transpose(1, 0, 2))).transpose(2, 0, 1)
    step.parts = []  # the one N_ep buffer goes back to the system here ...
    nep = inv = y = t = None  # ... once no view of it is left
    npp_inv[lay.lonely] = step.lonely_inv
    if compute_covariance:
        q[lay.lonely] = 0.5 * (step.lonely_inv + step.lonely_inv.transpose(0, 2, 1))
    a_eo, a_pt = _kept_partials(prob, lay, step)
    return a_eo, a_pt, nep_obs, npp_inv, q


def _kept_partials(prob: BundleProblem, lay: _Layout, step: _Step):
    """Unweighted partials ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)`` at the last step's point."""
    k = len(prob.obs_point)
    a_eo, a_pt = np.empty((k, 2, 6)), np.empty((k, 2, 3))
    a_eo2, a_pt2 = a_eo.reshape(k, 12), a_pt.reshape(k, 6)
    cams = _cameras(step.eo)
    for blk in lay.blocks:
        _, b, _ = _linearise_block(blk, cams, step.xyz, prob, step.eo)
        c, g = len(blk.images), len(blk.points)
        rows = blk.obs.ravel()
        bt = b.reshape(c, 18, g).transpose(0, 2, 1).reshape(c * g, 2, 9)
        a_eo2[rows] = bt[:, :, :6].reshape(c * g, 12)
        a_pt2[rows] = bt[:, :, 6:].reshape(c * g, 6)
    return a_eo, a_pt


def _converged_result(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                      step: _Step, it: int, history: list,
                      compute_covariance: bool) -> BundleResult:
    """Residuals, sigma0 and covariances at the converged estimate, as a BundleResult."""
    v_image = _final_residuals(prob, lay, eo, xyz)
    vtpv = _vtpv(prob, v_image, xyz, eo)
    n_obs, n_unk = prob.counts()
    dof = n_obs - n_unk
    s0sq = vtpv / dof if dof > 0 else float("nan")
    n = prob.n_images
    s_inv = scipy.linalg.cho_solve(step.factor, np.eye(6 * n))
    if step.free_corr is not None:  # the pseudo-inverse: inner constraints over the cameras
        s_inv = s_inv - step.free_corr
    s_inv = 0.5 * (s_inv + s_inv.T)
    fixed = prob.eo_fixed
    if fixed.any():  # held parameters have no variance
        s_inv[fixed.ravel(), :] = 0.0
        s_inv[:, fixed.ravel()] = 0.0
    vf = s0sq if np.isfinite(s0sq) else 1.0
    eo_cov = vf * s_inv.reshape(n, 6, n, 6)[np.arange(n), :, np.arange(n), :]
    a_eo, a_pt, nep, npp_inv, q = _kept_arrays(prob, lay, step, s_inv, compute_covariance)
    point_cov = None if q is None else vf * q
    has_prior = lay.has_prior
    v_point = np.where(has_prior[:, None], xyz - prob.prior_xyz, np.nan)
    we = prob.eo_weight
    v_eo = np.where((we > 0) & ~fixed, eo - prob.eo0, np.nan)
    return BundleResult(
        eo=eo, xyz=xyz, eo_cov=eo_cov, point_cov=point_cov, v_image=v_image,
        v_point=v_point, v_eo=v_eo, vtpv=float(vtpv), n_obs=n_obs, n_unknowns=n_unk, dof=dof,
        sigma0_squared=float(s0sq), iterations=it, converged=True, history=history,
        s_inv=s_inv, npp_inv=npp_inv, nep_obs=nep, a_eo=a_eo, a_pt=a_pt, problem=prob,
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
    with _single_blas_thread():
        return _iterate(prob, max_iterations, tolerance_position, tolerance_angle, progress,
                        is_cancelled, compute_covariance)


def _iterate(prob: BundleProblem, max_iterations: int, tolerance_position: float,
             tolerance_angle: float, progress: Optional[ProgressCallback],
             is_cancelled: Optional[Callable[[], bool]],
             compute_covariance: bool) -> BundleResult:
    """The Gauss-Newton iteration of :func:`adjust` and its converged result."""
    eo = (prob.eo0 if prob.eo_start is None else np.asarray(prob.eo_start, float)).copy()
    xyz = prob.xyz0.copy()
    lay = _layout(prob, _group_observations(prob.obs_point, prob.obs_image, prob.n_points))
    history: list = []
    converged = False
    best = np.inf
    it = 0
    for it in range(1, max_iterations + 1):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("The adjustment was cancelled", "Run it again when ready")
        step = None  # free the previous step's blocks before building the next
        step = _gauss_newton_step(prob, lay, eo, xyz, check_points=it == 1)
        vtpv_now = step.vtpv_image + _prior_vtpv(prob, lay.has_prior, xyz, eo)
        max_pos, max_ang, max_bias = _largest_corrections(prob, step)
        history.append({"iteration": it, "vtpv": vtpv_now, "max_position_correction": max_pos,
                        "max_angle_correction": max_ang})
        if prob.sensors is not None and prob.is_rpc.any():
            history[-1]["max_bias_correction"] = max_bias
        _check_diverged(it, max_pos, max_ang + max_bias / 1e4, history)
        best = min(best, vtpv_now)
        eo += step.dx_e
        xyz += step.dx_p
        if progress is not None:
            progress(min(0.9, it / max_iterations), f"iteration {it}: v'Pv = {vtpv_now:.6g}")
        if max_pos < tolerance_position and max_ang < tolerance_angle and max_bias < TOLERANCE_BIAS:
            converged = True
            break
    if not converged:
        _raise_not_converged(max_iterations, history)
    result = _converged_result(prob, lay, eo, xyz, step, it, history, compute_covariance)
    if progress is not None:
        progress(1.0, f"converged after {it} iterations")
    return result


#: an RPC image's bias parameters are converged when every correction is below this (px)
TOLERANCE_BIAS = 1e-5


def _largest_corrections(prob: BundleProblem, step: _Step) -> tuple[float, float, float]:
    """Largest position (m: frame cameras and points), angle (rad: frame cameras) and
    bias (px: RPC images) correction of a step."""
    rpc = prob.is_rpc
    frame = step.dx_e[~rpc]
    max_pos = max(np.abs(frame[:, :3]).max(initial=0.0), np.abs(step.dx_p).max(initial=0.0))
    max_ang = float(np.abs(frame[:, 3:]).max(initial=0.0))
    max_bias = float(np.abs(step.dx_e[rpc]).max(initial=0.0))
    return float(max_pos), max_ang, max_bias


def _prior_vtpv(prob: BundleProblem, has: np.ndarray, xyz: np.ndarray, eo: np.ndarray) -> float:
    """``v'Pv`` of the point and EO priors."""
    d = np.where(has[:, None], xyz - prob.prior_xyz, 0.0)
    total = float(np.einsum("mi,mij,mj->", d, prob.prior_weight, d))
    we = prob.eo_weight
    de = np.where(we > 0, eo - prob.eo0, 0.0)
    return total + float(np.sum(we * de * de))


def _vtpv(prob: BundleProblem, ell: np.ndarray, xyz: np.ndarray, eo: np.ndarray) -> float:
    w = 1.0 / prob.obs_sigma**2
    total = float(np.sum(ell * ell * w))
    d = np.where(prob.has_prior[:, None], xyz - prob.prior_xyz, 0.0)
    total += float(np.einsum("mi,mij,mj->", d, prob.prior_weight, d))
    we = prob.eo_weight
    de = np.where(we > 0, eo - prob.eo0, 0.0)
    total += float(np.sum(we * de * de))
    return total

