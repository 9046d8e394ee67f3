"""Length of features: the sigma of a road's length (full covariance and without
covariances), its expected lengthening, the conflated vertices' share, and the
feature-level accuracy (vertex CE90/LE90, LengthSD).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vectoradjust.accuracy.derived.bands import _measured_segments, vertex_covariance
from vectoradjust.accuracy.derived.covariance import (
    _CHUNK,
    _adjusted_coords,
    _block_sum,
    _check_result,
    _identification_variance,
    _ObsIndex,
    _segments,
    cross_covariance,
)

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["feature_length_sigma", "segment_lengthening", "conflated_length_variance",
           "feature_vertex_accuracy", "feature_accuracy", "conflated_length_sigma"]


# ------------------------------------------------------------------- length of features
def _segment_gradients(run: AdjustmentRun, db: DatabaseResult, a: np.ndarray, dims: int):
    """For the segments starting at vertices ``a``: their end vertices ``b``, unit
    directions ``u``, lengths, the gradient of each length by its two vertices
    (``2 a.size`` rows: the starts' ``-u``, then the ends' ``u``) and those vertices."""
    adj = _adjusted_coords(run, db)
    b = a + 1
    d = adj[b, :dims] - adj[a, :dims]
    length = np.sqrt(np.sum(d ** 2, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    grad = np.zeros((2 * a.size, 3))
    grad[: a.size, :dims] = -u
    grad[a.size:, :dims] = u
    return b, u, length, grad, np.concatenate([a, b])


def feature_length_sigma(run: AdjustmentRun, db: DatabaseResult, dims: int = 2,
                         lengthening: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Standard deviation of the length of every feature of a road database.

    The length is that of the adjusted geometry, the sum of the segment lengths within
    each part (the ``Length`` field of the ``features`` layer); horizontal by default.
    Its gradient with respect to vertex ``i`` is ``u_{i-1} - u_i`` (unit vectors of the
    adjacent segments; a zero-length segment contributes nothing). Vertices that share
    one object point are one point (their gradients are added).

    ``LengthSD`` is the root mean square error of the length: its standard deviation
    and its expected lengthening (:func:`segment_lengthening`: errors across a segment
    always lengthen it, by about ``sigma^2 / l`` per segment of length ``l``; on a
    road of many short segments this is most of the error).

    The covariance is that of the vertices' CE90: the adjustment's (with the database
    offsets' share) plus the identification error of every measured object point
    (``identification_sigma``, independent from point to point). Vertices that were not
    measured are taken as fixed here: :func:`conflated_length_sigma` adds the conflated
    vertices' share once the run is conflated. Features without any measured vertex
    get NaN.

    All features at once (module docstring): ``sigma^2 = s0^2 [sum_j J_j D_j J_j' +
    b S^-1 b']`` with ``b`` accumulated per feature with ``bincount``.

    With the vertices tabulated it also sets ``db.features["CE90"]`` / ``["LE90"]``
    (:func:`feature_vertex_accuracy`; completed after the conflation by :func:`feature_accuracy`).

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
        One of ``run.databases``.
    dims : {2, 3}
        Horizontal (2, the ``Length`` field) or 3D (3) length.
    lengthening : bool
        Include the expected lengthening (default; False: the standard deviation of
        the linearised length alone).

    Returns
    -------
    length_sd : numpy.ndarray, shape (nf,)
        With the full covariance of the feature's points (``LengthSD``).
    length_sd_nocov : numpy.ndarray, shape (nf,)
        With each point's own covariance block only (``LengthSDnc``).
    """
    if dims not in (2, 3):
        raise ValueError("dims must be 2 or 3")
    res = run.result
    _check_result(res)
    layer = db.shape.layer
    nf = layer.n_features
    vp = np.asarray(db.vertex_point, np.int64)
    fi = layer.vertex_feature
    sd = np.full(nf, np.nan)
    sd_nc = np.full(nf, np.nan)
    has = np.bincount(fi[vp >= 0], minlength=nf) > 0 if len(fi) else np.zeros(nf, bool)
    sd[has] = 0.0
    sd_nc[has] = 0.0
    a = _segments(db)
    if a.size == 0 or not has.any():
        return sd, sd_nc
    g, pf, pp = _point_gradients(run, db, a, dims)
    # without covariances between points: each point's own block
    blocks = res.point_cov[pp] if res.point_cov is not None else cross_covariance(res, pp, pp)
    var_nc = np.bincount(pf, weights=np.einsum("mi,mij,mj->m", g, blocks, g), minlength=nf)
    # full: s0^2 [sum g' D g + b S^-1 b']
    h = np.einsum("mij,mj->mi", res.npp_inv[pp], g)
    diag = np.bincount(pf, weights=np.einsum("mi,mi->m", g, h), minlength=nf)
    quad = _orientation_share(res, h, pf, pp, nf)
    if res.offset_cofactor is not None:  # the database offsets' share
        quad += _offset_share(res, g, pf, pp, nf)
    # the identification error: independent per object point (docs/method.md section 10)
    ident = np.bincount(pf, weights=g ** 2 @ _identification_variance(db), minlength=nf)
    var = res.variance_factor * (diag + quad) + ident
    var_nc = var_nc + ident
    bias, bias_nc = _lengthening_so_far(run, db, dims, lengthening)
    sd[has] = np.sqrt(np.clip(var[has], 0.0, None) + bias[has] ** 2)
    sd_nc[has] = np.sqrt(np.clip(var_nc[has], 0.0, None) + bias_nc[has] ** 2)
    return sd, sd_nc


