"""Tests of the simulated satellite imagery (vectoradjust.simulate.satellite).

Independent checks: the rigorous pushbroom model against its own inverse (image to ray,
ray to ground) and against plain geometry (rays of two images meet at the true point,
their convergence angle and the parallax of a height change give the base-to-height
ratio); the fitted RPC (evaluated by :class:`vectoradjust.sensor.rpc.RpcModel`, written
by someone else) against the pushbroom model on random points; the observations against
the true biased projection (noise statistics) and against
:func:`vectoradjust.sensor.rpc.biased_partials` (the bias definition); determinism.
Run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from vectoradjust.errors import ProjectError
from vectoradjust.sensor.rpc import BIAS_MODELS, biased_partials
from vectoradjust.simulate.satellite import (
    GroundPoints,
    SceneArea,
    biased_project,
    ecef_to_geodetic,
    fit_rpc,
    geodetic_to_ecef,
    image_domain,
    pushbroom_localize,
    pushbroom_project,
    pushbroom_ray,
    satellite_scenario,
    stereo_base_to_height,
    stereo_sensors,
)

LON, LAT, H = -87.0, 40.4, 200.0
H_RANGE = (-100.0, 500.0)


def _drift(n_images: int, size: float, seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, size, (n_images, 3, 2))


def _closest_points(p1, d1, p2, d2) -> np.ndarray:
    """Midpoints of the shortest segments between rays ``p + s d`` (unit ``d``)."""
    w = p1 - p2
    b = np.sum(d1 * d2, axis=1)
    d, e = np.sum(d1 * w, axis=1), np.sum(d2 * w, axis=1)
    den = 1.0 - b**2
    s1, s2 = (b * e - d) / den, (e - b * d) / den
    return 0.5 * ((p1 + s1[:, None] * d1) + (p2 + s2[:, None] * d2))


def test_geodesy_roundtrip():
    lon = np.array([-87.0, 10.0, 179.0, -120.0])
    lat = np.array([40.4, -60.0, 0.0, 85.0])
    h = np.array([200.0, -50.0, 600e3, 1000.0])
    back = ecef_to_geodetic(geodetic_to_ecef(lon, lat, h))
    assert np.allclose(back[0], lon, atol=1e-11)
    assert np.allclose(back[1], lat, atol=1e-11)
    assert np.allclose(back[2], h, atol=1e-6)
    # a known value: the equator at lon 0 is (a, 0, 0)
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [6378137.0, 0.0, 0.0], atol=1e-9)


def test_pushbroom_inverse_and_rays():
    sensors = stereo_sensors(LON, LAT, H, 2, drift=_drift(2, 1e-4), yaw=[2e-3, -1e-3])
    rng = np.random.default_rng(0)
    for s in sensors:
        col = rng.uniform(0, s.n_cols, 2000)
        row = rng.uniform(0, s.n_rows, 2000)
        h = rng.uniform(*H_RANGE, 2000)
        lon, lat = pushbroom_localize(s, col, row, h)
        col2, row2 = pushbroom_project(s, lon, lat, h)
        assert np.max(np.hypot(col2 - col, row2 - row)) < 1e-6
        # the ground point lies on the ray of its projection (image -> ray, independently)
        pos, d = pushbroom_ray(s, col2, row2)
        v = geodetic_to_ecef(lon, lat, h) - pos
        off_ray = np.linalg.norm(v - np.sum(v * d, axis=1)[:, None] * d, axis=1)
        assert np.max(off_ray) < 1e-3  # m
        # origin conventions differ by half a pixel
        c_c, r_c = pushbroom_project(s, lon[:5], lat[:5], h[:5], origin="center")
        assert np.allclose(col2[:5] - c_c, 0.5) and np.allclose(row2[:5] - r_c, 0.5)
    # the image centre sees the scene centre (pointing), at nadir GSD 0.5 m
    col, row = pushbroom_project(sensors[0], LON, LAT, H, origin="center")
    assert abs(col - (sensors[0].n_cols - 1) / 2) < 1e-6
    assert abs(row - (sensors[0].n_rows - 1) / 2) < 1e-6


def test_fit_rpc_reproduces_pushbroom_10km():
    """The fitted RPC of a 10 x 10 km image agrees with the pushbroom model < 0.01 px."""
    sensors = stereo_sensors(LON, LAT, H, 2, size=(20000, 20000), drift=_drift(2, 1e-4),
                             yaw=[1e-3, -2e-3])
    rng = np.random.default_rng(1)
    for s in sensors:
        lon_r, lat_r = image_domain(s, H_RANGE)
        t0 = time.perf_counter()
        rpc, fit_rms, fit_max = fit_rpc(
            lambda lo, la, hh, s=s: pushbroom_project(s, lo, la, hh),
            lon_r, lat_r, H_RANGE, s.size)
        t_fit = time.perf_counter() - t0
        n = 20000
        col, row = rng.uniform(0, s.n_cols, n), rng.uniform(0, s.n_rows, n)
        h = rng.uniform(*H_RANGE, n)
        lon, lat = pushbroom_localize(s, col, row, h)
        t0 = time.perf_counter()
        c_true, r_true = pushbroom_project(s, lon, lat, h)
        t_proj = time.perf_counter() - t0
        got = rpc.project(lon, lat, h)  # origin="corner"
        err = np.hypot(got[:, 0] - c_true, got[:, 1] - r_true)
        got_c = rpc.project(lon, lat, h, origin="center")
        c_c, r_c = pushbroom_project(s, lon, lat, h, origin="center")
        err_c = np.hypot(got_c[:, 0] - c_c, got_c[:, 1] - r_c)
        print(f"\n{s.name} 20000x20000 px: fit grid rms {fit_rms:.2e} max {fit_max:.2e} px; "
              f"{n} random points rms {np.sqrt(np.mean(err**2)):.2e} max {err.max():.2e} px; "
              f"fit {t_fit * 1e3:.0f} ms, pushbroom_project {n} points {t_proj * 1e3:.0f} ms")
        assert fit_rms < 0.01 and fit_max < 0.01
        assert err.max() < 0.01 and err_c.max() < 0.01
        assert not np.any(rpc.outside_domain(lon, lat, h, margin=0.0))
        assert rpc.line_den[0] == 1.0 and rpc.samp_den[0] == 1.0


def test_fit_rpc_misfit_is_measured():
    """A scanner with a strong attitude wobble is no cubic rational: the fit says so."""
    s = stereo_sensors(LON, LAT, H, 1, size=(20000, 20000))[0]
    lon_r, lat_r = image_domain(s, H_RANGE)

    def wobbly(lo, la, hh):
        col, row = pushbroom_project(s, lo, la, hh)
        return col + 0.5 * np.sin(row / 1500.0), row

    _, fit_rms, fit_max = fit_rpc(wobbly, lon_r, lat_r, H_RANGE, s.size)
    print(f"\nwobble 0.5 px, period 9400 lines: fit rms {fit_rms:.3f} max {fit_max:.3f} px")
    assert 0.01 < fit_rms < fit_max < 1.0


@pytest.mark.parametrize("n_images, b_h", [(2, 0.6), (3, 0.8), (2, 0.5)])
def test_stereo_geometry(n_images, b_h):
    sensors = stereo_sensors(LON, LAT, H, n_images, base_to_height=b_h,
                             drift=_drift(n_images, 1e-5))
    first, last = sensors[0], sensors[-1]
    measured = stereo_base_to_height(first, last, LON, LAT, H)
    assert measured == pytest.approx(b_h, rel=1e-3)
    assert first.pitch > 0.1 and last.pitch < -0.1  # forward and backward looking
    if n_images == 3:
        assert abs(sensors[1].pitch) < 1e-9
        assert stereo_base_to_height(first, sensors[1], LON, LAT, H) == pytest.approx(
            b_h / 2, rel=2e-3)
    area = SceneArea()
    rng = np.random.default_rng(2)
    lon, lat = area.to_lonlat(rng.uniform(-1500, 1500, 200), rng.uniform(-1500, 1500, 200))
    h = rng.uniform(150, 250, 200)
    # the two rays of each point meet at the point
    (cf, rf), (cb, rb) = (pushbroom_project(s, lon, lat, h) for s in (first, last))
    (pf, df), (pb, db) = pushbroom_ray(first, cf, rf), pushbroom_ray(last, cb, rb)
    meet = _closest_points(pf, df, pb, db)
    assert np.max(np.linalg.norm(meet - geodetic_to_ecef(lon, lat, h), axis=1)) < 1e-3
    # convergence angle: B/H = 2 tan(gamma / 2) for a symmetric pair
    gamma = np.arccos(np.clip(np.sum(df * db, axis=1), -1.0, 1.0))
    assert np.median(2 * np.tan(gamma / 2)) == pytest.approx(b_h, rel=0.01)
    # parallax of a 10 m height change: (B/H) * dh / GSD pixels
    (cf2, rf2), (cb2, rb2) = (pushbroom_project(s, lon, lat, h + 10.0) for s in (first, last))
    parallax = np.hypot((cf2 - cf) - (cb2 - cb), (rf2 - rf) - (rb2 - rb))
    print(f"\nB/H {b_h}: measured {measured:.5f}, from the convergence angle "
          f"{np.median(2 * np.tan(gamma / 2)):.4f}, from the parallax "
          f"{np.median(parallax) * 0.5 / 10.0:.4f}")
    assert np.median(parallax) * 0.5 / 10.0 == pytest.approx(b_h, rel=0.02)


@pytest.fixture(scope="module")
def big():
    t0 = time.perf_counter()
    sc = satellite_scenario(2, "shift", bias_size_px=8.0, seed=11, n_tie=3000)
    print(f"\nscenario with {len(sc.lon)} points: {time.perf_counter() - t0:.2f} s")
    return sc


def test_observation_noise(big):
    sc = big
    for i in range(sc.n_images):
        m = sc.obs_image == i
        true = sc.true_projection(i, sc.obs_point[m])
        res = np.column_stack([sc.obs_col[m], sc.obs_row[m]]) - true
        n = len(res)
        mean, std = res.mean(axis=0), res.std(axis=0, ddof=1)
        print(f"\nimage {i}: {n} obs, residual mean {mean}, std {std} (sigma {sc.sigma_px})")
        assert np.all(np.abs(mean) < 4 * sc.sigma_px / np.sqrt(n))
        assert np.all(np.abs(std / sc.sigma_px - 1.0) < 0.05)
        assert np.allclose(sc.obs_sigma[m], sc.sigma_px)
        # against the vendor's (unbiased) RPC the observations carry the true shift
        raw = sc.rpcs[i].project(sc.lon[sc.obs_point[m]], sc.lat[sc.obs_point[m]],
                                 sc.h[sc.obs_point[m]])
        shift = (np.column_stack([sc.obs_col[m], sc.obs_row[m]]) - raw).mean(axis=0)
        assert np.allclose(shift, sc.true_bias[i, [0, 3]], atol=4 * sc.sigma_px / np.sqrt(n))
        assert np.hypot(*sc.true_bias[i, [0, 3]]) > 1.0


@pytest.mark.slow
def test_noise_free_observations_follow_the_bias_definition():
    for model in ("shift", "shift+drift", "affine"):
        sc = satellite_scenario(3, model, bias_size_px=10.0, seed=4, sigma_px=0.0)
        assert sc.true_bias.shape == (3, 6)
        outside = [k for k in range(6) if k not in BIAS_MODELS[model]]
        assert np.all(sc.true_bias[:, outside] == 0.0)
        assert np.all(sc.true_bias[:, list(BIAS_MODELS[model])] != 0.0)
        for i in range(3):
            m = sc.obs_image == i
            p = sc.obs_point[m]
            ref = biased_partials(sc.rpcs[i], sc.lon[p], sc.lat[p], sc.h[p], sc.true_bias[i])[0]
            assert np.max(np.abs(np.column_stack([sc.obs_col[m], sc.obs_row[m]]) - ref)) < 1e-7
            # and the physical sensor agrees with the RPC once the bias is removed
            unb = biased_project(sc.rpcs[i], np.zeros(6), sc.lon[p], sc.lat[p], sc.h[p])
            col, row = pushbroom_project(sc.sensors[i], sc.lon[p], sc.lat[p], sc.h[p])
            assert np.max(np.hypot(unb[:, 0] - col, unb[:, 1] - row)) < 0.01


def test_scene_layout():
    sc = satellite_scenario(3, "affine", seed=0)
    kinds, counts = np.unique(sc.kind, return_counts=True)
    assert dict(zip(kinds, counts)) == {"control": 6, "check": 10, "tie": 30, "road": 60}
    assert len(set(sc.point_ids)) == len(sc.point_ids)
    assert 150.0 <= sc.h.min() and sc.h.max() <= 250.0 and np.ptp(sc.h) > 40.0
    assert abs(sc.lon.mean() - LON) < 0.02 and abs(sc.lat.mean() - LAT) < 0.02
    # every point observed in every image, inside it
    assert len(sc.obs_point) == 3 * len(sc.lon)
    for i, s in enumerate(sc.sensors):
        m = sc.obs_image == i
        assert np.array_equal(np.sort(sc.obs_point[m]), np.arange(len(sc.lon)))
        assert sc.obs_col[m].min() > 0 and sc.obs_col[m].max() < s.n_cols
        assert sc.obs_row[m].min() > 0 and sc.obs_row[m].max() < s.n_rows
    assert sc.base_to_height == pytest.approx(0.6, rel=1e-3)
    print(f"\nRPC fits of the triplet: rms {sc.fit_rms_px}, max {sc.fit_max_px} px")
    assert np.all(sc.fit_max_px < 0.01)


def _arrays(sc):
    rpc = [np.concatenate([r.line_num, r.line_den, r.samp_num, r.samp_den]) for r in sc.rpcs]
    return [sc.true_bias, sc.lon, sc.lat, sc.h, sc.obs_point, sc.obs_image, sc.obs_col,
            sc.obs_row, sc.point_ids, sc.kind] + rpc


def test_determinism_per_seed():
    a = satellite_scenario(2, "shift+drift", seed=7)
    b = satellite_scenario(2, "shift+drift", seed=7)
    assert all(np.array_equal(x, y) for x, y in zip(_arrays(a), _arrays(b)))
    c = satellite_scenario(2, "shift+drift", seed=8)
    assert not np.array_equal(a.obs_col, c.obs_col)
    assert not np.array_equal(a.true_bias, c.true_bias)
    assert not np.array_equal(a.lon, c.lon)
    assert not np.array_equal(a.rpcs[0].line_num, c.rpcs[0].line_num)
    # a fixed geometry seed keeps the scene and the RPCs, redraws bias and noise
    d = satellite_scenario(2, "shift+drift", seed=8, geometry_seed=7)
    assert np.array_equal(a.lon, d.lon) and np.array_equal(a.h, d.h)
    assert np.array_equal(a.rpcs[1].samp_num, d.rpcs[1].samp_num)
    assert not np.array_equal(a.true_bias, d.true_bias)
    assert not np.array_equal(a.obs_col, d.obs_col)


def test_explicit_ground_points_and_errors():
    area = SceneArea(lon=10.0, lat=-30.0)
    lon, lat = area.to_lonlat([0.0, 500.0, -700.0], [0.0, 300.0, -200.0])
    pts = GroundPoints(ids=["A", "B", "C"], lon=lon, lat=lat, h=np.array([10.0, 20.0, 30.0]),
                       kind=["control", "check", "road"])
    sc = satellite_scenario(2, "none", seed=1, ground=pts, sigma_px=0.0)
    assert list(sc.point_ids) == ["A", "B", "C"] and np.all(sc.true_bias == 0.0)
    m = sc.obs_image == 1
    col, row = pushbroom_project(sc.sensors[1], lon, lat, [10.0, 20.0, 30.0])
    got = np.column_stack([sc.obs_col[m], sc.obs_row[m]])
    assert np.max(np.abs(got - np.column_stack([col, row])[sc.obs_point[m]])) < 0.01
    with pytest.raises(ProjectError, match="bias model"):
        satellite_scenario(2, "quadratic")
    with pytest.raises(ProjectError, match="n_images"):
        satellite_scenario(4)
    with pytest.raises(ProjectError, match="sigma_px"):
        satellite_scenario(2, sigma_px=-1.0)
    with pytest.raises(ProjectError, match="lengths"):
        satellite_scenario(2, ground=GroundPoints(["A"], lon, lat, [1.0, 2.0, 3.0], ["tie"]))
    with pytest.raises(ProjectError, match="kinds"):
        satellite_scenario(2, ground=GroundPoints(["A", "B", "C"], lon, lat, [1.0, 2.0, 3.0],
                                                  ["tie", "gcp", "road"]))
