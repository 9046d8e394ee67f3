"""Relative orientation of a stereo pair (collinearity or coplanarity) and the intersection
of its model points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from vectoradjust.adjust.orientation.common import (
    _block_diag,
    _check_point_pairs,
    _obs_weights,
    _vertical_parallax,
    rotation_matrix_partials,
)
from vectoradjust.errors import (
    MeasurementError,
    NonConvergenceError,
    SingularityError,
)
from vectoradjust.sensor.collinearity import (
    partials,
    project,
    rotation_matrix,
)

__all__ = ["RelativeOrientation", "relative_orientation", "model_intersection"]


_RO_PARAMS = ("omega", "phi", "kappa", "YL", "ZL")



@dataclass
class RelativeOrientation:
    """Result of :func:`relative_orientation` (dependent pair, left photo fixed).

    Attributes
    ----------
    method : str
        ``"collinearity"`` or ``"coplanarity"``.
    eo_left, eo_right : numpy.ndarray, shape (6,)
        ``XL, YL, ZL, omega, phi, kappa`` (model units = photo mm, radians). The left
        photo is ``(0, 0, f, 0, 0, 0)``; ``XL`` of the right photo is the fixed base.
    params : numpy.ndarray, shape (5,)
        ``omega, phi, kappa`` (rad), ``YL, ZL`` of the right photo.
    cov_params : numpy.ndarray, shape (5, 5)
        Their covariance (scaled by ``s0**2`` when ``a_posteriori``).
    model_xyz : numpy.ndarray, shape (n, 3)
        Model coordinates of the points.
    cov_model : numpy.ndarray, shape (3n, 3n)
        FULL covariance of the model coordinates (point-major: x1, y1, z1, x2, ...).
    residuals : numpy.ndarray, shape (n, 4)
        Photo coordinate residuals ``v = adjusted - measured`` (xL, yL, xR, yR), mm.
    vertical_parallax : numpy.ndarray, shape (n,)
        Residual y-parallax of the measured coordinates in the epipolar-normalised pair
        (mm); zero for rays that intersect.
    s0 : float
        A-posteriori standard deviation of unit weight (``nan`` with no redundancy).
    dof : int
        Degrees of freedom ``n - 5``.
    iterations : int
    a_posteriori : bool
        Whether the covariances were scaled by ``s0**2``.
    """

    method: str
    eo_left: np.ndarray
    eo_right: np.ndarray
    params: np.ndarray
    cov_params: np.ndarray
    model_xyz: np.ndarray
    cov_model: np.ndarray
    residuals: np.ndarray
    vertical_parallax: np.ndarray
    s0: float
    dof: int
    iterations: int
    a_posteriori: bool

    @property
    def sigma_params(self) -> np.ndarray:
        """Standard deviations of ``omega, phi, kappa`` (rad), ``YL, ZL``."""
        return np.sqrt(np.diag(self.cov_params))

    @property
    def sigma_model(self) -> np.ndarray:
        """``(n, 3)`` standard deviations of the model coordinates."""
        return np.sqrt(np.diag(self.cov_model)).reshape(-1, 3)

    @property
    def cov_model_blocks(self) -> np.ndarray:
        """``(n, 3, 3)`` per-point covariance blocks of the model coordinates."""
        n = self.model_xyz.shape[0]
        idx = np.arange(n)
        return self.cov_model.reshape(n, 3, n, 3)[idx, :, idx, :]

    def report(self) -> str:
        """Plain-text summary in the layout of Dewitt's ``relor`` output."""
        deg = 180.0 / np.pi
        sd = self.sigma_params
        lines = [f"Relative orientation ({self.method})", "",
                 f"{'Parameter':<10}  {'Left pho':>10}  {'Right pho':>10}  {'SD right':>8}"]
        for i, name in enumerate(("Omega(deg)", "Phi(deg)", "Kappa(deg)")):
            lines.append(f"{name:<10}  {self.eo_left[3 + i] * deg:10.4f}  "
                         f"{self.eo_right[3 + i] * deg:10.4f}  {sd[i] * deg:8.4f}")
        lines.append(f"{'XL':<10}  {self.eo_left[0]:10.4f}  {self.eo_right[0]:10.4f}")
        lines.append(f"{'YL':<10}  {self.eo_left[1]:10.4f}  {self.eo_right[1]:10.4f}  {sd[3]:8.4f}")
        lines.append(f"{'ZL':<10}  {self.eo_left[2]:10.4f}  {self.eo_right[2]:10.4f}  {sd[4]:8.4f}")
        lines += ["", f"Standard error of unit weight: {self.s0:7.4f}",
                  f"Degrees of freedom: {self.dof}"]
        return "\n".join(lines)


