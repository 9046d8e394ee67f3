"""``segment_buffer_test``: the exact buffer test on segment arrays (numpy only, the QGIS
plugin's entry point) gives the rows of ``buffer_test(..., method="exact")``."""

import numpy as np
import pytest

from vectoradjust.accuracy.buffer import buffer_test, line_segments, segment_buffer_test


def _lines():
    shapely = pytest.importorskip("shapely")
    rng = np.random.default_rng(3)
    ref = [shapely.linestrings(np.cumsum(rng.normal(0, 5, (30, 2)), axis=0)) for _ in range(8)]
    tst = [shapely.linestrings(np.asarray(g.coords) + rng.normal(0, 1.0, (30, 2)))
           for g in ref]
    return tst, ref


def test_segments_give_the_exact_rows():
    tst, ref = _lines()
    widths = [0.0, 0.5, 1.0, 2.0]
    want = buffer_test(tst, ref, widths, method="exact")
    steps = []
    got = segment_buffer_test(line_segments(tst), line_segments(ref), widths, chunk=50,
                              step=steps.append)
    for a, b in zip(got, want):
        assert a["width"] == b["width"]
        assert a["length_total"] == pytest.approx(b["length_total"], rel=1e-12)
        assert a["length_inside"] == pytest.approx(b["length_inside"], rel=1e-12, abs=1e-9)
    assert got[0]["share"] == 0.0 and 0.0 < got[1]["share"] < got[3]["share"] <= 1.0
    assert sum(steps) == len(line_segments(tst)) and len(steps) == 5  # 232 segments by 50


def test_no_reference_or_no_length():
    seg = np.array([[[0.0, 0.0], [3.0, 4.0]]])
    rows = segment_buffer_test(seg, np.zeros((0, 2, 2)), [1.0])
    assert rows == [{"width": 1.0, "share": 0.0, "length_inside": 0.0, "length_total": 5.0}]
    assert segment_buffer_test(np.zeros((0, 2, 2)), seg, 1.0)[0]["share"] is None
    with pytest.raises(ValueError, match="finite and >= 0"):
        segment_buffer_test(seg, seg, [-1.0])
