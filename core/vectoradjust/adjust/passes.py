"""The adjustment stage: one or more bundle adjustments of a run's problem.

:func:`solve` runs the bundle adjustment as the project's ``[adjustment]`` asks:
once (``reweight = "none"``), twice with each database's prior sigma set to the RMS of
its residuals (``"two-pass"``, DESIGN section 1 step 6), or with variance component
estimation (``"vce"``, DESIGN section 3), followed by data snooping where
``snooping = true``. Numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from vectoradjust.adjust import offsets as off
from vectoradjust.adjust.bundle import BundleProblem, BundleResult, adjust
from vectoradjust.adjust.classify import BundleSetup
from vectoradjust.formatting import float_or_none

__all__ = ["Solution", "solve"]

Progress = Callable[[float, str], None]

#: measured points a database needs for its offset kind (fewer: no offset estimated)
_MIN_OFFSET_POINTS = {"none": 0, "shift": 1, "shift3d": 1, "similarity": 3, "affine": 4}

#: variance components of the well-known groups may move at most this factor from the
#: stated sigma; beyond it they are held and a finding is reported (issue: a biased
#: database must not make the control look 50 times worse than surveyed)
VCE_BOUNDS = {"image": 3.0, "control": 3.0}


@dataclass
class Solution:
    """The final adjustment of a run and how it was reached.

    Attributes
    ----------
    problem : BundleProblem
        The problem of the last pass (after reweighting and snooping).
    result : BundleResult
    passes : list of dict
        One record per pass (sigma0^2, iterations, databases' prior sigmas).
    vce : dict or None
        Variance components (``reweight = "vce"``).
    snooping : dict or None
        Data snooping record (``snooping = true``).
    offsets : dict or None
        Per database with an offset: ``{"axes", "values", "cofactor"}`` (m, cofactor of
        the final solution, to be scaled by the variance factor).
    """

    problem: BundleProblem
    result: BundleResult
    passes: list = field(default_factory=list)
    vce: Optional[dict] = None
    snooping: Optional[dict] = None
    offsets: Optional[dict] = None


def _pass_record(label, result: BundleResult, iterations: int, dbs: list) -> dict:
    return {"pass": label, "sigma0_squared": float_or_none(result.sigma0_squared),
            "iterations": iterations, "sigma": {d.name: list(d.sigma_used) for d in dbs}}


def _reweight_two_pass(setup: BundleSetup, result: BundleResult) -> None:
    """Each database's sigma per axis <- sqrt(sum v^2 / sum r) of its residuals (in place).

    ``r`` are the redundancy numbers of the shape point priors along that axis: the
    residuals of a prior that shares its redundancy with the images are smaller than the
    prior's error, so the plain RMS (``sum v^2 / n``) would underestimate its sigma;
    ``sum v^2 / sum r`` is the Foerstner estimate (one step of variance component
    estimation), the same as the RMS when the priors are light (``r ~ 1``).
    """
    from vectoradjust.adjust.reliability import reliability

    r_point = reliability(result).r_point
    weight = setup.problem.prior_weight.copy()
    for d in setup.databases:
        m = setup.point_database == d.name
        v = result.v_point[m]
        red = r_point[m].sum(axis=0) if len(v) else np.zeros(3)
        if len(v) and np.all(red > 0.5):
            new = np.sqrt(np.sum(v**2, axis=0) / red)
        else:
            new = np.sqrt(np.mean(v**2, axis=0)) if len(v) else np.asarray(d.sigma_used)
        new = np.maximum(new, 1e-3)
        d.sigma_used = tuple(float(s) for s in new)
        idx = np.flatnonzero(m)
        weight[idx[:, None], [0, 1, 2], [0, 1, 2]] = 1.0 / new**2
    p = setup.problem
    setup.problem = BundleProblem(p.focal_length, p.principal_point, p.eo0, p.eo_sigma, p.xyz0,
                                  p.prior_xyz, weight, p.obs_point, p.obs_image, p.obs_xy,
                                  p.obs_sigma)


def _vce(problem, point_kind, point_db, db_results, adjust_kwargs, warnings):
    """Variance component estimation: image coordinates, GCPs, each database h / v."""
    from vectoradjust.adjust.vce import variance_components

    m = problem.n_points
    labels = np.full((m, 3), "", dtype=object)
    labels[point_kind == "control"] = "control"
    for d in db_results:
        sel = (point_kind == "shape") & (point_db == d.name)
        labels[sel, :2] = f"{d.name}:h"
        labels[sel, 2] = f"{d.name}:v"
    v = variance_components(problem, "image", labels.astype(str), adjust_kwargs=adjust_kwargs,
                            bounds=VCE_BOUNDS)
    for note in v.notes:
        warnings.append(f"variance components: {note}")
    if not v.converged:
        warnings.append("variance component estimation did not converge; the last estimates are "
                        "used")
    for d in db_results:
        h = v.sigma.get(f"{d.name}:h")
        z = v.sigma.get(f"{d.name}:v")
        d.sigma_used = (float(h if h is not None else d.sigma_used[0]),
                        float(h if h is not None else d.sigma_used[1]),
                        float(z if z is not None else d.sigma_used[2]))
    info = {
        "iterations": int(v.iterations), "converged": bool(v.converged),
        "groups": {g: {"sigma": float_or_none(v.sigma.get(g)),
                       "sigma_initial": float_or_none(v.sigma_initial.get(g)),
                       "redundancy": float_or_none(v.redundancy.get(g)),
                       "count": int(v.count.get(g, 0)),
                       "estimable": bool(v.estimable.get(g, False)),
                       "unit": "mm" if g == "image" else "m"}
                   for g in v.groups},
        "notes": list(v.notes),
        "findings": [{k: f[k] for k in ("group", "estimated_ratio", "bound", "text")}
                     for f in v.findings],
        "bounds": dict(VCE_BOUNDS),
    }
    return v.problem, v.result, info


def _snooping_record(sn, point_ids, image_ids, meas, obs_rows) -> dict:
    removed = []
    for rec in sn.removed:
        r = dict(rec)
        k = r.get("observation")
        if k is not None:
            r["line"] = int(meas.rows[obs_rows[int(k)]])
        r["point"] = str(point_ids[int(r["point"])])
        r["image"] = str(image_ids[int(r["image"])])
        r["dropped_points"] = [str(point_ids[int(j)]) for j in r.get("dropped_points", [])]
        removed.append({key: (val.tolist() if isinstance(val, np.ndarray) else val)
                        for key, val in r.items()})
    return {"removed": removed, "clean": bool(sn.clean), "iterations": int(sn.iterations)}


def _snoop(setup: BundleSetup, settings, adjust_kwargs, image_ids, meas, warnings):
    """Data snooping; drops the removed observations (and points) from ``setup``."""
    from vectoradjust.adjust.reliability import data_snooping

    sn = data_snooping(setup.problem, alpha0=settings.alpha0, beta0=settings.beta0,
                       max_removals=settings.max_removals, adjust_kwargs=adjust_kwargs)
    info = _snooping_record(sn, setup.point_ids, image_ids, meas, setup.obs_rows)
    kept = np.asarray(sn.point_index, np.int64)
    remap = np.full(len(setup.point_ids), -1, np.int64)
    remap[kept] = np.arange(len(kept))
    setup.point_ids, setup.point_kind, setup.point_database = (
        a[kept] for a in (setup.point_ids, setup.point_kind, setup.point_database))
    if setup.db_prior is not None:
        setup.db_prior = setup.db_prior[kept]
    for d in setup.databases:
        d.vertex_point = np.where(d.vertex_point >= 0, remap[np.maximum(d.vertex_point, 0)], -1)
    setup.obs_rows = setup.obs_rows[np.asarray(sn.observation_index, np.int64)]
    setup.problem = sn.problem
    for rec in info["removed"]:
        warnings.append(f"data snooping removed the measurement of point {rec['point']!r} on "
                        f"image {rec['image']!r} (w = {rec['w']:.2f})")
    return sn.result, info


# --------------------------------------------------------------------------- offsets
def _offset_model(setup: BundleSetup) -> Optional[off.OffsetModel]:
    """The databases whose systematic offset is estimated (None: none is)."""
    names, kinds, points = [], [], []
    for d in setup.databases:
        kind = getattr(d.spec, "offset", "none") or "none"
        pts = np.flatnonzero((setup.point_kind == "shape") & (setup.point_database == d.name))
        if off.OFFSET_KINDS[kind] and len(pts) >= _MIN_OFFSET_POINTS[kind]:
            names.append(d.name)
            kinds.append(kind)
            points.append(pts)
    if not names:
        return None
    return off.OffsetModel.build(names, kinds, points, setup.db_prior)


def _adjust(setup: BundleSetup, model, adjust_kwargs: dict, progress, state: dict):
    """One adjustment; with offsets, Newton steps on them until they settle.

    ``state["values"]`` carries the offsets between calls (two-pass, VCE); the final
    cofactor and the covariance update are applied to the returned result.
    """
    if model is None:
        return adjust(setup.problem, progress=progress, **adjust_kwargs)
    values = state.get("values", np.zeros(model.n_params))
    # the offsets converge to far below the position tolerance: the Newton step is exact
    # for the linearised problem, so this costs one or two more warm-started adjustments
    tol = min(adjust_kwargs.get("tolerance_position", 1e-4), 1e-6)
    history = state.setdefault("history", [])
    setup.problem = off.shifted_problem(setup.problem, setup.db_prior, model, values)
    result = adjust(setup.problem, progress=progress, **adjust_kwargs)
    # warm-started re-adjustments converge far below the usual tolerance, so that the
    # solution does not depend on where the iteration happened to stop
    tight = dict(adjust_kwargs)
    tight["tolerance_position"] = adjust_kwargs.get("tolerance_position", 1e-4) * 1e-3
    tight["tolerance_angle"] = adjust_kwargs.get("tolerance_angle", 1e-8) * 1e-3
    for _ in range(20):
        new, cof, gmax, qb, s_ztb = off.newton_step(result, model, values)
        step = float(np.abs(model.displacement(new - values)).max(initial=0.0))  # m
        history.append({"step": step, "gradient": gmax, "values": new.tolist()})
        if step < tol:
            break
        values = new
        setup.problem = off.shifted_problem(setup.problem, setup.db_prior, model, values,
                                            xyz0=result.xyz, eo_start=result.eo)
        result = adjust(setup.problem, progress=progress, **tight)
    state["values"] = values
    state["cofactor"] = cof
    state["converged"] = step < tol
    off.apply_offsets(result, model, off.OffsetEstimate(values, cof), qb, s_ztb)
    return result


def _offset_record(model, state: dict, result: BundleResult) -> dict:
    """Per database: offset values, sigmas (a posteriori) and the cofactor block."""
    vf = result.variance_factor
    rec = {}
    for name, kind, center, cols in zip(model.names, model.kinds, model.centers,
                                        model.columns()):
        cof = state["cofactor"][np.ix_(cols, cols)]
        rec[name] = {"axes": list(off.OFFSET_KINDS[kind]), "kind": kind,
                     "center": [float(c) for c in center],
                     "values": [float(state["values"][c]) for c in cols],
                     "sigma": np.sqrt(np.maximum(np.diag(cof) * vf, 0.0)).tolist(),
                     "cofactor": cof.tolist(), "variance_factor": vf,
                     "converged": bool(state.get("converged", True)),
                     "newton_steps": len(state.get("history", []))}
    return rec


def solve(setup: BundleSetup, settings, *, image_ids: np.ndarray, meas, warnings: list,
          progress: Progress, is_cancelled: Optional[Callable[[], bool]] = None) -> Solution:
    """Adjust ``setup.problem`` as ``settings`` asks (passes, VCE, snooping).

    Parameters
    ----------
    setup : BundleSetup
        Updated in place: the final problem, and after snooping the kept points and
        observations; each database's ``sigma_used``.
    settings : Settings
        The project's ``[adjustment]``.
    image_ids : numpy.ndarray of str
        Ids of the adjusted images (for the snooping record).
    meas : Measurements
        For the CSV lines of removed observations.
    warnings : list of str
        Appended to.
    progress : callable
        ``progress(fraction, message)`` for the whole run.
    is_cancelled : callable, optional
        Polled between iterations.

    Returns
    -------
    Solution
    """
    adjust_kwargs = {"max_iterations": settings.max_iterations,
                     "tolerance_position": settings.tolerance_position,
                     "tolerance_angle": settings.tolerance_angle,
                     "is_cancelled": is_cancelled}
    dbs = setup.databases
    model = _offset_model(setup)
    state: dict = {}
    n_pass = 2 if settings.reweight == "two-pass" and dbs else 1
    sol: Optional[Solution] = None
    for p in range(n_pass):
        progress(0.1 + 0.6 * p / n_pass, f"adjustment pass {p + 1} of {n_pass}")

        def sub(frac, msg, p=p):
            progress(0.1 + 0.6 * (p + frac) / n_pass, msg)

        result = _adjust(setup, model, adjust_kwargs, sub, state)
        record = _pass_record(p + 1, result, result.iterations, dbs)
        if sol is None:
            sol = Solution(setup.problem, result, [record])
        else:
            sol.problem, sol.result = setup.problem, result
            sol.passes.append(record)
        if p + 1 < n_pass:
            _reweight_two_pass(setup, result)
    assert sol is not None
    if settings.reweight == "vce":
        progress(0.55, "variance component estimation")
        setup.problem, sol.result, sol.vce = _vce(setup.problem, setup.point_kind,
                                                  setup.point_database, dbs, adjust_kwargs,
                                                  warnings)
        sol.passes.append(_pass_record("vce", sol.result, sol.vce["iterations"], dbs))
        if model is not None:  # the offsets again, with the estimated weights
            sol.result = _adjust(setup, model, adjust_kwargs, lambda f, m: None, state)
    if settings.snooping:
        progress(0.65, "data snooping")
        sol.result, sol.snooping = _snoop(setup, settings, adjust_kwargs, image_ids, meas,
                                          warnings)
    sol.result.set_covariance_scale(settings.covariance_scale)
    if model is not None:
        sol.offsets = _offset_record(model, state, sol.result)
    sol.problem = setup.problem
    return sol