def _ro_start(l_obs: np.ndarray, f: float, bx: float | None):
    if bx is None:
        bx = float(np.mean(l_obs[:, 0] - l_obs[:, 2]))
    if not np.isfinite(bx) or bx == 0.0:
        raise MeasurementError(
            "Relative orientation: the air base (mean x-parallax) is zero",
            "Check that left and right photo coordinates are not identical or swapped",
        )
    return float(bx)


def _eo_right(bx: float, e: np.ndarray) -> np.ndarray:
    return np.array([bx, e[3], e[4], e[0], e[1], e[2]])


def _collinearity_normals(l_obs, w, eo_l, eo_r, pts, f):
    n = pts.shape[0]
    comp = np.hstack([project(eo_l, pts, f), project(eo_r, pts, f)])
    r = l_obs - comp
    _, ap_l = partials(np.broadcast_to(eo_l, (n, 6)), pts, f)
    ae_r, ap_r = partials(np.broadcast_to(eo_r, (n, 6)), pts, f)
    ae = np.zeros((n, 4, 5))
    ae[:, 2:, :] = ae_r[:, :, [3, 4, 5, 1, 2]]
    ap = np.concatenate([ap_l, ap_r], axis=1)
    return r, ae, ap


def _reduced(ae, ap, w, r):
    """Normal equations with the point blocks eliminated (Schur complement)."""
    wae = w[:, :, None] * ae
    wap = w[:, :, None] * ap
    nee = np.einsum("nij,nik->jk", ae, wae)
    nep = np.einsum("nij,nik->njk", ae, wap)
    npp = np.einsum("nij,nik->njk", ap, wap)
    te = np.einsum("nij,ni->j", wae, r)
    tp = np.einsum("nij,ni->nj", wap, r)
    det = np.linalg.det(npp)
    if np.any(~np.isfinite(det)) or np.any(np.abs(det) <= 1e-300):
        raise SingularityError(
            "Relative orientation: a model point is not determined by its two rays",
            "Check for points measured at the same place on both photos (zero parallax)",
        )
    npp_inv = np.linalg.inv(npp)
    g = np.einsum("njk,nlk->njl", npp_inv, nep)  # N_pp^-1 N_pe, (n, 3, 5)
    s = nee - np.einsum("nij,njk->ik", nep, g)
    ptp = np.einsum("njk,nk->nj", npp_inv, tp)
    rhs = te - np.einsum("nij,nj->i", nep, ptp)
    return s, rhs, npp_inv, g, ptp


def _scaled_cond(n_mat: np.ndarray) -> float:
    """Condition number of the normal matrix after Jacobi (unit-diagonal) scaling."""
    d = np.sqrt(np.abs(np.diag(n_mat)))
    if not np.all(np.isfinite(d)) or np.any(d == 0):
        return float("inf")
    return float(np.linalg.cond(n_mat / np.outer(d, d)))


def _converged(step: float, previous: float, tol: float) -> bool:
    """Converged: the correction is below ``tol``, or it stalls at round-off level."""
    return step < tol or (step < 1e-7 and step >= 0.5 * previous)


