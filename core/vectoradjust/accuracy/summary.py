"""The summary stage: the JSON-ready run summary (summary.json, docs/method.md section 9).

:func:`run_summary` gives the contract's fields (sigma0^2, degrees of freedom, chi-square
test, RMSE of shape, check and control points, the adjusted images) and more (per
database, observations, passes); :func:`reliability_summary` the redundancy numbers and
flagged observations. Numpy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.accuracy import stats
from vectoradjust.accuracy.tables import one_vertex_per_point
from vectoradjust.formatting import float_or_none
from vectoradjust.results import AdjustmentRun
from vectoradjust.sensor.models import EO_PARAMETERS, corrected_rpc_names

__all__ = ["MAX_FLAGGED_IN_SUMMARY", "float_or_none", "rmse_dict", "run_summary",
           "reliability_summary", "COMPARE_COLUMNS", "compare_row", "compare_columns"]

MAX_FLAGGED_IN_SUMMARY = 1000


def rmse_dict(d: np.ndarray) -> dict:
    """RMSE summary of an (n, 3) array of differences (NaN rows ignored)."""
    ok = np.isfinite(d).all(axis=1) if len(d) else np.zeros(0, bool)
    s = stats.rmse_summary(d[ok, 0], d[ok, 1], d[ok, 2])
    return {k: (float_or_none(v) if k != "count" else int(v)) for k, v in s.items()}


def reliability_summary(out: AdjustmentRun, settings) -> dict:
    """Redundancy numbers, w-tests and flagged observations (Baarda, a-priori sigma0).

    Sets ``out.reliability`` and ``out.flagged`` (with the CSV line of each flagged
    image observation).
    """
    from vectoradjust.adjust.reliability import flagged_observations, reliability

    rel = reliability(out.result, alpha0=settings.alpha0, beta0=settings.beta0)
    out.reliability = rel
    flagged = flagged_observations(rel, out.result, out.point_ids, out.image_ids,
                                   out.point_kind)
    meas = out.data.measurements
    for f in flagged:
        k = f.get("observation")
        if f.get("kind") == "image" and k is not None:
            f["line"] = int(meas.rows[out.obs_rows[int(k)]])
    out.flagged = flagged
    r_img = rel.r_image[np.isfinite(rel.r_image)]
    return {
        "test": "Baarda w-test with the a-priori sigma0 = 1",
        "alpha0": settings.alpha0, "beta0": settings.beta0,
        "critical_value": float(rel.critical), "delta0": float(rel.delta0),
        "sum_of_redundancy_numbers": float(rel.sum_r), "degrees_of_freedom": int(rel.dof),
        "mean_redundancy_image": float_or_none(r_img.mean()) if r_img.size else None,
        "n_flagged": len(flagged),
        "flagged": flagged[:MAX_FLAGGED_IN_SUMMARY],
        "flagged_truncated": len(flagged) > MAX_FLAGGED_IN_SUMMARY,
    }


def _chi_square(res, alpha: float) -> dict:
    """The global test of v'Pv, JSON-ready."""
    chi = stats.chi_square_test(res.vtpv, res.dof, alpha) if res.dof > 0 else {
        "statistic": res.vtpv, "lower": None, "upper": None, "alpha": alpha,
        "passed": None}
    return {k: (bool(v) if k == "passed" and v is not None else
                (float_or_none(v) if v is not None else None)) for k, v in chi.items()}


def _eo_correlation(cov: np.ndarray, sd: np.ndarray) -> dict:
    """The correlation matrix of one image's exterior orientation (``parameters`` named
    as :data:`~vectoradjust.sensor.models.EO_PARAMETERS`): what ``vectoradjust measure``
    needs for search windows from the joint orientation covariance."""
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.asarray(cov, float) / np.outer(sd, sd)
    corr = np.where(np.outer(sd, sd) > 0, corr, np.eye(6))
    return {"parameters": list(EO_PARAMETERS),
            "matrix": np.round(np.clip(corr, -1.0, 1.0), 9).tolist()}


