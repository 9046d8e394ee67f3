"""Derived quantities of an adjustment run (issue 6): lengths, bands, equal-error map.

Truth used here, independent of the code under test:
* the covariance of the unknowns as ``s0^2 N^-1`` from the full normal matrix, formed
  densely and inverted (docs/method.md section 3) - the definition the batched formulas avoid;
* ``BundleResult.joint_covariance`` and the Jacobians of :mod:`vectoradjust.accuracy.propagate`
  (tested against finite differences by their own tests) for the dense checks;
* finite differences of the forward intersection (:func:`vectoradjust.adjust.bundle.intersect`)
  for the equal-error grid;
* sampled error ellipses and :func:`vectoradjust.accuracy.propagate.g_band` for the G-bands;
* the collinearity equations for the stereo overlap.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from vectoradjust.accuracy import derived
from vectoradjust.accuracy import propagate as prop
from vectoradjust.adjust.bundle import intersect
from vectoradjust.errors import LayerError, MeasurementError, ProjectError
from vectoradjust.pipeline import run
from vectoradjust.sensor.collinearity import project
from vectoradjust.simulate import make_scenario


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module", params=[2, 3], ids=["pair", "strip3"])
def adj_run(request):
    # no database offsets: these tests check the structured formulas against the dense
    # N^-1 of the plain bundle (tests/test_offsets.py checks them with offsets)
    sc = make_scenario(7, n_images=request.param)
    data = sc.to_project_data()
    data = replace(data, vectors=[(replace(s, offset="none"), lay) for s, lay in data.vectors])
    return run(data)


def _dense_cov(res) -> np.ndarray:
    """``s0^2 N^-1`` from the full normal matrix (images first, then points)."""
    prob = res.problem
    n, m = prob.n_images, prob.n_points
    u = 6 * n + 3 * m
    k = len(prob.obs_point)
    a = np.zeros((2 * k, u))
    rows = np.arange(2 * k).reshape(k, 2)
    ce = 6 * prob.obs_image[:, None] + np.arange(6)
    cp = 6 * n + 3 * prob.obs_point[:, None] + np.arange(3)
    a[rows[:, :, None], ce[:, None, :]] = res.a_eo
    a[rows[:, :, None], cp[:, None, :]] = res.a_pt
    w = (1.0 / prob.obs_sigma**2).ravel()
    nmat = a.T @ (w[:, None] * a)
    ip = 6 * n + 3 * np.arange(m)[:, None] + np.arange(3)
    nmat[ip[:, :, None], ip[:, None, :]] += prob.prior_weight
    ie = np.arange(6 * n)
    nmat[ie, ie] += prob.eo_weight.ravel()
    return res.variance_factor * np.linalg.inv(nmat)


@pytest.fixture(scope="module")
def dense(adj_run):
    return _dense_cov(adj_run.result)


def _point_block(dense, n_images, a, b):
    o = 6 * n_images
    return dense[o + 3 * a:o + 3 * a + 3, o + 3 * b:o + 3 * b + 3]


# ------------------------------------------------------------------ cross covariances
def test_cross_covariance_matches_the_inverse_of_the_normal_matrix(adj_run, dense):
    res = adj_run.result
    rng = np.random.default_rng(0)
    m = res.problem.n_points
    pa = rng.integers(0, m, 60)
    pb = rng.integers(0, m, 60)
    pb[:10] = pa[:10]  # own blocks too
    got = derived.cross_covariance(res, pa, pb)
    ref = np.stack([_point_block(dense, res.problem.n_images, a, b) for a, b in zip(pa, pb)])
    scale = np.abs(ref).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(got - ref) <= 1e-8 * scale)
    # the own blocks are the bundle's point covariances
    assert np.allclose(got[:10], res.point_cov[pa[:10]], rtol=1e-9, atol=1e-15)


def test_cross_covariance_matches_joint_covariance(adj_run):
    res = adj_run.result
    rng = np.random.default_rng(1)
    pts = rng.choice(res.problem.n_points, 12, replace=False)
    joint = res.joint_covariance(pts).reshape(12, 3, 12, 3)
    ia, ib = np.triu_indices(12, 1)
    got = derived.cross_covariance(res, pts[ia], pts[ib])
    ref = joint[ia, :, ib, :]
    assert np.allclose(got, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


# ----------------------------------------------------------------------- LengthSD
def _photogrammetric(db):
    """The database without its identification error: the adjustment's covariance only."""
    return replace(db, spec=replace(db.spec, identification_sigma=None))


