"""The compiled union of each feature's segment bands (numba, issue 13) against GEOS.

Truth is GEOS's union (``shapely.union_all`` per feature, and the buffer-by-0 union of
:func:`derived_outputs._union_per_feature` that the kernel replaces): the same area to
1e-9 (symmetric difference), the same parts and holes, a valid MultiPolygon, oriented as
GEOS orients it. Features the kernel leaves to GEOS (a close decision) must be rare on
real and random bands, and where it leaves them the answer is still GEOS's. Without
numba (QGIS's Python) the module is skipped and GEOS is what runs.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.accuracy.derived import band_kernels

pytest.importorskip("numba")
shapely = pytest.importorskip("shapely")


@pytest.fixture
def union(monkeypatch):
    """The compiled union kernel."""
    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    k = band_kernels._union_kernel()
    assert k is not None
    return k


def _arrays(features):
    """Kernel inputs from features given as lists of polygons (or None: no ring)."""
    rings, usable, fs = [], [], [0]
    for polys in features:
        for p in polys:
            if p is None:
                rings.append(np.zeros((0, 2)))
                usable.append(0)
            else:
                rings.append(shapely.get_coordinates(p.exterior))
                usable.append(1 if p.is_valid else -1)
        fs.append(len(rings))
    sizes = [len(r) for r in rings]
    xy = np.concatenate(rings) if rings else np.zeros((0, 2))
    return (xy, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            np.array(fs, np.int64), np.array(usable, np.int8))


def _geoms(out, loops, lstart, n):
    """MultiPolygons from the kernel's loops (None where it left the feature)."""
    res = []
    for f in range(n):
        parts = []
        for a, b, sign in loops[lstart[f]:lstart[f + 1]]:
            ring = out[a:b]
            if sign > 0:
                parts.append([ring])
            else:
                parts[-1].append(ring)
        res.append(shapely.MultiPolygon([shapely.Polygon(p[0], p[1:]) for p in parts]))
    return res


def _check(features, union, max_left=0.0):
    """The kernel's union of every feature against GEOS; returns the status."""
    from vectoradjust.files.derived_outputs import _union_per_feature

    out, loops, lstart, status = union(*_arrays(features), 1e-10)
    assert status.mean() <= max_left
    mine = _geoms(out, loops, lstart, len(features))
    polys = np.array([p if p is not None else shapely.Polygon() for f in features for p in f],
                     dtype=object)
    group = np.repeat(np.arange(len(features)), [len(f) for f in features])
    geos = _union_per_feature(shapely.make_valid(polys), group, len(features))
    for f, (got, ref) in enumerate(zip(mine, geos)):
        exact = shapely.union_all(shapely.make_valid(polys[group == f]))
        if status[f]:  # left to GEOS: nothing written here
            assert lstart[f + 1] == lstart[f]
            continue
        assert got.is_valid and got.geom_type == "MultiPolygon"
        assert shapely.symmetric_difference(got, exact).area <= 1e-9 * max(exact.area, 1e-300)
        assert len(got.geoms) == len(ref.geoms)
        assert sorted(len(p.interiors) for p in got.geoms) == \
            sorted(len(p.interiors) for p in ref.geoms)
        for p in got.geoms:  # as GEOS writes a buffer: outer rings clockwise, holes not
            assert not p.exterior.is_ccw and all(h.is_ccw for h in p.interiors)
    return status


def _chains(n_features, seed, scale, step=1.5):
    """Random walks (one feature each) and their segments' G-band rings."""
    rng = np.random.default_rng(seed)
    p1, p2, group = [], [], []
    for f in range(n_features):
        walk = np.cumsum(rng.normal(0, step, (int(rng.integers(2, 14)), 2)), axis=0) + f * 60
        p1 += list(walk[:-1])
        p2 += list(walk[1:])
        group += [f] * (len(walk) - 1)
    p1, p2 = np.array(p1), np.array(p2)
    a = rng.normal(size=(len(p1), 4, 4)) * scale
    xy, off = band_kernels.g_band_rings(p1, p2, a @ np.swapaxes(a, 1, 2) + np.eye(4) * scale**2)
    return xy, off, np.array(group)


