"""Estimates of the identification error from the data (docs/method.md section 10).

The adjustment estimates the point the analyst measured, ``X_id = X_true + e_id``; the
identification error ``e_id`` leaves no trace in the image residuals, so it is stated in
``[[vectors]] identification_sigma``. Two kinds of data reveal it:

- **truth** (``truth`` tables keyed by vertex id: surveyed road points, or a
  simulation's truth): ``E[(X_hat - X_true)_a^2] = C_aa + sigma_id,a^2`` per axis, with
  ``C`` the adjusted point's covariance, so ``sigma_id^2`` is the mean of
  ``e_a^2 - C_aa`` (horizontal: X and Y pooled);
- **common intersections of two databases** measured separately: the same road
  intersection adjusted twice, ``d = X_hat_A - X_hat_B``, has
  ``E[d_a^2] = 2 sigma_id,a^2 + C_A,aa + C_B,aa`` (each measurement has its own
  identification error; the shared exterior orientation only lowers the
  photogrammetric part, which is neglected: a slight underestimate).

Each estimate comes with its standard error (the spread of the per-point terms over
sqrt(n)). Numpy and scipy only.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from vectoradjust.accuracy.tables import truth_vertex_index
from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["from_truth", "from_common_intersections", "identification_estimates",
           "choose_identification", "default_identification", "DEFAULT_PIXELS"]

#: the conservative default identification error: this many pixels on the ground
#: (horizontal; the measured point lies on the terrain, so 0 vertically)
DEFAULT_PIXELS = 10.0
#: an estimate is used when it rests on at least this many points ...
MIN_COUNT = 5

#: two databases' adjusted intersections closer than this (m) are the same intersection
MATCH_RADIUS = 6.0


def _estimate(terms_h: np.ndarray, terms_v: np.ndarray, n: int, source: str,
              scale: float = 1.0) -> dict:
    """sigma_id from per-point variance terms (h: X and Y pooled), with standard errors."""
    def one(terms):
        terms = terms[np.isfinite(terms)]
        if terms.size < 2:
            return None, None
        var = float(terms.mean()) / scale
        se_var = float(terms.std(ddof=1) / np.sqrt(terms.size)) / scale
        sig = float(np.sqrt(max(var, 0.0)))
        # standard error of sigma from that of sigma^2 (delta method; bounded near 0)
        se_sig = se_var / (2.0 * sig) if sig > 0 else float(np.sqrt(se_var))
        return sig, se_sig

    h, se_h = one(terms_h)
    v, se_v = one(terms_v)
    return {"source": source, "count": int(n), "horizontal": h, "horizontal_se": se_h,
            "vertical": v, "vertical_se": se_v}


def _vertex_cov(out: AdjustmentRun, d: DatabaseResult, sel: np.ndarray) -> np.ndarray:
    """Photogrammetric covariance (no identification error) of the selected vertices."""
    return out.result.point_cov[d.vertex_point[sel]]


def from_truth(out: AdjustmentRun, d: DatabaseResult) -> Optional[dict]:
    """sigma_id of a database from its truth table (None without truth)."""
    truth = out.data.truth.get(d.name)
    if truth is None or out.result.point_cov is None:
        return None
    txyz = truth[1]
    ti = truth_vertex_index(out, d)
    sel = (d.vertex_point >= 0) & (ti >= 0)
    if sel.sum() < 2:
        return None
    adj = out.result.xyz[d.vertex_point[sel]]
    e = adj - txyz[ti[sel]]
    c = _vertex_cov(out, d, sel)
    terms_h = np.concatenate([e[:, 0] ** 2 - c[:, 0, 0], e[:, 1] ** 2 - c[:, 1, 1]])
    terms_v = e[:, 2] ** 2 - c[:, 2, 2]
    return _estimate(terms_h, terms_v, int(sel.sum()), "truth")


def _intersections(out: AdjustmentRun, d: DatabaseResult):
    """Bundle point index of the measured object points where two or more features meet."""
    sp = d.shape
    feat = sp.layer.vertex_feature
    obj = sp.vertex_object
    pairs = np.unique(np.column_stack([obj, feat]), axis=0)
    n_feat = np.bincount(pairs[:, 0], minlength=sp.n_objects)
    pts = np.unique(d.vertex_point[(n_feat[obj] >= 2) & (d.vertex_point >= 0)])
    return pts


def from_common_intersections(out: AdjustmentRun, a: DatabaseResult,
                              b: DatabaseResult) -> Optional[dict]:
    """sigma_id common to two databases from their separately measured intersections."""
    if out.result.point_cov is None:
        return None
    pa, pb = _intersections(out, a), _intersections(out, b)
    if len(pa) < 2 or len(pb) < 2:
        return None
    xa, xb = out.result.xyz[pa], out.result.xyz[pb]
    dist_ab, jb = cKDTree(xb[:, :2]).query(xa[:, :2])
    _, ja = cKDTree(xa[:, :2]).query(xb[:, :2])
    mutual = (ja[jb] == np.arange(len(pa))) & (dist_ab <= MATCH_RADIUS)
    mutual &= pa != pb[jb]  # a point shared by both databases is one measurement
    ia, ib = np.flatnonzero(mutual), jb[mutual]
    if len(ia) < 2:
        return None
    dd = xa[ia] - xb[ib]
    c = out.result.point_cov[pa[ia]] + out.result.point_cov[pb[ib]]
    terms_h = np.concatenate([dd[:, 0] ** 2 - c[:, 0, 0], dd[:, 1] ** 2 - c[:, 1, 1]])
    terms_v = dd[:, 2] ** 2 - c[:, 2, 2]
    est = _estimate(terms_h, terms_v, len(ia), f"common intersections {a.name}/{b.name}",
                    scale=2.0)
    est["match_radius"] = MATCH_RADIUS
    return est


def identification_estimates(out: AdjustmentRun) -> dict:
    """Every estimate the run's data allow, per database (truth) and per pair.

    Returns
    -------
    dict
        ``{"databases": {name: estimate}, "pairs": [estimate, ...]}``; an estimate has
        ``horizontal``, ``vertical`` (m), their standard errors, ``count`` and
        ``source``.
    """
    dbs = {}
    for d in out.databases:
        est = from_truth(out, d)
        if est is not None:
            dbs[d.name] = est
    pairs = []
    for i, a in enumerate(out.databases):
        for b in out.databases[i + 1:]:
            est = from_common_intersections(out, a, b)
            if est is not None:
                pairs.append(est)
    return {"databases": dbs, "pairs": pairs}


def _candidates(name: str, estimates: dict) -> list:
    """The estimates that concern database ``name`` (its truth, its pairs)."""
    found = [e for e in [estimates.get("databases", {}).get(name)] if e]
    found += [e for e in estimates.get("pairs", [])
              if name in e["source"].split(" ", 2)[-1].split("/")]
    return [e for e in found if e.get("horizontal") is not None]


def choose_identification(name: str, estimates: dict) -> Optional[dict]:
    """The identification sigma the data determine for database ``name``, or None.

    Among the estimates with at least :data:`MIN_COUNT` points and a standard error
    below half the estimate (or 5 cm), the one with the smallest standard error; the
    value used is the estimate (from truth) or the estimate plus one standard error
    (from common intersections, which run a little low: see the module docstring).

    Returns
    -------
    dict or None
        ``{"horizontal", "vertical", "source", "estimate", "se", "count"}`` (m).
    """
    ok = [e for e in _candidates(name, estimates)
          if e["count"] >= MIN_COUNT and e["horizontal_se"] is not None
          and e["horizontal_se"] < max(0.5 * e["horizontal"], 0.05)]
    if not ok:
        return None
    best = min(ok, key=lambda e: e["horizontal_se"])
    # truth gives an unbiased variance; common intersections neglect the shared exterior
    # orientation and run a little low: one standard error is added to them
    pad = 0.0 if best["source"] == "truth" else 1.0
    h = best["horizontal"] + pad * best["horizontal_se"]
    v = 0.0
    if best.get("vertical") is not None and best.get("vertical_se") is not None \
            and best["vertical_se"] < max(0.5 * best["vertical"], 0.05):
        v = best["vertical"] + pad * best["vertical_se"]
    return {"horizontal": float(h), "vertical": float(v), "source": best["source"],
            "estimate": float(best["horizontal"]), "se": float(best["horizontal_se"]),
            "count": int(best["count"])}


def default_identification(pixel_ground: Optional[float]) -> dict:
    """The conservative default: :data:`DEFAULT_PIXELS` pixels on the ground
    horizontally (``pixel_ground`` m; None: 1 m), 0 vertically."""
    if pixel_ground is None or not np.isfinite(pixel_ground) or pixel_ground <= 0:
        return {"horizontal": 1.0, "vertical": 0.0,
                "source": "default: 1 m (the image scale is not known)"}
    h = DEFAULT_PIXELS * float(pixel_ground)
    return {"horizontal": h, "vertical": 0.0,
            "source": f"default: {DEFAULT_PIXELS:g} pixels of {pixel_ground:.3g} m on the "
                      "ground"}
