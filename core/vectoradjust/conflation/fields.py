"""The trend (the database's systematic offset) and the horizontal and vertical fields of a
run's database: fit, predict, cross-validate, write the conflated vertices.

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from vectoradjust.conflation.covariance import CovarianceModel, fit_covariance
from vectoradjust.conflation.kriging import _cv_stats, _krige_many
from vectoradjust.conflation.settings import CE90_CIRCULAR, LE90, ConflationSettings

__all__ = []


# --------------------------------------------------------------------------- a run
@dataclass
class _Trend:
    """The trend at the object points and what its error is made of.

    ``t`` (n, 3) the trend; ``g`` (n, 3, q) its design in the estimated parameters (the
    database offset's, then one per applied mean) and ``c`` (q, q) their covariance, so
    that the trend's error is ``g dT``; ``fixed`` (3,) the variance no prediction
    reduces (a mean not applied stays in every vertex); ``covered`` (3,) the axes of
    the offset model; ``mean`` and ``mean_var`` (3,) the applied means and their
    variances (0 elsewhere).
    """

    t: np.ndarray
    g: np.ndarray
    c: np.ndarray
    fixed: np.ndarray
    covered: np.ndarray
    mean: np.ndarray
    mean_var: np.ndarray

    def cov(self, sel=slice(None)) -> np.ndarray:
        """Covariance (n, 3, 3) of the trend alone (no field) at the points ``sel``."""
        g = self.g[sel]
        return np.einsum("niq,qr,njr->nij", g, self.c, g) + np.diag(self.fixed)


def _trend_design(rec: Optional[dict], xyz: np.ndarray, mean: np.ndarray,
                  mean_var: np.ndarray):
    """``t``, ``g``, ``c`` of :class:`_Trend` at ``xyz``: the offset's ``-G(x) T`` and
    the means of the axes ``mean_var > 0``."""
    from vectoradjust.adjust.offsets import _kind_design

    n = len(xyz)
    t = np.zeros((n, 3))
    gs, cs = [np.zeros((n, 3, 0))], []
    if rec is not None:
        g = _kind_design(rec["kind"], xyz, np.asarray(rec["center"], float))
        t = -np.einsum("niq,q->ni", g, np.asarray(rec["values"], float))
        gs.append(g)
        cs.append(np.asarray(rec["cofactor"], float) * float(rec["variance_factor"]))
    for a in np.flatnonzero(np.asarray(mean_var) > 0):
        t[:, a] = mean[a]
        col = np.zeros((n, 3, 1))
        col[:, a, 0] = 1.0
        gs.append(col)
        cs.append(np.array([[float(mean_var[a])]]))
    g = np.concatenate(gs, axis=2)
    c = np.zeros((g.shape[2], g.shape[2]))
    i = 0
    for b in cs:
        c[i:i + len(b), i:i + len(b)] = b
        i += len(b)
    return t, g, c


def _trend(rec: Optional[dict], db_xyz: np.ndarray, dm: np.ndarray, common: np.ndarray,
           mean_var: Optional[np.ndarray] = None) -> _Trend:
    """The trend at every object point (:class:`_Trend`).

    ``-G(x) T`` of the estimated offset (database minus images, so the displacement is
    its negative); axes the offset model does not cover get the measured points' mean
    ``m`` where it differs from zero by more than 1.96 times the larger of its scatter's
    standard error and ``sqrt(common)`` (3,), the adjusted points' mean variance: a
    common height error of a stereo model, larger than its covariance says when the
    adjustment is strained, must not move good database heights (DEM heights). Its
    variance is ``mean_var`` (3,; default ``common``), the variance of the points' mean
    (:func:`_mean_variance`), at least the scatter's; where the mean is not applied, the
    vertex keeps an error of about ``m``, so its variance is ``m^2 + mean_var``, and no
    prediction removes it (``fixed``).
    """
    g0 = np.zeros((1, 3, 0))
    if rec is not None:
        from vectoradjust.adjust.offsets import _kind_design

        g0 = _kind_design(rec["kind"], db_xyz[:1], np.asarray(rec["center"], float))
    covered = np.abs(g0).sum(axis=(0, 2)) > 0 if len(db_xyz) else np.zeros(3, bool)
    mean_var = common if mean_var is None else mean_var
    mean, applied_var, fixed = np.zeros(3), np.zeros(3), np.zeros(3)
    for a in np.flatnonzero(~covered):
        col = dm[:, a][np.isfinite(dm[:, a])]
        if col.size:
            m, scatter = float(col.mean()), col.var() / col.size
            var = max(scatter, float(mean_var[a]))
            if abs(m) > 1.96 * np.sqrt(max(scatter, float(common[a]))):
                mean[a], applied_var[a] = m, max(var, 1e-300)
            else:
                fixed[a] = m * m + var
    t, g, c = _trend_design(rec, db_xyz, mean, applied_var)
    return _Trend(t, g, c, fixed, covered, mean, applied_var)


def _trend_cov(tr: _Trend, sel, ws_h: Optional[np.ndarray], ws_v: Optional[np.ndarray]):
    """Covariance (n, 3, 3) of the trend's error in the prediction at the points ``sel``.

    The prediction ``t(x) + sum w_i (d_i - t(x_i))`` carries the trend's error ``g dT``
    as ``(g(x) - sum w_i g(x_i)) dT``: near measured points (``sum w`` about 1) the
    collocation has put the field back around the measured displacements and the
    trend's error cancels; far from them (``w`` about 0) it counts in full. ``ws_h``
    (n, 2 q) and ``ws_v`` (n, q) are the kriging weights' sums of ``g`` over the
    measured points (:func:`_krige_many`, horizontal and vertical weights); the error's
    correlation with the neighbours' own data is left out (it is small beyond the
    neighbourhood that fixed ``T``). Plus ``fixed``.
    """
    h = tr.g[sel].copy()
    q = h.shape[2]
    if ws_h is not None:
        h[:, :2, :] -= ws_h.reshape(len(h), 2, q)
    if ws_v is not None:
        h[:, 2, :] -= ws_v
    return np.einsum("niq,qr,njr->nij", h, tr.c, h) + np.diag(tr.fixed)


def _trend_field_cov(g_m: np.ndarray, xy_m: np.ndarray, covs, max_points: int = 1500,
                     seed: int = 0) -> np.ndarray:
    """Covariance (q, q) the correlated field adds to the estimated trend's error.

    The offset (and an applied mean) is estimated from the measured points as if their
    database errors were independent (the adjustment's cofactor holds each point's own
    variance); the field correlates them, so the estimate also carries the field's
    weighted mean over the measured points: ``A (sum_{i != j} g_i' C(r_ij) g_j) A`` with
    ``A = (sum g_i' g_i)^-1`` (the offset's least-squares weights; a mean: ``1/n``) and
    ``C`` the fitted signal covariance of the row's component (``covs``: horizontal for
    X and Y, vertical for Z). The pair sum is taken on a random subset of at most
    ``max_points`` points and scaled by the number of pairs (an unbiased estimate).
    """
    m, q = g_m.shape[0], g_m.shape[2]
    if q == 0 or m < 2 or all(c is None or c.sill <= 0 or c.length <= 0 for c in covs):
        return np.zeros((q, q))
    from scipy.spatial.distance import pdist, squareform

    a = np.linalg.pinv(np.einsum("naq,nar->qr", g_m, g_m))
    pick = (np.sort(np.random.default_rng(seed).choice(m, max_points, replace=False))
            if m > max_points else np.arange(m))
    ns = len(pick)
    dist = squareform(pdist(xy_m[pick]))
    mid = np.zeros((q, q))
    for rows, cov in (((0, 1), covs[0]), ((2,), covs[1])):
        if cov is None or cov.sill <= 0 or cov.length <= 0:
            continue
        k = cov(dist)
        np.fill_diagonal(k, 0.0)
        for r in rows:
            gr = g_m[pick, r, :]
            mid += gr.T @ k @ gr
    mid *= m * (m - 1) / (ns * (ns - 1))
    out = a @ mid @ a
    return 0.5 * (out + out.T)


@dataclass
class _Field:
    """One component group's field at the unmeasured object points."""

    pred: np.ndarray
    var: np.ndarray
    nearest: np.ndarray
    cov: Optional[CovarianceModel]
    cv: dict
    wsum: Optional[np.ndarray] = None  # kriging weights' sums of the trend's design
    band_factor: Optional[np.ndarray] = None  # variance calibration per distance band
    # (:func:`band_factors`, set with the sill's prior: the CE90 factor needs it)


