"""Accuracy claims on REAL road geometry: OpenStreetMap centrelines of central Helsinki.

The true roads of the simulated stereo model are 600 m x 600 m of OSM road centrelines
(``tests/data/helsinki``, ODbL 1.0, (c) OpenStreetMap contributors; read with the json
module, so no geodata package is needed) instead of the synthetic street grid: irregular
spacing, curves, dense intersections. On them, a database shifted by 3 m with 1.5 m
noise per vertex, an analyst's identification error of 0.5 m (``pointing_sigma``,
``identification_sigma = (0.5, 0)``) and the database offset estimated
(``offset = "shift"``) must give CE90/LE90 that cover the truth 85-95 %, check points no
worse than with the control alone (ratio <= 1.05), and the offset within 4 sigma of the
database's mean displacement - in each reweighting mode, and with four databases.

Measured on seed 1 (``validation/real_roads.py`` shows seeds 1-5): CE90, LE90, the check
ratio and the offsets hold in every mode. The identification error is stated as
``(0.5, 0)``: the simulated one is horizontal (the measured point lies on the terrain).
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.pipeline import run
from vectoradjust.simulate import DatabaseModel, make_scenario, read_road_lines

DATA = Path(__file__).parent / "data" / "helsinki" / "helsinki_roads.geojson"
MODES = ("none", "two-pass", "vce")
IDENT = (0.5, 0.0)
R2 = math.sqrt(2.0)
#: the single database: 3 m to the north-east, 1.5 m noise per axis and vertex
SINGLE = DatabaseModel("OSM", "osm_id", "osm", 20.0, 0.5, (3.0 / R2, 3.0 / R2), 0.0, 0.0,
                       1.5)
#: four databases at once
FOUR = (
    SINGLE,
    DatabaseModel("TNM", "permanent_", "tnm", 15.0, 0.5, (-2.0 / R2, 2.0 / R2), 0.0, 0.0, 1.0),
    DatabaseModel("TIGER", "tlid", "tiger", 30.0, 0.5, (12.0, -14.0), 0.0, 0.0, 3.0),
    DatabaseModel("CITY", "city_id", "city", 10.0, 0.5, (0.5, -0.8), 0.0, 0.0, 0.5),
)
SEED = 1


@functools.cache
def _roads():
    return read_road_lines(DATA)


@functools.cache
def _run(models: tuple, n_shape_points: int, reweight: str):
    """The scenario's project data and the run, offsets estimated in every database.

    Prior sigma of the shape points: in ``none`` each database's real per-axis noise
    horizontally and the default-like 3.5 m vertically (``none`` scales every
    covariance by the a-posteriori sigma0^2, so the prior must be right); the
    reweighting modes start from 3.5 m on every axis and estimate it.
    """
    sc = make_scenario(SEED, databases=models, n_shape_points=n_shape_points,
                       pointing_sigma=0.5, shape_sigma=(3.5, 3.5, 3.5), true_roads=_roads())
    data = sc.to_project_data()
    vecs = []
    for spec, layer in data.vectors:
        m = sc.databases[spec.name]
        sigma = (m.noise, m.noise, 3.5) if reweight == "none" else spec.sigma
        vecs.append((replace(spec, sigma=sigma, offset="shift", identification_sigma=IDENT),
                     layer))
    data = replace(data, vectors=vecs, settings=replace(data.settings, reweight=reweight))
    return data, run(data)


def _mean_displacement(data, d):
    """Mean database-minus-truth XY at the measured (adjusted) vertices of ``d``."""
    tid, txyz = data.truth[d.name]
    ti = lookup(tid, d.shape.vertex_ids)
    sel = (d.vertices["Adjusted"] == 1) & (ti >= 0)
    return (d.shape.layer.coords[sel] - txyz[ti[sel]]).mean(axis=0)[:2]


def _check_run(data, out):
    """CE90 coverage, check point ratio and offsets of every database of a run."""
    ratio = out.summary["roads_and_control"]["check_ratio"]
    assert ratio <= 1.05, ratio
    for d, entry in zip(out.databases, out.summary["databases"]):
        assert 2000 <= d.truth["count"] <= 10000, d.truth["count"]
        ce = d.truth["share_within_ce90"]
        assert 0.85 <= ce <= 0.95, (d.name, ce)
        off = entry["offset"]
        mean = _mean_displacement(data, d)
        # X, Y (the DEM heights' own height offset, the third, is not the database's)
        assert off["axes"] == ["X", "Y", "Z"]
        sig = np.asarray(off["sigma"][:2])
        assert np.all(np.abs(np.asarray(off["values"][:2]) - mean) < 4.0 * sig + 0.02), (
            d.name, off["values"], mean, sig)


# --- the data and the scenario (fast) ------------------------------------------------
def test_helsinki_window_file():
    """The committed window: 302 OSM ways, 600 m x 600 m in UTM 35N, shared nodes."""
    doc = json.loads(DATA.read_text(encoding="utf-8"))
    assert "OpenStreetMap contributors" in doc["license"] and "ODbL" in doc["license"]
    assert doc["crs"]["properties"]["name"].endswith("32635")
    assert DATA.stat().st_size < 200_000
    rl = _roads()
    assert len(rl.lines) == len(doc["features"]) == 302
    xy = np.concatenate(rl.lines)
    assert len(xy) == 1080
    assert np.allclose(xy.min(axis=0), doc["window"][:2]) and np.allclose(
        xy.max(axis=0), doc["window"][2:])
    _, count = np.unique(xy, axis=0, return_counts=True)
    assert (count > 1).sum() == 267  # intersections and way junctions
    assert {"primary", "secondary", "residential", "service"} <= set(rl.highway)


def test_helsinki_scenario_has_shared_intersections_and_thousands_of_points():
    sc = make_scenario(SEED, databases=(SINGLE,), n_shape_points=3000, true_roads=_roads())
    real = sc.options["true_roads"]
    assert real["lines"] == 302 and real["features"] == 352  # split at shared vertices
    ids, xyz = sc.truth["OSM"]
    assert sc.measured["OSM"].all()  # the window lies inside the stereo overlap
    _, count = np.unique(xyz[:, :2], axis=0, return_counts=True)
    assert abs(len(count) - 3000) <= 30  # object points
    assert (count > 1).sum() == 267  # every shared node is one object point in the database
    layer = sc.layers["OSM"]
    for xy in np.unique(xyz[:, :2], axis=0)[::50]:  # shared XY are stored identically
        at = np.all(xyz[:, :2] == xy, axis=1)
        assert len(np.unique(layer.coords[at, :2], axis=0)) == 1
    # the window is centred on the model
    lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    assert np.allclose(0.5 * (lo + hi), sc.center, atol=1e-6)
    assert np.all(hi - lo <= 600.0 + 1e-6)


# --- one database ---------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("reweight", MODES)
def test_one_database_on_helsinki_roads(reweight):
    """3 m shift + 1.5 m noise, 0.5 m identification error, offset estimated: CE90 covers
    the truth 85-95 % (measured 0.894-0.897), the check points are no worse than with the
    control alone (ratio 0.89-0.93), the offset is the mean displacement (within 1.3
    sigma)."""
    data, out = _run((SINGLE,), 3000, reweight)
    _check_run(data, out)


@pytest.mark.slow
@pytest.mark.parametrize("reweight", MODES)
def test_le90_covers_the_truth_on_helsinki_roads(reweight):
    """LE90 covers the truth 85-95 % in every mode, one and four databases (seed 1: one
    database 0.90-0.91; four 0.88-0.94). What it takes: heights from the DEM at the
    offset-corrected position (TIGER-like, 18 m off on sloping ground: before, its
    heights were 0.10 m biased and LE90 covered 0.82); a vertical sigma that is too
    imprecise to estimate kept at its stated value (two-pass, VCE); covariances not
    shrunk by a database prior stated too large (``covariance_scale = "auto"``: before,
    sigma0^2 = 0.76 made LE90 cover 0.84 in ``none``)."""
    for models, n in (((SINGLE,), 3000), (FOUR, 8000)):
        _, out = _run(models, n, reweight)
        for d in out.databases:
            le = d.truth["share_within_le90"]
            assert 0.85 <= le <= 0.95, (d.name, le)


# --- four databases --------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("reweight", MODES)
def test_four_databases_on_helsinki_roads(reweight):
    """OSM-like (3 m), TNM-like (2 m), TIGER-like (12 m east, 14 m south) and a city
    database (0.9 m), all with offsets: CE90 coverage, check ratio and offsets as for one."""
    data, out = _run(FOUR, 8000, reweight)
    assert len(out.databases) == 4
    _check_run(data, out)
