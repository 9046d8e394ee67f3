"""The report's long listings: features, shape points, residuals, flagged observations, QA.

Long tables are bounded: above ``MAX_FEATURE_ROWS`` features, ``MAX_FULL_SHAPE_ROWS``
shape points or ``LARGEST_FLAGGED_ROWS`` flagged observations only the largest are listed
and the report says how many were left out (all are in ``adjusted.gpkg`` and the CSVs).
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from vectoradjust.files.report.figures import _img, _Later, residual_histogram_figure
from vectoradjust.files.report.markup import (
    _badge,
    _columns_table,
    _e,
    _fmt,
    _fmt_col,
    _generic,
    _note,
    _records_table,
    _table,
)

__all__ = [
    "MAX_FULL_SHAPE_ROWS",
    "LARGEST_SHAPE_ROWS",
    "LARGEST_FEATURE_ROWS",
    "MAX_FEATURE_ROWS",
    "LARGEST_FLAGGED_ROWS",
]


#: Up to this many vertices (all databases) the shape points table lists every vertex.
MAX_FULL_SHAPE_ROWS = 1000
#: Otherwise it lists the vertices with the largest horizontal residuals.
LARGEST_SHAPE_ROWS = 200
#: Features tables longer than this show the features with the largest RMSE only.
MAX_FEATURE_ROWS = 1000
#: ... that many of them (the others are in the features layer).
LARGEST_FEATURE_ROWS = 200
#: Flagged observations listed in the report (largest |w| first; all in the CSV).
LARGEST_FLAGGED_ROWS = 200


_NAME_KEYS = ("name", "fullname", "full_name", "street", "st_name", "road_name", "label")
_TYPE_KEYS = ("highway", "fclass", "mtfcc", "road_class", "class", "type", "roadtype")


def _name_columns(attributes: dict) -> list:
    """Up to two attribute columns that name or classify the road."""
    low = {str(k).lower(): k for k in attributes}
    out = []
    for cands in (_NAME_KEYS, _TYPE_KEYS):
        hit = next((low[c] for c in cands if c in low), None)
        if hit is None and cands is _NAME_KEYS:
            hit = next((k for lk, k in low.items() if "name" in lk), None)
        if hit is not None and hit not in out:
            out.append(hit)
    return out


def _attr_text(v: Any) -> str:
    """An attribute value as text; None and NaN as '\u2013'."""
    if v is None or (isinstance(v, (float, np.floating)) and not math.isfinite(float(v))):
        return "\u2013"
    return str(v)


def _statement_rows(rows, fids: list) -> dict:
    """The per-feature statements of the features ``fids`` by feature id: only those
    rows are built from :class:`~vectoradjust.accuracy.statements.FeatureStatements`."""
    if hasattr(rows, "index_of"):
        at = rows.index_of(fids).tolist()
        return {f: rows[i] for f, i in zip(fids, at) if i >= 0}
    return {r["feature_id"]: r for r in rows}


def _features_body(run, acc: Optional[dict], prefix: str) -> str:
    parts = []
    feats_acc = (acc or {}).get("features") or {}
    for d in run.databases:
        f = d.features
        layer = d.shape.layer
        nf = layer.n_features
        if not nf:
            continue
        names = _name_columns(layer.attributes)
        order = np.arange(nf)
        note = ""
        if nf > MAX_FEATURE_ROWS:
            rm = np.nan_to_num(np.asarray(f["RMSE"], float), nan=-1.0)
            order = np.argsort(-rm, kind="stable")[:LARGEST_FEATURE_ROWS]
            note = _note(f"{nf} features: the {LARGEST_FEATURE_ROWS} with the largest RMSE are "
                         f"listed ({nf - LARGEST_FEATURE_ROWS} left out); all are in the "
                         "features layer of adjusted.gpkg and their accuracy statements in "
                         "feature_accuracy.csv.")
        cols = [layer.feature_ids[order].tolist()]
        heads = ["feature"]
        for k in names:
            vals = layer.attributes[k]
            cols.append([_attr_text(vals[i]) for i in order.tolist()])
            heads.append(str(k))
        for key, head, nd in (("NPts", "NPts", None), ("NAdj", "NAdj", None),
                              ("RMSE_X", "RMSE X (m)", 3), ("RMSE_Y", "RMSE Y (m)", 3),
                              ("RMSE_Z", "RMSE Z (m)", 3), ("RMSE", "RMSE horiz. (m)", 3),
                              ("Length", "length (m)", 1)):
            a = np.asarray(f[key])[order]
            cols.append(_fmt_col(a) if nd is None else _fmt_col(a.astype(float), nd))
            heads.append(head)
        fids = layer.feature_ids[order].tolist()
        arow = _statement_rows(feats_acc.get(d.name, []), fids)
        ce, ce_f, bias = [], [], []
        for fid in fids:
            r = arow.get(fid)
            ag = (r or {}).get("ager") or {}
            ce.append(_fmt(ag.get("ce90_exact")))
            ce_f.append(_fmt(ag.get("ce90_formula")))
            bias.append((r or {}).get("bias_text") or "\u2013")
        cols += [ce, ce_f, bias]
        heads += ["CE90 exact (m)", "CE90 Ager (m)", "bias (database \u2212 adjusted)"]
        for key, head in (("Images", "images"), ("Problem", "problem")):
            if key in f:
                cols.append([str(x) if x not in (None, "") else "\u2013"
                             for x in np.asarray(f[key], dtype=object)[order].tolist()])
                heads.append(head)
        rows = [list(r) for r in zip(*cols)]
        parts.append(f"<h3>{_e(d.name)}: {nf} features</h3>")
        parts.append(note)
        parts.append('<div class="scroll">' + _table(heads, rows,
                                                     ident=f"{prefix}features-{d.name}")
                     + "</div>")
    if not parts:
        return _note("(no features)")
    n_min = (acc or {}).get("min_feature_vertices")
    head = _note("RMSE of the residuals V over the adjusted vertices of each feature; CE90 "
                 "with bias (exact and Ager's formula) and bias of database \u2212 adjusted "
                 + (f"for features with at least {n_min} adjusted vertices." if n_min else "."))
    return head + "".join(parts)


_SHAPE_COLS = [("Database", "database", None), ("point_id", "point", None),
               ("feature_id", "feature", None), ("X", "X (m)", 3), ("Y", "Y (m)", 3),
               ("Z", "Z (m)", 3), ("Vx", "Vx (m)", 3), ("Vy", "Vy (m)", 3), ("Vz", "Vz (m)", 3),
               ("Vh", "|V| horiz. (m)", 3), ("SigmaX", "\u03c3X (m)", 3),
               ("SigmaY", "\u03c3Y (m)", 3), ("SigmaZ", "\u03c3Z (m)", 3),
               ("CE90", "CE90 (m)", 3), ("LE90", "LE90 (m)", 3), ("NImages", "images", None),
               ("Adjusted", "adjusted", None)]


def _shape_body(run, prefix: str) -> str:
    dbs = [d for d in run.databases if d.vertices]
    if not dbs:
        return _note("(no shape points)")
    def column(k):
        return np.concatenate([np.asarray(d.vertices[k], float) for d in dbs])

    vh = np.hypot(column("Vx"), column("Vy"))
    n = len(vh)
    n_adj = int(sum(np.sum(np.asarray(d.vertices["Adjusted"]) == 1) for d in dbs))
    if n <= MAX_FULL_SHAPE_ROWS:
        order = np.arange(n)
        note = _note(f"All {n} vertices ({n_adj} adjusted). V = adjusted \u2212 database; "
                     "unmeasured vertices are not adjusted (\u2013).")
    else:
        vh = np.where(np.isfinite(vh), vh, -1.0)
        k = min(LARGEST_SHAPE_ROWS, n)
        top = np.argpartition(-vh, k - 1)[:k]
        order = top[np.argsort(-vh[top], kind="stable")]
        note = _note(f"{n} vertices ({n_adj} adjusted): the {k} with the largest horizontal "
                     "residual are listed; every vertex is in the shape_points layer of "
                     "adjusted.gpkg.")
    # only the listed rows are gathered (not every column of a million vertices)
    ends = np.cumsum([len(d.vertices["X"]) for d in dbs])
    which = np.searchsorted(ends, order, side="right")
    local = order - np.concatenate([[0], ends[:-1]])[which]
    cols = {"Vh": np.where(vh[order] >= 0, vh[order], np.nan)}
    for k in (k for k, _, _ in _SHAPE_COLS if k != "Vh"):
        parts = [np.asarray(d.vertices[k])[local[which == i]] if k in d.vertices else
                 np.full(int(np.sum(which == i)), d.name, dtype=object)
                 for i, d in enumerate(dbs)]
        gathered = np.concatenate(parts)
        cols[k] = np.empty(len(order), gathered.dtype)
        cols[k][np.argsort(which, kind="stable")] = gathered
    m = len(order)
    return note + '<div class="scroll">' + _columns_table(
        cols, _SHAPE_COLS, np.ones(m, bool), ident=f"{prefix}shape-table",
        order=np.arange(m)) + "</div>"


def _flagged_list(run, reliability) -> Optional[list]:
    """Flagged observations from the reliability argument or the summary; None if absent."""
    if reliability is not None:
        if isinstance(reliability, (list, tuple)):
            return list(reliability)
        if isinstance(reliability, dict) and "flagged" in reliability:
            return list(reliability["flagged"] or [])
        fl = getattr(reliability, "flagged", None)
        if fl is not None and not callable(fl):
            return list(fl)
        if hasattr(reliability, "flag_image"):  # a vectoradjust.adjust.reliability.Reliability
            try:
                from vectoradjust.adjust.reliability import flagged_observations
            except ImportError:  # pragma: no cover - module not installed
                flagged_observations = None
            if flagged_observations is not None:
                return flagged_observations(reliability, run.result, run.point_ids,
                                            run.image_ids, run.point_kind)
    rel = (run.summary or {}).get("reliability")
    if isinstance(rel, dict):
        return list(rel.get("flagged") or [])
    return None


def _residuals_body(run, reliability) -> str:
    out = [_img(_Later(("histogram", id(run), id(reliability)),
                       lambda: residual_histogram_figure(run, reliability)),
                "standardized residuals",
                "Image coordinate residuals v (adjusted \u2212 observed) divided by their "
                "a-priori \u03c3, x and y pooled, with the standard normal density; v/\u03c3 "
                "has variance \u03c3\u2080\u00b2 r\u1d62 (redundancy number r\u1d62 < 1), so "
                "it is narrower than N(0, 1). The w-tests (when computed) are N(0, 1) under "
                "the null hypothesis.")]
    v = np.asarray(run.result.v_image, float) * 1000.0
    if v.size:
        rms = np.sqrt(np.nanmean(v**2, axis=0))
        out.append(_note(f"RMS of the image residuals: x {rms[0]:.2f} \u00b5m, y "
                         f"{rms[1]:.2f} \u00b5m over {len(v)} measurements; largest |v| "
                         f"{np.nanmax(np.abs(v)):.2f} \u00b5m."))
    return "".join(out)


def _flagged_body(run, reliability, prefix: str = "") -> str:
    flagged = _flagged_list(run, reliability)
    if flagged is None:
        return _note("Reliability analysis (w-tests, flagged observations): not computed.")
    if not flagged:
        return _note("No observation is flagged by the w-test.")
    text = f"{len(flagged)} observation(s) flagged by the w-test, largest |w| first."
    if len(flagged) > LARGEST_FLAGGED_ROWS:  # bounded: all of them are in the CSV
        left = len(flagged) - LARGEST_FLAGGED_ROWS
        text += (f" The first {LARGEST_FLAGGED_ROWS} are listed ({left} left out); all are in "
                 "flagged_observations.csv.")
        flagged = flagged[:LARGEST_FLAGGED_ROWS]
    return (_note(text) + '<div class="scroll">'
            + _records_table(flagged, ident=f"{prefix}flagged-table") + "</div>")


def _qa_body(qa: Any) -> str:
    if hasattr(qa, "as_dict"):
        qa = qa.as_dict()
    if not isinstance(qa, dict):
        return _generic(qa)
    out = []
    passed = qa.get("passed")
    if passed is None and isinstance(qa.get("verdict"), str):
        passed = {"pass": True, "fail": False}.get(qa["verdict"].lower())
    if "passed" in qa or "verdict" in qa:
        cls = "na" if passed is None else ("pass" if passed else "fail")
        out.append(f'<div class="verdict {cls}">{_badge(passed, "accepted", "REJECTED")} '
                   f"QA verdict: {_e(qa.get('verdict', ''))}</div>")
    from vectoradjust.qa.verdict import production_rows

    # the production checks as compact tables (zones, inter-strip ties, free model);
    # their full detail (point ids per zone, overlap polygons) is in qa.json
    for title, rows in production_rows(qa):
        out.append(f"<h4>{_e(title)}</h4>" + _records_table(rows))
    skip = ("passed", "verdict", "tie_zones", "triplet_zones", "inter_strip", "free_model")
    out.append(_generic({k: v for k, v in qa.items() if k not in skip}))
    return "".join(out)
