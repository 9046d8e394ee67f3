"""The statistics stage: a run's tables in the contract's fields (docs/method.md section 9).

- :func:`tabulate_control` - control points from the bundle, check points intersected
  from the adjusted exterior orientation (with its covariance), CE90/LE90.
- :func:`tabulate_database` - per vertex (``shape_points``: V = adjusted - database,
  sigmas, CE90/LE90) and per feature (``features``: RMSE, length, ends, provenance),
  and the comparison with the truth where a simulation gives it.

Numpy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from vectoradjust.accuracy import stats
from vectoradjust.adjust.bundle import intersect
from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["LE90_FACTOR", "cov_stats", "tabulate_control", "tabulate_database",
           "one_vertex_per_point", "truth_points", "vertex_problems", "shape_point_column"]

#: LE90 / sigma (:data:`vectoradjust.accuracy.stats.LE90_FACTOR`, defined there once)
LE90_FACTOR = stats.LE90_FACTOR


def cov_stats(cov: np.ndarray):
    """Sigmas, CE90 and LE90 of (..., 3, 3) covariances."""
    sig = np.sqrt(np.maximum(np.einsum("...ii->...i", cov), 0.0))
    ce = stats.ce90(cov[..., :2, :2])
    le = LE90_FACTOR * sig[..., 2]
    return sig, ce, le


def n_images_per_point(out: AdjustmentRun) -> np.ndarray:
    """Number of images measuring each bundle point."""
    return np.bincount(out.problem.obs_point, minlength=out.problem.n_points)


# --------------------------------------------------------------------------- control
def _intersect_check_points(out: AdjustmentRun, ctrl_of_obs, is_check, img_of_obs, imap,
                            adj, cov, nimg) -> None:
    """Check points intersected from the adjusted EO (not in the adjustment), in place."""
    data, res = out.data, out.result
    meas = data.measurements
    chk = np.flatnonzero(is_check & (imap[img_of_obs] >= 0))
    if not chk.size:
        return
    cids, cinv = np.unique(ctrl_of_obs[chk], return_inverse=True)
    cinv = np.asarray(cinv).reshape(-1)
    cnt = np.bincount(cinv, minlength=len(cids))
    n_img = res.eo.shape[0]
    eo_cov_full = res.variance_factor * res.eo_cofactor()
    assert eo_cov_full.shape == (6 * n_img, 6 * n_img)
    xyz_c, cov_c = intersect(res.eo, cinv, imap[img_of_obs[chk]], meas.xy[chk],
                             meas.sigma[chk], len(cids), data.camera.focal_length,
                             data.camera.principal_point, eo_cov_full=eo_cov_full,
                             variance_factor=res.variance_factor,
                             sensors=None if res.problem is None else res.problem.sensors)
    ok = cnt >= 2
    adj[cids[ok]] = xyz_c[ok]
    cov[cids[ok]] = cov_c[ok]
    nimg[cids] = cnt
    for j in cids[~ok]:
        out.warnings.append(f"check point {str(data.control.point_id[j])!r} is measured on one "
                            "image only "
                            "and cannot be intersected; it was not used")


def tabulate_control(out: AdjustmentRun, ctrl_of_obs, is_check, img_of_obs, imap) -> None:
    """Fill ``out.control_points`` (control and check points, the contract's fields).

    Parameters
    ----------
    out : AdjustmentRun
        With ``result`` and ``point_ids``; its warnings are appended to.
    ctrl_of_obs : numpy.ndarray of int
        Control-file row of each measurement (-1: none).
    is_check : numpy.ndarray of bool
        Measurements of check points.
    img_of_obs : numpy.ndarray of int
        ``[[images]]`` index of each measurement.
    imap : numpy.ndarray of int
        Adjusted-image index of each ``[[images]]`` entry (-1: not adjusted).
    """
    res = out.result
    ctrl = out.data.control
    n = len(ctrl.point_id)
    adj = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    nimg = np.zeros(n, np.int64)
    # control points: from the bundle
    pidx = lookup(out.point_ids[out.point_kind == "control"], ctrl.point_id)
    has = pidx >= 0
    adj[has] = res.xyz[pidx[has]]
    cov[has] = res.point_cov[pidx[has]]
    nimg[has] = n_images_per_point(out)[pidx[has]]
    _intersect_check_points(out, ctrl_of_obs, is_check, img_of_obs, imap, adj, cov, nimg)
    for j in np.flatnonzero((ctrl.role == "check") & (nimg == 0)):
        out.warnings.append(f"check point {str(ctrl.point_id[j])!r} is measured on no image "
                            "and was "
                            "not used")
    sig, ce, le = cov_stats(cov)
    v = adj - ctrl.xyz
    out.control_points = {
        "point_id": ctrl.point_id, "role": ctrl.role,
        "X": ctrl.xyz[:, 0], "Y": ctrl.xyz[:, 1], "Z": ctrl.xyz[:, 2],
        "AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2],
        "Vx": v[:, 0], "Vy": v[:, 1], "Vz": v[:, 2],
        "SigmaX": sig[:, 0], "SigmaY": sig[:, 1], "SigmaZ": sig[:, 2],
        "CE90": ce, "LE90": le, "NImages": nimg,
        "Used": np.isfinite(adj).all(axis=1).astype(np.int64),
    }


# --------------------------------------------------------------------------- databases
def _vertex_table(out: AdjustmentRun, d: DatabaseResult):
    """``d.vertices`` and ``d.adjusted_coords``; returns (adj, v, ce, le, measured)."""
    res = out.result
    sp = d.shape
    layer = sp.layer
    nv = len(sp.vertex_ids)
    vp = d.vertex_point
    meas_v = vp >= 0
    db_xyz = layer.coords
    adj = db_xyz.copy()
    adj[meas_v] = res.xyz[vp[meas_v]]
    cov = np.full((nv, 3, 3), np.nan)
    cov[meas_v] = res.point_cov[vp[meas_v]]
    _, ce_meas, le_meas = cov_stats(cov)  # the measured point (photogrammetry only)
    # the real road vertex: the identification error is added (docs/method.md section 10)
    cov[meas_v] += np.diag(d.spec.identification_variance)
    sig, ce, le = cov_stats(cov)
    v = np.full((nv, 3), np.nan)
    v[meas_v] = adj[meas_v] - db_xyz[meas_v]
    nimg = np.zeros(nv, np.int64)
    nimg[meas_v] = n_images_per_point(out)[vp[meas_v]]
    d.adjusted_coords = adj
    d.vertices = {
        "point_id": sp.vertex_ids, "feature_id": layer.feature_ids[layer.vertex_feature],
        "X": db_xyz[:, 0], "Y": db_xyz[:, 1], "Z": db_xyz[:, 2],
        "Vx": v[:, 0], "Vy": v[:, 1], "Vz": v[:, 2],
        "AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2],
        "SigmaX": sig[:, 0], "SigmaY": sig[:, 1], "SigmaZ": sig[:, 2],
        "CE90": ce, "LE90": le, "CE90_meas": ce_meas, "LE90_meas": le_meas,
        "NImages": nimg, "Adjusted": meas_v.astype(np.int64),
        "Database": np.full(nv, d.name, dtype=object),
        # how the vertex got its position; the conflation stage adds interpolated and
        # extrapolated (conflation/)
        "Source": np.where(meas_v, "measured", "unchanged").astype(object),
    }
    return adj, v, ce, le, meas_v


def _feature_rmse(layer, v: np.ndarray, meas_v: np.ndarray):
    """Per feature: number of vertices, adjusted vertices and the RMSE of V per axis."""
    nf = layer.n_features
    fi = layer.vertex_feature
    npts = np.bincount(fi, minlength=nf)
    nadj = np.bincount(fi, weights=meas_v, minlength=nf).astype(np.int64)
    vz = np.where(meas_v[:, None], v, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ms = np.stack([np.bincount(fi, weights=vz[:, a] ** 2, minlength=nf) for a in range(3)],
                      axis=1) / nadj[:, None]
    ms[nadj == 0] = np.nan
    return npts, nadj, np.sqrt(ms)


def _feature_geometry(layer, adj: np.ndarray) -> dict:
    """Horizontal length (segments within a part) and first/last vertex of each feature."""
    nv = len(adj)
    nf = layer.n_features
    fi = layer.vertex_feature
    same = np.zeros(nv, bool)
    if nv > 1:
        same[1:] = (fi[1:] == fi[:-1]) & (layer.vertex_part[1:] == layer.vertex_part[:-1])
    seg = np.zeros(nv)
    if nv > 1:
        seg[1:] = np.hypot(*(adj[1:, :2] - adj[:-1, :2]).T)
    length = np.bincount(fi, weights=np.where(same, seg, 0.0), minlength=nf)
    first = np.full(nf, -1, np.int64)
    last = np.full(nf, -1, np.int64)
    if nv:
        first[fi[::-1]] = np.arange(nv)[::-1]
        last[fi] = np.arange(nv)
    has_v = first >= 0

    def at(idx, col):
        out_ = np.full(nf, np.nan)
        out_[has_v] = adj[idx[has_v], col]
        return out_

    return {"Length": length, "FirstX": at(first, 0), "FirstY": at(first, 1),
            "LastX": at(last, 0), "LastY": at(last, 1)}


def _feature_provenance(out: AdjustmentRun, d: DatabaseResult, meas_v: np.ndarray):
    """Per feature: ids of the images that measured one of its points, and their dates."""
    layer = d.shape.layer
    nf = layer.n_features
    fi = layer.vertex_feature
    vp = d.vertex_point
    n_img = len(out.image_ids)
    seen = np.zeros((out.problem.n_points, n_img), bool)
    seen[out.problem.obs_point, out.problem.obs_image] = True
    fseen = np.zeros((nf, n_img), np.int64)
    if meas_v.any():
        np.add.at(fseen, fi[meas_v], seen[vp[meas_v]].astype(np.int64))
    fseen = fseen > 0
    dates = {im.id: (im.date or "") for im in out.data.images}
    patterns, inv = np.unique(fseen, axis=0, return_inverse=True)
    inv = np.asarray(inv).reshape(-1)
    img_txt = []
    date_txt = []
    for pat in patterns:
        ids = [out.image_ids[j] for j in np.flatnonzero(pat)]
        img_txt.append(",".join(ids))
        date_txt.append(",".join(sorted({dates[i] for i in ids if dates[i]})))
    if not nf:
        return np.zeros(0, object), np.zeros(0, object)
    return np.array(img_txt, dtype=object)[inv], np.array(date_txt, dtype=object)[inv]


def one_vertex_per_point(vertex_point: np.ndarray) -> np.ndarray:
    """Mask of the first vertex of each adjusted object point (``vertex_point >= 0``).

    Vertices of one object point (an intersection shared by several features) have the
    same database, adjusted and true coordinates; a per-database RMSE counts the point
    once.
    """
    vp = np.asarray(vertex_point)
    keep = np.zeros(len(vp), bool)
    idx = np.flatnonzero(vp >= 0)
    if idx.size:
        _, first = np.unique(vp[idx], return_index=True)
        keep[idx[first]] = True
    return keep


def truth_vertex_index(out: AdjustmentRun, d: DatabaseResult) -> Optional[np.ndarray]:
    """Row of the database's truth table for each of its vertices (-1 where there is
    none), or None without truth (simulations).

    Matched once per database and truth table and kept on ``d`` (read-only): the truth
    tables, the accuracy statements and the identification estimate all ask (at 10^6
    shape points each match of the ids took about 2 s).
    """
    truth = (getattr(out.data, "truth", None) or {}).get(d.name)
    if truth is None:
        return None
    ids = d.shape.vertex_ids
    kept = d.__dict__.get("_truth_index")
    if kept is not None and kept[0] is truth[0] and kept[1] is ids:
        return kept[2]
    ti = lookup(truth[0], ids)
    ti.setflags(write=False)
    d.__dict__["_truth_index"] = (truth[0], ids, ti)
    return ti


def truth_points(out: AdjustmentRun, d: DatabaseResult):
    """The per-point truth table of a database (one row per adjusted object point).

    Returns
    -------
    dict of str to numpy.ndarray or None
        ``point_id``, ``X, Y, Z`` (database), ``AdjX, AdjY, AdjZ``, ``TrueX, TrueY,
        TrueZ`` and the columns of :func:`vectoradjust.accuracy.study.truth_point_table`
        (before/after differences, ``Closer``); None without truth for the database.
    """
    from vectoradjust.accuracy.study import truth_point_table

    truth = out.data.truth.get(d.name)
    if truth is None or d.adjusted_coords is None:
        return None
    ti = truth_vertex_index(out, d)
    m = one_vertex_per_point(d.vertex_point) & (ti >= 0)
    db, adj, t = d.shape.layer.coords[m], d.adjusted_coords[m], truth[1][ti[m]]
    return {"point_id": d.shape.vertex_ids[m], "X": db[:, 0], "Y": db[:, 1], "Z": db[:, 2],
            "AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2], "TrueX": t[:, 0],
            "TrueY": t[:, 1], "TrueZ": t[:, 2], **truth_point_table(db, adj, t)}


def _truth_comparison(out: AdjustmentRun, d: DatabaseResult, adj, v, ce, le, meas_v):
    """RMSE, recovery, improvement and CE90/LE90 coverage against the truth (simulations);
    each object point counted once (``count``), the share moved closer to the truth."""
    truth = out.data.truth.get(d.name)
    if truth is None:
        return None
    sp = d.shape
    txyz = truth[1]
    ti = truth_vertex_index(out, d)
    m = meas_v & (ti >= 0) & one_vertex_per_point(d.vertex_point)
    if not m.any():
        return None
    t = txyz[ti[m]]
    resid = v[m]
    dbt = sp.layer.coords[m] - t
    adt = adj[m] - t
    r_res = stats.rmse_summary(resid[:, 0], resid[:, 1], resid[:, 2])
    r_db = stats.rmse_summary(dbt[:, 0], dbt[:, 1], dbt[:, 2])
    r_adj = stats.rmse_summary(adt[:, 0], adt[:, 1], adt[:, 2])
    h_res, h_db, h_adj = (r["rmse_horizontal"] for r in (r_res, r_db, r_adj))
    inside = np.hypot(adt[:, 0], adt[:, 1]) <= ce[m]
    inside_z = np.abs(adt[:, 2]) <= le[m]
    return {
        "count": int(m.sum()),
        "rmse_residuals_horizontal": float(h_res),
        "rmse_database_truth_horizontal": float(h_db),
        # the dissertation's "recovery": the smaller RMSE over the larger (<= 1)
        "recovery_rate": float(min(h_res, h_db) / max(h_res, h_db)),
        "residual_to_true_ratio": float(stats.recovery_rate(h_res, h_db)),
        "rmse_adjusted_truth_horizontal": float(h_adj),
        "rmse_adjusted_truth_z": float(r_adj["rmse_z"]),
        "improvement": float(stats.improvement(h_adj, h_db)),
        "share_within_ce90": float(inside.mean()),
        "share_within_le90": float(inside_z.mean()),
        # the dissertation's "moved closer to the truth" (93 %), horizontally
        "moved_closer": float(np.mean(np.hypot(adt[:, 0], adt[:, 1])
                                      < np.hypot(dbt[:, 0], dbt[:, 1]))),
    }


def _feature_problems(d: DatabaseResult, adj: np.ndarray) -> np.ndarray:
    """The ``Problem`` text of each feature: the reader's (null geometry, ...) and vertices
    without a height (unmeasured, outside the DEM: their Z is NaN, written as 0)."""
    layer = d.shape.layer
    nf = layer.n_features
    txt = np.array([layer.problems.get(i, "") for i in range(nf)], dtype=object)
    if len(adj) == 0:
        return txt
    noz = np.bincount(layer.vertex_feature, weights=~np.isfinite(adj[:, 2]),
                      minlength=nf).astype(np.int64)
    why = "outside the DEM" if getattr(d.spec, "dem", None) else "the layer has no Z"
    for f in np.flatnonzero(noz):
        n = int(noz[f])
        note = (f"{n} vertices without height ({why}); their Z is written as 0" if n > 1 else
                f"1 vertex without height ({why}); its Z is written as 0")
        txt[f] = f"{txt[f]}; {note}" if txt[f] else note
    return txt


def vertex_problems(v: dict) -> np.ndarray:
    """The ``Problem`` text of each vertex of a database's ``vertices`` table: a vertex
    whose adjusted height is unknown (``AdjZ`` NaN: not measured and outside the DEM, or
    a layer without Z) is written with Z = 0 in the point geometry, and says so here."""
    noz = ~np.isfinite(np.asarray(v["AdjZ"], float))
    txt = np.full(noz.shape, "", dtype=object)
    txt[noz] = "no height (outside the DEM or no Z in the layer): geometry Z is 0, AdjZ null"
    return txt


def shape_point_column(v: dict, name: str) -> np.ndarray:
    """Column ``name`` of the ``shape_points`` layer from a database's ``vertices``
    (``Problem`` is derived: :func:`vertex_problems`)."""
    return vertex_problems(v) if name == "Problem" and "Problem" not in v else v[name]


def length_sd_scope(npts: np.ndarray, nadj: np.ndarray) -> np.ndarray:
    """The ``LengthSDOf`` field: which vertices ``LengthSD`` / ``LengthSDnc`` account for.

    ``"all vertices"`` when every vertex of the feature was measured; ``"measured
    vertices"`` when some were not: they count as fixed (their conflated position's
    uncertainty, correlated from vertex to vertex, is not in the sigma), so the sigma is
    a lower bound; ``""`` without a measured vertex (no sigma). After the conflation
    :func:`vectoradjust.accuracy.derived.conflated_length_sigma` adds the conflated
    vertices and updates it (``"all vertices"``: every vertex measured or conflated).
    """
    npts, nadj = np.asarray(npts), np.asarray(nadj)
    return np.where(nadj <= 0, "", np.where(nadj >= npts, "all vertices",
                                            "measured vertices")).astype(object)


def tabulate_database(out: AdjustmentRun, d: DatabaseResult) -> None:
    """Fill ``d.vertices``, ``d.features``, ``d.adjusted_coords`` and ``d.truth``.

    Parameters
    ----------
    out : AdjustmentRun
        With ``result`` and ``problem``.
    d : DatabaseResult
        One database of the run (``vertex_point`` set).
    """
    layer = d.shape.layer
    adj, v, ce, le, meas_v = _vertex_table(out, d)
    npts, nadj, rm = _feature_rmse(layer, v, meas_v)
    geometry = _feature_geometry(layer, adj)
    images, dates = _feature_provenance(out, d, meas_v)
    problem_txt = _feature_problems(d, adj)
    d.features = {
        "NPts": npts.astype(np.int64), "NAdj": nadj,
        "RMSE_X": rm[:, 0], "RMSE_Y": rm[:, 1], "RMSE_Z": rm[:, 2],
        "RMSE": np.sqrt(rm[:, 0] ** 2 + rm[:, 1] ** 2), **geometry,
        "Images": images, "ImgDate": dates, "Problem": problem_txt,
        "LengthSDOf": length_sd_scope(npts, nadj),
    }
    d.truth = _truth_comparison(out, d, adj, v, ce, le, meas_v)
