"""Self-calibration of the focal length, principal point and radial distortion (issue 29:
drone cameras whose calibration is only nominal)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.adjust import passes, selfcal
from vectoradjust.adjust.bundle import adjust
from vectoradjust.adjust.classify import BundleSetup
from vectoradjust.errors import ProjectError
from vectoradjust.files.project import parse_project
from vectoradjust.simulate.block import FOCAL_LENGTH, make_block

NAMES = ("f", "x0", "y0", "k1", "k2")


def _block(seed: int, df: float = 0.3, k1: float = 0.02):
    """A 3 x 5 block with GNSS positions (0.1 m); the camera file's focal length is
    ``df`` mm short and the lens adds ``k1`` mm of radial distortion at the frame's edge."""
    b = make_block(n_strips=3, images_per_strip=5, n_shape_points=400, n_control=8,
                   seed=seed, position_noise=0.1, attitude_noise=0.3, sigma_position=0.1,
                   sigma_attitude=1e9)
    p = b.problem
    r = float(np.sqrt((p.obs_xy ** 2).sum(axis=1)).max())
    rho2 = (p.obs_xy ** 2).sum(axis=1) / r ** 2
    obs = p.obs_xy + p.obs_xy / r * (k1 * rho2)[:, None]
    rng = np.random.default_rng(seed + 500)
    eo0 = b.true_eo.copy()
    eo0[:, :3] += rng.normal(0.0, 0.1, (p.n_images, 3))
    sig = np.tile([0.1] * 3 + [np.inf] * 3, (p.n_images, 1))
    prob = replace(p, focal_length=FOCAL_LENGTH - df, obs_xy=obs, eo0=eo0, eo_sigma=sig)
    m = prob.n_points
    setup = BundleSetup(problem=prob, point_ids=np.arange(m).astype(str),
                        point_kind=b.point_kind, point_database=np.full(m, ""), databases=[],
                        obs_rows=np.arange(len(obs)), img_used=np.arange(prob.n_images),
                        imap=np.arange(prob.n_images), db_prior=prob.prior_xyz.copy())
    return b, setup, np.array([df, 0.0, 0.0, k1, 0.0])


def _calibrate(setup):
    state = {"interior": selfcal.InteriorModel.build(NAMES, setup.problem)}
    res = passes._adjust_joint(setup, None, {}, lambda f, m: None, state)
    return res, state


def test_recovers_the_focal_length_and_distortion_with_honest_sigmas():
    """Monte Carlo over 15 blocks: the estimates scatter about the truth as their sigmas
    say (normalised errors with mean about 0 and RMS about 1), and the points' 90 %
    ellipsoids (the calibration's uncertainty included) hold about 90 % of them."""
    z, inside, total = [], 0, 0
    for seed in range(15):
        b, setup, truth = _block(seed)
        res, state = _calibrate(setup)
        sig = np.sqrt(np.diag(state["cofactor"]) * res.variance_factor)
        z.append((state["theta"] - truth) / sig)
        tie = np.flatnonzero(b.point_kind == "tie")[:20]
        d = res.xyz[tie] - b.true_xyz[tie]
        m2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(res.point_cov[tie]), d)
        inside += int((m2 < 6.251).sum())
        total += len(tie)
    z = np.array(z)
    assert np.abs(z.mean(axis=0)).max() < 0.6
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert (rms > 0.6).all() and (rms < 1.5).all(), rms
    assert 0.82 <= inside / total <= 0.97


def test_without_self_calibration_the_wrong_focal_length_shows():
    """The same block adjusted with the camera file's focal length: sigma0^2 above 1
    (the chi-square test of ~5000 degrees of freedom fails), 1 with self-calibration."""
    _, setup, _ = _block(0)
    plain = adjust(setup.problem)
    res, state = _calibrate(setup)
    assert plain.sigma0_squared > 1.2
    assert res.sigma0_squared == pytest.approx(1.0, abs=0.2)
    assert res.dof == plain.dof - 5
    assert state["theta"][0] == pytest.approx(0.3, abs=0.05)


def test_degenerate_parameters_are_left_out():
    n = np.diag([4.0, 9.0, 1.0])
    assert selfcal.determined_parameters(n).tolist() == [True, True, True]
    n[0, 1] = n[1, 0] = 6.0  # perfectly correlated with the second: one goes
    keep = selfcal.determined_parameters(n)
    assert keep.sum() == 2 and keep[2]
    assert selfcal.determined_parameters(np.zeros((2, 2))).tolist() == [False, False]


def test_project_key():
    raw = {"crs": "EPSG:32616", "camera": {"focal_length": 152.4},
           "images": [{"id": "L", "position": [0, 0, 800]}],
           "measurements": {"path": "m.csv"},
           "adjustment": {"self_calibration": ["k1", "f", "f"]}}
    assert parse_project(raw, base_dir=".").settings.self_calibration == ("k1", "f")
    raw["adjustment"]["self_calibration"] = ["focal"]
    with pytest.raises(ProjectError, match="self_calibration must be a list of f, x0"):
        parse_project(raw, base_dir=".")


def test_pipeline_reports_values_sigmas_and_correlations():
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    def lens(xy):
        xy = np.asarray(xy, float)
        return xy + xy / 110.0 * (0.03 * (xy ** 2).sum(axis=1) / 110.0 ** 2)[:, None]

    data = make_scenario(0, image_distortion=lens).to_project_data()
    data.settings.self_calibration = NAMES
    out = run(data)
    rec = out.summary["self_calibration"]
    assert rec["parameters"] == list(NAMES)
    assert set(rec["sigma"]) == set(NAMES) and all(s > 0 for s in rec["sigma"].values())
    corr = np.array(rec["correlation"])
    assert corr.shape == (5, 5) and np.allclose(np.diag(corr), 1.0)
    assert rec["values"]["f"] == pytest.approx(data.camera.focal_length + rec["corrections"]["f"])
