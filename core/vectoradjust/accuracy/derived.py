"""Derived quantities of an adjustment run with their sigmas (``DESIGN.md`` section 6).

Everything computed from adjusted points - the length of a road, the distance between
two points, a height profile, the G-band of a road segment, the equal-error map of a
stereo pair - gets its standard deviation from the FULL a-posteriori covariance of the
points involved, and beside it the value "without covariances" (each point's own 3x3
block only), to show what the covariances between points change.

The covariances come from the reduced camera system of the bundle adjustment
(:class:`~vectoradjust.adjust.bundle.BundleResult`), never from a full inverse. With
``D_j = N_pp,j^-1`` (the point's own cofactor block), ``Z_j = N_pp,j^-1 N_pe,j``
(3 x 6n, nonzero only at the images that see point ``j``) and ``S^-1`` the inverse of
the reduced camera system, the cross covariance of two points is

    C_jl = s0^2 [delta_jl D_j + Z_j S^-1 Z_l']

and the variance of a linear function ``L = sum_j J_j x_j`` (1 x 3 gradients ``J_j``)

    sigma_L^2 = s0^2 [sum_j J_j D_j J_j' + b S^-1 b'],   b = sum_j J_j Z_j.

Both are evaluated for many points or functions at once (:func:`cross_covariance`,
:func:`feature_length_sigma`): the ``b`` rows are accumulated over the observations of
the points with ``bincount``, so the cost grows with the number of observations, not
with the number of images squared per point.

What the bands, lengths, distances and profiles state is the real road, as the
vertices' CE90/LE90 do: the adjustment's covariance (the database offsets' share
included) plus the identification error of each shape point (``identification_sigma``,
independent from object point to object point), and for the vertices the conflation
predicted their covariance from it (:func:`vertex_covariance`). ``LengthSD`` is the
root mean square error of a length, its expected lengthening included
(:func:`segment_lengthening`); the G-band's ellipses are drawn at the one-dimensional
scale of the error across the line (:func:`band_scale`).

Heart module: numpy and scipy only (and other vectoradjust heart modules).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, NamedTuple, Optional, Union

import numpy as np
from scipy.special import ndtri

from vectoradjust.accuracy import propagate as prop
from vectoradjust.accuracy import stats
from vectoradjust.adjust.orientation import two_step
from vectoradjust.errors import (
    ControlError,
    LayerError,
    MeasurementError,
    ProjectError,
)
from vectoradjust.sensor.collinearity import rotation_matrix

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.adjust.bundle import BundleResult
    from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = [
    "cross_covariance",
    "segment_covariances",
    "SegmentCovariances",
    "feature_length_sigma",
    "segment_lengthening",
    "conflated_length_variance",
    "conflated_length_sigma",
    "feature_vertex_accuracy",
    "feature_accuracy",
    "g_band_batch",
    "g_band_rings",
    "SegmentBands",
    "segment_bands",
    "band_segment_counts",
    "band_scale",
    "vertex_covariance",
    "uncertainty_bands",
    "DerivedValue",
    "resolve_points",
    "distance_between",
    "length_between",
    "mean_height_between",
    "FeatureProfile",
    "profile",
    "EqualErrorGrid",
    "equal_error_grid",
    "equal_error_range",
    "image_footprint",
    "compare_two_step",
]

DEFAULT_FRAME_MM = 230.0  # 23 x 23 cm aerial film (DESIGN section 1)
_CHUNK = 200_000  # rows of temporary (rows, 3, 3)-sized arrays per chunk


# ---------------------------------------------------------------------------- helpers
def _block_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum ``values`` (k, ...) into ``n`` bins by ``index`` (k,), vectorised."""
    k = values.shape[0]
    inner = values.shape[1:]
    size = int(np.prod(inner)) if inner else 1
    if k == 0:
        return np.zeros((n,) + inner)
    flat = values.reshape(k, size)
    idx = (index[:, None] * size + np.arange(size)[None, :]).ravel()
    out = np.bincount(idx, weights=flat.ravel(), minlength=n * size)
    return out.reshape((n,) + inner)


@dataclass
class _ObsIndex:
    """Observations of the bundle grouped by point (CSR layout)."""

    order: np.ndarray  # observation indices sorted by point
    starts: np.ndarray  # first position in ``order`` of each point
    counts: np.ndarray  # observations per point

    @classmethod
    def of(cls, result: BundleResult) -> _ObsIndex:
        prob = result.problem
        order = np.argsort(prob.obs_point, kind="stable")
        counts = np.bincount(prob.obs_point, minlength=prob.n_points)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        return cls(order, starts, counts)

    def expand(self, points: np.ndarray):
        """Every observation of every entry of ``points``: ``(entry, observation)``."""
        c = self.counts[points]
        entry = np.repeat(np.arange(len(points)), c)
        offs = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        return entry, self.order[np.repeat(self.starts[points], c) + offs]


def _check_result(result: BundleResult) -> None:
    if result.s_inv is None or result.npp_inv is None or result.nep_obs is None \
            or result.problem is None:
        raise ProjectError(
            "The adjustment result holds no factorisation (s_inv, npp_inv, nep_obs), so "
            "covariances between points cannot be computed",
            "Use a BundleResult from vectoradjust.adjust.bundle.adjust (pipeline.run keeps them; "
            "BundleResult.release_factorisation lets them go)",
        )


def cross_covariance(result: BundleResult, pa, pb) -> np.ndarray:
    """A-posteriori cross covariances ``C_jl`` of many pairs of bundle points at once.

    ``C_jl = s0^2 [delta_jl N_pp,j^-1 + Z_j S^-1 Z_l']`` with ``Z_j = N_pp,j^-1 N_pe,j``
    (module docstring); ``pa[i] == pb[i]`` gives the point's own covariance block.
    The work is one small product per pair of observations of the two points.

    Parameters
    ----------
    result : BundleResult
    pa, pb : array_like of int, shape (m,)
        Bundle point indices.

    Returns
    -------
    numpy.ndarray, shape (m, 3, 3)
        ``Cov(x_pa[i], x_pb[i])``.
    """
    _check_result(result)
    pa = np.asarray(pa, np.int64).reshape(-1)
    pb = np.asarray(pb, np.int64).reshape(-1)
    if pa.shape != pb.shape:
        raise ValueError("cross_covariance: pa and pb must have the same length")
    prob = result.problem
    n = prob.n_images
    m = len(pa)
    sinv = result.s_inv.reshape(n, 6, n, 6)
    idx = _ObsIndex.of(result)
    ca, cb = idx.counts[pa], idx.counts[pb]
    nt = ca * cb
    acc = np.zeros((m, 3, 3))
    if m == 0:
        return acc
    # chunks of pairs so that the per-observation-pair temporaries stay small
    ends = np.cumsum(nt)
    cuts = np.searchsorted(ends, np.arange(_CHUNK, int(ends[-1]), _CHUNK), side="left") + 1
    cuts = np.unique(np.concatenate([[0], np.clip(cuts, 1, m), [m]]))
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        ntc = nt[lo:hi]
        entry = np.repeat(np.arange(lo, hi), ntc)
        local = np.arange(int(ntc.sum())) - np.repeat(np.cumsum(ntc) - ntc, ntc)
        ia = local // cb[entry]
        ib = local % cb[entry]
        ka = idx.order[idx.starts[pa[entry]] + ia]
        kb = idx.order[idx.starts[pb[entry]] + ib]
        blk = sinv[prob.obs_image[ka], :, prob.obs_image[kb], :]  # (T, 6, 6)
        t = np.matmul(np.swapaxes(result.nep_obs[ka], 1, 2), blk) @ result.nep_obs[kb]
        acc[lo:hi] = _block_sum(entry - lo, t, hi - lo)
    cov = result.npp_inv[pa] @ acc @ result.npp_inv[pb]
    same = pa == pb
    cov[same] += result.npp_inv[pa[same]]
    cov += result.offset_cross(pa, pb)  # database offsets (zero without)
    return result.variance_factor * cov


def _adjusted_coords(run: AdjustmentRun, db: DatabaseResult) -> np.ndarray:
    if db.adjusted_coords is not None:
        return np.asarray(db.adjusted_coords, float)
    adj = np.array(db.shape.layer.coords, float)
    m = db.vertex_point >= 0
    adj[m] = run.result.xyz[db.vertex_point[m]]
    return adj


def _segments(db: DatabaseResult):
    """Start vertex of every segment within a part of a feature (``a`` -> ``a + 1``)."""
    layer = db.shape.layer
    fi, part = layer.vertex_feature, layer.vertex_part
    if len(fi) < 2:
        return np.zeros(0, np.int64)
    same = (fi[1:] == fi[:-1]) & (part[1:] == part[:-1])
    return np.flatnonzero(same)


# ------------------------------------------------------------------- length of features
def _identification_variance(db) -> np.ndarray:
    """Per-axis variance (3,) of the database's identification error (zeros when none is
    stated, or for a stand-in without a ``spec``)."""
    spec = getattr(db, "spec", None)
    return np.zeros(3) if spec is None else np.asarray(spec.identification_variance, float)


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
    (:func:`feature_vertex_accuracy`; :func:`feature_accuracy` completes them after the
    conflation).

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
    prob = res.problem
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
    b, u, length, grad, vert = _segment_gradients(run, db, a, dims)
    keep = vp[vert] >= 0
    ent_f = fi[vert][keep]
    ent_p = vp[vert][keep]
    grad = grad[keep]
    n_pts = prob.n_points
    key = ent_f.astype(np.int64) * n_pts + ent_p
    uniq, inv = np.unique(key, return_inverse=True)
    g = _block_sum(np.asarray(inv).reshape(-1), grad, len(uniq))  # (m, 3) per (feature, point)
    pf = uniq // n_pts
    pp = uniq % n_pts
    # without covariances between points: each point's own block
    blocks = res.point_cov[pp] if res.point_cov is not None else cross_covariance(res, pp, pp)
    var_nc = np.bincount(pf, weights=np.einsum("mi,mij,mj->m", g, blocks, g), minlength=nf)
    # full: s0^2 [sum g' D g + b S^-1 b']
    h = np.einsum("mij,mj->mi", res.npp_inv[pp], g)
    diag = np.bincount(pf, weights=np.einsum("mi,mi->m", g, h), minlength=nf)
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
    if res.offset_cofactor is not None:  # the database offsets' share
        hq = np.einsum("mi,miq->mq", g, res.offset_qb[pp])
        hq = np.stack([np.bincount(pf, weights=hq[:, c], minlength=nf)
                       for c in range(hq.shape[1])], axis=1)
        quad += np.einsum("fq,qr,fr->f", hq, res.offset_cofactor, hq)
    # the identification error: independent per object point (DESIGN section 10)
    ident = np.bincount(pf, weights=g ** 2 @ _identification_variance(db), minlength=nf)
    var = res.variance_factor * (diag + quad) + ident
    var_nc = var_nc + ident
    bias, bias_nc = _lengthening_so_far(run, db, dims, lengthening)
    sd[has] = np.sqrt(np.clip(var[has], 0.0, None) + bias[has] ** 2)
    sd_nc[has] = np.sqrt(np.clip(var_nc[has], 0.0, None) + bias_nc[has] ** 2)
    return sd, sd_nc


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


