"""The QA DTM stage: the project's DEM against the control and check points' heights.

Truth: the simulated DEM (the scenario's terrain) and what is planted in it: the DEM
raised by a known amount everywhere, or around one check point only.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vectoradjust.adjust.dem import bilinear
from vectoradjust.model import DemGrid
from vectoradjust.pipeline import run
from vectoradjust.qa.text import format_report
from vectoradjust.qa.tolerances import QASpec, dtm_height_tolerance
from vectoradjust.qa.verdict import accuracy_control
from vectoradjust.simulate import make_scenario

MAP_2000 = QASpec("topographic map", map_scale=2000, contour_interval=1.0)


@pytest.fixture(scope="module")
def adjusted():
    return run(make_scenario(0, n_images=3, sigma_image=0.003).to_project_data())


def _with_dem(r, change):
    """The run's road layers with their DEM changed by ``change(grid, transform)``."""
    out = []
    for spec, layer in r.data.vectors:
        d = layer.dem
        grid = change(np.array(d.grid, float), d.transform)
        out.append((spec, dataclasses.replace(layer, dem=DemGrid(grid, d.transform, d.nodata))))
    return out


def _stage(rep):
    return next(s for s in rep.stages if s.name == "DTM heights")


def test_dtm_stage_compares_the_dem_with_every_control_point(adjusted):
    rep = accuracy_control(adjusted, MAP_2000)
    st = _stage(rep)
    ctrl = adjusted.data.control
    dem = adjusted.data.vectors[0][1].dem
    dz = bilinear(dem.grid, dem.transform, ctrl.xyz[:, :2], nodata=dem.nodata) - ctrl.xyz[:, 2]
    assert st.status == "pass" and st.tolerance == pytest.approx(0.2)
    assert st.measured == pytest.approx(np.mean(np.abs(dz)))
    doc = rep.as_dict()
    assert [d["id"] for d in doc["dtm_points"]] == list(ctrl.point_id)
    assert {d["role"] for d in doc["dtm_points"]} == {"control", "check"}
    np.testing.assert_allclose([d["dz"] for d in doc["dtm_points"]], dz)
    assert doc["tolerances"]["dtm"]["point_m"] == pytest.approx(0.4)
    assert "DTM heights at control and check points" in format_report(doc)
    assert "DTM heights" not in doc["not_evaluated"]


def test_raised_dem_fails_the_stage_with_every_point(adjusted, monkeypatch):
    monkeypatch.setattr(adjusted.data, "vectors", _with_dem(adjusted, lambda g, t: g + 0.5))
    rep = accuracy_control(adjusted, MAP_2000)
    st = _stage(rep)
    assert st.status == "fail" and st.measured > 0.3
    assert not rep.passed
    nc = next(n for n in rep.as_dict()["nonconformities"] if n["stage"] == "DTM heights")
    assert set(nc["ids"]) == {d["id"] for d in rep.dtm_points if abs(d["dz"]) > 0.4}


def test_a_bump_at_one_check_point_fails_that_point_only(adjusted, monkeypatch):
    ctrl = adjusted.data.control
    j = int(np.flatnonzero(np.asarray(ctrl.role) == "check")[0])
    x, y = ctrl.xyz[j, :2]

    def bump(g, t):
        rows, cols = np.indices(g.shape)
        xc = t[0] + (cols + 0.5) * t[1]
        yc = t[3] + (rows + 0.5) * t[5]
        return g + 2.0 * (np.hypot(xc - x, yc - y) < 12.0)

    monkeypatch.setattr(adjusted.data, "vectors", _with_dem(adjusted, bump))
    rep = accuracy_control(adjusted, MAP_2000)
    st = _stage(rep)
    assert st.status == "fail"
    assert [r["id"] for r in st.rows if r["passed"] is False] == [ctrl.point_id[j]]


def test_orthophoto_uses_dh_dtm_and_no_dem_keeps_the_old_note(adjusted, monkeypatch):
    spec = QASpec("orthophoto", orthophoto_scale=10000)
    rep = accuracy_control(adjusted, spec)
    dh = rep.tolerances["orthophoto"]["dh_dtm_m"]
    assert _stage(rep).tolerance == pytest.approx(dh)
    assert dtm_height_tolerance(spec, 152.4, rep.tolerances["orthophoto"]["working_radius_mm"]
                                )[0] == pytest.approx(dh)
    assert not any(s.name == "orthophoto: DTM heights" for s in rep.stages)
    no_dem = [(s, dataclasses.replace(layer, dem=None)) for s, layer in adjusted.data.vectors]
    monkeypatch.setattr(adjusted.data, "vectors", no_dem)
    rep2 = accuracy_control(adjusted, spec)
    names = {s.name: s for s in rep2.stages}
    assert "DTM heights" not in names and names["orthophoto: DTM heights"].status == "n/a"
    assert rep2.as_dict()["dtm_points"] == []