def _point_gradients(run: AdjustmentRun, db: DatabaseResult, a: np.ndarray, dims: int):
    """The length gradients of the measured vertices of the segments starting at ``a``,
    summed per (feature, object point): gradient ``g`` (m, 3), feature ``pf`` (m,) and
    object point ``pp`` (m,), sorted by feature then point."""
    vp = np.asarray(db.vertex_point, np.int64)
    fi = db.shape.layer.vertex_feature
    b, u, length, grad, vert = _segment_gradients(run, db, a, dims)
    keep = vp[vert] >= 0
    ent_f = fi[vert][keep]
    ent_p = vp[vert][keep]
    grad = grad[keep]
    n_pts = run.result.problem.n_points
    key = ent_f.astype(np.int64) * n_pts + ent_p
    uniq, inv = np.unique(key, return_inverse=True)
    g = _block_sum(np.asarray(inv).reshape(-1), grad, len(uniq))  # (m, 3) per (feature, point)
    return g, uniq // n_pts, uniq % n_pts


def _orientation_share(res, h: np.ndarray, pf: np.ndarray, pp: np.ndarray,
                       nf: int) -> np.ndarray:
    """``b S^-1 b'`` per feature: the orientations' share of the length's variance (over
    ``s0^2``), with ``h = N_pp^-1 g`` per (feature, point); the dense ``b`` rows are
    formed for a chunk of features at a time."""
    prob = res.problem
    idx = _ObsIndex.of(res)
    ent, obs = idx.expand(pp)
    contrib = np.einsum("kij,kj->ki", res.nep_obs[obs], h[ent])  # (K, 6) at image of obs
    n = prob.n_images
    feat = pf[ent]
    quad = np.zeros(nf)
    order = np.argsort(feat, kind="stable")
    feat_s = feat[order]
    rows = max(1, int(2_000_000 // (6 * n)))  # features per chunk of the dense b rows
    for f0 in range(0, nf, rows):
        f1 = min(nf, f0 + rows)
        lo, hi = np.searchsorted(feat_s, [f0, f1])
        if hi <= lo:
            continue
        sel = order[lo:hi]
        bm = _block_sum((feat[sel] - f0) * n + prob.obs_image[obs[sel]], contrib[sel],
                        (f1 - f0) * n).reshape(f1 - f0, 6 * n)
        quad[f0:f1] = np.einsum("fi,fi->f", bm @ res.s_inv, bm)
    return quad


def _offset_share(res, g: np.ndarray, pf: np.ndarray, pp: np.ndarray, nf: int) -> np.ndarray:
    """The database offsets' share of the length's variance per feature (over ``s0^2``)."""
    hq = np.einsum("mi,miq->mq", g, res.offset_qb[pp])
    hq = np.stack([np.bincount(pf, weights=hq[:, c], minlength=nf)
                   for c in range(hq.shape[1])], axis=1)
    return np.einsum("fq,qr,fr->f", hq, res.offset_cofactor, hq)


def _lengthening_so_far(run: AdjustmentRun, db: DatabaseResult, dims: int, lengthening: bool):
    """:func:`_measured_bias` (zeros without ``lengthening``), kept for
    :func:`conflated_length_sigma` (the ``LengthSD`` field's); and the features' CE90 /
    LE90 of the vertices tabulated so far (:func:`feature_accuracy` completes them)."""
    nf = db.shape.layer.n_features
    bias = _measured_bias(run, db, dims) if lengthening else (np.zeros(nf), np.zeros(nf))
    if lengthening and dims == 2:
        db.__dict__["_length_bias"] = bias
    if getattr(db, "vertices", None) and isinstance(getattr(db, "features", None), dict):
        db.features["CE90"], db.features["LE90"] = feature_vertex_accuracy(db)
    return bias


def segment_lengthening(rel_cov: np.ndarray, u: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Expected lengthening of segments whose ends err: ``E|d + e| - |d|``.

    To second order ``(tr D - u' D u) / (2 l)`` with ``D`` (s, k, k) the covariance of
    the relative error ``e = e_b - e_a`` of the ends, ``u`` the unit direction and ``l``
    the length: an error across the segment always lengthens it. At most
    ``sqrt(tr D - u' D u)`` (about the mean length of the error itself, where ``l`` is
    not larger than it).
    """
    p = np.einsum("sii->s", rel_cov) - np.einsum("si,sij,sj->s", u, rel_cov, u)
    p = np.maximum(p, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        b = np.where(length > 0, p / (2.0 * length), np.inf)
    return np.minimum(b, np.sqrt(p))


def _measured_bias(run: AdjustmentRun, db: DatabaseResult, dims: int):
    """Expected lengthening per feature (with / without the cross covariances) from its
    segments with two measured ends (:func:`segment_lengthening`): the relative
    covariance of the adjusted ends plus twice the identification variance."""
    res = run.result
    nf = db.shape.layer.n_features
    a = _measured_segments(db)
    if a.size == 0:
        return np.zeros(nf), np.zeros(nf)
    vp = np.asarray(db.vertex_point, np.int64)
    pa, pb = vp[a], vp[a + 1]
    own_a = res.point_cov[pa] if res.point_cov is not None else cross_covariance(res, pa, pa)
    own_b = res.point_cov[pb] if res.point_cov is not None else cross_covariance(res, pb, pb)
    cab = cross_covariance(res, pa, pb)
    rel_nc = own_a + own_b + 2.0 * np.diag(_identification_variance(db))
    rel = rel_nc - cab - np.swapaxes(cab, 1, 2)
    adj = _adjusted_coords(run, db)
    d = adj[a + 1, :dims] - adj[a, :dims]
    length = np.sqrt(np.sum(d ** 2, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    fi = db.shape.layer.vertex_feature[a]
    return tuple(np.bincount(fi, weights=segment_lengthening(r[:, :dims, :dims], u, length),
                             minlength=nf) for r in (rel, rel_nc))


def _conflated_gradients(run: AdjustmentRun, db: DatabaseResult, vc: np.ndarray, dims: int):
    """The length gradients of the conflated vertices, per (feature, object point):
    feature (m,), a vertex of the object point (m,), gradient (m, 3); sorted by
    feature."""
    layer = db.shape.layer
    fi = np.asarray(layer.vertex_feature, np.int64)
    vo = np.asarray(db.shape.vertex_object, np.int64)
    conf = (np.asarray(db.vertex_point) < 0) & np.isfinite(vc[:, 0, 0])
    a = _segments(db)
    a = a[conf[a] | conf[a + 1]] if a.size else a
    b, u, length, grad, vert = _segment_gradients(run, db, a, dims)
    keep = conf[vert]
    vert, grad = vert[keep], grad[keep]
    nobj = max(int(db.shape.n_objects), 1)
    uniq, inv = np.unique(fi[vert] * nobj + vo[vert], return_inverse=True)
    inv = np.asarray(inv).reshape(-1)
    g = _block_sum(inv, grad, len(uniq))
    rep = np.zeros(len(uniq), np.int64)
    rep[inv] = vert
    return uniq // nobj, rep, g


def _correlation(cov_model, r: np.ndarray) -> np.ndarray:
    """``C(r) / C(0)`` of a fitted covariance function (1 without a correlated field:
    what is left is the trend's error, common to all vertices)."""
    if cov_model is None or cov_model.sill <= 0 or cov_model.length <= 0:
        return np.ones_like(r)
    return cov_model(r) / cov_model.sill


def conflated_length_variance(run: AdjustmentRun, db: DatabaseResult,
                              dims: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The conflated vertices' share of the variance of every feature's length.

    A conflated vertex's error (:func:`vertex_covariance`) is the database's white noise
    ``n_db`` (the fitted nugget, independent from object point to object point) and a
    smooth part, the rest of its variance, correlated between two vertices at distance
    ``r`` as the fitted covariance function says (``C(r) / C0``; fully without a fitted
    field). The measured vertices' share (:func:`feature_length_sigma`) is independent
    of it (their cross covariance with the prediction is left out). All features at
    once: the pairs of conflated points within each feature, in chunks.

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
        Conflated (``db.conflation`` set); otherwise the share is zero.
    dims : {2, 3}

    Returns
    -------
    var : numpy.ndarray, shape (nf,)
        With the correlations (m^2).
    var_nocov : numpy.ndarray, shape (nf,)
        Each point's own variance only.
    """
    nf = db.shape.layer.n_features
    vc = vertex_covariance(db)
    model = getattr(db, "conflation", None)
    if vc is None or model is None:
        return np.zeros(nf), np.zeros(nf)
    f, rep, g = _conflated_gradients(run, db, vc, dims)
    var = np.einsum("mii->mi", vc[rep])
    nug = np.array([getattr(model.cov_h, "nugget", 0.0)] * 2
                   + [getattr(model.cov_v, "nugget", 0.0)], float)
    nug = np.minimum(np.nan_to_num(nug), var)
    c = np.sqrt(np.maximum(var - nug, 0.0))
    var_nc = np.bincount(f, weights=np.sum(g * g * var, axis=1), minlength=nf)
    total = np.bincount(f, weights=np.sum(g * g * nug, axis=1), minlength=nf)
    xy = _adjusted_coords(run, db)[rep, :2]
    gc = g * c
    counts = np.bincount(f, minlength=nf)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per = counts[f]  # pairs of each entry
    ends = np.cumsum(per)
    lo = 0
    while lo < len(f):  # chunks of about _CHUNK pairs
        hi = int(np.searchsorted(ends, ends[lo] - per[lo] + _CHUNK, side="right"))
        hi = max(hi, lo + 1)
        ii = np.repeat(np.arange(lo, hi), per[lo:hi])
        jj = first[f[ii]] + (np.arange(ii.size) - np.repeat(np.cumsum(per[lo:hi])
                                                             - per[lo:hi], per[lo:hi]))
        r = np.hypot(*(xy[ii] - xy[jj]).T)
        rho_h, rho_v = _correlation(model.cov_h, r), _correlation(model.cov_v, r)
        term = (gc[ii, 0] * gc[jj, 0] + gc[ii, 1] * gc[jj, 1]) * rho_h \
            + gc[ii, 2] * gc[jj, 2] * rho_v
        total += np.bincount(f[ii], weights=term, minlength=nf)
        lo = hi
    return np.maximum(total, 0.0), var_nc


def _conflated_bias(run: AdjustmentRun, db: DatabaseResult, vc: np.ndarray) -> np.ndarray:
    """Expected lengthening per feature (:func:`segment_lengthening`) from its segments
    with a conflated end and a covariance at both: two conflated ends share the smooth
    part of their error as the fitted covariance function says (the database noise is
    theirs alone); a measured and a conflated end are taken as independent."""
    nf = db.shape.layer.n_features
    model = db.conflation
    vp = np.asarray(db.vertex_point, np.int64)
    vo = np.asarray(db.shape.vertex_object)
    a = _segments(db)
    if a.size:
        ok = np.isfinite(vc[a, 0, 0]) & np.isfinite(vc[a + 1, 0, 0])
        a = a[ok & ((vp[a] < 0) | (vp[a + 1] < 0)) & (vo[a] != vo[a + 1])]
    if a.size == 0:
        return np.zeros(nf)
    adj = _adjusted_coords(run, db)
    d = adj[a + 1, :2] - adj[a, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > 0, d / length[:, None], 0.0)
    rel = vc[a] + vc[a + 1]
    both = (vp[a] < 0) & (vp[a + 1] < 0)
    nug = max(float(np.nan_to_num(getattr(model.cov_h, "nugget", 0.0))), 0.0)
    for ax in (0, 1):
        va, vb = vc[a, ax, ax], vc[a + 1, ax, ax]
        ca = np.sqrt(np.maximum(va - np.minimum(nug, va), 0.0))
        cb = np.sqrt(np.maximum(vb - np.minimum(nug, vb), 0.0))
        shared = 2.0 * ca * cb * _correlation(model.cov_h, length)
        rel[:, ax, ax] -= np.where(both, shared, 0.0)
    fi = db.shape.layer.vertex_feature[a]
    return np.bincount(fi, weights=segment_lengthening(rel[:, :2, :2], u, length),
                       minlength=nf)


def feature_vertex_accuracy(db: DatabaseResult) -> tuple[np.ndarray, np.ndarray]:
    """The ``CE90`` and ``LE90`` of every feature: the largest of its vertices'.

    Each vertex with a value (measured, or predicted by the conflation) lies within its
    CE90 of the real road vertex with 90 % probability; the feature's CE90 is the
    largest of them, so that every vertex of the feature is stated at least as
    uncertain as it is (a statement per vertex, not a simultaneous one for all of them).
    NaN for a feature without a vertex with a value.

    Returns
    -------
    ce90, le90 : numpy.ndarray, shape (nf,)
    """
    layer = db.shape.layer
    nf = layer.n_features
    v = db.vertices
    out = []
    for name in ("CE90", "LE90"):
        col = np.asarray(v.get(name, np.full(len(layer.vertex_feature), np.nan)), float)
        ok = np.isfinite(col)
        best = np.full(nf, -np.inf)
        np.maximum.at(best, np.asarray(layer.vertex_feature)[ok], col[ok])
        out.append(np.where(np.isfinite(best), best, np.nan))
    return out[0], out[1]


def feature_accuracy(run: AdjustmentRun, db: DatabaseResult) -> None:
    """The features' statements from the covariance of their vertices' CE90/LE90, in
    place: ``CE90`` / ``LE90`` (:func:`feature_vertex_accuracy`), the ``Problem`` note of
    vertices without a height on the final geometry and, once the run is conflated, the
    conflated vertices' share of ``LengthSD`` / ``LengthSDnc``
    (:func:`conflated_length_sigma`). Safe to call again (the share is added once).
    """
    if db.vertices:
        db.features["CE90"], db.features["LE90"] = feature_vertex_accuracy(db)
    if db.adjusted_coords is not None and "Problem" in db.features:
        from vectoradjust.accuracy.tables import _feature_problems

        # vertices without a height after the conflation too (a vertex of an object
        # point shared with a vertex without one takes its position)
        db.features["Problem"] = _feature_problems(db, np.asarray(db.adjusted_coords))
    conflated_length_sigma(run, db)


def conflated_length_sigma(run: AdjustmentRun, db: DatabaseResult) -> None:
    """Add the conflated vertices' share to the features' ``LengthSD`` / ``LengthSDnc``
    (in place, once; the run must be conflated, :func:`conflated_length_variance`).

    Every feature with a measured or conflated vertex then has a ``LengthSD``;
    ``LengthSDOf`` says ``"all vertices"`` when every vertex has a covariance (measured
    or conflated), ``"measured vertices"`` when some kept their database position
    without one (they count as fixed), ``""`` without any.
    """
    feats = db.features
    if db.__dict__.get("_length_sd_conflated") or "LengthSD" not in feats:
        return
    vc = vertex_covariance(db)
    if vc is None or getattr(db, "conflation", None) is None:
        return
    var, var_nc = conflated_length_variance(run, db)
    b_c = _conflated_bias(run, db, vc)
    nf0 = db.shape.layer.n_features
    b_m, b_m_nc = db.__dict__.get("_length_bias", (np.zeros(nf0), np.zeros(nf0)))
    layer = db.shape.layer
    fi = np.asarray(layer.vertex_feature, np.int64)
    nf = layer.n_features
    valued = np.isfinite(vc[:, 0, 0]) | (np.asarray(db.vertex_point) >= 0)
    n_val = np.bincount(fi, weights=valued, minlength=nf)
    n_all = np.bincount(fi, minlength=nf)
    has = n_val > 0
    for name, v, b in (("LengthSD", var, b_m), ("LengthSDnc", var_nc, b_m_nc)):
        old = np.nan_to_num(np.asarray(feats[name], float), nan=0.0)
        v_old = np.maximum(old ** 2 - b ** 2, 0.0)  # the measured part's variance
        feats[name] = np.where(has, np.sqrt(v_old + v + (b + b_c) ** 2), np.nan)
    feats["LengthSDOf"] = np.where(~has, "", np.where(n_val >= n_all, "all vertices",
                                                      "measured vertices")).astype(object)
    db.__dict__["_length_sd_conflated"] = True
