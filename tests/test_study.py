"""The dissertation's experiments (``vectoradjust study``), the per-point truth tables,
reuse of measurements across databases and the per-database RMSE counting each object
point once."""

from __future__ import annotations

import csv
from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.accuracy.study import (
    directional_subset,
    moved_closer_share,
    parse_configuration,
    random_subsets,
    recovered_shift,
    spread_subset,
    truth_point_table,
)
from vectoradjust.errors import NothingAdjustedError, ProjectError
from vectoradjust.files.study import (
    common_points,
    default_numbers,
    gcp_plan,
    gcp_study,
    gcp_summary,
    identification_study,
    shift_data,
    shift_study,
    truth_point_rows,
    with_control,
    write_csv,
)
from vectoradjust.pipeline import run


@pytest.fixture(scope="module")
def sample(sample_dir):
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data

    spec = load_project(sample_dir / "project.toml")
    return spec, load_project_data(spec)


@pytest.fixture(scope="module")
def sample_run(sample):
    return run(sample[1])


# --------------------------------------------------------------------------- selection
def _grid(n=5):
    g = np.arange(n, dtype=float) * 100.0
    return np.array([(x, y) for y in g for x in g])


def test_spread_subset_takes_the_corners_of_a_grid():
    xy = _grid()
    got = {tuple(p) for p in xy[spread_subset(xy, 4)]}
    assert got == {(0.0, 0.0), (400.0, 0.0), (0.0, 400.0), (400.0, 400.0)}
    assert len(set(spread_subset(xy, 25).tolist())) == 25


@pytest.mark.parametrize("name,axis,sign", [("3-North", 1, 1), ("3-South", 1, -1),
                                            ("3-East", 0, 1), ("3-W", 0, -1)])
def test_directional_subset_stays_in_its_part_and_is_not_collinear(name, axis, sign):
    xy = _grid()
    k, part = parse_configuration(name)
    sel = directional_subset(xy, k, part)
    assert len(sel) == k == len(set(sel.tolist()))
    rel = sign * (xy[sel, axis] - xy[:, axis].mean())
    assert np.all(rel > 0)  # all in that half of the block
    a = xy[sel] - xy[sel].mean(axis=0)
    assert np.linalg.svd(a, compute_uv=False)[1] > 1.0  # not on one line


def test_southwest_configuration_is_in_the_southwest_corner():
    xy = _grid()
    sel = directional_subset(xy, 3, "SW")
    assert np.all(xy[sel].sum(axis=1) < xy.sum(axis=1).mean())
    assert parse_configuration("3-southwest") == (3, "SW")
    assert parse_configuration("North") is None and parse_configuration("3-Up") is None


def test_random_subsets_are_reproducible_and_differ():
    a = random_subsets(24, 3, 5, seed=7)
    b = random_subsets(24, 3, 5, seed=7)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert len({tuple(x) for x in a}) > 1
    assert all(len(set(x.tolist())) == 3 and x.max() < 24 for x in a)


def test_default_numbers_halve_down_to_three():
    assert default_numbers(24) == [24, 12, 6, 3]
    assert default_numbers(10) == [10, 5, 3]
    assert default_numbers(3) == [3]


