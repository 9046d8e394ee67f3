"""The ``[truth]`` tests' half before the adjustment computed beforehand
(``files/truth.py::truth_before``, in a forked process during ``adjust``): the same
shares and distances as measuring both halves after the adjustment, and the fallback
whenever the values do not belong to the run's layer."""

from __future__ import annotations

import copy
import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

shapely = pytest.importorskip("shapely")
gpd = pytest.importorskip("geopandas")

from vectoradjust.accuracy.buffer import buffer_test  # noqa: E402
from vectoradjust.files import truth as T  # noqa: E402

CRS = "EPSG:32616"
X0, Y0 = 500000.0, 4400000.0


# ------------------------------------------------------------------ a hand-made database
def _layer(coords, feature, part):
    coords = np.asarray(coords, float)
    return SimpleNamespace(coords=np.column_stack([coords, np.zeros(len(coords))]),
                           vertex_feature=np.asarray(feature), vertex_part=np.asarray(part))


def _case(tmp_path):
    """A truth file, the inputs (``data``) and a run of one database ``A``:

    feature 0 (adjusted), 1 (no adjusted vertex: not compared), 2 (adjusted, a vertex
    without coordinates in the middle), 3 (one vertex without coordinates: not
    adjustable), 4 (two parts, adjusted)."""
    truth = [shapely.LineString([(X0, Y0), (X0 + 100, Y0)]),
             shapely.LineString([(X0, Y0 + 20), (X0 + 60, Y0 + 40), (X0 + 100, Y0 + 20)])]
    path = tmp_path / "truth.gpkg"
    gpd.GeoDataFrame(geometry=truth, crs=CRS).to_file(path)
    xy = np.array([[0, 0.5], [30, 1.5], [60, -2.5], [90, 0.2],          # f0
                   [0, 10.0], [50, 11.0], [100, 10.0],                  # f1
                   [10, 21.0], [40, 30.5], [np.nan, np.nan], [70, 36.0], [95, 22.5],  # f2
                   [np.nan, np.nan],                                    # f3
                   [5, 3.0], [25, 2.0], [60, 19.0], [80, 29.0]])        # f4 (2 parts)
    xy = xy + [X0, Y0]
    feature = [0] * 4 + [1] * 3 + [2] * 5 + [3] + [4] * 4
    part = [0] * 13 + [0, 0, 1, 1]
    layer = _layer(xy, feature, part)
    adjusted = np.array([1, 1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 1])
    move = np.where(np.isnan(xy), np.nan, 0.0) + [0.3, -0.4]
    d = SimpleNamespace(
        name="A", shape=SimpleNamespace(layer=layer, vertex_ids=np.arange(len(xy))),
        vertices={"Adjusted": adjusted}, adjusted_coords=layer.coords + np.c_[move, 0 * xy[:, 0]],
        vertex_point=np.where(adjusted == 1, np.arange(len(xy)), -1))
    data = SimpleNamespace(crs=CRS, vectors=[(SimpleNamespace(name="A"), layer)])
    run = SimpleNamespace(databases=[d], summary={"databases": [{}]}, data=data)
    return str(path), truth, data, run


def _both(run, path, widths, before):
    """The buffer test and the distance table without and with ``before`` (on copies)."""
    plain, pre = copy.deepcopy(run), copy.deepcopy(run)
    pre.data = plain.data = run.data  # the same inputs (the run's layers are copies)
    out = []
    for r, b in ((plain, None), (pre, before)):
        buf = T.truth_buffer(r, path, widths, before=b)
        rows = T.truth_line_distances(r, path, as_columns=True, before=b)
        out.append((buf, rows, r.summary))
    return out


def _assert_same(a, b):
    (buf_a, rows_a, sum_a), (buf_b, rows_b, sum_b) = a, b
    assert buf_a.keys() == buf_b.keys()
    for name in buf_a:
        assert buf_b[name] == buf_a[name]  # bit for bit (per-segment values, one order)
    assert rows_a.keys() == rows_b.keys()
    for k in rows_a:
        assert np.array_equal(rows_a[k], rows_b[k], equal_nan=rows_a[k].dtype != object), k
    assert [e["truth"]["lines"] for e in sum_a["databases"] if "truth" in e] == \
        [e["truth"]["lines"] for e in sum_b["databases"] if "truth" in e]


