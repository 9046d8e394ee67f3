"""Accuracy statements of an adjustment: per road database, per feature, for check points.

:func:`accuracy_statements` turns an :class:`~vectoradjust.pipeline.AdjustmentRun`
into JSON-ready accuracy statements built with the functions of
:mod:`vectoradjust.accuracy.stats` (docs/method.md section 4): the bias (mean error) and its
direction, Ager's CE90/LE90 with bias (the piecewise formula and the exact numeric value side by
side), NSSDA at 95 % and ASPRS 2023 RMSE_H / RMSE_V / RMSE_3D with their statement
text.

What is tested against what
---------------------------
* **Road databases and features**: the errors are ``e = database - adjusted =
  -V`` at the adjusted (measured) vertices, i.e. the adjusted positions play the part
  of the checkpoints and the statements describe the accuracy of the *database*. The
  residuals ``V = adjusted - database`` of the outputs are the same numbers with the
  opposite sign: ``residual_bias`` holds ``mean(V)``, the direction text describes
  ``mean(e) = -mean(V)`` ("the database lies 14.0 m towards south-east of the
  adjusted positions"). Every vertex row counts (a vertex shared by two features
  counts twice, as in ``summary.json``). The adjusted positions are not error-free:
  their a-posteriori precision (RMS of the per-point sigmas) is reported as
  ``reference_rmse_h`` / ``reference_rmse_v`` and, as ASPRS 2023 prescribes for the
  checkpoints' own accuracy, added in quadrature in the ASPRS block only. The vertical
  statements describe the Z used in the adjustment (sampled from the DEM when the
  ``[[vectors]]`` entry names one).
* **Check points**: ``e = adjusted - surveyed`` (the check point intersected from the
  adjusted images minus its surveyed coordinates, the ``Vx, Vy, Vz`` of the
  ``control_points`` layer); the statements describe the accuracy of the
  photogrammetric block. The survey sigmas of the check points are the ASPRS
  checkpoint accuracy.

Bias, ``mu = |mean horizontal error|`` and ``sigma_c = (sqrt(l1) + sqrt(l2)) / 2``
(eigenvalues of the sample covariance, ``ddof = 1``) are those of
:func:`vectoradjust.accuracy.stats.absolute_accuracy`; per feature the same quantities are
computed for all features at once (vectorised) and agree with that function.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from vectoradjust.accuracy import stats
from vectoradjust.formatting import float_or_none as _num

__all__ = ["accuracy_statements", "ager_ce90_rule", "ager_le90_rule", "MIN_FEATURE_VERTICES",
           "FeatureStatements"]

#: Default minimum number of adjusted vertices for a feature to get a statement.
MIN_FEATURE_VERTICES = 5

_NSSDA_H = 1.7308
_NSSDA_V = 1.9600
_NSSDA_GS = 2.4477


def _clean(obj):
    """Recursively replace NaN/inf by None and numpy scalars by Python ones."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num(obj)
    return obj


def ager_ce90_rule(mu: float, sigma_c: float) -> str:
    """The branch of Ager's CE90 formula that applies, as text.

    Parameters
    ----------
    mu : float
        Length of the horizontal bias.
    sigma_c : float
        Circular standard deviation.

    Returns
    -------
    str
        E.g. ``"mu/sigma_c = 0.05 <= 0.1: CE90 = 2.1460 sigma_c"``; ``""`` when
        undefined.
    """
    if mu is None or sigma_c is None or not (math.isfinite(mu) and math.isfinite(sigma_c)):
        return ""
    k = mu / sigma_c if sigma_c > 0 else (math.inf if mu > 0 else 0.0)
    if k <= 0.1:
        return f"mu/sigma_c = {k:.3g} <= 0.1: CE90 = 2.1460 sigma_c"
    if k <= 3.0:
        return (f"mu/sigma_c = {k:.3g} <= 3: CE90 = 2.1272 sigma_c + 0.1674 mu + "
                "0.3623 mu^2/sigma_c - 0.0550 mu^3/sigma_c^2")
    return f"mu/sigma_c = {k:.3g} > 3: CE90 = 0.9860 mu + 1.4548 sigma_c"


