"""Automatic tie points and the relative RPC bias of a real Pleiades pair (s2p's test data).

``vectoradjust.files.rpc_ties.rpc_tie_points`` on ``../shared/data/rpc/pleiades_pair``
(Pleiades-1B crops with RPCs, 0.5 m, La Reunion) with s2p's DSM as the height source,
then bundle adjustments of the ties (UTM 40S, ellipsoidal heights; image 1 fixed).
Measured with ``validation/pleiades.py`` (GDAL 3.10, this machine):

- 400 candidates, 261 accepted (133 low correlation: vegetation and shadow), 5-9 s
  (without the DSM: 257 accepted with 10 seed points, 15-25 s);
  back-matching error of the accepted: median 0.028 px, 95 % 0.106 px, max 0.30 px;
- raw RPCs (no bias): image residual RMS 0.253 px per coordinate (0.350 in columns:
  the y-parallax); with a shift of image 2: 0.037 px;
- shift of image 2 across the epipolar direction: -0.707 +- 0.004 px (with the DSM
  height prior), -0.707 +- 0.007 px (heights free); along it: -0.005 +- 0.113 px with
  the prior, but +52 +- 144 px with the heights free (nearly singular: it moves every
  height alike);
- triangulated heights minus the DSM, no DSM information in the adjustment (raw RPCs,
  or image 2 shifted across the epipolar direction only, as s2p corrects it): median
  -0.01 m, NMAD 0.35-0.36 m, RMSE 0.42-0.43 m, 121-125 points.

The synthetic test at the end pins the half-pixel convention (GDAL's corner
convention, as rasterio windows read pixels) on a rendered pair whose second image is
rotated and scaled: the accepted ties (32 of 36) meet the RPC prediction within a median
0.007 px (90 %: 0.013 px); with the chip origin moved by half a pixel (the centre
convention) they miss by 0.31 px.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.files.rpc_ties import (
    TIE_FLAGS,
    dem_height,
    interest_points,
    rpc_tie_points,
    tie_problem,
)
from vectoradjust.sensor.rpc import RpcModel

PAIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rpc" / "pleiades_pair"

pytestmark = pytest.mark.io


def _stats(dh: np.ndarray) -> dict:
    d = dh[np.isfinite(dh)]
    med = float(np.median(d))
    return {"median": med, "nmad": float(1.4826 * np.median(np.abs(d - med))),
            "rmse": float(np.sqrt(np.mean(d * d))), "count": int(d.size)}


@pytest.fixture(scope="module")
def pleiades():
    """Tie points of the pair (with the DSM), the RPCs, the frame and the DSM."""
    for name in ("img_01.tif", "img_02.tif", "dsm_s2p.tif"):
        if not (PAIR / name).is_file():
            pytest.skip(f"Pleiades pair not found: {PAIR / name} (shared data absent)")
    pytest.importorskip("rasterio")
    pytest.importorskip("pyproj")
    from vectoradjust.files.rpc import crs_frame, read_rpc

    paths = [PAIR / "img_01.tif", PAIR / "img_02.tif"]
    rpcs = [read_rpc(p) for p in paths]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ties = rpc_tie_points(paths, rpcs, height=PAIR / "dsm_s2p.tif")
    seconds = time.perf_counter() - t0
    acc = ties.subset(ties.accepted)
    lon, lat = rpcs[0].localize(*np.median(acc.px1, axis=0), np.median(acc.height))[0]
    frame = crs_frame("EPSG:32740", heights="ellipsoidal", near=(lon, lat))
    # unit vectors along and across the epipolar direction of image 2
    col, row = np.median(acc.px1, axis=0)
    h = np.median(acc.height) + np.array([0.0, 1.0])
    ll = rpcs[0].localize(col, row, h)
    e = np.diff(rpcs[1].project(ll[:, 0], ll[:, 1], h), axis=0)[0]
    u = e / np.hypot(*e)
    return {"ties": ties, "rpcs": rpcs, "frame": frame, "dsm": dem_height(PAIR / "dsm_s2p.tif"),
            "axes": np.array([u, [-u[1], u[0]]]), "seconds": seconds}


def _adjust(p, bias, prior=False, held=None):
    """Bundle adjustment of the ties: shift (a0, b0) of image 2, its covariance, residual
    RMS per coordinate (px) and the triangulated heights minus the DSM."""
    from vectoradjust.adjust.bundle import adjust

    prob = tie_problem(p["ties"], p["rpcs"], p["frame"], bias,
                       height=p["dsm"] if prior else None, height_sigma=5.0, obs_sigma=0.1)
    if held is not None:
        eo0 = prob.eo0.copy()
        eo0[1, [0, 3]] = held
        prob = dataclasses.replace(prob, eo0=eo0)
    res = adjust(prob)
    llh, _ = p["frame"].to_geodetic(res.xyz)
    return {"shift": res.eo[1, [0, 3]], "cov": res.eo_cov[1][np.ix_([0, 3], [0, 3])],
            "rms": float(np.sqrt(np.mean(res.v_image ** 2))),
            "dh": _stats(llh[:, 2] - p["dsm"](llh[:, 0], llh[:, 1]))}


def test_ties_are_accepted_and_back_match(pleiades):
    ties = pleiades["ties"]
    acc = ties.accepted
    # a 1024 px image, 15 px templates, a 48 px grid: 20 x 20 cells with an interest point
    assert len(acc) >= 300
    # measured 261 of 400; a matcher losing 40 % of them has changed
    assert acc.sum() >= 150, ties.count_flags()
    assert np.isfinite(ties.px2[acc]).all()
    back = ties.back_error[acc]
    assert np.all(back <= 0.5)  # the criterion itself
    # measured median 0.028, 95 % 0.106 px: back-matching agrees far below the tolerance
    assert np.median(back) < 0.06 and np.percentile(back, 95) < 0.2
    # every rejected tie says why
    assert np.all(ties.flags[~acc] != 0)
    assert set(ties.count_flags()) == set(TIE_FLAGS)
    # the DSM covers the ROI of s2p's config (700 x 700 px from 150, 150): predictions
    # at the DSM height leave about a pixel of bias, nothing more
    d = np.median(ties.px2[acc] - ties.pred2[acc], axis=0)
    assert np.all(np.abs(d) < 2.0), d
    # with the DSM every window is small: no seed points (those take 10-20 s more)
    assert ties.seeds == 0


def test_relative_shift_removes_the_y_parallax(pleiades):
    p, axes = pleiades, pleiades["axes"]
    raw = _adjust(p, ("none", "none"))
    dsm = _adjust(p, ("none", "shift"), prior=True)
    free = _adjust(p, ("none", "shift"))
    # raw RPCs: 0.253 px RMS per coordinate (the y-parallax of a 0.7 px relative shift);
    # with the shift of image 2: 0.037 px (LSM sigma about 0.035 px)
    assert raw["rms"] > 0.15
    assert dsm["rms"] < 0.08 and free["rms"] < 0.08
    across = axes[1] @ dsm["shift"]
    s_dsm = np.sqrt(np.diag(axes @ dsm["cov"] @ axes.T))
    s_free = np.sqrt(np.diag(axes @ free["cov"] @ axes.T))
    # measured -0.707 +- 0.004 px across the epipolar direction
    assert -0.85 < across < -0.55 and s_dsm[1] < 0.02
    # along it the DSM prior holds the shift: -0.005 +- 0.113 px
    assert abs(axes[0] @ dsm["shift"]) < 0.5 and s_dsm[0] < 0.3
    # heights free: the across component is the same, the along one nearly singular
    assert abs(axes[1] @ free["shift"] - across) < 0.03 and s_free[1] < 0.02
    assert s_free[0] > 10.0


def test_triangulated_heights_agree_with_the_s2p_dsm(pleiades):
    p, axes = pleiades, pleiades["axes"]
    free = _adjust(p, ("none", "shift"))
    held = (axes[1] @ free["shift"]) * axes[1]  # across-epipolar part only (as s2p)
    for r in (_adjust(p, ("none", "none")), _adjust(p, ("none", "none"), held=held)):
        dh = r["dh"]
        # measured: median -0.01 m, NMAD 0.35 m, RMSE 0.42 m on 121-125 points; 1 px of
        # x-parallax is 1.9 m of height here
        assert dh["count"] >= 60
        assert abs(dh["median"]) < 0.5 and dh["nmad"] < 1.0 and dh["rmse"] < 1.5, dh


# ---------------------------------------------------------------------- synthetic pair
def _toy_rpc(size: int, scale: float, angle_deg: float, tilt: float) -> RpcModel:
    """An RPC whose image is rotated by ``angle`` and has ``scale`` px per metre-ish."""
    z = np.zeros(20)
    den = z.copy()
    den[0] = 1.0
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    samp, line = z.copy(), z.copy()
    samp[[1, 2, 3]] = [scale * c, -scale * s, tilt]
    line[[1, 2, 3]] = [-scale * s, -scale * c, 0.02]
    half = size / 2.0
    return RpcModel(line_off=half - 0.5, samp_off=half - 0.5, lat_off=-21.23,
                    long_off=55.65, height_off=2300.0, line_scale=half, samp_scale=half,
                    lat_scale=half / 110_000.0, long_scale=half / 103_700.0,
                    height_scale=500.0, line_num=line, line_den=den, samp_num=samp,
                    samp_den=den)


def _render(rpc: RpcModel, size: int, h: float, blobs: np.ndarray) -> np.ndarray:
    """Grey values at the pixel centres (corner convention: c + 0.5, r + 0.5) of ground
    blobs (x, y, amplitude in metres from the RPC's centre) at height ``h``."""
    r, c = np.mgrid[0:size, 0:size] + 0.5
    ll = rpc.localize(c.ravel(), r.ravel(), h)
    x = (ll[:, 0] - rpc.long_off) * 103_700.0
    y = (ll[:, 1] - rpc.lat_off) * 110_000.0
    img = np.zeros(len(x))
    for bx, by, amp in blobs:
        img += amp * np.exp(-((x - bx) ** 2 + (y - by) ** 2) / (2 * 2.0**2))
    return (1000.0 + 400.0 * img).reshape(size, size)


def test_half_pixel_convention_on_a_rendered_pair(tmp_path):
    """Ties of a rendered pair satisfy the RPCs to a few hundredths of a pixel; image 2
    is rotated by 25 degrees and scaled by 0.8, so a chip origin half a pixel off
    (centre instead of corner convention) would miss by about 0.2-0.3 px."""
    rasterio = pytest.importorskip("rasterio")
    size, h = 200, 2300.0
    rng = np.random.default_rng(3)
    blobs = np.column_stack([rng.uniform(-140, 140, (900, 2)), rng.normal(0, 1, 900)])
    rpcs = [_toy_rpc(size, 1.0, 0.0, 0.3), _toy_rpc(size, 0.8, 25.0, -0.3)]
    paths = []
    for i, rpc in enumerate(rpcs):
        img = _render(rpc, size, h, blobs).astype(np.float32)
        path = tmp_path / f"toy_{i}.tif"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1,
                               dtype="float32") as ds:
                ds.write(img, 1)
        paths.append(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ties = rpc_tie_points(paths, rpcs, height=h, height_sigma=1.0, bias_sigma=1.0,
                              spacing=24)
    acc = ties.accepted
    assert acc.sum() >= 15, ties.count_flags()
    miss = np.hypot(*(ties.px2[acc] - ties.pred2[acc]).T)
    assert np.median(miss) < 0.03 and np.percentile(miss, 90) < 0.08, miss
    # interest points are pixel centres
    assert np.all(np.mod(ties.px1, 1.0) == 0.5)


def test_interest_points_pick_corners_not_edges():
    """One point per cell at the strongest round feature; a straight edge gives none."""

    class Reader:
        def __init__(self, a):
            self.a, self.size = a, (a.shape[1], a.shape[0])

        def read(self, c0, r0, w, h):
            out = np.full((h, w), np.nan)
            r1, c1 = max(r0, 0), max(c0, 0)
            r2, c2 = min(r0 + h, self.a.shape[0]), min(c0 + w, self.a.shape[1])
            if r2 > r1 and c2 > c1:
                out[r1 - r0:r2 - r0, c1 - c0:c2 - c0] = self.a[r1:r2, c1:c2]
            return out

    a = np.zeros((64, 128))
    a[20:, 90:] = 100.0          # a corner at row 20, column 90 (right half)
    a[:, :40] += np.arange(40)   # a ramp; and a straight edge at column 20:
    a[:, 20:40] += 100.0
    px, w = interest_points(Reader(a), spacing=64, border=0, min_roundness=0.5)
    assert len(px) == 1  # the left cell has the edge only
    assert abs(px[0, 0] - 90.0) <= 3 and abs(px[0, 1] - 20.0) <= 3 and w[0] > 0