def _images(out: AdjustmentRun) -> list:
    """Adjusted EO and its sigmas per image (unused images with their approximations)."""
    res = out.result
    images = []
    used = {iid: j for j, iid in enumerate(out.image_ids)}
    for im in out.data.images:
        if im.id in used and im.model == "rpc":
            images.append(rpc_image_entry(im, res, used[im.id], out.data.settings.alpha,
                                          corrected_rpc_names(out.data.images)[str(im.id)]))
        elif im.id in used:
            j = used[im.id]
            sd = np.sqrt(np.diag(res.eo_cov[j]))
            images.append({
                "id": im.id, "position": res.eo[j, :3].tolist(),
                "attitude": np.degrees(res.eo[j, 3:]).tolist(),
                "sigma_position": sd[:3].tolist(), "sigma_attitude": np.degrees(sd[3:]).tolist(),
                "correlation": _eo_correlation(res.eo_cov[j], sd),
                "date": im.date, "used": True,
            })
        else:
            images.append({"id": im.id, "position": list(map(float, im.position)),
                           "attitude": list(map(float, im.attitude)), "sigma_position": None,
                           "sigma_attitude": None, "date": im.date, "used": False})
    return images


def rpc_image_entry(im, res, j: int, alpha: float = 0.05,
                    corrected: Optional[str] = None) -> dict:
    """An RPC image's estimated bias in the summary: values and sigmas (px), the
    correlations of the estimated parameters, and whether the bias is significant.

    The joint test compares ``b' C^-1 b`` of the estimated parameters with the
    chi-square quantile ``1 - alpha`` (``k`` degrees of freedom); each parameter's test
    compares ``|b| / sigma`` with the normal quantile ``1 - alpha / 2``. ``corrected``
    names the RPC file with the bias folded in that the outputs hold; the fold's largest
    misfit (px) goes with it.
    """
    from scipy.special import gammaincinv, ndtri

    from vectoradjust.sensor.models import BIAS_PARAMETERS
    from vectoradjust.sensor.rpc import fold_bias

    free = im.rpc.free
    b, cov = res.eo[j], res.eo_cov[j]
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    entry = {"id": im.id, "model": "rpc", "rpc": im.rpc.path, "bias_model": im.rpc.bias,
             "bias": {n: float(b[k]) for k, n in enumerate(BIAS_PARAMETERS) if free[k]},
             "sigma_bias": {n: float(sd[k]) for k, n in enumerate(BIAS_PARAMETERS) if free[k]},
             "date": im.date, "used": True}
    if corrected is not None:
        entry["corrected_rpc"] = {"file": corrected,
                                  "fold_misfit_px": float(fold_bias(im.rpc.rpc, b)[1])}
    if not free.any():
        return entry
    idx = np.flatnonzero(free)
    c = cov[np.ix_(idx, idx)]
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = c / np.outer(sd[idx], sd[idx])
    stat = float(b[idx] @ np.linalg.solve(c, b[idx])) if np.all(sd[idx] > 0) else None
    zq = float(ndtri(1 - alpha / 2))
    crit = float(2.0 * gammaincinv(len(idx) / 2.0, 1 - alpha))  # chi-square quantile
    entry["correlation"] = {"parameters": [BIAS_PARAMETERS[k] for k in idx],
                            "matrix": np.round(corr, 6).tolist()}
    entry["significance"] = {
        "alpha": alpha, "statistic": stat, "dof": int(len(idx)),
        "critical": crit, "significant": None if stat is None else bool(stat > crit),
        "parameters": {BIAS_PARAMETERS[k]: bool(abs(b[k]) > zq * sd[k]) for k in idx}}
    return entry


def _database_entry(d) -> dict:
    """Summary of one database: counts, prior sigma, residual RMSE, mean CE90/LE90, truth."""
    adjm = d.vertices["Adjusted"] == 1
    entry = {
        "name": d.name,
        "vertices": int(len(adjm)),
        "adjusted_vertices": int(adjm.sum()),
        "features": int(d.shape.layer.n_features),
        "unadjustable_features": int(len(d.shape.layer.problems)),
        "sigma_prior": list(map(float, d.sigma_used)),
        # each object point once (an intersection vertex shared by two features is one
        # point): "points" of the RMSE, "adjusted_vertices" of the layer
        "points": int(one_vertex_per_point(d.vertex_point).sum()),
        "residuals": rmse_dict(np.column_stack([d.vertices["Vx"], d.vertices["Vy"],
                                                d.vertices["Vz"]])
                               [one_vertex_per_point(d.vertex_point)]),
        "mean_ce90": float_or_none(np.mean(d.vertices["CE90"][adjm])) if adjm.any() else None,
        "mean_le90": float_or_none(np.mean(d.vertices["LE90"][adjm])) if adjm.any() else None,
    }
    if d.truth is not None:
        entry["truth"] = d.truth
    return entry


