"""Bands, lengths and per-feature statements from the covariance of the vertices' CE90
(issue 30): the identification error, the offsets and the conflation included, every
feature with a band and a LengthSD; the features layer's CE90/LE90, geometry types and
integer ids. The fast tier of validation/bands_lengths.py (seed 1 of both scenarios).
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "validation"))

from vectoradjust.accuracy import derived  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402

bands_lengths = pytest.importorskip("bands_lengths")
pytest.importorskip("shapely")


@pytest.fixture(scope="module")
def roads():
    if not bands_lengths.ROADS.is_file():
        pytest.skip(f"true roads not found: {bands_lengths.ROADS}")
    return bands_lengths.read_road_lines(bands_lengths.ROADS)


@pytest.fixture(scope="module")
def conflated(roads):
    data = bands_lengths.scenario_data("conflation", 1, roads)
    return data, run(data)


@pytest.fixture(scope="module")
def real_roads(roads):
    data = bands_lengths.scenario_data("real-roads", 1, roads)
    return data, run(data)


def test_bands_and_length_sd_cover_the_truth(conflated, real_roads):
    rows = [{"seed": 1, "scenario": name, **bands_lengths.measure_run(*pair)}
            for name, pair in (("conflation", conflated), ("real-roads", real_roads))]
    crit = bands_lengths.criteria(rows)
    assert crit.passed, "\n".join(c.line() for c in crit.items)
    conf = rows[0]
    # the conflated scenario has both kinds of vertex, every feature a band and a LengthSD
    assert conf["band_measured"][1] > 200 and conf["band_conflated"][1] > 500
    assert conf["no_band"] == conf["no_length"] == 0
    assert conf["length"][1] == conf["features"]


def test_without_the_identification_error_the_bands_were_far_too_narrow(conflated):
    """The measured segments' band of the adjusted points alone (what the bands were
    before): the true road inside at well under half of the vertices."""
    data, out = conflated
    d = out.databases[0]
    bare = replace(d, spec=replace(d.spec, identification_sigma=None))
    sb = derived.segment_bands(out, bare, 0.9, segments="measured")
    with_id = derived.segment_bands(out, d, 0.9, segments="measured")
    from vectoradjust.adjust.shapepoints import lookup

    tid, txyz = data.truth[d.name]
    ti = lookup(tid, d.shape.vertex_ids)
    ends = np.zeros(len(ti), bool)  # vertices of the measured segments
    ends[with_id.start_vertex] = ends[with_id.start_vertex + 1] = True
    vidx = np.flatnonzero((ti >= 0) & ends)
    true_xy = np.asarray(txyz, float)[ti[vidx], :2]
    narrow = bands_lengths._band_inside(out, d, sb, vidx, true_xy).mean()
    honest = bands_lengths._band_inside(out, d, with_id, vidx, true_xy).mean()
    assert narrow < 0.5 < 0.85 <= honest


def test_conflated_segments_get_bands_of_their_vertices_covariance(conflated):
    _, out = conflated
    d = out.databases[0]
    sb = derived.segment_bands(out, d, 0.9)
    meas = np.asarray(d.vertex_point) >= 0
    other = ~(meas[sb.start_vertex] & meas[sb.start_vertex + 1])
    assert other.sum() > 100 and (~other).sum() > 50
    n_meas, n_other = derived.band_segment_counts(out, d)
    assert (n_meas, n_other) == ((~other).sum(), other.sum())
    # each end's block is its vertex covariance (CE90-consistent), fully correlated ends
    vc = derived.vertex_covariance(d)
    i = np.flatnonzero(other)[0]
    a = sb.start_vertex[i]
    assert np.allclose(sb.cov_joint[i, :3, :3], vc[a]) and np.allclose(sb.cov_joint[i, 3:, 3:],
                                                                        vc[a + 1])
    sa, sb_ = np.sqrt(np.diag(vc[a])), np.sqrt(np.diag(vc[a + 1]))
    assert np.allclose(np.diag(sb.cov_joint[i, :3, 3:]), sa * sb_)
    # the vertex covariance reproduces the vertex's CE90
    from vectoradjust.accuracy import stats

    u = np.flatnonzero(~meas)[:50]
    assert np.allclose(stats.ce90(vc[u, :2, :2]), np.asarray(d.vertices["CE90"])[u],
                       rtol=1e-6)


def test_segment_lengthening_against_monte_carlo():
    rng = np.random.default_rng(3)
    length, sig = 4.0, 0.8
    d = np.array([length, 0.0])
    cov = np.diag([sig ** 2, 2.0 * sig ** 2])  # relative covariance, more across
    e = rng.multivariate_normal(np.zeros(2), cov, size=400_000)
    mc = np.mean(np.hypot(*(d + e).T)) - length
    got = derived.segment_lengthening(cov[None], np.array([[1.0, 0.0]]), np.array([length]))
    assert got[0] == pytest.approx(2.0 * sig ** 2 / (2.0 * length))
    assert got[0] == pytest.approx(mc, rel=0.1)
    # a segment as short as its error: capped at the error's own size
    tiny = derived.segment_lengthening(cov[None], np.array([[1.0, 0.0]]), np.array([1e-3]))
    assert tiny[0] == pytest.approx(np.sqrt(2.0) * sig)


def test_length_sd_is_the_rms_of_the_length_error(real_roads):
    """LengthSD = sqrt(sd^2 + lengthening^2): the length of a line through erring
    vertices is too long on average; the true errors' mean is that lengthening."""
    data, out = real_roads
    d = out.databases[0]
    sd_lin, _ = derived.feature_length_sigma(out, d, lengthening=False)
    sd, _ = derived.feature_length_sigma(out, d)
    bias = d.__dict__["_length_bias"][0]
    ok = np.isfinite(sd)
    assert np.allclose(sd[ok], np.sqrt(sd_lin[ok] ** 2 + bias[ok] ** 2))
    from vectoradjust.adjust.shapepoints import lookup

    tid, txyz = data.truth[d.name]
    ti = lookup(tid, d.shape.vertex_ids)
    tru = np.asarray(txyz, float)[ti]
    layer = d.shape.layer
    err = bands_lengths._lengths(layer, d.adjusted_coords) - bands_lengths._lengths(layer, tru)
    # the mean error is the predicted lengthening (not zero), to a fifth of the spread
    assert np.mean(err) > 0.2
    assert abs(np.mean(err) - np.mean(bias)) < 0.2 * np.std(err)