def _features_of_rings(xy, off, group, n):
    polys = [shapely.Polygon(xy[off[i]:off[i + 1]]) if off[i + 1] - off[i] >= 4 else None
             for i in range(len(off) - 1)]
    return [[polys[i] for i in np.flatnonzero(group == f)] for f in range(n)]


@pytest.mark.parametrize("scale", [0.02, 0.1, 0.5, 2.0])
def test_union_of_random_chains_equals_geos(union, scale):
    """From bands much narrower than the segments (neighbours overlap at their common
    end) to much wider (every band overlaps many others; holes where a walk loops)."""
    xy, off, group = _chains(60, int(scale * 100), scale)
    status = _check(_features_of_rings(xy, off, group, 60), union, max_left=0.1)
    assert status.sum() <= 6


def test_union_of_real_road_bands_equals_geos(union):
    """The real Helsinki OSM centrelines (tests/data/helsinki, ODbL, (c) OpenStreetMap
    contributors), one feature per line, at three band widths."""
    from pathlib import Path

    from vectoradjust.simulate import read_road_lines

    lines = read_road_lines(Path(__file__).parent / "data" / "helsinki"
                            / "helsinki_roads.geojson")
    coords = [np.asarray(c, float)[:, :2] for c in lines.lines]
    p1 = np.concatenate([c[:-1] for c in coords])
    p2 = np.concatenate([c[1:] for c in coords])
    group = np.repeat(np.arange(len(coords)), [len(c) - 1 for c in coords])
    rng = np.random.default_rng(3)
    own = rng.normal(size=(len(p1), 2, 2))
    own = own @ np.swapaxes(own, 1, 2) + np.eye(2) * 0.1
    c = np.zeros((len(p1), 4, 4))
    c[:, :2, :2] = c[:, 2:, 2:] = own
    c[:, :2, 2:] = c[:, 2:, :2] = 0.8 * own
    for scale in (0.01, 1.0, 25.0):  # about 0.3 m, 3 m and 15 m wide
        xy, off = band_kernels.g_band_rings(p1, p2, c * scale)
        status = _check(_features_of_rings(xy, off, group, len(coords)), union,
                        max_left=0.05)
        assert len(status) > 100


def test_union_with_a_hole_disjoint_parts_and_containment(union):
    box = shapely.box
    frame = [box(0, 0, 10, 2), box(8.5, 0.5, 10.5, 10), box(-0.5, 8.3, 9.7, 10.3),
             box(0.3, -0.4, 2.1, 9.1)]  # four bars around a hole
    apart = [box(0, 0, 1, 1), box(5, 5, 6.5, 6.2)]
    inside = [box(0, 0, 4, 4), box(1, 1.5, 2, 2.5)]  # the second in the first
    crossing = [box(0, 0, 3, 1), box(1, -1, 2, 2)]  # a plus sign: 4 crossings
    status = _check([frame, apart, inside, crossing, [box(0, 0, 1, 1)]], union)
    assert not status.any()
    out, loops, lstart, _ = union(*_arrays([frame]), 1e-10)
    assert list(loops[:, 2]) == [1, -1]  # the outer loop, then the hole


def test_close_decisions_are_left_to_geos(union):
    box = shapely.box
    cases = {
        "the same ring twice": [box(0, 0, 2, 1), box(0, 0, 2, 1)],
        "an edge shared": [box(0, 0, 2, 1), box(2, 0, 3, 1)],
        "collinear overlapping edges": [box(0, 0, 2, 1), box(1, 0, 3, 2)],
        "a vertex on an edge": [box(0, 0, 2, 2), shapely.Polygon([(1, 2), (2, 3), (0, 3)])],
        "clockwise": [box(0, 0, 2, 1, ccw=False), box(1, 0.5, 3, 2)],
        "not valid": [shapely.Polygon([(0, 0), (2, 2), (2, 0), (0, 2)])],
        "two parts and a hole": [box(0, 0, 10, 2), box(8.5, 0.5, 10.5, 10),
                                 box(-0.5, 8.3, 9.7, 10.3), box(0.3, -0.4, 2.1, 9.1),
                                 box(20, 20, 21, 21)],
    }
    status = _check(list(cases.values()), union, max_left=1.0)
    assert status.all(), [k for k, s in zip(cases, status) if not s]


