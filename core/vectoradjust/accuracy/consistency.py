"""Do the road databases and the control agree? (issue: adding roads must do no harm)

The same adjustment is repeated with control and tie points only (no shape points). If
the databases only add information, the exterior orientation moves between the two
solutions by no more than the difference of their covariances allows (Hausman's test
for nested least-squares estimates: ``d = e_roads - e_control``,
``Cov(d) = Q_control - Q_roads``, ``d' Cov(d)^+ d ~ chi^2(rank)`` with a-priori
cofactors); check points are intersected from both. A significant test, or check
points worse with the roads, means the databases pull the images away from the control
(a biased database without an estimated offset, a wrong prior sigma): a finding that is
reported, never silent. Numpy and scipy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.special import gammaincinv, ndtri  # not scipy.stats: 0.5 s to import

from vectoradjust.adjust.bundle import adjust, intersect
from vectoradjust.adjust.reliability import subset_problem
from vectoradjust.results import AdjustmentRun

__all__ = ["roads_versus_control", "HARM_RATIO"]

#: check points with the roads may be at most this much worse before it is a finding
HARM_RATIO = 1.05


def _check_errors(out: AdjustmentRun, eo: np.ndarray, check_obs) -> Optional[np.ndarray]:
    """Horizontal errors (k, 2) of the check points intersected from ``eo`` (None: none)."""
    if check_obs is None:
        return None
    rows, ctrl_idx, img_idx = check_obs
    cids, cinv = np.unique(ctrl_idx, return_inverse=True)
    cinv = np.asarray(cinv).reshape(-1)
    cnt = np.bincount(cinv, minlength=len(cids))
    meas, cam = out.data.measurements, out.data.camera
    xyz, _ = intersect(eo, cinv, img_idx, meas.xy[rows], meas.sigma[rows], len(cids),
                       cam.focal_length, cam.principal_point,
                       sensors=out.result.problem.sensors if out.result.problem else None)
    ok = cnt >= 2
    if not ok.any():
        return None
    return xyz[ok, :2] - out.data.control.xyz[cids[ok], :2]


def _rmse(e: Optional[np.ndarray]) -> Optional[float]:
    return None if e is None else float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def _check_change_z(out: AdjustmentRun, eo0: np.ndarray, e0, e1, cov_d: np.ndarray,
                    check_obs) -> Optional[float]:
    """How many standard deviations the check points' mean squared error grew by.

    With ``e1 = e0 + J d`` (``J``: the check points' horizontal position with respect to
    the exterior orientation, by central differences) and ``d ~ N(0, Cov(d))`` when the
    roads only add information, ``MSE1 - MSE0`` has mean ``tr(J C J') / k`` and standard
    deviation ``2 sqrt(e0' J C J' e0) / k`` to first order.
    """
    if e0 is None or e1 is None or len(e0) != len(e1):
        return None
    steps = np.where(np.arange(eo0.size) % 6 < 3, 1e-3, 1e-7)
    cols = []
    for k, h in enumerate(steps):
        up, dn = eo0.ravel().copy(), eo0.ravel().copy()
        up[k] += h
        dn[k] -= h
        cols.append(((_check_errors(out, up.reshape(eo0.shape), check_obs)
                      - _check_errors(out, dn.reshape(eo0.shape), check_obs)) / (2 * h)).ravel())
    jac = np.column_stack(cols)
    c = jac @ cov_d @ jac.T
    n = len(e0)
    sd = 2.0 * float(np.sqrt(max(e0.ravel() @ c @ e0.ravel(), 0.0))) / n
    mean = float(np.trace(c)) / n
    diff = float(np.mean(np.sum(e1 * e1, axis=1)) - np.mean(np.sum(e0 * e0, axis=1)))
    return (diff - mean) / sd if sd > 0 else None


def roads_versus_control(out: AdjustmentRun, check_obs=None, alpha: float = 0.05,
                         adjust_kwargs: Optional[dict] = None) -> Optional[dict]:
    """Compare the adjustment with its control-and-tie-points-only twin.

    Parameters
    ----------
    out : AdjustmentRun
        A finished run with shape points.
    check_obs : tuple of numpy.ndarray, optional
        ``(measurement rows, control-file rows, adjusted-image index)`` of the check
        point measurements, for the check point comparison.
    alpha : float
        Level of the test.
    adjust_kwargs : dict, optional
        Passed to the bundle adjustment.

    Returns
    -------
    dict or None
        ``eo_test`` (statistic, critical, degrees of freedom, passed),
        ``check_rmse_with_roads``/``without_roads`` and their ratio, ``check_change_z``
        (when the ratio exceeds :data:`HARM_RATIO`: how many standard deviations the
        check points' mean squared error grew by beyond what the exterior orientation's
        change explains), ``check_worse``, ``harm`` (bool) and ``text``; None without
        shape points.
    """
    prob, res = out.problem, out.result
    keep = out.point_kind != "shape"
    if keep.all():
        return None
    sub, _, _ = subset_problem(prob, np.ones(len(prob.obs_point), bool), keep)
    kw = dict(adjust_kwargs or {})
    kw.pop("is_cancelled", None)
    res0 = adjust(sub, compute_covariance=False, **kw)
    d = (res.eo - res0.eo).ravel()
    q = res0.s_inv - res.eo_cofactor()
    w, v = np.linalg.eigh(0.5 * (q + q.T))
    # directions the roads do not inform have eigenvalues ~1e-7 of the largest and only
    # convergence noise in d; they are left out of the test
    use = w > 1e-4 * max(float(w.max(initial=0.0)), 1e-300)
    stat = float(np.sum((v[:, use].T @ d) ** 2 / w[use]))
    dof = int(use.sum())
    crit = float(2.0 * gammaincinv(0.5 * dof, 1.0 - alpha)) if dof else float("nan")
    e1, e0 = _check_errors(out, res.eo, check_obs), _check_errors(out, res0.eo, check_obs)
    with_roads, without = _rmse(e1), _rmse(e0)
    ratio = with_roads / without if with_roads is not None and without else None
    passed = bool(stat <= crit) if dof else True
    z = None
    if ratio is not None and ratio > HARM_RATIO:
        cov_d = (v[:, use] * w[use]) @ v[:, use].T
        z = _check_change_z(out, res0.eo, e0, e1, cov_d, check_obs)
    # check points worse by more than 5 % AND more than the exterior orientation's change
    # explains by chance (one-sided, alpha): a few check points' RMSE is noisy
    worse = ratio is not None and ratio > HARM_RATIO and (z is None or z > ndtri(1 - alpha))
    harm = (not passed) or worse
    text = (f"roads and control {'agree' if not harm else 'DISAGREE'}: the exterior "
            f"orientation moved by chi2 = {stat:.1f} (critical {crit:.1f}, {dof} dof) when "
            "the road databases were added")
    if ratio is not None:
        text += (f"; check points {with_roads:.3f} m with the roads, {without:.3f} m "
                 f"without (ratio {ratio:.3f})")
    if z is not None and not worse:
        text += (f", more than {HARM_RATIO:g} but within what the change of the exterior "
                 f"orientation explains by chance (z = {z:.2f}: {len(e0)} check points)")
    if harm:
        text += (". The databases pull the images away from the control: estimate their "
                 "offsets (offset = \"shift\" in [[vectors]]), check their prior sigma, or "
                 "adjust without them")
    return {"eo_test": {"statistic": stat, "critical": crit, "degrees_of_freedom": dof,
                        "alpha": alpha, "passed": passed},
            "check_rmse_with_roads": with_roads, "check_rmse_without_roads": without,
            "check_ratio": ratio, "check_change_z": z, "check_worse": bool(worse),
            "harm": bool(harm), "text": text}