def test_features_get_ce90_le90_and_every_conflated_feature_a_length_sd(conflated):
    _, out = conflated
    d = out.databases[0]
    layer = d.shape.layer
    before = np.isfinite(derived.feature_length_sigma(out, d)[0]).sum()  # measured only
    derived.feature_accuracy(out, d)
    sd = np.asarray(d.features["LengthSD"], float)
    once = sd.copy()
    derived.feature_accuracy(out, d)  # a second call adds nothing
    assert np.array_equal(once, np.asarray(d.features["LengthSD"], float), equal_nan=True)
    nadj = np.asarray(d.features["NAdj"])
    assert before == (nadj > 0).sum() < layer.n_features == np.isfinite(sd).sum()
    assert set(d.features["LengthSDOf"]) == {"all vertices"}
    ce = np.asarray(d.vertices["CE90"], float)
    f = int(np.argmax(np.bincount(layer.vertex_feature)))
    assert d.features["CE90"][f] == pytest.approx(np.nanmax(ce[layer.vertex_feature == f]))
    assert np.all(np.isfinite(d.features["CE90"])) and np.all(np.isfinite(d.features["LE90"]))


def test_distance_between_shape_points_includes_the_identification_error(conflated):
    _, out = conflated
    d = out.databases[0]
    ids = d.shape.vertex_ids[np.asarray(d.vertex_point) >= 0][:2]
    r = derived.distance_between(out, ids[0], ids[1])
    bare = replace(out, databases=[replace(d, spec=replace(d.spec,
                                                           identification_sigma=None))])
    r0 = derived.distance_between(bare, ids[0], ids[1])
    ident = d.spec.identification_sigma[0]
    assert r.sigma_no_cov == pytest.approx(np.sqrt(r0.sigma_no_cov ** 2 + 2 * ident ** 2))
    assert r.sigma > 0.3 > r0.sigma


@pytest.mark.io
def test_features_layer_keeps_geometry_types_int64_ids_and_flags_missing_heights(
        roads, tmp_path):
    pytest.importorskip("geopandas")
    import pyogrio

    from vectoradjust.files.outputs import _write_layer, features_frame

    data = bands_lengths.scenario_data("conflation", 2, roads)
    spec, layer = data.vectors[0]
    big = [2 ** 60 + 7 * i for i in range(layer.n_features)]  # beyond 2^53
    coords = layer.coords.copy()
    coords[layer.vertex_feature == 3, 2] = np.nan  # no height (outside the DEM)
    layer = replace(layer, attributes={**layer.attributes, "big_id": big}, coords=coords,
                    geometry_type="LineString")
    out = run(replace(data, vectors=[(spec, layer)]))
    frame = features_frame(out)
    assert set(frame.geom_type.dropna()) == {"LineString"}
    assert np.isfinite(frame["CE90"]).all() and np.isfinite(frame["LE90"]).all()
    _write_layer(frame, tmp_path / "f.gpkg", "features", "gpkg")
    info = pyogrio.read_info(tmp_path / "f.gpkg", layer="features")
    assert info["geometry_type"] == "LineString Z"
    back = pyogrio.read_dataframe(tmp_path / "f.gpkg", layer="features")
    assert back["big_id"].dtype == np.int64 and back["big_id"].tolist() == big
    d = out.databases[0]
    noz = ~np.isfinite(d.adjusted_coords[:, 2])
    flagged = np.unique(layer.vertex_feature[noz])
    assert 3 in flagged
    assert all("without height" in back["Problem"][f] for f in flagged)
    # a layer of MultiLineStrings stays one, one part too
    d.shape.layer.geometry_type = "MultiLineString"
    assert set(features_frame(out).geom_type.dropna()) == {"MultiLineString"}


