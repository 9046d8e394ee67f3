"""The adjustment stage: one or more bundle adjustments of a run's problem.

:func:`solve` runs the bundle adjustment as the project's ``[adjustment]`` asks:
once (``reweight = "none"``), twice with each database's prior sigma set to the RMS of
its residuals (``"two-pass"``, docs/method.md section 1 step 6), or with variance component
estimation (``"vce"``, docs/method.md section 3), followed by data snooping where
``snooping = true``. Numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import numpy as np

from vectoradjust.adjust import datum
from vectoradjust.adjust import offsets as off
from vectoradjust.adjust.bundle import BundleProblem, BundleResult, adjust
from vectoradjust.adjust.classify import BundleSetup
from vectoradjust.formatting import float_or_none

__all__ = ["Solution", "solve", "datum_record", "free_network"]

Progress = Callable[[float, str], None]

#: measured points a database needs for its offset kind (fewer: no offset estimated)
_MIN_OFFSET_POINTS = {"none": 0, "shift": 1, "shift3d": 1, "height": 1, "similarity": 3,
                      "affine": 4}
#: heights from a DEM: its systematic height error is estimated too (issue 30: a biased
#: DEM must not pull the stereo model), the offset kind becomes this
_WITH_DEM_HEIGHT = {"shift": "shift3d"}

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
    kept_groups : list of str
        Groups kept at their stated sigma by two-pass or VCE (not estimable, held at a
        bound, or too imprecise); left out of the covariances' variance factor.
    """

    problem: BundleProblem
    result: BundleResult
    passes: list = field(default_factory=list)
    vce: Optional[dict] = None
    snooping: Optional[dict] = None
    offsets: Optional[dict] = None
    kept_groups: list = field(default_factory=list)
    #: what fixes the datum (:func:`datum_record`), for summary.json
    datum: Optional[dict] = None
    #: the self-calibrated interior parameters (values, sigmas, correlations)
    self_calibration: Optional[dict] = None


def _pass_record(label, result: BundleResult, iterations: int, dbs: list) -> dict:
    return {"pass": label, "sigma0_squared": float_or_none(result.sigma0_squared),
            "iterations": iterations, "sigma": {d.name: list(d.sigma_used) for d in dbs}}


#: a variance estimated less precisely than this (relative standard deviation of sigma^2)
#: is not applied: an LE90 that covers the truth 85-95 % of the time needs the sigma
#: within -12 % / +19 % (see adjust/vce.py)
MAX_RELATIVE_SD = 0.25


def _db_labels(setup: BundleSetup) -> np.ndarray:
    """Per point and axis: "control", "<db>:h" (X, Y), "<db>:v" (Z) or ""."""
    labels = np.full((setup.problem.n_points, 3), "", dtype=object)
    labels[setup.point_kind == "control"] = "control"
    for d in setup.databases:
        sel = (setup.point_kind == "shape") & (setup.point_database == d.name)
        labels[sel, :2] = f"{d.name}:h"
        labels[sel, 2] = f"{d.name}:v"
    return labels.astype(str)