def _fields(xy_m, resid, noise, xy_u, s: ConflationSettings, report, cancel, carry=None,
            corr_v=None):
    """Fit, predict and cross-validate the horizontal and the vertical field.

    Each group (X and Y sharing one covariance function; Z) uses the measured points
    where it is finite; when both use the same points the KD-tree queries and the
    neighbours' distance matrices are shared. ``carry`` (horizontal (m, fh), vertical
    (m, fv)) is summed with each group's kriging weights (``_Field.wsum``; no field:
    None, the weights are zero). ``corr_v`` (m, r): the images' height error the
    measured points share (:func:`_orientation_basis`), in the vertical fit and system.
    """
    carry = carry or (None, None)
    corr = (None, corr_v)
    groups = [(resid[:, :2], noise[:, :2].mean(axis=1), CE90_CIRCULAR),
              (resid[:, 2:], noise[:, 2], LE90)]
    n_u = len(xy_u)
    oks = [np.isfinite(r).all(axis=1) for r, _, _ in groups]
    covs = [fit_covariance(xy_m[ok], r[ok], nz[ok], s.model, s.k,
                           corr=None if u is None else u[ok])
            if ok.sum() >= s.min_points else None
            for ok, (r, nz, _), u in zip(oks, groups, corr)]
    live = [i for i, c in enumerate(covs) if c is not None]
    fields = [_Field(np.full((n_u, r.shape[1]), np.nan), np.full(n_u, np.nan),
                     np.full(n_u, np.inf), None, {"count": int(ok.sum()), "rmse": None})
              for ok, (r, _, _) in zip(oks, groups)]
    batches = ([live] if len(live) == 2 and np.array_equal(*oks) else [[i] for i in live])
    for b, batch in enumerate(batches):
        ok = oks[batch[0]]
        models = [(covs[i], groups[i][0][ok], groups[i][1][ok],
                   None if carry[i] is None else carry[i][ok],
                   None if corr[i] is None else corr[i][ok]) for i in batch]
        part = (b, len(batches))
        res, nearest = _krige_many(models, xy_m[ok], xy_u, s.k, progress=lambda f, p=part:
                                   report((p[0] + f) / p[1]), is_cancelled=cancel)
        loo, _ = _krige_many([(*m[:3], None, m[4]) for m in models], xy_m[ok], xy_m[ok], s.k,
                             skip_self=True, is_cancelled=cancel)
        for i, (pred, var, ws), (lp, lv, _), m in zip(batch, res, loo, models):
            cv = (_cv_stats(covs[i], m[1], m[2], lp, lv, groups[i][2]) if ok.sum() >= 3 else
                  {"count": int(ok.sum()), "rmse": None})
            fields[i] = _Field(pred, var, nearest, covs[i], cv, ws)
    return fields[0], fields[1]


