"""The 3D conformal (seven-parameter similarity) transformation, adjusted by Gauss-Helmert:
:class:`Conformal3D` and :func:`conformal3d`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from vectoradjust.adjust.orientation.common import (
    _block_diag,
    _check_point_pairs,
    _cov3,
    _sandwich,
    rotation_matrix_partials,
)
from vectoradjust.adjust.orientation.relative import _iterate, _scaled_cond
from vectoradjust.errors import ControlError
from vectoradjust.sensor.collinearity import (
    rotation_matrix,
    rotation_to_angles,
)

__all__ = ["Conformal3D", "conformal3d"]


_CONF_PARAMS = ("scale", "omega", "phi", "kappa", "Tx", "Ty", "Tz")



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
    _check_point_pairs(x, X, 3, 3, ControlError, (
        ("3D conformal transformation: model {a} and ground {b} coordinates must both be "
         "(n, 3) arrays of the same points",
         "Give one row of x, y, z per common point in both systems"),
        ("3D conformal transformation needs at least 3 common points; got {n}",
         "Add control points (3 non-collinear, better 4 or more)"),
        ("3D conformal transformation: coordinates contain NaN or inf",
         "Complete or remove the incomplete points")))


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

    def update() -> Optional[float]:
        nonlocal params, v_m
        a, b_m, qw, qw_inv, wv = _conf_gh_terms(params, x, X, v_m, c_m, c_g)
        n_mat = a.T @ qw_inv @ a
        dx = -_solve_conf(n_mat, a.T @ (qw_inv @ wv))
        kk = -qw_inv @ (a @ dx + wv)
        v_m = (c_m @ (b_m.T @ kk)).reshape(n, 3)  # zero for "ols" (c_m = 0)
        params = params + dx
        if not np.all(np.isfinite(dx)):
            return None
        return max(abs(dx[0]) / max(abs(params[0]), 1e-300), np.max(np.abs(dx[1:4])),
                   np.max(np.abs(dx[4:])) / scale_ref)

    it = _iterate(update, max_iter, tol, "3D conformal transformation",
                  "Check that the common points are the same points in both systems")
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