def ager_le90_rule(mu: float, sigma: float) -> str:
    """The branch of Ager's LE90 formula that applies, as text.

    Parameters
    ----------
    mu : float
        Vertical bias.
    sigma : float
        Vertical standard deviation.

    Returns
    -------
    str
        ``""`` when undefined.
    """
    if mu is None or sigma is None or not (math.isfinite(mu) and math.isfinite(sigma)):
        return ""
    m = abs(mu)
    k = m / sigma if sigma > 0 else (math.inf if m > 0 else 0.0)
    if k <= 1.4:
        return (f"|mu|/sigma = {k:.3g} <= 1.4: LE90 = |mu| + sigma (1.6435 - 0.999556 k + "
                "0.923237 k^2 - 0.282533 k^3)")
    return f"|mu|/sigma = {k:.3g} > 1.4: LE90 = |mu| + 1.2815 sigma"


def _decimals(magnitude) -> int:
    """Decimals for a length in metres: 1 from 10 m, 2 from 0.1 m, else 3."""
    m = _num(magnitude)
    if m is None or m >= 10.0:
        return 1
    return 2 if m >= 0.1 else 3


def _bias_text(mx: float, my: float) -> str:
    """:func:`vectoradjust.accuracy.stats.bias_statement` with decimals suited to the length."""
    return stats.bias_statement(mx, my, decimals=_decimals(math.hypot(mx, my)))


def _rms(a: np.ndarray) -> Optional[float]:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else None


def _statement_block(errors: np.ndarray, ref_sigma: Optional[np.ndarray], *,
                     what: str, reference: str) -> dict[str, Any]:
    """Bias, Ager, NSSDA and ASPRS 2023 of one set of errors (n, 3).

    ``ref_sigma`` (n, 3): standard deviations of the reference positions (the
    ASPRS checkpoint accuracy), or None.
    """
    e = np.asarray(errors, float).reshape(-1, 3)
    ok = np.isfinite(e).all(axis=1)
    e = e[ok]
    aa = stats.absolute_accuracy(e)
    d = aa.as_dict()
    ref_h = ref_v = None
    if ref_sigma is not None and len(e):
        rs = np.asarray(ref_sigma, float).reshape(-1, 3)[ok]
        ref_h = _rms(np.sqrt(rs[:, 0] ** 2 + rs[:, 1] ** 2))
        ref_v = _rms(rs[:, 2])
    ns = stats.nssda(d["rmse_x"], d["rmse_y"], d["rmse_z"])
    if ns["rmse_r"] is not None:
        ns["horizontal_95_1_7308_rmse_r"] = _NSSDA_H * ns["rmse_r"]
    asprs = stats.asprs2023(e[:, 0], e[:, 1], e[:, 2], survey_rmse_h=ref_h,
                            survey_rmse_v=ref_v)
    asprs["survey_rmse_h"] = ref_h
    asprs["survey_rmse_v"] = ref_v
    rh_data, rv_data = d["rmse_horizontal"], d["rmse_z"]
    asprs["rmse_h_data"] = rh_data
    asprs["rmse_v_data"] = rv_data
    return {
        "count": aa.count,
        "errors": what,
        "reference": reference,
        "mean_error": {"x": d["mean_x"], "y": d["mean_y"], "z": d["mean_z"]},
        "bias": {
            "magnitude": d["bias_magnitude"], "azimuth": d["bias_azimuth"],
            "direction": aa.bias_direction, "text": _bias_text(aa.mean_x, aa.mean_y),
        },
        "rmse": {"x": d["rmse_x"], "y": d["rmse_y"], "z": d["rmse_z"],
                 "horizontal": d["rmse_horizontal"]},
        "ager": {
            "mu": d["mu"], "sigma_c": d["sigma_c"], "sigma_x": d["sigma_x"],
            "sigma_y": d["sigma_y"], "cov_xy": d["cov_xy"], "sigma_z": d["sigma_z"],
            "ce90_exact": d["ce90_exact"], "ce90_formula": d["ce90_formula"],
            "ce90_rule": ager_ce90_rule(aa.mu, aa.sigma_c),
            "le90_exact": d["le90_exact"], "le90_formula": d["le90_formula"],
            "le90_rule": ager_le90_rule(aa.mean_z, aa.sigma_z),
        },
        "nssda": ns,
        "asprs2023": asprs,
        "reference_rmse_h": ref_h,
        "reference_rmse_v": ref_v,
    }


