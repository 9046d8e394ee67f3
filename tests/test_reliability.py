"""Reliability statistics: redundancy numbers, Baarda's w-test, MDB, data snooping.

Truths used: the published redundancy numbers of Dewitt's resection; a brute-force dense
``Q_vv = P^-1 - A (A'PA)^-1 A'``; the trace identity ``sum r = n - u``; the normal
quantiles; and Monte Carlo on simulations (the w of a correct model is N(0, 1), and a
blunder is flagged as often as the noncentral normal distribution says).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg

from vectoradjust.adjust.bundle import BundleProblem, adjust
from vectoradjust.adjust.reliability import (
    critical_value,
    data_snooping,
    detection_power,
    flagged_observations,
    noncentrality,
    reliability,
)
from vectoradjust.sensor.collinearity import project, rotation_matrix
from vectoradjust.simulate import DatabaseModel, make_scenario


# --------------------------------------------------------------------------- fixtures
def _dewitt_problem(dewitt_dir):
    lines = (dewitt_dir / "resect.dat").read_text().split("\n")
    f = float(lines[0])
    rows = [r.split() for r in lines[1:] if r.strip()]
    xy = np.array([[float(r[1]), float(r[2])] for r in rows])
    xyz = np.array([[float(v) for v in r[3:6]] for r in rows])
    m = len(rows)
    eo0 = np.array([[xyz[:, 0].mean(), xyz[:, 1].mean(), 600.0, 0.0, 0.0, np.radians(90.0)]])
    return BundleProblem(f, (0, 0), eo0, np.full((1, 6), np.inf), xyz, xyz,
                         np.tile(np.eye(3) / 1e-6**2, (m, 1, 1)), np.arange(m),
                         np.zeros(m, int), xy, np.ones((m, 2)))


@pytest.fixture(scope="module")
def dewitt(dewitt_dir):
    return adjust(_dewitt_problem(dewitt_dir), max_iterations=30, tolerance_position=1e-7,
                  tolerance_angle=1e-11)


IID = DatabaseModel("IID", "iid_id", "iid", 20.0, 0.4, (0.0, 0.0), 0.0, 0.0, 3.0)


def _iid_run(seed, **kw):
    """Pipeline run of a simulation whose stochastic model is the true one."""
    from vectoradjust.pipeline import run

    sc = make_scenario(seed, databases=(IID,), **kw)
    data = sc.to_project_data()
    data.settings.reweight = "none"
    spec, layer = data.vectors[0]
    sz = float(np.sqrt(np.mean((layer.coords[:, 2] - sc.truth["IID"][1][:, 2]) ** 2)))
    data.vectors[0] = (replace(spec, sigma=(3.0, 3.0, sz)), layer)
    return run(data)


@pytest.fixture(scope="module")
def small_block():
    """Three images, few points, a full 3x3 covariance on some control points."""
    out = _iid_run(1, n_images=3, n_control=8, n_check=1, n_tie=6, grid=(2, 2))
    prob = out.problem
    w = prob.prior_weight.copy()
    ctrl = np.flatnonzero(out.point_kind == "control")[:4]
    rng = np.random.default_rng(5)
    for j in ctrl:
        a = rng.normal(0.0, 0.03, (3, 3))
        cov = a @ a.T + np.diag([0.05, 0.05, 0.08]) ** 2
        w[j] = np.linalg.inv(cov)
    prob = replace(prob, prior_weight=w)
    res = adjust(prob)
    return res, reliability(res), _dense(res)


def _dense(res):
    """Brute force: A, P, N = A'PA, N^-1 (Jacobi-scaled), Q_vv; all observations."""
    prob = res.problem
    n, m, k = prob.n_images, prob.n_points, len(prob.obs_point)
    u = 6 * n + 3 * m
    a_img = np.zeros((2 * k, u))
    for q in range(k):
        i, j = prob.obs_image[q], prob.obs_point[q]
        a_img[2 * q:2 * q + 2, 6 * i:6 * i + 6] = res.a_eo[q]
        a_img[2 * q:2 * q + 2, 6 * n + 3 * j:6 * n + 3 * j + 3] = res.a_pt[q]
    hp = np.flatnonzero(prob.has_prior)
    a_pt = np.zeros((3 * len(hp), u))
    for t, j in enumerate(hp):
        a_pt[3 * t:3 * t + 3, 6 * n + 3 * j:6 * n + 3 * j + 3] = np.eye(3)
    we = prob.eo_weight.ravel()
    he = np.flatnonzero(we > 0)
    a_eo = np.zeros((len(he), u))
    a_eo[np.arange(len(he)), he] = 1.0
    a = np.vstack([a_img, a_pt, a_eo])
    p = scipy.linalg.block_diag(np.diag(1.0 / prob.obs_sigma.ravel() ** 2),
                                *[prob.prior_weight[j] for j in hp], np.diag(we[he]))
    nn = a.T @ p @ a
    d = 1.0 / np.sqrt(np.diag(nn))
    ninv = d[:, None] * np.linalg.inv(d[:, None] * nn * d[None, :]) * d[None, :]
    qvv = np.linalg.inv(p) - a @ ninv @ a.T
    return dict(k=k, hp=hp, he=he, p=p, qvv=qvv, ninv=ninv, n=n, a=a)