def _observations(out: AdjustmentRun) -> dict:
    res, kinds = out.result, out.point_kind
    return {
        "image_coordinates": int(2 * len(out.problem.obs_point)),
        "point_priors": int(3 * out.problem.has_prior.sum()),
        "eo_priors": int((out.problem.eo_weight > 0).sum()),
        "total": int(res.n_obs), "unknowns": int(res.n_unknowns),
        "control_points": int((kinds == "control").sum()),
        "shape_points": int((kinds == "shape").sum()),
        "tie_points": int((kinds == "tie").sum()),
    }


def _adjusted(out: AdjustmentRun, column: str) -> np.ndarray:
    """A shape-point column over every database's adjusted vertices."""
    if not out.databases:
        return np.zeros(0)
    return np.concatenate([d.vertices[column][d.vertices["Adjusted"] == 1]
                           for d in out.databases])


def run_summary(out: AdjustmentRun) -> dict:
    """The run summary (summary.json without reliability, VCE, snooping and accuracy).

    Parameters
    ----------
    out : AdjustmentRun
        With its tables filled (:mod:`vectoradjust.accuracy.tables`).

    Returns
    -------
    dict
        JSON-ready.
    """
    res = out.result
    data = out.data
    cp = out.control_points
    vv = np.column_stack([cp["Vx"], cp["Vy"], cp["Vz"]])
    chk = (cp["role"] == "check") & (cp["Used"] == 1)
    con = (cp["role"] == "control") & (cp["Used"] == 1)
    # each object point of a database once (shared intersection vertices are one point)
    shape_rows = [np.column_stack([d.vertices["Vx"], d.vertices["Vy"], d.vertices["Vz"]])
                  [one_vertex_per_point(d.vertex_point)] for d in out.databases]
    all_v = np.concatenate(shape_rows) if shape_rows else np.zeros((0, 3))
    allce, allle = _adjusted(out, "CE90"), _adjusted(out, "LE90")
    return {
        "project": data.source,
        "crs": data.crs,
        "sigma0_squared": float_or_none(res.sigma0_squared),
        "sigma0": float_or_none(np.sqrt(res.sigma0_squared)) if res.dof > 0 else None,
        "degrees_of_freedom": int(res.dof),
        "iterations": int(res.iterations),
        "converged": bool(res.converged),
        "chi_square": _chi_square(res, data.settings.alpha),
        "observations": _observations(out),
        "shape_points": rmse_dict(all_v),
        "check_points": rmse_dict(vv[chk]),
        "control_points": rmse_dict(vv[con]),
        "mean_ce90": float_or_none(allce.mean()) if allce.size else None,
        "mean_le90": float_or_none(allle.mean()) if allle.size else None,
        "images": _images(out),
        "databases": [_database_entry(d) for d in out.databases],
        "reweight": data.settings.reweight,
        "passes": out.passes,
        "interior_orientation": data.interior or None,
        "warnings": list(out.warnings),
    }


# --------------------------------------------------------------------------- compare table
COMPARE_COLUMNS = [
    ("database", "database"), ("adjusted", "adjusted"), ("points", "points"),
    ("rmse_x", "RMSE x"),
    ("rmse_y", "RMSE y"), ("rmse_z", "RMSE z"), ("rmse_horizontal", "RMSE h"),
    ("mean_ce90", "CE90"), ("mean_le90", "LE90"), ("sigma0_squared", "s0^2"),
    ("chi_square_passed", "chi2 ok"), ("check_rmse_horizontal", "check h"),
    ("true_rmse", "true RMSE"), ("recovery", "recovery"), ("adjusted_truth_rmse", "adj-truth"),
    ("improvement", "improve"), ("vce", "VCE"), ("offset", "offset"),
    ("moved_closer", "closer"),
]


