"""General error propagation: block-diagonal covariances, :class:`PropagationResult` and
:func:`propagate` (analytic or finite-difference Jacobians).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import numpy as np

__all__ = ["PropagationResult", "propagate", "block_diagonal"]


ArrayLike = Union[float, np.ndarray, list, tuple]



def block_diagonal(cov, block_size: int) -> np.ndarray:
    """The covariance "without covariances between points".

    Parameters
    ----------
    cov : array_like, shape (n, n)
        Full covariance of ``n / block_size`` points, point-major
        (``x1, y1, z1, x2, ...``).
    block_size : int
        Coordinates per point (3 for XYZ, 2 for XY, 1 keeps only the diagonal).

    Returns
    -------
    numpy.ndarray, shape (n, n)
        ``cov`` with every entry outside the diagonal ``block_size`` blocks set to 0.
    """
    c = np.asarray(cov, float)
    n = c.shape[0]
    if c.shape != (n, n) or n % block_size:
        raise ValueError(f"covariance of shape {c.shape} does not split into {block_size}-blocks")
    point = np.arange(n) // block_size
    return np.where(point[:, None] == point[None, :], c, 0.0)


def _full_cov(cov, n: int, d: int) -> np.ndarray:
    """``(n d, n d)`` covariance from a full matrix or ``(n, d, d)`` blocks."""
    c = np.asarray(cov, float)
    if c.shape == (n * d, n * d):
        return c
    if c.shape == (n, d, d):
        out = np.zeros((n, d, n, d))
        idx = np.arange(n)
        out[idx, :, idx, :] = c
        return out.reshape(n * d, n * d)
    raise ValueError(
        f"covariance of shape {c.shape} does not fit {n} points of dimension {d}: give "
        f"({n * d}, {n * d}) or ({n}, {d}, {d})"
    )


@dataclass
class PropagationResult:
    """Result of :func:`propagate`.

    Attributes
    ----------
    value : float or numpy.ndarray, shape (m,)
        ``func(x)``.
    covariance : numpy.ndarray, shape (m, m)
        ``F Sigma F'`` with the full covariance.
    sigma : float or numpy.ndarray, shape (m,)
        Square roots of its diagonal.
    covariance_variance_only : numpy.ndarray, shape (m, m)
        ``F Sigma_b F'`` with ``Sigma_b`` the block-diagonal part (per point).
    sigma_variance_only : float or numpy.ndarray, shape (m,)
        Square roots of its diagonal ("without covariances between points").
    jacobian : numpy.ndarray, shape (m, n)
    """

    value: float | np.ndarray
    covariance: np.ndarray
    sigma: float | np.ndarray
    covariance_variance_only: np.ndarray
    sigma_variance_only: float | np.ndarray
    jacobian: np.ndarray


def _fd_steps(x: np.ndarray, cov: np.ndarray, step) -> np.ndarray:
    if step is not None:
        h = np.broadcast_to(np.asarray(step, float), x.shape).astype(float)
    else:
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        scale = np.maximum(np.abs(x), 1.0)
        # a thousandth of the standard deviation: the scale on which the linearisation
        # is used; never below the round-off floor of x itself
        h = np.where(sig > 0, 1e-3 * sig, np.cbrt(np.finfo(float).eps) * scale)
        h = np.maximum(h, 1e4 * np.finfo(float).eps * scale)
    return (x + h) - x  # exactly representable steps


def propagate(
    func: Callable[[np.ndarray], ArrayLike],
    x,
    cov,
    jacobian: Callable[[np.ndarray], np.ndarray] | np.ndarray | None = None,
    step=None,
    block_size: int = 3,
) -> PropagationResult:
    """General first-order propagation ``Sigma_f = F Sigma F'``.

    Parameters
    ----------
    func : callable
        ``func(x) -> scalar or (m,)``.
    x : array_like, shape (n,)
        Parameter vector, e.g. the flattened XYZ of several points (point-major).
    cov : array_like, shape (n, n)
        FULL covariance of ``x``.
    jacobian : callable or array_like, optional
        Analytic Jacobian ``(m, n)`` (or a callable returning it). Default: central
        finite differences.
    step : float or array_like, optional
        Finite-difference step(s). Default: ``1e-3`` standard deviation of each
        parameter (scale-aware: the linearisation is only used within a few sigma),
        at least ``1e4 eps max(|x|, 1)``; parameters with zero variance use
        ``eps^(1/3) max(|x|, 1)``.
    block_size : int
        Coordinates per point for :attr:`PropagationResult.sigma_variance_only` (the
        block-diagonal part of ``cov``: covariances between points ignored). 3 for
        XYZ, 2 for XY, 1 for "variances only".

    Returns
    -------
    PropagationResult
    """
    x = np.asarray(x, float).ravel()
    n = x.size
    cov = np.asarray(cov, float)
    if cov.shape != (n, n):
        raise ValueError(f"covariance must be ({n}, {n}); got {cov.shape}")
    f0 = np.asarray(func(x), float)
    scalar = f0.ndim == 0
    f0v = f0.ravel()
    if jacobian is None:
        h = _fd_steps(x, cov, step)
        jac = np.empty((f0v.size, n))
        for i in range(n):  # black-box function: one column per parameter
            xp = x.copy()
            xm = x.copy()
            xp[i] += h[i]
            xm[i] -= h[i]
            jac[:, i] = (np.asarray(func(xp), float).ravel()
                         - np.asarray(func(xm), float).ravel()) / (2 * h[i])
    else:
        jac = jacobian(x) if callable(jacobian) else jacobian
        jac = np.asarray(jac, float).reshape(f0v.size, n)
    c_full = jac @ cov @ jac.T
    c_blk = jac @ block_diagonal(cov, block_size) @ jac.T
    s_full = np.sqrt(np.clip(np.diag(c_full), 0.0, None))
    s_blk = np.sqrt(np.clip(np.diag(c_blk), 0.0, None))
    if scalar:
        return PropagationResult(float(f0), c_full, float(s_full[0]), c_blk, float(s_blk[0]), jac)
    return PropagationResult(f0v.reshape(f0.shape), c_full, s_full, c_blk, s_blk, jac)

