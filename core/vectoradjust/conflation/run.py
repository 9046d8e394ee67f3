"""Conflating a database and a run (:func:`conflate_database`, :func:`conflate_run`) and
the displacement field on a grid (:func:`field_grid`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from vectoradjust.conflation.coverage import _truth_check
from vectoradjust.conflation.fields import _vertex_columns
from vectoradjust.conflation.images import _measured_objects
from vectoradjust.conflation.prediction import _predicted_objects
from vectoradjust.conflation.settings import (
    CE90_CIRCULAR,
    LE90,
    SOURCES,
    ConflationSettings,
)

__all__ = ["conflate_database", "conflate_run", "field_grid"]


def conflate_database(out, d, rec: Optional[dict], s: ConflationSettings,
                      report: Optional[Callable[[float], None]] = None,
                      cancel: Optional[Callable[[], bool]] = None) -> dict:
    """Correct every unmeasured vertex of one database (``d.vertices`` etc. in place).

    Parameters
    ----------
    out : AdjustmentRun
        With ``result`` (points and covariances) and ``d.vertices`` tabulated.
    d : DatabaseResult
    rec : dict or None
        The database's estimated offset (``Solution.offsets[name]``), None without.
    s : ConflationSettings
    report, cancel : callable, optional
        ``report(fraction)``; ``cancel()`` true raises ``CancelledError``.

    Returns
    -------
    dict
        summary.json's entry: status, vertices per source, trend, covariance functions,
        leave-one-out cross-validation and (simulations) the comparison with the truth.
    """
    report = report or (lambda f: None)
    obj_pt, meas_v = _measured_objects(d)
    n_meas = int((obj_pt >= 0).sum())
    source = np.where(meas_v, "measured", "unchanged").astype(object)
    entry: dict = {"name": d.name, "measured_points": n_meas}
    scope = np.asarray(d.features.get("LengthSDOf", []), object)
    entry["length_sd"] = {
        "covers": "measured and conflated vertices; those left at their database position "
                  "count as fixed (features: LengthSDOf)",
        "features_with_unmeasured_vertices": int((scope == "measured vertices").sum())}
    if not s.enabled or n_meas < s.min_points or meas_v.all():
        d.vertices["Source"] = source
        entry["status"] = ("disabled" if not s.enabled else "nothing to predict"
                           if meas_v.all() else
                           f"not done: {n_meas} measured points, fewer than min_points = "
                           f"{s.min_points}")
        entry["vertices"] = {k: int((source == k).sum()) for k in SOURCES}
        return entry
    u_obj, disp, cov, kappa, fh, info, d.conflation = _predicted_objects(
        out, d, rec, s, obj_pt, report, cancel)
    if fh.cov is None:  # no horizontal field: nothing honest to predict with
        d.conflation = None
        d.vertices["Source"] = source
        n_img = info["cross_validation"]["horizontal"]["count"]
        entry.update({"status": f"not done: {n_img} of {n_meas} measured points have a "
                      f"position from the images alone, fewer than min_points = "
                      f"{s.min_points}", **info,
                      "vertices": {k: int((source == k).sum()) for k in SOURCES}})
        return entry
    db = d.shape.object_xyz
    adj_o, cov_o, near_o, kappa_o = _per_object(d, u_obj, disp, cov, kappa, fh.nearest)
    cov_m = fh.cov
    if cov_m is None:  # no field fitted (too few finite residuals)
        maxd = s.max_distance or np.inf
    else:
        maxd = s.max_distance or (cov_m.practical_range if cov_m.sill > 0 else
                                  (max(cov_m.fit.get("lags") or [np.inf])))
    vo = d.shape.vertex_object
    u = ~meas_v
    # interpolated: among the measured points (inside their convex hull) and within
    # max_distance of one; anywhere else the field is extrapolated
    inside = inside_hull(db[vo[meas_v], :2], db[:, :2])
    source[u] = np.where((near_o[vo[u]] <= maxd) & inside[vo[u]], "interpolated",
                         "extrapolated")
    _vertex_columns(d, meas_v, adj_o[vo], cov_o[vo], source, kappa_o[vo])
    if info["covariance"]["vertical"] is None:  # too few heights: Z unchanged
        d.vertices["Vz"][u] = np.nan
    entry.update({"status": "conflated", "max_distance": float(maxd), **info,
                  "vertices": {k: int((source == k).sum()) for k in SOURCES},
                  "truth": _truth_check(out, d, meas_v, source, near_o[vo])})
    return entry


def _per_object(d, u_obj, disp, cov, kappa, nearest):
    """Adjusted position, covariance, nearest measured distance and CE90 factor per
    object point of ``d`` (the predicted ones ``u_obj``; NaN, inf and 1 elsewhere)."""
    nobj = d.shape.n_objects
    db = d.shape.object_xyz
    adj_o = np.full((nobj, 3), np.nan)
    cov_o = np.full((nobj, 3, 3), np.nan)
    near_o = np.full(nobj, np.inf)
    kappa_o = np.ones(nobj)
    adj_o[u_obj] = db[u_obj] + np.where(np.isfinite(disp), disp, 0.0)
    cov_o[u_obj] = cov
    kappa_o[u_obj] = kappa
    near_o[u_obj] = nearest
    return adj_o, cov_o, near_o, kappa_o


def inside_hull(points: np.ndarray, query: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Which ``query`` points (n, 2) lie in the convex hull of ``points`` (m, 2).

    ``scipy.spatial.ConvexHull`` and its facets' half-planes (a point on the boundary,
    to 1e-9 of the hull's extent, is inside); all False where the points span no area
    (fewer than three, or on one line). Linear in ``n`` (chunks of ``chunk`` points).
    """
    from scipy.spatial import ConvexHull, QhullError

    query = np.asarray(query, float)
    out = np.zeros(len(query), bool)
    pts = np.unique(np.asarray(points, float)[np.isfinite(points).all(axis=1)], axis=0)
    if len(pts) < 3:
        return out
    try:
        hull = ConvexHull(pts)
    except QhullError:  # collinear: no area
        return out
    eq = hull.equations  # (f, 3): normal . x + offset <= 0 inside
    tol = 1e-9 * float(np.ptp(pts, axis=0).max())
    for lo in range(0, len(query), chunk):
        q = query[lo:lo + chunk]
        out[lo:lo + chunk] = np.all(q @ eq[:, :2].T + eq[:, 2] <= tol, axis=1)
    return out