def _dense_length_check(res, db, f):
    """sigma of the feature's length from joint_covariance and propagate's Jacobian."""
    layer = db.shape.layer
    v = np.flatnonzero(layer.vertex_feature == f)
    vp = db.vertex_point[v]
    mi = np.flatnonzero(vp >= 0)
    nv = len(v)
    full = np.zeros((nv, 3, nv, 3))
    upts, inv = np.unique(vp[mi], return_inverse=True)
    j = res.joint_covariance(upts).reshape(len(upts), 3, len(upts), 3)
    inv = np.asarray(inv).reshape(-1)
    full[np.ix_(mi, [0, 1, 2], mi, [0, 1, 2])] = j[np.ix_(inv, [0, 1, 2], inv, [0, 1, 2])]
    cov = full.reshape(3 * nv, 3 * nv)
    g = np.zeros(3 * nv)
    parts = layer.vertex_part[v]
    for p in np.unique(parts):
        s = np.flatnonzero(parts == p)
        if len(s) < 2:
            continue
        pl = prop.polyline_length(db.adjusted_coords[v][s], np.zeros((len(s), 3, 3)))
        g[(3 * s[:, None] + np.arange(3)).ravel()] += pl.jacobian
    # without covariances: the blocks of the same object point only
    pt = np.repeat(np.where(vp >= 0, vp, -1 - np.arange(nv)), 3)
    blk = np.where(pt[:, None] == pt[None, :], cov, 0.0)
    return np.sqrt(g @ cov @ g), np.sqrt(g @ blk @ g)


def test_length_sd_matches_the_dense_check(adj_run):
    res = adj_run.result
    n_partial = 0
    for db in adj_run.databases:
        sd, sd_nc = derived.feature_length_sigma(adj_run, _photogrammetric(db), lengthening=False)
        layer = db.shape.layer
        assert sd.shape == sd_nc.shape == (layer.n_features,)
        for f in range(layer.n_features):
            meas = db.vertex_point[layer.vertex_feature == f] >= 0
            n_partial += int(meas.any() and not meas.all())
            ref, ref_nc = _dense_length_check(res, db, f)
            assert sd[f] == pytest.approx(ref, rel=1e-9)
            assert sd_nc[f] == pytest.approx(ref_nc, rel=1e-9)
    assert n_partial > 0  # unmeasured (fixed) vertices were part of the check


def test_length_sd_against_the_inverse_of_the_normal_matrix(adj_run, dense):
    """Same quantity, truth from s0^2 N^-1 and an explicit gradient (multi-part too)."""
    res = adj_run.result
    n = res.problem.n_images
    db = adj_run.databases[0]
    layer = db.shape.layer
    sd, _ = derived.feature_length_sigma(adj_run, _photogrammetric(db), lengthening=False)
    multi = np.unique(layer.vertex_feature[layer.vertex_part > 0])
    feats = np.unique(np.r_[multi, 0, 1, layer.n_features - 1])
    for f in feats:
        v = np.flatnonzero(layer.vertex_feature == f)
        grad = np.zeros(dense.shape[0])
        xyz = db.adjusted_coords[v]
        part = layer.vertex_part[v]
        for i in range(len(v) - 1):
            if part[i] != part[i + 1]:
                continue
            d = xyz[i + 1, :2] - xyz[i, :2]
            u = d / np.hypot(*d)
            for vert, sign in ((v[i], -1.0), (v[i + 1], 1.0)):
                p = db.vertex_point[vert]
                if p >= 0:
                    grad[6 * n + 3 * p:6 * n + 3 * p + 2] += sign * u
        assert sd[f] == pytest.approx(np.sqrt(grad @ dense @ grad), rel=1e-8)


def test_length_sd_of_a_feature_through_one_point_twice(adj_run):
    """A closed loop A-B-C-A: the repeated point's gradients add up before squaring."""
    res = adj_run.result
    pts = np.flatnonzero(adj_run.point_kind == "shape")[:3]
    vp = np.array([pts[0], pts[1], pts[2], pts[0], -1, pts[1]])
    xyz = res.xyz[np.where(vp >= 0, vp, pts[2])].copy()
    xyz[4] += [30.0, 10.0, 0.0]  # an unmeasured vertex (fixed)
    layer = SimpleNamespace(n_features=2, vertex_feature=np.array([0, 0, 0, 0, 1, 1]),
                            vertex_part=np.zeros(6, np.int64), coords=xyz)
    db = SimpleNamespace(shape=SimpleNamespace(layer=layer), vertex_point=vp,
                         adjusted_coords=xyz)
    sd, sd_nc = derived.feature_length_sigma(adj_run, db, lengthening=False)
    for f, v in ((0, [0, 1, 2, 3]), (1, [4, 5])):
        p = vp[v]
        m = p >= 0
        cov = np.zeros((len(v), 3, len(v), 3))
        mi = np.flatnonzero(m)
        up, inv = np.unique(p[m], return_inverse=True)
        j = res.joint_covariance(up).reshape(len(up), 3, len(up), 3)
        inv = np.asarray(inv).reshape(-1)
        cov[np.ix_(mi, [0, 1, 2], mi, [0, 1, 2])] = j[np.ix_(inv, [0, 1, 2], inv, [0, 1, 2])]
        cov = cov.reshape(3 * len(v), -1)
        r = prop.polyline_length(xyz[v], cov)
        assert sd[f] == pytest.approx(r.sigma, rel=1e-9)
    # loop without covariances: the point's own block with the summed gradient
    g = prop.polyline_length(xyz[:4], np.zeros((4, 3, 3))).jacobian.reshape(4, 3)
    gsum = np.array([g[0] + g[3], g[1], g[2]])
    blocks = res.point_cov[pts]
    assert sd_nc[0] == pytest.approx(np.sqrt(np.einsum("pi,pij,pj->", gsum, blocks, gsum)),
                                     rel=1e-9)


