"""The vectorised G-band construction (issue 13): envelope, thinning, tangents, rings.

Truth used here, independent of the code under test:
* dense evaluation of the chains and of their maximum on a fine grid (the definition of
  the upper envelope), and of the chord through kept vertices for the thinning;
* the definition of a common tangent: equal support functions of both ellipses;
* sampled error ellipses ``P(t)`` of the segment (the definition of the G-band) for
  containment, and a dense union of ellipses (shapely) for the excess area;
* ``shapely.union_all`` per feature for the union of the bands.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.accuracy import derived
from vectoradjust.accuracy import propagate as prop


def _concave_chains(rng, m, p, k):
    """Random concave piecewise-linear chains: vertices, and each piece's line."""
    brk = np.sort(rng.uniform(-5, 5, (m, p, k)), axis=2)  # vertices u
    brk += rng.uniform(-3, 3, (m, p, 1))
    slope = -np.sort(rng.normal(0, 2, (m, p, k - 1)), axis=2)  # descending: concave
    # continuity at the inner vertices fixes the intercepts from the first one
    icpt = np.empty_like(slope)
    icpt[..., 0] = rng.normal(0, 2, (m, p))
    for j in range(1, k - 1):
        icpt[..., j] = icpt[..., j - 1] + (slope[..., j - 1] - slope[..., j]) * brk[..., j]
    return brk, slope, icpt


def _dense_envelope(cu, slope, icpt, x):
    """max over chains of min over pieces (a concave chain is the min of its lines)."""
    val = np.min(icpt[..., None, :] + slope[..., None, :] * x[:, None, :, None], axis=-1)
    inside = (x[:, None, :] >= cu[:, :, :1]) & (x[:, None, :] <= cu[:, :, -1:])
    return np.where(inside, val, -np.inf).max(axis=1)


def test_upper_envelope_is_exact_at_the_stations_and_an_outer_polyline():
    rng = np.random.default_rng(11)
    m, p, k = 40, 5, 7
    cu, slope, icpt = _concave_chains(rng, m, p, k)
    su, w = derived._upper_envelope(cu, slope, icpt)
    assert np.all(np.diff(su, axis=1) >= 0)
    assert np.array_equal(np.sort(su, axis=1), np.sort(cu.reshape(m, -1), axis=1))
    # exact at every station (definition, evaluated independently)
    ref = _dense_envelope(cu, slope, icpt, su)
    assert np.allclose(w, ref, rtol=0, atol=1e-9)
    # between stations the polyline is on or above the envelope (dense grid)
    x = np.sort(rng.uniform(su[:, :1], su[:, -1:], (m, 2000)), axis=1)
    dense = _dense_envelope(cu, slope, icpt, x)
    poly = np.array([np.interp(x[i], su[i], w[i]) for i in range(m)])
    assert np.all(poly >= dense - 1e-9)
    # ... and it is not a loose bound: somewhere it touches, nowhere far above stations
    assert np.all(np.min(poly - dense, axis=1) < 1e-6)


