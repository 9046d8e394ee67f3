"""Database offsets (nuisance parameters) and the identification error (docs/method.md section 10).

The offsets are checked against a dense textbook adjustment with the offsets as explicit
unknowns (estimates, sigma0^2, every covariance), and on simulations with a biased
database and an analyst's identification error against the truth.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_bundle import _dense  # noqa: E402  (tests/ is on sys.path under pytest)

from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.pipeline import run
from vectoradjust.simulate import DatabaseModel, make_scenario


def _with(data, **spec_changes):
    vecs = [(replace(s, **spec_changes), layer) for s, layer in data.vectors]
    return replace(data, vectors=vecs)


@pytest.fixture(scope="module")
def small_shift_run():
    db = DatabaseModel("DB", "db_id", "db", 25.0, 0.5, (2.0, -1.5), 0.0, 0.0, 1.0)
    sc = make_scenario(3, n_images=2, grid=(2, 2), databases=(db,), n_tie=6,
                       shape_sigma=(1.0, 1.0, 1.0))
    data = _with(sc.to_project_data(), offset="shift")
    # covariances scaled by sigma0^2, so that they compare with the dense inverse
    return run(replace(data, settings=replace(data.settings, covariance_scale="a-posteriori")))


def test_offsets_equal_the_dense_adjustment_with_explicit_offset_unknowns(small_shift_run):
    out = small_shift_run
    prob, res = out.problem, out.result
    n, m = prob.n_images, prob.n_points
    # more unknowns: the offset (dX, dY, and dZ: the heights come from a DEM, whose bias
    # is its own parameter) enters every shape point prior X_db = X + G T
    a, p, _ = _dense_with_offsets(out)
    q_off = res.offset_g.shape[2]
    assert q_off == 3 and out.summary["databases"][0]["offset"]["axes"] == ["X", "Y", "Z"]
    n_mat = a.T @ p @ a
    q = np.linalg.inv(n_mat)
    # misclosures at the solution: database prior minus (X + G T); prior_xyz holds
    # X_db - G T (the DEM heights sampled at the shifted position)
    entry = out.summary["databases"][0]["offset"]
    has = np.flatnonzero(prob.has_prior)
    lp = (prob.prior_xyz[has] - res.xyz[has]).copy()
    we = prob.eo_weight.ravel()
    ell = np.concatenate([-res.v_image.ravel(), lp.ravel(), (prob.eo0 - res.eo).ravel()[we > 0]])
    step = np.linalg.solve(n_mat, a.T @ p @ ell)
    assert np.abs(step).max() < 1e-5  # first-order optimality of the joint problem
    vtpv = float(ell @ p @ ell)
    dof = a.shape[0] - a.shape[1]
    assert res.dof == dof
    assert res.sigma0_squared == pytest.approx(vtpv / dof, rel=1e-6)
    s0 = res.sigma0_squared
    assert np.allclose(np.array(entry["sigma"]) ** 2, s0 * np.diag(q)[-q_off:], rtol=1e-6)
    for i in range(n):
        assert np.allclose(res.eo_cov[i], s0 * q[6 * i:6 * i + 6, 6 * i:6 * i + 6],
                           rtol=1e-6, atol=1e-14)
    for j in range(m):
        o = 6 * n + 3 * j
        assert np.allclose(res.point_cov[j], s0 * q[o:o + 3, o:o + 3], rtol=1e-6, atol=1e-12)


def _biased(seed, *, offset, ident, reweight, n_pts=1500, pointing=0.5, bias=(3.0, 2.0)):
    db = DatabaseModel("DB", "db_id", "db", 20.0, 0.5, bias, 0.0, 0.0, 1.5)
    sc = make_scenario(seed, databases=(db,), n_shape_points=n_pts, pointing_sigma=pointing,
                       shape_sigma=(3.0, 3.0, 3.0))
    data = _with(sc.to_project_data(), offset=offset, identification_sigma=ident)
    data = replace(data, settings=replace(data.settings, reweight=reweight))
    out = run(data)
    ctrl_only = run(replace(data, vectors=[]))
    return data, out, ctrl_only


@pytest.mark.slow
@pytest.mark.parametrize("reweight", ["none", "two-pass"])
def test_a_biased_database_no_longer_pulls_the_images(reweight):
    """Without offsets a 3.6 m bias makes the check points 2-3x worse; with them <= 1.05x."""
    ratios = {}
    for offset in ("none", "shift"):
        data, out, base = _biased(1, offset=offset, ident=(0.5, 0.1), reweight=reweight)
        ratios[offset] = (out.summary["check_points"]["rmse_horizontal"]
                          / base.summary["check_points"]["rmse_horizontal"])
    assert ratios["none"] > 1.5  # the harm the offsets remove (measured: 2.6-2.7)
    assert ratios["shift"] <= 1.05
    # the estimate is the database's mean displacement at the measured vertices
    entry = out.summary["databases"][0]["offset"]
    d = out.databases[0]
    tid, txyz = data.truth["DB"]
    ti = lookup(tid, d.shape.vertex_ids)
    sel = (d.vertices["Adjusted"] == 1) & (ti >= 0)
    mean = (d.shape.layer.coords[sel] - txyz[ti[sel]]).mean(axis=0)[:2]
    sig = np.array(entry["sigma"][:2])  # (X, Y; Z is the DEM heights' own offset)
    assert np.all(np.abs(np.array(entry["values"][:2]) - mean) < 4 * sig + 0.02)
    assert entry["test"]["significant"]
    assert "north-east of the images" in entry["statement"]


@pytest.mark.slow
@pytest.mark.parametrize("reweight", ["none", "two-pass"])
def test_ce90_covers_the_real_road_vertex_with_the_identification_error(reweight):
    """0.5 m identification error: CE90 of the real vertex covers the truth 85-95 %;
    the photogrammetric CE90 alone (CE90_meas) covers almost nothing."""
    inside, inside_meas, n = 0, 0, 0
    for seed in (1, 2, 3):
        data, out, _ = _biased(seed, offset="shift", ident=(0.5, 0.1), reweight=reweight,
                               n_pts=800)
        d = out.databases[0]
        tid, txyz = data.truth["DB"]
        ti = lookup(tid, d.shape.vertex_ids)
        sel = (d.vertices["Adjusted"] == 1) & (ti >= 0)
        err = np.hypot(d.vertices["AdjX"][sel] - txyz[ti[sel], 0],
                       d.vertices["AdjY"][sel] - txyz[ti[sel], 1])
        inside += int((err <= d.vertices["CE90"][sel]).sum())
        inside_meas += int((err <= d.vertices["CE90_meas"][sel]).sum())
        n += int(sel.sum())
    assert 0.85 <= inside / n <= 0.95, inside / n
    assert inside_meas / n < 0.2


def test_missing_identification_sigma_is_said(small_shift_run):
    warnings = small_shift_run.summary["warnings"]
    assert any("identification_sigma is not given" in w for w in warnings)
    assert small_shift_run.summary["databases"][0]["identification_sigma"] is None


@pytest.mark.slow
def test_roads_that_disagree_with_the_control_are_reported():
    """A biased database without an offset moves the images: a finding with the check
    point ratio; with the offset estimated, roads and control agree."""
    _, out, _ = _biased(1, offset="none", ident=(0.5, 0.1), reweight="none")
    rec = out.summary["roads_and_control"]
    assert rec["harm"] and not rec["eo_test"]["passed"] and rec["check_ratio"] > 1.5
    # the check points' worsening is far beyond chance (z of the MSE change)
    assert rec["check_worse"] and rec["check_change_z"] > 3.0
    assert any("DISAGREE" in w for w in out.summary["warnings"])
    _, out, _ = _biased(1, offset="shift", ident=(0.5, 0.1), reweight="none")
    rec = out.summary["roads_and_control"]
    assert not rec["harm"] and rec["eo_test"]["passed"]


@pytest.mark.slow
def test_the_roads_versus_control_test_rarely_alarms_on_unbiased_databases():
    """Unbiased databases (iid noise): the EO test passes in at least 8 of 10 runs
    (nominal 95 %)."""
    passed = 0
    for seed in range(10):
        db = DatabaseModel("DB", "db_id", "db", 25.0, 0.5, (0.0, 0.0), 0.0, 0.0, 2.0)
        sc = make_scenario(seed, databases=(db,), n_shape_points=300,
                           shape_sigma=(2.0, 2.0, 2.0))
        out = run(sc.to_project_data())
        passed += out.summary["roads_and_control"]["eo_test"]["passed"]
    assert passed >= 8


def test_vce_holds_the_control_at_its_stated_sigma_when_the_data_disagree():
    _, out, _ = _biased(1, offset="none", ident=None, reweight="vce", n_pts=800)
    vce = out.summary["variance_components"]
    assert any(f["group"] == "control" for f in vce["findings"])
    assert vce["groups"]["control"]["sigma"] == pytest.approx(
        vce["groups"]["control"]["sigma_initial"])
    assert any("FINDING" in w for w in out.summary["warnings"])


def test_project_file_keys_for_the_error_model(tmp_path):
    from vectoradjust.errors import ProjectError
    from vectoradjust.files.project import parse_project

    base = {"crs": "EPSG:32616", "camera": {"focal_length": 152.4},
            "images": [{"id": "L", "position": [0, 0, 800], "attitude": [0, 0, 0]}],
            "measurements": {"path": "m.csv"}, "control": {"path": "c.csv"}}

    def spec(**v):
        raw = dict(base, vectors=[dict({"name": "OSM", "path": "r.shp"}, **v)])
        return parse_project(raw, tmp_path, tmp_path / "p.toml").vectors[0]

    assert spec().identification_sigma is None and spec().offset == "shift"
    assert spec(identification_sigma=0.5).identification_sigma == (0.5, 0.0)
    assert spec(identification_sigma=[0.5, 0.2], offset="shift3d").offset == "shift3d"
    with pytest.raises(ProjectError, match="identification_sigma"):
        spec(identification_sigma=[0.5])
    assert spec(offset="similarity").offset == "similarity"
    with pytest.raises(ProjectError, match="offset must be one of"):
        spec(offset="warp")


def test_a_priori_covariances_are_the_cofactors():
    """covariance_scale = "a-priori": the covariances are not shrunk by sigma0^2 < 1 (a
    prior sigma that is too large would otherwise shrink every covariance)."""
    db = DatabaseModel("DB", "db_id", "db", 25.0, 0.5, (0.0, 0.0), 0.0, 0.0, 1.0)
    sc = make_scenario(4, databases=(db,), n_shape_points=300, shape_sigma=(3.0, 3.0, 3.0))
    data = _with(sc.to_project_data(), identification_sigma=(0.0, 0.0))  # none simulated
    post = run(replace(data, settings=replace(data.settings, covariance_scale="a-posteriori")))
    prio = run(replace(data, settings=replace(data.settings, covariance_scale="a-priori")))
    s0 = post.result.sigma0_squared
    assert s0 < 0.9  # the 3 m prior is too large for 1 m noise
    assert np.allclose(prio.result.point_cov, post.result.point_cov / s0)
    assert np.allclose(prio.result.eo_cov, post.result.eo_cov / s0)
    assert prio.summary["covariance_scale"]["scale"] == "a-priori"
    assert prio.summary["covariance_scale"]["factor"] == 1.0
    ce_ratio = prio.databases[0].vertices["CE90_meas"] / post.databases[0].vertices["CE90_meas"]
    ok = np.isfinite(ce_ratio)
    assert np.allclose(ce_ratio[ok], 1 / np.sqrt(s0))


@pytest.mark.slow
def test_identification_sigma_is_estimated_from_truth_and_common_intersections():
    a = DatabaseModel("A", "a_id", "a", 20.0, 0.5, (3.0, 2.0), 0.0, 0.0, 1.5)
    b = DatabaseModel("B", "b_id", "b", 25.0, 0.5, (-1.0, 1.0), 0.0, 0.0, 2.0)
    sc = make_scenario(2, databases=(a, b), n_shape_points=2000, pointing_sigma=0.5,
                       shape_sigma=(3.0, 3.0, 3.0))
    # the analyst does not state his identification error: the data must say it
    out = run(_with(sc.to_project_data(), offset="shift", identification_sigma=None))
    est = out.summary["identification_estimates"]
    for name in ("A", "B"):  # from the truth tables: 0.513 and 0.511 measured
        e = est["databases"][name]
        assert abs(e["horizontal"] - 0.5) < 3 * e["horizontal_se"] + 0.02
    (pair,) = est["pairs"]  # two databases measured separately at the same crossings
    assert pair["count"] >= 30
    assert abs(pair["horizontal"] - 0.5) < 3 * pair["horizontal_se"] + 0.02  # 0.469 measured
    warn = [w for w in out.summary["warnings"] if "identification_sigma is not given" in w]
    assert warn and "was used (estimated from truth" in warn[0]  # and applied
    used = out.summary["databases"][0]["identification_sigma_used"]
    assert abs(used["horizontal"] - 0.5) < 3 * used["se"] + 0.02


def _dense_with_offsets(out):
    """A, P and the inverse of N of the adjustment with the offsets as unknowns."""
    prob, res = out.problem, out.result
    a, p = _dense(prob, res.eo, res.xyz)
    g = res.offset_g  # (m, 3, q): the shift (X, Y) and the DEM heights' own Z offset
    q = g.shape[2]
    a = np.hstack([a, np.zeros((a.shape[0], q))])
    k_img = 2 * len(prob.obs_point)
    has = np.flatnonzero(prob.has_prior)
    row_of = {j: k_img + 3 * r for r, j in enumerate(has)}
    for j in np.flatnonzero(out.point_kind == "shape"):
        a[row_of[j]:row_of[j] + 3, -q:] = g[j]
    return a, p, np.linalg.inv(a.T @ p @ a)


def test_reliability_and_joint_covariances_include_the_offsets(small_shift_run):
    from vectoradjust.accuracy.derived import cross_covariance
    from vectoradjust.adjust.reliability import reliability

    out = small_shift_run
    prob, res = out.problem, out.result
    a, p, q = _dense_with_offsets(out)
    r_dense = np.diag(np.eye(len(p)) - a @ q @ a.T @ p)
    rel = reliability(res)
    assert rel.sum_r == pytest.approx(res.dof, abs=1e-6)  # sum of r = n - u with offsets
    k = 2 * len(prob.obs_point)
    assert np.allclose(rel.r_image.ravel(), r_dense[:k], atol=1e-8)
    has = np.flatnonzero(prob.has_prior)
    assert np.allclose(rel.r_point[has].ravel(), r_dense[k:k + 3 * len(has)], atol=1e-8)
    s0 = res.sigma0_squared
    n = prob.n_images
    pts = np.flatnonzero(out.point_kind == "shape")[[0, 3, 7]]
    idx = np.concatenate([6 * n + 3 * j + np.arange(3) for j in pts])
    assert np.allclose(res.joint_covariance(pts), s0 * q[np.ix_(idx, idx)], rtol=1e-6,
                       atol=1e-12)
    cc = cross_covariance(res, pts[[0, 0]], pts[[1, 0]])
    o0, o1 = 6 * n + 3 * pts[0], 6 * n + 3 * pts[1]
    assert np.allclose(cc[0], s0 * q[o0:o0 + 3, o1:o1 + 3], rtol=1e-6, atol=1e-12)
    assert np.allclose(cc[1], s0 * q[o0:o0 + 3, o0:o0 + 3], rtol=1e-6, atol=1e-12)


def test_length_sigma_with_offsets_matches_the_joint_covariance(small_shift_run):
    """LengthSD from the structured formula (offsets' share included) equals g' C g with
    the dense joint covariance of the feature's measured vertices."""
    out = small_shift_run
    d = out.databases[0]
    layer = d.shape.layer
    nadj = d.features["NAdj"]
    f = int(np.flatnonzero((nadj == d.features["NPts"]) & (nadj >= 3))[0])
    v = np.flatnonzero(layer.vertex_feature == f)
    xy = d.adjusted_coords[v, :2]
    seg = np.diff(xy, axis=0)
    u = seg / np.linalg.norm(seg, axis=1)[:, None]
    g = np.zeros((len(v), 3))
    g[:-1, :2] -= u
    g[1:, :2] += u
    pts, inv = np.unique(d.vertex_point[v], return_inverse=True)
    gp = np.zeros((len(pts), 3))
    np.add.at(gp, inv, g)
    c = out.result.joint_covariance(pts)
    # the adjustment's share (LengthSD adds the identification error and the lengthening)
    from dataclasses import replace

    from vectoradjust.accuracy.derived import feature_length_sigma

    bare = replace(d, spec=replace(d.spec, identification_sigma=None))
    sd = feature_length_sigma(out, bare, lengthening=False)[0]
    assert sd[f] == pytest.approx(float(np.sqrt(gp.ravel() @ c @ gp.ravel())), rel=1e-8)


@pytest.mark.slow
def test_a_rotated_and_scaled_database_is_absorbed_by_a_similarity_offset():
    """A database rotated by 2 mrad and scaled by +500 ppm about its centre (plus a
    shift): the similarity offset recovers rotation and scale, the shift alone leaves
    them in the residuals and pulls the images more."""
    db = DatabaseModel("DB", "db_id", "db", 20.0, 0.5, (2.0, 1.0), 0.0, 0.0, 0.5)
    sc = make_scenario(5, databases=(db,), n_shape_points=1500, shape_sigma=(1.0, 1.0, 1.0))
    data = sc.to_project_data()
    spec, layer = data.vectors[0]
    xy = layer.coords[:, :2]
    c = xy.mean(axis=0)
    r, s = 2e-3, 500e-6
    d = xy - c
    layer.coords[:, 0] += s * d[:, 0] - r * d[:, 1]
    layer.coords[:, 1] += r * d[:, 0] + s * d[:, 1]
    ratios, entries = {}, {}
    for kind in ("shift", "similarity"):
        run_ = run(replace(data, vectors=[(replace(spec, offset=kind), layer)]))
        ratios[kind] = run_.summary["roads_and_control"]["check_ratio"]
        entries[kind] = run_.summary["databases"][0]["offset"]
    e = entries["similarity"]
    i, j = e["axes"].index("rotation"), e["axes"].index("scale")
    assert abs(e["values"][i] - r) < 4 * e["sigma"][i] + 1e-5
    assert abs(e["values"][j] - s) < 4 * e["sigma"][j] + 1e-5
    assert "rotated" in e["statement"]
    assert ratios["similarity"] <= 1.05


def test_auto_scale_leaves_out_a_prior_stated_too_large():
    """covariance_scale = "auto" (default): a database whose stated sigma is larger than
    its residuals say does not scale the covariances; the factor is that of the images
    and the control (v'Pv / r of the other groups), and summary.json says which groups
    were left out."""
    db = DatabaseModel("DB", "db_id", "db", 25.0, 0.5, (0.0, 0.0), 0.0, 0.0, 1.0)
    sc = make_scenario(4, databases=(db,), n_shape_points=300, shape_sigma=(3.0, 3.0, 3.0))
    data = _with(sc.to_project_data(), identification_sigma=(0.0, 0.0))  # none simulated
    auto = run(data)
    post = run(replace(data, settings=replace(data.settings, covariance_scale="a-posteriori")))
    rec = auto.summary["covariance_scale"]
    assert rec["scale"] == "groups"
    assert set(rec["groups_left_out"]) == {"DB:h", "DB:v"}
    groups = auto.summary["variance_factors"]["groups"]
    rest = [g for g in groups if not g.startswith("DB:")]
    factor = (sum(groups[g]["vtpv"] for g in rest) / sum(groups[g]["redundancy"] for g in rest))
    assert rec["factor"] == pytest.approx(factor, rel=1e-6)
    assert 0.8 < factor < 1.25 and post.result.sigma0_squared < 0.9
    s0 = post.result.sigma0_squared
    assert np.allclose(auto.result.point_cov, post.result.point_cov / s0 * factor)


def test_q_times_b_equals_the_dense_inverse(small_shift_run):
    """``Q_xx B`` and ``S^-1 Z' B`` from the factorisation (per image products) against
    the inverse of the dense normal matrix, for an arbitrary B (the operator is linear)."""
    from vectoradjust.adjust.offsets import _q_times

    out = small_shift_run
    prob, res = out.problem, out.result
    n, m = prob.n_images, prob.n_points
    assert len(np.unique(prob.obs_image[: 2 * n])) > 1  # images interleaved, not grouped
    a, p = _dense(prob, res.eo, res.xyz)
    q = np.linalg.inv(a.T @ p @ a)  # unknowns: 6 per image, then 3 per point
    b = np.random.default_rng(5).normal(size=(m, 3, 4))
    qb, s_ztb, ztb = _q_times(res, b)
    dense = q[6 * n:, 6 * n:] @ b.reshape(3 * m, 4)
    assert np.allclose(qb.reshape(3 * m, 4), dense, rtol=1e-9, atol=1e-12 * np.abs(dense).max())
    # S^-1 Z' B is minus the images' cross block of the inverse times B: Q_ep B
    assert np.allclose(q[:6 * n, 6 * n:] @ b.reshape(3 * m, 4), -s_ztb, rtol=1e-8,
                       atol=1e-12 * np.abs(s_ztb).max())