def _database_block(run, d, truth_xyz: Optional[np.ndarray]) -> dict[str, Any]:
    from vectoradjust.accuracy.tables import one_vertex_per_point

    v = d.vertices
    # each object point once (a shared intersection vertex is one point), as the summary
    adj = one_vertex_per_point(d.vertex_point)
    vv = np.column_stack([v["Vx"], v["Vy"], v["Vz"]])[adj].astype(float)
    sig = np.column_stack([v["SigmaX"], v["SigmaY"], v["SigmaZ"]])[adj].astype(float)
    block = _statement_block(-vv, sig, what="database - adjusted (= -V)",
                             reference="adjusted shape points")
    mean_v = vv.mean(axis=0) if len(vv) else np.full(3, np.nan)
    block["residual_bias"] = {"vx": _num(mean_v[0]), "vy": _num(mean_v[1]),
                              "vz": _num(mean_v[2])}
    btxt = block["bias"]["text"]
    if block["bias"]["direction"] not in ("", "none"):
        block["bias"]["statement"] = (f"{d.name}: on average the database lies {btxt} of "
                                      "the adjusted positions")
    else:
        block["bias"]["statement"] = f"{d.name}: {btxt}"
    out = {"name": d.name, "vertices": int(len(adj)), **block}
    out["truth"] = None
    if truth_xyz is not None:
        t = truth_xyz[adj]
        db = np.column_stack([v["X"], v["Y"], v["Z"]])[adj].astype(float)
        ok = np.isfinite(t).all(axis=1)
        if ok.any():
            aa = stats.absolute_accuracy(db[ok] - t[ok])
            out["truth"] = {
                "count": aa.count, "errors": "database - truth",
                "mean_error": {"x": aa.mean_x, "y": aa.mean_y, "z": aa.mean_z},
                "bias_text": _bias_text(aa.mean_x, aa.mean_y), "ce90_exact": aa.ce90_exact,
                "ce90_formula": aa.ce90_formula, "le90_exact": aa.le90_exact,
                "rmse_horizontal": aa.rmse_horizontal, "rmse_z": aa.rmse_z,
            }
    return out


def _truth_for(run, d) -> Optional[np.ndarray]:
    """True XYZ of every vertex of database ``d`` (NaN where unknown), or None."""
    truth = getattr(run.data, "truth", None) or {}
    t = truth.get(d.name)
    if t is None:
        return None
    from vectoradjust.accuracy.tables import truth_vertex_index

    txyz = t[1]
    idx = truth_vertex_index(run, d)
    out = np.full((len(idx), 3), np.nan)
    out[idx >= 0] = np.asarray(txyz, float)[idx[idx >= 0]]
    return out


