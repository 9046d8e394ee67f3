"""Checks of the conflation against the truth: coverage per distance band
(:func:`band_coverage`) and the unmeasured vertices' RMSE before and after.

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["DISTANCE_BANDS", "band_coverage"]


#: distance bands (m) from the nearest measured point of the truth check's coverage table
DISTANCE_BANDS = (0.0, 50.0, 100.0, 200.0, np.inf)


def band_coverage(near: np.ndarray, inside_h: np.ndarray, inside_v: np.ndarray,
                  edges=DISTANCE_BANDS) -> list:
    """Coverage per distance band: ``[{"band", "count", "ce90", "le90"}]``.

    ``near`` (n,) the distance to the nearest measured point, ``inside_h`` and
    ``inside_v`` (n,) whether the truth lies within the CE90 / LE90 (NaN: no LE90);
    ``edges`` the bands' limits (m), lower inclusive.
    """
    near = np.asarray(near, float)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (near >= lo) & (near < hi)
        v = np.asarray(inside_v, float)[m]
        v = v[np.isfinite(v)]
        out.append({"band": f"{lo:g}-{hi:g}" if np.isfinite(hi) else f">{lo:g}",
                    "count": int(m.sum()),
                    "ce90": float(np.mean(np.asarray(inside_h, float)[m])) if m.any() else None,
                    "le90": float(np.mean(v)) if v.size else None})
    return out


def _truth_check(out, d, meas_v, source, near=None) -> Optional[dict]:
    """RMSE of the unmeasured vertices to the truth before and after, CE90/LE90 coverage
    (also per distance band of ``near``, each vertex's distance to the nearest measured
    point, :func:`band_coverage`)."""
    from vectoradjust.adjust.shapepoints import lookup

    truth = (getattr(out.data, "truth", None) or {}).get(d.name)
    if truth is None:
        return None
    tid, txyz = truth
    ti = lookup(np.asarray(tid), d.shape.vertex_ids)
    m = (~meas_v) & (ti >= 0) & np.isin(source, ("interpolated", "extrapolated"))
    if not m.any():
        return None
    v = d.vertices
    t = np.asarray(txyz, float)[ti[m]]
    db = d.shape.layer.coords[m]
    adj = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])[m]
    e_db, e_adj = np.hypot(*(db[:, :2] - t[:, :2]).T), np.hypot(*(adj[:, :2] - t[:, :2]).T)
    ez = np.abs(adj[:, 2] - t[:, 2])
    okz = np.isfinite(ez) & np.isfinite(v["LE90"][m])
    r_db, r_adj = float(np.sqrt(np.mean(e_db ** 2))), float(np.sqrt(np.mean(e_adj ** 2)))
    in_v = np.where(okz, ez <= np.where(okz, v["LE90"][m], 0.0), np.nan)
    bands = (band_coverage(np.asarray(near, float)[m], e_adj <= v["CE90"][m], in_v)
             if near is not None else None)
    return {"bands": bands, "count": int(m.sum()), "rmse_database_truth_horizontal": r_db,
            "rmse_conflated_truth_horizontal": r_adj,
            "reduction": float(1.0 - r_adj / r_db) if r_db > 0 else None,
            "share_within_ce90": float(np.mean(e_adj <= v["CE90"][m])),
            "rmse_database_truth_z": float(np.sqrt(np.nanmean((db[:, 2] - t[:, 2]) ** 2))),
            "rmse_conflated_truth_z": (float(np.sqrt(np.mean(ez[okz] ** 2)))
                                       if okz.any() else None),
            "share_within_le90": float(np.mean(ez[okz] <= v["LE90"][m][okz]))
            if okz.any() else None}
