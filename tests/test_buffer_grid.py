"""The grid pairing of the exact buffer test against brute force and GEOS."""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.accuracy.buffer import (
    SegmentBuffer,
    _Grid,
    capsule_intervals,
    covered_length,
)


def _random_segments(rng, n, spread=1000.0, length=30.0, long_share=0.05):
    a = rng.uniform(0, spread, (n, 2))
    ln = np.where(rng.random(n) < long_share, rng.uniform(100, 800, n), rng.exponential(length, n))
    ang = rng.uniform(0, 2 * np.pi, n)
    b = a + ln[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    return np.stack([a, b], axis=1)


def test_grid_pairs_are_every_overlapping_pair_once():
    rng = np.random.default_rng(5)
    ref = _random_segments(rng, 300)
    tst = _random_segments(rng, 400)
    lo_r, hi_r = ref.min(axis=1) - 2.0, ref.max(axis=1) + 2.0
    lo_t, hi_t = tst.min(axis=1), tst.max(axis=1)
    i, j = _Grid(lo_r, hi_r, 25.0).pairs(lo_t, hi_t)
    got = set(zip(i.tolist(), j.tolist()))
    assert len(got) == len(i)  # each pair once
    brute = np.all((lo_t[:, None] <= hi_r[None]) & (lo_r[None] <= hi_t[:, None]), axis=2)
    assert got == set(zip(*map(np.ndarray.tolist, np.nonzero(brute))))


def _reference_inside(ref, tst, widths):
    """The former implementation: GEOS dwithin pairs of whole segments."""
    shapely = pytest.importorskip("shapely")
    tree = shapely.STRtree(shapely.linestrings(ref.reshape(-1, 2),
                                               indices=np.repeat(np.arange(len(ref)), 2)))
    geoms = shapely.linestrings(tst.reshape(-1, 2), indices=np.repeat(np.arange(len(tst)), 2))
    i, j = tree.query(geoms, predicate="dwithin", distance=float(max(widths)))
    length = np.hypot(*(tst[:, 1] - tst[:, 0]).T)
    out = []
    for x in widths:
        s, e = capsule_intervals(tst[i, 0], tst[i, 1], ref[j, 0], ref[j, 1], x)
        out.append(covered_length(i, s, e, length))
    return np.array(out)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_grid_buffer_lengths_equal_the_geos_pairs(seed):
    rng = np.random.default_rng(seed)
    ref = _random_segments(rng, 500)
    # tested lines near the reference: shifted copies, and some far away
    tst = np.concatenate([ref[:300] + rng.normal(0, 1.5, (300, 1, 2)),
                          _random_segments(rng, 200)])
    widths = [0.5, 1.0, 2.0, 5.0]
    got = SegmentBuffer(ref + 506000.0).inside(tst + 506000.0, widths)
    want = _reference_inside(ref, tst, widths)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert np.all(np.diff(got) >= 0) and got[-1] > 0


def test_long_reference_segments_are_cut_without_changing_the_buffer():
    ref = np.array([[[0.0, 0.0], [1000.0, 1000.0]], [[0.0, 5.0], [3.0, 5.0]],
                    [[10.0, 10.0], [12.0, 10.0]]])
    tst = np.array([[[0.0, 1.0], [999.0, 1000.5]], [[500.0, 0.0], [500.0, 1000.0]]])
    buf = SegmentBuffer(ref)
    assert len(buf.ref) > len(ref)  # the diagonal was cut
    np.testing.assert_allclose(buf.inside(tst, [1.0, 2.0]),
                               _reference_inside(ref, tst, [1.0, 2.0]), rtol=1e-12)


def test_nearest_distance_equals_brute_force_within_the_radius():
    rng = np.random.default_rng(9)
    ref = _random_segments(rng, 400)
    xy = np.concatenate([ref[:200, 0] + rng.normal(0, 3, (200, 2)),
                         rng.uniform(-500, 1500, (300, 2))])
    xy[7] = np.nan
    buf = SegmentBuffer(ref + [506000.0, 4474000.0])
    got = buf.nearest_distance(xy + [506000.0, 4474000.0], radius=20.0)
    a, d = ref[None, :, 0], ref[None, :, 1] - ref[None, :, 0]
    w = xy[:, None] - a
    t = np.clip(np.einsum("nmk,nmk->nm", w, d) / np.einsum("nmk,nmk->nm", d, d), 0, 1)
    brute = np.hypot(*np.moveaxis(w - t[..., None] * d, -1, 0)).min(axis=1)
    near = brute <= 20.0
    assert np.isnan(got[7]) and near.sum() > 200 and (~near).sum() > 20
    np.testing.assert_allclose(got[near], brute[near], rtol=0, atol=1e-9)
    assert np.isnan(got[~near & np.isfinite(brute)]).all()  # farther: left to the caller


def test_long_tested_segments_against_dense_reference_lines():
    """A database with 5 km segments (TIGER-like) against true lines sampled every 5 m:
    the tested segments are cut into pieces of a few cells (their boxes would cover a
    million cells each), and the lengths stay those of the GEOS pairs."""
    from vectoradjust.accuracy.buffer import _cut

    t = np.linspace(0.0, 1.0, 1001)[:, None]
    line = t * [3000.0, 4000.0]  # 5 km, 5 m steps
    ref = np.stack([line[:-1], line[1:]], axis=1)
    tst = np.array([[[0.0, 0.8], [3000.0, 4000.8]], [[10.0, 0.0], [3010.0, 4000.0]],
                    [[0.0, 1.6], [3000.0, 4001.6]]])
    buf = SegmentBuffer(ref)
    assert buf.cell < 10 and len(_cut(tst, 4 * buf.cell)) > 100 * len(tst)
    np.testing.assert_allclose(buf.inside(tst, [1.0, 2.0, 10.0]),
                               _reference_inside(ref, tst, [1.0, 2.0, 10.0]), rtol=1e-12)