def compare_row(summary: dict) -> dict:
    """One row of the comparison table (``compare.csv``) from a run's summary."""
    db = summary["databases"][0] if summary["databases"] else {}
    res = db.get("residuals", {})
    truth = db.get("truth") or {}
    return {
        "database": db.get("name"), "adjusted": db.get("adjusted_vertices"),
        "points": db.get("points"),  # the object points the RMSE counts (each once)
        "rmse_x": res.get("rmse_x"), "rmse_y": res.get("rmse_y"), "rmse_z": res.get("rmse_z"),
        "rmse_horizontal": res.get("rmse_horizontal"), "mean_ce90": db.get("mean_ce90"),
        "mean_le90": db.get("mean_le90"), "sigma0_squared": summary.get("sigma0_squared"),
        "chi_square_passed": summary["chi_square"].get("passed"),
        "check_rmse_horizontal": summary["check_points"].get("rmse_horizontal"),
        "true_rmse": truth.get("rmse_database_truth_horizontal"),
        "recovery": truth.get("recovery_rate"),
        "adjusted_truth_rmse": truth.get("rmse_adjusted_truth_horizontal"),
        "improvement": truth.get("improvement"),
        "vce": _vce_state(summary.get("variance_components")),
        "offset": _offset_short(db.get("offset")),
        "moved_closer": truth.get("moved_closer"),
        **_buffer_columns(truth.get("buffer")),
    }


_COMPASS = {"north": "N", "north-east": "NE", "east": "E", "south-east": "SE", "south": "S",
            "south-west": "SW", "west": "W", "north-west": "NW"}


def _offset_short(off) -> str:
    """``1.41 m NW +-0.20 (significant)`` for the compare table; ``-`` without offset."""
    if not off:
        return "-"
    d = _COMPASS.get(off.get("direction", ""), "")
    sig = " (significant)" if off["test"]["significant"] else ""
    return f"{off['horizontal']:.2f} m {d} +-{off['horizontal_sigma']:.2f}{sig}"


def _vce_state(vce) -> str:
    """``-`` (no VCE), ``converged``, ``NOT converged`` and ``finding`` for a held group."""
    if not vce:
        return "-"
    state = "converged" if vce.get("converged") else "NOT converged"
    if vce.get("findings"):
        state += " + finding"
    return state


def _buffer_columns(buf) -> dict:
    """``in 1m before`` / ``in 1m after`` ... from a truth buffer test (shares, 0-1)."""
    if not buf:
        return {}
    out = {}
    for w, b, a in zip(buf["widths"], buf["before"], buf["after"]):
        out[f"in_{w:g}m_before"] = b
        out[f"in_{w:g}m_after"] = a
    return out


def compare_columns(rows: list) -> list:
    """The table's (key, heading) pairs: the fixed columns, then any buffer-test shares."""
    cols = list(COMPARE_COLUMNS)
    known = {k for k, _ in cols}
    for r in rows:
        for k in r:
            if k not in known:
                known.add(k)
                cols.append((k, k.replace("in_", "in ").replace("_", " ")))
    return cols


