"""The geometry-free part of the ``[truth]`` buffer test (used by the QGIS plugin with
GEOS): line ranges, the lines compared, progress per database/chunk and Cancel."""

from types import SimpleNamespace

import numpy as np
import pytest

from vectoradjust.errors import CancelledError
from vectoradjust.files.truth import drive_truth_buffer, line_ranges


def test_line_ranges_skip_parts_with_one_vertex():
    feature = np.array([0, 0, 0, 1, 2, 2, 2, 2])
    part = np.array([0, 0, 0, 0, 0, 0, 1, 1])
    assert line_ranges(feature, part) == [(0, 3), (4, 6), (6, 8)]
    assert line_ranges(np.array([], int), np.array([], int)) == []


def _run():
    layer = SimpleNamespace(vertex_feature=np.array([0, 0, 1, 1, 2, 2]),
                            vertex_part=np.zeros(6, int),
                            coords=np.arange(18, dtype=float).reshape(6, 3))
    db = SimpleNamespace(name="A", shape=SimpleNamespace(layer=layer),
                         vertices={"Adjusted": np.array([1, 0, 0, 0, 0, 1])},
                         adjusted_coords=layer.coords + 1.0)
    return SimpleNamespace(databases=[db], summary={"databases": [{}]})


def test_drive_truth_buffer_reports_and_writes_the_summary():
    run, seen, calls = _run(), [], []

    def shares(xy, ranges, step):
        seen.append((xy.copy(), list(ranges)))
        for _ in ranges:
            step(1)
        return [0.5]

    out = drive_truth_buffer(run, [1.0], shares, "t.shp",
                             progress=lambda f, m="": calls.append((f, m)))
    # features 0 and 2 have adjusted vertices; feature 1 did not move
    assert [r for _, r in seen] == [[(0, 2), (2, 4)], [(0, 2), (2, 4)]]
    assert seen[1][0][0, 0] == seen[0][0][0, 0] + 1.0  # after = adjusted coordinates
    assert out["A"] == {"widths": [1.0], "before": [0.5], "after": [0.5], "truth_lines": "t.shp"}
    assert run.summary["databases"][0]["truth"]["buffer"] is out["A"]
    fractions = [f for f, _ in calls]
    assert fractions == [0.0, 0.25, 0.5, 0.75, 1.0, 1.0]
    assert calls[0][1] == "buffer test: A" and calls[-1][1] == "buffer test: done"


def test_drive_truth_buffer_stops_on_cancel_between_chunks():
    steps = []

    def shares(xy, ranges, step):
        for _ in ranges:
            steps.append(1)
            step(1)
        return [0.5]

    with pytest.raises(CancelledError, match=r"true centrelines was cancelled.*\[truth\]"):
        drive_truth_buffer(_run(), [1.0], shares, "t.shp", is_cancelled=lambda: len(steps) >= 1)
    assert len(steps) == 1
