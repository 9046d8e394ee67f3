"""Collinearity equations, rotation matrices and their analytic partials.

Conventions (``docs/method.md`` section 2): photo coordinates in millimetres, exterior
orientation ``[XL, YL, ZL, omega, phi, kappa]`` with angles in radians,
``M = M_kappa M_phi M_omega`` (Wolf & Dewitt). Everything is vectorised over
observations: pass arrays of shape ``(k, 6)`` for the exterior orientation of the
image of each observation and ``(k, 3)`` for its object point.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rotation_matrix", "rotation_derivatives", "project", "partials",
           "rotation_to_angles"]


def rotation_matrix(omega, phi, kappa) -> np.ndarray:
    """Rotation matrix ``M = M_kappa M_phi M_omega`` (ground to image).

    Parameters
    ----------
    omega, phi, kappa : float or array_like
        Angles in radians, broadcastable to a common shape ``s``.

    Returns
    -------
    numpy.ndarray
        Shape ``s + (3, 3)``.
    """
    o, p, k = np.broadcast_arrays(
        np.asarray(omega, float), np.asarray(phi, float), np.asarray(kappa, float)
    )
    so, co, sp, cp, sk, ck = np.sin(o), np.cos(o), np.sin(p), np.cos(p), np.sin(k), np.cos(k)
    m = np.empty(o.shape + (3, 3))
    m[..., 0, 0] = cp * ck
    m[..., 0, 1] = so * sp * ck + co * sk
    m[..., 0, 2] = -co * sp * ck + so * sk
    m[..., 1, 0] = -cp * sk
    m[..., 1, 1] = -so * sp * sk + co * ck
    m[..., 1, 2] = co * sp * sk + so * ck
    m[..., 2, 0] = sp
    m[..., 2, 1] = -so * cp
    m[..., 2, 2] = co * cp
    return m


def rotation_derivatives(omega, phi, kappa) -> np.ndarray:
    """Derivatives of :func:`rotation_matrix` with respect to omega, phi and kappa.

    Parameters
    ----------
    omega, phi, kappa : float or array_like
        Angles in radians, broadcastable to a common shape ``s``.

    Returns
    -------
    numpy.ndarray
        Shape ``s + (3, 3, 3)``: ``[..., 0]`` is ``dM/domega``, ``[..., 1]``
        ``dM/dphi``, ``[..., 2]`` ``dM/dkappa``, each a 3x3 matrix (the last two axes).

    Notes
    -----
    ``dM/domega`` has the columns ``0, -m_i3, m_i2`` and ``dM/dkappa`` the rows
    ``m_2j, -m_1j, 0``; ``dM/dphi`` is the derivative of the ``cos phi`` / ``sin phi``
    factors of ``docs/method.md`` section 2. Computed once per image, they give the angular
    partials of every observation of that image (:mod:`vectoradjust.adjust.bundle`).
    """
    o, p, k = np.broadcast_arrays(
        np.asarray(omega, float), np.asarray(phi, float), np.asarray(kappa, float)
    )
    m = rotation_matrix(o, p, k)
    so, co, sp, cp, sk, ck = np.sin(o), np.cos(o), np.sin(p), np.cos(p), np.sin(k), np.cos(k)
    d = np.zeros(o.shape + (3, 3, 3))
    d[..., 0, :, 1] = -m[..., :, 2]
    d[..., 0, :, 2] = m[..., :, 1]
    d[..., 1, 0, 0] = -sp * ck
    d[..., 1, 0, 1] = so * cp * ck
    d[..., 1, 0, 2] = -co * cp * ck
    d[..., 1, 1, 0] = sp * sk
    d[..., 1, 1, 1] = -so * cp * sk
    d[..., 1, 1, 2] = co * cp * sk
    d[..., 1, 2, 0] = cp
    d[..., 1, 2, 1] = so * sp
    d[..., 1, 2, 2] = -co * sp
    d[..., 2, 0, :] = m[..., 1, :]
    d[..., 2, 1, :] = -m[..., 0, :]
    return d


def rotation_to_angles(m: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_matrix`: ``(..., 3, 3) -> (..., 3)`` omega, phi, kappa."""
    m = np.asarray(m, float)
    phi = np.arcsin(np.clip(m[..., 2, 0], -1.0, 1.0))
    omega = np.arctan2(-m[..., 2, 1], m[..., 2, 2])
    kappa = np.arctan2(-m[..., 1, 0], m[..., 0, 0])
    return np.stack([omega, phi, kappa], axis=-1)