# ------------------------------------------------------------------------------ G-band
_BAND_BUDGET = 500_000  # elements of the largest (chunk, P, P K) temporaries (~1000 rows)


def _upper_envelope(cu: np.ndarray, slope: np.ndarray, icpt: np.ndarray):
    """Upper envelope of P concave piecewise-linear chains per row, at every chain vertex.

    Chain ``c`` of a row has the vertices ``cu[c, 0] <= ... <= cu[c, K-1]`` and on piece
    ``j`` (between vertices ``j`` and ``j + 1``) the line ``w = icpt[c, j] + slope[c, j] u``
    (an upper edge of a convex polygon); outside ``[cu[c, 0], cu[c, K-1]]`` it is absent.
    The envelope is evaluated at every vertex of every chain (the stations, sorted): the
    piece of chain ``c`` holding station ``i`` is found by counting chain ``c``'s vertices
    among the sorted stations up to ``i`` (one cumulative sum, no search); at a tie the
    neighbouring piece gives the same value (the chain is continuous).

    ``cu``: (m, P, K); ``slope, icpt``: (m, P, K - 1). Returns ``(u, w)`` of shape
    (m, P K): the stations in ascending order and the envelope there.
    """
    m, p, kk = cu.shape
    flat = cu.reshape(m, p * kk)
    order = np.argsort(flat, axis=1, kind="stable")
    su = np.take_along_axis(flat, order, axis=1)
    owner = order // kk  # chain of each station
    # (m, P, P K): vertices of chain c up to station i, made the flat index of the piece
    count = np.cumsum(owner[:, None, :] == np.arange(p)[None, :, None], axis=2, dtype=np.intp)
    np.subtract(count, 1, out=count)
    np.clip(count, 0, kk - 2, out=count)
    count += (np.arange(m * p) * (kk - 1)).reshape(m, p, 1)
    sb = su[:, None, :]
    val = np.take(slope, count)
    val *= sb
    val += np.take(icpt, count)
    out = (sb < cu[:, :, :1]) | (sb > cu[:, :, -1:])
    np.putmask(val, out, -np.inf)
    return su, val.max(axis=1)


def _neighbours(keep: np.ndarray):
    """Index of the last kept entry at or before, and the first at or after, each entry."""
    m, n = keep.shape
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(keep, idx, -1), axis=1)
    nxt = np.minimum.accumulate(np.where(keep, idx, n)[:, ::-1], axis=1)[:, ::-1]
    return prev, nxt


def _chord_gap(u: np.ndarray, w: np.ndarray, prev: np.ndarray, nxt: np.ndarray):
    """``w`` minus the chord through the entries ``prev`` and ``nxt`` (NaN without both)."""
    m, n = u.shape
    inner = (prev >= 0) & (nxt < n)
    base = np.arange(0, m * n, n)[:, None]
    pi = np.clip(prev, 0, n - 1) + base
    ni = np.clip(nxt, 0, n - 1) + base
    uf, wf = u.ravel(), w.ravel()
    u0, u1, w0, w1 = uf.take(pi), uf.take(ni), wf.take(pi), wf.take(ni)
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = w - (w0 + (w1 - w0) * (u - u0) / (u1 - u0))
    return np.where(inner, gap, np.nan)


def _drop_collinear(u: np.ndarray, w: np.ndarray, valid: np.ndarray,
                    tol: np.ndarray) -> np.ndarray:
    """Vertices of the polyline ``(u, w)[valid]`` to keep, straight runs thinned out.

    One vectorised pass drops every vertex within ``tol`` (per row) of the chord through
    its two neighbours; then every dropped vertex is checked against the chord through
    the kept vertices around it, and those farther than ``tol`` are kept after all
    (repeated until none is; usually no repetition). So the thinned polyline is within
    ``tol`` of the full one at every dropped vertex and, both being linear between the
    vertices, everywhere: an outer polyline stays outer to within ``tol``.
    """
    prev, nxt = _neighbours(valid)
    n = u.shape[1]
    prev = np.concatenate([np.full((len(u), 1), -1), prev[:, :-1]], axis=1)
    nxt = np.concatenate([nxt[:, 1:], np.full((len(u), 1), n)], axis=1)
    gap = _chord_gap(u, w, prev, nxt)
    keep = valid & ~(np.abs(gap) <= tol)
    for _ in range(n):
        dropped = valid & ~keep
        if not dropped.any():
            break
        gap = _chord_gap(u, w, *_neighbours(keep))
        bad = dropped & ~(np.abs(gap) <= tol)
        if not bad.any():
            break
        keep |= bad
    return keep


def _tangent_normals(tl: np.ndarray, ql: np.ndarray, k: float, du: float):
    """Normal directions of the common tangents of consecutive ellipses (both sides).

    The support functions ``h_j(d) = tl_j d_u + k sqrt(d' Q_j d)`` of the ellipses ``j``
    and ``j + 1`` are equal at the normal ``d`` of their common tangent. It is searched
    within one uniform direction step ``du`` of the left normal ``(0, 1)`` and of the right
    normal ``(0, -1)``, as ``d = (-s, 1)`` and ``(s, -1)`` with ``|s| <= tan(du)`` (the
    support function is positively homogeneous, so the sign of ``h_j - h_j+1`` does not
    depend on the length of ``d``; no trigonometric function in the loop): 6 bisection
    steps, then 5 steps of regula falsi with the Illinois modification (the function is
    smooth: the supports then agree to ~1e-12 of the band's scale). Where there is no
    sign change (one ellipse reaches farther on the whole interval) or the root is within
    ``1e-6`` rad of a uniform direction, the direction half a step past the normal is taken.
    Any direction keeps the circumscribed polygon valid (an outer bound): the precision
    only makes it follow the band's side.

    ``tl``: (m, P+1) centres; ``ql``: (m, P+1, 2, 2) local covariances.
    Returns ``(cos, sin, phi)`` (m, P, 2) of the left and right tangent normals and their
    angle ``phi`` from ``(0, 1)`` resp. ``(0, -1)``, in ``(-du, du)``.
    """
    q00, q01, q11 = ql[..., 0, 0, None], ql[..., 0, 1, None], ql[..., 1, 1, None]
    dt = (tl[:, :-1] - tl[:, 1:])[..., None] * np.array([-1.0, 1.0])

    def g(s):
        ss, s2 = s * s, 2.0 * s
        v0 = ss * q00[:, :-1] - s2 * q01[:, :-1] + q11[:, :-1]  # d' Q_j d
        v1 = ss * q00[:, 1:] - s2 * q01[:, 1:] + q11[:, 1:]  # d' Q_j+1 d
        return dt * s + k * (np.sqrt(np.clip(v0, 0.0, None)) - np.sqrt(np.clip(v1, 0.0, None)))

    smax = np.tan(du)
    lo, hi = np.full(dt.shape, -smax), np.full(dt.shape, smax)
    glo, ghi = g(lo), g(hi)
    ok = np.sign(glo) * np.sign(ghi) < 0
    for _ in range(6):  # bisection: bracket 2 tan(du) / 64
        mid = 0.5 * (lo + hi)
        gm = g(mid)
        left = np.sign(gm) == np.sign(glo)
        lo, glo = np.where(left, mid, lo), np.where(left, gm, glo)
        hi, ghi = np.where(left, hi, mid), np.where(left, ghi, gm)
    s = 0.5 * (lo + hi)
    last = np.zeros(dt.shape, bool)  # the low end was replaced in the previous step
    for it in range(5):  # regula falsi within the bracket (Illinois: no stuck end)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = lo - glo * (hi - lo) / (ghi - glo)
        # converged, the step may leave the bracket by rounding: stay at its end
        s = np.where(np.isfinite(s), np.clip(s, lo, hi), 0.5 * (lo + hi))
        gs = g(s)
        left = np.sign(gs) == np.sign(glo)
        lo, glo = np.where(left, s, lo), np.where(left, gs, glo)
        hi, ghi = np.where(left, hi, s), np.where(left, ghi, gs)
        if it:  # the same end replaced twice: halve the other end's value
            ghi = np.where(left & last, 0.5 * ghi, ghi)
            glo = np.where(~left & ~last, 0.5 * glo, glo)
        last = left
    phi = np.arctan(s)
    near = (np.abs(phi) < 1e-6) | (np.abs(phi) > du - 1e-6)
    use = ok & ~near
    phi = np.where(use, phi, 0.5 * du)
    s = np.where(use, s, np.tan(0.5 * du))
    r = 1.0 / np.sqrt(1.0 + s * s)
    side = np.array([1.0, -1.0])  # left: (-s, 1), right: (s, -1)
    return -side * s * r, side * r, phi


def _directions(n_directions: int, extra, phi):
    """Arrange the uniform directions and the tangent normals in ascending angle.

    ``extra``: (cos, sin) of the left and right tangent normals, (m, P, 2) each, at
    ``pi/2 + phi`` and ``3 pi/2 + phi``; each goes just before or after the uniform
    direction ``pi/2`` (``3 pi/2``) by the sign of ``phi``. Returns a function that lays
    out any per-direction quantity ``(uniform (..., M), extra (m, P, 2))`` as
    (m, P, M + 2) in that order (no sort, no trigonometric function per segment).
    """
    a, b = n_directions // 4, 3 * n_directions // 4
    before = phi < 0  # (m, P, 2)

    def lay(uni, ext):
        shape = ext.shape[:2] + (n_directions,)
        u = np.broadcast_to(uni, shape)
        cols = []
        for j, c in ((0, a), (1, b)):
            e, bf = ext[..., j:j + 1], before[..., j:j + 1]
            cols.append((np.where(bf, e, u[..., c:c + 1]), np.where(bf, u[..., c:c + 1], e)))
        return np.concatenate([u[..., :a], *cols[0], u[..., a + 1:b], *cols[1], u[..., b + 1:]],
                              axis=2)

    return lay


