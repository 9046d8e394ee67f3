"""Collinearity equations and analytic partials against independent computations."""

import numpy as np
import pytest

from vectoradjust.sensor.collinearity import partials, project, rotation_matrix, rotation_to_angles


def _random_config(seed, k=200):
    rng = np.random.default_rng(seed)
    eo = np.column_stack([
        rng.normal(0, 200, k), rng.normal(0, 200, k), rng.normal(800, 50, k),
        rng.normal(0, 0.2, k), rng.normal(0, 0.2, k), rng.uniform(-np.pi, np.pi, k),
    ])
    xyz = np.column_stack([rng.normal(0, 300, k), rng.normal(0, 300, k), rng.normal(180, 20, k)])
    return eo, xyz


def test_rotation_matrix_is_orthonormal_and_matches_elementary_rotations():
    o, p, k = 0.3, -0.2, 1.1
    m = rotation_matrix(o, p, k)
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-15)
    assert np.isclose(np.linalg.det(m), 1.0)
    mo = np.array([[1, 0, 0], [0, np.cos(o), np.sin(o)], [0, -np.sin(o), np.cos(o)]])
    mp = np.array([[np.cos(p), 0, -np.sin(p)], [0, 1, 0], [np.sin(p), 0, np.cos(p)]])
    mk = np.array([[np.cos(k), np.sin(k), 0], [-np.sin(k), np.cos(k), 0], [0, 0, 1]])
    assert np.allclose(m, mk @ mp @ mo, atol=1e-15)
    assert np.allclose(rotation_to_angles(m), [o, p, k])


def test_projection_of_nadir_point_is_principal_point_and_scale_is_f_over_h():
    eo = np.array([1000.0, 2000.0, 800.0, 0, 0, 0])
    x = project(eo, [1000.0, 2000.0, 190.0], 152.4, (0.01, -0.02))
    assert np.allclose(x, [0.01, -0.02])
    x = project(eo, [1010.0, 2005.0, 190.0], 152.4)
    assert np.allclose(x, np.array([10.0, 5.0]) * 152.4 / 610.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_eo_partials_against_central_differences(seed):
    eo, xyz = _random_config(seed)
    f = 152.4
    a_eo, _ = partials(eo, xyz, f)
    for j in range(6):
        h = 1e-3 if j < 3 else 1e-7
        e1, e2 = eo.copy(), eo.copy()
        e1[:, j] += h
        e2[:, j] -= h
        num = (project(e1, xyz, f) - project(e2, xyz, f)) / (2 * h)
        scale = np.abs(num).max() + 1e-12
        assert np.abs(num - a_eo[:, :, j]).max() / scale < 1e-6, f"parameter {j}"


@pytest.mark.parametrize("seed", [0, 1])
def test_point_partials_against_central_differences(seed):
    eo, xyz = _random_config(seed)
    f = 152.4
    a_eo, a_pt = partials(eo, xyz, f)
    for j in range(3):
        x1, x2 = xyz.copy(), xyz.copy()
        x1[:, j] += 1e-3
        x2[:, j] -= 1e-3
        num = (project(eo, x1, f) - project(eo, x2, f)) / 2e-3
        assert np.abs(num - a_pt[:, :, j]).max() / np.abs(num).max() < 1e-6
    # d/dXA = -d/dXL (docs/method.md section 2)
    assert np.allclose(a_pt, -a_eo[:, :, :3])