def test_upper_envelope_of_disjoint_and_nested_chains():
    # chain 0 on [0, 2], chain 1 on [3, 5] (a gap: the envelope is absent there) and
    # chain 2 inside chain 0's range but lower (never on the envelope)
    cu = np.array([[[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [0.5, 1.0, 1.5]]])
    slope = np.array([[[1.0, -1.0], [2.0, -2.0], [0.0, 0.0]]])
    icpt = np.array([[[0.0, 2.0], [-6.0, 10.0], [-1.0, -1.0]]])
    su, w = derived._upper_envelope(cu, slope, icpt)
    expect = {0.0: 0.0, 0.5: 0.5, 1.0: 1.0, 1.5: 0.5, 2.0: 0.0, 3.0: 0.0, 4.0: 2.0, 5.0: 0.0}
    for u, v in zip(su[0], w[0]):
        assert v == pytest.approx(expect[u], abs=1e-12)


def test_drop_collinear_thins_straight_runs_within_the_tolerance():
    rng = np.random.default_rng(5)
    m, n = 30, 60
    u = np.sort(rng.uniform(0, 10, (m, n)), axis=1)
    # polylines with 4 straight pieces, plus tiny wiggles (below / above the tolerance)
    knots = np.sort(rng.uniform(0, 10, (m, 3)), axis=1)
    w = np.zeros((m, n))
    for j in range(3):
        w += rng.normal(0, 1, (m, 1)) * np.maximum(u - knots[:, j:j + 1], 0.0)
    w += rng.normal(0, 1, (m, 1)) * u
    tol = np.full((m, 1), 1e-6)
    w[:, ::7] += rng.choice([-1, 1], (m, len(range(0, n, 7)))) * 3e-7  # within tol
    valid = np.ones((m, n), bool)
    valid[:, 3] = False  # an invalid entry is never kept
    keep = derived._drop_collinear(u, w, valid, tol)
    assert not keep[:, 3].any()
    assert keep[:, 0].all() and keep[:, -1].all()
    assert keep.sum(axis=1).max() <= 12  # 4 pieces: ends and knots (and a few ties)
    for i in range(m):
        v = valid[i]
        thin = np.interp(u[i, v], u[i, keep[i]], w[i, keep[i]])
        assert np.all(np.abs(thin - w[i, v]) <= tol[i, 0] * (1 + 1e-9))
    # a gentle curve: every vertex within tol of its neighbours' chord, not of a long one
    uc = np.tile(np.linspace(0, 10, 60), (2, 1))
    wc = 2e-5 * uc**2 * np.array([[1.0], [-1.0]])
    keepc = derived._drop_collinear(uc, wc, np.ones_like(uc, bool), np.full((2, 1), 1e-6))
    assert keepc[:, [0, -1]].all()
    for i in range(2):
        thin = np.interp(uc[i], uc[i, keepc[i]], wc[i, keepc[i]])
        assert np.all(np.abs(thin - wc[i]) <= 1e-6)
    # a vertex off the chord by more than the tolerance is kept
    w2 = u.copy()
    w2[:, 30] += 1e-3
    keep2 = derived._drop_collinear(u, w2, np.ones((m, n), bool), tol)
    assert keep2[:, 30].all()
    assert keep2.sum(axis=1).max() == 5  # ends, the bump and its two neighbours


def _pair_covariances(rng, m, p, length):
    """Random end-point covariances of segments, sampled at P + 1 points (local frame)."""
    a = rng.normal(size=(m, 4, 4)) * 0.06
    c = a @ np.swapaxes(a, 1, 2) + np.eye(4) * 0.004
    t = np.linspace(0, 1, p + 1)
    f = np.concatenate([(1 - t)[:, None, None] * np.eye(2), t[:, None, None] * np.eye(2)], axis=2)
    return t[None, :] * length[:, None], f @ c[:, None] @ np.swapaxes(f, 1, 2)


@pytest.mark.parametrize("case", ["random", "road"])
def test_tangent_normals_make_both_supports_equal(case):
    rng = np.random.default_rng(3)
    m, p = 2000, 6
    k = prop.confidence_scale(0.9)
    if case == "random":
        length = rng.uniform(0.5, 30, m)
        tl = np.linspace(0, 1, p + 1)[None, :] * length[:, None]
        a = rng.normal(size=(m, p + 1, 2, 2))
        ql = a @ np.swapaxes(a, -1, -2) * rng.uniform(0.01, 1, (m, 1, 1, 1))
    else:  # short to long road segments, small ellipses: the regula falsi converges fully
        length = rng.uniform(0.8, 25, m)
        tl, ql = _pair_covariances(rng, m, p, length)
    du = 2 * np.pi / 24
    c, s, phi = derived._tangent_normals(tl, ql, k, du)
    assert np.allclose(c * c + s * s, 1.0)
    assert np.all(np.abs(phi) < du)
    assert np.allclose(np.arctan2(s[..., 0], c[..., 0]), 0.5 * np.pi + phi[..., 0])
    assert np.allclose(np.mod(np.arctan2(s[..., 1], c[..., 1]), 2 * np.pi),
                       1.5 * np.pi + phi[..., 1])

    def h(j):  # support of ellipse j (of each pair) in the found directions
        q = ql[:, j:j + p]
        v = c * c * q[..., 0, 0, None] + 2 * c * s * q[..., 0, 1, None] + s * s * q[..., 1, 1, None]
        return tl[:, j:j + p, None] * c + k * np.sqrt(v)

    h0, h1 = h(0), h(1)
    found = np.abs(phi - 0.5 * du) > 1e-12  # not the fallback direction
    assert found.mean() > 0.2, found.mean()
    scale = (np.sqrt(ql[..., 0, 0] + ql[..., 1, 1]).max(axis=1) + length)[:, None, None]
    assert np.all(np.abs(h0 - h1)[found] <= 1e-9 * np.broadcast_to(scale, h0.shape)[found])
    # where none was taken, the bracket's ends have the same sign (one ellipse reaches
    # farther at both), or the root is at a uniform direction (within 1e-6 rad)
    for side, centre in ((0, 0.5 * np.pi), (1, 1.5 * np.pi)):
        th = centre + np.linspace(-du, du, 41)
        cc, ss = np.cos(th), np.sin(th)

        def hh(j, cc=cc, ss=ss):
            q = ql[:, j:j + p, None]
            v = cc * cc * q[..., 0, 0] + 2 * cc * ss * q[..., 0, 1] + ss * ss * q[..., 1, 1]
            return tl[:, j:j + p, None] * cc + k * np.sqrt(v)

        d = hh(0) - hh(1)
        same = np.sign(d[..., 0]) == np.sign(d[..., -1])
        at_uniform = np.abs(d[..., [0, 20, 40]]).min(axis=2) < 1e-5 * scale[..., 0]
        fallback = ~found[..., side]
        assert fallback.any()
        assert np.all((same | at_uniform)[fallback])


def _ellipse_points(centre, cov2, k, n=120):
    w, v = np.linalg.eigh(cov2)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return centre[None, :] + (k * (v * np.sqrt(np.clip(w, 0, None))) @ np.vstack(
        [np.cos(th), np.sin(th)])).T


def _road_like_segments(m, seed):
    """Short segments with ellipses of a fifth of their length and weak correlation."""
    rng = np.random.default_rng(seed)
    p1 = rng.normal(size=(m, 2)) * 50
    ang = rng.uniform(0, 2 * np.pi, m)
    p2 = p1 + rng.uniform(0.8, 2.5, (m, 1)) * np.column_stack([np.cos(ang), np.sin(ang)])
    a = rng.normal(size=(m, 4, 4)) * 0.06
    c = a @ np.swapaxes(a, 1, 2) + np.eye(4) * 0.004
    return p1, p2, c


@pytest.mark.parametrize("n_pairs,n_directions", [(6, 24), (3, 8), (8, 32)])
def test_rings_contain_every_sampled_ellipse_of_short_segments(n_pairs, n_directions):
    shapely = pytest.importorskip("shapely")
    p1, p2, c = _road_like_segments(60, n_pairs)
    k = prop.confidence_scale(0.9)
    xy, off = derived.g_band_rings(p1, p2, c, 0.9, n_pairs, n_directions)
    assert len(off) == 61 and off[0] == 0 and off[-1] == len(xy)
    rings = derived.g_band_batch(p1, p2, c, 0.9, n_pairs, n_directions)
    for i, ring in enumerate(rings):
        assert np.array_equal(ring, xy[off[i]:off[i + 1]])
        poly = shapely.Polygon(ring)
        assert poly.is_valid and shapely.is_ccw(shapely.LinearRing(ring))
        ells = []
        for t in np.linspace(0.0, 1.0, 41):
            f = np.hstack([(1 - t) * np.eye(2), t * np.eye(2)])
            pts = _ellipse_points((1 - t) * p1[i] + t * p2[i], f @ c[i] @ f.T, k)
            ells.append(shapely.Polygon(pts))
            # containment (outer bound), to the thinning tolerance and round-off
            d = shapely.distance(shapely.points(pts), poly)
            assert d.max() <= 1e-8, (i, t)
        # excess over a dense union of ellipses: the caps' 1/cos(pi/M) - 1 and the
        # waist's O(1/P^2), a few per cent at most with these resolutions
        exact = shapely.union_all(ells).area
        excess = poly.area / exact - 1
        assert -1e-3 < excess < 1 / np.cos(np.pi / n_directions) - 1 + 2.0 / n_pairs**2


def test_rings_in_chunks_equal_one_pass_and_report_progress(monkeypatch):
    p1, p2, c = _road_like_segments(300, 1)
    whole = derived.g_band_rings(p1, p2, c)
    monkeypatch.setattr(derived.band_kernels, "_BAND_BUDGET", 468 * 40)  # chunks of 40 segments
    seen = []
    xy, off = derived.g_band_rings(p1, p2, c, progress=seen.append)
    assert np.array_equal(xy, whole[0]) and np.array_equal(off, whole[1])
    assert len(seen) == 8 and seen[-1] == 1.0 and np.all(np.diff(seen) > 0)
    assert derived.g_band_batch(p1[:0], p2[:0], c[:0]) == []
    xy0, off0 = derived.g_band_rings(p1[:0], p2[:0], c[:0])
    assert xy0.shape == (0, 2) and list(off0) == [0]


def test_ring_list_of_segment_bands_is_a_read_only_sequence():
    xy = np.arange(20.0).reshape(10, 2)
    rings = derived._Rings(xy, np.array([0, 4, 4, 10]))
    assert len(rings) == 3
    assert np.array_equal(rings[0], xy[:4]) and len(rings[1]) == 0
    assert np.array_equal(rings[-1], xy[4:])
    assert [len(r) for r in rings] == [4, 0, 6]
    assert [len(r) for r in rings[1:]] == [0, 6]
    with pytest.raises(IndexError, match="ring index out of range"):
        rings[3]
    assert not derived._Rings(np.zeros((0, 2)), np.array([0]))


def test_union_per_feature_against_union_all():
    shapely = pytest.importorskip("shapely")
    from vectoradjust.files.derived_outputs import _union_per_feature

    box = shapely.box
    polys = np.array([box(0, 0, 2, 2), box(1, 1, 3, 3),  # group 0: overlapping
                      box(10, 0, 11, 1), box(20, 0, 21, 1),  # group 1: disjoint
                      box(0, 10, 1, 11)], dtype=object)  # group 3: single; group 2 empty
    group = np.array([0, 0, 1, 1, 3])
    out = _union_per_feature(polys, group, 4)
    assert all(g.geom_type == "MultiPolygon" for g in out)
    assert [len(g.geoms) for g in out] == [1, 2, 0, 1]
    for j in (0, 1, 3):
        ref = shapely.union_all(polys[group == j])
        assert shapely.symmetric_difference(out[j], ref).area == pytest.approx(0, abs=1e-12)
    assert out[2].is_empty
    # a collection from make_valid (a bow tie and a line) keeps its polygon parts
    bow = shapely.make_valid(shapely.Polygon([(0, 0), (2, 2), (2, 0), (0, 2)]))
    out = _union_per_feature(np.array([bow], dtype=object), np.array([0]), 1)
    assert out[0].geom_type == "MultiPolygon" and out[0].area == pytest.approx(2.0)


@pytest.mark.parametrize("shuffled", [True, False])
def test_feature_unions_in_chunks_equal_one_union_per_feature(shuffled):
    shapely = pytest.importorskip("shapely")
    from types import SimpleNamespace

    from vectoradjust.files.derived_outputs import _feature_unions

    # 12 features of 1 .. 9 consecutive segments (a random walk each), shuffled groups
    # or feature by feature (as segment_bands gives them: one run of points a chunk)
    rng = np.random.default_rng(8)
    pts, group = [], []
    for f in (rng.permutation(12) if shuffled else range(12)):
        walk = np.cumsum(rng.normal(0, 1.5, (int(rng.integers(2, 11)), 2)), axis=0) + f * 40
        pts += [(walk[j], walk[j + 1]) for j in range(len(walk) - 1)]
        group += [f] * (len(walk) - 1)
    p1, p2 = (np.array(x) for x in zip(*pts))
    group = np.array(group)
    a = rng.normal(size=(len(p1), 4, 4)) * 0.1
    xy, off = derived.g_band_rings(p1, p2, a @ np.swapaxes(a, 1, 2) + np.eye(4) * 0.01)
    sb = SimpleNamespace(xy=xy, offsets=off)
    seen = []
    small = _feature_unions(sb, group, 12, seen.append, chunk=7)
    whole = _feature_unions(sb, group, 12, lambda f: None)
    assert len(seen) > 3 and seen[-1] == 1.0
    polys = shapely.polygons([shapely.linearrings(xy[off[i]:off[i + 1]]) for i in range(len(p1))])
    for f in range(12):
        ref = shapely.union_all(polys[group == f])
        for got in (small[f], whole[f]):
            assert got.geom_type == "MultiPolygon" and got.is_valid
            assert shapely.symmetric_difference(got, ref).area <= 1e-9 * ref.area


def test_degenerate_covariances_give_empty_or_flat_rings():
    shapely = pytest.importorskip("shapely")
    from types import SimpleNamespace

    from vectoradjust.files.derived_outputs import _feature_unions

    p1, p2, c = _road_like_segments(4, 2)
    ref = derived.g_band_batch(p1, p2, c)
    for bad in (0, 3):  # a covariance that is not finite: an empty ring, the others kept
        cn = c.copy()
        cn[bad] = np.nan
        rings = derived.g_band_batch(p1, p2, cn)
        assert len(rings) == 4 and len(rings[bad]) == 0
        assert all(np.array_equal(rings[i], ref[i]) for i in range(4) if i != bad)
        xy, off = derived.g_band_rings(p1, p2, cn)
        out = _feature_unions(SimpleNamespace(xy=xy, offsets=off), np.array([0, 0, 1, 1]), 2,
                              lambda f: None)
        assert all(g.geom_type == "MultiPolygon" and g.area > 0 for g in out)
    flat = derived.g_band_batch(p1, p2, c * 0.0)  # no uncertainty: the segment itself
    for r, a, b in zip(flat, p1, p2):
        assert shapely.Polygon(r).area == pytest.approx(0.0, abs=1e-12)
        assert shapely.LineString(r).hausdorff_distance(shapely.LineString([a, b])) < 1e-12