def _vertex_columns(d, meas_v, adj, cov, source, ce_factor=None) -> None:
    """Write the conflated vertices into ``d.vertices`` / ``d.adjusted_coords`` (in place);
    ``ce_factor`` (per vertex, :func:`ce90_factor`) scales the predicted vertices' CE90."""
    from vectoradjust.accuracy.tables import _feature_geometry, cov_stats

    v = d.vertices
    db = d.shape.layer.coords
    u = ~meas_v
    sig, ce, le = cov_stats(cov[u])
    if ce_factor is not None:
        ce = ce * ce_factor[u]
    for a, ax in enumerate("XYZ"):
        col = np.array(v[f"Adj{ax}"], float)
        col[u] = adj[u, a]
        v[f"Adj{ax}"] = col
        vcol = np.array(v[f"V{ax.lower()}"], float)
        vcol[u] = adj[u, a] - db[u, a]
        v[f"V{ax.lower()}"] = vcol
        scol = np.array(v[f"Sigma{ax}"], float)
        scol[u] = sig[:, a]
        v[f"Sigma{ax}"] = scol
    for name, val in (("CE90", ce), ("LE90", le)):
        col = np.array(v[name], float)
        col[u] = val
        v[name] = col
    v["Source"] = source
    d.adjusted_coords = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])
    d.features.update(_feature_geometry(d.shape.layer, d.adjusted_coords))