def one_step_variance(v: np.ndarray, q: np.ndarray, sigma: np.ndarray):
    """Variance of point priors from one adjustment's residuals, per axis.

    A prior ``X_db`` with stated sigma ``s`` pulls the adjusted point by the share
    ``w = q / s^2`` (``q``: the adjusted point's cofactor), so ``v = (1 - w) (X_photo -
    X_db)`` and ``E[v^2] = (1 - w)^2 (q_photo + sigma^2)`` with ``q_photo = q / (1 - w)``:

        sigma^2 = mean(v^2 / (1 - w)^2 - q / (1 - w)),

    consistent whatever ``s`` was (the plain RMS of ``v`` includes the photogrammetric
    error ``q_photo``: for heights from a DEM that is better than the stereo heights it is
    mostly that). Relative standard deviation of the estimate: ``sqrt(2 / n) mean(v^2 /
    (1 - w)^2) / sigma^2``.

    Parameters
    ----------
    v, q, sigma : numpy.ndarray, shape (p, 3)
        Residuals (adjusted minus prior), cofactor diagonal (sigma0 = 1) and the stated
        prior sigma of ``p`` points.

    Returns
    -------
    variance, relative_sd : numpy.ndarray, shape (3,)
        ``relative_sd`` is ``inf`` where the estimate is not positive.
    """
    w = np.clip(q / sigma**2, 0.0, 0.99)
    a = v**2 / (1.0 - w) ** 2
    est = np.mean(a - q / (1.0 - w), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rsd = np.where(est > 0, np.sqrt(2.0 / len(v)) * np.mean(a, axis=0) / est, np.inf)
    return est, rsd


def _reweight_two_pass(setup: BundleSetup, result: BundleResult, warnings: list) -> list:
    """Each database's prior sigma per axis from pass 1's residuals (in place).

    :func:`one_step_variance` estimates the total prior variance (database and
    identification); the database's share is what remains after the stated
    identification variance. An axis whose estimate is too imprecise
    (:data:`MAX_RELATIVE_SD`) keeps its pass-1 sigma and a warning says so.

    Returns
    -------
    list of str
        Groups (``"<db>:h"``, ``"<db>:v"``) kept at their stated sigma.
    """
    q = (np.einsum("mii->mi", result.point_cov) / result.variance_factor
         if result.point_cov is not None else np.zeros(result.v_point.shape))
    if result.point_cov is not None and result.offset_cofactor is not None:
        # a point's own pull (q / s^2) excludes the offsets' share: an offset is common to
        # all the database's points, its uncertainty is not one prior pulling one point
        qb = result.offset_qb
        q = q - np.einsum("miq,qr,mir->mi", qb, result.offset_cofactor, qb)
    weight = setup.problem.prior_weight.copy()
    sig1 = 1.0 / np.sqrt(np.maximum(np.einsum("mii->mi", weight), 1e-300))
    kept = []
    for d in setup.databases:
        m = np.flatnonzero((setup.point_kind == "shape") & (setup.point_database == d.name))
        if not len(m):
            continue
        est, rsd = one_step_variance(result.v_point[m], q[m], sig1[m])
        old = np.sqrt(np.mean(sig1[m] ** 2, axis=0))
        ok = rsd <= MAX_RELATIVE_SD
        total = np.where(ok, np.sqrt(np.maximum(est, 1e-6)), old)
        for a, label in ((0, "h"), (1, "h"), (2, "v")):
            if not ok[a] and f"{d.name}:{label}" not in kept:
                kept.append(f"{d.name}:{label}")
                warnings.append(_kept_warning(d.name, a, est[a], rsd[a], old[a]))
        idv = d.spec.identification_variance
        d.sigma_used = tuple(float(x) for x in np.sqrt(np.maximum(total**2 - idv, 0.0)))
        weight[m[:, None], [0, 1, 2], [0, 1, 2]] = 1.0 / total**2
    p = setup.problem
    setup.problem = BundleProblem(p.focal_length, p.principal_point, p.eo0, p.eo_sigma, p.xyz0,
                                  p.prior_xyz, weight, p.obs_point, p.obs_image, p.obs_xy,
                                  p.obs_sigma, sensors=p.sensors, free_datum=p.free_datum)
    return kept


def _kept_warning(name: str, axis: int, est: float, rsd: float, old: float) -> str:
    what = "XYZ"[axis]
    if not est > 0:
        found = "its residuals are no larger than the photogrammetric error alone"
    else:
        found = (f"estimated {np.sqrt(est):.3g} m +- {100 * rsd:.0f} % in variance, "
                 f"more than the {100 * MAX_RELATIVE_SD:.0f} % a 90 % figure can bear")
    return (f"two-pass: {name} {what} prior sigma cannot be estimated from pass 1 ({found}); "
            f"the stated {old:.3g} m is used. State the accuracy you know in sigma (for "
            f"heights from a DEM: its vertical accuracy); a large stated sigma leaves {what} "
            "to the images")


def group_variance_factor(result: BundleResult, setup: BundleSetup, excluded=(),
                          pessimistic_priors: bool = False):
    """``sum v'Pv / sum r`` over the observation groups, some left out.

    The variance factor of the groups whose sigma is known or was estimated: a group kept
    at a stated sigma that the data could not check (e.g. a light prior on DEM heights)
    would otherwise pull the global sigma0^2 down and shrink every covariance.

    Parameters
    ----------
    result : BundleResult
    setup : BundleSetup
    excluded : iterable of str
        Groups left out (``"<db>:h"``, ``"<db>:v"``, ``"control"``, ``"image"``).
    pessimistic_priors : bool
        Also leave out every database group whose own factor is below 1 (its stated sigma
        is larger than its residuals say: the images, not the prior, fix those points).

    Returns
    -------
    factor : float
    left_out : list of str
        The groups left out that have observations.
    """
    from vectoradjust.adjust.reliability import reliability
    from vectoradjust.adjust.vce import group_statistics

    labels = _db_labels(setup)
    groups = sorted(set(labels.ravel().tolist()) - {""}) + ["image", "eo"]
    obs = np.full((len(result.problem.obs_point), 2), "image").astype(str)
    eo = np.full((result.problem.n_images, 6), "eo").astype(str)
    vtpv, red, cnt = group_statistics(result, reliability(result), obs, labels, eo, groups)
    out = set(excluded)
    if pessimistic_priors:
        out |= {g for g in groups if ":" in g and red[g] > 0 and vtpv[g] < red[g]}
    use = [g for g in groups if g not in out]
    r = sum(red[g] for g in use)
    factor = float(sum(vtpv[g] for g in use) / r) if r > 0 else 1.0
    return factor, [g for g in groups if g in out and cnt[g] > 0]


def _vce(setup: BundleSetup, adjust_kwargs, warnings):
    """Variance component estimation: image coordinates, GCPs, each database h / v.

    Returns the final problem and result, the record for summary.json and the groups kept
    at their stated sigma (not estimable, held at a bound, or too imprecise).
    """
    from vectoradjust.adjust.vce import variance_components

    db_results = setup.databases
    v = variance_components(setup.problem, "image", _db_labels(setup),
                            adjust_kwargs=adjust_kwargs, bounds=VCE_BOUNDS,
                            max_relative_sd=MAX_RELATIVE_SD, precise_only=lambda g: ":" in g)
    for note in v.notes:
        warnings.append(f"variance components: {note}")
    if not v.converged:
        warnings.append("variance component estimation did not converge; the last estimates are "
                        "used")
    for d in db_results:
        h = v.sigma.get(f"{d.name}:h")
        z = v.sigma.get(f"{d.name}:v")
        total = np.array([h if h is not None else np.nan] * 2 + [z if z is not None else np.nan])
        db = np.sqrt(np.maximum(total**2 - d.spec.identification_variance, 0.0))
        d.sigma_used = tuple(float(b) if np.isfinite(b) else float(o)
                             for b, o in zip(db, d.sigma_used))
    info = {
        "iterations": int(v.iterations), "converged": bool(v.converged),
        "groups": {g: {"sigma": float_or_none(v.sigma.get(g)),
                       "sigma_initial": float_or_none(v.sigma_initial.get(g)),
                       "redundancy": float_or_none(v.redundancy.get(g)),
                       "relative_sd": float_or_none(v.relative_sd.get(g)),
                       "count": int(v.count.get(g, 0)),
                       "estimable": bool(v.estimable.get(g, False)),
                       "not_applied": ({k: float(x) for k, x in v.imprecise[g].items()}
                                       if g in v.imprecise else None),
                       "unit": "mm" if g == "image" else "m"}
                   for g in v.groups},
        "notes": list(v.notes),
        "findings": [{k: f[k] for k in ("group", "estimated_ratio", "bound", "text")}
                     for f in v.findings],
        "bounds": dict(VCE_BOUNDS), "max_relative_sd": MAX_RELATIVE_SD,
    }
    kept = [g for g in v.groups if not v.estimable.get(g, False)]
    return v.problem, v.result, info, kept


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


def _scale_covariances(sol: Solution, setup: BundleSetup, settings, kept: list) -> None:
    """Scale the covariances as ``[adjustment] covariance_scale`` says (in place).

    ``"a-posteriori"``: by sigma0^2; ``"a-priori"``: by 1; ``"auto"`` (default): without
    road databases as ``"a-posteriori"``; with them by the variance factor of the groups
    (:func:`group_variance_factor`) whose sigma is known or was estimated - after
    two-pass or VCE without the groups kept at their stated sigma, in a single
    adjustment without the databases whose stated sigma is larger than their residuals
    say. ``sol.kept_groups`` names the groups left out.
    """
    scale = settings.covariance_scale
    if scale != "auto" or not setup.databases:
        sol.kept_groups = []
        sol.result.set_covariance_scale("a-posteriori" if scale == "auto" else scale)
        return
    reweighted = settings.reweight in ("two-pass", "vce")
    factor, sol.kept_groups = group_variance_factor(sol.result, setup, kept,
                                                    pessimistic_priors=not reweighted)
    sol.result.set_covariance_scale("groups", factor)


# --------------------------------------------------------------------------- offsets
def _offset_model(setup: BundleSetup, warnings: list) -> Optional[off.OffsetModel]:
    """The databases whose systematic offset is estimated (None: none is).

    Heights from a DEM add a height offset (``shift`` -> ``shift3d``; ``none`` says the
    database, DEM included, has no systematic error): the DEM's systematic height error,
    estimated with the adjustment, so that a biased DEM does not pull the stereo model.
    A control database (``role = "control"``) is never offset freely: with a stated
    ``systematic_sigma`` it gets a 3D shift whose prior is that systematic part (an
    error common to its vertices, carried into the covariances, not estimated from
    the data); without one, no offset.
    """
    names, kinds, points, dems, priors, dem_height = [], [], [], [], [], []
    for d in setup.databases:
        kind = getattr(d.spec, "offset", "none") or "none"
        if getattr(d.spec, "dem", None) and kind in _WITH_DEM_HEIGHT:
            kind = _WITH_DEM_HEIGHT[kind]  # the DEM's height bias, its own parameter
            dem_height.append(d.name)
        prior = None
        if getattr(d.spec, "role", "adjust") == "control":
            sys_ = np.sqrt(d.spec.systematic_variance)
            kind = "shift3d" if (sys_ > 0).any() else "none"
            prior = np.where(sys_ > 0, sys_, 1e-6)  # a zero part: held (1 um)
        pts = np.flatnonzero((setup.point_kind == "shape") & (setup.point_database == d.name))
        if off.OFFSET_KINDS[kind] and (prior is not None or
                                       len(pts) >= _MIN_OFFSET_POINTS[kind]):
            names.append(d.name)
            kinds.append(kind)
            points.append(pts)
            dems.append(getattr(d.shape.layer, "dem", None))
            priors.append(prior)
        elif off.OFFSET_KINDS[kind]:
            warnings.append(
                f"{d.name}: offset = {kind!r} needs at least {_MIN_OFFSET_POINTS[kind]} "
                f"measured shape points, the run has {len(pts)}: no offset is estimated "
                "for it (measure more points, or choose offset = \"shift\")")
    if not names:
        return None
    model = off.OffsetModel.build(names, kinds, points, setup.db_prior, dems, priors)
    model.dem_height = [n for n in dem_height if n in names]
    return model


def _adjust(setup: BundleSetup, model, adjust_kwargs: dict, progress, state: dict):
    """One adjustment; with offsets, Newton steps on them until they settle (with
    self-calibration: :func:`_adjust_joint`).

    ``state["values"]`` carries the offsets between calls (two-pass, VCE); the final
    cofactor and the covariance update are applied to the returned result.
    """
    if state.get("interior") is not None:
        return _adjust_joint(setup, model, adjust_kwargs, progress, state)
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
    # the first step is Newton's; the next reuse its cofactor with the new misclosure (a
    # chord step: the reduced normal matrix hardly changes between these re-adjustments,
    # and Q_xx B is the expensive part); the cofactor and Q_xx B that go with the result
    # are computed once more at the final estimate
    progress(0.7, "database offsets: Newton step (Q_xx B)")
    new, cof, gmax, qb, s_ztb = off.newton_step(result, model, values)
    exact = True  # cof, qb and s_ztb belong to the current result
    for _ in range(20):
        step = float(np.abs(model.displacement(new - values)).max(initial=0.0))  # m
        history.append({"step": step, "gradient": gmax, "values": new.tolist()})
        if step < tol:
            break
        # start from the linear prediction of the new solution: the offsets enter only the
        # point priors, so dX = -Q_xx B dT and dEO = S^-1 Z' B dT (a few % off at most)
        dt = new - values
        values = new
        setup.problem = off.shifted_problem(
            setup.problem, setup.db_prior, model, values,
            xyz0=result.xyz - np.matmul(qb, dt), eo_start=result.eo + (s_ztb @ dt).reshape(-1, 6))
        result = None  # the previous solution's arrays go before the next are made
        result = adjust(setup.problem, progress=progress, **tight)
        exact = False
        g = off.misclosure(result, model, values)
        new, gmax = values + cof @ g, float(np.abs(g).max(initial=0.0))
    if not exact:
        progress(0.7, "database offsets: their cofactor at the solution")
        _, cof, _, qb, s_ztb = off.newton_step(result, model, values)
    state["values"] = values
    state["cofactor"] = cof
    state["converged"] = step < tol
    off.apply_offsets(result, model, off.OffsetEstimate(values, cof), qb, s_ztb)
    return result


# --------------------------------------------------------------------------- self-calibration
def _joint_normals(result: BundleResult, model, interior, values, theta):
    """Reduced normals of the offsets and the interior parameters together."""
    from vectoradjust.adjust import selfcal

    n_i, g_i, qbp_i, qbe_i, a = selfcal.interior_normals(result, interior, theta)
    if model is None:
        return n_i, g_i, qbp_i, -qbe_i, a, None
    n_t, g_t, qb_t, s_ztb = off.offset_normals(result, model, values)
    b_t = off._b_blocks(result.problem, model)
    cross = -np.einsum("miq,mic->qc", b_t, qbp_i)
    n = np.block([[n_t, cross], [cross.T, n_i]])
    q, k = model.n_params, a.shape[0]
    a_all = np.concatenate([np.zeros((k, 2, q)), a], axis=2)
    return (n, np.r_[g_t, g_i], np.concatenate([qb_t, qbp_i], axis=2),
            np.concatenate([s_ztb, -qbe_i], axis=1), a_all, q)


class _Joint:
    """The offsets and the interior parameters as one set of nuisance parameters (for
    :func:`vectoradjust.adjust.offsets.apply_offsets`)."""

    def __init__(self, model, c: int, m: int) -> None:
        q = 0 if model is None else model.n_params
        self.n_params = q + c
        self.weights = np.r_[np.zeros(0) if model is None else model.weights, np.zeros(c)]
        g = np.zeros((m, 3, c))
        self.g = g if model is None else np.concatenate([model.g, g], axis=2)


def _interior_model(setup: BundleSetup, settings):
    """The interior parameters to self-calibrate (None: none)."""
    from vectoradjust.adjust import selfcal
    from vectoradjust.errors import ProjectError

    names = tuple(getattr(settings, "self_calibration", ()) or ())
    if not names:
        return None
    prob = setup.problem
    if prob.sensors is not None and prob.is_rpc.any():
        raise ProjectError("[adjustment] self_calibration is for frame cameras, but the block "
                           "has RPC images", "Leave self_calibration out for RPC blocks")
    return selfcal.InteriorModel.build(names, prob)


def _self_calibration_record(state: dict, model, result: BundleResult, warnings: list):
    """summary.json's self_calibration; a warning for parameters not determined."""
    from vectoradjust.adjust import selfcal

    interior = state["interior"]
    q = 0 if model is None else model.n_params
    active = state["active"]
    dropped = [n for n, a in zip(interior.names, active) if not a]
    if dropped:
        warnings.append("self-calibration: the block does not determine " + ", ".join(dropped)
                        + " (left at the camera's values): add height control, camera height "
                        "priors, convergent or cross strips, or points near the image corners")
    cof = state["cofactor"][q:, q:]
    return selfcal.summary_record(interior, state["theta"], cof, result.variance_factor,
                                  dropped)


def _adjust_joint(setup: BundleSetup, model, adjust_kwargs: dict, progress, state: dict):
    """Self-calibration (and offsets): Newton steps on the interior parameters (and
    the offsets) at the bundle's solution until they settle; parameters the block does
    not determine are left at the camera's values (:mod:`vectoradjust.adjust.selfcal`)."""
    from vectoradjust.adjust import selfcal

    interior = state["interior"]
    q = 0 if model is None else model.n_params
    values = state.get("values", np.zeros(q))
    theta = state.get("theta", np.zeros(interior.n_params))
    active = state.setdefault("active", np.ones(interior.n_params, bool))
    base = setup.problem
    xyz0 = eo0 = None
    result = None
    for it in range(25):
        prob = base if model is None else off.shifted_problem(base, setup.db_prior, model,
                                                              values)
        setup.problem = interior.problem(prob, theta, **(
            {} if xyz0 is None else {"xyz0": xyz0, "eo_start": eo0}))
        result = None
        result = adjust(setup.problem, progress=progress, **adjust_kwargs)
        n, g, qb, u, a, _ = _joint_normals(result, model, interior, values, theta)
        if it == 0:  # which interior parameters the block determines
            sub = n[q:, q:]
            active &= selfcal.determined_parameters(sub)
        keep = np.r_[np.ones(q, bool), active]
        cof = np.zeros_like(n)
        cof[np.ix_(keep, keep)] = np.linalg.inv(n[np.ix_(keep, keep)])
        step = cof @ g
        values = values + step[:q]
        theta = theta + step[q:]
        xyz0, eo0 = result.xyz, result.eo
        moved = float(np.abs(step).max(initial=0.0))
        progress(0.7, f"self-calibration: step {it + 1}, largest change {moved:.2g}")
        if moved < 1e-7:
            break
    state["values"], state["theta"], state["cofactor"] = values, theta, cof
    state["converged"] = moved < 1e-7
    keep = np.r_[np.ones(q, bool), active]
    joint = _Joint(model, interior.n_params, result.problem.n_points)
    off.apply_offsets(result, joint, off.OffsetEstimate(np.r_[values, theta], cof), qb, u)
    result.offset_a = a
    result.n_unknowns -= int((~keep).sum())  # left out: not unknowns
    result.dof += int((~keep).sum())
    result.sigma0_squared = (float(result.vtpv / result.dof) if result.dof > 0
                             else float("nan"))
    setup.problem = result.problem
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
        if name in getattr(model, "dem_height", []):
            rec[name]["dem_height"] = True  # its Z is the DEM's systematic height error
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
    model = None if setup.problem.free_datum else _offset_model(setup, warnings)
    # a datum defect stops here, named, before the solve
    datum_rec = datum_record(setup, model, warnings)
    state: dict = {"interior": _interior_model(setup, settings)}
    n_pass = 2 if settings.reweight == "two-pass" and dbs else 1
    sol: Optional[Solution] = None
    kept: list = []
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
            kept = _reweight_two_pass(setup, result, warnings)
    assert sol is not None
    if settings.reweight == "vce":
        progress(0.55, "variance component estimation")
        setup.problem, sol.result, sol.vce, kept = _vce(setup, adjust_kwargs, warnings)
        sol.passes.append(_pass_record("vce", sol.result, sol.vce["iterations"], dbs))
        if model is not None:  # the offsets again, with the estimated weights
            sol.result = _adjust(setup, model, adjust_kwargs, lambda f, m: None, state)
    if settings.snooping:
        progress(0.65, "data snooping")
        sol.result, sol.snooping = _snoop(setup, settings, adjust_kwargs, image_ids, meas,
                                          warnings)
    progress(0.72, "variance factor of the observation groups")
    _scale_covariances(sol, setup, settings, kept)
    _datum_floor(sol, setup, datum_rec, warnings)
    if model is not None:
        sol.offsets = _offset_record(model, state, sol.result)
        _relative_to_control(sol.offsets, setup)
    if state["interior"] is not None:
        sol.self_calibration = _self_calibration_record(state, model, sol.result, warnings)
    sol.problem = setup.problem
    sol.datum = datum_rec
    return sol


# --------------------------------------------------------------------------- datum
def _datum_sources(setup: BundleSetup) -> list:
    """What carries datum information, in words (for messages and summary.json)."""
    prob = setup.problem
    out = []
    ctrl = setup.point_kind == "control"
    w = prob.prior_weight
    n_xy = int((ctrl & (w[:, 0, 0] > 0) & (w[:, 1, 1] > 0)).sum())
    n_z = int((ctrl & (w[:, 2, 2] > 0)).sum())
    if ctrl.any():
        out.append(f"{int(ctrl.sum())} measured control point(s) ({n_xy} with X, Y; "
                   f"{n_z} with Z)")
    we = np.where(prob.eo_fixed, 0.0, prob.eo_weight)
    n_pos = int((we[:, :3] > 0).any(axis=1).sum())
    n_att = int((we[:, 3:] > 0).any(axis=1).sum())
    if n_pos:
        out.append(f"camera position priors on {n_pos} of {prob.n_images} image(s)")
    if n_att:
        out.append(f"attitude priors on {n_att} image(s)")
    for d in setup.databases:
        role = getattr(d.spec, "role", "adjust")
        heights = "DEM heights" if d.spec.dem else "heights from the layer"
        if role == "control":
            sys_ = d.spec.systematic_sigma
            out.append(f"road database {d.name} as control (sigma {list(d.spec.sigma)} m, "
                       + (f"systematic part {list(sys_)} m" if sys_ else
                          "no systematic part stated") + f", {heights})")
        else:
            kind = getattr(d.spec, "offset", "none") or "none"
            out.append(f"road database {d.name} (sigma {list(d.spec.sigma)} m, {heights}"
                       + (f"; its {kind} is estimated, so it fixes no shift)"
                          if kind != "none" else ")"))
    return out


def datum_record(setup: BundleSetup, model, warnings: Optional[list] = None) -> dict:
    """Check that the datum is fixed (frame cameras) and describe what fixes it.

    Raises
    ------
    DatumError
        A datum parameter is not determined: the message says which and how to fix it.
    """
    prob = setup.problem
    if prob.free_datum:
        return {"kind": "free network", "note": datum.FREE_NETWORK_NOTE}
    if prob.sensors is not None and prob.is_rpc.any():
        return {"kind": "sensor model", "note": "the RPCs place the images on the ground; "
                "their bias parameters are adjusted"}
    g = None if model is None else model.g
    pw = None if model is None else model.weights
    a = datum.analyse_datum(prob.eo0, prob.xyz0, prob.prior_weight,
                            np.where(prob.eo_fixed, 0.0, prob.eo_weight), g, pw,
                            sources=_datum_sources(setup))
    datum.check_datum(a)
    rec = a.to_dict()
    if a.weak and warnings is not None:
        sig = {p: s for p, s in zip(datum.DATUM_PARAMETERS, a.sigma)}
        warnings.append("the datum is only weakly fixed: " + ", ".join(
            f"{p} to {sig[p]:.3g} m" for p in a.weak) + " (by " + "; ".join(a.sources) +
            "); positions carry that uncertainty: add control points, tighter camera "
            "priors or a control road database")
    rec["kind"] = "prior information"
    return rec


def free_network(setup: BundleSetup, warnings: list) -> None:
    """Turn ``setup`` into a free network (in place): no point or camera prior, inner
    constraints over the cameras. A point seen on one image only cannot be intersected
    without its prior: its ray is left out and it keeps its database position (a
    warning says how many).

    Raises
    ------
    DatumError
        RPC images (their sensor model fixes the datum; nothing is free).
    """
    from vectoradjust.adjust.reliability import subset_problem
    from vectoradjust.errors import DatumError

    prob = setup.problem
    if prob.sensors is not None and prob.is_rpc.any():
        raise DatumError("A free network was asked for, but the block has RPC images: their "
                         "sensor model places them on the ground, so nothing is free",
                         'Leave datum = "free" out for blocks with RPC images')
    rays = np.bincount(prob.obs_point, minlength=prob.n_points)
    weight = np.where((rays >= 2)[:, None, None], 0.0, prob.prior_weight)
    free = replace(prob, prior_weight=weight, eo_sigma=np.full(prob.eo_sigma.shape, np.inf),
                   free_datum=True)
    sub, obs_index, _ = subset_problem(free, rays[prob.obs_point] >= 2)
    setup.problem = sub
    setup.obs_rows = setup.obs_rows[obs_index]
    n_single = int((rays == 1).sum())
    if n_single:
        warnings.append(f"free network: {n_single} point(s) measured on one image only cannot "
                        "be intersected without a prior; they keep their database position")
    ctrl = int(((setup.point_kind == "control") & (rays >= 2)).sum())
    if ctrl:
        warnings.append(f"free network: the {ctrl} control point(s) are used as tie points "
                        "(their coordinates are not used; compare them afterwards)")


def _datum_floor(sol: Solution, setup: BundleSetup, datum_rec: dict, warnings: list) -> None:
    """Without control points the datum rests on stated priors (camera positions, a
    control database's systematic part) that the image residuals do not test: a
    variance factor below 1 is not applied to them - the covariances are kept a priori
    (a warning says so)."""
    if datum_rec.get("kind") != "prior information" or (setup.point_kind == "control").any():
        return
    factor = sol.result.variance_factor
    if factor < 1.0:
        sol.result.set_covariance_scale("a-priori")
        warnings.append(f"the variance factor {factor:.3g} (< 1) was not applied to the "
                        "covariances: without control points the datum rests on stated priors "
                        "(camera positions, a control database's systematic part) that the "
                        "images do not test; the covariances are a priori")


def _relative_to_control(offsets: dict, setup: BundleSetup) -> None:
    """Say that the other databases' offsets are relative to a control database."""
    control = [d.name for d in setup.databases if getattr(d.spec, "role", "") == "control"]
    if not control:
        return
    for name, rec in offsets.items():
        if name in control:
            rec["note"] = ("systematic part of a control database: carried with its stated "
                           "prior (systematic_sigma), not estimated freely")
        elif not (setup.point_kind == "control").any():
            rec["relative_to"] = control
            rec["note"] = ("relative to the control database(s) " + ", ".join(control) +
                           " (no control points): an offset the control shares is not seen")
