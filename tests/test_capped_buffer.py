"""The buffer test with flat and square end caps (:mod:`vectoradjust.accuracy.capped_buffer`)
and the nearest distances of :mod:`vectoradjust.accuracy.line_distances`, against hand
computations, GEOS's polygon buffers (shapely) and brute force."""

import math

import numpy as np
import pytest

from vectoradjust.accuracy.buffer import SegmentBuffer, line_segments
from vectoradjust.accuracy.capped_buffer import capped_buffer_test, part_segments
from vectoradjust.accuracy.line_distances import nearest_distances, room_in_box

shapely = pytest.importorskip("shapely")


def _seg(*xy):
    xy = np.asarray(xy, float)
    return np.stack([xy[:-1], xy[1:]], axis=1)


def _inside(tested, parts, widths, cap):
    return [r["length_inside"] for r in capped_buffer_test(tested, parts, widths, cap)]


def test_a_straight_reference_by_hand():
    ref = [np.array([[0.0, 0.0], [10.0, 0.0]])]
    along = _seg((-5, 1), (15, 1))  # 20 m parallel, 1 m off
    assert _inside(along, ref, [0.5, 2.0], "flat") == pytest.approx([0.0, 10.0], abs=1e-12)
    assert _inside(along, ref, [0.5, 2.0], "square") == pytest.approx([0.0, 14.0], abs=1e-12)
    across = _seg((12, -5), (12, 5))  # crosses beyond the end: only the square cap holds it
    assert _inside(across, ref, [3.0], "flat") == [0.0]
    assert _inside(across, ref, [3.0], "square") == pytest.approx([6.0], abs=1e-12)
    rows = capped_buffer_test(along, ref, [0, 2.0], "flat")
    assert rows[0] == {"width": 0.0, "share": 0.0, "length_inside": 0.0, "length_total": 20.0}
    assert rows[1]["share"] == pytest.approx(0.5)


def test_the_round_join_at_a_corner_by_hand():
    # an L: east then north; the outer side of the turn is the south-east quadrant
    ref = [np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])]
    x = 2.0
    # a line through the corner's outer quadrant at 45 degrees: inside the join disc
    # for |t| <= x around the corner's diagonal point, so 2 * sqrt(x^2 - d^2) with the
    # distance d of the line from the corner
    d = 1.0
    c = np.array([10.0, 0.0]) + d * np.array([1.0, -1.0]) / math.sqrt(2)
    u = np.array([1.0, 1.0]) / math.sqrt(2)
    tested = _seg(c - 5 * u, c + 5 * u)
    # the rectangles: the line runs in the first rectangle (y >= -2, x <= 10) and in the
    # second (x <= 12, y >= 0); with the sector the union is one interval
    got = _inside(tested, ref, [x], "flat")[0]
    # brute force: sample the line densely, test each point against the region
    t = np.linspace(-5, 5, 200001)
    p = c + t[:, None] * u
    in1 = (p[:, 0] >= 0) & (p[:, 0] <= 10) & (np.abs(p[:, 1]) <= x)
    in2 = (p[:, 1] >= 0) & (p[:, 1] <= 10) & (np.abs(p[:, 0] - 10) <= x)
    w = p - [10.0, 0.0]
    in3 = (np.hypot(w[:, 0], w[:, 1]) <= x) & (w[:, 0] >= 0) & (w[:, 1] <= 0)
    assert got == pytest.approx(10.0 * np.mean(in1 | in2 | in3), abs=1e-3)
    assert got > 0