def test_feature_without_measured_vertices_has_no_length_sd(adj_run):
    db = adj_run.databases[0]
    vp = db.vertex_point.copy()
    vp[db.shape.layer.vertex_feature == 0] = -1
    sd, sd_nc = derived.feature_length_sigma(adj_run, replace(db, vertex_point=vp))
    assert np.isnan(sd[0]) and np.isnan(sd_nc[0])
    assert np.all(np.isfinite(sd[1:]))


def test_length_sd_monte_carlo(adj_run):
    """The linearised sigma against lengths of simulated adjusted geometries."""
    db = adj_run.databases[0]
    layer = db.shape.layer
    sd, _ = derived.feature_length_sigma(adj_run, _photogrammetric(db), lengthening=False)
    meas = db.vertex_point >= 0
    f = int(np.argmax(np.bincount(layer.vertex_feature[meas], minlength=layer.n_features)))
    v = np.flatnonzero(layer.vertex_feature == f)
    vp = db.vertex_point[v]
    mi = np.flatnonzero(vp >= 0)
    up, inv = np.unique(vp[mi], return_inverse=True)
    c = adj_run.result.joint_covariance(up)
    rng = np.random.default_rng(5)
    e = rng.multivariate_normal(np.zeros(len(c)), c, size=20000).reshape(-1, len(up), 3)
    xyz = np.repeat(db.adjusted_coords[v][None], len(e), axis=0)
    xyz[:, mi] += e[:, np.asarray(inv).reshape(-1)]  # unmeasured vertices stay fixed
    same = layer.vertex_part[v][1:] == layer.vertex_part[v][:-1]
    lengths = np.sum(np.hypot(*np.moveaxis(np.diff(xyz[..., :2], axis=1), -1, 0)) * same,
                     axis=1)
    # the standard error of a sample sd with 20000 draws is 0.5 %
    assert np.std(lengths) == pytest.approx(sd[f], rel=0.025)


# ---------------------------------------------------------------------------- G-bands
def _ellipse_points(centre, cov2, k, n=180):
    """Points on the boundary of the ellipse ``{x : (x - c)' C^-1 (x - c) = k^2}``."""
    w, v = np.linalg.eigh(cov2)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    circle = np.vstack([np.cos(th), np.sin(th)])
    return centre[None, :] + (k * (v * np.sqrt(np.clip(w, 0, None))) @ circle).T


def _covered(ring, pts, tol):
    """Points inside the closed ring or within ``tol`` of its boundary (numpy only)."""
    a = ring[:-1][None, :, :]
    b = ring[1:][None, :, :]
    p = pts[:, None, :]
    # crossing number
    cond = (a[..., 1] > p[..., 1]) != (b[..., 1] > p[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        xc = a[..., 0] + (p[..., 1] - a[..., 1]) * (b[..., 0] - a[..., 0]) / (b[..., 1] - a[..., 1])
    inside = np.sum(cond & (p[..., 0] < xc), axis=1) % 2 == 1
    # distance to the edges
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-300),
                0, 1)
    dist = np.linalg.norm(a + t[..., None] * ab - p, axis=-1).min(axis=1)
    return inside | (dist <= tol)


def _area(ring):
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1])


def _random_segments(m, seed):
    rng = np.random.default_rng(seed)
    p1 = rng.normal(size=(m, 2)) * 100
    p2 = p1 + rng.normal(size=(m, 2)) * 20
    a = rng.normal(size=(m, 4, 4))
    c = a @ np.swapaxes(a, 1, 2) * rng.uniform(0.01, 1.0, (m, 1, 1))
    return p1, p2, c


def test_g_band_batch_contains_every_ellipse_of_the_segment():
    p1, p2, c = _random_segments(40, 2)
    rings = derived.g_band_batch(p1, p2, c, 0.9)
    k = prop.confidence_scale(0.9)
    for i, ring in enumerate(rings):
        assert np.allclose(ring[0], ring[-1])
        assert _area(ring) > 0  # counter-clockwise
        tol = 1e-7 * np.sqrt(np.abs(c[i]).max())  # round-off at the tangent points
        for t in np.linspace(0.0, 1.0, 21):
            f = np.hstack([(1 - t) * np.eye(2), t * np.eye(2)])
            pts = _ellipse_points((1 - t) * p1[i] + t * p2[i], f @ c[i] @ f.T, k)
            assert _covered(ring, pts, tol).all(), (i, t)


