"""Transfer search windows between frame images (issue 28): the terrain height's error
moves the target along the epipolar line (:func:`height_parallax`), and the windows hold
the homologous point over draws of the orientations, the DEM and the pointing."""

from __future__ import annotations

import numpy as np

from vectoradjust.files.measuring import height_parallax, transfer_window
from vectoradjust.measure.geometry import WINDOW_K, ImageGeometry, inv2
from vectoradjust.simulate.render import camera

SIG = np.r_[np.full(3, 0.5), np.radians(np.full(3, 0.02))]


def _pair():
    """Two 1500 px wide-angle frames (50 mm, 0.04 mm pixels) 300 m up, 120 m apart."""
    cam = camera(1500, pixel_size=0.04, focal_length=50.0, distortion=True)
    rng = np.random.default_rng(5)
    return {iid: ImageGeometry(iid, np.r_[500000.0 + dx, 4400000.0, 500.0,
                                          np.radians(rng.normal(0, 1.0, 3))], cam)
            for iid, dx in (("L", -60.0), ("R", 60.0))}


def _height(xy):
    xy = np.asarray(xy, float).reshape(-1, 2)
    return 200.0 + 5.0 * np.sin(xy[:, 0] / 40.0) * np.cos(xy[:, 1] / 55.0)


def test_height_parallax_runs_along_the_epipolar_line():
    g = _pair()
    # a point below R's projection centre: moved vertically it would not move on R at all
    below_r = np.array([[g["R"].eo[0], g["R"].eo[1], 0.0]])
    below_r[0, 2] = _height(below_r[:, :2])[0]
    ref = g["L"].to_pixel(below_r)
    par = height_parallax(g["L"], g["R"], ref, _height)
    # 1 m along L's ray: about base / height * focal / pixel / height = 1.67 px on R
    assert 1.4 < np.hypot(*par[0]) < 1.9, par
    assert abs(par[0, 0]) > 5 * abs(par[0, 1])  # along the base (east-west)
    up = g["R"].to_pixel(g["L"].to_ground(ref, lambda xy: _height(xy) + 1.0))
    down = g["R"].to_pixel(g["L"].to_ground(ref, lambda xy: _height(xy) - 1.0))
    assert np.allclose(par, 0.5 * (up - down), atol=1e-9)


def test_transfer_windows_hold_the_homologous_point():
    """20 draws of both orientations (0.5 m, 0.02 deg), a DEM error (2 m) and 0.5 px of
    pointing: at least 99 % of 4000 homologous points inside the window, and the window
    is not far larger than it needs to be (at least 70 % inside the 90 % ellipse)."""
    true = _pair()
    rng = np.random.default_rng(28)
    ref0 = np.c_[rng.uniform(500, 1000, 200), rng.uniform(100, 1400, 200)]
    inside, in90 = [], []
    for _ in range(20):
        g = {k: ImageGeometry(k, t.eo + rng.normal(0, 1, 6) * SIG, t.camera, sigma_eo=SIG)
             for k, t in true.items()}
        dh = rng.normal(0, 2.0)
        ref = ref0 + rng.normal(0, 0.5, ref0.shape)
        target = true["R"].to_pixel(true["L"].to_ground(ref, _height))
        pred, a, cov, cov_rays = transfer_window(g["L"], g["R"], ref,
                                                 lambda xy, dh=dh: _height(xy) + dh, 2.0, 0.5)
        assert np.all(np.linalg.eigvalsh(cov - cov_rays) > -1e-9)  # the height's part
        d = target - pred
        m2 = np.einsum("ni,nij,nj->n", d, inv2(cov + (0.5 / WINDOW_K) ** 2 * np.eye(2)), d)
        inside.append(m2 <= WINDOW_K**2)
        in90.append(m2 <= -2.0 * np.log(0.1))
    assert np.mean(inside) >= 0.99, np.mean(inside)
    assert np.mean(in90) >= 0.7, np.mean(in90)