def test_bands_built_before_the_conflation_are_completed_when_merged(conflated, tmp_path,
                                                                     monkeypatch):
    """The command line's band processes start before the conflation (measured segments
    only); the merge adds the conflated segments' bands: the same layer as built whole."""
    pytest.importorskip("geopandas")
    import shapely

    from vectoradjust.files import derived_outputs as do

    _, out = conflated
    whole = do.uncertainty_bands_frame(out)
    n_meas, n_other = derived.band_segment_counts(out, out.databases[0])
    assert whole["NSeg"].sum() == n_meas + n_other and n_other > 0
    parts = [do.uncertainty_bands_frame(out, part=(i, 2), segments="measured")
             for i in range(2)]
    assert sum(p["NSeg"].sum() for p in parts) == n_meas
    merged = do.merge_band_parts(out, parts)
    assert list(merged["feature_id"]) == list(whole["feature_id"])
    assert (merged["NSeg"].to_numpy() == whole["NSeg"].to_numpy()).all()
    assert shapely.equals_exact(merged.geometry.values, whole.geometry.values, 0.0).all()
    if do.arrow_layers():  # the files of the band processes, mapped by the parent
        import pyarrow as pa

        paths = [do.uncertainty_bands_file(out, tmp_path, part=(i, 2), segments="measured")
                 for i in range(2)]
        for batch in (do.BAND_BATCH, 7):  # a feature's two rows never split by a batch
            monkeypatch.setattr(do, "BAND_BATCH", batch)
            layer = do.merge_band_files(out, paths)
            table = pa.Table.from_batches(list(layer.batches()))
            assert len(layer) == table.num_rows == len(whole)
            assert table.column("NSeg").to_pylist() == whole["NSeg"].tolist()
            geo = shapely.from_wkb(np.asarray(table.column("geometry").to_pylist(), object))
            assert shapely.equals_exact(geo, whole.geometry.values, 0.0).all()


def test_end_scale_holds_the_true_end_vertex_at_the_confidence():
    """At a free end the band is the half-strip of 1.645 sigma across plus the end's
    ellipse at end_scale: together they hold a circular normal error at 90 % (the cap of
    1.645 sigma held 82 %, the 2-D ellipse of 2.146 sigma 92 %)."""
    k, a = derived.end_scale(0.9), derived.band_scale(0.9)
    assert k == pytest.approx(2.0109, abs=1e-4)
    assert a < k < np.sqrt(-2.0 * np.log(0.1))
    rng = np.random.default_rng(5)
    e = rng.standard_normal((1_000_000, 2))  # along (negative: back into the line), across
    held = ((e[:, 0] < 0) & (np.abs(e[:, 1]) < a)) | (np.hypot(*e.T) < k)
    assert held.mean() == pytest.approx(0.9, abs=0.002)
    one_d = ((e[:, 0] < 0) & (np.abs(e[:, 1]) < a)) | (np.hypot(*e.T) < a)
    assert one_d.mean() < 0.83
    for c in (0.5, 0.95, 0.99):
        assert derived.band_scale(c) < derived.end_scale(c) < np.sqrt(-2.0 * np.log(1 - c))
    with pytest.raises(ValueError, match="confidence must lie between 0 and 1"):
        derived.end_scale(1.0)


def test_free_end_caps_scale_only_the_ends_where_no_band_continues():
    from vectoradjust.accuracy.derived.bands import _free_end_caps, _free_ends

    c0 = np.eye(4) + 0.5 * np.eye(4, k=2) + 0.5 * np.eye(4, k=-2)
    cov = np.tile(c0, (3, 1, 1))
    a = np.array([10, 11, 20])  # a line 10-11-12 and a lone segment 20-21
    free = _free_ends(a, a)
    assert free.tolist() == [[True, False], [False, True], [True, True]]
    out = _free_end_caps(cov, free, 0.9)
    f = derived.end_scale(0.9) / derived.band_scale(0.9)
    d = np.array([[f, f, 1, 1], [1, 1, f, f], [f, f, f, f]])
    assert np.allclose(out, cov * d[:, :, None] * d[:, None, :])
    assert np.allclose(cov[0], c0)  # the input is not changed
    # a neighbour with a band of the other kind (measured / conflated) is no free end
    assert _free_ends(a[:1], a).tolist() == [[True, False]]
    assert np.all(np.linalg.eigvalsh(out) > 0)


