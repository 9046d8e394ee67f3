"""The two-step orientation: relative, then absolute by a 3D conformal transformation, with
error propagation (:class:`TwoStep`, :func:`two_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.adjust.orientation.common import _cov3, _right_apply, _sandwich
from vectoradjust.adjust.orientation.conformal import Conformal3D, conformal3d
from vectoradjust.adjust.orientation.relative import RelativeOrientation, relative_orientation
from vectoradjust.errors import (
    ControlError,
    MeasurementError,
)

__all__ = ["TwoStep", "two_step"]


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
    ids, cidx, cxyz = _control_index(ids, control_ids, control_xyz)
    k = len(cidx)
    ro = relative_orientation(left_xy, right_xy, f, bx=bx, sigma=image_sigma, method=method,
                              a_posteriori=False)
    sel = (3 * cidx[:, None] + np.arange(3)).ravel()
    c_mm = ro.cov_model
    c_gg = _cov3(control_sigma, k, "Two-step orientation (control)")
    ao = conformal3d(ro.model_xyz[cidx], cxyz, cov_model=c_mm[np.ix_(sel, sel)],
                     cov_ground=c_gg, method="gauss-helmert", a_posteriori=False)
    ground, cov_classical = ao.transform(ro.model_xyz, c_mm, full=True)
    cov = _rigorous_cov(ro.model_xyz, c_mm, c_gg, ao, sel)
    return TwoStep(
        ids=ids,
        ground_xyz=ground,
        cov=0.5 * (cov + cov.T),
        cov_classical=0.5 * (cov_classical + cov_classical.T),
        relative=ro,
        absolute=ao,
        control_index=cidx,
    )


def _control_index(ids, control_ids, control_xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check the ids and the control; return ``ids``, the control rows and their XYZ.

    Raises :class:`MeasurementError` for duplicate ids and :class:`ControlError` for
    unknown control ids, fewer than 3 control points or coordinates of the wrong shape.
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
    return ids, cidx, cxyz


def _rigorous_cov(model_xyz: np.ndarray, c_mm: np.ndarray, c_gg: np.ndarray, ao: Conformal3D,
                  sel: np.ndarray) -> np.ndarray:
    """Covariance ``(3n, 3n)`` of the ground points, the absolute orientation's
    parameters being functions of the model and ground control coordinates.

    ``d ground = (I kron sR + F1 K_m S) d model + F1 K_g d control`` with ``F1`` the
    Jacobian of the transformed points by the 7 parameters, ``K_m, K_g`` the
    parameters' sensitivities to the model and ground control, ``S`` the selection of
    the control rows ``sel``.
    """
    k3 = len(sel)
    f1 = ao.jacobian_params(model_xyz)  # (3n, 7)
    k_m = ao.sensitivity[:, :k3]
    k_g = ao.sensitivity[:, k3:]
    sr = ao.scale * ao.rotation
    km_sig = k_m @ c_mm[sel, :]  # K_m S Sigma_mm  (7, 3n)
    cross = f1 @ _right_apply(km_sig, sr)  # F1 K_m S Sigma (I kron sR)'
    inner = km_sig[:, sel] @ k_m.T + k_g @ c_gg @ k_g.T
    return _sandwich(sr, c_mm) + cross + cross.T + f1 @ inner @ f1.T

