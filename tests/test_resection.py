"""B. Dewitt's space resection example (docs/method.md section 8) through the bundle adjustment.

The five control points are held by very heavy priors (1 micrometre), so the bundle
reduces to a resection with 10 - 6 = 4 degrees of freedom; unit weights on the photo
coordinates make sigma0 come out in millimetres as in the published solution.
"""

import numpy as np
import pytest

from vectoradjust.adjust.bundle import BundleProblem, adjust


def _load(dewitt_dir):
    lines = (dewitt_dir / "resect.dat").read_text().split("\n")
    f = float(lines[0])
    rows = [r.split() for r in lines[1:] if r.strip()]
    xy = np.array([[float(r[1]), float(r[2])] for r in rows])
    xyz = np.array([[float(v) for v in r[3:6]] for r in rows])
    return f, [r[0] for r in rows], xy, xyz


@pytest.fixture(scope="module")
def resection(dewitt_dir):
    f, ids, xy, xyz = _load(dewitt_dir)
    m = len(ids)
    eo0 = np.array([[xyz[:, 0].mean(), xyz[:, 1].mean(), 600.0, 0.0, 0.0, np.radians(90.0)]])
    prob = BundleProblem(f, (0, 0), eo0, np.full((1, 6), np.inf), xyz, xyz,
                         np.tile(np.eye(3) / 1e-6**2, (m, 1, 1)), np.arange(m), np.zeros(m, int),
                         xy, np.ones((m, 2)))
    return adjust(prob, max_iterations=30, tolerance_position=1e-7, tolerance_angle=1e-11)


def test_exterior_orientation_to_published_digits(resection):
    eo = resection.eo[0]
    assert np.degrees(eo[3:]) == pytest.approx([-0.4109, 1.2108, 102.8003], abs=6e-5)
    assert eo[:3] == pytest.approx([1027.8700, 1044.1143, 611.1973], abs=6e-5)


def test_sigma0_dof_and_residuals(resection):
    assert resection.dof == 4
    assert np.sqrt(resection.sigma0_squared) == pytest.approx(0.00282, abs=6e-6)
    expected = np.array([[.0014, -.0014], [.0006, .0030], [.0015, .0009], [-.0030, .0001],
                         [-.0005, -.0025]])
    assert resection.v_image == pytest.approx(expected, abs=6e-5)


def test_standard_deviations_of_eo(resection):
    sd = np.sqrt(np.diag(resection.eo_cov[0]))
    assert np.degrees(sd[3:]) == pytest.approx([0.00136, 0.00135, 0.00063], abs=6e-6)
    assert sd[:3] == pytest.approx([0.0197, 0.0197, 0.0071], abs=6e-5)
