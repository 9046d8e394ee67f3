"""The Brown (OpenCV/OpenSfM) lens model: :func:`brown_distort` and
:func:`brown_undistort`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera.validators import _positive

__all__ = ["brown_distort", "brown_undistort"]


def _brown_parts(xy: Any, focal_length: float, coefficients: Any,
                 center: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Photo coordinates as normalised OpenCV coordinates (``y`` down) and the checked
    coefficients ``[k1, k2, k3, p1, p2]`` and centre."""
    xy = np.asarray(xy, dtype=float)
    if xy.ndim == 0 or xy.shape[-1] != 2:
        raise CameraError(f"photo coordinates must have two columns (x, y), got shape "
                          f"{xy.shape}", "Pass an (n, 2) array")
    c = np.zeros(5)
    given = np.asarray(coefficients, dtype=float).ravel()
    if given.size > 5:
        raise CameraError(f"the brown model has 5 coefficients (k1 k2 k3 p1 p2), not "
                          f"{given.size}", "Give k1, k2, k3, p1, p2")
    c[:given.size] = given
    f = _positive(focal_length, "focal_length", "brown distortion")
    centre = np.asarray(center, dtype=float).reshape(2)
    u = (xy - centre) / f
    u[..., 1] = -u[..., 1]  # photo y up -> OpenCV y down
    return u, c, centre, np.asarray(f)


def _brown_formula(u: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's formula ``d(u)`` at normalised ``u`` (``y`` down) and its Jacobian."""
    k1, k2, k3, p1, p2 = c
    x, y = u[..., 0], u[..., 1]
    s = x * x + y * y
    radial = 1.0 + s * (k1 + s * (k2 + s * k3))
    dradial = k1 + s * (2.0 * k2 + 3.0 * k3 * s)  # d radial / d s
    d = np.stack([x * radial + 2.0 * p1 * x * y + p2 * (s + 2.0 * x * x),
                  y * radial + p1 * (s + 2.0 * y * y) + 2.0 * p2 * x * y], axis=-1)
    jac = np.empty(u.shape[:-1] + (2, 2))
    cross = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jac[..., 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    jac[..., 0, 1] = cross
    jac[..., 1, 0] = cross
    jac[..., 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return d, jac


def brown_distort(xy: Any, focal_length: float, coefficients: Any,
                  center: Any = (0.0, 0.0)) -> np.ndarray:
    """Where the lens records an ideal position: the Brown (OpenCV) model, forward.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal photo coordinates (mm, ``x`` right, ``y`` up).
    focal_length : float
        ``f`` (mm): the coordinates are normalised as ``x / f``.
    coefficients : sequence of up to 5 floats
        ``k1, k2, k3, p1, p2`` as OpenCV and OpenSfM give them (``y`` down); missing
        trailing ones are zero.
    center : (float, float)
        The principal point (mm) in the frame of ``xy``.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Distorted photo coordinates (mm, same frame).
    """
    u, c, centre, f = _brown_parts(xy, focal_length, coefficients, center)
    d, _ = _brown_formula(u, c)
    d[..., 1] = -d[..., 1]
    return d * f + centre


def brown_undistort(xy: Any, focal_length: float, coefficients: Any,
                    center: Any = (0.0, 0.0), *, tol: float = 1e-12,
                    max_iter: int = 50) -> np.ndarray:
    """The ideal position of recorded photo coordinates: :func:`brown_distort` inverted.

    Newton's method in the plane, vectorised over the points, started at the recorded
    position, until every point's residual ``|distort(ideal) - recorded|`` is below
    ``tol`` (mm).

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Recorded (distorted) photo coordinates (mm, ``y`` up).
    focal_length, coefficients, center
        As for :func:`brown_distort`.
    tol : float
        Convergence tolerance (mm).
    max_iter : int
        Iteration limit.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Ideal photo coordinates (mm).

    Raises
    ------
    CameraError
        When some point does not converge (beyond the radius where the model folds
        back: coefficients of another convention or unit).
    """
    target, c, centre, f = _brown_parts(xy, focal_length, coefficients, center)
    m = target.copy()
    res = np.zeros_like(m)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            d, jac = _brown_formula(m, c)
            res = target - d
            if m.size == 0 or float(np.max(np.abs(res))) * f <= tol:
                break
            det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
            m = m + np.stack([jac[..., 1, 1] * res[..., 0] - jac[..., 0, 1] * res[..., 1],
                              jac[..., 0, 0] * res[..., 1] - jac[..., 1, 0] * res[..., 0]],
                             axis=-1) / det[..., None]
    bad = ~(np.abs(res).max(axis=-1) * f <= tol) if m.size else np.zeros(0, bool)
    if np.any(bad):
        r = np.hypot(target[..., 0], target[..., 1])[bad] * f
        raise CameraError(
            f"the brown lens distortion could not be inverted to {tol:g} mm at "
            f"{int(np.sum(bad))} point(s), up to {float(np.max(r)):.4g} mm from the "
            "principal point (the model folds back there)",
            "Check k1 k2 k3 p1 p2: they are unitless, of coordinates normalised by the "
            "focal length (OpenCV/OpenSfM), and the points lie inside the frame",
            details={"points": int(np.sum(bad))})
    m[..., 1] = -m[..., 1]
    return m * f + centre

