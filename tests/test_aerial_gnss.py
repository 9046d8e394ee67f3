"""GCP-free orientation of the real NGI DMC frames (issue 29): GNSS/INS-like priors and
automatic tie points agree with the survey's orientation (validation/aerial_gnss.py).

Two seeds of the validation script's procedure: the survey's orientation perturbed by
0.1 m and 0.01 degrees, tie points measured from it (measure/ties.py), the bundle
adjustment with those priors and the ties, the adjusted orientation against the survey's
within the adjustment's own sigmas. Skips when ``../shared/data/aerial/ngi_dmc`` is absent.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "aerial" / "ngi_dmc"

pytestmark = pytest.mark.io


@pytest.fixture(scope="module")
def script():
    if not (DATA / "camera_pos_ori.txt").is_file():
        pytest.skip(f"NGI DMC frames not found: {DATA}")
    pytest.importorskip("rasterio")
    sys.path.insert(0, str(ROOT / "validation"))
    try:
        import aerial_gnss
    finally:
        sys.path.remove(str(ROOT / "validation"))
    return aerial_gnss


@pytest.fixture(scope="module")
def block(script):
    return script.read_block(DATA)


@pytest.fixture(scope="module")
def runs(script, block):
    sigma = script.prior_sigma(0.1, 0.01)
    return [script.run_seed(block, seed, sigma, spacing=32) for seed in (0, 1)]


def test_survey_angles_are_ours_unchanged(script, block):
    """orthority's R = Rx(omega) Ry(phi) Rz(kappa) (camera to world) is our M'."""
    from vectoradjust.sensor.collinearity import rotation_matrix

    def rx(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    def ry(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    for o, p, k in block.eo[:, 3:]:
        assert np.allclose(rotation_matrix(o, p, k), (rx(o) @ ry(p) @ rz(k)).T, atol=1e-12)
    assert block.camera.pixel_size == pytest.approx((0.144, 0.144))
    assert block.camera.focal_length == 120.0 and block.camera.image_size == (640, 1152)


def test_ties_connect_every_overlapping_pair(runs):
    for r in runs:
        assert min(r["pairs"].values()) >= 10  # measured 14-122
        assert r["back_median"] <= 0.1  # measured 0.045
        assert r["tie_sigma_px"] <= 0.1  # measured 0.057


def test_orientation_agrees_with_the_survey_within_its_sigma(script, runs):
    z = np.array([r["z"] for r in runs])
    assert np.mean(np.abs(z) < 1.96) >= 0.85  # measured 0.94 (seeds 0, 1)
    assert np.sqrt(np.mean(z ** 2)) <= 1.5  # measured 1.01
    crit = script.criteria(runs)
    assert crit.passed, "\n".join(c.line() for c in crit.items if not c.passed)


def test_ties_improve_the_relative_attitude(script, runs):
    d = np.array([r["diff"] for r in runs])
    pd = np.array([r["prior_diff"] for r in runs])
    assert script.relative_rms(d) < 0.8 * script.relative_rms(pd)  # measured 3.8 vs 5.9
    # the priors fix the positions: adjusted sigmas close to the prior's 0.1 m, and the
    # attitude sigmas smaller than the prior's 0.01 degrees
    s = np.array([r["sigma"] for r in runs])
    assert np.all((s[..., :3] > 0.07) & (s[..., :3] <= 0.105))
    assert np.all(np.degrees(s[..., 3:]) < 0.0065)