# --------------------------------------------------------------------------- offsets
def offset_entry(rec: dict, name: str, alpha: float = 0.05) -> dict:
    """The estimated systematic offset of a database, with its sigma and a test of zero.

    Parameters
    ----------
    rec : dict
        One entry of :attr:`vectoradjust.adjust.passes.Solution.offsets`.
    name : str
        Database name (for the statement).
    alpha : float
        Significance level of the test ``T = 0`` (chi-square, one degree of freedom
        per offset parameter).

    Returns
    -------
    dict
        ``values``/``sigma`` per axis (database minus images, m), the horizontal
        magnitude with its sigma and compass direction, the test and a sentence such as
        ``"OSM is 2.93 m north-east of the images (+- 0.05 m)"``.
    """
    from scipy.special import gammaincinv  # chi2.ppf(q, k) = 2 gammaincinv(k/2, q)

    vals = np.asarray(rec["values"], float)
    cov = np.asarray(rec["cofactor"], float) * float(rec["variance_factor"])
    axes = list(rec["axes"])
    stat = float(vals @ np.linalg.solve(cov, vals)) if len(vals) else 0.0
    crit = float(2.0 * gammaincinv(0.5 * len(vals), 1.0 - alpha)) if len(vals) else float("nan")
    entry = {"axes": axes, "values": vals.tolist(), "sigma": list(rec["sigma"]),
             "test": {"statistic": stat, "critical": crit, "alpha": alpha,
                      "significant": bool(stat > crit)},
             "converged": rec.get("converged", True), "newton_steps": rec.get("newton_steps")}
    if "X" in axes:
        dx, dy = vals[axes.index("X")], vals[axes.index("Y")]
        mag, az, direction = stats.bias_direction(dx, dy)
        u = np.array([dx, dy]) / mag if mag > 0 else np.zeros(2)
        sig_mag = float(np.sqrt(max(u @ cov[:2, :2] @ u, 0.0))) if mag > 0 else float(
            np.sqrt(np.trace(cov[:2, :2]) / 2))
        entry.update({"horizontal": float(mag), "horizontal_sigma": sig_mag,
                      "azimuth": float_or_none(az), "direction": direction})
        where = f"{direction} of" if direction not in ("", "none") else "on"
        text = f"{name} is {mag:.2f} m {where} the images (+- {sig_mag:.2f} m)"
    else:  # a height offset alone (heights from a DEM, offset = "none")
        text = f"{name}'s heights are"
    if "Z" in axes:
        dz, sz = vals[axes.index("Z")], rec["sigma"][axes.index("Z")]
        text += (f"{',' if 'X' in axes else ''} {abs(dz):.2f} m "
                 f"{'above' if dz > 0 else 'below'} (+- {sz:.2f} m)")
        if rec.get("dem_height"):
            text += " (its DEM's height bias)"
    if "rotation" in axes:
        i, j = axes.index("rotation"), axes.index("scale")
        text += (f", rotated {vals[i] * 1e3:+.3f} mrad (+- {rec['sigma'][i] * 1e3:.3f}) and "
                 f"scaled {vals[j] * 1e6:+.0f} ppm (+- {rec['sigma'][j] * 1e6:.0f}) about "
                 "its centroid")
    if "a11" in axes:
        text += ", with an affine distortion about its centroid (a11..a22 in summary.json)"
    text += "; significant" if entry["test"]["significant"] else "; not significant"
    entry["statement"] = text
    return entry


# --------------------------------------------------------------------------- group factors
def group_factors(out: AdjustmentRun) -> dict:
    """``v'Pv / r`` of every observation group: which stated sigma the data contradict.

    Groups: image coordinates, control points, each database's horizontal and vertical
    shape point priors, and the exterior orientation priors. A factor near 1 means the
    group's stated sigma fits its residuals; the chi-square test of the run is the
    redundancy-weighted mean of these factors, so when it fails they say why. A factor
    is flagged when it is more than 3 standard deviations (``sqrt(2 / r)``) from 1.

    Returns
    -------
    dict
        ``{"groups": {name: {vtpv, redundancy, factor, count, flagged}}, "explanation"}``.
    """
    from vectoradjust.adjust.vce import group_statistics

    res, rel = out.result, out.reliability
    m = res.problem.n_points
    lab = np.full((m, 3), "", dtype=object)
    lab[out.point_kind == "control"] = "control"
    groups = ["image", "control"]
    for d in out.databases:
        sel = (out.point_kind == "shape") & (out.point_database == d.name)
        lab[sel, :2] = f"{d.name}:h"
        lab[sel, 2] = f"{d.name}:v"
        groups += [f"{d.name}:h", f"{d.name}:v"]
    obs = np.full(len(res.problem.obs_point), "image", dtype=object)
    eo = np.full((res.problem.n_images, 6), "exterior orientation priors", dtype=object)
    groups.append("exterior orientation priors")
    vtpv, red, cnt = group_statistics(res, rel, obs.astype(str), lab.astype(str),
                                      eo.astype(str), groups)
    table, flagged = {}, []
    for g in groups:
        if cnt[g] == 0:
            continue
        f = vtpv[g] / red[g] if red[g] > 0 else float("nan")
        bad = bool(red[g] >= 1.0 and abs(f - 1.0) > 3.0 * np.sqrt(2.0 / red[g]))
        table[g] = {"vtpv": vtpv[g], "redundancy": red[g], "factor": float_or_none(f),
                    "count": cnt[g], "flagged": bad}
        if bad:
            flagged.append(f"{g} {f:.2f} (r = {red[g]:.1f})")
    text = ("every group's residuals fit its stated sigma" if not flagged else
            "v'Pv / r far from 1 for: " + ", ".join(flagged) + " - a factor below 1 means "
            "the stated sigma is too large (e.g. DEM heights after two-pass, whose pass-1 "
            "residuals include the stereo height error; uninformative exterior orientation "
            "priors), above 1 too small; reweight = \"vce\" estimates them")
    return {"groups": table, "explanation": text}
