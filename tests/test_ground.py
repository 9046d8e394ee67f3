"""Ground frames (sensor/ground.py): WGS84 geodetic <-> ECEF <-> local ENU, Jacobians.

The conversions are checked against PROJ (EPSG:4979 -> EPSG:4978 and PROJ's
``topocentric`` operation) and against a 40-digit evaluation (mpmath); the Jacobians
against central differences, and :class:`CallableFrame`'s numerical Jacobian against
the analytic ones of :class:`EnuFrame` and of a UTM projection (PROJ's factors).
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.sensor.ground import (
    WGS84_A,
    CallableFrame,
    EnuFrame,
    GroundFrame,
    ecef_to_geodetic,
    geodetic_jacobian_ecef,
    geodetic_to_ecef,
)

#: float64 resolution of geocentric coordinates: an ulp of 6.4e6 m is 9.3e-10 m, so
#: conversions through ECEF agree with exact values to a few 1e-9 m at best (up to 5.8e-9 m
#: with numpy 1.24's trigonometry, Debian's Python)
ROUNDING_M = 1e-8
M_PER_DEG = np.radians(1.0) * WGS84_A


def _random_llh(rng, n, h_range=(-500.0, 9000.0)):
    return np.column_stack([rng.uniform(-180, 180, n), rng.uniform(-89.9, 89.9, n),
                            rng.uniform(*h_range, n)])


def _enu_pipeline(lon0, lat0, h0):
    pyproj = pytest.importorskip("pyproj")
    return pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lon_0={lon0!r} +lat_0={lat0!r} +h_0={h0!r}")


def test_geodetic_to_ecef_matches_proj():
    pyproj = pytest.importorskip("pyproj")
    llh = _random_llh(np.random.default_rng(1), 2000, (-1000.0, 1.0e6))
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    ref = np.column_stack(t.transform(*llh.T))
    assert np.abs(geodetic_to_ecef(llh) - ref).max() < ROUNDING_M
    # PROJ's inverse (one Bowring step) is exact only near the surface: compare there
    # (at 1000 km altitude it is off by mm; the 40-digit test below covers that range)
    near = np.abs(llh[:, 2]) < 10000.0
    back = np.column_stack(t.transform(*ref[near].T, direction="INVERSE"))
    ours = ecef_to_geodetic(ref[near])
    assert np.abs((ours[:, 1] - back[:, 1]) * M_PER_DEG).max() < 1e-6
    assert np.abs(ours[:, 2] - back[:, 2]).max() < 1e-6
    np.testing.assert_allclose(ours[:, 0], back[:, 0], rtol=0, atol=1e-12)


def _mp_geodetic(x, y, z):
    """Latitude (deg) and height of an ECEF point, iterated to convergence at 40 digits."""
    mpmath = pytest.importorskip("mpmath")
    with mpmath.workdps(40):
        a, f = mpmath.mpf(WGS84_A), 1 / mpmath.mpf("298.257223563")
        e2 = f * (2 - f)
        x, y, z = mpmath.mpf(x), mpmath.mpf(y), mpmath.mpf(z)
        p = mpmath.sqrt(x * x + y * y)
        phi = mpmath.atan2(z, p * (1 - e2))
        for _ in range(60):
            n = a / mpmath.sqrt(1 - e2 * mpmath.sin(phi) ** 2)
            phi = mpmath.atan2(z + e2 * n * mpmath.sin(phi), p)
        h = p * mpmath.cos(phi) + z * mpmath.sin(phi) - a * mpmath.sqrt(
            1 - e2 * mpmath.sin(phi) ** 2)
        return float(mpmath.degrees(phi)), float(h)


@pytest.mark.parametrize("h_range", [(-1000.0, 10000.0), (1.0e5, 1.0e6)])
def test_ecef_to_geodetic_is_exact_to_float_rounding(h_range):
    # three Bowring iterations: the error left is float64 rounding (measured 1.1e-9 m in
    # latitude, 1.5e-9 m in height, up to 1000 km altitude), not the iteration
    llh = _random_llh(np.random.default_rng(2), 150, h_range)
    llh[:3, 1] = [89.99999, -89.99999, 0.0]
    ecef = geodetic_to_ecef(llh)
    ours = ecef_to_geodetic(ecef)
    ref = np.array([_mp_geodetic(*e) for e in ecef])
    assert np.abs((ours[:, 1] - ref[:, 0]) * M_PER_DEG).max() < ROUNDING_M
    assert np.abs(ours[:, 2] - ref[:, 1]).max() < ROUNDING_M
    dlon = (ours[:, 0] - llh[:, 0] + 180.0) % 360.0 - 180.0
    assert np.abs(dlon * M_PER_DEG * np.cos(np.radians(llh[:, 1]))).max() < ROUNDING_M


@pytest.mark.parametrize("origin", [(24.4057, -33.6726, 703.0), (55.71, -21.23, 1200.0),
                                    (-89.3, 41.8, 180.0), (179.99, 70.0, 0.0)])
def test_enu_frame_matches_proj_topocentric(origin):
    frame = EnuFrame(*origin)
    rng = np.random.default_rng(3)
    enu = np.column_stack([rng.uniform(-50e3, 50e3, 500), rng.uniform(-50e3, 50e3, 500),
                           rng.uniform(-3000, 6000, 500)])
    enu[0] = 0.0
    llh, _ = frame.to_geodetic(enu)
    np.testing.assert_allclose(llh[0, :2], origin[:2], rtol=0, atol=1e-12)  # degrees
    assert abs(llh[0, 2] - origin[2]) < ROUNDING_M  # metres
    ref = np.column_stack(_enu_pipeline(*origin).transform(*llh.T))
    assert np.abs(ref - enu).max() < ROUNDING_M
    assert np.abs(frame.from_geodetic(llh) - enu).max() < ROUNDING_M


def test_enu_round_trip_and_far_points():
    frame = EnuFrame(24.4057, -33.6726, 703.0)
    rng = np.random.default_rng(4)
    # out to 500 km and up to a satellite's altitude (the RPC's look direction)
    enu = np.column_stack([rng.uniform(-5e5, 5e5, 1000), rng.uniform(-5e5, 5e5, 1000),
                           rng.uniform(-1e3, 7e5, 1000)])
    llh, _ = frame.to_geodetic(enu)
    back = frame.from_geodetic(llh)
    assert np.abs(back - enu).max() < ROUNDING_M
    # Z departs from the ellipsoidal height by about d^2 / 2R (8 cm at 1 km)
    llh1, _ = frame.to_geodetic([1000.0, 0.0, 0.0])
    assert llh1[0, 2] - 703.0 == pytest.approx(1000.0**2 / (2 * 6.37e6), rel=0.01)


def _product_error(a, b):
    """``a @ b - I`` of (n, 3, 3) stacks, each entry relative to ``|row of a| |column of b|``.

    The rows and columns carry different units (degrees, metres), so a plain tolerance
    would measure the units rather than the agreement.
    """
    err = a @ b - np.eye(3)
    scale = np.linalg.norm(a, axis=2)[:, :, None] * np.linalg.norm(b, axis=1)[:, None, :]
    return np.abs(err / scale).max()


def _central(fun, pts, step):
    cols = []
    for k in range(3):
        d = np.zeros(3)
        d[k] = step
        diff = fun(pts + d) - fun(pts - d)
        diff[:, 0] = (diff[:, 0] + 180.0) % 360.0 - 180.0
        cols.append(diff / (2 * step))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("origin", [(24.4057, -33.6726, 703.0), (-179.999, 64.0, 50.0)])
def test_enu_jacobian_against_finite_differences(origin):
    frame = EnuFrame(*origin)
    rng = np.random.default_rng(5)
    enu = np.column_stack([rng.uniform(-3e4, 3e4, 200), rng.uniform(-3e4, 3e4, 200),
                           rng.uniform(-500, 4000, 200)])
    _, jac = frame.to_geodetic(enu)
    num = _central(lambda p: frame.to_geodetic(p)[0], enu, 0.5)
    scale = np.abs(jac).max(axis=2, keepdims=True)          # per row (lon, lat, h)
    assert np.abs((jac - num) / scale).max() < 1e-6
    # exact: the inverse of d(ENU)/d(llh) obtained through the other direction
    llh = frame.to_geodetic(enu)[0]
    d = np.array([1e-5, 1e-5, 1.0])
    back = np.stack([(frame.from_geodetic(llh + np.eye(3)[k] * d[k])
                      - frame.from_geodetic(llh - np.eye(3)[k] * d[k])) / (2 * d[k])
                     for k in range(3)], axis=-1)
    assert _product_error(jac, back) < 1e-7


def test_geodetic_jacobian_ecef_is_the_inverse_of_the_forward_derivative():
    llh = _random_llh(np.random.default_rng(6), 100, (-500.0, 8e5))
    jac = geodetic_jacobian_ecef(llh)
    d = np.array([1e-5, 1e-5, 1.0])
    fwd = np.stack([(geodetic_to_ecef(llh + np.eye(3)[k] * d[k])
                     - geodetic_to_ecef(llh - np.eye(3)[k] * d[k])) / (2 * d[k])
                    for k in range(3)], axis=-1)
    assert _product_error(jac, fwd) < 1e-7


def test_enu_frame_input_checks_and_description():
    frame = EnuFrame(24.4057, -33.6726, 703.0)
    assert isinstance(frame, GroundFrame)
    assert "24.405700 E, 33.672600 S" in frame.description and "703.000 m" in frame.description
    llh, jac = frame.to_geodetic([0.0, 0.0, 0.0])            # one point (3,)
    assert llh.shape == (1, 3) and jac.shape == (1, 3, 3)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        frame.to_geodetic(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="latitude"):
        EnuFrame(0.0, 90.0)
    with pytest.raises(TypeError, match=r"abstract class GroundFrame.*to_geodetic"):
        GroundFrame()  # abstract


def test_callable_frame_jacobian_matches_the_analytic_enu_one():
    # CallableFrame around EnuFrame's own functions: the measured central-difference
    # error with the default 1 m step (truncation step^2/6 f''' plus rounding)
    enu = EnuFrame(24.4057, -33.6726, 703.0)

    def forward(x, y, z):
        llh = enu.to_geodetic(np.column_stack([x, y, z]))[0]
        return llh[:, 0], llh[:, 1], llh[:, 2]

    def inverse(lon, lat, h):
        xyz = enu.from_geodetic(np.column_stack([lon, lat, h]))
        return xyz[:, 0], xyz[:, 1], xyz[:, 2]

    frame = CallableFrame(forward, inverse, "ENU through callables")
    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(-2e4, 2e4, 300), rng.uniform(-2e4, 2e4, 300),
                           rng.uniform(-100, 3000, 300)])
    llh_c, jac_c = frame.to_geodetic(pts)
    llh_e, jac_e = enu.to_geodetic(pts)
    np.testing.assert_array_equal(llh_c, llh_e)
    rel = np.abs(jac_c - jac_e) / np.abs(jac_e).max(axis=2, keepdims=True)
    assert rel.max() < 1e-7                         # measured: about 1e-9
    np.testing.assert_allclose(frame.from_geodetic(llh_e), pts, atol=ROUNDING_M)
    assert "ENU through callables" in repr(frame)
    with pytest.raises(ValueError, match="step"):
        CallableFrame(forward, inverse, "x", step=0.0)


def test_callable_frame_utm_jacobian_against_proj_factors():
    # UTM zone 35S (the QuickBird scene): PROJ's analytic projection derivatives
    # (get_factors: dx/dlam, dx/dphi, dy/dlam, dy/dphi) inverted give d(lon,lat)/d(x,y)
    pyproj = pytest.importorskip("pyproj")
    t = pyproj.Transformer.from_crs("EPSG:32735", "EPSG:4979", always_xy=True)
    frame = CallableFrame(t.transform, lambda lo, la, h: t.transform(lo, la, h,
                                                                     direction="INVERSE"),
                          "UTM 35S")
    rng = np.random.default_rng(8)
    xyz = np.column_stack([rng.uniform(2.4e5, 3.6e5, 200), rng.uniform(6.21e6, 6.33e6, 200),
                           rng.uniform(0, 1500, 200)])
    llh, jac = frame.to_geodetic(xyz)
    np.testing.assert_allclose(llh[:, 2], xyz[:, 2], atol=1e-9)   # h passes unchanged
    fac = pyproj.Proj("EPSG:32735").get_factors(llh[:, 0], llh[:, 1])
    fwd = np.stack([[fac.dx_dlam, fac.dx_dphi], [fac.dy_dlam, fac.dy_dphi]])  # per radian
    # PROJ gives them on a unit ellipsoid: times a, per radian -> metres per degree
    fwd = np.moveaxis(fwd, -1, 0) * WGS84_A * np.radians(1.0)
    ref = np.linalg.inv(fwd)                                                   # (n, 2, 2)
    rel = np.abs(jac[:, :2, :2] - ref) / np.abs(ref).max(axis=2, keepdims=True)
    assert rel.max() < 1e-6                         # measured: about 1e-9
    np.testing.assert_allclose(jac[:, 2], np.broadcast_to([0.0, 0.0, 1.0], (200, 3)),
                               atol=1e-9)
    np.testing.assert_allclose(jac[:, :2, 2], 0.0, atol=1e-12)


def test_callable_frame_differentiates_across_the_antimeridian():
    enu = EnuFrame(180.0, 10.0, 0.0)

    def forward(x, y, z):
        llh = enu.to_geodetic(np.column_stack([x, y, z]))[0]
        return llh[:, 0], llh[:, 1], llh[:, 2]

    frame = CallableFrame(forward, None, "antimeridian")
    llh, jac = frame.to_geodetic([[0.3, 0.0, 0.0], [-0.3, 0.0, 0.0]])
    assert np.sign(llh[0, 0]) != np.sign(llh[1, 0])            # the points straddle +-180
    ref = enu.to_geodetic([[0.3, 0, 0], [-0.3, 0, 0]])[1]
    assert np.abs((jac - ref) / np.abs(ref).max(axis=2, keepdims=True)).max() < 1e-7
