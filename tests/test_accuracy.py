"""Accuracy statements (vectoradjust.accuracy.statements) checked against their definitions.

Every expected value is recomputed here from the run's per-vertex arrays (or the raw
control/truth arrays) with the formulas of docs/method.md section 4, NSSDA and ASPRS 2023;
exact CE90/LE90 values are checked by their defining probability (Monte Carlo and the
normal CDF).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import norm

from vectoradjust.accuracy import stats
from vectoradjust.accuracy.statements import accuracy_statements
from vectoradjust.pipeline import run
from vectoradjust.simulate import make_scenario


@pytest.fixture(scope="module")
def adj_run():
    data = make_scenario(0).to_project_data()
    data.settings.reweight = "two-pass"
    return run(data)


@pytest.fixture(scope="module")
def acc(adj_run):
    return accuracy_statements(adj_run)


def _residuals(d):
    v = d.vertices
    adj = v["Adjusted"] == 1
    return np.column_stack([v["Vx"], v["Vy"], v["Vz"]])[adj].astype(float), adj


def _point_residuals(d):
    """Database level: each object point once (shared intersection vertices are one)."""
    from vectoradjust.accuracy.tables import one_vertex_per_point

    v = d.vertices
    adj = one_vertex_per_point(d.vertex_point)
    return np.column_stack([v["Vx"], v["Vy"], v["Vz"]])[adj].astype(float), adj


def _ager_formula(mu, sc):
    k = mu / sc
    if k <= 0.1:
        return 2.1460 * sc
    if k <= 3.0:
        return 2.1272 * sc + 0.1674 * mu + 0.3623 * mu**2 / sc - 0.0550 * mu**3 / sc**2
    return 0.9860 * mu + 1.4548 * sc


def _compass(az):
    names = ["north", "north-east", "east", "south-east", "south", "south-west", "west",
             "north-west"]
    return names[int(((az + 22.5) % 360) // 45)]


def test_json_ready(acc):
    text = json.dumps(acc, allow_nan=False)
    assert json.loads(text)["databases"]


def test_database_bias_is_mean_residual(adj_run, acc):
    assert [b["name"] for b in acc["databases"]] == [d.name for d in adj_run.databases]
    for d, b in zip(adj_run.databases, acc["databases"]):
        v, adj = _point_residuals(d)
        assert b["count"] == int(adj.sum()) == len(v)
        for a, key in enumerate(("vx", "vy", "vz")):
            assert b["residual_bias"][key] == pytest.approx(v[:, a].mean(), rel=1e-12,
                                                             abs=1e-12)
        # the statements are about database - adjusted = -V
        for a, key in enumerate("xyz"):
            assert b["mean_error"][key] == pytest.approx(-v[:, a].mean(), rel=1e-12, abs=1e-12)


def test_bias_direction_of_the_database(adj_run, acc):
    for d, b in zip(adj_run.databases, acc["databases"]):
        v, _ = _point_residuals(d)
        ex, ey = -v[:, 0].mean(), -v[:, 1].mean()
        az = math.degrees(math.atan2(ex, ey)) % 360.0
        assert b["bias"]["magnitude"] == pytest.approx(math.hypot(ex, ey))
        assert b["bias"]["azimuth"] == pytest.approx(az)
        assert b["bias"]["direction"] == _compass(az)
        assert b["bias"]["direction"] in b["bias"]["text"]
        assert b["bias"]["direction"] in b["bias"]["statement"]
    # the scenario's TIGER-like database is shifted by a large systematic bias
    tiger = next(b for b in acc["databases"] if b["name"] == "TIGER")
    assert tiger["bias"]["magnitude"] > 5.0


def test_nssda_and_asprs_from_rmse(adj_run, acc):
    for d, b in zip(adj_run.databases, acc["databases"]):
        v, adj = _point_residuals(d)
        rx, ry, rz = np.sqrt(np.mean(v**2, axis=0))
        rr = math.hypot(rx, ry)
        ns = b["nssda"]
        assert ns["rmse_r"] == pytest.approx(rr, rel=1e-12)
        assert ns["horizontal_95_1_7308_rmse_r"] == pytest.approx(1.7308 * rr, rel=1e-12)
        assert ns["vertical_95"] == pytest.approx(1.9600 * rz, rel=1e-12)
        ratio = min(rx, ry) / max(rx, ry)
        if 0.6 < ratio < 1.0:  # NSSDA's Greenwalt-Schultz rule for unequal RMSE_x, RMSE_y
            assert ns["horizontal_95"] == pytest.approx(2.4477 * 0.5 * (rx + ry), rel=1e-12)
        # ASPRS 2023: the adjusted points' own precision is the checkpoint accuracy
        sig = np.column_stack([d.vertices["SigmaX"], d.vertices["SigmaY"],
                               d.vertices["SigmaZ"]])[adj]
        ref_h = math.sqrt(np.mean(sig[:, 0] ** 2 + sig[:, 1] ** 2))
        ref_v = math.sqrt(np.mean(sig[:, 2] ** 2))
        ap = b["asprs2023"]
        assert ap["rmse_h_data"] == pytest.approx(rr, rel=1e-12)
        assert ap["rmse_h"] == pytest.approx(math.hypot(rr, ref_h), rel=1e-12)
        assert ap["rmse_v"] == pytest.approx(math.hypot(rz, ref_v), rel=1e-12)
        assert ap["rmse_3d"] == pytest.approx(math.hypot(ap["rmse_h"], ap["rmse_v"]), rel=1e-12)
        assert f"{ap['rmse_h']:.3f}" in ap["statement_h"]
        assert ap["min_checkpoints_met"] == (len(v) >= 30)
        # and they agree with the run's own RMSE summary
        s = next(x for x in adj_run.summary["databases"] if x["name"] == d.name)
        assert s["residuals"]["rmse_horizontal"] == pytest.approx(rr, rel=1e-9)


def test_ager_ce90_le90_formula_and_exact(adj_run, acc):
    rng = np.random.default_rng(7)
    for d, b in zip(adj_run.databases, acc["databases"]):
        v, _ = _point_residuals(d)
        e = -v
        mean = e.mean(axis=0)
        cov = np.cov(e[:, :2], rowvar=False, ddof=1)
        lam = np.linalg.eigvalsh(cov)
        sc = 0.5 * (math.sqrt(lam[0]) + math.sqrt(lam[1]))
        mu = math.hypot(mean[0], mean[1])
        ag = b["ager"]
        assert ag["sigma_c"] == pytest.approx(sc, rel=1e-9)
        assert ag["mu"] == pytest.approx(mu, rel=1e-9)
        assert ag["ce90_formula"] == pytest.approx(_ager_formula(mu, sc), rel=1e-9)
        # exact CE90: 90 % of N(mean, cov) within the radius (Monte Carlo, 4e5 draws:
        # sd of the share 4.7e-4)
        x = rng.multivariate_normal(mean[:2], cov, size=400_000)
        share = np.mean(np.hypot(x[:, 0], x[:, 1]) <= ag["ce90_exact"])
        assert share == pytest.approx(0.9, abs=0.0025)
        # exact LE90 with the vertical bias, from the normal CDF
        sz = np.std(e[:, 2], ddof=1)
        r = ag["le90_exact"]
        p = norm.cdf((r - mean[2]) / sz) - norm.cdf((-r - mean[2]) / sz)
        assert p == pytest.approx(0.9, abs=1e-9)
        k = abs(mean[2]) / sz
        assert k <= 1.4
        le_f = abs(mean[2]) + sz * (1.6435 - 0.999556 * k + 0.923237 * k**2 - 0.282533 * k**3)
        assert ag["le90_formula"] == pytest.approx(le_f, rel=1e-9)
        assert ag["ce90_rule"] and ag["le90_rule"]


def test_check_points_are_adjusted_minus_surveyed(adj_run, acc):
    cp = adj_run.control_points
    ctrl = adj_run.data.control
    chk = (ctrl.role == "check") & (cp["Used"] == 1)
    e = np.column_stack([cp["AdjX"], cp["AdjY"], cp["AdjZ"]])[chk] - ctrl.xyz[chk]
    c = acc["check_points"]
    assert c["count"] == int(chk.sum()) > 0
    assert c["point_ids"] == [str(p) for p in ctrl.point_id[chk]]
    for a, key in enumerate("xyz"):
        assert c["mean_error"][key] == pytest.approx(e[:, a].mean(), rel=1e-9, abs=1e-12)
    rx, ry, rz = np.sqrt(np.mean(e**2, axis=0))
    assert c["rmse"]["horizontal"] == pytest.approx(math.hypot(rx, ry), rel=1e-9)
    assert c["nssda"]["vertical_95"] == pytest.approx(1.96 * rz, rel=1e-9)
    assert c["nssda"]["horizontal_95_1_7308_rmse_r"] == pytest.approx(
        1.7308 * math.hypot(rx, ry), rel=1e-9)
    # ASPRS: the survey sigmas of the check points added in quadrature
    sh = math.sqrt(np.mean(ctrl.sigma[chk, 0] ** 2 + ctrl.sigma[chk, 1] ** 2))
    assert c["asprs2023"]["rmse_h"] == pytest.approx(math.hypot(math.hypot(rx, ry), sh))
    assert c["asprs2023"]["min_checkpoints_met"] is (int(chk.sum()) >= 30)
    assert adj_run.summary["check_points"]["rmse_horizontal"] == pytest.approx(
        c["rmse"]["horizontal"], rel=1e-9)


def test_truth_block_is_database_minus_truth(adj_run, acc):
    for d, b in zip(adj_run.databases, acc["databases"]):
        tid, txyz = adj_run.data.truth[d.name]
        pos = {str(p): i for i, p in enumerate(tid)}
        _, adj = _point_residuals(d)
        idx = np.array([pos[str(p)] for p in d.vertices["point_id"][adj]])
        db = np.column_stack([d.vertices["X"], d.vertices["Y"]])[adj]
        err = db - txyz[idx, :2]
        t = b["truth"]
        assert t["count"] == int(adj.sum())
        assert t["rmse_horizontal"] == pytest.approx(
            math.sqrt(np.mean(np.sum(err**2, axis=1))), rel=1e-9)
        assert t["rmse_horizontal"] == pytest.approx(
            d.truth["rmse_database_truth_horizontal"], rel=1e-9)
        # the residual-based statement recovers the true database accuracy
        assert b["ager"]["ce90_exact"] == pytest.approx(t["ce90_exact"], rel=0.1)


@pytest.mark.parametrize("k", [2, 5, 9])
def test_feature_rows_match_absolute_accuracy(adj_run, k):
    acc = accuracy_statements(adj_run, min_feature_vertices=k)
    assert acc["min_feature_vertices"] == k
    for d in adj_run.databases:
        rows = {r["feature_id"]: r for r in acc["features"][d.name]}
        v, adj = _residuals(d)
        fid = d.vertices["feature_id"][adj]
        nadj = np.asarray(d.features["NAdj"])
        expected = {str(f) for f, n in zip(d.shape.layer.feature_ids, nadj) if n >= k}
        assert set(rows) == expected
        for f in sorted(expected)[:12]:
            e = -v[fid == f]
            ref = stats.absolute_accuracy(e)
            r = rows[f]
            assert r["count"] == len(e)
            assert r["residual_bias"]["vx"] == pytest.approx(v[fid == f, 0].mean(), abs=1e-12)
            assert r["ager"]["ce90_exact"] == pytest.approx(ref.ce90_exact, rel=1e-9)
            assert r["ager"]["ce90_formula"] == pytest.approx(ref.ce90_formula, rel=1e-9)
            assert r["ager"]["le90_exact"] == pytest.approx(ref.le90_exact, rel=1e-9)
            assert r["rmse"]["horizontal"] == pytest.approx(ref.rmse_horizontal, rel=1e-12)
            ns = stats.nssda(ref.rmse_x, ref.rmse_y, ref.rmse_z)
            assert r["nssda"]["horizontal_95"] == pytest.approx(ns["horizontal_95"], rel=1e-9)
            assert r["nssda"]["vertical_95"] == pytest.approx(1.96 * ref.rmse_z, rel=1e-12)
            assert r["bias_text"].endswith(stats.bias_direction(ref.mean_x, ref.mean_y)[2])


def test_run_without_databases_or_check_points(adj_run):
    no_db = replace(adj_run, databases=[])
    acc = accuracy_statements(no_db)
    assert acc["databases"] == [] and acc["features"] == {}
    assert acc["check_points"]["count"] > 0
    cp = dict(adj_run.control_points)
    cp["Used"] = np.where(cp["role"] == "check", 0, cp["Used"])
    acc2 = accuracy_statements(replace(adj_run, control_points=cp))
    assert acc2["check_points"] is None


def test_truth_vertex_index_is_matched_once_and_follows_the_truth(adj_run):
    from vectoradjust.accuracy.tables import truth_vertex_index

    for d in adj_run.databases:
        tid, txyz = adj_run.data.truth[d.name]
        ti = truth_vertex_index(adj_run, d)
        # the definition: the truth row whose id is the vertex's id, -1 where none
        row = {str(t): i for i, t in enumerate(np.asarray(tid).astype(str))}
        want = [row.get(str(v), -1) for v in d.shape.vertex_ids]
        assert ti.tolist() == want and (ti >= 0).any()
        assert truth_vertex_index(adj_run, d) is ti  # kept, not matched again
        assert not ti.flags.writeable
        # another truth table (same ids, reversed order): matched again
        truth = adj_run.data.truth
        try:
            adj_run.data.truth = {**truth, d.name: (np.asarray(tid)[::-1].copy(), txyz[::-1])}
            again = truth_vertex_index(adj_run, d)
            assert again is not ti
            ok = ti >= 0
            np.testing.assert_array_equal(again[ok], len(tid) - 1 - ti[ok])
        finally:
            adj_run.data.truth = truth