def _uvw(eo: np.ndarray, xyz: np.ndarray):
    eo = np.asarray(eo, float)
    xyz = np.asarray(xyz, float)
    m = rotation_matrix(eo[..., 3], eo[..., 4], eo[..., 5])
    d = xyz - eo[..., :3]
    rsq = np.einsum("...ij,...j->...i", m, d)
    return m, d, rsq


def project(eo, xyz, focal_length: float, principal_point=(0.0, 0.0)) -> np.ndarray:
    """Photo coordinates of object points (collinearity equations).

    Parameters
    ----------
    eo : array_like, shape (..., 6)
        ``XL, YL, ZL, omega, phi, kappa`` (metres, radians).
    xyz : array_like, shape (..., 3)
        Object point coordinates (metres), broadcastable against ``eo``.
    focal_length : float
        Calibrated focal length ``f`` (mm).
    principal_point : (float, float)
        ``x0, y0`` (mm).

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        ``x = x0 - f r/q``, ``y = y0 - f s/q`` in millimetres.
    """
    _, _, rsq = _uvw(eo, xyz)
    r, s, q = rsq[..., 0], rsq[..., 1], rsq[..., 2]
    x0, y0 = principal_point
    return np.stack([x0 - focal_length * r / q, y0 - focal_length * s / q], axis=-1)


def partials(eo, xyz, focal_length: float):
    """Analytic partial derivatives of the collinearity equations.

    Parameters
    ----------
    eo : array_like, shape (k, 6)
    xyz : array_like, shape (k, 3)
    focal_length : float

    Returns
    -------
    a_eo : numpy.ndarray, shape (k, 2, 6)
        ``d(x, y) / d(XL, YL, ZL, omega, phi, kappa)``.
    a_pt : numpy.ndarray, shape (k, 2, 3)
        ``d(x, y) / d(XA, YA, ZA)`` (equal to minus the position columns of ``a_eo``).

    Notes
    -----
    Wolf & Dewitt, Appendix D (the ``b`` coefficients in ``docs/method.md`` section 2): the ``b``
    terms are the partials of the linearised form ``x_meas = F + b dparam + v``, with
    ``d x / d omega = b11`` etc. and ``d x / d XL = -b14``.
    """
    eo = np.asarray(eo, float)
    xyz = np.asarray(xyz, float)
    m, d, rsq = _uvw(eo, xyz)
    f = float(focal_length)
    o, p, k = eo[..., 3], eo[..., 4], eo[..., 5]
    so, co, sp, cp, sk, ck = np.sin(o), np.cos(o), np.sin(p), np.cos(p), np.sin(k), np.cos(k)
    dX, dY, dZ = d[..., 0], d[..., 1], d[..., 2]
    r, s, q = rsq[..., 0], rsq[..., 1], rsq[..., 2]
    fq2 = f / (q * q)
    fq = f / q

    dq_dom = -m[..., 2, 2] * dY + m[..., 2, 1] * dZ
    b11 = fq2 * (r * dq_dom - q * (-m[..., 0, 2] * dY + m[..., 0, 1] * dZ))
    dq_dphi = cp * dX + so * sp * dY - co * sp * dZ
    b12 = fq2 * (r * dq_dphi - q * (-sp * ck * dX + so * cp * ck * dY - co * cp * ck * dZ))
    b13 = -fq * s
    b21 = fq2 * (s * dq_dom - q * (-m[..., 1, 2] * dY + m[..., 1, 1] * dZ))
    b22 = fq2 * (s * dq_dphi - q * (sp * sk * dX - so * cp * sk * dY + co * cp * sk * dZ))
    b23 = fq * r
    # b14..b16 and b24..b26: f/q^2 (r m3j - q m1j) and f/q^2 (s m3j - q m2j)
    bx = fq2[..., None] * (r[..., None] * m[..., 2, :] - q[..., None] * m[..., 0, :])
    by = fq2[..., None] * (s[..., None] * m[..., 2, :] - q[..., None] * m[..., 1, :])

    shape = eo.shape[:-1] if eo.ndim > 1 else xyz.shape[:-1]
    a_eo = np.empty(np.broadcast_shapes(shape, xyz.shape[:-1]) + (2, 6))
    a_eo[..., 0, 3] = b11
    a_eo[..., 0, 4] = b12
    a_eo[..., 0, 5] = b13
    a_eo[..., 1, 3] = b21
    a_eo[..., 1, 4] = b22
    a_eo[..., 1, 5] = b23
    a_eo[..., 0, :3] = -bx
    a_eo[..., 1, :3] = -by
    a_pt = np.empty(a_eo.shape[:-1] + (3,))
    a_pt[..., 0, :] = bx
    a_pt[..., 1, :] = by
    return a_eo, a_pt