def test_g_band_batch_agrees_with_the_single_segment_g_band():
    shapely = pytest.importorskip("shapely")
    p1, p2, c = _random_segments(12, 3)
    fine = derived.g_band_batch(p1, p2, c, 0.9, n_pairs=32, n_directions=64)
    rings = derived.g_band_batch(p1, p2, c, 0.9)
    for i in range(12):
        ref = shapely.Polygon(prop.g_band(p1[i], p2[i], c[i], 0.9))
        got = shapely.Polygon(fine[i])
        assert got.area / ref.area == pytest.approx(1.0, abs=0.01)
        assert got.symmetric_difference(ref).area / ref.area < 0.01
        # the default resolution: an outer band a few per cent larger at most
        assert 0.995 < shapely.Polygon(rings[i]).area / got.area < 1.04


def test_g_band_of_independent_equal_ends_is_a_stadium_with_a_waist():
    """C = diag(s^2) at both ends, no correlation: half-width k s sqrt((1-t)^2 + t^2)."""
    s, k = 0.5, prop.confidence_scale(0.9)
    c = np.diag([s * s] * 4)[None]
    ring = derived.g_band_batch([[0.0, 0.0]], [[40.0, 0.0]], c, 0.9, n_pairs=16)[0]
    for t, x in ((0.0, 0.0), (0.5, 20.0), (1.0, 40.0)):
        half = k * s * np.sqrt((1 - t) ** 2 + t**2)
        # the ring's extent on the vertical line X = x
        a, b = ring[:-1], ring[1:]
        hit = (a[:, 0] - x) * (b[:, 0] - x) <= 0
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(b[:, 0] != a[:, 0],
                         a[:, 1] + (x - a[:, 0]) * (b[:, 1] - a[:, 1]) / (b[:, 0] - a[:, 0]),
                         np.maximum(a[:, 1], b[:, 1]))
        lo, hi = w[hit].min(), w[hit].max()
        # outer bound, exact at the ends, waist overestimated by O(1 / n_pairs^2)
        for got in (-lo, hi):
            assert half * (1 - 1e-9) <= got <= half * 1.002


def test_segment_bands_contain_their_end_point_ellipses(adj_run):
    res = adj_run.result
    k = derived.band_scale(0.9)  # the error across the line (1-D)
    db = adj_run.databases[0]
    sb = derived.segment_bands(adj_run, db, 0.9, segments="measured")
    ident = np.diag(db.spec.identification_variance)  # the real road's, as CE90
    vp = db.vertex_point
    assert len(sb.rings) == len(sb.feature) > 0
    for a, ring in zip(sb.start_vertex, sb.rings):
        for p in (vp[a], vp[a + 1]):
            pts = _ellipse_points(res.xyz[p, :2], (res.point_cov[p] + ident)[:2, :2], k)
            assert _covered(ring, pts, 1e-6).all()  # 1 um: round-off at tangent points
    # the joint covariance of each segment is the dense one
    i = len(sb.start_vertex) // 2
    a = sb.start_vertex[i]
    want = res.joint_covariance([vp[a], vp[a + 1]]) + np.kron(np.eye(2), ident)
    assert np.allclose(sb.cov_joint[i], want, rtol=1e-9, atol=1e-15)
    bands = derived.uncertainty_bands(adj_run, db)
    assert [f for f, _ in bands] == derived.segment_bands(adj_run, db).feature.tolist()


def test_segment_bands_from_kept_covariances_once_the_factorisation_is_let_go(adj_run):
    """The covariances kept before ``release_factorisation`` give the same bands (of a
    share of the features too), with or without ``point_cov``; the released result
    refuses what needs the factorisation, and covariances of other segments are refused."""
    import copy

    db = adj_run.databases[0]
    want = derived.segment_bands(adj_run, db, 0.9, part=(1, 2))
    assert len(want.start_vertex) > 3
    for with_point_cov in (True, False):
        run2 = copy.copy(adj_run)  # the module's fixture stays whole
        run2.result = copy.copy(adj_run.result)
        if not with_point_cov:
            run2.result.point_cov = None
        kept = {d.name: derived.segment_covariances(run2, d) for d in run2.databases}
        share = {db.name: derived.segment_covariances(run2, db, (1, 2))}  # a process's own
        assert len(share[db.name].start) == len(want.start_vertex) < len(kept[db.name].start)
        assert (kept[db.name].own_a is None) == with_point_cov
        run2.result.release_factorisation()
        assert run2.result.nep_obs is None and run2.result.a_eo is None
        assert adj_run.result.nep_obs is not None
        with pytest.raises(ProjectError, match="release_factorisation"):
            derived.cross_covariance(run2.result, [0], [1])
        with pytest.raises(ProjectError, match=r"holds no factorisation.*release_factorisation"):
            derived.segment_bands(run2, db, 0.9)
        for given in (kept, share):
            got = derived.segment_bands(run2, db, 0.9, part=(1, 2), covariances=given)
            assert np.array_equal(got.start_vertex, want.start_vertex)
            # (the same numbers by another summation order: 1e-12 holds with numpy 2,
            # numpy 1.24 differs in the last digits)
            assert np.allclose(got.cov_joint, want.cov_joint, rtol=1e-9, atol=1e-18)
            if with_point_cov:  # the same numbers, so the same rings
                assert np.array_equal(got.xy, want.xy)
                assert np.array_equal(got.offsets, want.offsets)
    short = derived.SegmentCovariances(kept[db.name].start[1:], kept[db.name].cross[1:])
    with pytest.raises(ValueError, match="not those of database"):
        derived.segment_bands(run2, db, 0.9, covariances={db.name: short})


