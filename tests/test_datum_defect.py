"""The datum without surveyed control: defect analysis, camera priors, control databases,
the free network (issue 29)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.adjust.bundle import adjust
from vectoradjust.adjust.datum import (
    DATUM_PARAMETERS,
    analyse_datum,
    block_frame,
    camera_helmert,
    check_datum,
    point_helmert,
)
from vectoradjust.errors import DatumError
from vectoradjust.model import ControlPoints
from vectoradjust.pipeline import run
from vectoradjust.sensor.collinearity import project
from vectoradjust.simulate import make_scenario
from vectoradjust.simulate.block import make_block

INF = np.inf


@pytest.fixture(scope="module")
def block():
    """Two strips of four images along X, control, tie and shape points."""
    return make_block(n_strips=2, images_per_strip=4, n_shape_points=300, n_control=8, seed=3)


def _priors(block, *, control=None, control_axes=(0, 1, 2), shape=False, pos=None,
            att=None, images=None):
    """Prior weights (points) and EO weights of a variant of the block."""
    p = block.problem
    w = np.zeros_like(p.prior_weight)
    kind = block.point_kind
    if control is not None:
        idx = np.flatnonzero(kind == "control")[:control]
        for a in control_axes:
            w[idx, a, a] = 1.0 / 0.02 ** 2
    if shape:
        idx = np.flatnonzero(kind == "shape")
        w[idx] = p.prior_weight[idx]
    we = np.zeros((p.n_images, 6))
    sel = np.arange(p.n_images) if images is None else np.asarray(images)
    if pos is not None:
        we[sel, :3] = 1.0 / pos ** 2
    if att is not None:
        we[sel, 3:] = 1.0 / np.radians(att) ** 2
    return w, we


def _analyse(block, w, we, g=None, gw=None):
    eo = block.true_eo.copy()
    eo[:4, 1:3] = eo[:4, 1:3].mean(axis=0)  # the first strip exactly on one line (along X)
    return analyse_datum(eo, block.true_xyz, w, we, g, gw)


def test_similarity_columns_leave_every_projection_unchanged(block):
    """The seven columns are the null space of the image observations (to first order)."""
    p = block.problem
    c, ext = block_frame(block.true_eo, block.true_xyz)
    ge, gp = camera_helmert(block.true_eo, c, ext), point_helmert(block.true_xyz, c, ext)
    for k in range(7):
        th = np.zeros(7)
        th[k] = 1e-3  # 1 mm at the block's extent
        eo2, x2 = block.true_eo + ge @ th, block.true_xyz + gp @ th
        worst = 0.0
        for i in range(p.n_images):
            pts = p.obs_point[p.obs_image == i]
            d = project(eo2[i], x2[pts], p.focal_length) - project(block.true_eo[i],
                                                                    block.true_xyz[pts],
                                                                    p.focal_length)
            worst = max(worst, float(np.abs(d).max()))
        moved = float(np.abs(gp @ th).max())
        assert moved > 5e-4  # the points really moved ...
        assert worst < 1e-8, DATUM_PARAMETERS[k]  # ... and no image saw it (mm)


def test_doctests_of_the_module():
    import doctest

    import vectoradjust.adjust.datum as mod

    result = doctest.testmod(mod)
    assert result.attempted >= 3 and result.failed == 0


def _free(a):
    return [p for p, d in zip(DATUM_PARAMETERS, a.determined) if not d]


# the ten kinds of missing datum: what is given, what must be reported free, the message
KINDS = [
    ("nothing", {}, list(DATUM_PARAMETERS), "Nothing fixes the block in space"),
    ("one control point", {"control": 1},
     ["rotation about X", "rotation about Y", "rotation about Z", "scale"],
     "can tilt .*turn about the vertical.*scale is free"),
    # (the tilts are fixed, weakly, by the control points' height differences)
    ("planimetric control only", {"control": 4, "control_axes": (0, 1)},
     ["Z shift"], "move freely in height.*give heights to the control points"),
    # (the scale is fixed, weakly, by the heights' spread)
    ("height control only", {"control": 4, "control_axes": (2,)},
     ["X shift", "Y shift", "rotation about Z"],
     "move freely in X and Y.*turn about the vertical"),
    ("attitude priors only", {"att": 0.01},
     ["X shift", "Y shift", "Z shift", "scale"], "move freely in X and Y.*in height.*scale"),
    ("position prior on one image", {"pos": 0.1, "images": [0]},
     ["rotation about X", "rotation about Y", "rotation about Z", "scale"],
     "can tilt.*turn.*scale"),
    ("positions of one strip, no attitude", {"pos": 0.1, "images": [0, 1, 2, 3]},
     ["rotation about X"], r"can tilt \(about the X axis\)"),
    ("position priors on both strips: complete", {"pos": 0.1}, [], None),
    ("roads whose shift is estimated", {"shape": True, "offset": "shift"},
     ["X shift", "Y shift"], r"move freely in X and Y.*role = \"control\""),
    ("roads with a free 3D shift", {"shape": True, "offset": "shift3d"},
     ["X shift", "Y shift", "Z shift"], "move freely in X and Y.*in height"),
]


@pytest.mark.parametrize("name,given,free,message", KINDS, ids=[k[0] for k in KINDS])
def test_each_missing_datum_is_named(block, name, given, free, message):
    offset = given.pop("offset", None) if "offset" in given else None
    w, we = _priors(block, **{k: v for k, v in given.items()})
    g = gw = None
    if offset:  # one database: all shape points with a freely estimated shift
        q = 2 if offset == "shift" else 3
        g = np.zeros((block.problem.n_points, 3, q))
        idx = np.flatnonzero(block.point_kind == "shape")
        for a in range(q):
            g[idx, a, a] = 1.0
        gw = np.zeros(q)
    a = _analyse(block, w, we, g, gw)
    assert _free(a) == free
    if message is None:
        check_datum(a)  # complete: no error
        assert np.isfinite(a.sigma).all() and (a.sigma < 1.0).all()
    else:
        with pytest.raises(DatumError, match=message):
            check_datum(a)


def test_two_control_points_leave_the_rotation_about_their_line(block):
    """Two control points: one combined rotation (about their line) is free."""
    w, we = _priors(block, control=2)
    a = _analyse(block, w, we)
    assert len(a.free_directions) == 1
    with pytest.raises(DatumError, match="datum is not fixed"):
        check_datum(a)


def test_a_control_database_prior_on_its_shift_fixes_the_datum(block):
    """The offset with a prior (systematic part 1 m) fixes the shift to about 1 m."""
    w, we = _priors(block, shape=True)
    idx = np.flatnonzero(block.point_kind == "shape")
    g = np.zeros((block.problem.n_points, 3, 3))
    for a_ in range(3):
        g[idx, a_, a_] = 1.0
    a = _analyse(block, w, we, g, np.full(3, 1.0))
    check_datum(a)
    assert a.sigma[:2] == pytest.approx([1.0, 1.0], rel=0.05)  # not sigma / sqrt(n)


def test_camera_position_priors_alone_cover_the_truth():
    """Monte Carlo: GNSS positions (0.5 m) and no control; image positions and points
    within their 90 % ellipse about 90 % of the time."""
    inside_img, inside_pt, n_img, n_pt = 0, 0, 0, 0
    for seed in range(40):  # the points of one block share its datum error: many blocks
        b = make_block(n_strips=2, images_per_strip=5, n_shape_points=60, n_control=4,
                       seed=seed, position_noise=0.5, attitude_noise=0.3,
                       sigma_position=0.5, sigma_attitude=1e9)
        p = b.problem
        rng = np.random.default_rng(100 + seed)
        eo0 = b.true_eo.copy()  # GNSS: truth plus N(0, 0.5 m); attitude only approximate
        eo0[:, :3] += rng.normal(0.0, 0.5, (p.n_images, 3))
        eo0[:, 3:] += np.radians(rng.normal(0.0, 0.3, (p.n_images, 3)))
        sig = np.tile([0.5, 0.5, 0.5, np.inf, np.inf, np.inf], (p.n_images, 1))
        w = np.zeros_like(p.prior_weight)  # no control, no roads: the cameras alone
        prob = replace(p, eo0=eo0, eo_sigma=sig, prior_weight=w)
        a = analyse_datum(prob.eo0, prob.xyz0, prob.prior_weight, prob.eo_weight)
        check_datum(a)
        r = adjust(prob)
        d = r.eo[:, :3] - b.true_eo[:, :3]
        cov = r.eo_cov[:, :3, :3] / r.variance_factor  # a-priori: the stated sigmas
        m2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
        inside_img += int((m2 < 6.251).sum())  # chi-square 3 dof, 90 %
        n_img += len(d)
        sel = np.flatnonzero(b.point_kind != "tie")[:10]
        dp = r.xyz[sel] - b.true_xyz[sel]
        cp = r.point_cov[sel] / r.variance_factor
        m2p = np.einsum("ni,nij,nj->n", dp, np.linalg.inv(cp), dp)
        inside_pt += int((m2p < 6.251).sum())
        n_pt += len(sel)
    assert 0.84 <= inside_img / n_img <= 0.96
    assert 0.84 <= inside_pt / n_pt <= 0.96


def test_free_network_keeps_distances_and_says_relative(block):
    """Free network: no priors; distances equal those with control within their
    precision; dof gains the seven datum parameters."""
    p = block.problem
    r = adjust(p)
    fp = replace(p, prior_weight=np.zeros_like(p.prior_weight), eo0=r.eo.copy(),
                 eo_sigma=np.full(p.eo_sigma.shape, np.inf), free_datum=True)
    rf = adjust(fp)
    assert rf.dof == fp.counts()[0] - fp.counts()[1]
    assert rf.sigma0_squared == pytest.approx(1.0, abs=0.15)
    tie = np.flatnonzero(block.point_kind == "tie")
    i, j = tie[:40], tie[40:80]
    d_free = np.linalg.norm(rf.xyz[i] - rf.xyz[j], axis=1)
    d_ctrl = np.linalg.norm(r.xyz[i] - r.xyz[j], axis=1)
    # precision of the free network's distances from its covariances (the points' joint
    # covariance is not needed for a bound: sigma_d <= sigma_i + sigma_j)
    s_i = np.sqrt(np.einsum("nii->n", rf.point_cov[i]))
    s_j = np.sqrt(np.einsum("nii->n", rf.point_cov[j]))
    assert (np.abs(d_free - d_ctrl) < 3.0 * (s_i + s_j)).all()
    assert np.abs(d_free - d_ctrl).max() > 0.0  # really two adjustments
    # the inner constraints keep the cameras' centroid of the approximations
    assert np.abs((rf.eo[:, :3] - fp.eo0[:, :3]).mean(axis=0)).max() < 1e-3


@pytest.fixture(scope="module")
def scenario():
    return make_scenario(0)


def _no_control(data):
    c = data.control
    keep = c.role == "check"
    data.control = ControlPoints(c.point_id[keep], c.xyz[keep], c.sigma[keep], c.role[keep])
    for im in data.images:
        im.sigma_position = None
        im.sigma_attitude = None
    return data


def test_run_without_any_datum_stops_with_the_fix(scenario):
    data = _no_control(scenario.to_project_data())
    with pytest.raises(DatumError, match=r"move freely in X and Y.*role = \"control\""):
        run(data)


def test_run_with_a_control_database(scenario):
    """OSM as control (1.5 m, of which 1 m systematic): runs, says so, and no vertex is
    claimed better than the systematic part allows."""
    data = _no_control(scenario.to_project_data())
    data.vectors = [(replace(spec, role="control", systematic_sigma=(1.0, 1.0),
                             sigma=(1.5, 1.5, 3.0)) if spec.name == "OSM" else spec, lay)
                    for spec, lay in data.vectors]
    out = run(data)
    rec = out.summary["datum"]
    assert rec["kind"] == "prior information"
    assert any("OSM as control" in s for s in rec["sources"])
    assert rec["parameters"]["X shift"]["sigma_m_at_extent"] == pytest.approx(1.0, rel=0.05)
    for d in out.databases:
        cov = out.result.point_cov[d.vertex_point[d.vertex_point >= 0]]
        sx = np.sqrt(cov[:, 0, 0] / out.result.variance_factor)
        assert sx.min() > 0.9, d.name  # the 1 m common error is in every vertex
    assert "OSM" not in (out.summary.get("roads_and_control") or {}).get("text", "OSM")


def test_run_free_network(scenario):
    data = scenario.to_project_data()
    data.settings.datum = "free"
    out = run(data)
    assert out.summary["datum"]["kind"] == "free network"
    assert "relative" in out.summary["datum"]["note"]
    assert out.problem.free_datum
    assert any("free network" in w for w in out.warnings)


def test_single_image_resection_from_a_control_database():
    """One image, no control points: the road vertices of a control database (an OSM
    whose errors are what its entry states: a common 1 m shift, 1.1 m per vertex) and an
    EXIF-like GPS position (3 m horizontal, 5 m vertical) resect it; the position is
    within its sigmas of the truth and carries the database's systematic part."""
    from vectoradjust.simulate import DatabaseModel

    osm = DatabaseModel("OSM", "osm_id", "osm", 20.0, 0.4, (0.8, -0.6), 0.0, 0.0, 1.118)
    scenario = make_scenario(4, databases=[osm])
    data = scenario.to_project_data()
    c = data.control
    m = data.measurements
    on_l = (m.image_id == "L") & ~np.isin(m.point_id, c.point_id)
    on_l &= ~np.char.startswith(m.point_id.astype(str), "T")  # tie points need two images
    data.control = ControlPoints(c.point_id[:0], c.xyz[:0], c.sigma[:0], c.role[:0])
    data.measurements = replace(m, point_id=m.point_id[on_l], image_id=m.image_id[on_l],
                                xy=m.xy[on_l], sigma=m.sigma[on_l], rows=m.rows[on_l])
    data.images = [im for im in data.images if im.id == "L"]
    data.images[0].sigma_position = (3.0, 3.0, 5.0)
    data.images[0].sigma_attitude = None
    data.vectors = [(replace(spec, role="control", systematic_sigma=(1.0, 1.0),
                             sigma=(1.5, 1.5, 3.0)) if spec.name == "OSM" else spec, lay)
                    for spec, lay in data.vectors]
    out = run(data)
    assert out.image_ids == ["L"]
    rec = out.summary["datum"]
    assert rec["sources"][0] == "camera position priors on 1 of 1 image(s)"
    sig = np.sqrt(np.diag(out.result.eo_cov[0]) / out.result.variance_factor)
    err = out.result.eo[0] - scenario.true_eo[0]
    assert (np.abs(err[:3]) < 3.0 * sig[:3]).all(), (err, sig)
    assert (sig[:2] > 1.0).all()  # at least the control database's systematic 1 m


def test_sigma_position_per_axis_in_the_project():
    from vectoradjust.errors import ProjectError
    from vectoradjust.files.project import parse_project

    raw = {"crs": "EPSG:32616", "camera": {"focal_length": 152.4},
           "images": [{"id": "L", "position": [0, 0, 800], "sigma_position": [3, 3, 5],
                       "sigma_attitude": 0.5}],
           "measurements": {"path": "m.csv"}}
    spec = parse_project(raw, base_dir=".")
    assert spec.images[0].sigma_position == (3.0, 3.0, 5.0)
    assert spec.images[0].sigma_attitude == 0.5
    raw["images"][0]["sigma_position"] = [3, 5]
    with pytest.raises(ProjectError, match=r"sigma_position must be a list of 3 numbers"):
        parse_project(raw, base_dir=".")
