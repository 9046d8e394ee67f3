"""Two-step stereo orientation: relative, then absolute, with error propagation.

The classical alternative to the bundle adjustment (``DESIGN.md`` section 6):

1. :func:`relative_orientation` - a dependent pair: the left photo is fixed at
   ``(0, 0, f)`` with zero rotations, the right photo's ``XL`` is held at the mean
   x-parallax (this fixes the model scale) and ``omega, phi, kappa, YL, ZL`` of the
   right photo are solved, either by the collinearity equations with the model points
   as unknowns (B. Dewitt's public-domain ``relor.c``) or by the coplanarity condition
   in the Gauss-Helmert model. Both are rigorous least squares for the same functional
   model and give the same orientation; model coordinates (in photo millimetres) come
   with their FULL covariance ``F_m Sigma_rr F_m'``.
2. :func:`conformal3d` - the 7-parameter similarity ``X = s M' x + T`` from model to
   ground (B. Dewitt's ``3DCONF.c``: ``M = M_kappa M_phi M_omega`` is transposed),
   either by ordinary least squares on the ground residuals or by the Gauss-Helmert
   model ``A dx + B v + w = 0`` with errors in the model AND the ground coordinates.
3. :func:`two_step` - both steps and the ground coordinates of every point with
   their full covariance.

Conventions: photo coordinates in millimetres, angles in radians (degrees only in
printed reports), ``M = M_kappa M_phi M_omega`` (:mod:`vectoradjust.sensor.collinearity`).
Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vectoradjust.errors import (
    ControlError,
    MeasurementError,
    NonConvergenceError,
    SingularityError,
)
from vectoradjust.sensor.collinearity import (
    partials,
    project,
    rotation_derivatives,
    rotation_matrix,
    rotation_to_angles,
)

__all__ = [
    "rotation_matrix_partials",
    "RelativeOrientation",
    "relative_orientation",
    "model_intersection",
    "Conformal3D",
    "conformal3d",
    "TwoStep",
    "two_step",
]

_RO_PARAMS = ("omega", "phi", "kappa", "YL", "ZL")
_CONF_PARAMS = ("scale", "omega", "phi", "kappa", "Tx", "Ty", "Tz")


# ----------------------------------------------------------------------------- helpers
def rotation_matrix_partials(omega, phi, kappa) -> np.ndarray:
    """Derivatives of ``M = M_kappa M_phi M_omega`` with respect to the three angles.

    Parameters
    ----------
    omega, phi, kappa : float or array_like
        Angles in radians, broadcastable to a common shape ``s``.

    Returns
    -------
    numpy.ndarray
        Shape ``s + (3, 3, 3)``: ``[..., k, i, j] = d m_ij / d angle_k`` with
        ``k = 0, 1, 2`` for omega, phi, kappa.
    """
    return rotation_derivatives(omega, phi, kappa)


def _obs_weights(sigma, n: int, what: str) -> np.ndarray:
    """Weights ``1 / sigma^2`` of the ``(n, 4)`` photo coordinates."""
    if sigma is None:
        return np.ones((n, 4))
    s = np.asarray(sigma, float)
    try:
        s = np.broadcast_to(s, (n, 4))
    except ValueError as exc:
        raise MeasurementError(
            f"{what}: image sigma of shape {np.shape(sigma)} does not fit {n} points x 4 "
            "coordinates",
            "Give one sigma (mm), four (xL, yL, xR, yR) or one row of four per point",
        ) from exc
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise MeasurementError(
            f"{what}: image sigmas must be positive and finite", "Check the image sigma (mm)"
        )
    return 1.0 / s**2


def _block_diag(blocks: np.ndarray) -> np.ndarray:
    """Dense block-diagonal matrix from ``(n, k, k)`` blocks."""
    n, k, _ = blocks.shape
    out = np.zeros((n, k, n, k))
    idx = np.arange(n)
    out[idx, :, idx, :] = blocks
    return out.reshape(n * k, n * k)


def _sandwich(r: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``(I_n kron R) cov (I_n kron R)'`` for a 3x3 ``R`` and a ``(3n, 3n)`` ``cov``."""
    m = cov.shape[0]
    left = np.einsum("ij,ajk->aik", r, cov.reshape(m // 3, 3, m))
    return (left.reshape(m, m // 3, 3) @ r.T).reshape(m, m)


def _right_apply(mat: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``mat (I_n kron R)'`` for a ``(k, 3n)`` matrix."""
    k, m = mat.shape
    return (mat.reshape(k, m // 3, 3) @ r.T).reshape(k, m)


def _cov3(cov, n: int, what: str) -> np.ndarray:
    """Full ``(3n, 3n)`` covariance from a scalar sigma, per-axis sigmas or blocks.

    Accepted: ``None`` (identity), a scalar sigma, ``(3,)`` sigmas per axis, ``(n, 3)``
    sigmas per point and axis, ``(n, 3, 3)`` covariance blocks, ``(3n, 3n)`` covariance.
    """
    if cov is None:
        return np.eye(3 * n)
    c = np.asarray(cov, float)
    if c.shape == (3 * n, 3 * n):
        return 0.5 * (c + c.T)
    if c.shape == (n, 3, 3):
        return _block_diag(c)
    if c.ndim == 0 or c.shape in ((3,), (n, 3)):
        sig = np.broadcast_to(c, (n, 3))
        if np.any(sig < 0) or not np.all(np.isfinite(sig)):
            raise ControlError(f"{what}: sigmas must be non-negative and finite",
                               "Check the sigma values")
        return np.diag((sig**2).ravel())
    raise ControlError(
        f"{what}: covariance of shape {c.shape} does not fit {n} points",
        "Give a sigma, 3 sigmas, (n, 3) sigmas, (n, 3, 3) blocks or a (3n, 3n) matrix",
    )


def _vertical_parallax(l_obs: np.ndarray, eo_l: np.ndarray, eo_r: np.ndarray, f: float):
    """y-parallax of conjugate points in the base-aligned (epipolar) normalised pair."""
    m_l = rotation_matrix(*eo_l[3:])
    m_r = rotation_matrix(*eo_r[3:])
    n = l_obs.shape[0]
    ray_l = np.column_stack([l_obs[:, 0], l_obs[:, 1], np.full(n, -f)]) @ m_l
    ray_r = np.column_stack([l_obs[:, 2], l_obs[:, 3], np.full(n, -f)]) @ m_r
    e1 = eo_r[:3] - eo_l[:3]
    e1 = e1 / np.linalg.norm(e1)
    w = m_l[2] + m_r[2]
    e3 = w - (w @ e1) * e1
    e3 = e3 / np.linalg.norm(e3)
    e2 = np.cross(e3, e1)
    return -f * (ray_l @ e2) / (ray_l @ e3) + f * (ray_r @ e2) / (ray_r @ e3)


# ---------------------------------------------------------------- relative orientation
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
    it = 0
    converged = False
    previous = np.inf
    while it < max_iter:
        it += 1
        r, ae, ap = _collinearity_normals(l_obs, w, eo_l, _eo_right(bx, e), pts, f)
        s, rhs, npp_inv, g, ptp = _reduced(ae, ap, w, r)
        de = _solve_spd(s, rhs, "Relative orientation")
        dp = ptp - np.einsum("njk,k->nj", g, de)
        e = e + de
        pts = pts + dp
        if not (np.all(np.isfinite(de)) and np.all(np.isfinite(dp))):
            break
        step = max(np.max(np.abs(de[:3])), np.max(np.abs(de[3:])) / f, np.max(np.abs(dp)) / f)
        if _converged(step, previous, tol):
            converged = True
            break
        previous = step
    if not converged:
        raise NonConvergenceError(
            f"Relative orientation did not converge in {it} iterations",
            "Check the point labels (left/right coordinates of different points) and the "
            "focal length; the photos must be near-vertical with the base along x",
        )
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
    it = 0
    converged = False
    previous = np.inf
    while it < max_iter:
        it += 1
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
            break
        step = max(np.max(np.abs(dx[:3])), np.max(np.abs(dx[3:])) / f)
        if _converged(step, previous, tol):
            converged = True
            break
        previous = step
    if not converged:
        raise NonConvergenceError(
            f"Relative orientation (coplanarity) did not converge in {it} iterations",
            "Check the point labels and the focal length",
        )
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

    The left photo is fixed at ``XL = YL = 0, ZL = f`` with zero rotations; the right
    photo's ``XL`` is fixed to ``bx`` (default: the mean x-parallax ``mean(xL - xR)``,
    as in Dewitt's ``relor.c``), which makes the model roughly at photo scale (model
    units = mm). Unknowns: ``omega, phi, kappa, YL, ZL`` of the right photo.

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
        Iteration limit and convergence threshold (largest correction, radians or
        relative to ``f``); corrections that stop decreasing below ``1e-7`` (round-off
        level) also count as converged.

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
    lxy = np.asarray(left_xy, float)
    rxy = np.asarray(right_xy, float)
    if lxy.ndim != 2 or lxy.shape[1] != 2 or lxy.shape != rxy.shape:
        raise MeasurementError(
            f"Relative orientation: left ({lxy.shape}) and right ({rxy.shape}) photo "
            "coordinates must both be (n, 2) arrays of the same points",
            "Give one row per point with its x, y on each photo",
        )
    n = lxy.shape[0]
    if n < 5:
        raise MeasurementError(
            f"Relative orientation needs at least 5 points measured on both photos; got {n}",
            "Measure more tie points in the overlap (6 or more, spread like the von Gruber "
            "points)",
        )
    if not (np.all(np.isfinite(lxy)) and np.all(np.isfinite(rxy))):
        raise MeasurementError("Relative orientation: photo coordinates contain NaN or inf",
                               "Remove or complete the incomplete measurements")
    f = float(f)
    l_obs = np.hstack([lxy, rxy])
    w = _obs_weights(sigma, n, "Relative orientation")
    bx = _ro_start(l_obs, f, bx)
    if method == "collinearity":
        e, pts, v, q_ee, q_pp, it = _ro_collinearity(l_obs, w, f, bx, max_iter, tol)
    elif method == "coplanarity":
        e, pts, v, q_ee, q_pp, it = _ro_coplanarity(l_obs, w, f, bx, max_iter, tol)
    else:
        raise ValueError(f"unknown method {method!r}")
    dof = n - 5
    vtpv = float(np.sum(w * v * v))
    s0 = float(np.sqrt(vtpv / dof)) if dof > 0 else float("nan")
    scale = s0**2 if a_posteriori else 1.0
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


# --------------------------------------------------------- 3D conformal transformation
def _conf_apply(params: np.ndarray, x: np.ndarray) -> np.ndarray:
    m = rotation_matrix(params[1], params[2], params[3])
    return params[0] * (x @ m) + params[4:7]


def _conf_partials(params: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``d X / d(scale, omega, phi, kappa, Tx, Ty, Tz)`` for ``X = s M' x + T``: (n, 3, 7)."""
    m = rotation_matrix(params[1], params[2], params[3])
    dm = rotation_matrix_partials(params[1], params[2], params[3])
    n = x.shape[0]
    a = np.zeros((n, 3, 7))
    a[:, :, 0] = x @ m
    for k in range(3):
        a[:, :, 1 + k] = params[0] * (x @ dm[k])
    a[:, :, 4:7] = np.eye(3)
    return a


def _conf_initial(x: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Closed-form similarity (Horn / Umeyama) as initial approximation."""
    xc = x - x.mean(0)
    Xc = X - X.mean(0)
    u, d, vt = np.linalg.svd(Xc.T @ xc)
    sign = np.sign(np.linalg.det(u @ vt)) or 1.0
    dd = np.array([1.0, 1.0, sign])
    rot = (u * dd) @ vt  # X ~ s rot x
    s = float(np.sum(d * dd) / np.sum(xc * xc))
    t = X.mean(0) - s * (x.mean(0) @ rot.T)
    ang = rotation_to_angles(rot.T)  # rot = M'
    return np.array([s, ang[0], ang[1], ang[2], t[0], t[1], t[2]])


@dataclass
class Conformal3D:
    """Result of :func:`conformal3d`: ``X = s M' x + T``.

    Attributes
    ----------
    method : str
        ``"ols"`` (ground residuals only) or ``"gauss-helmert"`` (model and ground).
    params : numpy.ndarray, shape (7,)
        ``scale, omega, phi, kappa`` (rad), ``Tx, Ty, Tz``.
    cov_params : numpy.ndarray, shape (7, 7)
    residuals_ground : numpy.ndarray, shape (n, 3)
        ``v = adjusted - observed`` of the ground coordinates.
    residuals_model : numpy.ndarray, shape (n, 3)
        Same for the model coordinates (zero for ``"ols"``).
    s0 : float
        A-posteriori standard deviation of unit weight.
    dof : int
        ``3n - 7``.
    iterations : int
    a_posteriori : bool
        Whether ``cov_params`` was scaled by ``s0**2``.
    sensitivity : numpy.ndarray, shape (7, 6n)
        ``d params / d observations`` with observations ordered
        ``[model.ravel(), ground.ravel()]`` (used for rigorous propagation).
    """

    method: str
    params: np.ndarray
    cov_params: np.ndarray
    residuals_ground: np.ndarray
    residuals_model: np.ndarray
    s0: float
    dof: int
    iterations: int
    a_posteriori: bool
    sensitivity: np.ndarray = field(repr=False)

    @property
    def scale(self) -> float:
        """Scale factor ``s``."""
        return float(self.params[0])

    @property
    def angles_deg(self) -> np.ndarray:
        """``omega, phi, kappa`` in degrees."""
        return np.degrees(self.params[1:4])

    @property
    def translation(self) -> np.ndarray:
        """``Tx, Ty, Tz``."""
        return self.params[4:7].copy()

    @property
    def rotation(self) -> np.ndarray:
        """The model-to-ground rotation ``M'`` (``M = M_kappa M_phi M_omega``)."""
        return rotation_matrix(*self.params[1:4]).T

    @property
    def sigma_params(self) -> np.ndarray:
        """Standard deviations of the seven parameters (angles in radians)."""
        return np.sqrt(np.diag(self.cov_params))

    def jacobian_params(self, points) -> np.ndarray:
        """``F1 = d X / d params`` for model points ``(k, 3)``: shape ``(3k, 7)``."""
        x = np.asarray(points, float).reshape(-1, 3)
        return _conf_partials(self.params, x).reshape(-1, 7)

    def transform(self, points, cov_points=None, *, full: bool = True):
        """Ground coordinates of model points and their covariance.

        ``Sigma_X = F1 Sigma_aa F1' + F2 Sigma_mm F2'`` with ``F1 = dX/dparams`` and
        ``F2 = s M'`` (per point). The points are taken as independent of the
        transformation parameters (true for points that were not control points).

        Parameters
        ----------
        points : array_like, shape (k, 3)
            Model coordinates.
        cov_points : array_like, optional
            Their covariance: ``(3k, 3k)`` full or ``(k, 3, 3)`` blocks (or a scalar
            sigma / ``(3,)`` / ``(k, 3)`` sigmas). ``None``: error-free points.
        full : bool
            Return the full ``(3k, 3k)`` covariance (default); ``False`` returns the
            ``(k, 3, 3)`` per-point blocks only (cheap for many points).

        Returns
        -------
        xyz : numpy.ndarray, shape (k, 3)
        cov : numpy.ndarray, shape (3k, 3k) or (k, 3, 3)
        """
        x = np.asarray(points, float).reshape(-1, 3)
        k = x.shape[0]
        xyz = _conf_apply(self.params, x)
        f1 = _conf_partials(self.params, x)  # (k, 3, 7)
        sr = self.scale * self.rotation
        if full:
            f1f = f1.reshape(3 * k, 7)
            cov = f1f @ self.cov_params @ f1f.T
            if cov_points is not None:
                cov = cov + _sandwich(sr, _cov3(cov_points, k, "transform"))
            return xyz, cov
        cov = np.einsum("nij,jk,nlk->nil", f1, self.cov_params, f1)
        if cov_points is not None:
            c = np.asarray(cov_points, float)
            if c.shape == (3 * k, 3 * k) and k > 0:
                idx = np.arange(k)
                blocks = c.reshape(k, 3, k, 3)[idx, :, idx, :]
            elif c.shape == (k, 3, 3):
                blocks = c
            else:
                cm = _cov3(c, k, "transform").reshape(k, 3, k, 3)
                idx = np.arange(k)
                blocks = cm[idx, :, idx, :]
            cov = cov + np.einsum("ij,njl,kl->nik", sr, blocks, sr)
        return xyz, cov

    def report(self) -> str:
        """Plain-text summary in the layout of Dewitt's ``3DCONF`` output."""
        sd = self.sigma_params
        deg = 180.0 / np.pi
        lines = [f"3D conformal transformation ({self.method})", "",
                 f"{'Param':>5}  {'Value':>10}  {'Stan.Dev.':>10}",
                 f"{'scale':>5}  {self.params[0]:10.5f}  {sd[0]:10.5f}"]
        for i in range(1, 4):
            lines.append(f"{_CONF_PARAMS[i]:>5}  {self.params[i] * deg:10.4f}d "
                         f"{sd[i] * deg:10.4f}d")
        for i in range(4, 7):
            lines.append(f"{_CONF_PARAMS[i]:>5}  {self.params[i]:10.3f}  {sd[i]:10.3f}")
        lines.append(f"Standard error of unit weight: {self.s0:.5f} ({self.dof} dof)")
        return "\n".join(lines)


def _conf_check_points(x: np.ndarray, X: np.ndarray) -> None:
    """Raise :class:`ControlError` unless model and ground are the same >= 3 finite points."""
    if x.ndim != 2 or x.shape[1] != 3 or x.shape != X.shape:
        raise ControlError(
            f"3D conformal transformation: model {x.shape} and ground {X.shape} coordinates "
            "must both be (n, 3) arrays of the same points",
            "Give one row of x, y, z per common point in both systems",
        )
    n = x.shape[0]
    if n < 3:
        raise ControlError(
            f"3D conformal transformation needs at least 3 common points; got {n}",
            "Add control points (3 non-collinear, better 4 or more)",
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(X))):
        raise ControlError("3D conformal transformation: coordinates contain NaN or inf",
                           "Complete or remove the incomplete points")


def _conf_check_collinear(x: np.ndarray) -> None:
    """Raise :class:`ControlError` if the common points are collinear."""
    sv = np.linalg.svd(x - x.mean(0), compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ControlError(
            "3D conformal transformation: the common points are collinear",
            "Use control points that span a plane or a volume",
        )


def _conf_iterate(params, x, X, c_m, c_g, max_iter: int, tol: float):
    """Gauss-Helmert iteration from ``params``: the parameters, model residuals, iterations."""
    n = x.shape[0]
    scale_ref = max(float(np.max(np.abs(X))), 1.0)
    v_m = np.zeros((n, 3))
    it = 0
    converged = False
    previous = np.inf
    while it < max_iter:
        it += 1
        a, b_m, qw, qw_inv, wv = _conf_gh_terms(params, x, X, v_m, c_m, c_g)
        n_mat = a.T @ qw_inv @ a
        dx = -_solve_conf(n_mat, a.T @ (qw_inv @ wv))
        kk = -qw_inv @ (a @ dx + wv)
        v_m = (c_m @ (b_m.T @ kk)).reshape(n, 3)  # zero for "ols" (c_m = 0)
        params = params + dx
        if not np.all(np.isfinite(dx)):
            break
        step = max(abs(dx[0]) / max(abs(params[0]), 1e-300), np.max(np.abs(dx[1:4])),
                   np.max(np.abs(dx[4:])) / scale_ref)
        if _converged(step, previous, tol):
            converged = True
            break
        previous = step
    if not converged:
        raise NonConvergenceError(
            f"3D conformal transformation did not converge in {it} iterations",
            "Check that the common points are the same points in both systems",
        )
    return params, v_m, it


def _conf_result(params, x, X, v_m, c_m, c_g, method: str, a_posteriori: bool,
                 it: int) -> Conformal3D:
    """Residuals, ``s0``, parameter covariance and sensitivity at the solution."""
    n = x.shape[0]
    a, b_m, qw, qw_inv, wv = _conf_gh_terms(params, x, X, v_m, c_m, c_g)
    q_xx = np.linalg.inv(a.T @ qw_inv @ a)
    kk = -qw_inv @ wv
    v_m = (c_m @ (b_m.T @ kk)).reshape(n, 3)
    v_g = (-(c_g @ kk)).reshape(n, 3)
    vtpv = float(kk @ qw @ kk)  # v' Sigma^-1 v = k' Qw k (also for a singular Sigma)
    dof = 3 * n - 7
    s0 = float(np.sqrt(vtpv / dof)) if dof > 0 else float("nan")
    # d params / d l  with l = [model, ground]: -N^-1 A' Qw^-1 B, B = [b_m, -I]
    b_full = np.hstack([b_m, -np.eye(3 * n)])
    sens = -q_xx @ a.T @ qw_inv @ b_full
    return Conformal3D(
        method=method,
        params=params,
        cov_params=(s0**2 if a_posteriori else 1.0) * q_xx,
        residuals_ground=v_g,
        residuals_model=v_m if method != "ols" else np.zeros((n, 3)),
        s0=s0,
        dof=dof,
        iterations=it,
        a_posteriori=bool(a_posteriori),
        sensitivity=sens,
    )


def conformal3d(
    model,
    ground,
    cov_model=None,
    cov_ground=None,
    *,
    method: str | None = None,
    a_posteriori: bool | None = None,
    max_iter: int = 50,
    tol: float = 1e-11,
) -> Conformal3D:
    """Seven-parameter 3D similarity ``X = s M' x + T`` by least squares.

    Parameters
    ----------
    model : array_like, shape (n, 3)
        Coordinates in the arbitrary (model) system, ``n >= 3`` non-collinear points.
    ground : array_like, shape (n, 3)
        The same points in the control (ground) system.
    cov_model, cov_ground : array_like, optional
        Covariances: ``(3n, 3n)`` full, ``(n, 3, 3)`` blocks, or sigmas (scalar,
        ``(3,)``, ``(n, 3)``). ``None``: unit weights (identity).
    method : {"ols", "gauss-helmert"}, optional
        ``"ols"``: only the ground coordinates have errors (Dewitt ``3DCONF``).
        ``"gauss-helmert"``: condition equations ``s M' x + T - X = 0`` with errors in
        model and ground coordinates, ``A dx + B v + w = 0``, linearised at the
        adjusted observations and iterated to the rigorous solution.
        Default: ``"gauss-helmert"`` if ``cov_model`` is given, else ``"ols"``.
    a_posteriori : bool, optional
        Scale ``cov_params`` by ``s0**2``. Default: only when no covariance was given
        (unit weights, as ``3DCONF``).
    max_iter, tol : int, float
        Iteration limit and threshold on the largest correction (scale relative,
        angles in radians, translations relative to the largest ground coordinate);
        corrections that stop decreasing below ``1e-7`` also count as converged.

    Returns
    -------
    Conformal3D

    Raises
    ------
    ControlError
        Fewer than 3 points, shape mismatch, collinear points.
    NonConvergenceError
    """
    x = np.asarray(model, float)
    X = np.asarray(ground, float)
    _conf_check_points(x, X)
    n = x.shape[0]
    if method is None:
        method = "gauss-helmert" if cov_model is not None else "ols"
    if method not in ("ols", "gauss-helmert"):
        raise ValueError(f"unknown method {method!r}")
    if a_posteriori is None:
        a_posteriori = cov_model is None and cov_ground is None
    c_g = _cov3(cov_ground, n, "3D conformal transformation (ground)")
    c_m = (np.zeros((3 * n, 3 * n)) if method == "ols"
           else _cov3(cov_model, n, "3D conformal transformation (model)"))
    _conf_check_collinear(x)
    params, v_m, it = _conf_iterate(_conf_initial(x, X), x, X, c_m, c_g, max_iter, tol)
    return _conf_result(params, x, X, v_m, c_m, c_g, method, a_posteriori, it)


def _solve_conf(n_mat, rhs):
    cond = _scaled_cond(n_mat)
    if not np.isfinite(cond) or cond > 1e15:
        raise ControlError(
            f"3D conformal transformation: normal equations singular (condition {cond:.3g})",
            "The common points are too few or collinear; add well-spread control points",
        )
    return np.linalg.solve(n_mat, rhs)


def _conf_gh_terms(params, x, X, v_m, c_m, c_g):
    """Gauss-Helmert terms at the adjusted model coordinates ``x + v_m``.

    Condition ``g = s M' (x + v_m) + T - (X + v_g) = 0``. Returns ``A`` (3n, 7),
    ``B_m = d g / d x`` (3n, 3n), ``Qw``, ``Qw^-1`` and the misclosure ``w = g0 - B v``
    (``g0`` at the current adjusted observations, ``B v`` at the current residuals;
    the ground residuals cancel exactly because ``g`` is linear in ``X``).
    """
    n = x.shape[0]
    xa = x + v_m
    a = _conf_partials(params, xa).reshape(3 * n, 7)
    sr = params[0] * rotation_matrix(params[1], params[2], params[3]).T
    b_m = _block_diag(np.broadcast_to(sr, (n, 3, 3)))
    g0 = (_conf_apply(params, xa) - X).ravel()  # with v_g: g0 - v_g, and B_g v_g = -v_g
    wv = g0 - b_m @ v_m.ravel()
    qw = b_m @ c_m @ b_m.T + c_g
    try:
        qw_inv = np.linalg.inv(qw)
    except np.linalg.LinAlgError as exc:
        raise ControlError(
            "3D conformal transformation: the covariance of the conditions is singular",
            "Give positive sigmas for the ground (and model) coordinates",
        ) from exc
    return a, b_m, qw, qw_inv, wv


# ----------------------------------------------------------------------------- two step
@dataclass
class TwoStep:
    """Result of :func:`two_step`.

    Attributes
    ----------
    ids : numpy.ndarray, shape (n,)
        Point ids in input order.
    ground_xyz : numpy.ndarray, shape (n, 3)
        Ground coordinates of all points: the similarity applied to the model
        coordinates (control points included, i.e. their photogrammetric position).
    cov : numpy.ndarray, shape (3n, 3n)
        Rigorous full covariance: the transformation parameters are functions of the
        control points' model coordinates, so their correlation with the model
        coordinates of all points is propagated
        (``J_m Sigma_mm J_m' + J_g Sigma_gg J_g'``).
    cov_classical : numpy.ndarray, shape (3n, 3n)
        The textbook ``F1 Sigma_aa F1' + F2 Sigma_mm F2'`` (parameters taken as
        independent of the model coordinates).
    relative : RelativeOrientation
    absolute : Conformal3D
    control_index : numpy.ndarray
        Indices (into ``ids``) of the control points used.
    """

    ids: np.ndarray
    ground_xyz: np.ndarray
    cov: np.ndarray
    cov_classical: np.ndarray
    relative: RelativeOrientation
    absolute: Conformal3D
    control_index: np.ndarray

    @property
    def cov_points(self) -> np.ndarray:
        """``(n, 3, 3)`` per-point blocks of :attr:`cov`."""
        n = self.ground_xyz.shape[0]
        idx = np.arange(n)
        return self.cov.reshape(n, 3, n, 3)[idx, :, idx, :]

    @property
    def sigma(self) -> np.ndarray:
        """``(n, 3)`` standard deviations of the ground coordinates."""
        return np.sqrt(np.diag(self.cov)).reshape(-1, 3)


def two_step(
    left_xy,
    right_xy,
    ids,
    f: float,
    control_ids,
    control_xyz,
    control_sigma,
    image_sigma,
    *,
    bx: float | None = None,
    method: str = "collinearity",
) -> TwoStep:
    """Relative orientation, then absolute orientation, with full error propagation.

    The given sigmas are taken as true (a-priori variance factor 1 in both steps);
    ``relative.s0`` and ``absolute.s0`` tell whether they were realistic.

    Parameters
    ----------
    left_xy, right_xy : array_like, shape (n, 2)
        Photo coordinates (mm) of all points (tie, control and others).
    ids : array_like, shape (n,)
        Point ids (unique).
    f : float
        Focal length (mm).
    control_ids : array_like, shape (k,)
        Ids of the control points (``k >= 3``, all among ``ids``).
    control_xyz : array_like, shape (k, 3)
        Their ground coordinates.
    control_sigma : float or array_like
        Ground control sigmas: scalar, ``(3,)``, ``(k, 3)``, ``(k, 3, 3)`` or
        ``(3k, 3k)``.
    image_sigma : float or array_like
        Photo coordinate sigma(s) (mm), as in :func:`relative_orientation`.
    bx : float, optional
        Model base (default: mean x-parallax).
    method : {"collinearity", "coplanarity"}
        Relative orientation formulation.
    Returns
    -------
    TwoStep

    Raises
    ------
    MeasurementError
        Duplicate ids or bad image measurements.
    ControlError
        Unknown control ids, fewer than 3 control points, collinear control.
    """
    ids = np.asarray(ids)
    n = len(ids)
    if len(np.unique(ids)) != n:
        u, c = np.unique(ids, return_counts=True)
        raise MeasurementError(
            f"Two-step orientation: duplicate point ids {list(u[c > 1][:5])}",
            "Give every measured point a unique id",
        )
    cids = np.asarray(control_ids)
    pos = {k: i for i, k in enumerate(ids.tolist())}
    missing = [c for c in cids.tolist() if c not in pos]
    if missing:
        raise ControlError(
            f"Two-step orientation: control point(s) {missing[:5]} are not measured on the "
            "stereo pair",
            "Measure them on both photos or remove them from the control list",
        )
    cidx = np.array([pos[c] for c in cids.tolist()], dtype=int)
    k = len(cidx)
    if k < 3:
        raise ControlError(
            f"Two-step orientation needs at least 3 control points; got {k}",
            "Add control points (3 non-collinear, better 4 or more)",
        )
    cxyz = np.asarray(control_xyz, float)
    if cxyz.shape != (k, 3):
        raise ControlError(
            f"Two-step orientation: control coordinates have shape {cxyz.shape}, expected "
            f"({k}, 3)",
            "Give X, Y, Z for every control id",
        )
    ro = relative_orientation(left_xy, right_xy, f, bx=bx, sigma=image_sigma, method=method,
                              a_posteriori=False)
    sel = (3 * cidx[:, None] + np.arange(3)).ravel()
    c_mm = ro.cov_model
    c_gg = _cov3(control_sigma, k, "Two-step orientation (control)")
    ao = conformal3d(ro.model_xyz[cidx], cxyz, cov_model=c_mm[np.ix_(sel, sel)],
                     cov_ground=c_gg, method="gauss-helmert", a_posteriori=False)
    ground, cov_classical = ao.transform(ro.model_xyz, c_mm, full=True)
    # rigorous: params = params(model_c, ground_c), so
    # d ground = (I kron sR + F1 K_m S) d model + F1 K_g d control
    f1 = ao.jacobian_params(ro.model_xyz)  # (3n, 7)
    k_m = ao.sensitivity[:, : 3 * k]
    k_g = ao.sensitivity[:, 3 * k:]
    sr = ao.scale * ao.rotation
    km_sig = k_m @ c_mm[sel, :]  # K_m S Sigma_mm  (7, 3n)
    cross = f1 @ _right_apply(km_sig, sr)  # F1 K_m S Sigma (I kron sR)'
    inner = km_sig[:, sel] @ k_m.T + k_g @ c_gg @ k_g.T
    cov = _sandwich(sr, c_mm) + cross + cross.T + f1 @ inner @ f1.T
    return TwoStep(
        ids=ids,
        ground_xyz=ground,
        cov=0.5 * (cov + cov.T),
        cov_classical=0.5 * (cov_classical + cov_classical.T),
        relative=ro,
        absolute=ao,
        control_index=cidx,
    )