def _iterate(update: Callable[[], Optional[float]], max_iter: int, tol: float, what: str,
             mend: str) -> int:
    """Repeat ``update`` until :func:`_converged`; the number of iterations run.

    ``update()`` makes one correction and returns its size (None when it is not
    finite). Raises :class:`NonConvergenceError` (``what`` did not converge; ``mend``)
    after ``max_iter`` iterations or a correction that is not finite.
    """
    it = 0
    previous = np.inf
    while it < max_iter:
        it += 1
        step = update()
        if step is None:
            break
        if _converged(step, previous, tol):
            return it
        previous = step
    raise NonConvergenceError(f"{what} did not converge in {it} iterations", mend)


def _solve_spd(s: np.ndarray, rhs: np.ndarray, what: str) -> np.ndarray:
    cond = _scaled_cond(s)
    if not np.isfinite(cond) or cond > 1e15:
        raise SingularityError(
            f"{what}: the normal equations are singular (condition number {cond:.3g})",
            "The points are too few or badly distributed (e.g. all on a line); "
            "measure points spread over the overlap",
        )
    return np.linalg.solve(s, rhs)


def _ro_collinearity(l_obs, w, f, bx, max_iter, tol):
    n = l_obs.shape[0]
    eo_l = np.array([0.0, 0.0, f, 0.0, 0.0, 0.0])
    e = np.array([0.0, 0.0, 0.0, 0.0, f])
    pts = np.column_stack([l_obs[:, 0], l_obs[:, 1], np.zeros(n)])

    def update() -> Optional[float]:
        nonlocal e, pts
        r, ae, ap = _collinearity_normals(l_obs, w, eo_l, _eo_right(bx, e), pts, f)
        s, rhs, npp_inv, g, ptp = _reduced(ae, ap, w, r)
        de = _solve_spd(s, rhs, "Relative orientation")
        dp = ptp - np.einsum("njk,k->nj", g, de)
        e = e + de
        pts = pts + dp
        if not (np.all(np.isfinite(de)) and np.all(np.isfinite(dp))):
            return None
        return max(np.max(np.abs(de[:3])), np.max(np.abs(de[3:])) / f, np.max(np.abs(dp)) / f)

    it = _iterate(update, max_iter, tol, "Relative orientation",
                  "Check the point labels (left/right coordinates of different points) and "
                  "the focal length; the photos must be near-vertical with the base along x")
    eo_r = _eo_right(bx, e)
    r, ae, ap = _collinearity_normals(l_obs, w, eo_l, eo_r, pts, f)
    s, _, npp_inv, g, _ = _reduced(ae, ap, w, r)
    q_ee = np.linalg.inv(s)
    # full cofactor of the points: blockdiag(N_pp^-1) + G Q_ee G'
    gf = g.reshape(3 * n, 5)
    q_pp = _block_diag(npp_inv) + gf @ q_ee @ gf.T
    return e, pts, -r, q_ee, q_pp, it


def _coplanarity_terms(lv: np.ndarray, e: np.ndarray, f: float, bx: float):
    """Misclosure F, A = dF/dparams (n, 5) and B = dF/dobs (n, 4) of the coplanarity."""
    n = lv.shape[0]
    m = rotation_matrix(e[0], e[1], e[2])
    dm = rotation_matrix_partials(e[0], e[1], e[2])
    ray_l = np.column_stack([lv[:, 0], lv[:, 1], np.full(n, -f)])
    img_r = np.column_stack([lv[:, 2], lv[:, 3], np.full(n, -f)])
    ray_r = img_r @ m
    base = np.array([bx, e[3], e[4] - f])
    lxr = np.cross(ray_l, ray_r)
    big_f = lxr @ base
    bxl = np.cross(base, ray_l)
    a = np.empty((n, 5))
    for k in range(3):
        a[:, k] = np.sum(bxl * (img_r @ dm[k]), axis=1)
    a[:, 3] = lxr[:, 1]
    a[:, 4] = lxr[:, 2]
    rxb = np.cross(ray_r, base)
    b = np.column_stack([rxb[:, 0], rxb[:, 1], bxl @ m[0], bxl @ m[1]])
    return big_f, a, b


