"""Smart conflation (issue 34): matching, choice, chaining, files, and the sample.

The unit tests build feature sets from coordinates; the ``io`` tests adjust the sample
project once (OSM, TNM and TIGER; module fixture) and conflate its output folder, and
measure the conflated layer's true RMSE (each vertex's distance to the nearest true
centreline of ``resources/sample/truth_roads.shp``) against each database's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vectoradjust.conflation.smart import (
    FeatureSet,
    choose,
    default_max_distance,
    line_distances,
    match_features,
    normalise_name,
    pair_geometry,
    sample_line,
    smart_conflate,
    summarise,
)

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"


def _fs(name, lines, ce, rmse=None, names=None):
    n = len(lines)
    rmse = np.ones(n) if rmse is None else rmse
    return FeatureSet(name, [np.asarray(x, float) for x in lines], np.asarray(ce, float),
                      np.asarray(ce, float) / 2, np.asarray(rmse, float),
                      None if names is None else np.array([normalise_name(v) for v in names],
                                                          object))


def _grid(shift=(0.0, 0.0)):
    """Four 100 m lines: two horizontal 50 m apart, two vertical."""
    dx, dy = shift
    return [[(0 + dx, 0 + dy), (100 + dx, 0 + dy)], [(0 + dx, 50 + dy), (100 + dx, 50 + dy)],
            [(200 + dx, 0 + dy), (200 + dx, 100 + dy)], [(300 + dx, 0 + dy),
                                                           (300 + dx, 100 + dy)]]


# ----------------------------------------------------------------------- geometry
def test_normalise_name_abbreviates():
    assert normalise_name("First Street") == normalise_name("first st.") == "first st"
    assert normalise_name("Oak Avenue") == normalise_name("OAK AVE") == "oak ave"
    assert normalise_name(None) is None and normalise_name(float("nan")) is None
    assert normalise_name(" - ") is None


def test_line_distances_and_samples():
    line = np.array([(0.0, 0.0), (10.0, 0.0), (np.nan, np.nan), (20.0, 0.0), (20.0, 10.0)])
    d = line_distances(np.array([(5.0, 3.0), (-4.0, 3.0), (15.0, 0.0), (21.0, 5.0)]), line)
    assert np.allclose(d, [3.0, 5.0, 5.0, 1.0])  # no segment across the NaN row
    s = sample_line(line, 2.0)
    assert len(s) == 5 + 1 + 5 + 1 - 1 and np.allclose(line_distances(s, line), 0.0)
    assert np.isinf(line_distances(np.zeros((1, 2)), np.empty((0, 2))))[0]


def test_pair_geometry_parallel_and_half_overlap():
    a = np.array([(0.0, 0.0), (100.0, 0.0)])
    b = a + (0.0, 2.0)
    mean, haus, overlap, near = pair_geometry(sample_line(a, 1), a, sample_line(b, 1), b, 5.0)
    assert mean == pytest.approx(2.0) and haus == pytest.approx(2.0)
    assert overlap == 1.0 and near == pytest.approx(2.0)
    c = np.array([(50.0, 1.0), (150.0, 1.0)])  # half along a
    _, haus, overlap, _ = pair_geometry(sample_line(a, 1), a, sample_line(c, 1), c, 5.0)
    # x 45..100 of a is within 5 m of c (and c's x 50..105 of a): 56 of 101 samples
    assert overlap == pytest.approx(55 / 101) and haus == pytest.approx(np.hypot(50, 1))


def test_default_max_distance_is_two_ce90_with_a_floor():
    assert np.allclose(default_max_distance([1.0, 4.0, np.nan], [0.5, 2.0, np.nan]),
                       [5.0, 8.0, 5.0])
    assert np.allclose(default_max_distance([4.0], [2.0], factor=3.0, floor=1.0), [12.0])


# ----------------------------------------------------------------------- matching
def test_match_features_one_to_one_by_geometry():
    a = _fs("A", _grid(), [1, 1, 1, 1])
    b = _fs("B", _grid((1.0, -1.0))[::-1] + [[(900, 900), (950, 900)]], [2, 2, 2, 2, 2])
    m = match_features(a, b)
    assert sorted(zip(m.a.tolist(), m.b.tolist())) == [(0, 3), (1, 2), (2, 1), (3, 0)]
    assert np.all(m.overlap == 1.0) and np.allclose(m.mean_distance, 1.0, atol=0.02)
    # overlap 1 x (1 - 1.01 / 5 m) x ends sqrt(2) m apart (1 - 0.5 x 1.41 / 5)
    assert np.allclose(m.score, 0.8 * (1 - 0.5 * np.sqrt(2) / 5), atol=0.005)
    # within 0.5 m nothing overlaps: no match
    assert len(match_features(a, b, max_distance=0.5).a) == 0


def test_hungarian_beats_greedy():
    """Two close parallel lines in both sets: the greedy best pair (a0-b1) would leave a1
    without a partner; the assignment matches both with the larger total score."""
    a = _fs("A", [[(0, 0), (100, 0)], [(0, 3), (100, 3)]], [2, 2])
    b = _fs("B", [[(0, -2.0), (100, -2.0)], [(0, 1.0), (100, 1.0)]], [2, 2])
    m = match_features(a, b, max_distance=6.0)
    assert sorted(zip(m.a.tolist(), m.b.tolist())) == [(0, 0), (1, 1)]


def test_names_are_a_bonus_never_required():
    lines = [[(0, 0), (100, 0)], [(0, 2), (100, 2)]]
    a = _fs("A", [[(0, 1), (100, 1)]], [2], names=["Oak Avenue"])
    b = _fs("B", lines, [2, 2], names=["Elm St", "Oak Ave"])  # equally far: the name decides
    m = match_features(a, b)
    assert m.b.tolist() == [1] and m.score[0] == pytest.approx(
        1.0 * (1 - 1 / 5) * (1 - 0.5 / 5) + 0.1)  # overlap, 1 m apart, ends 1 m apart
    b2 = _fs("B", lines, [2, 2], names=["Elm St", None])
    assert len(match_features(a, b2).a) == 1  # no name: still matched


def test_min_overlap_rejects_partial_matches():
    a = _fs("A", [[(0, 0), (100, 0)]], [1])
    b = _fs("B", [[(70, 0.5), (170, 0.5)]], [1])
    assert len(match_features(a, b, min_overlap=0.5).a) == 0
    assert len(match_features(a, b, min_overlap=0.2).a) == 1


# ----------------------------------------------------------------------- choice
def test_choose_ce90_then_rmse():
    w = choose([1.0, 1.0, 1.000001, np.nan, 2.0, 1.0], [5.0, 1.0, 3.0, 1.0, 1.0, np.nan],
               [2.0, 1.0, 1.0, 1.0, 2.0, 1.0], [1.0, 5.0, 2.0, 9.0, 1.0, 2.0])
    # smaller CE90; CE90 tie -> smaller RMSE; unknown loses to known; all equal -> first
    assert w.tolist() == [True, True, False, False, True, False]
    # by RMSE: the displacement decides, CE90 breaks ties
    assert choose([1.0, 1.0], [5.0, 2.0], [2.0, 2.0], [1.0, 2.0], by="rmse").tolist() == [
        False, True]
    with pytest.raises(ValueError, match="'ce90' or 'rmse'"):
        choose([1.0], [1.0], [1.0], [1.0], by="le90")


def test_smart_conflate_chains_three_and_carries_unmatched():
    a = _fs("A", _grid() + [[(0, 500), (100, 500)]], [1, 5, 1, 5, 1])
    b = _fs("B", _grid((0.5, 0.5)), [2, 2, 2, 2])
    c = _fs("C", _grid((-0.5, 0.0))[:2] + [[(0, 900), (100, 900)]], [0.5, 9, 1])
    r, steps = smart_conflate([a, b, c])
    assert [len(m.a) for m in steps] == [4, 2]
    names = [r.sets[s].name for s in r.source]
    # grid 0: A 1 vs B 2 vs C 0.5 -> C; grid 1: A 5, B 2, C 9 -> B; 2: A; 3: B;
    # A's line at y = 500 and C's at y = 900 unmatched
    assert names == ["C", "B", "A", "B", "A", "C"]
    assert r.loser_names() == ["A,B", "A,C", "B", "A", "", ""]
    assert np.isnan(r.score[4:]).all() and np.isfinite(r.score[:4]).all()
    assert np.allclose(r.loser_offset[[2, 3]], 0.5, atol=0.01)  # B and A 0.5 m apart
    assert np.allclose(r.column("ce90"), [0.5, 2, 1, 2, 1, 1])
    assert np.allclose(r.loser_values("ce90")[:4], [1, 5, 2, 5])
    s = summarise(r)
    assert s["databases"]["A"] == {"features": 5, "matched": 4, "unmatched": 1, "wins": 1,
                                   "rows": 2, "mean_ce90": 1.0, "mean_ce90_input": 2.6}
    assert s["databases"]["C"]["wins"] == 1 and s["databases"]["C"]["unmatched"] == 1
    assert s["features"] == 6 and s["matched"] == 4 and s["unmatched"] == 2
    with pytest.raises(ValueError, match="at least two"):
        smart_conflate([a])


# ----------------------------------------------------------------------- the sample
def _true_rmse(geoms, truth) -> tuple:
    """RMS of each vertex's distance to the nearest true centreline (as [truth])."""
    import shapely

    xy = shapely.get_coordinates(np.asarray(geoms))
    d = shapely.distance(shapely.points(xy), truth)
    return float(np.sqrt(np.mean(d ** 2))), len(xy)