# --------------------------------------------------------------------------- constants
def test_critical_value_and_delta0_are_the_published_numbers():
    assert critical_value(0.001) == pytest.approx(3.2905, abs=5e-5)
    assert critical_value(0.05) == pytest.approx(1.9600, abs=5e-5)
    assert noncentrality(0.001, 0.2) == pytest.approx(4.1321, abs=5e-5)  # docs/method.md section 3
    # Baarda's classical pair alpha0 = 0.001, beta0 = 0.20 -> delta0 = 4.13; power at delta0
    assert float(detection_power(noncentrality(0.001, 0.2))) == pytest.approx(0.8, abs=1e-4)


# --------------------------------------------------------------------------- Dewitt
def test_dewitt_redundancy_numbers(dewitt):
    rel = reliability(dewitt)
    expected = [.3288, .3311, .3288, .3424, .2909, .3579, .3853, .2991, .6670, .6687]
    assert rel.r_image.ravel() == pytest.approx(expected, abs=6e-5)
    assert rel.sum_r == pytest.approx(4.0, abs=1e-9)
    assert rel.dof == 4
    # the 1e-6 m priors are not controlled: untested, never flagged
    assert np.all(rel.r_point < 1e-6)
    assert np.all(np.isnan(rel.w_point)) and not rel.flag_point.any()


def test_dewitt_w_and_mdb_from_their_definitions(dewitt):
    rel = reliability(dewitt, sigma0=0.00282)  # unit weights: sigma0 in mm
    v = dewitt.v_image
    qvv = rel.r_image * 1.0  # sigma_i = 1 (unit weights): qvv = r sigma^2
    assert rel.qvv_image == pytest.approx(qvv, rel=1e-12)
    assert rel.w_image == pytest.approx(v / (0.00282 * np.sqrt(rel.r_image)), rel=1e-12)
    assert rel.mdb_image == pytest.approx(4.1321 * 0.00282 / np.sqrt(rel.r_image), rel=2e-5)
    assert not rel.flag_image.any()