def test_truth_point_table_and_closer_share():
    t = np.zeros((3, 3))
    db = np.array([[3.0, 4.0, 1.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    adj = np.array([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.5, 0.0]])
    tab = truth_point_table(db, adj, t)
    np.testing.assert_allclose(tab["D_before"], [5.0, 1.0, 2.0])
    np.testing.assert_allclose(tab["D_after"], [1.0, 2.0, 0.5])
    assert tab["Closer"].tolist() == [1, 0, 1]
    assert moved_closer_share(tab["D_before"], tab["D_after"]) == pytest.approx(2 / 3)


def test_recovered_shift_is_the_mean_difference():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(50, 3))
    rec = recovered_shift(v, v - [15.0, -7.0, 0.0])
    assert rec["dx"] == pytest.approx(15.0) and rec["dy"] == pytest.approx(-7.0)
    assert rec["sd_x"] == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- GCP study
@pytest.mark.io
def test_held_out_gcps_are_not_in_the_adjustment_and_are_scored_as_check_points(sample):
    _, data = sample
    plan = gcp_plan(data, [], ["3-North"])
    keep = plan[0]["rows"]
    sub = with_control(data, keep)
    res = run(sub)
    ctrl_ids = set(res.point_ids[res.point_kind == "control"].tolist())
    assert ctrl_ids == set(data.control.point_id[keep].tolist())
    held = np.setdiff1d(np.flatnonzero(data.control.role == "control"), keep)
    assert held.size == 21
    cp = res.control_points
    assert set(cp["role"][held]) == {"check"} and np.all(cp["Used"][held] == 1)
    # moving a held-out point's surveyed coordinates does not change the adjustment,
    # only its check-point error (it is not in the adjustment)
    moved = sub.control.xyz.copy()
    moved[held[0]] += [100.0, 0.0, 0.0]
    res2 = run(replace(sub, control=replace(sub.control, xyz=moved)))
    np.testing.assert_allclose(res2.result.eo, res.result.eo, atol=1e-9)
    assert res2.control_points["Vx"][held[0]] == pytest.approx(cp["Vx"][held[0]] - 100.0)
    # the study row scores exactly those points
    row = gcp_study(data, plan)[0]
    dh = np.hypot(cp["Vx"][held], cp["Vy"][held])
    assert row["n_held_out"] == 21
    assert row["held_out_rmse_h"] == pytest.approx(np.sqrt(np.mean(dh ** 2)))
    assert row["n_check"] == 21 + int((data.control.role == "check").sum())
    assert row["control_ids"].split() == data.control.point_id[keep].tolist()


@pytest.mark.io
def test_gcp_sweep_fewer_points_are_less_accurate_on_check_points(sample):
    _, data = sample
    plan = gcp_plan(data)
    assert [p["n"] for p in plan] == [24, 12, 6, 3]
    rows = gcp_study(data, plan)
    assert not any(r["error"] for r in rows)
    assert rows[0]["n_held_out"] == 0 and rows[0]["held_out_rmse_h"] is None
    # all 24: the check RMSE of a normal run
    assert rows[0]["check_rmse_h"] == pytest.approx(run(data).summary["check_points"]
                                                    ["rmse_horizontal"])
    assert rows[-1]["check_rmse_h"] > rows[0]["check_rmse_h"]
    for r in rows:  # roads are still adjusted to well under a metre of the truth
        assert r["OSM_adj_truth"] < 1.0


@pytest.mark.io
def test_random_subsets_summary_has_the_spread(sample):
    _, data = sample
    plan = gcp_plan(data, [], [], [4], repeats=3, seed=2)
    rows = gcp_study(data, plan)
    summ = gcp_summary(rows)
    assert len(summ) == 1 and summ[0]["runs"] == 3
    vals = [r["check_rmse_h"] for r in rows]
    assert summ[0]["check_rmse_h_min"] == pytest.approx(min(vals))
    assert summ[0]["check_rmse_h_max"] == pytest.approx(max(vals))
    assert summ[0]["check_rmse_h_mean"] == pytest.approx(np.mean(vals))


@pytest.mark.io
def test_collinear_configuration_is_reported_not_raised(sample):
    _, data = sample
    ids = data.control.point_id
    xy = data.control.xyz[:, :2]
    # three control points on (nearly) one line: the two farthest apart and their midpoint
    # (moved there: their image measurements no longer fit, and with the roads' heights
    # and the 100 m camera priors fixing the datum the adjustment runs and fails)
    rows = np.flatnonzero(data.control.role == "control")
    plan = [{"label": "line", "group": "configuration", "n": 3, "repeat": 0,
             "rows": rows[:3]}]
    sub = data.control.xyz.copy()
    mid = 0.5 * (xy[rows[0]] + xy[rows[1]])
    sub[rows[2], :2] = mid
    data2 = replace(data, control=replace(data.control, xyz=sub))
    out = gcp_study(data2, plan)
    assert "did not converge" in out[0]["error"] and out[0]["control_ids"].split() == \
        ids[rows[:3]].tolist()


@pytest.mark.io
def test_unknown_configuration_and_too_few_points_are_user_errors(sample):
    _, data = sample
    with pytest.raises(ProjectError, match="3-Up"):
        gcp_plan(data, [], ["3-Up"])
    with pytest.raises(ProjectError, match="at least"):
        gcp_plan(data, [2])
    with pytest.raises(ProjectError, match="NOPE"):
        gcp_plan(data, [], ["mine=GCP01,GCP02,NOPE"])


# --------------------------------------------------------------------------- shift study
@pytest.mark.io
def test_shift_study_recovers_the_shift(sample):
    _, data = sample
    rows, runs = shift_study(data, 15.0, -7.0, ["OSM"])
    r = rows[0]
    assert r["recovered_dx"] == pytest.approx(15.0, abs=0.05)
    assert r["recovered_dy"] == pytest.approx(-7.0, abs=0.05)
    assert r["adjusted_moved_max"] < 0.05  # the images put the road where it is
    # true RMSE of the shifted database, from the truth file directly
    tid, txyz = data.truth["OSM"]
    assert r["true_rmse_shifted"] > 15.0 and r["recovery_shifted"] > 0.95
    assert r["closer_shifted"] > 0.99
    assert r["offset_dx"] == pytest.approx(15.0, abs=3.0)


@pytest.mark.io
def test_shift_study_without_offset_parameters_still_recovers_the_shift(sample):
    _, data = sample
    nooff = replace(data, vectors=[(replace(s, offset="none"), lay) for s, lay in data.vectors])
    rows, _ = shift_study(nooff, 10.0, 10.0, ["TNM"])
    assert rows[0]["recovered_dx"] == pytest.approx(10.0, abs=0.3)
    assert rows[0]["recovered_dy"] == pytest.approx(10.0, abs=0.3)


@pytest.mark.io
def test_shift_data_moves_only_the_named_database(sample):
    _, data = sample
    moved = shift_data(data, 1.0, 2.0, ["TNM"])
    for (s, a), (_, b) in zip(data.vectors, moved.vectors):
        d = b.coords - a.coords
        want = [1.0, 2.0, 0.0] if s.name == "TNM" else [0.0, 0.0, 0.0]
        np.testing.assert_allclose(d, np.broadcast_to(want, d.shape), equal_nan=True)
    with pytest.raises(ProjectError, match="NOPE"):
        shift_data(data, 1.0, 1.0, ["NOPE"])


# --------------------------------------------------------------------------- identification
def test_identification_study_accuracy_follows_the_error():
    rows = identification_study([0.0, 1.0], databases=("TNM",))
    by = {r["identification_error"]: r for r in rows}
    assert by[0.0]["adj_truth_rmse"] < 0.2
    # the adjusted point is the identified one: its horizontal error is about
    # sqrt(2) * sigma (two axes) when the identification error dominates
    assert by[1.0]["adj_truth_rmse"] == pytest.approx(np.sqrt(2.0), rel=0.2)
    assert by[1.0]["moved_closer"] < by[0.0]["moved_closer"]


# --------------------------------------------------------------------------- truth tables, RMSE
@pytest.mark.io
def test_database_rmse_counts_each_object_point_once(sample_run):
    r = sample_run
    for d, e in zip(r.databases, r.summary["databases"]):
        objects = np.unique(d.vertex_point[d.vertex_point >= 0])
        assert e["points"] == e["residuals"]["count"] == len(objects)
        # independently: bundle points of the database minus their database prior
        sel = (r.point_kind == "shape") & (r.point_database == d.name)
        assert int(sel.sum()) == len(objects)
        v = r.result.xyz[objects] - d.shape.object_xyz[d.shape.vertex_object[
            np.array([np.flatnonzero(d.vertex_point == p)[0] for p in objects])]]
        rmse_h = np.sqrt(np.mean(v[:, 0] ** 2) + np.mean(v[:, 1] ** 2))
        assert e["residuals"]["rmse_horizontal"] == pytest.approx(rmse_h, rel=1e-9)
    osm = r.summary["databases"][0]
    assert (osm["adjusted_vertices"], osm["points"]) == (211, 183)


@pytest.mark.io
def test_truth_points_table_matches_the_truth_file(sample_run, sample_dir):
    rows = [x for x in truth_point_rows(sample_run) if x["database"] == "OSM"]
    with open(sample_dir / "truth_osm.csv", encoding="utf-8") as fh:
        truth = {x["point_id"]: x for x in csv.DictReader(fh)}
    e = sample_run.summary["databases"][0]
    assert len(rows) == e["points"]
    for x in rows[:20]:
        t = truth[x["point_id"]]
        assert x["dX_before"] == pytest.approx(x["X"] - float(t["X"]), abs=1e-3)
        assert x["D_after"] == pytest.approx(np.hypot(x["AdjX"] - float(t["X"]),
                                                      x["AdjY"] - float(t["Y"])), abs=1e-3)
    share = np.mean([x["Closer"] for x in rows])
    assert e["truth"]["moved_closer"] == pytest.approx(share)


@pytest.mark.io
def test_truth_line_distances_are_nearest_line_distances(sample_run, sample_dir):
    import shapely

    from vectoradjust.files.truth import read_lines, truth_line_distances

    rows = truth_line_distances(sample_run, sample_dir / "truth_roads.shp")
    lines, _ = read_lines(sample_dir / "truth_roads.shp")
    union = shapely.union_all(lines)
    for x in rows[::97]:
        assert x["D_before"] == pytest.approx(shapely.Point(x["X"], x["Y"]).distance(union),
                                              abs=1e-6)
        assert x["D_after"] == pytest.approx(
            shapely.Point(x["AdjX"], x["AdjY"]).distance(union), abs=1e-6)
    entry = sample_run.summary["databases"][0]["truth"]["lines"]
    osm = [x for x in rows if x["database"] == "OSM"]
    assert entry["count"] == len(osm)
    assert entry["moved_closer"] == pytest.approx(np.mean([x["Closer"] for x in osm]))


# --------------------------------------------------------------------------- reuse
def _copy_of_osm(data):
    """A second database with OSM's geometry, other feature ids and no measurements."""
    spec, layer = next((s, lay) for s, lay in data.vectors if s.name == "OSM")
    twin = replace(layer, name="COPY", feature_ids=np.char.add("X", layer.feature_ids))
    return replace(data, vectors=list(data.vectors) + [(replace(spec, name="COPY"), twin)],
                   truth={})


@pytest.mark.io
def test_reused_measurements_give_the_same_adjusted_points(sample):
    _, data = sample
    data2 = _copy_of_osm(data)
    with pytest.raises(NothingAdjustedError, match=r"^COPY .*none of its shape points is measured"):
        run(data2, vectors=["COPY"])
    data3 = replace(data2, settings=replace(data2.settings, reuse_tolerance=0.01,
                                            reuse_points="all"))
    a = run(data3, vectors=["OSM"])
    b = run(data3, vectors=["COPY"])
    np.testing.assert_allclose(b.databases[0].adjusted_coords, a.databases[0].adjusted_coords,
                               atol=1e-6, equal_nan=True)
    assert any("reuse" in w for w in b.warnings)
    common = common_points([a, b])
    shape = a.point_kind[a.problem.obs_point] == "shape"
    measured = set(a.data.measurements.point_id[a.obs_rows[shape]].tolist())
    assert {c["measured_id"] for c in common} == measured
    assert max(c["adjusted_spread"] for c in common) < 1e-6
    assert all(c["COPY_id"] == "X" + c["OSM_id"] for c in common)


@pytest.mark.io
def test_reuse_needs_the_other_database_out_of_the_run(sample):
    _, data = sample
    data3 = replace(_copy_of_osm(data), settings=replace(data.settings, reuse_tolerance=0.01,
                                                         reuse_points="all"))
    with pytest.raises(NothingAdjustedError, match=r"^COPY .*leave the database out"):
        run(data3, vectors=["OSM", "COPY"])


@pytest.mark.io
def test_reuse_at_intersections_measures_the_true_intersection(sample):
    """TNM without measurements of its own: its intersections reuse OSM's (default
    reuse_points = "intersections") and land where the true intersections are."""
    from vectoradjust.model import Measurements

    _, data = sample
    m = data.measurements
    keep = ~np.char.startswith(m.point_id.astype(str), "TNM-")
    m2 = Measurements(m.point_id[keep], m.image_id[keep], m.xy[keep], m.sigma[keep], m.source,
                      m.rows[keep])
    d = replace(data, measurements=m2, settings=replace(data.settings, reuse_tolerance=8.0))
    res = run(d, vectors=["TNM"])
    db = res.databases[0]
    sp = db.shape
    junction = np.bincount(sp.vertex_object, minlength=sp.n_objects) >= 2
    used = np.unique(db.vertex_point[db.vertex_point >= 0])
    assert used.size >= 5
    objs = np.unique(sp.vertex_object[db.vertex_point >= 0])
    assert junction[objs].all()  # only intersections reused
    rows = truth_point_rows(res)
    d_after = np.array([x["D_after"] for x in rows])
    # the identification error of the sample is 0.5 m per axis: ~0.7 m horizontally
    assert np.sqrt(np.mean(d_after ** 2)) < 1.2
    assert np.sqrt(np.mean([x["D_before"] ** 2 for x in rows])) > 1.5


def test_reuse_keys_are_read_from_the_project(tmp_path, sample_dir):
    from vectoradjust.files.project import load_project

    text = (sample_dir / "project.toml").read_text(encoding="utf-8")
    text = text.replace("max_iterations = 20", "max_iterations = 20\nreuse_tolerance = 2.5\n"
                        "reuse_points = \"all\"")
    p = sample_dir / "project.toml"
    spec = load_project(_write(tmp_path, p, text))
    assert spec.settings.reuse_tolerance == 2.5 and spec.settings.reuse_points == "all"
    with pytest.raises(ProjectError, match="reuse_points"):
        load_project(_write(tmp_path, p, text.replace('"all"', '"some"')))


def _write(tmp_path, project, text):
    import shutil

    d = tmp_path / "prj"
    if not d.exists():
        shutil.copytree(project.parent, d)
    (d / "project.toml").write_text(text, encoding="utf-8")
    return d / "project.toml"


# --------------------------------------------------------------------------- CLI
@pytest.mark.io
def test_study_commands_write_tables_figures_and_report(sample_dir, tmp_path):
    from vectoradjust.cli.commands import main

    assert main(["study", "gcp", str(sample_dir / "project.toml"), "--out",
                 str(tmp_path / "g"), "-q", "--numbers", "24,3", "--config", "3-SW"]) == 0
    for f in ("gcp_study.csv", "gcp_summary.csv", "gcp_map.png", "gcp_rmse.png",
              "report.html"):
        assert (tmp_path / "g" / f).stat().st_size > 0
    with open(tmp_path / "g" / "gcp_study.csv", encoding="utf-8") as fh:
        assert [r["label"] for r in csv.DictReader(fh)] == ["24 spread", "3 spread", "3-SW"]
    assert main(["study", "shift", str(sample_dir / "project.toml"), "--out",
                 str(tmp_path / "s"), "-q", "--vectors", "OSM"]) == 0
    with open(tmp_path / "s" / "shift_study.csv", encoding="utf-8") as fh:
        row = next(csv.DictReader(fh))
    assert float(row["recovered_dx"]) == pytest.approx(15.0, abs=0.05)
    assert float(row["in_1m_after_shifted"]) > float(row["in_1m_before_shifted"])
    assert (tmp_path / "s" / "OSM_shifted" / "truth_points.csv").is_file()
    assert main(["study", "gcp", str(sample_dir / "project.toml"), "--out",
                 str(tmp_path / "x"), "-q", "--numbers", "2"]) == 1
    assert main(["study", "identification", "--out", str(tmp_path / "i"), "-q",
                 "--errors", "0,1", "--databases", "TNM"]) == 0
    with open(tmp_path / "i" / "identification_study.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["identification_error"]) for r in rows] == [0.0, 1.0]
    assert (tmp_path / "i" / "identification.png").stat().st_size > 0
    assert main(["study", "identification", "--out", str(tmp_path / "j"), "-q",
                 "--errors", "a,b"]) == 1


@pytest.mark.io
def test_study_reports_progress_and_honours_cancel(sample):
    from vectoradjust.errors import CancelledError

    _, data = sample
    plan = gcp_plan(data, [24, 3])
    seen = []
    gcp_study(data, plan, progress=lambda f, msg="": seen.append((f, msg)))
    assert seen[-1][0] == 1.0 and any("3 spread" in m for _, m in seen)
    assert all(0.0 <= f <= 1.0 for f, _ in seen)
    calls = []

    def cancel_after_first_run():
        calls.append(1)
        return len(calls) > 3

    with pytest.raises(CancelledError, match="The adjustment was cancelled"):
        gcp_study(data, plan, is_cancelled=cancel_after_first_run)
    with pytest.raises(CancelledError, match="The study was cancelled"):
        shift_study(data, 1.0, 1.0, ["OSM"], is_cancelled=lambda: True)


@pytest.mark.io
def test_csv_from_columns_equals_csv_from_rows(tmp_path):
    from vectoradjust.files.study import rows_from_columns

    cols = {"database": np.array(["OSM", "OSM", "TNM"], dtype=object),
            "point_id": np.array(["a", 'b,"x"', "c"], dtype=object),
            "X": np.array([1.25, 506301.123456789, -3e-7]), "Closer": np.array([1, 0, 1]),
            "D": np.array([0.1, np.nan, 2.0])}
    rows = rows_from_columns(cols)
    assert rows[1] == {"database": "OSM", "point_id": 'b,"x"', "X": 506301.123456789,
                       "Closer": 0, "D": rows[1]["D"]} and np.isnan(rows[1]["D"])
    write_csv(cols, tmp_path / "c.csv")
    rows[1]["D"] = None  # the row writer's empty cell
    write_csv(rows, tmp_path / "r.csv")
    with open(tmp_path / "c.csv", newline="", encoding="utf-8") as fa, \
            open(tmp_path / "r.csv", newline="", encoding="utf-8") as fb:
        a, b = list(csv.reader(fa)), list(csv.reader(fb))
    assert len(a) == len(b) == 4 and a[0] == b[0] == list(cols) and a[2][4] == b[2][4] == ""
    for ra, rb in zip(a[1:], b[1:]):  # floats: 15 significant digits against repr
        assert ra[:2] == rb[:2] and ra[3] == rb[3]
        fa, fb = ([float(x) if x else np.nan for x in r[2:3] + r[4:]] for r in (ra, rb))
        np.testing.assert_allclose(fa, fb, rtol=1e-15)
    assert float(a[2][2]) == 506301.123456789


def test_column_writer_chunks_write_the_same_file(tmp_path, monkeypatch):
    import vectoradjust.files.study as st

    cols = {"id": np.array([f"p{i}" for i in range(23)], dtype=object),
            "x": np.linspace(-1.5, 2e6, 23), "n": np.arange(23)}
    write_csv(cols, tmp_path / "one.csv")
    monkeypatch.setattr(st, "_CSV_CHUNK", 5)
    write_csv(cols, tmp_path / "chunks.csv")
    one = (tmp_path / "one.csv").read_bytes()
    assert one == (tmp_path / "chunks.csv").read_bytes() and one.count(b"\r\n") == 24


@pytest.mark.io
def test_arrow_csv_writer_reads_back_as_the_plain_writer(tmp_path, monkeypatch):
    """The pyarrow path of write_csv against the plain (Python) one: same header, text,
    empty cells and integers; floats read back exactly (shortest round-trip text)."""
    pytest.importorskip("pyarrow")
    import vectoradjust.files.study as st

    rng = np.random.default_rng(3)
    x = rng.normal(5e5, 1e3, 200)
    x[::13] = np.nan
    cols = {"database": np.array(["OSM"] * 100 + ["TNM"] * 100, dtype=object),
            "point_id": np.array([f"p{i}" for i in range(200)], dtype=object),
            "X": x, "n": np.arange(200), "maybe": np.array([None, 1.5] * 100, dtype=object)}
    calls = []
    write_csv(cols, tmp_path / "arrow.csv", progress=calls.append)
    monkeypatch.setattr(st, "_arrow_csv", lambda *a: False)
    write_csv(cols, tmp_path / "plain.csv")
    with open(tmp_path / "arrow.csv", newline="") as fa, open(tmp_path / "plain.csv",
                                                              newline="") as fb:
        a, b = list(csv.reader(fa)), list(csv.reader(fb))
    assert calls and calls[-1] == 1.0
    assert len(a) == len(b) == 201 and a[0] == b[0] == list(cols)
    assert b"\r\n" in (tmp_path / "arrow.csv").read_bytes()[:40]
    assert [r[:2] + r[3:4] for r in a] == [r[:2] + r[3:4] for r in b]
    assert [r[4] for r in a] == [r[4] for r in b]  # None -> empty, 1.5 -> "1.5"
    back = np.array([float(r[2]) if r[2] else np.nan for r in a[1:]])
    np.testing.assert_array_equal(back, x)  # exact: no digit lost
    assert '"' not in (tmp_path / "arrow.csv").read_text()  # nothing needed quoting


@pytest.mark.io
def test_arrow_csv_writer_quotes_text_that_needs_it_and_falls_back(tmp_path):
    pytest.importorskip("pyarrow")
    import vectoradjust.files.study as st

    cols = {"id": np.array(['a,b', 'say "x"', "plain"], dtype=object), "v": np.ones(3)}
    write_csv(cols, tmp_path / "q.csv")
    with open(tmp_path / "q.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows == [["id", "v"], ["a,b", "1"], ['say "x"', "1"], ["plain", "1"]]
    # numpy text and booleans: as the plain writer writes them
    flags = {"u": np.array(["p1", "p22", "p3"]), "b": np.array([True, False, True])}
    assert st._arrow_csv(flags, tmp_path / "f.csv", None)
    assert (tmp_path / "f.csv").read_text().splitlines() == ["u,b", "p1,True", "p22,False",
                                                             "p3,True"]
    # text and numbers in one column: the plain writer, same cells
    mixed = {"m": np.array(["x", 2.5, None], dtype=object), "n": np.array([1, 2, 3])}
    assert not st._arrow_csv(mixed, tmp_path / "no.csv", None)
    write_csv(mixed, tmp_path / "m.csv")
    assert (tmp_path / "m.csv").read_text().splitlines() == ["m,n", "x,1", "2.5,2", ",3"]