@pytest.fixture(scope="module")
def sample_out(tmp_path_factory):
    pytest.importorskip("geopandas")
    from vectoradjust.cli import main

    out = tmp_path_factory.mktemp("smart") / "adjusted"
    assert main(["adjust", str(SAMPLE / "project.toml"), "-o", str(out), "--no-bands",
                 "-q"]) == 0
    return out


@pytest.mark.io
def test_sample_conflated_beats_the_best_database(sample_out, tmp_path):
    import geopandas as gpd
    import shapely

    from vectoradjust.files.smart_outputs import (
        conflated_frame,
        feature_sets,
        read_sources,
        write_smart,
    )

    sources = read_sources([sample_out])
    assert [n for n, _ in sources] == ["OSM", "TNM", "TIGER"]
    r, steps = smart_conflate(feature_sets(sources))
    frame = conflated_frame(sources, r)
    truth = shapely.union_all(gpd.read_file(SAMPLE / "truth_roads.shp").geometry.values)
    single = {n: _true_rmse(f.geometry.values, truth)[0] for n, f in sources}
    conflated = _true_rmse(frame.geometry.values, truth)[0]
    print("true RMSE:", single, "conflated", conflated)
    # measured: OSM 0.931, TNM 0.782, TIGER 1.159; conflated 0.779 m
    assert conflated < min(single.values())
    # per-feature choice: every sample road is in all three databases
    assert [len(m.a) for m in steps] == [26, 26] and len(frame) == 26
    assert (frame["NSources"] == 3).all() and frame["MatchScore"].between(0.5, 1.0).all()
    # where the CE90s differ (the curves with extrapolated vertices) the smaller one won
    differ = frame["LoserCE90"] > 1.01 * frame["CE90"]
    assert differ.sum() == 2 and (frame.loc[differ, "Source"] == "TNM").all()
    assert (frame["CE90"] <= 1.01 * frame["LoserCE90"]).all()
    tie = ~differ
    assert (frame.loc[tie, "RMSE"] <= frame.loc[tie, "LoserRMSE"]).all()
    assert frame["LoserOffset"].between(0.0, 2.0).all()
    paths = write_smart(frame, summarise(r), tmp_path)
    back = gpd.read_file(paths["gpkg"], layer="conflated")
    assert back["tlid"].dtype.kind == "f" and back["permanent_"].dtype.kind in "OU"
    assert back["Source"].tolist() == frame["Source"].tolist()