def test_random_lines_agree_with_geos_where_geos_cuts_nothing():
    # every reference segment longer than twice the widest buffer: GEOS's flat and square
    # buffers are then the union of rectangles and round joins too, up to its chords
    rng = np.random.default_rng(11)
    widths = [0.5, 1.0, 2.0, 3.0]
    refs = []
    while len(refs) < 12:
        xy = np.cumsum(rng.normal(0, 12, (int(rng.integers(2, 7)), 2)), axis=0)
        if np.all(np.hypot(*np.diff(xy, axis=0).T) > 2 * max(widths) + 1):
            refs.append(xy)
    refs.append(np.array([[40.0, 40.0], [60.0, 40.0], [60.0, 60.0], [40.0, 60.0], [40, 40]]))
    tested = [shapely.LineString(np.cumsum(rng.normal(0, 6, (int(rng.integers(2, 40)), 2)),
                                           axis=0) + rng.normal(0, 10, 2)) for _ in range(40)]
    tseg = line_segments(tested)
    ml = shapely.MultiLineString([shapely.LineString(r) for r in refs])
    for cap in ("flat", "square"):
        got = _inside(tseg, refs, widths, cap)
        for w, g in zip(widths, got):
            buf = shapely.buffer(ml, w, quad_segs=512, cap_style=cap)
            geos = float(sum(shapely.intersection(t, buf).length for t in tested))
            assert g == pytest.approx(geos, rel=2e-6, abs=1e-4), (cap, w)
        assert got[-1] > 0


def test_a_short_last_segment_keeps_the_rectangle_geos_cuts():
    # GEOS's flat buffer of this line cuts the first segment's rectangle above y = 0.5
    # (the end cap of the short last segment); the union of rectangles does not
    ref = [np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 0.5]])]
    tested = _seg((0, 3), (20, 3))
    got = _inside(tested, ref, [5.0], "flat")[0]
    assert got == pytest.approx(10.0, abs=1e-12)  # the points (0..10, 3): within 3 m
    geos = shapely.intersection(shapely.LineString([(0, 3), (20, 3)]), shapely.buffer(
        shapely.LineString(ref[0]), 5.0, quad_segs=64, cap_style="flat")).length
    assert geos < got - 1.0


def test_part_segments_caps_and_joins():
    seg, first, last, joins = part_segments([
        np.array([[0, 0], [1, 0], [1, 0], [2, 0]]),  # a repeated vertex is dropped
        np.array([[0, 5], [1, 5], [1, 6], [0, 5]]),  # closed: no caps, three joins
        np.array([[9, 9]]),  # a single vertex: nothing
    ])
    assert len(seg) == 5
    assert first.tolist() == [True, False, False, False, False]
    assert last.tolist() == [False, True, False, False, False]
    assert len(joins) == 1 + 3
    assert joins[0, 0].tolist() == [1.0, 0.0]


def test_bad_arguments():
    with pytest.raises(ValueError, match="cap_style must be one of"):
        capped_buffer_test(_seg((0, 0), (1, 0)), [np.array([[0, 0], [1, 0]])], [1], "round")
    with pytest.raises(ValueError, match="finite and >= 0"):
        capped_buffer_test(_seg((0, 0), (1, 0)), [np.array([[0, 0], [1, 0]])], [-1], "flat")
    steps = []
    rows = capped_buffer_test(np.zeros((0, 2, 2)), [], [1.0], "flat", step=steps.append)
    assert rows[0]["share"] is None and rows[0]["length_total"] == 0.0 and steps == [0]


def test_nearest_distances_and_room_match_brute_force():
    rng = np.random.default_rng(4)
    ref = _seg(*np.cumsum(rng.normal(0, 30, (60, 2)), axis=0))
    xy = rng.uniform(-300, 300, (300, 2))
    xy[5] = np.nan
    calls = []
    got = nearest_distances(SegmentBuffer(ref), xy, check=lambda: calls.append(1))
    a, b = ref[:, 0], ref[:, 1]
    d = b - a
    w = xy[:, None, :] - a[None]
    t = np.clip((w * d).sum(-1) / (d * d).sum(-1), 0, 1)
    brute = np.hypot(*(w - t[..., None] * d).transpose(2, 0, 1)).min(axis=1)
    ok = np.isfinite(brute)
    assert np.allclose(got[ok], brute[ok], rtol=0, atol=1e-9)
    assert np.isnan(got[5]) and calls
    room = room_in_box(np.array([[1.0, 2.0], [-1.0, 0.5]]), (0.0, 0.0, 10.0, 4.0))
    assert room.tolist() == [1.0, -1.0]
    assert room_in_box(np.zeros((2, 2)), None).tolist() == [math.inf, math.inf]