def test_empty_rings_are_left_out(union):
    box = shapely.box
    status = _check([[None, box(0, 0, 1, 1), None, box(0.5, 0.5, 2, 2.2)], [None, None], []],
                    union)
    assert not status.any()
    out, loops, lstart, _ = union(*_arrays([[None, None], []]), 1e-10)
    assert len(loops) == 0 and list(lstart) == [0, 0, 0]


def test_band_union_by_the_kernel_equals_geos_through_the_chunks(union, monkeypatch):
    """:func:`_feature_unions` with the kernel (rings in order and shuffled, empty rings,
    a ring not closed) against GEOS's union of the same rings."""
    from types import SimpleNamespace

    from vectoradjust.files import derived_outputs as do

    xy, off, group = _chains(40, 11, 0.3)
    sizes = np.diff(off)
    sizes[5] = 0  # no ring
    keep = np.ones(len(xy), bool)
    keep[off[9] - 1] = False  # ring 9 not closed: to GEOS
    xy = xy[keep]
    sizes[9] -= 1
    off = np.concatenate([[0], np.cumsum(sizes)])
    used = []
    real = do._kernel_union
    monkeypatch.setattr(do, "_kernel_union", lambda *a: used.append(1) or real(*a))
    for shuffled in (False, True):
        perm = np.random.default_rng(1).permutation(len(group)) if shuffled \
            else np.arange(len(group))
        take = np.concatenate([np.arange(off[i], off[i + 1]) for i in perm]).astype(int)
        sb = SimpleNamespace(xy=xy[take], offsets=np.concatenate([[0], np.cumsum(sizes[perm])]))
        monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 0)
        got = do._feature_unions(sb, group[perm], 40, lambda f: None, chunk=60)
        monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 10**9)
        ref = do._feature_unions(sb, group[perm], 40, lambda f: None, chunk=60)
        for a, b in zip(got, ref):
            assert a.geom_type == "MultiPolygon" and a.is_valid
            assert shapely.symmetric_difference(a, b).area <= 1e-9 * max(b.area, 1e-300)
            assert len(a.geoms) == len(b.geoms)
    assert len(used) >= 4  # the kernel did the chunks (two calls per pass at least)


def test_a_union_kernel_that_fails_leaves_geos_with_a_warning(monkeypatch):
    from vectoradjust.accuracy import _unionkernel

    def broken(*args):
        raise RuntimeError("cannot cache function 'union_rings': no locator available")

    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    monkeypatch.setattr(band_kernels, "_UNION", [])
    monkeypatch.setattr(_unionkernel, "union_rings", broken)
    with pytest.warns(RuntimeWarning, match="no locator available.*GEOS"):
        assert band_kernels._union_kernel() is None
    assert band_kernels._UNION == [None]
    monkeypatch.setattr(band_kernels, "_UNION", [])
    monkeypatch.setenv("VECTORADJUST_NUMBA", "0")
    assert band_kernels._union_kernel() is None and band_kernels._UNION == []


def test_without_numba_geos_unites_the_bands(monkeypatch):
    import sys

    import vectoradjust.accuracy as package

    monkeypatch.setattr(band_kernels, "_UNION", [])
    monkeypatch.setitem(sys.modules, "vectoradjust.accuracy._unionkernel", None)
    monkeypatch.delattr(package, "_unionkernel", raising=False)
    assert band_kernels._union_kernel() is None
    assert band_kernels._UNION == [None]
    assert not band_kernels.warm_ring_kernel(10**6)