def _ro_coplanarity(l_obs, w, f, bx, max_iter, tol):
    n = l_obs.shape[0]
    e = np.array([0.0, 0.0, 0.0, 0.0, f])
    v = np.zeros_like(l_obs)

    def update() -> Optional[float]:
        nonlocal e, v
        big_f, a, b = _coplanarity_terms(l_obs + v, e, f, bx)
        wv = big_f - np.sum(b * v, axis=1)
        qw = np.sum(b * b / w, axis=1)
        if np.any(qw <= 0):
            raise SingularityError(
                "Relative orientation: a coplanarity condition has no observation weight",
                "Check for points with zero parallax or repeated coordinates",
            )
        n_mat = a.T @ (a / qw[:, None])
        dx = -_solve_spd(n_mat, a.T @ (wv / qw), "Relative orientation (coplanarity)")
        k = -(a @ dx + wv) / qw
        v = b * k[:, None] / w
        e = e + dx
        if not np.all(np.isfinite(dx)):
            return None
        return max(np.max(np.abs(dx[:3])), np.max(np.abs(dx[3:])) / f)

    it = _iterate(update, max_iter, tol, "Relative orientation (coplanarity)",
                  "Check the point labels and the focal length")
    big_f, a, b = _coplanarity_terms(l_obs + v, e, f, bx)
    qw = np.sum(b * b / w, axis=1)
    q_ee = np.linalg.inv(a.T @ (a / qw[:, None]))
    # cofactor between parameters and observations: d x / d l = -N^-1 A' Qw^-1 B
    dxdl = -(q_ee @ (a / qw[:, None]).T)[:, :, None] * b[None, :, :]  # (5, n, 4)
    q_xl = dxdl / w[None, :, :]  # times P^-1
    eo_l = np.array([0.0, 0.0, f, 0.0, 0.0, 0.0])
    eo_r = _eo_right(bx, e)
    pts, g_p, h_l = _intersection(l_obs, w, eo_l, eo_r, f)
    # cov(X_i, X_j) = G_i Qee G_j' + G_i Q_xl,j H_j' + H_i Q_lx,i G_j' + delta_ij H_i Qll,i H_i'
    gf = g_p.reshape(3 * n, 5)
    hq = np.einsum("nij,knj->nik", h_l, q_xl).reshape(3 * n, 5)  # H_i Q_lx,i  (3n, 5)
    q_pp = gf @ q_ee @ gf.T + gf @ hq.T + hq @ gf.T
    q_pp = q_pp + _block_diag(np.einsum("nij,nj,nkj->nik", h_l, 1.0 / w, h_l))
    return e, pts, v, q_ee, q_pp, it


