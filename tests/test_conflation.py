"""Conflation (every vertex corrected by least-squares collocation, docs/method.md section 10).

Numerics against independent truth: the batched k-nearest kriging equals the dense
collocation formula solved directly; the fit (leave-one-out score) recovers the parameters
and the covariance function of simulated random fields; the database noise taken as its
mean given the data covers new points 90 % (Monte Carlo); the variance of the measured
points' mean is that of their joint covariance (definition); the leave-one-out coverage of
a known model is 90 % (Monte Carlo); the image-only position undoes the prior's pull by
definition. On simulated
projects with known truth (a smooth field + shift, a shift only, real Helsinki road
geometry): the unmeasured vertices' RMSE to the truth drops by >= 70 %, measured
vertices are unchanged, coincident vertices and closed rings stay together.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import solve

from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.conflation import (
    CE90_CIRCULAR,
    ConflationSettings,
    CovarianceModel,
    cross_validate,
    fit_covariance,
    image_only,
    krige,
    settings_from_table,
)
from vectoradjust.errors import CancelledError, ProjectError
from vectoradjust.pipeline import run
from vectoradjust.simulate import read_road_lines
from vectoradjust.simulate.conflation import conflation_scenario, smooth_field

ROADS = Path(__file__).parent / "data" / "helsinki" / "helsinki_roads.geojson"


def _dense(cov: CovarianceModel, xy_m, resid, noise, xy_p):
    """The collocation formula with every measured point, solved directly."""
    r = np.hypot(*(xy_m[:, None, :] - xy_m[None, :, :]).transpose(2, 0, 1))
    a = cov(r) + np.diag(cov.nugget + noise)
    c = cov(np.hypot(*(xy_p[:, None, :] - xy_m[None, :, :]).transpose(2, 0, 1)))
    w = solve(a, c.T, assume_a="pos").T
    return w @ resid, cov.sill - np.einsum("pk,pk->p", w, c)


def _field(rng, n, cov: CovarianceModel, extent=1000.0, comps=2):
    """Points and a Gaussian random field with covariance ``cov`` plus its nugget."""
    xy = rng.uniform(0, extent, (n, 2))
    r = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    chol = np.linalg.cholesky(cov(r) + 1e-9 * np.eye(n))
    z = chol @ rng.normal(size=(n, comps)) + rng.normal(0, np.sqrt(cov.nugget), (n, comps))
    return xy, z


@pytest.mark.parametrize("kind", ["exponential", "gaussian"])
def test_krige_with_all_points_equals_the_dense_collocation_formula(kind):
    rng = np.random.default_rng(3)
    cov = CovarianceModel(kind, 2.0, 80.0, 0.05)
    xy_m = rng.uniform(0, 300, (25, 2))
    resid = rng.normal(size=(25, 2))
    noise = rng.uniform(0.01, 0.2, 25)
    xy_p = rng.uniform(-50, 350, (40, 2))
    pred, var, near = krige(cov, xy_m, resid, noise, xy_p, k=25, chunk=7)
    pd, vd = _dense(cov, xy_m, resid, noise, xy_p)
    assert np.allclose(pred, pd, atol=1e-9) and np.allclose(var, vd, atol=1e-9)
    assert np.allclose(near, np.min(np.hypot(*(xy_p[:, None] - xy_m[None]).transpose(2, 0, 1)),
                                    axis=1))


def test_leave_one_out_leaves_exactly_the_point_out():
    rng = np.random.default_rng(4)
    cov = CovarianceModel("exponential", 1.0, 50.0, 0.1)
    xy = rng.uniform(0, 200, (15, 2))
    resid = rng.normal(size=(15, 1))
    noise = np.full(15, 0.02)
    pred, var, _ = krige(cov, xy, resid, noise, xy, k=14, skip_self=True)
    for i in (0, 7, 14):
        keep = np.arange(15) != i
        pd, vd = _dense(cov, xy[keep], resid[keep], noise[keep], xy[[i]])
        assert np.allclose(pred[i], pd[0]) and var[i] == pytest.approx(vd[0])


def test_kriging_limits_reproduce_data_and_fall_back_to_the_trend():
    cov = CovarianceModel("gaussian", 4.0, 100.0, 0.0)
    xy = np.array([[0.0, 0.0], [500.0, 0.0], [0.0, 500.0]])
    resid = np.array([[1.0], [-2.0], [0.5]])
    pred, var, _ = krige(cov, xy, resid, np.zeros(3), np.array([[0.0, 0.0], [1e5, 1e5]]), k=3)
    assert pred[0, 0] == pytest.approx(1.0, abs=1e-6) and var[0] == pytest.approx(0, abs=1e-6)
    assert pred[1, 0] == pytest.approx(0.0, abs=1e-12) and var[1] == pytest.approx(4.0)


def test_no_signal_means_the_trend_alone():
    cov = CovarianceModel("exponential", 0.0, 0.0, 0.3)
    pred, var, _ = krige(cov, np.zeros((3, 2)) + [[0, 0], [1, 0], [0, 1]],
                         np.ones((3, 2)), np.zeros(3), np.array([[0.5, 0.5]]), k=3)
    assert np.all(pred == 0) and np.all(var == 0)


def test_cancel_stops_the_prediction():
    cov = CovarianceModel("exponential", 1.0, 10.0, 0.0)
    with pytest.raises(CancelledError, match="conflation was cancelled"):
        krige(cov, np.zeros((2, 2)) + [[0, 0], [1, 1]], np.ones((2, 1)), np.zeros(2),
              np.zeros((5, 2)), k=2, is_cancelled=lambda: True)


@pytest.mark.parametrize("kind", ["exponential", "gaussian"])
def test_fit_recovers_the_parameters_of_simulated_fields(kind):
    rng = np.random.default_rng(11)
    true = CovarianceModel(kind, 4.0, 120.0, 0.25)
    # dense enough (400 m square) that the short lags resolve the nugget
    fits = [fit_covariance(*_field(rng, 500, true, extent=400.0), np.zeros(500), kind)
            for _ in range(4)]
    sill = np.mean([f.sill for f in fits])
    length = np.mean([f.length for f in fits])
    nug = np.mean([f.nugget for f in fits])
    assert sill == pytest.approx(4.0, rel=0.35)
    assert length == pytest.approx(120.0, rel=0.4)
    assert nug == pytest.approx(0.25, abs=0.15)


def test_fit_nugget_is_at_least_the_known_noise_and_split_from_it():
    rng = np.random.default_rng(12)
    xy = rng.uniform(0, 1000, (400, 2))
    z = rng.normal(0, 0.5, (400, 2))  # white: known 0.16 + database 0.09
    f = fit_covariance(xy, z, np.full(400, 0.16))
    assert f.sill < 0.05
    assert f.nugget == pytest.approx(0.09, abs=0.04)


def test_auto_keeps_the_covariance_function_the_field_was_drawn_from():
    """The leave-one-out score tells a smooth (Gaussian) field from a rough one."""
    rng = np.random.default_rng(14)
    for kind in ("gaussian", "exponential"):
        true = CovarianceModel(kind, 4.0, 120.0, 0.25)
        xy, z = _field(rng, 400, true, extent=600.0)
        f = fit_covariance(xy, z, np.zeros(400))  # model "auto"
        assert f.kind == kind
        assert f.fit["loo_score"] < f.fit["loo_score_white"]  # the field beats white noise


def test_database_noise_as_its_mean_given_the_data_covers_new_points():
    """Monte Carlo: white database noise (0.09 m^2) under known image noise (0.1 m^2),
    60 measured points. A new vertex's error is N(0, 0.09) per axis; with the predicted
    variance v its CE90 covers it with probability 1 - 0.1^(v / 0.09) (Rayleigh)."""
    rng = np.random.default_rng(21)
    cover, nug = [], []
    for _ in range(30):
        xy = rng.uniform(0, 700, (60, 2))
        z = rng.normal(0, np.sqrt(0.09 + 0.1), (60, 2))
        f = fit_covariance(xy, z, np.full(60, 0.1))
        cover.append(1 - 0.1 ** ((f.nugget + f.sill) / 0.09))
        nug.append(f.nugget)
    assert np.mean(cover) == pytest.approx(0.90, abs=0.04)
    assert np.mean(nug) == pytest.approx(0.09, abs=0.025)


def test_mean_variance_is_that_of_the_joint_covariance():
    """Definition: Var(mean) = 1' C 1 / p^2 of the points' joint covariance."""
    from vectoradjust.conflation import _mean_variance

    _, out, _ = _runs("shift")
    res = out.result
    pts = np.arange(0, res.problem.n_points, 3)[:50]
    j = res.joint_covariance(pts)
    want = [j[a::3, a::3].sum() / len(pts) ** 2 for a in range(3)]
    assert np.allclose(_mean_variance(res, pts), want, rtol=1e-9, atol=0)
    # the points' own (intersection) errors average out: far below one point's variance
    assert np.all(_mean_variance(res, pts) < 0.5 * np.mean(np.diagonal(j).reshape(-1, 3), 0))


def test_leave_one_out_coverage_of_a_known_model_is_90_percent():
    """Monte Carlo: a field drawn from the model -> 90 % of held-out points inside."""
    rng = np.random.default_rng(13)
    cov = CovarianceModel("exponential", 2.0, 100.0, 0.1)
    shares = []
    for _ in range(6):
        xy, z = _field(rng, 300, cov)
        noise = np.full(300, 0.05)
        z = z + rng.normal(0, np.sqrt(0.05), z.shape)
        shares.append(cross_validate(cov, xy, z, noise, 12, CE90_CIRCULAR)["share_within_90"])
    assert np.mean(shares) == pytest.approx(0.90, abs=0.03)


def test_image_only_undoes_the_prior_pull():
    """X_hat = Q (P_img X_img + P_prior X_prior): image_only returns X_img, P_img^-1."""
    rng = np.random.default_rng(5)
    n = 6
    a = rng.normal(size=(n, 3, 3))
    p_img = np.einsum("nij,nkj->nik", a, a) + 0.5 * np.eye(3)
    p_prior = np.broadcast_to(np.diag([4.0, 4.0, 0.1]), (n, 3, 3)).copy()
    x_img = rng.normal(size=(n, 3))
    x_prior = rng.normal(size=(n, 3))
    q = np.linalg.inv(p_img + p_prior)
    xhat = np.einsum("nij,nj->ni", q, np.einsum("nij,nj->ni", p_img, x_img)
                     + np.einsum("nij,nj->ni", p_prior, x_prior))
    vf = 2.5
    result = SimpleNamespace(variance_factor=vf, point_cov=vf * q, xyz=xhat)
    problem = SimpleNamespace(prior_weight=p_prior, prior_xyz=x_prior)
    xyz, var = image_only(result, problem, np.arange(n), min_share=0.0, scale=1.5)
    assert np.allclose(xyz, x_img)
    assert np.allclose(var, 1.5 * np.einsum("nii->ni", np.linalg.inv(p_img)))


def test_smooth_field_has_the_stated_variance():
    xy = np.random.default_rng(0).uniform(0, 1e5, (20000, 2))
    f = smooth_field(xy, 2.0, 150.0, seed=1, n_waves=400)
    assert f.std(axis=0) == pytest.approx([2.0, 2.0], rel=0.15)


# --------------------------------------------------------------------------- settings
def test_settings_defaults_and_errors():
    assert settings_from_table(None) == ConflationSettings()
    s = settings_from_table({"enabled": False, "k": 8, "max_distance": 50, "model": "gaussian"})
    assert (s.enabled, s.k, s.max_distance, s.model) == (False, 8, 50.0, "gaussian")
    for bad in ({"k": 0}, {"k": 2.5}, {"model": "spherical"}, {"enabled": "yes"},
                {"max_distance": -1}, {"nearest": 3}, {"min_points": 1}):
        with pytest.raises(ProjectError, match=r"\[conflation\]"):
            settings_from_table(bad, "p.toml")


def test_project_file_checks_the_conflation_table():
    from vectoradjust.files.project import parse_project

    raw = {"crs": "EPSG:32616", "camera": {"focal_length": 152.4},
           "images": [{"id": "L", "position": [0, 0, 800], "attitude": [0, 0, 0]}],
           "measurements": {"path": "m.csv", "sigma": 0.015},
           "conflation": {"k": "many"}}
    with pytest.raises(ProjectError, match="k"):
        parse_project(raw, base_dir=".")
    raw["conflation"] = {"k": 6}
    assert parse_project(raw, base_dir=".").raw["conflation"]["k"] == 6


# --------------------------------------------------------------------------- whole runs
@functools.cache
def _runs(name: str):
    kw = {"smooth": {}, "shift": {"amplitude": 0.0},
          "helsinki": {"true_roads": read_road_lines(ROADS)},
          "helsinki-0.3": {"true_roads": read_road_lines(ROADS), "stated_sigma": 0.3}}[name]
    data = conflation_scenario(1, **kw)
    return data, run(data), run(replace(data, conflation={"enabled": False}))


@pytest.mark.parametrize("name", ["smooth", "shift", "helsinki"])
def test_unmeasured_vertices_move_towards_the_truth(name):
    data, out, _ = _runs(name)
    d = out.databases[0]
    v = d.vertices
    tid, txyz = data.truth["OSM"]
    t = np.asarray(txyz)[lookup(tid, d.shape.vertex_ids)]
    u = v["Adjusted"] == 0
    assert u.sum() > 100 and set(v["Source"][u]) <= {"interpolated", "extrapolated"}
    before = np.sqrt(np.mean(np.sum((d.shape.layer.coords[u, :2] - t[u, :2]) ** 2, axis=1)))
    adj = np.column_stack([v["AdjX"], v["AdjY"]])[u]
    after = np.sqrt(np.mean(np.sum((adj - t[u, :2]) ** 2, axis=1)))
    assert after <= 0.3 * before  # >= 70 % of the (mostly systematic) error removed
    e = out.summary["conflation"]["databases"][0]
    assert e["truth"]["rmse_conflated_truth_horizontal"] == pytest.approx(after)
    inside = np.mean(np.hypot(*(adj - t[u, :2]).T) <= v["CE90"][u])
    # CE90 covers the truth 0.85-0.95 pooled over seeds (test_conflation_trend.py); one
    # seed scatters with its fitted covariance and database noise (validation/conflation.py
    # --seeds 1-20, SD over the seeds: smooth and shift 0.06 on ~140 vertices, Helsinki
    # 0.03 on ~560): seed 1 gives smooth 0.79, shift 0.84, Helsinki 0.88
    assert inside == pytest.approx(e["truth"]["share_within_ce90"])
    assert (0.75 if name in ("smooth", "shift") else 0.85) <= inside <= 0.95
    ez = np.abs(v["AdjZ"][u] - t[u, 2])
    le = np.mean(ez <= v["LE90"][u])
    assert le == pytest.approx(e["truth"]["share_within_le90"])
    # heights: the DEM heights (0.1 m) are better than one image height (0.3 m); LE90
    # 0.84-0.96 on Helsinki, wider (0.96-1.00) on the 50-point synthetic grid
    assert 0.85 <= le <= (0.95 if name == "helsinki" else 1.0)
    cv = e["cross_validation"]["horizontal"]
    assert cv["count"] >= 40 and cv["rmse"] < cv["rmse_trend_only"] + 1e-9


@pytest.mark.parametrize("name", ["smooth", "helsinki"])
def test_measured_unchanged_and_coincident_vertices_move_together(name):
    _, out, ref = _runs(name)
    d, r = out.databases[0], ref.databases[0]
    m = d.vertices["Adjusted"] == 1
    # the two runs solve the same problem; under Debian's numpy 1.24 a run's float sums can
    # differ in the last bits (~1e-13 m, alignment-dependent SIMD reductions), so compare to
    # a nanometre rather than bit for bit
    for c in ("AdjX", "AdjY", "AdjZ", "Vx", "CE90", "LE90"):
        np.testing.assert_allclose(d.vertices[c][m], r.vertices[c][m], rtol=0, atol=1e-9,
                                   err_msg=c)
    assert np.all(r.vertices["Source"][~m] == "unchanged")
    assert np.all(np.isnan(r.vertices["Vx"][~m]))
    adj = d.adjusted_coords
    vo = d.shape.vertex_object
    first = d.shape.object_vertex[vo]
    shared = vo[np.flatnonzero(first != np.arange(len(vo)))]
    assert shared.size > 0  # junctions exist
    assert np.array_equal(adj[:, :2], adj[first, :2])


def test_closed_rings_stay_closed_and_features_follow_the_corrected_line():
    _, out, _ = _runs("helsinki")
    d = out.databases[0]
    lay = d.shape.layer
    adj = d.adjusted_coords
    fi = lay.vertex_feature
    nf = lay.n_features
    first = np.full(nf, -1)
    first[fi[::-1]] = np.arange(len(fi))[::-1]
    last = np.full(nf, -1)
    last[fi] = np.arange(len(fi))
    ring = np.flatnonzero(np.all(lay.coords[first, :2] == lay.coords[last, :2], axis=1))
    assert ring.size > 0
    assert np.array_equal(adj[first[ring], :2], adj[last[ring], :2])
    f = 0
    seg = adj[fi == f, :2]
    assert d.features["Length"][f] == pytest.approx(np.sum(np.hypot(*np.diff(seg, axis=0).T)))
    assert d.features["FirstX"][f] == adj[first[f], 0]


def test_too_few_measured_points_leave_the_database_unchanged_with_a_warning():
    data, _, _ = _runs("shift")
    out = run(replace(data, conflation={"min_points": 100000}))
    d = out.databases[0]
    m = d.vertices["Adjusted"] == 1
    assert np.all(d.vertices["Source"][~m] == "unchanged")
    assert np.array_equal(d.vertices["AdjX"][~m], d.vertices["X"][~m])
    assert any("conflation not done" in w for w in out.warnings)


def test_field_model_predicts_what_the_vertices_got():
    _, out, _ = _runs("helsinki")
    d = out.databases[0]
    v = d.vertices
    u = np.flatnonzero(v["Adjusted"] == 0)[:200]
    obj = d.shape.object_xyz[d.shape.vertex_object[u]]  # vertices of one object share it
    disp, var = d.conflation.predict(obj[:, :2])
    assert np.allclose(obj[:, 0] + disp[:, 0], v["AdjX"][u], atol=1e-6)
    assert np.allclose(obj[:, 2] + disp[:, 2], v["AdjZ"][u], atol=1e-6)
    assert np.allclose(np.sqrt(var[:, 0]), v["SigmaX"][u], rtol=1e-6)


def test_report_has_the_conflation_section_and_figure():
    from vectoradjust.conflation import field_grid
    from vectoradjust.files.report import conflation_figure, report_html

    _, out, ref = _runs("smooth")
    html = report_html(out)
    assert "Conflation: every vertex corrected" in html and "conflation field" in html
    assert conflation_figure(ref) is None  # nothing conflated: no figure
    g = field_grid(out.databases[0], cell=25.0)
    x = g["x0"] + 25.0 * np.array([0.5, 3.5])
    y = g["y0"] - 25.0 * np.array([0.5, 2.5])
    disp, var = out.databases[0].conflation.predict(np.column_stack([x, y]))
    assert g["cell"] == 25.0
    assert np.allclose([g["dx"][0, 0], g["dx"][2, 3]], disp[:, 0])
    assert np.all(g["ce90"] > 0) and np.isfinite(g["dx"]).all()


def test_conflation_raster_is_written_with_the_field(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from vectoradjust.conflation import field_grid
    from vectoradjust.files.derived_outputs import write_conflation_rasters

    _, out, _ = _runs("shift")
    paths = write_conflation_rasters(out, tmp_path, cell=20.0)
    g = field_grid(out.databases[0], 20.0)
    with rasterio.open(paths["OSM"]) as src:
        assert src.count == 5 and src.res == (20.0, 20.0)
        assert np.allclose(src.read(1), g["dx"]) and np.allclose(src.read(4), g["ce90"])
        assert src.transform.c == pytest.approx(g["x0"]) and src.crs is not None


def test_the_stage_reports_progress_and_honours_cancel():
    data, _, _ = _runs("shift")
    seen = []

    def progress(f, msg):
        seen.append((f, msg))

    run(data, progress=progress)
    conf = [f for f, m in seen if m.startswith("conflation of OSM")]
    assert conf and 0.9 <= min(conf) and max(conf) <= 1.0
    state = {"go": False}

    def progress_then_cancel(f, msg):
        state["go"] = state["go"] or msg.startswith("conflation")

    with pytest.raises(CancelledError, match="conflation"):
        run(data, progress=progress_then_cancel, is_cancelled=lambda: state["go"])


def test_a_common_height_error_of_a_strained_adjustment_does_not_move_dem_heights():
    """The database states 0.3 m while a 2 m field is present: the adjustment is strained
    and its heights share an error far beyond their covariance. The heights' mean is
    applied only where it exceeds what one measured point's height error could be; an
    unapplied mean is counted in the vertices' variance (sigma^2 >= m^2)."""
    data, out, _ = _runs("helsinki-0.3")
    e = out.summary["conflation"]["databases"][0]
    mean, sig = e["trend"]["mean"][2], e["trend"]["mean_sigma"][2]
    d = out.databases[0]
    v = d.vertices
    m = v["Adjusted"] == 1
    raw = float(np.nanmean(v["Vz"][m]))  # the adjusted heights' mean displacement
    assert abs(raw) > 0.2  # the strained stereo model's common height error
    own = np.sqrt(np.nanmean(v["SigmaZ"][m] ** 2) - d.spec.identification_sigma[1] ** 2)
    if abs(raw) <= 1.96 * own:
        assert mean == 0.0 and sig >= 0.95 * abs(raw)
    else:
        assert mean != 0.0
    tid, txyz = data.truth["OSM"]
    t = np.asarray(txyz)[lookup(tid, d.shape.vertex_ids)]
    u = ~m
    rz_db = np.sqrt(np.mean((v["Z"][u] - t[u, 2]) ** 2))
    rz = np.sqrt(np.mean((v["AdjZ"][u] - t[u, 2]) ** 2))
    assert rz <= rz_db * 1.1  # the DEM heights are not spoilt (nor through the field)
    assert np.mean(np.abs(v["AdjZ"][u] - t[u, 2]) <= v["LE90"][u]) >= 0.9


