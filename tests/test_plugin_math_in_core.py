"""The math the QGIS plugin used to do itself, now in the core: residual vectors
(:mod:`vectoradjust.accuracy.residual_vectors`) and junction renames
(:mod:`vectoradjust.adjust.junctions`), checked against independent computations
(plain ``math`` per element, brute-force distances)."""

import math

import numpy as np
import pytest

from vectoradjust.accuracy.residual_vectors import residual_azimuth, residual_vectors
from vectoradjust.adjust.junctions import junction_renames, nearest_within
from vectoradjust.model import LineLayer


def _azimuth_by_hand(vx, vy):
    """Clockwise from north, by quadrant (not atan2): an independent reference."""
    if vx == 0 and vy == 0:
        return 0.0
    if vy == 0:
        return 90.0 if vx > 0 else 270.0
    a = math.degrees(math.atan(abs(vx) / abs(vy)))
    if vx >= 0 and vy > 0:
        return a
    if vx >= 0 and vy < 0:
        return 180.0 - a
    if vx < 0 and vy < 0:
        return 180.0 + a
    return 360.0 - a


def test_azimuth_of_the_compass_points_and_random_vectors():
    assert residual_azimuth([0, 1, 0, -1, 1, -1], [1, 0, -1, 0, 1, -1]).tolist() == \
        pytest.approx([0, 90, 180, 270, 45, 225], abs=1e-12)
    rng = np.random.default_rng(5)
    v = rng.normal(size=(500, 2)) * 10.0 ** rng.integers(-3, 3, size=(500, 1))
    got = residual_azimuth(v[:, 0], v[:, 1])
    ref = np.array([_azimuth_by_hand(a, b) for a, b in v])
    assert np.all((got >= 0) & (got < 360))
    assert np.max(np.abs(got - ref)) < 1e-9
    assert np.isnan(residual_azimuth([np.nan], [1.0])[0])
    assert residual_azimuth([0.0], [0.0])[0] == 0.0


def test_residual_vectors_match_a_per_vertex_computation():
    rng = np.random.default_rng(7)
    n = 200
    x, y = rng.uniform(5e5, 6e5, n), rng.uniform(4e6, 5e6, n)
    z = rng.uniform(100, 300, n)
    z[::7] = np.nan  # unknown heights: drawn at 0
    vx, vy, vz = rng.normal(0, 2, (3, n))
    vz[::5] = np.nan  # unknown height residual: no vertical move
    for scale in (1.0, 10.0):
        r = residual_vectors(x, y, z, vx, vy, vz, scale=scale)
        assert r.start.shape == r.end.shape == (n, 3)
        for i in range(n):
            z0 = z[i] if math.isfinite(z[i]) else 0.0
            dz = vz[i] if math.isfinite(vz[i]) else 0.0
            assert r.start[i].tolist() == [x[i], y[i], z0]
            assert r.end[i].tolist() == pytest.approx(
                [x[i] + scale * vx[i], y[i] + scale * vy[i], z0 + scale * dz], abs=1e-9)
            assert r.length[i] == pytest.approx(math.sqrt(vx[i] ** 2 + vy[i] ** 2), rel=1e-14)
            assert r.azimuth[i] == pytest.approx(_azimuth_by_hand(vx[i], vy[i]), abs=1e-9)
    # the length is the true one whatever the scale
    assert np.array_equal(residual_vectors(x, y, z, vx, vy, vz, 10.0).length,
                          residual_vectors(x, y, z, vx, vy, vz, 1.0).length)


def test_nearest_within_matches_brute_force():
    rng = np.random.default_rng(3)
    targets = rng.uniform(0, 100, (300, 3))
    points = np.vstack([targets[:50, :2] + rng.normal(0, 0.0004, (50, 2)),
                        rng.uniform(0, 100, (200, 2))])
    tol = 0.5
    got = nearest_within(points, targets, tol)
    d = np.sqrt(((points[:, None, :] - targets[None, :, :2]) ** 2).sum(axis=2))
    best = d.argmin(axis=1)
    want = np.where(d[np.arange(len(points)), best] <= tol, best, -1)
    assert np.array_equal(got, want)
    assert (got[:50] == np.arange(50)).all() and (got >= 0).sum() >= 50
    assert nearest_within(points, np.zeros((0, 2)), tol).tolist() == [-1] * len(points)
    assert nearest_within(np.zeros((0, 2)), targets, tol).shape == (0,)


def _layer(features):
    """A LineLayer of ``{id: [(x, y), ...]}`` (one part each)."""
    ids, coords, vf, vi = [], [], [], []
    for k, (fid, pts) in enumerate(features.items()):
        ids.append(fid)
        for j, (px, py) in enumerate(pts):
            coords.append((px, py, 0.0))
            vf.append(k)
            vi.append(j)
    return LineLayer(name="OSM", feature_ids=ids, attributes={}, coords=coords,
                     vertex_feature=vf, vertex_index=vi, vertex_part=[0] * len(vf))


def test_junction_renames_of_a_left_out_road():
    roads = {"a": [(0, 0), (10, 0), (20, 0)],
             "b": [(10, 0.0002), (10, 10)],  # starts at a's middle vertex: a junction
             "c": [(30, 0), (40, 0)]}
    full = _layer(roads)
    kept = _layer({"a": roads["a"], "c": roads["c"]})
    out = junction_renames(full, kept, {"b"}, tolerance=0.001)
    assert out == {"b_0": "a_1", "b_1": None}
    # a tolerance smaller than the gap: no junction, both left out
    assert junction_renames(full, kept, {"b"}, tolerance=0.0001) == {"b_0": None, "b_1": None}
    assert junction_renames(full, kept, set(), tolerance=0.001) == {}
    # nothing kept: every vertex of the missing roads is left out
    none = _layer({})
    assert junction_renames(full, none, {"a", "b", "c"}, 0.001) == dict.fromkeys(
        ["a_0", "a_1", "a_2", "b_0", "b_1", "c_0", "c_1"])