# ---------------------------------------------------------------- quantities between ids
def test_distance_length_and_mean_height_against_the_dense_inverse(adj_run, dense):
    res = adj_run.result
    n = res.problem.n_images
    db = adj_run.databases[0]
    ids = db.shape.vertex_ids[db.vertex_point >= 0][:5]
    pts = db.vertex_point[db.vertex_point >= 0][:5]
    sel = (6 * n + 3 * pts[:, None] + np.arange(3)).ravel()
    # plus the identification error of each (distinct) shape point, as their CE90
    c = dense[np.ix_(sel, sel)] + np.kron(np.eye(5), np.diag(db.spec.identification_variance))
    xyz = res.xyz[pts]
    # 2D distance, explicit gradient
    d = xyz[0, :2] - xyz[4, :2]
    dist = np.hypot(*d)
    g = np.zeros(15)
    g[0:2], g[12:14] = d / dist, -d / dist
    r = derived.distance_between(adj_run, ids[0], ids[4])
    assert r.value == pytest.approx(dist)
    assert r.sigma == pytest.approx(np.sqrt(g @ c @ g), rel=1e-8)
    blk = np.zeros_like(c)
    for i in range(5):
        blk[3 * i:3 * i + 3, 3 * i:3 * i + 3] = c[3 * i:3 * i + 3, 3 * i:3 * i + 3]
    assert r.sigma_no_cov == pytest.approx(np.sqrt(g @ blk @ g), rel=1e-8)
    # 3D distance with a qualified id
    r3 = derived.distance_between(adj_run, f"{db.name}:{ids[0]}", ids[4], dims=3)
    d3 = xyz[0] - xyz[4]
    g3 = np.zeros(15)
    g3[0:3], g3[12:15] = d3 / np.linalg.norm(d3), -d3 / np.linalg.norm(d3)
    assert r3.sigma == pytest.approx(np.sqrt(g3 @ c @ g3), rel=1e-8)
    # mean height
    mh = derived.mean_height_between(adj_run, list(ids))
    gz = np.zeros(15)
    gz[2::3] = 0.2
    assert mh.value == pytest.approx(xyz[:, 2].mean())
    assert mh.sigma == pytest.approx(np.sqrt(gz @ c @ gz), rel=1e-8)
    # length through the points (a control point id as well)
    cid = adj_run.point_ids[0]
    ln = derived.length_between(adj_run, [cid] + list(ids[:2]))
    assert ln.value == pytest.approx(
        np.hypot(*(res.xyz[0, :2] - xyz[0, :2])) + np.hypot(*(xyz[0, :2] - xyz[1, :2])))
    assert ln.points.tolist() == [0, pts[0], pts[1]]


def test_point_ids_that_are_not_adjusted_points_are_refused(adj_run):
    db = adj_run.databases[0]
    with pytest.raises(MeasurementError, match="not a point of the adjustment"):
        derived.distance_between(adj_run, "no-such-point", db.shape.vertex_ids[0])
    unmeasured = db.shape.vertex_ids[db.vertex_point < 0]
    if unmeasured.size:
        with pytest.raises(MeasurementError, match="not measured"):
            derived.length_between(adj_run, [unmeasured[0], db.shape.vertex_ids[0]])
    with pytest.raises(MeasurementError, match="at least two"):
        derived.length_between(adj_run, [db.shape.vertex_ids[0]])


