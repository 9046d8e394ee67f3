"""Tests of the production accuracy-control tolerances (vectoradjust.qa.tolerances).

Sources of the expected numbers
-------------------------------
* Analog triplet table (f = 90 / 150 / 300 mm, film scanned at 12 micrometres):
  E_xy = 0.008 mm, E_z = 0.008 / 0.014 / 0.028 mm, the PHOTOMOD manual's values as
  quoted in issue 7. The frame is 23 x 23 cm flown at 60 % forward overlap, so the
  photo base is 92 mm.
* Block tolerances: the published rules (GKINP-02-036-02 via the PHOTOMOD manual,
  docs/method.md section 7): GCP 0.2 mm x M and 0.15 h; check points 0.3 mm x M and
  0.2 / 0.25 / 0.35 h for h = 1 / 2.5 / 5-10 m. The expected metres below are those
  rules worked by hand (0.2 mm x 2000 = 0.4 m, ...).
* Orthomosaic: 0.5 mm flat and hilly, 0.7 mm mountainous; seamlines 0.7 / 1.0 mm
  (the instruction's "0.5 mm for flat, hilly and desert areas, 0.7 mm for mountains").
* Digital cameras: the PHOTOMOD manual's own digital-camera tables could not be
  found, so there are no published numbers to compare with. The camera data are the
  manufacturers' public specifications (DMC: Z/I Imaging / Intergraph, 120 mm, 12 um,
  13824 x 7680 px; UltraCamD: Vexcel, 100 mm, 9 um, 11500 x 7500 px; UltraCamX: Vexcel,
  100.5 mm, 7.2 um, 14430 x 9420 px; DSS: Applanix DSS 439, 60 mm, 6.8 um,
  7216 x 5412 px), and the formulas are checked against independent geometry (a
  numerical stereo intersection with the collinearity equations).
* The DTM rule dh = 0.3 mm f M / r is checked against the relief displacement of a
  collinearity projection, not against a printed table (not found either).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from vectoradjust.errors import ControlError, ProjectError
from vectoradjust.qa.tolerances import (
    QASpec,
    block_tolerances,
    check_stage,
    check_z_factor,
    control_point_qa,
    interior_orientation_tolerance,
    max_from_mean,
    mean_from_rms,
    model_discrepancies,
    orthomosaic_tolerance,
    orthophoto_dtm_tolerance,
    parallax_stages,
    parallax_stats,
    qa_verdict,
    relative_orientation_tolerance,
    rms_from_mean,
    stereo_base_mm,
    triplet_tolerance,
    vertical_parallax,
)
from vectoradjust.sensor.collinearity import project

# Manufacturers' public specifications: f (mm), pixel (mm), pixels along track,
# pixels across track.
DIGITAL_CAMERAS = {
    "DMC": (120.0, 0.012, 7680, 13824),
    "DSS": (60.0, 0.0068, 5412, 7216),
    "UltraCamD": (100.0, 0.009, 7500, 11500),
    "UltraCamX": (100.5, 0.0072, 9420, 14430),
}


# ------------------------------------------------------------ helper: geometry
def _height_error_from_parallax(f_mm, base_mm, dp_mm, photo_scale=10000.0):
    """Height change (mm at image scale) that a parallax error dp causes.

    Independent of the formula under test: two vertical photos, projected with the
    collinearity equations; the height of a point is found by root finding so that
    its x-parallax equals the true parallax plus dp.
    """
    h = f_mm * photo_scale / 1000.0  # flying height, m
    b = base_mm * photo_scale / 1000.0  # air base, m
    eo_l = np.array([0.0, 0.0, h, 0.0, 0.0, 0.0])
    eo_r = np.array([b, 0.0, h, 0.0, 0.0, 0.0])
    ground = np.array([0.5 * b, 0.3 * b, 0.0])

    def parallax(z):
        pt = ground + np.array([0.0, 0.0, z])
        return project(eo_l, pt, f_mm)[0] - project(eo_r, pt, f_mm)[0]

    p0 = parallax(0.0)
    z = brentq(lambda zz: parallax(zz) - (p0 + dp_mm), -0.2 * h, 0.2 * h, xtol=1e-12)
    return abs(z) / photo_scale * 1000.0


# --------------------------------------------------------------- triplets
def test_analog_triplet_table_reproduces_the_manual():
    published_exy = [0.008, 0.008, 0.008]
    published_ez = [0.008, 0.014, 0.028]
    f = np.array([90.0, 150.0, 300.0])
    b = stereo_base_mm(230.0, 0.6)
    assert b == pytest.approx(92.0)
    e_xy, e_z = triplet_tolerance(f, b, 0.012)
    # The manual prints three decimals of a millimetre.
    np.testing.assert_array_equal(np.round(e_xy, 3), published_exy)
    np.testing.assert_array_equal(np.round(e_z, 3), published_ez)


@pytest.mark.parametrize("name", sorted(DIGITAL_CAMERAS))
def test_digital_triplet_tolerance_matches_stereo_geometry(name):
    f, pix, n_along, _ = DIGITAL_CAMERAS[name]
    base = stereo_base_mm(n_along * pix, 0.6)
    e_xy, e_z = triplet_tolerance(f, base, pix)
    # sqrt(2) half-pixel pointings (definition)
    assert e_xy == pytest.approx(math.hypot(0.5 * pix, 0.5 * pix), rel=1e-12)
    # height effect of an e_xy parallax error, by intersection
    assert e_z == pytest.approx(_height_error_from_parallax(f, base, e_xy), rel=1e-3)


def test_digital_triplet_table_values():
    # Worked from the specs above (no published table found): E_z = f / (0.4 l) E_xy.
    rows = {}
    for name, (f, pix, n_along, _) in DIGITAL_CAMERAS.items():
        rows[name] = triplet_tolerance(f, stereo_base_mm(n_along * pix), pix)
    assert rows["DMC"][0] == pytest.approx(0.012 / math.sqrt(2))
    assert rows["DMC"][1] == pytest.approx(120.0 / (0.4 * 92.16) * 0.012 / math.sqrt(2))
    # Digital frames are short along track: E_z / E_xy = f / b is 3.3 (DMC) to 4.1
    # (DSS), twice that of 23 cm film with f = 150 mm (1.63).
    ratios = {k: v[1] / v[0] for k, v in rows.items()}
    assert all(3.2 < r < 4.2 for r in ratios.values()), ratios


def test_triplet_tolerance_rejects_nonsense():
    with pytest.raises(ValueError, match="focal length, base and pixel size must be positive"):
        triplet_tolerance(150.0, 0.0, 0.012)
    with pytest.raises(ValueError, match=r"forward overlap must be in \[0, 1\), got 1\.0"):
        stereo_base_mm(230.0, 1.0)


# --------------------------------------------------------- orientation stages
def test_orientation_tolerances_in_pixels_and_mm():
    io = interior_orientation_tolerance(0.012)
    assert (io.max_px, io.max_mm, io.mean_px) == (1.0, 0.012, None)
    ro = relative_orientation_tolerance(0.009)
    assert ro.mean_px == 0.5 and ro.max_px == 1.0
    assert ro.mean_mm == pytest.approx(0.0045) and ro.max_mm == pytest.approx(0.009)
    # the published pair (0.5 px mean, 1 px max) is the E_max = 2 E_mean rule
    assert max_from_mean(ro.mean_px) == ro.max_px
    with pytest.raises(ValueError, match=r"pixel size must be a positive number of mm, got 0\.0"):
        interior_orientation_tolerance(0.0)


def test_max_and_rms_rules():
    assert max_from_mean(0.2) == pytest.approx(0.4)
    assert rms_from_mean(0.2) == pytest.approx(0.2 * math.sqrt(2))
    assert mean_from_rms(rms_from_mean(0.3)) == pytest.approx(0.3)
    np.testing.assert_allclose(max_from_mean([0.1, 0.3]), [0.2, 0.6])


def test_rms_to_mean_ratio_of_normal_errors_documented():
    # The docstring of rms_from_mean says sqrt(2) is a rule of thumb: for normal errors
    # RMS/mean|e| is sqrt(pi/2) in 1D and 2/sqrt(pi) for horizontal lengths.
    rng = np.random.default_rng(7)
    e = rng.standard_normal((200_000, 2))
    one = np.abs(e[:, 0])
    two = np.hypot(e[:, 0], e[:, 1])
    assert np.sqrt(np.mean(one**2)) / one.mean() == pytest.approx(math.sqrt(math.pi / 2), rel=5e-3)
    assert np.sqrt(np.mean(two**2)) / two.mean() == pytest.approx(2 / math.sqrt(math.pi), rel=5e-3)


# ------------------------------------------------------------- block tolerances
@pytest.mark.parametrize(
    "scale, h, gcp_xy, gcp_z, check_xy, check_z",
    [
        (2000, 1.0, 0.4, 0.15, 0.6, 0.2),
        (2000, 2.5, 0.4, 0.375, 0.6, 0.625),
        (10000, 2.5, 2.0, 0.375, 3.0, 0.625),
        (10000, 5.0, 2.0, 0.75, 3.0, 1.75),
        (25000, 5.0, 5.0, 0.75, 7.5, 1.75),
        (25000, 10.0, 5.0, 1.5, 7.5, 3.5),
    ],
)
def test_map_block_tolerances(scale, h, gcp_xy, gcp_z, check_xy, check_z):
    spec = QASpec("topographic map", map_scale=scale, contour_interval=h)
    t = block_tolerances(spec)
    assert t.gcp_xy == pytest.approx(gcp_xy)
    assert t.gcp_z == pytest.approx(gcp_z)
    assert t.check_xy == pytest.approx(check_xy)
    assert t.check_z == pytest.approx(check_z)
    assert t.notes == ()


def test_check_z_factor_published_and_fallback():
    assert check_z_factor(1.0) == (0.2, "published")
    assert check_z_factor(2.5) == (0.25, "published")
    assert check_z_factor(5.0) == (0.35, "published")
    assert check_z_factor(10.0) == (0.35, "published")
    assert check_z_factor(2.0)[0] == 0.2 and "1 m" in check_z_factor(2.0)[1]
    assert check_z_factor(0.5)[0] == 0.2 and "below" in check_z_factor(0.5)[1]
    assert check_z_factor(20.0)[0] == 0.35 and "above" in check_z_factor(20.0)[1]
    # the tolerance factor * h never decreases as h grows
    h = np.linspace(0.25, 25.0, 2000)
    tol = np.array([check_z_factor(x)[0] * x for x in h])
    assert np.all(np.diff(tol) >= 0)
    # a non-published interval is noted in the block tolerances
    t = block_tolerances(QASpec("topographic map", map_scale=5000, contour_interval=2.0))
    assert t.check_z == pytest.approx(0.4) and len(t.notes) == 1


@pytest.mark.parametrize(
    "scale, terrain, xy, seam",
    [
        (2000, "flat", 1.0, 1.4),
        (2000, "mountainous", 1.4, 2.0),
        (5000, "hilly", 2.5, 3.5),
        (5000, "mountainous", 3.5, 5.0),
        (10000, "flat", 5.0, 7.0),
        (10000, "mountainous", 7.0, 10.0),
    ],
)
def test_orthomosaic_table(scale, terrain, xy, seam):
    spec = QASpec("orthomosaic", orthophoto_scale=scale, terrain=terrain)
    t = orthomosaic_tolerance(spec)
    assert t.xy_m == pytest.approx(xy)
    assert t.seamline_m == pytest.approx(seam)
    b = block_tolerances(spec)
    assert b.gcp_xy == pytest.approx(xy) and b.check_xy == pytest.approx(xy)
    assert b.gcp_z is None and b.check_z is None and b.notes


@pytest.mark.parametrize("f", [90.0, 150.0, 300.0])
@pytest.mark.parametrize("scale", [2000.0, 10000.0])
def test_dtm_tolerance_is_the_relief_displacement_limit(f, scale):
    # A DTM error dh at radial distance r on the image displaces the orthophoto point by
    # 0.3 mm at the orthophoto scale. Independent check with the collinearity equations.
    r = 134.0
    dh, dh_block = orthophoto_dtm_tolerance(f, scale, r)
    assert dh_block == pytest.approx(dh / 3)
    photo_scale = 4.0 * scale
    h = f * photo_scale / 1000.0
    eo = np.array([0.0, 0.0, h, 0.0, 0.0, 0.0])
    radius = r * photo_scale / 1000.0  # ground distance of the image point at r
    x_img = project(eo, np.array([radius, 0.0, dh]), f)[0]
    x_ortho = x_img * photo_scale / 1000.0  # where the orthophoto (DTM at 0) puts it
    displacement = x_ortho - radius
    assert displacement == pytest.approx(0.3e-3 * scale, rel=2 * dh / h)


def test_dtm_tables_analog_and_digital():
    # Analog, r = 134 mm (the manual's working-area radius for 23 x 23 cm film): the
    # tolerance is linear in f and M: 0.3 mm x M x f / r.
    f = np.array([90.0, 150.0, 300.0])[:, None]
    m = np.array([2000.0, 5000.0, 10000.0])[None, :]
    dh, third = orthophoto_dtm_tolerance(f, m, 134.0)
    assert dh.shape == (3, 3)
    assert dh[1, 0] == pytest.approx(0.3e-3 * 2000 * 150 / 134)  # 0.672 m
    np.testing.assert_allclose(third, dh / 3)
    # Digital: r = half the frame diagonal (our choice; the manual's r not found).
    for fd, pix, n_al, n_ac in DIGITAL_CAMERAS.values():
        r = 0.5 * math.hypot(n_al * pix, n_ac * pix)
        dh_d, _ = orthophoto_dtm_tolerance(fd, 2000.0, r)
        assert dh_d == pytest.approx(0.3e-3 * 2000.0 * fd / r)
    with pytest.raises(ValueError, match="focal length, scale and r must be positive"):
        orthophoto_dtm_tolerance(150.0, 2000.0, 0.0)


def test_orthophoto_block_tolerances_use_dtm_third():
    spec = QASpec("orthophoto", map_scale=2000)
    t = block_tolerances(spec, focal_length_mm=150.0, working_radius_mm=134.0)
    assert t.gcp_z == pytest.approx(0.3e-3 * 2000 * 150 / 134 / 3)
    assert t.check_z == t.gcp_z
    assert t.gcp_xy == pytest.approx(0.4) and t.check_xy == pytest.approx(0.6)
    # orthophoto_scale takes precedence over map_scale
    spec2 = QASpec("orthophoto", map_scale=10000, orthophoto_scale=2000)
    assert block_tolerances(spec2).gcp_xy == pytest.approx(0.4)
    assert block_tolerances(spec2).gcp_z is None


# ------------------------------------------------------------------------ spec
def test_spec_from_dict_and_scale_strings():
    s = QASpec.from_dict({"product": "Topographic_Map", "map_scale": "1:2000",
                          "contour_interval": 1, "terrain": "Hilly"})
    assert (s.product, s.map_scale, s.terrain) == ("topographic map", 2000.0, "hilly")
    assert json.loads(json.dumps(s.as_dict()))["map_scale"] == 2000.0
    assert QASpec.from_dict({"product": "orthomosaic", "orthophoto_scale": 5000}).terrain == "flat"


@pytest.mark.parametrize(
    "d, key, words",
    [
        ({"product": "vector map"}, "product", ["topographic map", "orthophoto"]),
        ({"map_scale": 2000}, "product", ["topographic map"]),
        ({"product": "orthophoto", "scale": 2000}, "keys", ["scale", "orthophoto_scale"]),
        ({"product": "topographic map", "map_scale": 2000}, "contour_interval", []),
        ({"product": "topographic map", "map_scale": -5, "contour_interval": 1},
         "map_scale", ["2000"]),
        ({"product": "topographic map", "map_scale": "2:2000", "contour_interval": 1},
         "map_scale", []),
        ({"product": "topographic map", "map_scale": 2000, "contour_interval": True},
         "contour_interval", []),
        ({"product": "orthophoto"}, "orthophoto_scale", []),
        ({"product": "orthomosaic", "orthophoto_scale": 2000, "terrain": "alpine"},
         "terrain", ["mountainous"]),
    ],
)
def test_spec_errors_name_the_key_and_allowed_values(d, key, words):
    with pytest.raises(ProjectError, match=r"^\[qa\] .+\. (set|use only|add|give) ") as err:
        QASpec.from_dict(d)
    msg = str(err.value)
    assert "[qa]" in msg
    if key == "keys":
        assert "scale" in err.value.details["keys"]
    else:
        assert key in msg and err.value.details["key"] == key
    for w in words:
        assert w in msg


# ---------------------------------------------------------------- parallax
def test_parallax_stats_definitions():
    s = parallax_stats([0.003, -0.006, 0.0, np.nan], 0.012)
    assert s.n == 3
    assert s.mean_um == pytest.approx(3.0)
    assert s.rms_um == pytest.approx(math.sqrt(15.0))
    assert s.max_um == pytest.approx(6.0)
    assert (s.mean_px, s.max_px) == (pytest.approx(0.25), pytest.approx(0.5))
    assert s.rms_px == pytest.approx(math.sqrt(15.0) / 12.0)
    empty = parallax_stats([], 0.012)
    assert empty.n == 0 and json.loads(json.dumps(empty.as_dict()))["mean_um"] is None


def test_vertical_parallax_zero_for_intersecting_rays_any_attitude():
    rng = np.random.default_rng(3)
    f = 152.4
    eo_l = np.array([1000.0, 2000.0, 1500.0, 0.02, -0.03, 0.4])
    eo_r = np.array([1550.0, 2040.0, 1520.0, -0.01, 0.025, 0.38])
    pts = np.column_stack([rng.uniform(1100, 1450, 50), rng.uniform(1800, 2200, 50),
                           rng.uniform(0, 120, 50)])
    py = vertical_parallax(project(eo_l, pts, f), project(eo_r, pts, f), eo_l, eo_r, f)
    assert np.max(np.abs(py)) < 1e-10
    # a y error on one image is not coplanar any more
    xr = project(eo_r, pts, f)
    xr[:, 1] += 0.01
    py2 = vertical_parallax(project(eo_l, pts, f), xr, eo_l, eo_r, f)
    assert np.all(np.abs(py2) > 0.005)


def test_vertical_parallax_normal_case_is_y_difference():
    f = 150.0
    eo_l = np.array([0.0, 0.0, 1500.0, 0.0, 0.0, 0.0])
    eo_r = np.array([920.0, 0.0, 1500.0, 0.0, 0.0, 0.0])
    xl = np.array([[10.0, 20.0], [-30.0, 5.0]])
    xr = np.array([[-80.0, 19.99], [-120.0, 5.02]])
    np.testing.assert_allclose(vertical_parallax(xl, xr, eo_l, eo_r, f), [0.01, -0.02],
                               atol=1e-12)


def test_parallax_stages_mean_and_max():
    py = np.array([0.3, 0.2, -0.4, 1.2]) * 0.012  # pixels -> mm
    mean_stage, max_stage = parallax_stages("L-R", py, ["a", "b", "c", "d"], 0.012)
    assert mean_stage.measured == pytest.approx(0.525)
    assert mean_stage.passed is False and mean_stage.failed_ids == ["d"]
    assert max_stage.measured == pytest.approx(1.2) and max_stage.passed is False
    ok = parallax_stages("L-R", py[:3], None, 0.012)
    assert all(s.passed for s in ok)


def test_model_discrepancies_at_image_scale():
    a = np.array([[100.0, 200.0, 50.0], [0.0, 0.0, 0.0]])
    b = a - np.array([[3.0, 4.0, -2.0], [0.0, 0.0, 0.0]])
    e_xy, e_z = model_discrepancies(a, b, 10000.0)
    np.testing.assert_allclose(e_xy, [0.5, 0.0])
    np.testing.assert_allclose(e_z, [0.2, 0.0])


# ------------------------------------------------------------ stages, verdict
def test_check_stage_statistics_and_point_limits():
    v = [0.1, -0.2, 0.3]
    s = check_stage("x", v, ["a", "b", "c"], 0.25, "mean")
    assert s.measured == pytest.approx(0.2) and s.point_tolerance == pytest.approx(0.5)
    assert s.passed is True and s.status == "pass"
    s = check_stage("x", v, None, 0.2, "rms")
    assert s.measured == pytest.approx(math.sqrt(14 / 300))
    assert s.point_tolerance == pytest.approx(0.2 * math.sqrt(2)) and s.passed is False
    assert s.failed_ids == [2]
    s = check_stage("x", v, None, 0.3, "max")
    assert s.measured == pytest.approx(0.3) and s.passed is True
    # mean within tolerance but one point over the limit: the stage fails
    s = check_stage("x", [0.01] * 9 + [0.5], None, 0.1, "mean")
    assert s.measured < 0.1 and s.passed is False and s.failed_ids == [9]
    # nothing measured
    s = check_stage("x", [np.nan], ["p"], 0.1)
    assert s.passed is None and s.status == "n/a" and s.rows[0]["passed"] is None
    with pytest.raises(ValueError, match="1 ids for 3 values"):
        check_stage("x", v, ["a"], 0.1)
    with pytest.raises(ValueError,
                       match=r"statistic must be one of \('mean', 'rms', 'max'\), got 'median'"):
        check_stage("x", v, None, 0.1, "median")


def test_verdict_lists_nonconformities_first_and_is_json():
    good = check_stage("interior orientation", [0.5, 0.8], ["F1", "F2"], 1.0, "max",
                       unit="px")
    bad = check_stage("block: GCP XY", [0.01, 2.0, 0.9, 0.02], ["g1", "g2", "g3", "g4"],
                      0.4, "mean", unit="m")
    none = check_stage("triplets", [], [], 0.008)
    v = qa_verdict([good, none, bad])
    assert v.passed is False
    assert [s.name for s in v.stages] == ["block: GCP XY", "interior orientation", "triplets"]
    assert v.nonconformities[0]["ids"] == ["g2", "g3"]  # worst first
    assert v.remeasure == ["g2", "g3"]
    d = json.loads(json.dumps(v.as_dict()))
    assert d["verdict"] == "fail" and d["stages"][0]["status"] == "fail"
    assert d["nonconformities"][0]["stage"] == "block: GCP XY"
    assert qa_verdict([good, none]).passed is True


# ---------------------------------------------------------- control points
def test_one_gcp_shifted_by_one_metre_fails_exactly_that_gcp():
    rng = np.random.default_rng(11)
    ids = [f"G{i:02d}" for i in range(11)]
    res = rng.normal(0.0, 0.02, (11, 3))  # tiny residuals, 2 cm
    res[6] += [0.8, 0.6, 0.0]  # 1 m horizontal shift
    spec = QASpec("topographic map", map_scale=2000, contour_interval=1.0)
    qa = control_point_qa(ids, res, ["control"] * 11, spec)
    assert qa.failed_ids == ["G06"]
    assert qa.qa_field == ["fail" if i == 6 else "pass" for i in range(11)]
    stages = {s.name: s for s in qa.stages}
    assert set(stages) == {"block: GCP XY", "block: GCP Z"}
    assert stages["block: GCP XY"].passed is False
    assert stages["block: GCP XY"].failed_ids == ["G06"]
    assert stages["block: GCP Z"].passed is True
    v = qa_verdict(qa.stages)
    assert v.remeasure == ["G06"]


def test_vertical_shift_and_roles():
    spec = QASpec("topographic map", map_scale=2000, contour_interval=1.0)
    res = np.zeros((4, 3))
    res[0, 2] = 1.0  # GCP 1 m high: limit 2 x 0.15 = 0.3 m
    res[1, 0] = 0.9  # GCP 0.9 m off: limit 2 x 0.4 = 0.8 m -> fails
    res[2, 0] = 0.9  # check point 0.9 m off: limit 2 x 0.6 = 1.2 m -> passes
    res[3, 2] = 0.35  # check point 0.35 m high: limit 2 x 0.2 = 0.4 m -> passes
    qa = control_point_qa(["a", "b", "c", "d"], res, ["control", "GCP", "check", "check"], spec)
    assert qa.passed.tolist() == [False, False, True, True]
    assert qa.roles == ["control", "control", "check", "check"]
    np.testing.assert_allclose(qa.tol_xy, [0.8, 0.8, 1.2, 1.2])
    np.testing.assert_allclose(qa.tol_z, [0.3, 0.3, 0.4, 0.4])
    # the strict reading: every point within the mean tolerance itself
    strict = control_point_qa(["a", "b", "c", "d"], res, ["control", "gcp", "check", "check"],
                              spec, point_rule="mean")
    assert strict.passed.tolist() == [False, False, False, False]
    with pytest.raises(ControlError,
                       match=r"'a' has role 'tie'\. set role to 'control' or 'check'") as err:
        control_point_qa(["a"], np.zeros((1, 3)), ["tie"], spec)
    assert "'a'" in str(err.value)


def test_orthomosaic_control_points_check_xy_only():
    spec = QASpec("orthomosaic", orthophoto_scale=2000, terrain="mountainous")
    res = np.array([[1.0, 0.0, 50.0], [3.0, 0.0, 0.0]])
    qa = control_point_qa(["a", "b"], res, ["control", "check"], spec)
    assert qa.passed.tolist() == [True, False]  # limit 2 x 1.4 m, heights not checked
    assert np.isnan(qa.tol_z).all()
    assert [s.name for s in qa.stages] == ["block: GCP XY", "block: check XY"]