def test_before_equals_the_present_values_and_independent_geometry(tmp_path):
    path, truth, data, run = _case(tmp_path)
    widths = [1.0, 2.0, 5.0]
    before = T.truth_before(data, path, widths)
    rec = before.databases["A"]
    # segments: f0 3, f1 2, f2 2 (none across the vertex without coordinates), f4 1 + 1
    assert rec.segment_feature.tolist() == [0, 0, 0, 1, 1, 2, 2, 4, 4]
    assert np.isnan(rec.vertex_distance[[9, 12]]).all()
    plain, pre = _both(run, path, widths, before)
    _assert_same(plain, pre)
    # the shares before against shapely: the lines of the features with adjusted vertices
    # (0, 2 and 4; 1 did not move) clipped by fine polygon buffers of the true lines
    xy = run.databases[0].shape.layer.coords[:, :2]
    # feature 0; feature 2 in two pieces (no segment to or from the vertex without
    # coordinates); the two parts of feature 4
    lines = [shapely.LineString(xy[rows]) for rows in ([0, 1, 2, 3], [7, 8], [10, 11],
                                                       [13, 14], [15, 16])]
    ref = [r["share"] for r in buffer_test(lines, truth, widths, quad_segs=256)]
    assert pre[0]["A"]["before"] == pytest.approx(ref, abs=1e-5)
    assert 0 < pre[0]["A"]["before"][0] < pre[0]["A"]["before"][2] < 1
    # the distances before: to the nearest true line (shapely), per object point
    union = shapely.union_all(truth)
    pts = shapely.points(np.column_stack([pre[1]["X"], pre[1]["Y"]]))
    assert pre[1]["D_before"] == pytest.approx(shapely.distance(union, pts), abs=1e-9)


def test_a_changed_layer_other_widths_or_lines_fall_back(tmp_path):
    path, _, data, run = _case(tmp_path)
    widths = [1.0, 2.0]
    moved = copy.deepcopy(data)
    moved.vectors[0][1].coords[1, 1] += 3.0  # one vertex moved after the values were made
    stale = T.truth_before(moved, path, widths)
    d = run.databases[0]
    assert T._matching(stale, d, path, run) is None
    plain, pre = _both(run, path, widths, stale)
    _assert_same(plain, pre)
    # the stale values differ (the check is needed): their shares and distances
    fake = copy.deepcopy(stale)
    fake.databases["A"].digest = T._digest(d.shape.layer.coords[:, :2])
    _, wrong = _both(run, path, widths, fake)
    assert wrong[0]["A"]["before"] != pytest.approx(plain[0]["A"]["before"], rel=1e-6)
    assert not np.array_equal(wrong[1]["D_before"], plain[1]["D_before"])
    # other widths, another truth file, another CRS, another database name: not used
    good = T.truth_before(data, path, widths)
    assert T._before_shares(good, d, widths, path, run) is not None
    assert T._before_shares(good, d, [1.0, 3.0], path, run) is None
    assert T._matching(good, d, path + "x", run) is None
    other = copy.deepcopy(good)
    other.crs = "EPSG:32617"
    assert T._matching(other, d, path, run) is None
    other.crs, other.databases = good.crs, {"B": good.databases["A"]}
    assert T._matching(other, d, path, run) is None
    _assert_same(*_both(run, path, [1.0, 3.0], good))


def test_a_feature_in_two_runs_of_vertices_is_left_to_the_plain_path(tmp_path):
    path, _, data, run = _case(tmp_path)
    layer = data.vectors[0][1]
    layer.vertex_feature = layer.vertex_feature.copy()
    layer.vertex_feature[13:15] = 1  # feature 1 again after feature 3: its runs differ
    run.databases[0].shape.layer = layer
    before = T.truth_before(data, path, [1.0])
    assert "A" not in before.databases
    plain, pre = _both(run, path, [1.0], before)
    _assert_same(plain, pre)