def _intersection(l_obs, w, eo_l, eo_r, f, iterations: int = 20):
    """Least-squares intersection of the two rays of every point and its Jacobians.

    Returns the points ``(n, 3)``, ``d X / d(omega, phi, kappa, YL, ZL)`` ``(n, 3, 5)``
    and ``d X / d(xL, yL, xR, yR)`` ``(n, 3, 4)``.
    """
    n = l_obs.shape[0]
    # start: midpoint of the common perpendicular of the two rays
    m_l = rotation_matrix(*eo_l[3:])
    m_r = rotation_matrix(*eo_r[3:])
    d1 = np.column_stack([l_obs[:, 0], l_obs[:, 1], np.full(n, -f)]) @ m_l
    d2 = np.column_stack([l_obs[:, 2], l_obs[:, 3], np.full(n, -f)]) @ m_r
    c = eo_r[:3] - eo_l[:3]
    a11 = np.sum(d1 * d1, 1)
    a12 = -np.sum(d1 * d2, 1)
    a22 = np.sum(d2 * d2, 1)
    b1 = d1 @ c
    b2 = -(d2 @ c)
    det = a11 * a22 - a12 * a12
    with np.errstate(divide="ignore", invalid="ignore"):
        s1 = (b1 * a22 - a12 * b2) / det
        s2 = (a11 * b2 - a12 * b1) / det
    pts = 0.5 * (eo_l[:3] + s1[:, None] * d1 + eo_r[:3] + s2[:, None] * d2)
    if not np.all(np.isfinite(pts)):
        raise SingularityError(
            "Model intersection: parallel rays (a point without x-parallax)",
            "Check the photo coordinates of the points",
        )
    for _ in range(iterations):
        r, ae, ap = _collinearity_normals(l_obs, w, eo_l, eo_r, pts, f)
        wap = w[:, :, None] * ap
        npp = np.einsum("nij,nik->njk", ap, wap)
        dp = np.linalg.solve(npp, np.einsum("nij,ni->nj", wap, r)[..., None])[..., 0]
        pts = pts + dp
        if np.max(np.abs(dp)) < 1e-12 * max(f, np.max(np.abs(pts))):
            break
    r, ae, ap = _collinearity_normals(l_obs, w, eo_l, eo_r, pts, f)
    wap = w[:, :, None] * ap
    npp_inv = np.linalg.inv(np.einsum("nij,nik->njk", ap, wap))
    h_l = np.einsum("njk,nik->nji", npp_inv, wap)  # (n, 3, 4)
    g_p = -np.einsum("nji,nik->njk", h_l, ae)  # (n, 3, 5)
    return pts, g_p, h_l


def model_intersection(ro: RelativeOrientation, left_xy, right_xy, f: float, sigma=None):
    """Model coordinates of further points from an oriented pair (forward intersection).

    Parameters
    ----------
    ro : RelativeOrientation
        The oriented pair.
    left_xy, right_xy : array_like, shape (k, 2)
        Photo coordinates (mm) of the new points.
    f : float
        Focal length (mm).
    sigma : float or array_like, optional
        Photo coordinate sigmas (mm), as in :func:`relative_orientation`.

    Returns
    -------
    numpy.ndarray, shape (k, 3)
        Least-squares intersection of the two rays of each point (model units).
    """
    l_obs = np.hstack([np.asarray(left_xy, float), np.asarray(right_xy, float)])
    w = _obs_weights(sigma, l_obs.shape[0], "Model intersection")
    pts, _, _ = _intersection(l_obs, w, ro.eo_left, ro.eo_right, float(f))
    return pts