def test_measured_bands_are_the_same_before_and_after_the_conflation(conflated):
    """The command line builds the measured segments' bands before the conflation: their
    free ends must not depend on it (an unmeasured neighbour counts as continuing)."""
    from vectoradjust.accuracy.derived.bands import _measured_segments

    _, out = conflated
    d = out.databases[0]
    after = derived.segment_bands(out, d, 0.9, segments="measured")
    before = derived.segment_bands(out, replace(d, vertices={}), 0.9, segments="all")
    assert derived.vertex_covariance(replace(d, vertices={})) is None
    assert np.array_equal(after.start_vertex, before.start_vertex)
    assert np.array_equal(after.start_vertex, _measured_segments(d))
    assert np.array_equal(after.xy, before.xy) and np.array_equal(after.offsets,
                                                                  before.offsets)


def test_bands_hold_line_ends_at_end_scale_and_inner_vertices_at_band_scale(conflated):
    """The ring of a feature's first segment contains its first vertex's ellipse at
    end_scale; at a vertex where the line goes on it is drawn at band_scale (narrower)."""
    _, out = conflated
    d = out.databases[0]
    sb = derived.segment_bands(out, d, 0.9)
    vc = derived.vertex_covariance(d)
    fi = d.shape.layer.vertex_feature
    adj = np.asarray(d.adjusted_coords)[:, :2]
    starts = set(sb.start_vertex.tolist())
    first = [i for i, a in enumerate(sb.start_vertex)
             if a - 1 not in starts and a + 1 in starts and fi[a + 1] == fi[a]][:20]
    assert len(first) >= 10
    k_end, k_in = derived.end_scale(0.9), derived.band_scale(0.9)
    widened = 0
    for i in first:
        a = sb.start_vertex[i]
        ring = sb.rings[i]
        assert _inside(ring, _ellipse(adj[a], vc[a, :2, :2], 0.999 * k_end)).all()
        # the inner end (a + 1): not the end's ellipse, the band's
        assert _inside(ring, _ellipse(adj[a + 1], vc[a + 1, :2, :2], 0.999 * k_in)).all()
        widened += not _inside(ring, _ellipse(adj[a + 1], vc[a + 1, :2, :2], k_end)).all()
    assert widened >= len(first) // 2


def test_end_caps_raise_the_band_coverage_of_line_end_vertices(conflated):
    """Seed 1 of ``conflation``: the conflated vertices at line ends were inside the
    band at 0.785 with the 1.645-sigma cap (inner vertices 0.89); now both about 0.9."""
    data, out = conflated
    d = out.databases[0]
    sb = derived.segment_bands(out, d, 0.9)
    from vectoradjust.adjust.shapepoints import lookup

    tid, txyz = data.truth[d.name]
    ti = lookup(tid, d.shape.vertex_ids)
    vidx = np.flatnonzero(ti >= 0)
    inside = bands_lengths._band_inside(out, d, sb, vidx, np.asarray(txyz, float)[ti[vidx], :2])
    layer = d.shape.layer
    fi, part = layer.vertex_feature, layer.vertex_part
    same = (fi[1:] == fi[:-1]) & (part[1:] == part[:-1])
    end = np.ones(len(fi), bool)
    end[1:-1] = ~(same[1:] & same[:-1])
    src = np.asarray(d.vertices["Source"])[vidx]
    conf = np.isin(src, ("interpolated", "extrapolated"))
    at_end, inner = inside[conf & end[vidx]], inside[conf & ~end[vidx]]
    assert len(at_end) > 300 and len(inner) > 200
    assert 0.85 <= at_end.mean() <= 0.95 and 0.85 <= inner.mean() <= 0.95


def _ellipse(centre, cov2, k, n=72):
    w, v = np.linalg.eigh(cov2)
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return centre[None, :] + (k * (v * np.sqrt(np.clip(w, 0, None))) @ np.vstack(
        [np.cos(th), np.sin(th)])).T


def _inside(ring, pts):
    import shapely

    poly = shapely.Polygon(ring).buffer(1e-6)
    return shapely.contains_xy(poly, pts[:, 0], pts[:, 1])