@pytest.mark.io
def test_sources_errors(sample_out, tmp_path):
    import geopandas as gpd

    from vectoradjust.errors import CRSError, InputFileError, LayerError, ProjectError
    from vectoradjust.files.smart_outputs import read_sources

    with pytest.raises(InputFileError, match="no adjusted.gpkg"):
        read_sources([tmp_path])
    with pytest.raises(InputFileError, match="not found"):
        read_sources([tmp_path / "nothing.gpkg"])
    with pytest.raises(ProjectError, match="two or more databases.*hold 1 .OSM"):
        read_sources([sample_out], databases=["OSM"])
    with pytest.raises(ProjectError, match="--databases CITY: not in the sources"):
        read_sources([sample_out], databases=["OSM", "CITY"])
    f = gpd.read_file(sample_out / "adjusted.gpkg", layer="features")
    f.drop(columns="CE90").to_file(tmp_path / "no_ce90.gpkg", layer="features")
    with pytest.raises(LayerError, match="no_ce90.gpkg: no CE90 column"):
        read_sources([tmp_path / "no_ce90.gpkg", sample_out])
    f.to_crs("EPSG:4326").to_file(tmp_path / "deg.gpkg", layer="features")
    with pytest.raises(CRSError, match="deg.gpkg: the CRS EPSG:4326 is geographic"):
        read_sources([tmp_path / "deg.gpkg"])
    # a vector file and a folder: names made unique, the file's CRS as the folder's
    tnm = f[f["Database"] == "TNM"].drop(columns="Database")
    tnm.to_file(tmp_path / "tnm_again.gpkg", layer="roads")
    both = read_sources([sample_out, tmp_path / "tnm_again.gpkg"], databases=["tnm_again",
                                                                             "OSM"])
    assert [n for n, _ in both] == ["tnm_again", "OSM"]