# --------------------------------------------------------------------------- vs dense
def test_qvv_matches_a_dense_computation(small_block):
    res, rel, d = small_block
    k, hp, he = d["k"], d["hp"], d["he"]
    q = np.diag(d["qvv"])
    var = res.problem.obs_sigma**2
    # image observations: to 1e-9 of their variance (qvv = r sigma^2 spans 1e-8 .. 0.8)
    assert np.max(np.abs(q[:2 * k].reshape(k, 2) - rel.qvv_image) / var) < 1e-9
    big = rel.r_image > 1e-3
    assert rel.qvv_image[big] == pytest.approx(q[:2 * k].reshape(k, 2)[big], rel=1e-9)
    # redundancy numbers (Q_vv P)_ii of every kind
    r = np.einsum("ij,ji->i", d["qvv"], d["p"])
    assert rel.r_image.ravel() == pytest.approx(r[:2 * k], abs=1e-9)
    assert rel.r_point[hp].ravel() == pytest.approx(r[2 * k:2 * k + 3 * len(hp)], abs=1e-9)
    assert rel.r_eo.ravel()[he] == pytest.approx(r[2 * k + 3 * len(hp):], abs=1e-9)
    # point cofactors = diagonal 3x3 blocks of N^-1
    n = d["n"]
    for j in range(res.problem.n_points):
        blk = d["ninv"][6 * n + 3 * j:6 * n + 3 * j + 3, 6 * n + 3 * j:6 * n + 3 * j + 3]
        assert rel.q_point[j] == pytest.approx(blk, rel=1e-8, abs=1e-14)


def test_w_of_correlated_priors_is_baardas_general_form(small_block):
    """w = c'Pv / sqrt(c'P Q_vv P c) for a GCP with a full covariance."""
    res, rel, d = small_block
    k, hp = d["k"], d["hp"]
    sl = slice(2 * k, 2 * k + 3 * len(hp))
    p = d["p"][sl, sl]
    pqp = np.diag(p @ d["qvv"][sl, sl] @ p)
    pv = p @ res.v_point[hp].ravel()
    full = np.abs(res.problem.prior_weight[hp][:, 0, 1]) > 0
    assert full.sum() == 4
    w = (pv / np.sqrt(pqp)).reshape(-1, 3)
    assert rel.w_point[hp] == pytest.approx(w, rel=1e-7)
    assert rel.mdb_point[hp] == pytest.approx(rel.delta0 / np.sqrt(pqp).reshape(-1, 3),
                                              rel=1e-7)


def test_redundancy_numbers_sum_to_the_degrees_of_freedom():
    """The sample-like scenario: 3 databases, 2 images, EO priors (trace identity)."""
    from vectoradjust.pipeline import run

    out = run(make_scenario(3).to_project_data())
    rel = reliability(out.result)
    assert rel.sum_r == pytest.approx(out.result.dof, abs=1e-6 * out.result.dof)
    assert np.all(rel.r_image > -1e-9) and np.all(rel.r_image < 1 + 1e-9)
    assert np.all(np.nan_to_num(rel.r_point) > -1e-9)


# --------------------------------------------------------------------------- Monte Carlo
def test_w_is_standard_normal_when_the_model_is_right():
    """Image coordinates and point priors of 8 simulations with their true sigmas."""
    w = []
    for seed in range(8):
        rel = reliability(_iid_run(seed).result)
        for a in (rel.w_image, rel.w_point):
            w.append(a[np.isfinite(a)])
    w = np.concatenate(w)
    assert w.size > 10000
    assert np.mean(w**2) == pytest.approx(1.0, abs=0.06)
    assert np.mean(np.abs(w) > 1.959964) == pytest.approx(0.05, abs=0.01)
    assert np.mean(np.abs(w) > 2.575829) == pytest.approx(0.01, abs=0.005)


F_RC10 = 152.4
SIG = 0.015