def test_length_sd_says_which_vertices_it_covers():
    """LengthSD includes the conflated vertices' covariance (issue 30); only vertices left
    at their database position count as fixed, and the features layer says so."""
    _, out, _ = _runs("helsinki")
    d = out.databases[0]
    f = d.features
    scope = np.asarray(f["LengthSDOf"])
    fi = d.shape.layer.vertex_feature
    valued = np.asarray(d.vertices["Source"]) != "unchanged"  # measured or conflated
    val = np.bincount(fi, weights=valued, minlength=len(scope))
    meas = np.bincount(fi, weights=d.vertices["Adjusted"] == 1, minlength=len(scope))
    total = np.bincount(fi, minlength=len(scope))
    assert np.array_equal(scope == "all vertices", (val == total) & (val > 0))
    assert np.array_equal(scope == "measured vertices", (val > 0) & (val < total))
    assert np.array_equal(scope == "", val == 0)
    assert np.all(np.isfinite(f["LengthSD"][scope != ""]))
    assert np.all(np.isnan(f["LengthSD"][scope == ""]))
    assert ((meas < total) & (val == total) & (meas > 0)).any()  # conflated vertices count
    e = out.summary["conflation"]["databases"][0]["length_sd"]
    assert e["features_with_unmeasured_vertices"] == int(((meas > 0) & (meas < total)).sum())
