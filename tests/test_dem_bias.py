"""A biased DEM does not pull the stereo model (issue 30): heights from a DEM get a height
offset of their own, estimated with the adjustment."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.pipeline import run
from vectoradjust.simulate import make_scenario


def _biased(seed: int, bias: float, sigma_z: float = 0.3, offset: str = "shift"):
    """One database whose heights come from a DEM ``bias`` m too high (stated 0.3 m)."""
    data = make_scenario(seed, databases=("OSM",), pointing_sigma=0.5).to_project_data()
    vecs = []
    for spec, lay in data.vectors:
        lay.coords[:, 2] += bias
        if getattr(lay, "dem", None) is not None:
            lay.dem = replace(lay.dem, grid=lay.dem.grid + bias)
        vecs.append((replace(spec, offset=offset, sigma=(spec.sigma[0], spec.sigma[1],
                                                         sigma_z)), lay))
    data.vectors = vecs
    return data


def _le90_coverage(out, truth) -> tuple[float, float]:
    """LE90 coverage of the true heights: measured and conflated vertices."""
    d = out.databases[0]
    tid, txyz = truth[d.name]
    ti = lookup(tid, d.shape.vertex_ids)
    v = d.vertices
    z, le = np.asarray(v["AdjZ"], float), np.asarray(v["LE90"], float)
    res = []
    for sel in ((v["Adjusted"] == 1) & (ti >= 0), (v["Adjusted"] == 0) & (ti >= 0)
                & np.isfinite(le)):
        res.append(float((np.abs(z[sel] - txyz[ti[sel], 2]) <= le[sel]).mean()))
    return res[0], res[1]


@pytest.mark.parametrize("bias", [0.15, 0.3])
def test_biased_dem_keeps_le90_honest_and_the_check_heights(bias):
    meas, unmeas, check, plain = [], [], [], []
    for seed in (10, 11, 12, 13):
        data = _biased(seed, bias)
        truth = dict(data.truth)
        out = run(data)
        rec = out.summary["databases"][0]["offset"]
        assert rec["axes"] == ["X", "Y", "Z"]  # the DEM's height bias is a parameter
        m, u = _le90_coverage(out, truth)
        meas.append(m)
        unmeas.append(u)
        check.append(out.summary["check_points"]["rmse_z"])
        # the same without the DEM heights' weight: the stereo model alone
        free = _biased(seed, bias, sigma_z=1e4)
        plain.append(run(free).summary["check_points"]["rmse_z"])
    assert 0.85 <= np.mean(meas) <= 0.97, meas
    assert 0.85 <= np.mean(unmeas) <= 0.99, unmeas
    assert np.mean(check) <= 1.05 * np.mean(plain), (check, plain)


def test_without_the_height_offset_the_bias_pulls():
    """The old model (a horizontal shift only): the same 0.3 m bias drags the heights
    and LE90 misses - what the height offset mends."""
    meas = []
    for seed in (10, 11, 12, 13):
        data = _biased(seed, 0.3)
        data.vectors = [(replace(spec, dem=None), lay) for spec, lay in data.vectors]
        truth = dict(data.truth)
        meas.append(_le90_coverage(run(data), truth)[0])
    assert np.mean(meas) < 0.8, meas
