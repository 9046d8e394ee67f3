"""Two-step orientation versus the bundle adjustment (:func:`compare_two_step`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Optional

import numpy as np

from vectoradjust.accuracy.derived.covariance import cross_covariance
from vectoradjust.accuracy.derived.equal_error import _pair_indices, _stats
from vectoradjust.adjust.orientation import two_step
from vectoradjust.errors import ControlError

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun

__all__ = ["compare_two_step"]


# -------------------------------------------------------------------- two-step vs bundle
def compare_two_step(run: AdjustmentRun, image_pair: Optional[Sequence[str]] = None,
                     method: str = "collinearity") -> dict:
    """Two-step orientation of a stereo pair compared with the bundle adjustment.

    The points measured on both images of the pair (default: the first two images)
    are oriented with :func:`vectoradjust.adjust.orientation.two_step` (relative orientation,
    then a 7-parameter similarity to the run's control points measured on both images,
    with their prior covariances), from the same refined photo coordinates and sigmas
    the bundle used. The two-step sigmas are a-priori (variance factor 1); the bundle's
    are compared on the same footing (its a-posteriori covariance divided by
    ``s0^2``). Both two-step covariances are reported: the rigorous one and the
    textbook ``F1 Sigma_aa F1' + F2 Sigma_mm F2'``, which counts the control points'
    model coordinates twice (they enter the transformation parameters and are
    transformed again) and so overstates their sigma.

    Parameters
    ----------
    run : AdjustmentRun
    image_pair : (str, str), optional
    method : {"collinearity", "coplanarity"}
        Relative orientation formulation.

    Returns
    -------
    dict
        ``images``, counts (``n_points``, ...), ``relative_s0``, ``absolute_s0``,
        ``bundle_sigma0_squared``,
        ``difference`` (two-step minus bundle, shape points: ``xy`` and ``z``
        statistics of the absolute differences, m), ``sigma_ratio`` (two-step /
        bundle, per axis, for ``rigorous`` and ``classical``, shape points),
        ``tie_sigma_ratio`` and ``control_sigma_ratio`` (the same for tie and control
        points), ``classical_over_rigorous`` and ``points`` (per point rows). Shape
        points carry their coordinate priors in the bundle but not in the two-step
        orientation; tie points are the like-for-like comparison (when the run has
        only the two images: otherwise the bundle also used the others).
    """
    res = run.result
    ia, ib = _pair_indices(run, image_pair)
    obs_a, obs_b, pts = _common_points(res.problem, ia, ib)
    kind = run.point_kind[pts]
    ctrl = pts[kind == "control"]
    if ctrl.size < 3:
        raise ControlError(
            f"Only {ctrl.size} control point(s) are measured on both images "
            f"{run.image_ids[ia]!r} and {run.image_ids[ib]!r}; the two-step orientation needs 3",
            "Measure at least 3 control points on both images of the pair",
        )
    ts = _orient_two_step(run, obs_a[pts], obs_b[pts], pts, ctrl, method)
    return _comparison(run, (ia, ib), method, ts, pts, _sigmas(res, ts, pts))


def _common_points(prob, ia: int, ib: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first observation of every point on image ``ia`` and on ``ib`` (-1: none), and
    the points observed on both."""
    npnt = prob.n_points
    obs_a = np.full(npnt, -1, np.int64)
    obs_b = np.full(npnt, -1, np.int64)
    ka = np.flatnonzero(prob.obs_image == ia)
    kb = np.flatnonzero(prob.obs_image == ib)
    obs_a[prob.obs_point[ka[::-1]]] = ka[::-1]
    obs_b[prob.obs_point[kb[::-1]]] = kb[::-1]
    return obs_a, obs_b, np.flatnonzero((obs_a >= 0) & (obs_b >= 0))