def relative_orientation(
    left_xy,
    right_xy,
    f: float,
    bx: float | None = None,
    sigma=None,
    *,
    method: str = "collinearity",
    a_posteriori: bool = True,
    max_iter: int = 50,
    tol: float = 1e-12,
) -> RelativeOrientation:
    """Relative orientation of a dependent stereo pair.

    The left photo is fixed (``XL = YL = 0, ZL = f``, no rotation), the right photo's ``XL`` at
    ``bx`` (default: the mean x-parallax ``mean(xL - xR)``, as in Dewitt's ``relor.c``), so
    that the model is about at photo scale (mm). Unknowns: ``omega, phi, kappa, YL, ZL`` (right).

    Parameters
    ----------
    left_xy, right_xy : array_like, shape (n, 2)
        Refined photo coordinates (mm) of the same ``n >= 5`` points.
    f : float
        Focal length (mm).
    bx : float, optional
        Fixed base component ``XL`` of the right photo.
    sigma : float or array_like, optional
        Standard deviation(s) of the photo coordinates (mm): one value, four
        ``(xL, yL, xR, yR)`` or ``(n, 4)``. Default: unit weights.
    method : {"collinearity", "coplanarity"}
        ``"collinearity"``: the four collinearity equations per point with the model
        point as unknowns (Gauss-Markov, Schur-reduced; ``relor.c``).
        ``"coplanarity"``: one condition ``b . (r_L x r_R) = 0`` per point in the
        Gauss-Helmert model; model points are then intersected and their covariance
        propagated from the joint covariance of parameters and observations.
    a_posteriori : bool
        Scale the covariances by ``s0**2`` (default, as ``relor.c``); with ``False``
        the a-priori variance factor 1 is used (meaningful when ``sigma`` is given).
    max_iter, tol : int, float
        Iteration limit and convergence threshold (largest correction, radians or relative
        to ``f``); corrections that stop decreasing below ``1e-7`` (round-off level) also
        count as converged.

    Returns
    -------
    RelativeOrientation

    Raises
    ------
    MeasurementError
        Fewer than 5 points, shape mismatch or bad sigmas.
    SingularityError, NonConvergenceError
        Degenerate geometry or no convergence.
    """
    l_obs = _photo_pair(left_xy, right_xy)
    f = float(f)
    w = _obs_weights(sigma, len(l_obs), "Relative orientation")
    bx = _ro_start(l_obs, f, bx)
    solver = {"collinearity": _ro_collinearity, "coplanarity": _ro_coplanarity}.get(method)
    if solver is None:
        raise ValueError(f"unknown method {method!r}")
    e, pts, v, q_ee, q_pp, it = solver(l_obs, w, f, bx, max_iter, tol)
    dof, s0, scale = _variance_factor(w, v, len(l_obs), a_posteriori)
    eo_l = np.array([0.0, 0.0, f, 0.0, 0.0, 0.0])
    eo_r = _eo_right(bx, e)
    return RelativeOrientation(
        method=method,
        eo_left=eo_l,
        eo_right=eo_r,
        params=e,
        cov_params=scale * q_ee,
        model_xyz=pts,
        cov_model=scale * 0.5 * (q_pp + q_pp.T),
        residuals=v,
        vertical_parallax=_vertical_parallax(l_obs, eo_l, eo_r, f),
        s0=s0,
        dof=dof,
        iterations=it,
        a_posteriori=a_posteriori,
    )


def _photo_pair(left_xy, right_xy) -> np.ndarray:
    """The observations ``(n, 4)``: ``xL, yL, xR, yR`` (mm) of every point, checked.

    Raises :class:`MeasurementError` for arrays of different or wrong shapes, fewer
    than 5 points or non-finite coordinates.
    """
    lxy = np.asarray(left_xy, float)
    rxy = np.asarray(right_xy, float)
    _check_point_pairs(lxy, rxy, 2, 5, MeasurementError, _PAIR_MESSAGES)
    return np.hstack([lxy, rxy])


#: messages of :func:`_photo_pair` (:func:`_check_point_pairs`)
_PAIR_MESSAGES = (
    ("Relative orientation: left ({a}) and right ({b}) photo coordinates must both be "
     "(n, 2) arrays of the same points",
     "Give one row per point with its x, y on each photo"),
    ("Relative orientation needs at least 5 points measured on both photos; got {n}",
     "Measure more tie points in the overlap (6 or more, spread like the von Gruber points)"),
    ("Relative orientation: photo coordinates contain NaN or inf",
     "Remove or complete the incomplete measurements"),
)


def _variance_factor(w: np.ndarray, v: np.ndarray, n: int,
                     a_posteriori: bool) -> tuple[int, float, float]:
    """Degrees of freedom ``n - 5``, ``s0`` and the factor of the covariances."""
    dof = n - 5
    vtpv = float(np.sum(w * v * v))
    s0 = float(np.sqrt(vtpv / dof)) if dof > 0 else float("nan")
    scale = s0**2 if a_posteriori else 1.0
    return dof, s0, scale