def _feature_rows(d, min_vertices: int) -> Any:
    """Per-feature statements of one database, vectorised over features."""
    v = d.vertices
    layer = d.shape.layer
    nf = layer.n_features
    adj = (np.asarray(v["Adjusted"]) == 1)
    vv = np.column_stack([v["Vx"], v["Vy"], v["Vz"]]).astype(float)
    adj &= np.isfinite(vv).all(axis=1)
    fi = np.asarray(layer.vertex_feature)[adj]
    e = -vv[adj]  # database - adjusted
    sig = np.column_stack([v["SigmaX"], v["SigmaY"], v["SigmaZ"]]).astype(float)[adj]
    n = np.bincount(fi, minlength=nf).astype(float)
    keep = np.flatnonzero(n >= max(int(min_vertices), 2))
    if keep.size == 0:
        return []

    def gsum(w):
        return np.bincount(fi, weights=w, minlength=nf)

    mean = np.stack([gsum(e[:, a]) for a in range(3)], axis=1) / np.maximum(n, 1)[:, None]
    ms = np.stack([gsum(e[:, a] ** 2) for a in range(3)], axis=1) / np.maximum(n, 1)[:, None]
    r = np.sqrt(ms)
    c = e - mean[fi]
    den = np.maximum(n - 1, 1)
    cov = np.empty((nf, 2, 2))
    cov[:, 0, 0] = gsum(c[:, 0] ** 2) / den
    cov[:, 1, 1] = gsum(c[:, 1] ** 2) / den
    cov[:, 0, 1] = cov[:, 1, 0] = gsum(c[:, 0] * c[:, 1]) / den
    sz = np.sqrt(gsum(c[:, 2] ** 2) / den)
    ref_h = np.sqrt(gsum(sig[:, 0] ** 2 + sig[:, 1] ** 2) / np.maximum(n, 1))
    ref_v = np.sqrt(gsum(sig[:, 2] ** 2) / np.maximum(n, 1))
    # restrict to the features that get a statement
    mean, r, cov, sz, n, ref_h, ref_v = (a[keep] for a in (mean, r, cov, sz, n, ref_h, ref_v))
    mu = np.hypot(mean[:, 0], mean[:, 1])
    smax, smin, _ = stats.principal_axes(cov)
    sigma_c = 0.5 * (smax + smin)
    ce_exact = np.atleast_1d(stats.ce90_exact(cov, mean[:, :2]))
    ce_form = np.atleast_1d(stats.ager_ce90(mu, sigma_c))
    le_exact = np.atleast_1d(stats.le90(sz, mean[:, 2]))
    le_form = np.atleast_1d(stats.ager_le90(mean[:, 2], sz))
    rh = np.hypot(r[:, 0], r[:, 1])
    # NSSDA 95 % horizontal, the rule of stats.nssda applied to every feature at once
    big = np.maximum(r[:, 0], r[:, 1])
    small = np.minimum(r[:, 0], r[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(big > 0, small / big, 1.0)
    diag = np.zeros((len(keep), 2, 2))
    diag[:, 0, 0] = r[:, 0] ** 2
    diag[:, 1, 1] = r[:, 1] ** 2
    low = ratio <= 0.6
    exact95 = np.full(len(keep), np.nan)
    if low.any():
        exact95[low] = np.atleast_1d(stats.circular_error(diag[low], None, 0.95))
    h95 = np.where(ratio >= 1.0 - 1e-9, _NSSDA_H * rh,
                   np.where(ratio > 0.6, _NSSDA_GS * 0.5 * (r[:, 0] + r[:, 1]), exact95))
    v95 = _NSSDA_V * r[:, 2]
    asprs_h = np.hypot(rh, ref_h)
    asprs_v = np.hypot(r[:, 2], ref_v)
    cols = (mean[:, 0], mean[:, 1], mean[:, 2], r[:, 0], r[:, 1], r[:, 2], rh, mu, sigma_c,
            ce_exact, ce_form, sz, le_exact, le_form, h95, v95, asprs_h, asprs_v,
            np.hypot(asprs_h, asprs_v))
    return _feature_dicts(layer.feature_ids[keep], n, mean, cols)


#: the per-feature statement's keys, nested as in its dict, with the flat column of each
_FEATURE_LAYOUT = (
    ("feature_id", None), ("count", None),
    ("mean_error", ("x", "y", "z")), ("residual_bias", ("vx", "vy", "vz")),
    ("bias_text", None), ("rmse", ("x", "y", "z", "horizontal")),
    ("ager", ("mu", "sigma_c", "ce90_exact", "ce90_formula", "sigma_z", "le90_exact",
              "le90_formula")),
    ("nssda", ("horizontal_95", "vertical_95")), ("asprs2023", ("rmse_h", "rmse_v", "rmse_3d")),
)


class FeatureStatements(list):
    """The per-feature accuracy statements of one database: a list of dicts that also
    keeps the columns it was built from.

    Each row is ``feature_id, count, mean_error {x, y, z}, residual_bias {vx, vy, vz},
    bias_text, rmse {x, y, z, horizontal}, ager {...}, nssda {...}, asprs2023 {...}``
    (JSON-ready: numbers that are not finite as None). The writers take the columns
    (:meth:`columns`) instead of gathering them again from 125 000 dicts (10^6 shape
    points).

    Parameters
    ----------
    columns : dict of str to numpy.ndarray
        The flat columns (nested keys joined with ``_``, e.g. ``ager_ce90_exact``), in the
        order of a row's keys; ``feature_id`` and ``bias_text`` text, ``count`` integers,
        the others floats (NaN where undefined).
    """

    def __init__(self, columns: dict) -> None:
        self._cols = dict(columns)
        names = [key if sub is None else f"{key}_{k}" for key, sub in _FEATURE_LAYOUT
                 for k in (sub or (None,))]
        lists = [_finite_list(c) if np.asarray(c).dtype.kind == "f" else np.asarray(c).tolist()
                 for c in (self._cols[k] for k in names)]
        super().__init__(
            {"feature_id": fid, "count": cnt,
             "mean_error": {"x": mx, "y": my, "z": mz},
             "residual_bias": {"vx": vx, "vy": vy, "vz": vz},
             "bias_text": text,
             "rmse": {"x": rx, "y": ry, "z": rz, "horizontal": rh},
             "ager": {"mu": mu, "sigma_c": sc, "ce90_exact": cex, "ce90_formula": cfo,
                      "sigma_z": sz, "le90_exact": lex, "le90_formula": lfo},
             "nssda": {"horizontal_95": h95, "vertical_95": v95},
             "asprs2023": {"rmse_h": ah, "rmse_v": av, "rmse_3d": a3}}
            for (fid, cnt, mx, my, mz, vx, vy, vz, text, rx, ry, rz, rh, mu, sc, cex, cfo, sz,
                 lex, lfo, h95, v95, ah, av, a3) in zip(*lists))

    def columns(self) -> dict:
        """The flat columns the rows were built from (name to array, in the order of a
        row's keys; a copy of the dict, the arrays shared)."""
        return dict(self._cols)

    def index_of(self, feature_ids) -> np.ndarray:
        """Row of each feature id (-1 where the feature has no statement)."""
        from vectoradjust.adjust.shapepoints import lookup

        return lookup(self._cols.get("feature_id", np.zeros(0, str)), feature_ids)


def _finite_list(a) -> list:
    """A float array as a list of Python floats, None where not finite."""
    a = np.asarray(a, float)
    out = a.tolist()
    for j in np.flatnonzero(~np.isfinite(a)).tolist():
        out[j] = None
    return out


def _feature_dicts(fids, n, mean, cols) -> FeatureStatements:
    """The per-feature statements from their columns (:func:`_feature_rows`): ``cols`` =
    mean error x, y, z, then the rmse, ager, nssda and asprs2023 values in row order."""
    out = {"feature_id": np.asarray(fids).astype(str).astype(object),
           "count": np.asarray(n).astype(np.int64)}
    for a, k in enumerate("xyz"):
        out[f"mean_error_{k}"] = np.asarray(cols[a], float)
    for a, k in enumerate(("vx", "vy", "vz")):
        out[f"residual_bias_{k}"] = -np.asarray(mean[:, a], float)
    out["bias_text"] = np.asarray(
        [_bias_text(x, y) for x, y in zip(mean[:, 0].tolist(), mean[:, 1].tolist())], object)
    names = [f"{key}_{k}" for key, sub in _FEATURE_LAYOUT[5:] for k in sub]
    out.update(zip(names, (np.asarray(c, float) for c in cols[3:])))
    return FeatureStatements(out)


def _check_point_block(run) -> Optional[dict]:
    """The statement block of adjusted - surveyed at the used check points (with the
    surveyed sigmas as the reference's), or None when no check point was intersected."""
    cp = run.control_points
    if not (cp and len(cp.get("point_id", []))):
        return None
    chk = (np.asarray(cp["role"]) == "check") & (np.asarray(cp["Used"]) == 1)
    if not chk.any():
        return None
    e = np.column_stack([cp["Vx"], cp["Vy"], cp["Vz"]]).astype(float)[chk]
    ctrl = run.data.control
    if ctrl.cov is not None:
        sig = np.sqrt(np.einsum("nii->ni", np.asarray(ctrl.cov, float)))[chk]
    else:
        sig = np.asarray(ctrl.sigma, float)[chk]
    block = _statement_block(e, sig, what="adjusted - surveyed",
                             reference="surveyed check points")
    block["point_ids"] = [str(p) for p in np.asarray(cp["point_id"])[chk]]
    btxt = block["bias"]["text"]
    block["bias"]["statement"] = (
        f"check points: on average the adjusted block lies {btxt} of the survey"
        if block["bias"]["direction"] not in ("", "none") else
        f"check points: {btxt}")
    return _clean(block)


def accuracy_statements(run, *, min_feature_vertices: int = MIN_FEATURE_VERTICES) -> dict:
    """Accuracy statements of an adjustment, JSON-ready.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
        A finished adjustment.
    min_feature_vertices : int, optional
        Features with fewer adjusted vertices get no statement (default 5; at least 2
        are needed for a covariance).

    Returns
    -------
    dict
        ``{"definitions", "databases", "features", "check_points",
        "min_feature_vertices"}``:

        * ``databases``: one dict per road database with ``name, vertices, count``,
          ``residual_bias {vx, vy, vz}`` (mean V of the adjusted vertices),
          ``mean_error {x, y, z}`` (= -residual_bias, database - adjusted),
          ``bias {magnitude, azimuth, direction, text, statement}``,
          ``rmse {x, y, z, horizontal}``, ``ager {mu, sigma_c, sigma_x, sigma_y,
          cov_xy, sigma_z, ce90_exact, ce90_formula, ce90_rule, le90_exact,
          le90_formula, le90_rule}``, ``nssda`` (:func:`vectoradjust.accuracy.stats.nssda`
          plus ``horizontal_95_1_7308_rmse_r``), ``asprs2023``
          (:func:`vectoradjust.accuracy.stats.asprs2023` with the adjusted points' precision
          as survey accuracy, plus ``rmse_h_data, rmse_v_data, survey_rmse_h,
          survey_rmse_v``), ``reference_rmse_h/v`` and ``truth`` (database - truth
          statistics when the project carries truth, else None).
        * ``features``: per database name, the per-feature rows as a
          :class:`FeatureStatements` (a sequence of dicts ``feature_id, count,
          mean_error, residual_bias, bias_text, rmse, ager, nssda {horizontal_95,
          vertical_95}, asprs2023 {rmse_h, rmse_v, rmse_3d}``) for features with at
          least ``min_feature_vertices`` adjusted vertices (an empty list when none).
        * ``check_points``: the same block as a database for adjusted - surveyed at
          the check points, or None when no check point was intersected.

        Undefined numbers are None.
    """
    dbs = []
    feats: dict[str, list] = {}
    for d in run.databases:
        dbs.append(_clean(_database_block(run, d, _truth_for(run, d))))
        feats[d.name] = _feature_rows(d, min_feature_vertices)
    chk_block = _check_point_block(run)
    return {
        "definitions": {
            "databases": "errors = database - adjusted (= -V) at the adjusted vertices; "
                         "the adjusted positions are the reference",
            "features": "as databases, per feature with at least "
                        f"{int(min_feature_vertices)} adjusted vertices",
            "check_points": "errors = adjusted (intersected) - surveyed",
            "ager": "CE90/LE90 with bias: formula (Ager, NIMA) and exact numeric value",
            "nssda": "NSSDA 95 %: 1.7308 RMSE_r (RMSE_x = RMSE_y), 2.4477 * 0.5 (RMSE_x + "
                     "RMSE_y) for 0.6 < ratio < 1, exact 95 % circle otherwise; 1.9600 RMSE_z",
            "asprs2023": "RMSE_H, RMSE_V, RMSE_3D with the reference accuracy added in "
                         "quadrature",
        },
        "databases": dbs,
        "features": feats,
        "check_points": chk_block,
        "min_feature_vertices": int(min_feature_vertices),
    }