def _orient_two_step(run: AdjustmentRun, ka: np.ndarray, kb: np.ndarray, pts: np.ndarray,
                     ctrl: np.ndarray, method: str):
    """:func:`two_step` of the points ``pts`` (observations ``ka`` on the left, ``kb`` on
    the right image) to the control points ``ctrl`` with their prior covariances."""
    prob = run.result.problem
    pp = np.asarray(prob.principal_point, float)
    left = prob.obs_xy[ka] - pp
    right = prob.obs_xy[kb] - pp
    isig = np.column_stack([prob.obs_sigma[ka], prob.obs_sigma[kb]])
    ccov = np.linalg.inv(prob.prior_weight[ctrl])
    return two_step(left, right, run.point_ids[pts], prob.focal_length, run.point_ids[ctrl],
                    prob.prior_xyz[ctrl], ccov, isig, method=method)


def _sigmas(res, ts, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sigmas (n, 3) of the points: two-step rigorous and classical, and the bundle's
    a-posteriori ones divided by ``s0`` (the same footing as the a-priori two-step)."""
    bundle_cov = (res.point_cov[pts] if res.point_cov is not None
                  else cross_covariance(res, pts, pts)) / res.variance_factor
    b_sig = np.sqrt(np.einsum("mii->mi", bundle_cov))
    n = len(pts)
    rig = np.sqrt(np.clip(np.diag(ts.cov), 0, None)).reshape(n, 3)
    cla = np.sqrt(np.clip(np.diag(ts.cov_classical), 0, None)).reshape(n, 3)
    return rig, cla, b_sig


def _comparison(run: AdjustmentRun, pair: tuple[int, int], method: str, ts, pts: np.ndarray,
                sigmas: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict:
    """The dict of :func:`compare_two_step` from the two-step result ``ts`` of the points
    ``pts`` and their :func:`_sigmas`."""
    res = run.result
    rig, cla, b_sig = sigmas
    kind = run.point_kind[pts]
    ids = run.point_ids[pts]
    n = len(pts)
    diff = ts.ground_xyz - res.xyz[pts]
    shape = kind == "shape"
    con = kind == "control"
    tie = kind == "tie"
    dxy = np.hypot(diff[:, 0], diff[:, 1])
    dz = np.abs(diff[:, 2])

    def ratios(s, m):
        return {ax: _stats(s[m, i] / b_sig[m, i]) for i, ax in enumerate("xyz")}

    return {
        "images": [run.image_ids[pair[0]], run.image_ids[pair[1]]],
        "method": method,
        "n_points": int(n), "control_points": int(con.sum()), "shape_points": int(shape.sum()),
        "tie_points": int(tie.sum()),
        "relative_s0": float(ts.relative.s0), "absolute_s0": float(ts.absolute.s0),
        "bundle_sigma0_squared": float(res.sigma0_squared),
        "difference": {
            "xy": _stats(dxy[shape]), "z": _stats(dz[shape]),
            "rmse_xy": float(np.sqrt(np.mean(dxy[shape] ** 2))) if shape.any() else None,
            "rmse_z": float(np.sqrt(np.mean(dz[shape] ** 2))) if shape.any() else None,
            "tie_xy": _stats(dxy[tie]), "tie_z": _stats(dz[tie]),
            "control_xy": _stats(dxy[con]), "control_z": _stats(dz[con]),
        },
        "sigma_ratio": {"rigorous": ratios(rig, shape), "classical": ratios(cla, shape)},
        "tie_sigma_ratio": {"rigorous": ratios(rig, tie), "classical": ratios(cla, tie)},
        "control_sigma_ratio": {"rigorous": ratios(rig, con), "classical": ratios(cla, con)},
        "classical_over_rigorous": {
            "shape": {ax: _stats(cla[shape, i] / rig[shape, i]) for i, ax in enumerate("xyz")},
            "tie": {ax: _stats(cla[tie, i] / rig[tie, i]) for i, ax in enumerate("xyz")},
            "control": {ax: _stats(cla[con, i] / rig[con, i]) for i, ax in enumerate("xyz")},
        },
        "points": [
            {"point_id": str(ids[i]), "kind": str(kind[i]),
             "two_step": ts.ground_xyz[i].tolist(), "bundle": res.xyz[pts[i]].tolist(),
             "sigma_two_step": rig[i].tolist(), "sigma_classical": cla[i].tolist(),
             "sigma_bundle": b_sig[i].tolist()}
            for i in range(n)
        ],
    }
