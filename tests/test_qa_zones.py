"""Production checks of the accuracy control: tie-point zones, inter-strip ties, free model.

The zones are tested on a constructed pair (points placed in known zones of a known
overlap), the inter-strip parallax against a first-order prediction of a planted
attitude error, the free model's sigma0 against the simulated image noise, and the
sample's ``qa.json`` for the zones of its stereo pair.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.qa.free_model import free_model, free_model_stages, sigma0_bound
from vectoradjust.qa.tolerances import qa_verdict
from vectoradjust.qa.verdict import inter_strip_stages, zone_stages
from vectoradjust.qa.zones import (
    BlockView,
    clip_polygon,
    counted_kinds,
    image_strips,
    inter_strip_ties,
    overlap_polygon,
    pair_zones,
    triplet_zones,
    zone_status,
)
from vectoradjust.sensor.collinearity import rotation_matrix
from vectoradjust.simulate.block import make_block

SAMPLE = Path(__file__).resolve().parents[1] / "resources" / "sample" / "project.toml"
F = 152.4
H = 1524.0  # flying height above Z = 0: photo scale 1:10000
B = 920.0  # air base: photo base 92 mm, 60 % forward overlap of a 230 mm frame
HALF = 115.0

# points per zone placed on the pair (u along the base, v across it, in the left photo)
PLACED = {"top-left": 3, "top-right": 4, "centre-left": 2, "centre-right": 5,
          "bottom-left": 0, "bottom-right": 1}
# the overlap in the left photo: u in [-23, 115], v in [-115, 115]
U_COLUMNS = {"left": (-23.0, 46.0), "right": (46.0, 115.0)}
V_ROWS = {"top": (115.0, 115.0 / 3), "centre": (115.0 / 3, -115.0 / 3),
          "bottom": (-115.0 / 3, -115.0)}


def _vertical_photo(eo, xyz):
    """Photo coordinates of a vertical photo (omega = phi = 0), kappa rotating the frame."""
    d = xyz - eo[:3]
    k = eo[5]
    x, y = F * d[:, 0] / -d[:, 2], F * d[:, 1] / -d[:, 2]
    return np.column_stack([np.cos(k) * x + np.sin(k) * y, -np.sin(k) * x + np.cos(k) * y])


def _pair(along: str, with_road: bool = True):
    """Two vertical photos, base along ``along`` (X or Y), with points placed per zone."""
    rng = np.random.default_rng(1)
    base = np.array([B, 0.0]) if along == "X" else np.array([0.0, B])
    e_u = base / B
    e_v = np.array([-e_u[1], e_u[0]])
    uv, kind, zone = [], [], []
    for name, n in PLACED.items():
        row, col = name.split("-")
        (u0, u1), (v0, v1) = U_COLUMNS[col], V_ROWS[row]
        for _ in range(n):
            uv.append([rng.uniform(u0 + 1, u1 - 1), rng.uniform(v1 + 1, v0 - 1)])
            kind.append("tie")
            zone.append(name)
    if with_road:  # road vertices and a control point in the empty zone: not counted
        for _ in range(5):
            uv.append([rng.uniform(-22, 45), rng.uniform(-114, -39)])
            kind.append("shape")
            zone.append("bottom-left")
        uv.append([0.0, -80.0])
        kind.append("control")
        zone.append("bottom-left")
    uv = np.array(uv)
    photo = uv[:, :1] * e_u + uv[:, 1:] * e_v  # photo coordinates in the left image
    xyz = np.column_stack([photo * H / F, np.zeros(len(photo))])
    eo = np.array([[0.0, 0.0, H, 0.0, 0.0, 0.0], [*base, H, 0.0, 0.0, 0.0]])
    n = len(xyz)
    xy = np.concatenate([_vertical_photo(eo[0], xyz), _vertical_photo(eo[1], xyz)])
    view = BlockView(["L", "R"], eo, xyz, np.array([f"P{i}" for i in range(n)]),
                     np.array(kind), np.tile(np.arange(n), 2), np.repeat([0, 1], n), xy, F,
                     np.zeros(2), (230.0, 230.0))
    return view, zone


@pytest.mark.parametrize("along", ["X", "Y"])
def test_points_placed_in_known_zones_are_counted_there(along):
    view, zone = _pair(along)
    e = pair_zones(view, 0, 1)
    got = {z["zone"]: z["count"] for z in e["zones"]}
    assert got == PLACED
    road = {z["zone"]: z["road"] for z in e["zones"]}
    assert road["bottom-left"] == 5 and sum(road.values()) == 5
    assert sum(z["control"] for z in e["zones"]) == 1
    assert {z["zone"]: z["status"] for z in e["zones"]} == {
        "top-left": "pass", "top-right": "pass", "centre-left": "warn",
        "centre-right": "pass", "bottom-left": "fail", "bottom-right": "fail"}
    assert e["status"] == "fail" and e["min_count"] == 0
    # every placed point is reported in its zone by id
    ids = {i: z["zone"] for z in e["zones"] for i in z["ids"]}
    assert all(ids[f"P{k}"] == zone[k] for k in range(sum(PLACED.values())))
    # the overlap: 138 x 230 mm (60 % of the frame)
    assert e["overlap_area_mm2"] == pytest.approx(138.0 * 230.0, rel=1e-9)


def test_zone_stage_fails_empty_zones_and_warns_at_two():
    view, _ = _pair("X")
    stages, notes, pairs, trips = zone_stages(view, [0, 0])
    assert len(pairs) == 1 and trips == []
    s = stages[0]
    assert s.name == "tie-point zones L-R" and s.status == "fail" and s.measured == 0
    assert sorted(s.failed_ids) == ["L-R:bottom-left", "L-R:bottom-right"]
    assert s.warnings == ["L-R:centre-left"]
    v = qa_verdict(stages)
    assert v.nonconformities[0]["action"] == "add tie points"
    assert v.nonconformities[0]["ids"][0] == "L-R:bottom-left"  # the emptiest first
    assert v.remeasure == []  # zones are not points to re-measure
    assert any("warning" in n and "L-R:centre-left" in n for n in notes)


def test_two_points_per_zone_is_a_warning_not_a_failure():
    view, _ = _pair("X", with_road=False)
    keep = view.point_kind == "tie"
    assert zone_status(3) == "pass" and zone_status(2) == "warn" and zone_status(1) == "fail"
    # add two points to each short zone: every zone has >= 2
    extra = {"bottom-left": 2, "bottom-right": 1}
    rng = np.random.default_rng(5)
    uv = []
    for name, n in extra.items():
        (u0, u1), (v0, v1) = U_COLUMNS[name.split("-")[1]], V_ROWS["bottom"]
        uv += [[rng.uniform(u0 + 1, u1 - 1), rng.uniform(v1 + 1, v0 - 1)] for _ in range(n)]
    xyz = np.column_stack([np.array(uv) * H / F, np.zeros(len(uv))])
    n0 = int(keep.sum())
    allxyz = np.concatenate([view.xyz, xyz])
    n = len(allxyz)
    xy = np.concatenate([_vertical_photo(view.eo[0], allxyz), _vertical_photo(view.eo[1], allxyz)])
    view2 = BlockView(["L", "R"], view.eo, allxyz, np.array([f"P{i}" for i in range(n)]),
                      np.array(["tie"] * n), np.tile(np.arange(n), 2), np.repeat([0, 1], n), xy,
                      F, np.zeros(2), (230.0, 230.0))
    assert n == n0 + 3
    stages, _, pairs, _ = zone_stages(view2, [0, 0])
    assert min(z["count"] for z in pairs[0]["zones"]) == 2
    assert stages[0].status == "pass" and len(stages[0].warnings) == 3


def test_counted_points_are_all_points_without_tie_points():
    mask, label = counted_kinds(["shape", "control", "shape"])
    assert label == "all points" and mask.all()
    mask, label = counted_kinds(["shape", "tie", "control"])
    assert label == "tie points" and mask.tolist() == [False, True, False]


def test_clip_polygon_of_two_squares():
    a = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    b = a + 1.0
    p = clip_polygon(a, b[::-1])  # either orientation
    assert sorted(map(tuple, np.round(p, 12).tolist())) == [(1, 1), (1, 2), (2, 1), (2, 2)]
    assert len(clip_polygon(a, a + 5.0)) == 0


# ----------------------------------------------------------------------- strips
def _block_view(sb, eo):
    p = sb.problem
    return BlockView([f"I{i:02d}" for i in range(len(eo))], eo, sb.true_xyz,
                     np.array([f"P{i}" for i in range(p.n_points)]), sb.point_kind,
                     p.obs_point, p.obs_image, p.obs_xy, p.focal_length, p.principal_point,
                     (230.0, 230.0))


@pytest.fixture(scope="module")
def two_strips():
    return make_block(2, 4, n_shape_points=300, n_tie=200, sigma_image=1e-6, seed=3)


def test_strips_are_found_from_the_flight(two_strips):
    got = image_strips(two_strips.true_eo)
    assert got.tolist() == two_strips.strip.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    assert image_strips(two_strips.true_eo, ["a"] * 3 + ["b"] * 5).tolist() == [0] * 3 + [1] * 5


def _predicted_py(view, rays, strips, delta):
    """First order: kappa + delta on a strip-1 image turns its photo point by delta; the
    part of that shift across the base (as seen in that photo) is the vertical parallax."""
    out = []
    idx = {i: k for k, i in enumerate(view.image_ids)}
    for pid, a, b in zip(rays["point_ids"], rays["left"], rays["right"]):
        ia, ib = idx[a], idx[b]
        if strips[ib] != 1:
            ia, ib = ib, ia
        k = int(pid[1:])
        o = np.flatnonzero((view.obs_point == k) & (view.obs_image == ib))[0]
        x, y = view.obs_xy[o]
        m = rotation_matrix(*view.eo[ib, 3:])
        d = (m @ (view.eo[ib, :3] - view.eo[ia, :3]))[:2]
        n = np.array([-d[1], d[0]]) / np.hypot(*d)
        out.append(abs(delta * (-y * n[0] + x * n[1])))
    return np.array(out)


def test_inter_strip_parallax_grows_as_predicted(two_strips):
    sb = two_strips
    strips = sb.strip
    view = _block_view(sb, sb.true_eo)
    ties = inter_strip_ties(view, strips)
    assert len(ties) == 1 and ties[0]["strips"] == (0, 1)
    rays = ties[0]["ray_pairs"]
    assert len(rays["py_mm"]) > 20
    assert np.abs(rays["py_mm"]).max() < 1e-4  # true EO, noise-free: no parallax
    delta = 2e-4  # rad on kappa of the second strip
    eo = sb.true_eo.copy()
    eo[strips == 1, 5] += delta
    moved = inter_strip_ties(_block_view(sb, eo), strips)[0]["ray_pairs"]
    pred = _predicted_py(view, moved, strips, delta)
    got = np.abs(moved["py_mm"])
    assert got.mean() > 0.005  # micrometres grew to several
    np.testing.assert_allclose(got, pred, rtol=0.03, atol=2e-4)
    # the stage judges them with the relative orientation tolerance (0.5 / 1 px)
    stages, notes, entries = inter_strip_stages(_block_view(sb, eo), strips, 0.012)
    by = {s.name: s for s in stages}
    s = by["inter-strip 1-2: mean |py|"]
    assert s.tolerance == 0.5 and s.point_tolerance == 1.0
    assert s.measured == pytest.approx(got.mean() / 0.012, rel=1e-9)
    assert entries[0]["ray_pairs"] == len(got)
    assert by["inter-strip 1-2: tie points per image"].unit == "points"


def test_one_strip_is_not_a_pass():
    sb = make_block(1, 3, n_shape_points=50, seed=2)
    view = _block_view(sb, sb.true_eo)
    stages, notes, entries = inter_strip_stages(view, image_strips(sb.true_eo), 0.012)
    assert [s.status for s in stages] == ["n/a"] and entries == []
    assert notes == ["inter-strip ties: n/a: one strip"]
    t = triplet_zones(view, 0)
    assert len(t["zones"]) == 3 and t["reference_image"] == "I01"
    poly = overlap_polygon(view, 1, [0, 2], 0.0)
    assert len(poly) >= 4


# -------------------------------------------------------------------- free model
@pytest.fixture(scope="module")
def strip_block():
    return make_block(1, 4, n_shape_points=400, n_tie=60, sigma_image=0.010, seed=4)


def test_free_model_sigma0_is_one_with_the_right_sigmas(strip_block):
    sb = strip_block
    fm = free_model(sb.problem, sb.true_eo, sb.true_xyz)
    assert "error" not in fm
    assert fm["n_images"] == 4 and fm["dof"] > 500
    # chi-square: sigma0 within its 99 % band
    assert abs(fm["sigma0"] - 1.0) < 3.0 / np.sqrt(2 * fm["dof"])
    assert fm["sigma0"] <= sigma0_bound(fm["dof"])
    stages, entry, notes = free_model_stages(fm, [f"P{i}" for i in range(sb.problem.n_points)],
                                             0.012)
    assert [s.name for s in stages] == ["free model: sigma0", "free model: image residual RMS"]
    assert stages[0].status == "pass"
    assert entry["rms_um"] == pytest.approx(fm["rms_mm"] * 1e3)
    assert stages[1].measured == pytest.approx(fm["rms_mm"] / 0.012)


def test_free_model_sigma0_exceeds_one_when_image_sigmas_are_understated(strip_block):
    from dataclasses import replace

    sb = strip_block
    prob = replace(sb.problem, obs_sigma=sb.problem.obs_sigma / 2.0)  # 5 um stated, 10 true
    fm = free_model(prob, sb.true_eo, sb.true_xyz)
    assert 1.8 < fm["sigma0"] < 2.2
    stages, _, _ = free_model_stages(fm, [f"P{i}" for i in range(prob.n_points)], 0.012)
    assert stages[0].status == "fail" and stages[0].measured > stages[0].tolerance


# ------------------------------------------------------------------------ sample
@pytest.mark.io
def test_sample_qa_json_has_the_zones_of_its_pair(tmp_path, capsys):
    pytest.importorskip("rasterio")
    from vectoradjust.cli.qa import main

    out = tmp_path / "qa"
    assert main([str(SAMPLE), "--out", str(out), "-q", "--product", "orthophoto", "--scale",
                 "10000"]) == 0
    text = capsys.readouterr().out
    doc = json.loads((out / "qa.json").read_text(encoding="utf-8"))
    (pair,) = doc["tie_zones"]
    assert pair["images"] == ["L", "R"] and len(pair["zones"]) == 6
    assert sum(z["count"] for z in pair["zones"]) == pair["counted"] == 10  # T01..T10
    assert sum(z["road"] for z in pair["zones"]) > 400
    stage = next(s for s in doc["stages"] if s["name"] == "tie-point zones L-R")
    assert stage["measured"] == min(z["count"] for z in pair["zones"])
    assert next(s for s in doc["stages"] if s["name"] == "inter-strip ties")["status"] == "n/a"
    assert doc["free_model"]["sigma0"] is not None
    assert "DTM heights" in {s["name"] for s in doc["stages"]}
    assert "Tie-point zones per stereo pair" in text
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "Tie-point zones per stereo pair" in html


# ------------------------------------------------------------- strips from labels
@pytest.fixture(scope="module")
def strip_run():
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    return run(make_scenario(2, n_images=3).to_project_data())


def test_given_strip_labels_define_the_strips(strip_run):
    from vectoradjust.errors import ProjectError
    from vectoradjust.qa.tolerances import QASpec
    from vectoradjust.qa.verdict import accuracy_control, strips_from_project

    raw = {"images": [{"id": "I01", "strip": "a"}, {"id": "I02", "strip": "a"},
                      {"id": "I03", "strip": "b"}]}
    labels = strips_from_project(raw)
    assert labels == {"I01": "a", "I02": "a", "I03": "b"}
    assert strips_from_project({"images": [{"id": "I01"}]}) is None
    spec = QASpec("topographic map", map_scale=2000, contour_interval=1.0)
    rep = accuracy_control(strip_run, spec, pixel_size=0.012, strips=labels,
                           free_model=False).as_dict()
    assert rep["strips"]["source"] == "[[images]] strip"
    assert [s["strip"] for s in rep["strips"]["strips"]] == ["a", "b"]
    assert [z["images"] for z in rep["tie_zones"]] == [["I01", "I02"]]  # not across strips
    assert rep["triplet_zones"] == []
    (inter,) = rep["inter_strip"]
    assert inter["strips"] == ["a", "b"] and inter["ray_pairs"] > 0
    names = {s["name"] for s in rep["stages"]}
    assert {"inter-strip a-b: mean |py|", "inter-strip a-b: max |py|"} <= names
    assert not any(n.startswith("free model") for n in names)
    # found from the flight instead: one strip of three images
    auto = accuracy_control(strip_run, spec, pixel_size=0.012, free_model=False).as_dict()
    assert auto["strips"]["source"].startswith("flight") and auto["inter_strip"] == []
    assert len(auto["tie_zones"]) == 2 and len(auto["triplet_zones"]) == 1
    with pytest.raises(ProjectError, match="strip labels are given for 1 of 3 images"):
        accuracy_control(strip_run, spec, strips={"I01": "a"})