def test_profile_of_a_feature(adj_run, dense):
    res = adj_run.result
    n = res.problem.n_images
    db = adj_run.databases[0]
    layer = db.shape.layer
    # a single-part feature with unmeasured vertices if there is one
    meas = db.vertex_point >= 0
    partial = [f for f in range(layer.n_features)
               if (~meas[layer.vertex_feature == f]).any()
               and meas[layer.vertex_feature == f].sum() >= 2]
    f = partial[0] if partial else 0
    fid = layer.feature_ids[f]
    pr = derived.profile(adj_run, fid, db.name)
    v = np.flatnonzero(layer.vertex_feature == f)
    vp = db.vertex_point[v]
    m = vp >= 0
    assert np.allclose(pr.z, db.adjusted_coords[v, 2])
    idz = db.spec.identification_variance[2]
    assert np.allclose(pr.sigma_z[m], np.sqrt(res.point_cov[vp[m], 2, 2] + idz), rtol=1e-9)
    # conflated vertices: their own sigma (SigmaZ), the others none
    assert np.allclose(pr.sigma_z[~m], np.asarray(db.vertices["SigmaZ"])[v][~m], rtol=1e-9,
                       equal_nan=True)
    # chainage: cumulative segment lengths within each part; the part ends sum to Length
    ends = np.r_[np.flatnonzero(np.diff(pr.part)), len(v) - 1]
    assert pr.chainage[ends].sum() == pytest.approx(db.features["Length"][f], rel=1e-12)
    # rise between the first and last adjusted vertex: sigma from the dense inverse
    i0, i1 = vp[m][0], vp[m][-1]
    zi = [6 * n + 3 * i0 + 2, 6 * n + 3 * i1 + 2]
    cz = dense[np.ix_(zi, zi)] + idz * np.eye(2)
    assert pr.rise.sigma == pytest.approx(np.sqrt(cz[0, 0] + cz[1, 1] - 2 * cz[0, 1]), rel=1e-8)
    assert pr.rise.sigma_no_cov == pytest.approx(np.sqrt(cz[0, 0] + cz[1, 1]), rel=1e-8)
    d = pr.to_dict()
    assert len(d["vertices"]) == len(v)
    json.dumps(d)
    with pytest.raises(LayerError,
                       match=r"No feature with id 'no-such-feature'.*Give a feature id"):
        derived.profile(adj_run, "no-such-feature")
    with pytest.raises(ProjectError, match=r"no road database named 'NO-SUCH-DB'.*Use one of: "):
        derived.profile(adj_run, fid, "NO-SUCH-DB")


# ------------------------------------------------------------------- equal-error grid
def test_equal_error_grid_nodes_match_direct_propagation(adj_run):
    res = adj_run.result
    prob = res.problem
    grid = derived.equal_error_grid(adj_run, spacing=25.0)
    inside = np.flatnonzero(np.isfinite(grid.sigma_z).ravel())
    assert inside.size > 20
    vf = res.variance_factor
    sig = 0.015 * np.sqrt(vf)  # the scenario's photo sigma, a posteriori
    cee = vf * res.s_inv[:12, :12]
    f = prob.focal_length
    rng = np.random.default_rng(4)
    for node in rng.choice(inside, 4, replace=False):
        x, y = grid.X.ravel()[node], grid.Y.ravel()[node]
        z = float(np.mean(res.xyz[:, 2]))
        xyz = np.array([x, y, z])
        photo = project(res.eo[:2], np.vstack([xyz, xyz]), f)  # (2, 2) on images 1, 2

        def point(params):
            eo = params[4:].reshape(2, 6)
            ph = params[:4].reshape(2, 2)
            xyz_i, _ = intersect(eo, np.array([0, 0]), np.array([0, 1]), ph,
                                 np.full((2, 2), 0.015), 1, f, tolerance=1e-12)
            return xyz_i[0]

        params = np.r_[photo.ravel(), res.eo[:2].ravel()]
        cov = np.zeros((16, 16))
        cov[:4, :4] = np.eye(4) * sig**2
        cov[4:, 4:] = cee
        r = prop.propagate(point, params, cov, block_size=1)
        assert r.value == pytest.approx(xyz, abs=1e-6)
        assert grid.sigma_x.ravel()[node] == pytest.approx(r.sigma[0], rel=1e-4)
        assert grid.sigma_y.ravel()[node] == pytest.approx(r.sigma[1], rel=1e-4)
        assert grid.sigma_z.ravel()[node] == pytest.approx(r.sigma[2], rel=1e-4)