def _resection(seed, n_points=5):
    """A simulated single-image resection: 5 control points held fixed (10 tested obs)."""
    rng = np.random.default_rng([seed, 4242])
    eo = np.r_[rng.normal(0.0, 3.0, 2), 797.6 + rng.normal(0.0, 1.5),
               np.radians(rng.normal(0.0, 0.3, 3))]
    xy = rng.uniform(-100.0, 100.0, (n_points, 2))
    z = 188.0 + rng.normal(0.0, 3.0, n_points)
    d = np.column_stack([xy, np.full(n_points, -F_RC10)]) @ rotation_matrix(*eo[3:])
    xyz = eo[:3] + ((z - eo[2]) / d[:, 2])[:, None] * d
    obs = project(np.tile(eo, (n_points, 1)), xyz, F_RC10) + rng.normal(0.0, SIG, (n_points, 2))
    eo0 = np.r_[np.round(eo[:3]), 0.0, 0.0, 0.0]
    return BundleProblem(F_RC10, (0.0, 0.0), eo0[None], np.full((1, 6), np.inf), xyz, xyz,
                         np.tile(np.eye(3) / 1e-6**2, (n_points, 1, 1)), np.arange(n_points),
                         np.zeros(n_points, int), obs, np.full((n_points, 2), SIG))


@pytest.mark.slow
def test_blunder_detection_and_false_alarms_match_theory():
    """5-sigma blunders in each of the 10 coordinates of 60 resections; 300 clean runs.

    What is achievable: with r ~ 0.4 a 5-sigma blunder shifts w by 5 sqrt(r) ~ 3.2 and is
    flagged about 44 % of the time (the 95 % aim needs r >= 0.975; see
    validation/blunder_detection.py). The measured rate must equal the rate the
    noncentral normal distribution predicts from each observation's redundancy number
    (4 binomial standard errors), and >= 97 % of clean runs (10 tested coordinates,
    alpha0 = 0.001 each: about 99 % expected) must have no flag. A w without sqrt(r)
    detects ~16 %, Pope's tau against the normal critical value 0 %, a w divided by r
    instead of sqrt(r) leaves ~40 % of clean runs unflagged: each fails here.
    """
    clean = sum(reliability(adjust(_resection(s))).n_flagged == 0 for s in range(300))
    assert clean / 300 >= 0.97, clean
    hits, theory, n = 0, 0.0, 0
    for s in range(60):
        prob = _resection(s)
        r0 = reliability(adjust(prob)).r_image
        for c in range(10):
            k, a = divmod(c, 2)
            xy = prob.obs_xy.copy()
            xy[k, a] += 5 * SIG
            rel = reliability(adjust(replace(prob, obs_xy=xy)))
            hits += bool(rel.flag_image[k, a])
            theory += float(detection_power(5 * math.sqrt(r0[k, a])))
            n += 1
    rate, expect = hits / n, theory / n
    se = math.sqrt(expect * (1 - expect) / n)
    assert 0.35 < expect < 0.55  # the scenario is what the docstring says
    assert abs(rate - expect) < 4 * se, (rate, expect)


# --------------------------------------------------------------------------- reports
@pytest.fixture(scope="module")
def blundered():
    """Scenario with a 20-sigma blunder in the y of a shape point on image 0 and a
    30-sigma blunder in the y of a tie point."""
    out = _iid_run(2)
    prob = out.problem
    kind = out.point_kind[prob.obs_point]
    ks = int(np.flatnonzero((kind == "shape") & (prob.obs_image == 0))[7])
    kt = int(np.flatnonzero(kind == "tie")[3])
    xy = prob.obs_xy.copy()
    xy[ks, 1] += 20 * SIG
    xy[kt, 1] -= 30 * SIG
    return out, replace(prob, obs_xy=xy), ks, kt


def test_flagged_observations_report(blundered):
    out, prob, ks, kt = blundered
    res = adjust(prob)
    rel = reliability(res)
    rows = flagged_observations(rel, res, out.point_ids, out.image_ids, out.point_kind)
    json.dumps(rows)  # JSON-ready
    assert len(rows) == rel.n_flagged >= 2
    ws = [abs(r["w"]) for r in rows]
    assert ws == sorted(ws, reverse=True)
    assert all(w > rel.critical for w in ws)
    shape = [r for r in rows if r["observation"] == ks and r["component"] == "y"]
    assert len(shape) == 1
    r = shape[0]
    assert r["kind"] == "image" and r["unit"] == "um" and r["point_kind"] == "shape"
    assert r["image"] == out.image_ids[0]
    assert r["point"] == out.point_ids[prob.obs_point[ks]]
    # the estimated blunder -v/r is the planted +300 um within 4 sd (sd = sigma / sqrt(r))
    assert r["suspected_error"] == pytest.approx(300.0, abs=4 * 15.0 / math.sqrt(
        r["redundancy"]))
    assert r["residual"] == pytest.approx(1000 * res.v_image[ks, 1])
    assert r["mdb"] == pytest.approx(1000 * rel.delta0 * SIG / math.sqrt(r["redundancy"]))


