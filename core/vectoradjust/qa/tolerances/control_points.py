"""QA of control and check points: :class:`ControlPointQA` and :func:`control_point_qa`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vectoradjust.errors import ControlError
from vectoradjust.qa.tolerances.limits import BlockTolerances, block_tolerances
from vectoradjust.qa.tolerances.product import QASpec
from vectoradjust.qa.tolerances.stages import check_stage

__all__ = ["ControlPointQA", "control_point_qa"]


_CONTROL_ROLES = {"control": "control", "gcp": "control", "check": "check"}


@dataclass
class ControlPointQA:
    """Per-point QA of control and check points and the four block stages.

    Attributes
    ----------
    ids : list
    roles : list of str
        ``"control"`` or ``"check"``.
    e_xy, e_z : numpy.ndarray
        Horizontal residual length and ``|vertical residual|`` (m).
    tol_xy, tol_z : numpy.ndarray
        The limit applied to each point (m; NaN where not checked).
    passed : numpy.ndarray of bool
        Per point: within both limits (the ``QA`` field of the output layer).
    stages : list of StageResult
        ``block: GCP XY``, ``block: GCP Z``, ``block: check XY``, ``block: check Z``
        (those with points and a tolerance).
    tolerances : BlockTolerances
    """

    ids: list
    roles: list
    e_xy: np.ndarray
    e_z: np.ndarray
    tol_xy: np.ndarray
    tol_z: np.ndarray
    passed: np.ndarray
    stages: list
    tolerances: BlockTolerances

    @property
    def qa_field(self) -> list:
        """``"pass"`` / ``"fail"`` per point, for the control_points layer."""
        return ["pass" if p else "fail" for p in self.passed.tolist()]

    @property
    def failed_ids(self) -> list:
        """Ids of the points that fail (to re-measure)."""
        return [i for i, p in zip(self.ids, self.passed.tolist()) if not p]


def control_point_qa(ids: Sequence, residuals, roles: Sequence[str], spec: QASpec,
                     focal_length_mm: float | None = None,
                     working_radius_mm: float | None = None,
                     point_rule: str = "limit") -> ControlPointQA:
    """Judge every control and check point against its tolerance.

    Parameters
    ----------
    ids : sequence
        Point ids, length ``n``.
    residuals : array_like, shape (n, 3)
        ``adjusted - surveyed`` (control points) or ``intersected - surveyed`` (check
        points), metres. XY uses the horizontal length, Z the absolute value.
    roles : sequence of str
        ``"control"`` (or ``"gcp"``) / ``"check"`` per point.
    spec : QASpec
    focal_length_mm, working_radius_mm : float, optional
        For orthophoto / orthomosaic height tolerances (:func:`block_tolerances`).
    point_rule : {"limit", "mean"}
        ``"limit"`` (default): a point fails over the limiting error, twice the mean
        tolerance (``E_max ~ 2 E_mean``); ``"mean"``: over the mean tolerance itself.

    Returns
    -------
    ControlPointQA

    Raises
    ------
    ControlError
        A role other than control / check (the point is named).
    """
    if point_rule not in ("limit", "mean"):
        raise ValueError(f"point_rule must be 'limit' or 'mean', got {point_rule!r}")
    ids = list(ids)
    res = np.asarray(residuals, float).reshape(-1, 3)
    if len(ids) != res.shape[0] or len(roles) != res.shape[0]:
        raise ValueError(f"{len(ids)} ids, {len(roles)} roles for {res.shape[0]} residuals")
    canon = []
    for pid, role in zip(ids, roles):
        key = str(role).strip().lower()
        if key not in _CONTROL_ROLES:
            raise ControlError(
                f"control point {pid!r} has role {role!r}",
                "set role to 'control' or 'check'",
                details={"point_id": pid, "role": role},
            )
        canon.append(_CONTROL_ROLES[key])
    tol = block_tolerances(spec, focal_length_mm, working_radius_mm)
    is_check = np.array([r == "check" for r in canon], bool)
    e_xy = np.hypot(res[:, 0], res[:, 1])
    e_z = np.abs(res[:, 2])
    scale = 2.0 if point_rule == "limit" else 1.0

    def limit(t):  # no tolerance (None), or none derivable (NaN: no focal length, RPCs)
        return np.nan if t is None or not np.isfinite(t) else scale * t

    tol_xy = np.where(is_check, limit(tol.check_xy), limit(tol.gcp_xy))
    tol_z = np.where(is_check, limit(tol.check_z), limit(tol.gcp_z))
    with np.errstate(invalid="ignore"):
        ok_xy = np.where(np.isnan(tol_xy), True, e_xy <= tol_xy)
        ok_z = np.where(np.isnan(tol_z), True, e_z <= tol_z)
    passed = ok_xy & ok_z

    stages = []
    for label, mask, txy, tz in (("GCP", ~is_check, tol.gcp_xy, tol.gcp_z),
                                 ("check", is_check, tol.check_xy, tol.check_z)):
        if not mask.any():
            continue
        sel_ids = [i for i, m in zip(ids, mask.tolist()) if m]
        for comp, vals, t in (("XY", e_xy[mask], txy), ("Z", e_z[mask], tz)):
            if t is None or not np.isfinite(t):
                continue
            stages.append(check_stage(f"block: {label} {comp}", vals, sel_ids, t, "mean",
                                      point_tolerance=scale * t, unit="m"))
    return ControlPointQA(ids=ids, roles=canon, e_xy=e_xy, e_z=e_z, tol_xy=tol_xy,
                          tol_z=tol_z, passed=passed, stages=stages, tolerances=tol)