def test_equal_error_grid_covers_the_stereo_overlap(adj_run):
    res = adj_run.result
    grid = derived.equal_error_grid(adj_run, spacing=20.0, frame_mm=230.0)
    a, b, c, d, e, f = grid.transform
    rows, cols = np.indices(grid.X.shape)
    assert np.allclose(grid.X, a * (cols + 0.5) + b * (rows + 0.5) + c)
    assert np.allclose(grid.Y, d * (cols + 0.5) + e * (rows + 0.5) + f)
    z = np.full(grid.X.size, float(np.mean(res.xyz[:, 2])))
    pts = np.column_stack([grid.X.ravel(), grid.Y.ravel(), z])
    inside = np.isfinite(grid.sigma_x.ravel())
    in_frame = np.ones(len(pts), bool)
    for i in range(2):
        ph = project(np.broadcast_to(res.eo[i], (len(pts), 6)), pts, res.problem.focal_length)
        in_frame &= np.all(np.abs(ph) <= 115.0 + 1e-6, axis=1)
    assert np.array_equal(inside, in_frame)
    assert inside.any()
    if len(adj_run.image_ids) == 2:  # the bounding box of a pair's overlap has corners out
        assert (~inside).any()
    rng = derived.equal_error_range(grid)
    assert rng["nodes"] == inside.sum()
    assert 0 < rng["sigma_x"]["min"] <= rng["sigma_x"]["max"]
    with pytest.raises(ProjectError,
                       match=r"Image pair \['L', 'nope'\] is not two different images.*"
                             r"Name two of: "):
        derived.equal_error_grid(adj_run, image_pair=("L", "nope"))


# ------------------------------------------------------------------ two-step vs bundle
def test_two_step_comparison(adj_run):
    c = derived.compare_two_step(adj_run)
    assert c["images"] == adj_run.image_ids[:2]
    assert c["n_points"] == c["control_points"] + c["shape_points"] + c["tie_points"]
    # tie points (no priors in either): the same points within their sigmas, and the
    # rigorous two-step sigma close to the bundle's
    tie = [p for p in c["points"] if p["kind"] == "tie"]
    assert tie
    for p in tie:
        diff = np.abs(np.subtract(p["two_step"], p["bundle"]))
        assert np.all(diff < 4 * np.asarray(p["sigma_bundle"]) + 1e-3)
    pair_only = len(adj_run.image_ids) == 2
    for ax in "xyz":
        ratio = c["tie_sigma_ratio"]["rigorous"][ax]["median"]
        # alone on the pair, both use the same information; in a strip the bundle also
        # has the third image
        assert (0.9 < ratio < 1.5) if pair_only else ratio > 0.9
        # the classical formula counts the control twice: larger at the control points
        assert c["classical_over_rigorous"]["control"][ax]["median"] > 1.0
    json.dumps(c)


# ------------------------------------------------------------------------ files, CLI
@pytest.mark.io
def test_writers(adj_run, tmp_path):
    gpd = pytest.importorskip("geopandas")
    rasterio = pytest.importorskip("rasterio")
    from vectoradjust.files.derived_outputs import (
        EQUAL_ERROR_NODATA,
        write_equal_error_map,
        write_uncertainty_bands,
    )

    gpkg = tmp_path / "adjusted.gpkg"
    gpd.GeoDataFrame({"a": [1]}, geometry=gpd.points_from_xy([0.0], [0.0]),
                     crs=adj_run.data.crs).to_file(gpkg, layer="other", driver="GPKG")
    write_uncertainty_bands(adj_run, gpkg)
    import pyogrio

    layers = dict(pyogrio.list_layers(gpkg))
    assert "other" in layers and "uncertainty_bands" in layers
    bands = gpd.read_file(gpkg, layer="uncertainty_bands")
    assert list(bands.columns[:4]) == ["database", "feature_id", "confidence", "NSeg"]
    assert all(len(c) <= 10 for c in bands.columns)
    assert np.allclose(bands["confidence"], 0.9)
    db = adj_run.databases[0]
    sb = derived.segment_bands(adj_run, db)
    mine = bands[bands["database"] == db.name]
    assert mine["NSeg"].sum() == len(sb.rings)
    # every segment's end points (measured or conflated) lie in its feature's band
    import shapely

    geo = dict(zip(mine["feature_id"], mine.geometry))
    fids = db.shape.layer.feature_ids
    for f, a in zip(sb.feature, sb.start_vertex):
        ends = db.adjusted_coords[[a, a + 1], :2]
        assert shapely.covers(geo[fids[f]], shapely.points(ends)).all()
    shp = write_uncertainty_bands(adj_run, tmp_path / "bands.shp")
    assert len(gpd.read_file(shp)) == len(bands)

    grid = derived.equal_error_grid(adj_run, spacing=20.0)
    tif = write_equal_error_map(grid, tmp_path / "ee.tif", adj_run.data.crs)
    with rasterio.open(tif) as src:
        assert src.count == 3 and src.nodata == EQUAL_ERROR_NODATA
        assert src.descriptions == ("sigma X (m)", "sigma Y (m)", "sigma Z (m)")
        data = src.read()
        x, y = src.xy(0, 0)
        assert (x, y) == pytest.approx((grid.X[0, 0], grid.Y[0, 0]))
    ok = np.isfinite(grid.sigma_z)
    assert np.allclose(data[2][ok], grid.sigma_z[ok], rtol=1e-6)
    assert np.all(data[:, ~ok] == EQUAL_ERROR_NODATA)


