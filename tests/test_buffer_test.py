"""Tests of vectoradjust.accuracy.buffer against hand-computed geometry."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

shapely = pytest.importorskip("shapely")
from shapely.geometry import LineString, MultiLineString, Point  # noqa: E402

from vectoradjust.accuracy.buffer import buffer_test  # noqa: E402
from vectoradjust.errors import LayerError  # noqa: E402


def _shares(res):
    return [r["share"] for r in res]


def test_parallel_offset_line_is_a_step_at_the_offset():
    """A line offset by d from its reference: share 0 below d, 1 above."""
    d = 2.5
    ref = LineString([(0, 0), (100, 0)])
    tst = LineString([(0, d), (100, d)])
    res = buffer_test(tst, ref, [0.5, 1.0, 2.4, 2.6, 5.0])
    assert _shares(res) == [0.0, 0.0, 0.0, 1.0, 1.0]
    assert all(r["length_total"] == pytest.approx(100.0) for r in res)
    assert res[3]["length_inside"] == pytest.approx(100.0)
    assert [r["width"] for r in res] == [0.5, 1.0, 2.4, 2.6, 5.0]
    json.dumps(res)


def test_half_inside_flat_caps():
    """Reference covers x in [0, 50] of a 100 m tested line 1 m away: share 0.5."""
    ref = LineString([(0, 0), (50, 0)])
    tst = LineString([(0, 1), (100, 1)])
    res = buffer_test(tst, ref, [2.0], cap_style="flat")[0]
    assert res["share"] == pytest.approx(0.5, abs=1e-12)
    assert res["length_inside"] == pytest.approx(50.0, abs=1e-10)


def test_half_inside_round_cap_hand_computed():
    """With a round cap of radius x the inside part ends at 50 + sqrt(x^2 - 1)."""
    ref = LineString([(0, 0), (50, 0)])
    tst = LineString([(0, 1), (100, 1)])
    x = 2.0
    res = buffer_test(tst, ref, [x], quad_segs=64)[0]
    expected = 50.0 + math.sqrt(x * x - 1.0)
    # the polygonal cap lies inside the circle by at most x (1 - cos(pi / 256))
    sagitta = x * (1 - math.cos(math.pi / (4 * 64)))
    slack = sagitta * x / math.sqrt(x * x - 1.0) + 1e-9  # along the tested line
    assert expected - slack <= res["length_inside"] <= expected + 1e-9


def test_crossing_line_inside_length():
    """A line crossing a long reference at angle a has 2 x / sin(a) inside."""
    ref = LineString([(-1000, 0), (1000, 0)])
    a = math.radians(30)
    L = 200.0
    half = (L / 2 * math.cos(a), L / 2 * math.sin(a))
    tst = LineString([(-half[0], -half[1]), half])
    widths = [1.0, 5.0, 20.0]
    for r, x in zip(buffer_test(tst, ref, widths), widths):
        assert r["length_inside"] == pytest.approx(2 * x / math.sin(a), rel=1e-9)
        assert r["share"] == pytest.approx(2 * x / math.sin(a) / L, rel=1e-9)


def test_overlapping_reference_buffers_count_once():
    refs = [LineString([(0, 0), (10, 0)]), LineString([(0, 1), (10, 1)])]
    tst = LineString([(0, 0.5), (10, 0.5)])
    res = buffer_test(tst, refs, [1.0])[0]
    assert res["share"] == pytest.approx(1.0) and res["length_inside"] == pytest.approx(10.0)


def test_sequences_multilines_and_empties():
    ref = MultiLineString([[(0, 0), (10, 0)], [(20, 0), (30, 0)]])
    tst = [
        LineString([(0, 0.5), (10, 0.5)]),  # inside at 1 m
        None,
        LineString(),  # empty: skipped
        MultiLineString([[(20, 3), (30, 3)], [(40, 0), (50, 0)]]),  # outside at 1 m
    ]
    res = buffer_test(tst, ref, [1.0, 4.0], cap_style="flat")
    assert res[0]["length_total"] == pytest.approx(30.0)
    assert res[0]["share"] == pytest.approx(10.0 / 30.0)
    assert res[1]["share"] == pytest.approx(20.0 / 30.0)


def test_share_is_monotone_in_width():
    rng = np.random.default_rng(3)
    xs = np.linspace(0, 500, 60)
    ref = LineString(np.column_stack([xs, np.zeros_like(xs)]))
    tst = LineString(np.column_stack([xs, rng.normal(0, 3.0, xs.size)]))
    shares = _shares(buffer_test(tst, ref, np.linspace(0.1, 15, 30)))
    assert all(b >= a - 1e-12 for a, b in zip(shares, shares[1:]))
    assert shares[-1] == pytest.approx(1.0)


def test_degenerate_and_bad_inputs():
    ref = LineString([(0, 0), (10, 0)])
    assert buffer_test([], ref, [1.0])[0]["share"] is None
    assert buffer_test(LineString([(0, 0), (10, 0)]), ref, 0.0)[0]["share"] == 0.0
    assert buffer_test(LineString([(0, 0), (10, 0)]), [], 1.0)[0]["share"] == 0.0
    with pytest.raises(ValueError, match=r"widths must be finite and >= 0, got \[-1\.0\]"):
        buffer_test(ref, ref, [-1.0])
    with pytest.raises(ValueError, match=r"widths must be finite and >= 0, got \[nan\]"):
        buffer_test(ref, ref, [np.nan])
    with pytest.raises(LayerError, match=r"tested geometry 0 is a Point, not a line.*LineString"):
        buffer_test(Point(0, 0), ref, 1.0)
    with pytest.raises(LayerError, match=r"reference geometry 0 is a Polygon.*LineString"):
        buffer_test(ref, Point(0, 0).buffer(1.0), 1.0)


# --------------------------------------------------------------------------- exact method
def test_exact_method_on_hand_computed_cases():
    """The exact round buffer gives the closed-form lengths without chord error."""
    ref = LineString([(0, 0), (100, 0)])
    tst = LineString([(0, 2.5), (100, 2.5)])
    res = buffer_test(tst, ref, [0.5, 2.4, 2.5, 2.6], method="exact")
    assert _shares(res) == [0.0, 0.0, 1.0, 1.0]  # boundary included
    half = buffer_test(LineString([(0, 1), (100, 1)]), LineString([(0, 0), (50, 0)]), [2.0],
                       method="exact")[0]
    assert half["length_inside"] == pytest.approx(50.0 + math.sqrt(2.0**2 - 1.0), abs=1e-9)
    a = math.radians(30)
    cross = LineString([(-100 * math.cos(a), -100 * math.sin(a)),
                        (100 * math.cos(a), 100 * math.sin(a))])
    r = buffer_test(cross, LineString([(-1000, 0), (1000, 0)]), [5.0], method="exact")[0]
    assert r["length_inside"] == pytest.approx(10.0 / math.sin(a), rel=1e-12)


def test_exact_method_overlaps_count_once_and_joins_are_round():
    refs = [LineString([(0, 0), (10, 0)]), LineString([(0, 1), (10, 1)])]
    res = buffer_test(LineString([(0, 0.5), (10, 0.5)]), refs, [1.0], method="exact")[0]
    assert res["length_inside"] == pytest.approx(10.0, abs=1e-12)
    # a right-angle corner at the origin: points beyond it within x of the corner only
    ref = LineString([(-50, 0), (0, 0), (0, 50)])
    tst = LineString([(1, -10), (1, 10)])  # 1 m right of the vertical leg, below the corner
    got = buffer_test(tst, ref, [2.0], method="exact")[0]["length_inside"]
    # inside: y from -sqrt(4 - 1) (round join around the corner) up to 10
    assert got == pytest.approx(10.0 + math.sqrt(3.0), abs=1e-12)


def test_exact_equals_the_union_polygon_buffer_in_the_limit():
    """The old union-of-all-lines polygon method converges to the exact one.

    The polygon buffer is inscribed in the round one (chords of ``quad_segs`` per quarter
    circle), so it lies below by at most the chord error and the gap shrinks like
    ``1 / quad_segs^2``.
    """
    rng = np.random.default_rng(7)
    xs = np.linspace(0, 400, 40)
    refs = [LineString(np.column_stack([xs + rng.normal(0, 4, xs.size),
                                        rng.normal(0, 4, xs.size) + 6 * k]))
            for k in range(4)]
    tst = [LineString(np.column_stack([xs, rng.normal(0, 5, xs.size) + 6 * k]))
           for k in range(3)] + [MultiLineString([[(0, 0), (50, 30)], [(60, 0), (90, 5)]])]
    widths = [0.5, 1.0, 2.0, 5.0]
    exact = buffer_test(tst, refs, widths, method="exact")
    gaps = []
    for quad in (8, 32, 128):
        poly = buffer_test(tst, refs, widths, quad_segs=quad)
        gap = np.array([e["length_inside"] - p["length_inside"] for e, p in zip(exact, poly)])
        assert np.all(gap >= -1e-9)  # the polygon is inside the round buffer
        assert [e["length_total"] for e in exact] == [p["length_total"] for p in poly]
        gaps.append(gap.max())
    assert gaps[0] > 0 and gaps[2] < gaps[0] / 50  # ~1/16^2 of the gap at 8 chords
    shares32 = _shares(buffer_test(tst, refs, widths))
    assert _shares(exact) == pytest.approx(shares32, abs=1e-4)


def test_exact_method_rejects_flat_caps():
    with pytest.raises(ValueError, match="round"):
        buffer_test(LineString([(0, 0), (1, 0)]), LineString([(0, 0), (1, 0)]), [1.0],
                    cap_style="flat", method="exact")
    assert buffer_test([], LineString([(0, 0), (1, 0)]), [1.0], method="exact")[0]["share"] is None
    assert buffer_test(LineString([(0, 0), (1, 0)]), [], [1.0],
                       method="exact")[0]["share"] == 0.0


def test_exact_method_in_chunks_equals_one_pass():
    from vectoradjust.accuracy.buffer import SegmentBuffer, line_segments

    rng = np.random.default_rng(11)
    xs = np.linspace(0, 300, 80)
    ref = line_segments([LineString(np.column_stack([xs, rng.normal(0, 2, xs.size)]))])
    tst = line_segments([LineString(np.column_stack([xs, rng.normal(0, 3, xs.size)]))])
    whole = SegmentBuffer(ref).inside(tst, [1.0, 3.0])
    small = SegmentBuffer(ref)
    small.chunk = 7
    assert np.allclose(small.inside(tst, [1.0, 3.0]), whole, rtol=1e-13, atol=0)
    assert 0 < whole[0] < whole[1] < np.hypot(*(tst[:, 1] - tst[:, 0]).T).sum()


def test_covered_lengths_per_segment_by_hand():
    from vectoradjust.accuracy.buffer import covered_length, covered_lengths

    seg = np.array([2, 0, 0, 3, 0])
    start = np.array([0.1, 0.0, 0.25, 0.6, 0.9])
    end = np.array([0.2, 0.5, 0.75, 0.5, 1.0])  # segment 3's interval is empty
    length = np.array([10.0, 4.0, 20.0, 7.0])
    got = covered_lengths(seg, start, end, length)
    # segment 0: [0, 0.75] and [0.9, 1] of 10 m; segment 1 none; segment 2: 0.1 of 20 m
    assert got == pytest.approx([8.5, 0.0, 2.0, 0.0], abs=1e-12)
    assert got.sum() == pytest.approx(covered_length(seg, start, end, length), rel=1e-15)
    assert covered_lengths(seg[:0], start[:0], end[:0], length).tolist() == [0.0] * 4


def _wiggly_case():
    """Reference lines with short segments (a small grid cell) and tested lines with
    long segments (cut into many pieces), a crossing line and one far away."""
    from vectoradjust.accuracy.buffer import line_segments

    rng = np.random.default_rng(5)
    xs = np.linspace(0, 200, 120)
    refs = [LineString(np.column_stack([xs, rng.normal(0, 0.8, xs.size) + 5 * k]))
            for k in range(2)]
    long_x = np.linspace(-10, 210, 6)
    tst = [LineString(np.column_stack([long_x, rng.normal(0, 1.5, long_x.size) + 5 * k]))
           for k in range(2)]
    tst += [LineString([(50, -20), (60, 30)]), LineString([(0, 500), (100, 510)])]
    return refs, tst, line_segments(refs), line_segments(tst)


def test_inside_per_segment_equals_polygon_clipping_per_segment():
    """Each tested segment's length inside the buffer, against shapely clipping the
    segment with the (fine, quad_segs=256) polygon buffer of the union of the lines."""
    from vectoradjust.accuracy.buffer import SegmentBuffer

    refs, _, ref, tst = _wiggly_case()
    widths = [0.5, 2.0, 4.0]
    got = SegmentBuffer(ref).inside(tst, widths, per_segment=True)
    assert got.shape == (len(tst), 3)
    union = shapely.union_all(refs)
    for k, x in enumerate(widths):
        buf = union.buffer(x, quad_segs=256)
        lines = shapely.linestrings(tst)
        truth = shapely.length(shapely.intersection(lines, buf))
        # the polygon is inside the round buffer by at most its chord error
        assert np.all(got[:, k] >= truth - 1e-9)
        assert got[:, k] == pytest.approx(truth, abs=1e-4 * x)
    assert np.any(got[:, 0] > 0) and got[-1].tolist() == [0.0, 0.0, 0.0]  # the far line


def test_inside_per_segment_sums_to_the_summed_form_in_any_chunks():
    from vectoradjust.accuracy.buffer import SegmentBuffer

    _, _, ref, tst = _wiggly_case()
    widths = [0.0, 1.0, 3.0]
    buf = SegmentBuffer(ref)
    whole = buf.inside(tst, widths)
    per = buf.inside(tst, widths, per_segment=True)
    assert per.sum(axis=0) == pytest.approx(whole, rel=1e-13, abs=0)
    assert per[:, 0].tolist() == [0.0] * len(tst)  # width 0: nothing inside
    small = SegmentBuffer(ref)
    small.chunk = 3
    # a segment's values do not depend on the others measured with it: bit for bit
    assert np.array_equal(small.inside(tst, widths, per_segment=True), per)
    assert np.array_equal(buf.inside(tst[5:9], widths, per_segment=True), per[5:9])
    empty = buf.inside(tst[:0], widths, per_segment=True)
    assert empty.shape == (0, 3)
    assert SegmentBuffer(ref[:0]).inside(tst, widths, per_segment=True).shape == (len(tst), 3)
