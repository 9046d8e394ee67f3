"""Helpers of the stereo orientations: partial derivatives of the rotation matrix,
observation weights, block-diagonal covariances and the covariance sandwich.
"""

from __future__ import annotations

import numpy as np

from vectoradjust.errors import (
    ControlError,
    MeasurementError,
)
from vectoradjust.sensor.collinearity import (
    rotation_derivatives,
    rotation_matrix,
)

__all__ = ["rotation_matrix_partials"]


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


def _check_point_pairs(a: np.ndarray, b: np.ndarray, dim: int, n_min: int, error: type,
                       messages: tuple) -> None:
    """Raise ``error`` unless ``a`` and ``b`` are ``(n, dim)`` arrays of ``n >= n_min``
    finite points.

    ``messages`` are three ``(what, mend)`` pairs, for a shape mismatch (``what``
    formatted with the shapes ``a`` and ``b``), too few points (with ``n``) and
    non-finite coordinates.
    """
    shape, count, finite = messages
    if a.ndim != 2 or a.shape[1] != dim or a.shape != b.shape:
        raise error(shape[0].format(a=a.shape, b=b.shape), shape[1])
    n = a.shape[0]
    if n < n_min:
        raise error(count[0].format(n=n), count[1])
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise error(finite[0], finite[1])