def _horizontal(rec: Optional[dict]) -> Optional[dict]:
    """An offset record without the height of a DEM (``dem_height``): the DEM's
    systematic height error, estimated so that it does not pull the stereo model, is
    left to the conflation's own height rule (:func:`_trend`: a common height
    displacement is applied only where it exceeds one measured point's height error, and
    counted in the variance where not), not applied to every unmeasured vertex."""
    if rec is None or not rec.get("dem_height") or "Z" not in rec["axes"]:
        return rec
    keep = [i for i, a in enumerate(rec["axes"]) if a != "Z"]
    if not keep:
        return None
    cof = np.asarray(rec["cofactor"], float)[np.ix_(keep, keep)]
    kinds = {("X", "Y"): "shift"}
    return {**rec, "axes": [rec["axes"][i] for i in keep],
            "kind": kinds.get(tuple(rec["axes"][i] for i in keep), rec["kind"]),
            "values": [rec["values"][i] for i in keep],
            "sigma": [rec["sigma"][i] for i in keep], "cofactor": cof.tolist()}


def conflate_run(out, offsets: Optional[dict], settings: ConflationSettings,
                 progress: Optional[Callable[[float, str], None]] = None,
                 is_cancelled: Optional[Callable[[], bool]] = None) -> dict:
    """Conflate every database of a run; returns summary.json's ``conflation``.

    Parameters
    ----------
    out : AdjustmentRun
    offsets : dict or None
        ``Solution.offsets`` (per database name).
    settings : ConflationSettings
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional

    Returns
    -------
    dict
        The settings and one entry per database (:func:`conflate_database`).
    """
    entries = []
    n = max(len(out.databases), 1)
    for i, d in enumerate(out.databases):
        msg = f"conflation of {d.name}"

        def report(f, i=i, msg=msg):
            if progress is not None:
                progress((i + f) / n, msg)

        entries.append(conflate_database(out, d, _horizontal((offsets or {}).get(d.name)),
                                         settings,
                                         report, is_cancelled))
    return {"enabled": settings.enabled, "k": settings.k, "model": settings.model,
            "max_distance": settings.max_distance, "min_points": settings.min_points,
            "databases": entries}


def field_grid(d, cell: Optional[float] = None, max_cells: int = 40000) -> Optional[dict]:
    """The displacement field of a conflated database on a regular grid.

    Parameters
    ----------
    d : DatabaseResult
        Conflated (``d.conflation`` set).
    cell : float, optional
        Cell size (m); default: the extent over ``sqrt(max_cells)``, rounded up to 1-2-5.
    max_cells : int
        At most this many cells (the cell grows when needed).

    Returns
    -------
    dict or None
        ``x0``, ``y0`` (upper left corner), ``cell``, ``dx``, ``dy``, ``dz`` and
        ``ce90``, ``le90`` arrays (rows from north to south); None without a field.
    """
    model = getattr(d, "conflation", None)
    xy = np.asarray(d.shape.layer.coords, float)[:, :2] if len(d.shape.layer.coords) else None
    if model is None or xy is None:
        return None
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    ext = float(max((hi - lo).max(), 1.0))
    need = ext / np.sqrt(max_cells)
    if cell is None or cell < need:
        e = 10.0 ** np.floor(np.log10(need))
        cell = float(next(m * e for m in (1.0, 2.0, 5.0, 10.0) if m * e >= need))
    nx = int(np.ceil((hi[0] - lo[0]) / cell)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / cell)) + 1
    x0, y0 = float(lo[0] - cell / 2), float(hi[1] + cell / 2)
    gx = x0 + cell * (np.arange(nx) + 0.5)
    gy = y0 - cell * (np.arange(ny) + 0.5)
    xx, yy = np.meshgrid(gx, gy)
    disp, var, kappa = model.predict(np.column_stack([xx.ravel(), yy.ravel()]),
                                     ce90_factor=True)
    sig_h = kappa * np.sqrt(np.maximum(var[:, :2].mean(axis=1), 0.0))
    shape = (ny, nx)
    return {"x0": x0, "y0": y0, "cell": cell, "dx": disp[:, 0].reshape(shape),
            "dy": disp[:, 1].reshape(shape), "dz": disp[:, 2].reshape(shape),
            "ce90": (CE90_CIRCULAR * sig_h).reshape(shape),
            "le90": (LE90 * np.sqrt(np.maximum(var[:, 2], 0.0))).reshape(shape)}