@pytest.fixture(scope="module")
def written_project(tmp_path_factory):
    pytest.importorskip("geopandas")
    pytest.importorskip("rasterio")
    from vectoradjust.simulate import write_project

    out = tmp_path_factory.mktemp("derived_project")
    return write_project(make_scenario(3, grid=(2, 2), databases=("OSM",)), out)


def _cli(argv):
    from vectoradjust.cli.propagate import add_parsers

    parser = argparse.ArgumentParser(prog="vectoradjust")
    sub = parser.add_subparsers(dest="command")
    add_parsers(sub)
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.mark.io
def test_cli_propagate_equal_error_two_step(written_project, tmp_path, capsys):
    from vectoradjust.files.readers import load_project_data

    r = run(load_project_data(written_project))
    db = r.databases[0]
    ids = db.shape.vertex_ids[db.vertex_point >= 0][:3]
    proj = str(written_project)
    assert _cli(["propagate", proj, "--out", str(tmp_path), "-q", "--distance", ids[0],
                 ids[2]]) == 0
    out = json.loads((tmp_path / "propagate.json").read_text())
    ref = derived.distance_between(r, ids[0], ids[2])
    assert out["results"][0]["value"] == pytest.approx(ref.value, rel=1e-9)
    assert out["results"][0]["sigma"] == pytest.approx(ref.sigma, rel=1e-6)
    assert "with covariances" in capsys.readouterr().out
    assert _cli(["propagate", proj, "--out", str(tmp_path), "-q", "--length", *ids]) == 0
    assert _cli(["propagate", proj, "--out", str(tmp_path), "-q", "--profile",
                 db.shape.layer.feature_ids[0]]) == 0
    prof = json.loads((tmp_path / "propagate.json").read_text())["profile"]
    assert prof["feature_id"] == db.shape.layer.feature_ids[0]
    assert _cli(["equal-error", proj, "--out", str(tmp_path), "-q", "--spacing", "25"]) == 0
    ee = json.loads((tmp_path / "equal_error.json").read_text())
    assert (tmp_path / "equal_error.tif").is_file()
    assert ee["sigma_z"]["min"] <= ee["sigma_z"]["max"]
    assert ee["heights"].endswith("dem.tif")
    assert _cli(["two-step", proj, "--out", str(tmp_path), "-q"]) == 0
    ts = json.loads((tmp_path / "two_step.json").read_text())
    assert ts["n_points"] > 0 and "sigma_ratio" in ts
    # a user error exits with 1 and one message
    from vectoradjust.cli.propagate import main

    assert main(["propagate", proj, "--out", str(tmp_path), "-q", "--distance", "nope",
                 ids[0]]) == 1
    assert "not a point of the adjustment" in capsys.readouterr().err


def test_uncertainty_bands_equal_the_per_feature_union(adj_run):
    """The vectorised union (make_valid "structure") is the union of each feature's
    segment bands, as a loop of shapely.union_all over the features computes it."""
    pytest.importorskip("geopandas")
    import shapely

    from vectoradjust.files.derived_outputs import uncertainty_bands_frame

    frame = uncertainty_bands_frame(adj_run)
    for d in adj_run.databases:
        sb = derived.segment_bands(adj_run, d)
        polys = shapely.make_valid(shapely.polygons([shapely.linearrings(r) for r in sb.rings]))
        mine = frame[frame["database"] == d.name]
        fids = d.shape.layer.feature_ids
        assert list(mine["feature_id"]) == [str(fids[f]) for f in np.unique(sb.feature)]
        for f, geom, nseg in zip(np.unique(sb.feature), mine.geometry, mine["NSeg"]):
            ref = shapely.union_all(polys[sb.feature == f])
            assert nseg == np.sum(sb.feature == f)
            assert geom.geom_type == "MultiPolygon" and geom.is_valid
            assert shapely.symmetric_difference(geom, ref).area <= 1e-9 * ref.area


def test_uncertainty_bands_report_progress_and_cancel_in_the_union(adj_run):
    pytest.importorskip("geopandas")
    from vectoradjust.errors import CancelledError
    from vectoradjust.files.derived_outputs import uncertainty_bands_frame

    seen = []
    uncertainty_bands_frame(adj_run, progress=lambda f, msg: seen.append((f, msg)))
    fractions = [f for f, _ in seen]
    assert np.all(np.diff(fractions) >= 0) and 0.99 <= fractions[-1] <= 1.0
    assert any("union" in m for _, m in seen) and any("segments" in m for _, m in seen)
    msgs = []
    # polled before every progress report
    with pytest.raises(CancelledError, match=r"uncertainty bands was cancelled.*--no-bands"):
        uncertainty_bands_frame(adj_run, progress=lambda f, msg: msgs.append(msg),
                                is_cancelled=lambda: bool(msgs) and "union" in msgs[-1])
    assert "union" in msgs[-1] and len(msgs) < len(seen)
