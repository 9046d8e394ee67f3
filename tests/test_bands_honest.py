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