def test_data_snooping_removes_the_blunders(blundered):
    out, prob, ks, kt = blundered
    sn = data_snooping(prob)
    assert sn.clean
    assert not sn.reliability.flag_image.any()
    removed = {d["observation"] for d in sn.removed}
    jt = int(prob.obs_point[kt])
    # the tie point is seen on two images: whichever of its measurements goes, the point
    # is left on one image and is dropped with its other measurement
    tie_rec = [d for d in sn.removed if d["point"] == jt]
    assert len(tie_rec) == 1 and tie_rec[0]["dropped_points"] == [jt]
    tie_obs = set(np.flatnonzero(prob.obs_point == jt).tolist())
    assert {tie_rec[0]["observation"], *tie_rec[0]["dropped_observations"]} == tie_obs
    js = int(prob.obs_point[ks])
    assert any(d["point"] == js for d in sn.removed)
    assert all(abs(d["w"]) > sn.reliability.critical for d in sn.removed)
    assert len(sn.removed) <= 4
    # index mapping: the final problem is the original minus the removed measurements
    gone = removed | {o for d in sn.removed for o in d["dropped_observations"]}
    assert sorted(set(range(len(prob.obs_point))) - gone) == sn.observation_index.tolist()
    assert np.array_equal(sn.problem.obs_xy, prob.obs_xy[sn.observation_index])
    assert np.array_equal(sn.point_index[sn.problem.obs_point],
                          prob.obs_point[sn.observation_index])
    assert jt not in sn.point_index.tolist()
    assert sn.result.dof == sn.result.n_obs - sn.result.n_unknowns
    assert sn.iterations == len(sn.removed) + 1
    json.dumps(sn.removed)


def test_data_snooping_limit(blundered):
    _, prob, _, _ = blundered
    sn = data_snooping(prob, max_removals=1)
    assert len(sn.removed) == 1 and not sn.clean
    assert sn.reliability.flag_image.any()
    # the first removal is the measurement with the largest |w| of the first adjustment
    rel = reliability(adjust(prob))
    k = int(np.nanargmax(np.abs(rel.w_image))) // 2
    assert sn.removed[0]["observation"] == k


def test_distribution_functions_agree_with_scipy_stats():
    # the core computes these with scipy.special (scipy.stats is slow to import);
    # scipy.stats is the independent definition here
    from scipy import stats as st

    from vectoradjust.accuracy.propagate import confidence_scale
    from vectoradjust.adjust.reliability import critical_value, detection_power, noncentrality

    for a in (0.001, 0.01, 0.05):
        assert critical_value(a) == pytest.approx(st.norm.ppf(1 - a / 2), rel=1e-14)
        assert noncentrality(a, 0.2) == pytest.approx(
            st.norm.ppf(1 - a / 2) + st.norm.ppf(0.8), rel=1e-14)
    s = np.linspace(0, 8, 17)
    k = st.norm.ppf(1 - 0.0005)
    np.testing.assert_allclose(detection_power(s), st.norm.cdf(s - k) + st.norm.cdf(-s - k),
                               rtol=1e-13)
    for dof in (1, 2, 3, 7):
        for q in (0.9, 0.95, 0.99):
            assert confidence_scale(q, dof) == pytest.approx(np.sqrt(st.chi2.ppf(q, dof)),
                                                             rel=1e-13)