def test_progress_reports_the_before_half_and_only_the_after_half_later(tmp_path):
    path, _, data, run = _case(tmp_path)
    calls = []
    before = T.truth_before(data, path, [1.0], progress=lambda f, m="": calls.append((f, m)))
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and len(calls) >= 4
    steps = []
    T.drive_truth_buffer(run, [1.0], lambda xy, ranges, step: steps.append(len(ranges)) or [0.5],
                         path, before=before)
    assert steps == [4]  # the after half only: features 0, 2 and the two parts of 4


def test_the_lines_that_come_with_the_values_are_not_read_again(tmp_path, monkeypatch):
    import os
    import pickle

    path, _, data, run = _case(tmp_path)
    plain, _ = _both(run, path, [1.0, 2.0], None)
    before = pickle.loads(pickle.dumps(T.truth_before(data, path, [1.0, 2.0])))  # a pipe
    reads = []
    original = T.read_lines
    monkeypatch.setattr(T, "read_lines", lambda *a, **k: reads.append(a) or original(*a, **k))

    def with_before():
        r = copy.deepcopy(run)
        r.data = run.data
        buf = T.truth_buffer(r, path, [1.0, 2.0], before=before)
        return buf, T.truth_line_distances(r, path, as_columns=True, before=before), r.summary

    T._LAST_TRUTH.clear()
    T._LAST_BUFFER.clear()
    _assert_same(plain, with_before())
    assert reads == []  # the lines and their grid came with the values
    # the file changed since: read again (and the values of the layer still used)
    T._LAST_TRUTH.clear()
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert T._matching(before, run.databases[0], path, run) is None  # measured again
    _assert_same(plain, with_before())
    assert len(reads) == 1


# ------------------------------------------------------------------ the sample project
@pytest.fixture(scope="module")
def sample(sample_dir):
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    spec = load_project(sample_dir / "project.toml")
    data = load_project_data(spec)
    return data, run(data), T.project_truth(spec)


def test_sample_project_both_paths_agree(sample):
    data, r, (path, widths) = sample
    before = T.truth_before(data, path, widths)
    assert set(before.databases) == {d.name for d in r.databases}
    plain, pre = _both(r, path, widths, before)
    _assert_same(plain, pre)
    assert all(T._matching(before, d, path, r) is not None for d in r.databases)


# ------------------------------------------------------------------ the command line
def _adjust(sample_dir, out, monkeypatch, workers):
    from vectoradjust.cli.commands import main

    monkeypatch.setenv("VECTORADJUST_WORKERS", workers)
    assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(out), "-q",
                 "--no-bands"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    with open(out / "truth_line_points.csv", newline="", encoding="utf-8") as fh:
        return [d.get("truth") for d in summary["databases"]], list(csv.reader(fh))


def test_adjust_with_the_forked_before_half_writes_the_same_truth(sample_dir, tmp_path,
                                                                  monkeypatch, capfd):
    from vectoradjust.cli import buffer as cli_buffer
    from vectoradjust.runner.background import Background

    got = []
    original = cli_buffer.TruthBeforeAlongside.result

    def result(self, progress=None):
        got.append((self.job.forked, original(self, progress)))
        return got[-1][1]

    monkeypatch.setattr(cli_buffer.TruthBeforeAlongside, "result", result)
    ref = _adjust(sample_dir, tmp_path / "one", monkeypatch, "1")
    assert got[-1] == (False, None)  # one process: both halves after the adjustment
    two = _adjust(sample_dir, tmp_path / "two", monkeypatch, "2")
    forked = Background(lambda progress: 0, enabled=True).forked
    if forked:
        assert got[-1][0] and isinstance(got[-1][1], T.TruthBefore)
    assert ref[0] == two[0]  # summary.json truth entries, bit for bit
    assert ref[1] == two[1]  # truth_line_points.csv row for row

    # a child that fails: the parent measures the before half itself, without a traceback
    def broken(*args, **kwargs):
        raise MemoryError("the child ran out of memory")

    monkeypatch.setattr(T, "truth_before", broken)
    capfd.readouterr()
    three = _adjust(sample_dir, tmp_path / "three", monkeypatch, "2")
    assert got[-1][1] is None
    assert "Traceback" not in capfd.readouterr().err
    assert ref[0] == three[0]
    assert ref[1] == three[1]