def _band_constants(n_pairs: int, n_directions: int):
    """What every segment's band shares (the numpy code and the compiled kernel alike):
    the sample parameters ``t`` (P + 1,) and their weights ``(1 - t)^2``, ``2 (1 - t) t``,
    ``t^2``; the direction step ``du`` and the uniform directions' cos, sin (M,), exact
    zeros where they vanish."""
    t = np.linspace(0.0, 1.0, n_pairs + 1)
    du = 2.0 * np.pi / n_directions
    ang = du * np.arange(n_directions)
    uc, us = np.cos(ang), np.sin(ang)
    uc[np.abs(uc) < 1e-15], us[np.abs(us) < 1e-15] = 0.0, 0.0
    return t, (1 - t) ** 2, 2 * (1 - t) * t, t * t, du, uc, us


def _pair_polygons(a, b, c4, k: float, n_pairs: int, n_directions: int):
    """Circumscribed polygons of the pair hulls of many segments, in the segment frame.

    Local frame: ``u`` along the segment from ``a``, ``w`` to its left. Returns
    ``(e_u, cs, sn, hp, vu)``: the unit vector along each segment (m, 2); the polygon's
    edge normals ``(cs, sn)`` in ascending angle from 0 (the uniform directions and the
    two tangent normals), the support ``hp`` of the pair hull at each of them and the
    ``u`` of the vertex between edges ``i`` and ``i + 1`` (all (m, P, M + 2)).
    """
    delta = b - a
    length = np.hypot(delta[:, 0], delta[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        e_u = np.where(length[:, None] > 0, delta / length[:, None], [1.0, 0.0])
    c4 = 0.5 * (c4 + np.swapaxes(c4, 1, 2))
    t, t0, t1, t2, du, uc, us = _band_constants(n_pairs, n_directions)
    t, t0, t1, t2 = t[None, :], t0[None, :], t1[None, :], t2[None, :]

    def q(i, j):  # (m, P+1) element (i, j) of F(t) C F(t)'
        return (t0 * c4[:, i, j, None] + 0.5 * t1 * (c4[:, i, 2 + j, None]
                + c4[:, j, 2 + i, None]) + t2 * c4[:, 2 + i, 2 + j, None])

    qxx, qxy, qyy = q(0, 0), q(0, 1), q(1, 1)
    ex, ey = e_u[:, 0, None], e_u[:, 1, None]  # rotate to (u, w): R = [[ex, ey], [-ey, ex]]
    ql = np.empty(qxx.shape + (2, 2))
    ql[..., 0, 0] = ex * ex * qxx + 2 * ex * ey * qxy + ey * ey * qyy
    ql[..., 1, 1] = ey * ey * qxx - 2 * ex * ey * qxy + ex * ex * qyy
    ql[..., 0, 1] = ql[..., 1, 0] = ex * ey * (qyy - qxx) + (ex * ex - ey * ey) * qxy
    tl = t * length[:, None]  # (m, P+1) centres along the segment
    xc, xs, phi = _tangent_normals(tl, ql, k, du)  # (m, P, 2)

    def support(c, s, tl, ql):  # support of ellipses (m, n) in directions (..., d)
        v = c * c * ql[..., 0, 0, None] + 2.0 * c * s * ql[..., 0, 1, None] \
            + s * s * ql[..., 1, 1, None]
        return tl[..., None] * c + k * np.sqrt(np.clip(v, 0.0, None))

    hu = support(uc, us, tl, ql)  # every sampled ellipse at the uniform directions
    hu = np.maximum(hu[:, :-1], hu[:, 1:])
    hx = np.maximum(support(xc, xs, tl[:, :-1], ql[:, :-1]),
                    support(xc, xs, tl[:, 1:], ql[:, 1:]))
    lay = _directions(n_directions, (xc, xs), phi)
    cs, sn, hp = lay(uc, xc), lay(us, xs), lay(hu, hx)
    c1, s1, hn = (np.roll(x, -1, axis=2) for x in (cs, sn, hp))
    det = cs * s1 - sn * c1  # sin of the angle between consecutive directions
    vu = (hp * s1 - hn * sn) / det  # vertex between directions i and i + 1
    return e_u, cs, sn, hp, vu


def _band_chain(cu, cs, sn, hp, sign: float):
    """Envelope of one side's chains: ``sign`` 1 the left (upper), -1 the right side.

    The edge of normal ``(cs, sn)`` (``sn != 0``) is the line
    ``w = (h - u cs) / sn``; the right side is taken as the upper envelope of ``-w``.
    Returns ``(u, w, valid)`` (m, P K): the envelope's vertices where ``valid``, straight
    runs thinned to within ``1e-9`` of the band's scale.
    """
    slope = -sign * cs / sn
    icpt = sign * hp / sn
    u, w = _upper_envelope(cu, slope, icpt)
    valid = np.isfinite(w)
    valid[:, 1:] &= u[:, 1:] > u[:, :-1]  # repeated abscissae: the envelope is equal there
    w = np.where(valid, w, 0.0)
    scale = np.maximum(np.abs(w).max(axis=1), np.ptp(u, axis=1))
    tol = (1e-9 * np.maximum(scale, 1e-300))[:, None]
    return u, sign * w, _drop_collinear(u, w, valid, tol)


def _g_band_flat(a, b, c4, k: float, n_pairs: int, n_directions: int):
    """The rings of :func:`g_band_batch` as one coordinate array and ring offsets.

    Returns ``(xy, offsets)``: ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]`` (closed).
    """
    m = len(a)
    e_u, cs, sn, hp, vu = _pair_polygons(a, b, c4, k, n_pairs, n_directions)
    half = n_directions // 2 + 1  # directions in [0, pi) incl. the left tangent
    # left chain: vertices 0 .. half - 1 (u descending) on the edges 1 .. half - 1;
    # right chain: vertices half .. M + 1 (u ascending) on the edges half + 1 .. M + 1
    rev = slice(half - 1, 0, -1)
    up_u, up_w, up_v = _band_chain(vu[..., half - 1::-1], cs[..., rev], sn[..., rev],
                                   hp[..., rev], 1.0)
    lo_u, lo_w, lo_v = _band_chain(vu[..., half:], cs[..., half + 1:], sn[..., half + 1:],
                                   hp[..., half + 1:], -1.0)
    # ring: right side from u min to u max, then the left side back
    ru = np.concatenate([lo_u, up_u[:, ::-1]], axis=1)
    rw = np.concatenate([lo_w, up_w[:, ::-1]], axis=1)
    rv = np.concatenate([lo_v, up_v[:, ::-1]], axis=1)
    rows, cols = np.nonzero(rv)
    uu, ww = ru[rows, cols], rw[rows, cols]
    ex, ey = e_u[rows, 0], e_u[rows, 1]
    pts = np.column_stack([a[rows, 0] + uu * ex - ww * ey, a[rows, 1] + uu * ey + ww * ex])
    # drop repeated points, then close every ring with its first point
    keep = np.ones(len(pts), bool)
    keep[1:] = (rows[1:] != rows[:-1]) | np.any(pts[1:] != pts[:-1], axis=1)
    pts, rows = pts[keep], rows[keep]
    counts = np.bincount(rows, minlength=m)
    ends = np.cumsum(counts)
    has = counts > 0  # none where the covariance is not finite: an empty ring
    pts = np.insert(pts, ends[has], pts[(ends - counts)[has]], axis=0)
    offsets = np.concatenate([[0], np.cumsum(counts + has)])
    return pts, offsets


def g_band_rings(p1, p2, cov_joint, confidence: float = 0.9, n_pairs: int = 6,
                 n_directions: int = 24, progress=None):
    """:func:`g_band_batch` with the rings as one array: ``(xy, offsets)``.

    Ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]`` (closed, counter-clockwise); ready
    for ``shapely.linearrings(xy, indices=...)`` without a Python list of arrays. The
    parameters are those of :func:`g_band_batch`.

    With numba installed, ``_KERNEL_MIN`` segments or more are built by the compiled
    kernel of :mod:`vectoradjust.accuracy._bandkernel` (the same expressions one segment
    at a time, the same rings: ``tests/test_gband_kernel.py``), fewer, or all when
    ``VECTORADJUST_NUMBA=0``, by the numpy code.

    Returns
    -------
    xy : numpy.ndarray, shape (N, 2)
    offsets : numpy.ndarray of int, shape (m + 1,)
    """
    a = np.asarray(p1, float)
    b = np.asarray(p2, float)
    a = a.reshape(-1, a.shape[-1])[:, :2]
    b = b.reshape(-1, b.shape[-1])[:, :2]
    c4 = np.asarray(cov_joint, float).reshape(-1, 4, 4)
    m = a.shape[0]
    if b.shape[0] != m or c4.shape[0] != m:
        raise ValueError("g_band_batch: p1, p2 and cov_joint must describe the same segments")
    if n_pairs < 1 or n_directions < 8 or n_directions % 4:
        raise ValueError("g_band_batch needs n_pairs >= 1 and n_directions a multiple of 4, >= 8")
    k = prop.confidence_scale(confidence, 2)
    kernel = _ring_kernel() if m >= _KERNEL_MIN else None
    if kernel is not None:
        return _compiled_rings(kernel, a, b, c4, k, n_pairs, n_directions, progress)
    # bounded temporaries: (chunk, P, P (M / 2 + 1)) per chunk
    chunk = max(16, _BAND_BUDGET // (n_pairs * n_pairs * (n_directions // 2 + 1)))
    xys, offs, base = [], [np.zeros(1, np.int64)], 0
    for i in range(0, m, chunk):
        xy, off = _g_band_flat(a[i:i + chunk], b[i:i + chunk], c4[i:i + chunk], k,
                               n_pairs, n_directions)
        xys.append(xy)
        offs.append(off[1:] + base)
        base += len(xy)
        if progress is not None:
            progress(min(i + chunk, m) / m)
    xy = np.concatenate(xys) if xys else np.zeros((0, 2))
    return xy, np.concatenate(offs)


#: segments per call of the compiled ring kernel (progress and cancel in between)
_KERNEL_CHUNK = 8_192
#: fewer segments go to the numpy code (and their union to GEOS): loading the compiled
#: kernels from numba's cache costs about 0.5 s per process (about 20 s the first time,
#: when numba compiles them)
_KERNEL_MIN = 10_000
_KERNEL: list = []  # the compiled kernel once looked for (None: numpy only)
_UNION: list = []  # the compiled union of the rings once looked for (None: GEOS only)


def warm_ring_kernel(n_segments: int, progress: Optional[Callable[[str], None]] = None) -> bool:
    """Load (or compile, the first time) the compiled band kernels now - the rings
    (:func:`_ring_kernel`) and their union per feature (:func:`_union_kernel`) - if the
    bands of ``n_segments`` segments will use them; e.g. once in a parent before it
    forks the processes that build the bands. True if both are ready.

    ``progress(message)`` is called before they are looked for (once per process):
    loading takes about 0.5 s, compiling the first time after installation about 20 s.
    """
    if n_segments < _KERNEL_MIN:
        return False
    if not (_KERNEL and _UNION) and progress is not None and not _numba_off():
        progress("loading the compiled band kernels (compiled once after installing)")
    return _ring_kernel() is not None and _union_kernel() is not None


def _numba_off() -> bool:
    """``VECTORADJUST_NUMBA=0`` (or ``no``, ``false``): the numpy code only."""
    return os.environ.get("VECTORADJUST_NUMBA", "1").strip().lower() in ("0", "no", "false")


def _load_kernel(slot: list, load: Callable, trial: Callable, what: str, instead: str):
    """A compiled kernel, looked for once per process and remembered in ``slot``:
    ``load()`` imports its module (ImportError: no numba), ``trial(module)`` calls it
    once - compiled now or loaded from numba's cache - and returns it. None (the
    fallback ``instead`` runs) with ``VECTORADJUST_NUMBA=0``, without numba, or when
    numba cannot compile or cache it (a ``RuntimeWarning`` says why)."""
    if _numba_off():
        return None
    if not slot:
        try:
            module = load()
        except ImportError:  # no numba (e.g. QGIS's Python): the fallback
            slot.append(None)
            return None
        try:
            kernel = trial(module)
        except Exception as exc:  # noqa: BLE001 - any failure of numba: the fallback
            import warnings

            warnings.warn(f"{what} is not available ({exc!r}); {instead}", RuntimeWarning,
                          stacklevel=3)
            slot.append(None)
        else:
            slot.append(kernel)
    return slot[0]


def _ring_kernel():
    """The compiled ring kernel (:mod:`._bandkernel`, numba), loaded from numba's cache
    or compiled (about 8 s, once), or None: no numba, or numba cannot compile it here (a
    warning says why).

    Looked for once per process. ``VECTORADJUST_NUMBA=0`` in the environment keeps the
    numpy code (e.g. to compare the two).
    """
    def load():
        from vectoradjust.accuracy import _bandkernel

        return _bandkernel

    def trial(module):
        _compiled_rings(module.rings, np.zeros((1, 2)), np.ones((1, 2)), np.eye(4)[None],
                        1.0, 6, 24, None)
        return module.rings

    return _load_kernel(_KERNEL, load, trial, "the compiled G-band kernel",
                        "the bands are built by the numpy code (the same rings, slower)")


def _union_kernel():
    """The compiled union of the segment rings of each feature
    (:func:`._unionkernel.union_rings`, numba), loaded from numba's cache or compiled
    (about 11 s, once), or None: no numba, ``VECTORADJUST_NUMBA=0``, or numba cannot
    compile it here (a warning says why); the bands are then united by GEOS. Looked for
    once per process.
    """
    def load():
        from vectoradjust.accuracy import _unionkernel

        return _unionkernel

    def trial(module):  # two overlapping squares
        sq = np.array([[0.0, 0], [2, 0], [2, 1], [0, 1], [0, 0]])
        module.union_rings(np.concatenate([sq, sq + 1]), np.array([0, 5, 10]),
                           np.array([0, 2]), np.ones(2, np.int8), 1e-10)
        return module.union_rings

    return _load_kernel(_UNION, load, trial, "the compiled union of the bands",
                        "GEOS unites them (the same bands, slower)")


def _compiled_rings(kernel, a, b, c4, k, n_pairs, n_directions, progress):
    """:func:`g_band_rings` by the compiled kernel, ``_KERNEL_CHUNK`` segments a call;
    the few segments it leaves (an input or a point not finite) by the numpy code."""
    m = a.shape[0]
    t, t0, t1, t2, du, uc, us = _band_constants(n_pairs, n_directions)
    const = (k, t, t0, t1, t2, uc, us, float(np.tan(du)), float(np.tan(0.5 * du)), du)
    xys, counts = [], []
    for i in range(0, m, _KERNEL_CHUNK):
        j = min(i + _KERNEL_CHUNK, m)
        xy, cnt, ok = kernel(np.ascontiguousarray(a[i:j]), np.ascontiguousarray(b[i:j]),
                             np.ascontiguousarray(c4[i:j]), *const)
        if not ok.all():
            xy, cnt = _splice(xy, cnt, ok, *_g_band_flat(
                a[i:j][~ok], b[i:j][~ok], c4[i:j][~ok], k, n_pairs, n_directions))
        xys.append(xy)
        counts.append(cnt)
        if progress is not None:
            progress(j / m)
    xy = np.concatenate(xys) if xys else np.zeros((0, 2))
    return xy, np.concatenate([np.zeros(1, np.int64), np.cumsum(np.concatenate(counts or [
        np.zeros(0, np.int64)]))])


def _splice(xy, cnt, ok, xy_b, off_b):
    """Rings ``(xy, cnt)`` of the rows ``ok`` and ``(xy_b, off_b)`` of the others, put
    together in row order."""
    cnt = np.asarray(cnt, np.int64).copy()
    cnt[~ok] = np.diff(off_b)
    start = np.empty(len(cnt), np.int64)  # first point of each row in [xy; xy_b]
    start[ok] = np.cumsum(cnt[ok]) - cnt[ok]
    start[~ok] = off_b[:-1] + len(xy)
    src = np.concatenate([xy, xy_b])
    take = np.repeat(start - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))
    return src[take], cnt


def g_band_batch(p1, p2, cov_joint, confidence: float = 0.9, n_pairs: int = 6,
                 n_directions: int = 24, progress=None) -> list:
    """G-bands (Shi & Liu 2000) of many line segments at once.

    The band of a segment is the union over ``t`` in ``[0, 1]`` of the error ellipses
    (scaled by ``k = sqrt(chi2_2(confidence))``) of ``P(t) = (1 - t) P1 + t P2``, whose
    covariance is ``F(t) C F(t)'`` with ``F(t) = [(1 - t) I, t I]``.

    Construction (outer approximation, vectorised over segments): the support function
    of the ellipse of ``P(t)`` is convex in ``t`` (a norm of an affine function of ``t``
    plus an affine term), so every ellipse between two samples ``t_j, t_{j+1}`` lies in
    the convex hull of the two sampled ellipses. Each of the ``n_pairs`` hulls is
    replaced by the polygon circumscribed at ``n_directions`` uniform directions plus the
    normals of the two common tangents along the band's sides (bisection, then regula
    falsi), so it contains the hull, follows its straight sides and exceeds its round
    caps by at most ``1 / cos(pi / n_directions) - 1`` of the ellipse size. The band's
    ring is the upper and lower envelope of these polygons along the segment, evaluated
    exactly at every polygon vertex (each polygon side is a maximum / minimum of its edge
    lines); between two such stations the envelope is a maximum of linear pieces, which
    the chord bounds from outside. Stations on straight runs are then dropped where the
    ring moves by at most ``1e-9`` of the band's scale. The ring therefore contains every
    ellipse of the band (to that tolerance), in particular those of the two end points.
    It exceeds the exact band where the band narrows between samples (the waist,
    ``O(1 / n_pairs^2)``): on road segments about 0.5 % of the area with the defaults,
    0.3 % with 8 pairs and 32 directions. Like :func:`vectoradjust.accuracy.propagate.g_band`
    it assumes that every line normal to the segment cuts the band in one interval (true
    unless the segment is shorter than its ellipses).

    Parameters
    ----------
    p1, p2 : array_like, shape (m, 2) or (m, d)
        End points (X, Y used).
    cov_joint : array_like, shape (m, 4, 4)
        Joint covariance of ``[X1, Y1, X2, Y2]`` per segment.
    confidence : float
        Probability of the ellipses (2 degrees of freedom); 0.9 gives ``k = 2.146``.
    n_pairs : int
        Number of ``t`` intervals (``n_pairs + 1`` sampled ellipses).
    n_directions : int
        Uniform directions of the circumscribed polygons (a multiple of 4, >= 8).
    progress : callable, optional
        ``progress(fraction)`` after every chunk of segments (about 1000 with the
        defaults; fewer with more pairs or directions, so that the temporaries stay
        bounded). It may raise to cancel, e.g. :class:`vectoradjust.errors.CancelledError`.

    Returns
    -------
    list of numpy.ndarray
        One closed ring ``(k, 2)`` per segment (first point repeated), counter-clockwise.
        :func:`g_band_rings` gives the same rings as one array with offsets.
    """
    xy, offsets = g_band_rings(p1, p2, cov_joint, confidence, n_pairs, n_directions,
                               progress)
    if len(offsets) < 2:
        return []
    return np.split(xy, offsets[1:-1])


class _Rings(Sequence):
    """The rings of :func:`g_band_rings` as a read-only list of arrays (views, made on use)."""

    def __init__(self, xy: np.ndarray, offsets: np.ndarray) -> None:
        self._xy, self._off = xy, offsets

    def __len__(self) -> int:
        return max(len(self._off) - 1, 0)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        if not -len(self) <= i < len(self):
            raise IndexError("ring index out of range")
        i = i % len(self)
        return self._xy[self._off[i]:self._off[i + 1]]


@dataclass
class SegmentBands:
    """G-bands of the segments of a road database (:func:`segment_bands`).

    Attributes
    ----------
    feature : numpy.ndarray of int, shape (s,)
        Feature index of each segment.
    start_vertex : numpy.ndarray of int, shape (s,)
        First vertex of each segment (the segment runs to ``start_vertex + 1``).
    rings : sequence of numpy.ndarray
        Closed ring ``(k, 2)`` of each segment's band (a read-only list).
    cov_joint : numpy.ndarray, shape (s, 6, 6)
        Joint a-posteriori covariance of the segment's end points (X1, Y1, Z1, X2, ...).
    confidence : float
    xy, offsets : numpy.ndarray, optional
        The same rings as one array: ring ``i`` is ``xy[offsets[i]:offsets[i + 1]]``
        (:func:`g_band_rings`).
    """

    feature: np.ndarray
    start_vertex: np.ndarray
    rings: list
    cov_joint: np.ndarray
    confidence: float
    xy: Optional[np.ndarray] = None
    offsets: Optional[np.ndarray] = None


@dataclass
class SegmentCovariances:
    """Covariance blocks of the measured segments of a road database
    (:func:`segment_covariances`): everything :func:`segment_bands` takes from the
    factorisation, computed once so that the bands can be built after it is let go.

    ``start`` (s,) are the segments' first vertices (ascending), ``cross`` (s, 3, 3) the
    covariances ``Cov(x_a, x_b)`` of their end points, ``own_a`` / ``own_b`` (s, 3, 3)
    their own blocks when the result keeps no ``point_cov`` (None otherwise).
    """

    start: np.ndarray
    cross: np.ndarray
    own_a: Optional[np.ndarray] = None
    own_b: Optional[np.ndarray] = None


def _measured_segments(db: DatabaseResult, part: tuple = (0, 1)) -> np.ndarray:
    """First vertices of the segments with both end points measured (distinct points),
    of the features ``i`` modulo ``n`` (``part = (i, n)``)."""
    vp = np.asarray(db.vertex_point, np.int64)
    a = _part_segments(db, part)
    if a.size:
        a = a[(vp[a] >= 0) & (vp[a + 1] >= 0) & (vp[a] != vp[a + 1])]
    return a


def _part_segments(db: DatabaseResult, part: tuple = (0, 1)) -> np.ndarray:
    """:func:`_segments` of the features ``i`` modulo ``n`` (``part = (i, n)``)."""
    a = _segments(db)
    if part[1] > 1 and a.size:
        a = a[np.asarray(db.shape.layer.vertex_feature)[a] % part[1] == part[0]]
    return a


def vertex_covariance(db: DatabaseResult) -> Optional[np.ndarray]:
    """The covariance (nv, 3, 3) of every vertex that its ``CE90`` / ``LE90`` state.

    Built from ``d.vertices``: the sigmas ``SigmaX/Y/Z`` on the diagonal (a measured
    vertex: the adjustment's covariance, the database offsets' share included, plus the
    identification error; a conflated one: the collocation's prediction error with the
    database noise and the trend's error, :mod:`vectoradjust.accuracy.conflation`), the
    horizontal block scaled so that its CE90 is the vertex's ``CE90`` (for a conflated
    vertex the CE90 of the predictive distribution, a little wider than the plug-in
    normal's). NaN where the vertex has no value (unmeasured and not conflated).

    Returns
    -------
    numpy.ndarray or None
        None before the vertices are tabulated (``d.vertices`` empty).
    """
    v = db.vertices
    if not v or "SigmaX" not in v or "CE90" not in v:
        return None
    sig = np.column_stack([np.asarray(v[f"Sigma{a}"], float) for a in "XYZ"])
    cov = np.zeros((len(sig), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = sig ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        ce_diag = stats.ce90(cov[:, :2, :2])
        f = np.asarray(v["CE90"], float) / ce_diag
    f = np.where(np.isfinite(f) & (f > 0), f, 1.0)
    cov[:, :2, :2] *= (f * f)[:, None, None]
    cov[~np.isfinite(sig[:, :2]).all(axis=1)] = np.nan
    return cov


def _identification_blocks(cov: np.ndarray, idv: np.ndarray) -> np.ndarray:
    """``cov`` (s, 6, 6) of segments' two measured end points plus the identification
    error of each (independent per object point: the two ends are distinct points)."""
    out = cov.copy()
    d = np.concatenate([idv, idv])
    out[:, np.arange(6), np.arange(6)] += d
    return out


def _other_segments(run: AdjustmentRun, db: DatabaseResult, part: tuple):
    """The segments with an end point that was not measured but has a covariance (the
    conflation predicted it): first vertices (s,), end points and joint covariances
    (s, 6, 6); None before the conflation.

    A conflated vertex's error is a smooth field plus the database's white noise; the
    two ends of a segment (tens of metres apart, the field's range hundreds) are taken
    as fully correlated, ``C_ab = C_a^1/2 C_b^1/2``: the band between them is then the
    linear interpolation of their ellipses (the widest the two ends allow), never the
    narrower band of independent ends.
    """
    vc = vertex_covariance(db)
    if vc is None:
        return None
    vp = np.asarray(db.vertex_point, np.int64)
    vo = np.asarray(db.shape.vertex_object)
    a = _part_segments(db, part)
    if a.size:
        both = (vp[a] >= 0) & (vp[a + 1] >= 0)
        ok = np.isfinite(vc[a, 0, 0]) & np.isfinite(vc[a + 1, 0, 0])
        a = a[~both & ok & (vo[a] != vo[a + 1])]
    adj = _adjusted_coords(run, db)
    ca, cb = vc[a], vc[a + 1]
    sa = np.sqrt(np.einsum("sii->si", ca))
    sb = np.sqrt(np.einsum("sii->si", cb))
    cov = np.zeros((a.size, 6, 6))
    cov[:, :3, :3], cov[:, 3:, 3:] = ca, cb
    cross = np.zeros((a.size, 3, 3))
    cross[:, [0, 1, 2], [0, 1, 2]] = sa * sb
    cov[:, :3, 3:], cov[:, 3:, :3] = cross, cross
    return a, adj[a], adj[a + 1], cov


def segment_covariances(run: AdjustmentRun, db: DatabaseResult,
                        part: tuple = (0, 1)) -> SegmentCovariances:
    """The covariance blocks :func:`segment_bands` needs, for every measured segment.

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    part : (int, int)
        Only the segments of :func:`segment_bands` with the same ``part``.

    Returns
    -------
    SegmentCovariances
    """
    res = run.result
    _check_result(res)
    vp = np.asarray(db.vertex_point, np.int64)
    a = _measured_segments(db, part)
    pa, pb = vp[a], vp[a + 1]
    own = res.point_cov is None
    return SegmentCovariances(a, cross_covariance(res, pa, pb),
                              cross_covariance(res, pa, pa) if own else None,
                              cross_covariance(res, pb, pb) if own else None)


def segment_bands(run: AdjustmentRun, db: DatabaseResult, confidence: float = 0.9,
                  part: tuple = (0, 1), covariances: Optional[dict] = None,
                  segments: str = "all", **kwargs) -> SegmentBands:
    """G-band of every segment of a road database, from the covariance of its vertices'
    CE90/LE90.

    A segment whose two end points were measured: the joint 6x6 covariance of the
    adjusted points from :func:`cross_covariance` (their own blocks and the cross
    block, the database offsets' share included), plus the identification error
    (``identification_sigma``, independent per object point) on each end - the band of
    the real road, as the vertices' CE90 is. A segment with an end that the conflation
    predicted: the conflated vertices' covariance (:func:`vertex_covariance`, fully
    correlated ends, :func:`_other_segments`); these exist only once the run is
    conflated (before, e.g. in the command line's band processes started right after
    the adjustment, only the measured segments get bands). A segment with an end
    without any covariance (not measured, not conflated) or whose two vertices are one
    object point gets none.

    The ellipses are drawn at :func:`band_scale` (``confidence`` of the error across
    the line: 1.645 sigma at 90 %).

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    confidence : float
        Probability that the band holds the true road at a point of it (0.9 = 90 %).
    part : (int, int)
        ``(i, n)``: only the segments of the features whose index is ``i`` modulo ``n``
        (``n`` processes share the work; default all).
    covariances : dict, optional
        :class:`SegmentCovariances` by database name (:func:`segment_covariances`):
        taken from there instead of the factorisation, which may then be let go.
    segments : {"all", "measured", "other"}
        Which segments: both (default), those with two measured ends, or the others.
    **kwargs
        ``n_pairs``, ``n_directions``, ``progress`` of :func:`g_band_batch`.

    Returns
    -------
    SegmentBands
        Segments in the order of the layer (ascending first vertex).
    """
    if segments not in ("all", "measured", "other"):
        raise ValueError("segment_bands: segments must be 'all', 'measured' or 'other'")
    starts, p1s, p2s, covs = [], [], [], []
    if segments != "other":
        a, p1, p2, cov = _measured_joint(run, db, part, covariances)
        starts.append(a), p1s.append(p1), p2s.append(p2), covs.append(cov)
    other = _other_segments(run, db, part) if segments != "measured" else None
    if other is not None:
        starts.append(other[0]), p1s.append(other[1]), p2s.append(other[2])
        covs.append(other[3])
    if not starts:
        starts, p1s, p2s, covs = ([np.zeros(0, np.int64)], [np.zeros((0, 3))],
                                  [np.zeros((0, 3))], [np.zeros((0, 6, 6))])
    a = np.concatenate(starts)
    order = np.argsort(a, kind="stable")
    a, cov = a[order], np.concatenate(covs)[order]
    p1, p2 = np.concatenate(p1s)[order], np.concatenate(p2s)[order]
    sel = [0, 1, 3, 4]
    xy, offsets = g_band_rings(p1, p2, cov[:, sel][:, :, sel], _ellipse_confidence(confidence),
                               **kwargs)
    return SegmentBands(db.shape.layer.vertex_feature[a], a, _Rings(xy, offsets), cov,
                        confidence, xy, offsets)


def band_scale(confidence: float) -> float:
    """The factor of the sigmas that a road's G-band of ``confidence`` draws:
    ``Phi^-1((1 + c) / 2)``, 1.645 at 90 %.

    The band is a statement about the line: where the true road runs, i.e. its error
    across the line, one dimension (an error along the line moves a point along it, still
    on the line). The two-dimensional scale of a point's 90 % ellipse (2.146) made the
    band hold the true road at 95-97 % of its vertices on real road geometry
    (validation/bands_lengths.py), this one at 86-89 %.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError("the band's confidence must lie between 0 and 1")
    return float(ndtri(0.5 + 0.5 * confidence))


def _ellipse_confidence(confidence: float) -> float:
    """The probability of the 2-D ellipses :func:`g_band_rings` draws at
    :func:`band_scale` (``1 - exp(-k^2 / 2)``)."""
    k = band_scale(confidence)
    return float(1.0 - np.exp(-0.5 * k * k))


def band_segment_counts(run: AdjustmentRun, db: DatabaseResult) -> tuple[int, int]:
    """How many segments of a database :func:`segment_bands` gives a band: with two
    measured ends, and with a conflated end (0 before the conflation)."""
    other = _other_segments(run, db, (0, 1))
    return int(_measured_segments(db).size), 0 if other is None else int(other[0].size)


def _measured_joint(run: AdjustmentRun, db: DatabaseResult, part: tuple,
                    covariances: Optional[dict]):
    """First vertices, end points and joint covariances (s, 6, 6) of the segments with
    two measured ends, the identification error included (:func:`segment_bands`)."""
    res = run.result
    kept = None if covariances is None else covariances.get(db.name)
    if kept is None:  # from the factorisation now
        kept = segment_covariances(run, db, part)
    vp = np.asarray(db.vertex_point, np.int64)
    a = _measured_segments(db, part)
    pa, pb = vp[a], vp[a + 1]
    row = np.searchsorted(kept.start, a)
    if np.any(row >= len(kept.start)) or np.any(
            kept.start[np.minimum(row, max(len(kept.start) - 1, 0))] != a):
        raise ValueError(f"segment_bands: the covariances given are not those of "
                         f"database {db.name!r}")
    cov = np.zeros((a.size, 6, 6))
    if a.size:
        own = kept.own_a is None  # the points' own blocks from point_cov
        cov[:, :3, :3] = res.point_cov[pa] if own else kept.own_a[row]
        cov[:, 3:, 3:] = res.point_cov[pb] if own else kept.own_b[row]
        cab = kept.cross[row]
        cov[:, :3, 3:] = cab
        cov[:, 3:, :3] = np.swapaxes(cab, 1, 2)
    cov = _identification_blocks(cov, _identification_variance(db))
    return a, res.xyz[pa], res.xyz[pb], cov


def uncertainty_bands(run: AdjustmentRun, db: DatabaseResult,
                      confidence: float = 0.9, **kwargs) -> list:
    """G-band rings of the measured segments of every feature (Shi & Liu 2000).

    Parameters
    ----------
    run : AdjustmentRun
    db : DatabaseResult
    confidence : float
        Probability of the error ellipses (default 90 %).
    **kwargs
        ``n_pairs``, ``n_directions`` of :func:`g_band_batch`.

    Returns
    -------
    list of (int, numpy.ndarray)
        ``(feature index, closed ring (k, 2))`` per segment; the union of a feature's
        rings is its uncertainty band (:mod:`vectoradjust.files.derived_outputs` forms it).
    """
    sb = segment_bands(run, db, confidence, **kwargs)
    return [(int(f), r) for f, r in zip(sb.feature, sb.rings)]


# --------------------------------------------------------------- quantities between ids
@dataclass
class DerivedValue:
    """A derived quantity with its sigma with and without covariances between points.

    Attributes
    ----------
    quantity : str
        What it is (``"distance 2D"``, ``"length"``, ``"mean height"``).
    value : float
    sigma : float
        With the full covariance of the points.
    sigma_no_cov : float
        With each point's own covariance block only.
    point_ids : list of str
        The ids as given.
    points : numpy.ndarray of int
        Bundle point indices.
    """

    quantity: str
    value: float
    sigma: float
    sigma_no_cov: float
    point_ids: list
    points: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"quantity": self.quantity, "value": float(self.value),
                "sigma": float(self.sigma), "sigma_no_cov": float(self.sigma_no_cov),
                "ratio": (float(self.sigma / self.sigma_no_cov)
                          if self.sigma_no_cov > 0 else None),
                "point_ids": [str(p) for p in self.point_ids],
                "points": [int(p) for p in self.points]}


def resolve_points(run: AdjustmentRun, ids: Sequence[str]) -> np.ndarray:
    """Bundle point index of each given point id.

    An id may be a control or tie point id, the canonical id of a shape point or the
    id ``<feature id>_<vertex index>`` of any vertex of an object point, optionally
    qualified by its database (``OSM:123_4``).

    Raises
    ------
    MeasurementError
        For an id that is not an adjusted point, or a shape point id that several
        databases share.
    """
    ids = np.asarray([str(i) for i in ids], dtype=object).astype(str)
    from vectoradjust.adjust.shapepoints import lookup

    out = lookup(run.point_ids, ids)
    for i in np.flatnonzero(out < 0):
        pid = str(ids[i])
        found = []
        for d in run.databases:
            q = pid
            if ":" in pid:
                name, _, rest = pid.partition(":")
                if name != d.name:
                    continue
                q = rest
            v = lookup(d.shape.vertex_ids, np.array([q]))[0]
            if v >= 0:
                found.append((d.name, int(d.vertex_point[v])))
        if len(found) > 1:
            raise MeasurementError(
                f"Point id {pid!r} is a shape point id of several road databases "
                f"({', '.join(n for n, _ in found)})",
                f"Qualify it with the database name, e.g. '{found[0][0]}:{pid}'",
            )
        if not found:
            raise MeasurementError(
                f"Point id {pid!r} is not a point of the adjustment (not a control, tie or "
                "shape point id of this project)",
                "Give the id of a measured point: a control or tie point id, or a shape point "
                "id '<feature id>_<vertex index>' (qualified 'NAME:...' if ambiguous)",
            )
        name, p = found[0]
        if p < 0:
            raise MeasurementError(
                f"Shape point {pid!r} of {name} was not measured on the images, so it was not "
                "adjusted and has no covariance",
                "Choose a shape point that was measured (Adjusted = 1 in shape_points)",
            )
        out[i] = p
    return out


def _point_identification(run: AdjustmentRun, points: np.ndarray) -> np.ndarray:
    """Identification variance (p, 3) of bundle points: their database's for shape
    points (the real road vertex, as their CE90), zero for control and tie points."""
    out = np.zeros((len(points), 3))
    kind = np.asarray(getattr(run, "point_kind", []))
    dbname = np.asarray(getattr(run, "point_database", []))
    if len(kind) == 0 or len(points) == 0:
        return out
    for d in run.databases:
        m = (kind[points] == "shape") & (dbname[points].astype(str) == d.name)
        out[m] = _identification_variance(d)
    return out


def _joint(run: AdjustmentRun, points: np.ndarray) -> np.ndarray:
    """Joint covariance ``(3p, 3p)`` of ``points``; a point may be repeated.

    The adjustment's covariance plus the identification error of each shape point
    (independent from point to point, the same for a repeated point): that of the
    points' CE90/LE90.
    """
    pts = np.asarray(points, np.int64).reshape(-1)
    upts, inv = np.unique(pts, return_inverse=True)
    c = run.result.joint_covariance(upts).reshape(len(upts), 3, len(upts), 3)
    idv = _point_identification(run, upts)
    c[np.arange(len(upts)), :, np.arange(len(upts)), :] += idv[:, :, None] * np.eye(3)
    inv = np.asarray(inv).reshape(-1)
    return c[np.ix_(inv, [0, 1, 2], inv, [0, 1, 2])].reshape(3 * len(pts), 3 * len(pts))


def distance_between(run: AdjustmentRun, id_a: str, id_b: str, dims: int = 2) -> DerivedValue:
    """Distance between two adjusted points (2D or 3D) with its sigma.

    ``F = [dx/D, dy/D, (dz/D), -dx/D, ...]`` applied to the joint 6x6 covariance
    (:func:`vectoradjust.accuracy.propagate.distance`).

    Parameters
    ----------
    run : AdjustmentRun
    id_a, id_b : str
        Point ids (see :func:`resolve_points`).
    dims : {2, 3}
    """
    pts = resolve_points(run, [id_a, id_b])
    xyz = run.result.xyz[pts]
    r = prop.distance(xyz[0], xyz[1], _joint(run, pts), dims=dims)
    return DerivedValue(f"distance {dims}D", float(r.value), float(r.sigma),
                        float(r.sigma_no_cov), [id_a, id_b], pts)


def length_between(run: AdjustmentRun, ids: Sequence[str], dims: int = 2) -> DerivedValue:
    """Length of the polyline through the given adjusted points, with its sigma.

    Parameters
    ----------
    run : AdjustmentRun
    ids : sequence of str
        At least two point ids, in order along the line.
    dims : {2, 3}
        Horizontal (default) or 3D length.
    """
    if len(ids) < 2:
        raise MeasurementError("A length needs at least two point ids",
                               "Give the ids of the points in order along the line")
    pts = resolve_points(run, ids)
    r = prop.polyline_length(run.result.xyz[pts], _joint(run, pts), dims=dims)
    return DerivedValue("length" if dims == 2 else "length 3D", float(r.value), float(r.sigma),
                        float(r.sigma_no_cov), list(ids), pts)


def mean_height_between(run: AdjustmentRun, ids: Sequence[str]) -> DerivedValue:
    """Average height of a set of adjusted points, with its sigma."""
    if len(ids) < 1:
        raise MeasurementError("A mean height needs at least one point id",
                               "Give the ids of the points")
    pts = resolve_points(run, ids)
    c = _joint(run, pts)
    iz = 3 * np.arange(len(pts)) + 2
    r = prop.mean_height(run.result.xyz[pts, 2], c[np.ix_(iz, iz)])
    return DerivedValue("mean height", float(r.value), float(r.sigma), float(r.sigma_no_cov),
                        list(ids), pts)


@dataclass
class FeatureProfile:
    """Height profile along one feature of the adjusted geometry (:func:`profile`).

    Per vertex (all vertices of the feature, in order): ``part``, ``chainage``
    (horizontal distance from the start of its part), ``z``, ``sigma_z``,
    ``sigma_chainage`` and ``sigma_chainage_no_cov``, ``adjusted`` (measured or not;
    conflated vertices have their own sigma, vertices without a value are fixed).
    Plus the mean height of the adjusted vertices and the rise (last minus first
    adjusted vertex) with their sigmas with and without covariances.
    """

    database: str
    feature_id: str
    feature: int
    vertex_ids: np.ndarray
    part: np.ndarray
    chainage: np.ndarray
    z: np.ndarray
    sigma_z: np.ndarray
    sigma_chainage: np.ndarray
    sigma_chainage_no_cov: np.ndarray
    adjusted: np.ndarray
    mean_height: Optional[DerivedValue] = None
    rise: Optional[DerivedValue] = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN as None)."""
        def col(a):
            return [None if (isinstance(v, float) and not np.isfinite(v)) else v
                    for v in np.asarray(a).tolist()]
        return {
            "database": self.database, "feature_id": self.feature_id,
            "vertices": [
                {"point_id": str(i), "part": int(p), "chainage": c, "z": z,
                 "sigma_z": s, "sigma_chainage": sc, "sigma_chainage_no_cov": sn,
                 "adjusted": bool(a)}
                for i, p, c, z, s, sc, sn, a in zip(
                    self.vertex_ids, self.part, col(self.chainage), col(self.z),
                    col(self.sigma_z), col(self.sigma_chainage),
                    col(self.sigma_chainage_no_cov), self.adjusted)],
            "mean_height": self.mean_height.to_dict() if self.mean_height else None,
            "rise": self.rise.to_dict() if self.rise else None,
        }


def _find_feature(run: AdjustmentRun, feature_id: str, database: Optional[str]):
    dbs = run.databases
    if database is not None:
        dbs = [d for d in dbs if d.name == database]
        if not dbs:
            raise ProjectError(
                f"There is no road database named {database!r} in this run",
                f"Use one of: {', '.join(d.name for d in run.databases) or '(none)'}",
            )
    hits = []
    for d in dbs:
        f = np.flatnonzero(d.shape.layer.feature_ids == str(feature_id))
        if f.size:
            hits.append((d, int(f[0])))
    if not hits:
        raise LayerError(
            f"No feature with id {feature_id!r} in "
            + (f"database {database!r}" if database else "the road databases of this run"),
            "Give a feature id of the id field (id_field of the [[vectors]] entry) or a "
            "0-based feature index when the layer has no id field",
        )
    if len(hits) > 1:
        raise LayerError(
            f"Feature id {feature_id!r} exists in several road databases "
            f"({', '.join(d.name for d, _ in hits)})",
            "Name the database (--database NAME)",
        )
    return hits[0]


def profile(run: AdjustmentRun, feature_id: str,
            database: Optional[str] = None) -> FeatureProfile:
    """Height profile along a feature with the sigma of every vertex.

    Each part of the feature is profiled with
    :func:`vectoradjust.accuracy.propagate.height_profile` on the covariance of its
    vertices' CE90/LE90: the joint covariance of the measured ones with their
    identification error (:func:`_joint`), each conflated vertex's own covariance
    (:func:`vertex_covariance`; no covariance between them or with the measured ones),
    vertices without a value fixed. Also the mean height of the measured vertices and
    the rise between the first and last measured vertex.

    Parameters
    ----------
    run : AdjustmentRun
    feature_id : str
        Feature id (the id field's value).
    database : str, optional
        Road database; needed only when the id exists in several.

    Returns
    -------
    FeatureProfile
    """
    db, f = _find_feature(run, feature_id, database)
    layer = db.shape.layer
    verts = np.flatnonzero(layer.vertex_feature == f)
    if verts.size == 0:
        raise LayerError(f"Feature {feature_id!r} of {db.name} has no vertices "
                         f"({layer.problems.get(f, 'empty geometry')})",
                         "Choose a feature with a line geometry")
    adj = _adjusted_coords(run, db)[verts]
    vp = np.asarray(db.vertex_point, np.int64)[verts]
    meas = vp >= 0
    nv = verts.size
    full = np.zeros((nv, 3, nv, 3))
    if meas.any():
        mi = np.flatnonzero(meas)
        full[np.ix_(mi, [0, 1, 2], mi, [0, 1, 2])] = \
            _joint(run, vp[mi]).reshape(mi.size, 3, mi.size, 3)
    vc = vertex_covariance(db)
    conf = np.zeros(nv, bool) if vc is None else (~meas & np.isfinite(vc[verts, 0, 0]))
    if conf.any():  # conflated vertices: their own covariance (as their CE90 / LE90)
        ci = np.flatnonzero(conf)
        full[ci, :, ci, :] = vc[verts[ci]]
    cov = full.reshape(3 * nv, 3 * nv)
    part = layer.vertex_part[verts]
    chain = np.zeros(nv)
    sz = np.zeros(nv)
    sc = np.zeros(nv)
    scn = np.zeros(nv)
    for p in np.unique(part):  # parts of one feature (usually one)
        sel = np.flatnonzero(part == p)
        ci = (3 * sel[:, None] + np.arange(3)).ravel()
        pr = prop.height_profile(adj[sel], cov[np.ix_(ci, ci)])
        chain[sel], sz[sel] = pr.chainage, pr.sigma_z
        sc[sel], scn[sel] = pr.sigma_chainage, pr.sigma_chainage_no_cov
    sz = np.where(meas | conf, sz, np.nan)
    out = FeatureProfile(db.name, str(feature_id), f, db.shape.vertex_ids[verts], part, chain,
                         adj[:, 2].copy(), sz, sc, scn, meas)
    if meas.any():
        mi = np.flatnonzero(meas)
        iz = 3 * mi + 2
        mh = prop.mean_height(adj[mi, 2], cov[np.ix_(iz, iz)])
        ids = list(db.shape.vertex_ids[verts][mi])
        out.mean_height = DerivedValue("mean height", mh.value, mh.sigma, mh.sigma_no_cov,
                                       ids, vp[mi])
        if mi.size >= 2:
            i0, i1 = iz[0], iz[-1]
            c2 = cov[np.ix_([i0, i1], [i0, i1])]
            g = np.array([-1.0, 1.0])
            out.rise = DerivedValue(
                "rise", float(adj[mi[-1], 2] - adj[mi[0], 2]),
                float(np.sqrt(max(g @ c2 @ g, 0.0))),
                float(np.sqrt(max(c2[0, 0] + c2[1, 1], 0.0))),
                [ids[0], ids[-1]], vp[[mi[0], mi[-1]]])
    return out


# ----------------------------------------------------------------------- equal error map
class EqualErrorGrid(NamedTuple):
    """Equal-error map of a stereo pair (:func:`equal_error_grid`).

    ``X, Y`` are the grid nodes (pixel centres; row 0 is the northernmost), the sigmas
    (m) are NaN outside the stereo overlap, ``transform`` is the affine geotransform of
    the pixel grid in ``Affine(a, b, c, d, e, f)`` order:
    ``x = a col + b row + c``, ``y = d col + e row + f`` (pixel corners).
    """

    X: np.ndarray
    Y: np.ndarray
    sigma_x: np.ndarray
    sigma_y: np.ndarray
    sigma_z: np.ndarray
    transform: tuple


def _frame_mm(run: AdjustmentRun, frame_mm) -> np.ndarray:
    if frame_mm is not None:
        return np.broadcast_to(np.asarray(frame_mm, float), (2,)).copy()
    cal = getattr(run.data.camera, "calibration", None)
    px = getattr(cal, "pixel_size", None) if not isinstance(cal, dict) else cal.get("pixel_size")
    sz = getattr(cal, "image_size", None) if not isinstance(cal, dict) else cal.get("image_size")
    if px is not None and sz is not None:
        return np.broadcast_to(np.asarray(px, float), (2,)) * np.asarray(sz, float)
    return np.array([DEFAULT_FRAME_MM, DEFAULT_FRAME_MM])


def image_footprint(eo, focal_length: float, frame_mm, z: float,
                    principal_point=(0.0, 0.0)) -> np.ndarray:
    """Ground footprint of a frame image on the plane ``Z = z``.

    Parameters
    ----------
    eo : array_like, shape (6,)
        ``XL, YL, ZL, omega, phi, kappa`` (m, rad).
    focal_length : float
        mm.
    frame_mm : float or (float, float)
        Width and height of the image format (mm), centred on the principal point.
    z : float
        Terrain height of the plane.
    principal_point : (float, float)

    Returns
    -------
    numpy.ndarray, shape (4, 2)
        Corners X, Y (counter-clockwise when the image is not mirrored).
    """
    e = np.asarray(eo, float)
    w, h = np.broadcast_to(np.asarray(frame_mm, float), (2,)) / 2.0
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]])
    v = np.column_stack([corners, np.full(4, -float(focal_length))])
    m = rotation_matrix(e[3], e[4], e[5])
    d = v @ m  # M' v for each corner (ground direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z - e[2]) / d[:, 2]
    if not np.all(np.isfinite(s) & (s > 0)):
        raise ProjectError(
            "An image corner's ray does not reach the terrain (the image looks above the "
            "horizon or the terrain is above the camera)",
            "Check the exterior orientation and the terrain height of the equal-error map",
        )
    return e[None, :2] + s[:, None] * d[:, :2]


def _inside_convex(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Points inside (or on) a convex polygon of either orientation."""
    p0 = poly
    p1 = np.roll(poly, -1, axis=0)
    cross = ((p1[:, 0] - p0[:, 0])[:, None] * (y.ravel()[None, :] - p0[:, 1][:, None])
             - (p1[:, 1] - p0[:, 1])[:, None] * (x.ravel()[None, :] - p0[:, 0][:, None]))
    inside = np.all(cross >= 0, axis=0) | np.all(cross <= 0, axis=0)
    return inside.reshape(x.shape)


def _pair_indices(run: AdjustmentRun, image_pair) -> tuple[int, int]:
    ids = list(run.image_ids)
    if image_pair is None:
        if len(ids) < 2:
            raise ProjectError("The adjustment has fewer than two images, so there is no "
                               "stereo pair", "Measure points on at least two images")
        ia, ib = 0, 1
    else:
        ia, ib = _named_pair(ids, image_pair)
    prob = run.result.problem
    if prob is not None and prob.is_rpc[[ia, ib]].any():
        raise ProjectError(
            f"Images {ids[ia]!r} and {ids[ib]!r}: the equal-error map and the two-step "
            "orientation are frame camera methods (a perspective centre, a rotation); an "
            "RPC image has neither",
            "Name two frame images with --images, or use adjust: its CE90/LE90 per vertex "
            "cover RPC images")
    return ia, ib


def _named_pair(ids: list, image_pair) -> tuple[int, int]:
    pair = [str(i) for i in image_pair]
    bad = [i for i in pair if i not in ids]
    if len(pair) != 2 or bad or pair[0] == pair[1]:
        raise ProjectError(
            f"Image pair {pair} is not two different images of this adjustment"
            + (f" (unknown: {', '.join(bad)})" if bad else ""),
            f"Name two of: {', '.join(ids)}",
        )
    return ids.index(pair[0]), ids.index(pair[1])


def equal_error_grid(
    run: AdjustmentRun,
    spacing: float = 10.0,
    image_pair: Optional[Sequence[str]] = None,
    z: Union[None, float, np.ndarray, Callable[[np.ndarray, np.ndarray], np.ndarray]] = None,
    *,
    frame_mm=None,
) -> EqualErrorGrid:
    """Equal-error map: sigma X, Y, Z of a new point intersected from a stereo pair.

    Over the stereo overlap of the pair (the two image footprints on the plane of the
    mean terrain height, intersected), every grid node is projected into both images and
    intersected back (:func:`vectoradjust.accuracy.propagate.point_sigma_grid`): the covariance
    ``s0^2 N_pp^-1 + N_pp^-1 N_pe C_ee N_ep N_pp^-1`` includes the adjusted exterior
    orientation's 12x12 joint covariance ``C_ee = s0^2 S^-1`` of the pair. The photo
    coordinate sigma is the median of the pair's measurement sigmas.

    Parameters
    ----------
    run : AdjustmentRun
    spacing : float
        Grid spacing (m); nodes at multiples of it.
    image_pair : (str, str), optional
        Image ids (default: the first two images of the adjustment).
    z : None, float, array or callable, optional
        Terrain height of the nodes: ``None`` = mean height of the adjusted points, a
        constant, an array of the grid's shape, or ``z(X, Y)`` (e.g. a DEM sampler;
        NaN heights fall back to the mean).
    frame_mm : float or (float, float), optional
        Image format (mm); default from the camera calibration (pixel size x image
        size), else 230 mm.

    Returns
    -------
    EqualErrorGrid
    """
    if not spacing > 0:
        raise ProjectError(f"Grid spacing {spacing!r} is not positive",
                           "Give a spacing in metres, e.g. --spacing 10")
    res = run.result
    _check_result(res)
    prob = res.problem
    ia, ib = _pair_indices(run, image_pair)
    eo = res.eo[[ia, ib]]
    sel = np.r_[6 * ia:6 * ia + 6, 6 * ib:6 * ib + 6]
    cee = res.variance_factor * res.eo_cofactor()[np.ix_(sel, sel)]
    on_pair = np.isin(prob.obs_image, [ia, ib])
    sig = float(np.median(prob.obs_sigma[on_pair])) if on_pair.any() else \
        float(np.median(prob.obs_sigma))
    sig *= np.sqrt(res.variance_factor)
    zmean = float(np.mean(res.xyz[:, 2]))
    frame = _frame_mm(run, frame_mm)
    f = prob.focal_length
    fa = image_footprint(eo[0], f, frame, zmean)
    fb = image_footprint(eo[1], f, frame, zmean)
    x0 = max(fa[:, 0].min(), fb[:, 0].min())
    x1 = min(fa[:, 0].max(), fb[:, 0].max())
    y0 = max(fa[:, 1].min(), fb[:, 1].min())
    y1 = min(fa[:, 1].max(), fb[:, 1].max())
    xs = np.arange(np.ceil(x0 / spacing), np.floor(x1 / spacing) + 1) * spacing
    ys = (np.arange(np.ceil(y0 / spacing), np.floor(y1 / spacing) + 1) * spacing)[::-1]
    if xs.size == 0 or ys.size == 0:
        raise ProjectError(
            f"Images {run.image_ids[ia]!r} and {run.image_ids[ib]!r} do not overlap (or the "
            f"overlap is smaller than the spacing {spacing} m)",
            "Choose a stereo pair with overlap (--images) or a smaller spacing",
        )
    X, Y = np.meshgrid(xs, ys)
    inside = _inside_convex(fa, X, Y) & _inside_convex(fb, X, Y)
    if z is None:
        Z = np.full(X.shape, zmean)
    elif callable(z):
        Z = np.asarray(z(X, Y), float).reshape(X.shape)
    else:
        Z = np.broadcast_to(np.asarray(z, float), X.shape).astype(float)
    Z = np.where(np.isfinite(Z), Z, zmean)
    sx = np.full(X.shape, np.nan)
    sy = np.full(X.shape, np.nan)
    sz = np.full(X.shape, np.nan)
    if inside.any():
        gs = prop.point_sigma_grid(eo, cee, f, sig, X[inside], Y[inside], Z[inside])
        sx[inside], sy[inside], sz[inside] = gs.sigma_x, gs.sigma_y, gs.sigma_z
    transform = (float(spacing), 0.0, float(xs[0] - spacing / 2), 0.0, -float(spacing),
                 float(ys[0] + spacing / 2))
    return EqualErrorGrid(X, Y, sx, sy, sz, transform)


def equal_error_range(grid: EqualErrorGrid) -> dict:
    """Range of an equal-error grid inside the overlap.

    Returns
    -------
    dict
        ``nodes`` (inside the overlap), ``spacing`` and for ``sigma_x``, ``sigma_y``,
        ``sigma_z`` and ``sigma_h`` (``sqrt(sx^2 + sy^2)``) the ``min``, ``max``,
        ``mean`` and ``median`` (m).
    """
    sh = np.hypot(grid.sigma_x, grid.sigma_y)
    out: dict = {"nodes": int(np.isfinite(grid.sigma_z).sum()),
                 "spacing": float(grid.transform[0])}
    for name, a in (("sigma_x", grid.sigma_x), ("sigma_y", grid.sigma_y),
                    ("sigma_z", grid.sigma_z), ("sigma_h", sh)):
        st = _stats(a)
        out[name] = {k: st[k] for k in ("min", "max", "mean", "median")}
    return out


# -------------------------------------------------------------------- two-step vs bundle
def _stats(a: np.ndarray) -> dict:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"count": 0, "mean": None, "median": None, "min": None, "max": None}
    return {"count": int(a.size), "mean": float(a.mean()), "median": float(np.median(a)),
            "min": float(a.min()), "max": float(a.max())}


def compare_two_step(run: AdjustmentRun, image_pair: Optional[Sequence[str]] = None,
                     method: str = "collinearity") -> dict:
    """Two-step orientation of a stereo pair compared with the bundle adjustment.

    The points measured on both images of the pair (default: the first two images)
    are oriented with :func:`vectoradjust.adjust.orientation.two_step` (relative orientation,
    then a 7-parameter similarity to the run's control points measured on both images,
    with their prior covariances), from the same refined photo coordinates and sigmas
    the bundle used. The two-step sigmas are a-priori (variance factor 1); the bundle's
    are compared on the same footing (its a-posteriori covariance divided by
    ``s0^2``). Both two-step covariances are reported: the rigorous one and the
    textbook ``F1 Sigma_aa F1' + F2 Sigma_mm F2'``, which counts the control points'
    model coordinates twice (they enter the transformation parameters and are
    transformed again) and so overstates their sigma.

    Parameters
    ----------
    run : AdjustmentRun
    image_pair : (str, str), optional
    method : {"collinearity", "coplanarity"}
        Relative orientation formulation.

    Returns
    -------
    dict
        ``images``, counts (``n_points``, ...), ``relative_s0``, ``absolute_s0``,
        ``bundle_sigma0_squared``,
        ``difference`` (two-step minus bundle, shape points: ``xy`` and ``z``
        statistics of the absolute differences, m), ``sigma_ratio`` (two-step /
        bundle, per axis, for ``rigorous`` and ``classical``, shape points),
        ``tie_sigma_ratio`` and ``control_sigma_ratio`` (the same for tie and control
        points), ``classical_over_rigorous`` and ``points`` (per point rows). Shape
        points carry their coordinate priors in the bundle but not in the two-step
        orientation; tie points are the like-for-like comparison (when the run has
        only the two images: otherwise the bundle also used the others).
    """
    res = run.result
    prob = res.problem
    ia, ib = _pair_indices(run, image_pair)
    npnt = prob.n_points
    # first observation of each point on each image of the pair
    obs_a = np.full(npnt, -1, np.int64)
    obs_b = np.full(npnt, -1, np.int64)
    ka = np.flatnonzero(prob.obs_image == ia)
    kb = np.flatnonzero(prob.obs_image == ib)
    obs_a[prob.obs_point[ka[::-1]]] = ka[::-1]
    obs_b[prob.obs_point[kb[::-1]]] = kb[::-1]
    pts = np.flatnonzero((obs_a >= 0) & (obs_b >= 0))
    kind = run.point_kind[pts]
    ctrl = pts[kind == "control"]
    if ctrl.size < 3:
        raise ControlError(
            f"Only {ctrl.size} control point(s) are measured on both images "
            f"{run.image_ids[ia]!r} and {run.image_ids[ib]!r}; the two-step orientation needs 3",
            "Measure at least 3 control points on both images of the pair",
        )
    pp = np.asarray(prob.principal_point, float)
    left = prob.obs_xy[obs_a[pts]] - pp
    right = prob.obs_xy[obs_b[pts]] - pp
    isig = np.column_stack([prob.obs_sigma[obs_a[pts]], prob.obs_sigma[obs_b[pts]]])
    ids = run.point_ids[pts]
    ccov = np.linalg.inv(prob.prior_weight[ctrl])
    ts = two_step(left, right, ids, prob.focal_length, run.point_ids[ctrl],
                  prob.prior_xyz[ctrl], ccov, isig, method=method)
    vf = res.variance_factor
    bundle_cov = (res.point_cov[pts] if res.point_cov is not None
                  else cross_covariance(res, pts, pts)) / vf
    b_sig = np.sqrt(np.einsum("mii->mi", bundle_cov))
    n = len(pts)
    rig = np.sqrt(np.clip(np.diag(ts.cov), 0, None)).reshape(n, 3)
    cla = np.sqrt(np.clip(np.diag(ts.cov_classical), 0, None)).reshape(n, 3)
    diff = ts.ground_xyz - res.xyz[pts]
    shape = kind == "shape"
    con = kind == "control"
    tie = kind == "tie"
    dxy = np.hypot(diff[:, 0], diff[:, 1])
    dz = np.abs(diff[:, 2])

    def ratios(s, m):
        return {ax: _stats(s[m, i] / b_sig[m, i]) for i, ax in enumerate("xyz")}

    return {
        "images": [run.image_ids[ia], run.image_ids[ib]],
        "method": method,
        "n_points": int(n), "control_points": int(con.sum()), "shape_points": int(shape.sum()),
        "tie_points": int(tie.sum()),
        "relative_s0": float(ts.relative.s0), "absolute_s0": float(ts.absolute.s0),
        "bundle_sigma0_squared": float(res.sigma0_squared),
        "difference": {
            "xy": _stats(dxy[shape]), "z": _stats(dz[shape]),
            "rmse_xy": float(np.sqrt(np.mean(dxy[shape] ** 2))) if shape.any() else None,
            "rmse_z": float(np.sqrt(np.mean(dz[shape] ** 2))) if shape.any() else None,
            "tie_xy": _stats(dxy[tie]), "tie_z": _stats(dz[tie]),
            "control_xy": _stats(dxy[con]), "control_z": _stats(dz[con]),
        },
        "sigma_ratio": {"rigorous": ratios(rig, shape), "classical": ratios(cla, shape)},
        "tie_sigma_ratio": {"rigorous": ratios(rig, tie), "classical": ratios(cla, tie)},
        "control_sigma_ratio": {"rigorous": ratios(rig, con), "classical": ratios(cla, con)},
        "classical_over_rigorous": {
            "shape": {ax: _stats(cla[shape, i] / rig[shape, i]) for i, ax in enumerate("xyz")},
            "tie": {ax: _stats(cla[tie, i] / rig[tie, i]) for i, ax in enumerate("xyz")},
            "control": {ax: _stats(cla[con, i] / rig[con, i]) for i, ax in enumerate("xyz")},
        },
        "points": [
            {"point_id": str(ids[i]), "kind": str(kind[i]),
             "two_step": ts.ground_xyz[i].tolist(), "bundle": res.xyz[pts[i]].tolist(),
             "sigma_two_step": rig[i].tolist(), "sigma_classical": cla[i].tolist(),
             "sigma_bundle": b_sig[i].tolist()}
            for i in range(n)
        ],
    }

