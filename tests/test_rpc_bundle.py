"""RPC images in the bundle adjustment (the sensor seam): simulated truth and real GCPs.

The simulated blocks here use small analytic RPCs (a stereo pair of "affine" satellite
views with mild rational terms) in an exact local East-North-Up ground frame, so that the
truth of every bias parameter and point is known; ``tests/test_satellite_sim.py`` checks
the pushbroom simulator, ``tests/test_rpc.py`` the RPC model itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.adjust.bundle import BundleProblem, adjust, intersect
from vectoradjust.errors import ProjectError
from vectoradjust.sensor.ground import EnuFrame
from vectoradjust.sensor.models import RpcImage, SensorSet, observe_rpc
from vectoradjust.sensor.rpc import RpcModel

RPC_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rpc"
FRAME = EnuFrame(-87.0, 40.4, 0.0)


def toy_rpc(tilt: float) -> RpcModel:
    """A 10 000 px image over about 5 km; ``tilt`` is the column's height parallax."""
    z = np.zeros(20)
    den = z.copy()
    den[0] = 1.0
    samp, line = z.copy(), z.copy()
    samp[[1, 3, 7, 10]] = [1.0, tilt, 0.01, 0.002]
    line[[2, 3, 8]] = [-1.0, 0.05, 0.005]
    sden = den.copy()
    sden[[1, 3]] = [0.001, 0.0005]
    return RpcModel(line_off=5000.0, samp_off=5000.0, lat_off=40.4, long_off=-87.0,
                    height_off=200.0, line_scale=5000.0, samp_scale=5000.0, lat_scale=0.0225,
                    long_scale=0.0295, height_scale=500.0, line_num=line, line_den=den,
                    samp_num=samp, samp_den=sden)


def simulate(bias: str, true_bias: np.ndarray, seed: int, n_points: int = 60,
             n_control: int = 6, sigma_px: float = 0.3, tilts=(0.3, -0.3)):
    """A block of RPC images with known truth: problem, true points, control mask."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(-1500, 1500, n_points), rng.uniform(-1500, 1500, n_points),
                           rng.uniform(150, 250, n_points)])
    llh, jac = FRAME.to_geodetic(xyz)
    images = [RpcImage(toy_rpc(t), bias) for t in tilts]
    pt, im, obs = [], [], []
    for i, img in enumerate(images):
        cr, _, _ = observe_rpc(img, true_bias[i], llh, jac)
        pt.append(np.arange(n_points))
        im.append(np.full(n_points, i))
        obs.append(cr + rng.normal(0, sigma_px, cr.shape))
    ctrl = np.arange(n_points) < n_control
    w = np.zeros((n_points, 3, 3))
    w[ctrl] = np.eye(3) / 0.05**2
    prior = np.where(ctrl[:, None], xyz + rng.normal(0, 0.05, xyz.shape), 0.0)
    xyz0 = np.where(ctrl[:, None], prior, xyz + rng.normal(0, 30, xyz.shape))
    obs = np.concatenate(obs)
    prob = BundleProblem(np.nan, (0, 0), np.zeros((len(images), 6)),
                         np.full((len(images), 6), np.inf), xyz0, prior, w, np.concatenate(pt),
                         np.concatenate(im), obs, np.full(obs.shape, sigma_px),
                         sensors=SensorSet(images, FRAME))
    return prob, xyz, ctrl


def test_observe_rpc_partials_match_finite_differences():
    img = RpcImage(toy_rpc(0.3), "affine")
    p = np.array([2.0, 0.5, -0.7, -1.0, 0.3, 0.4])
    xyz = np.array([[120.0, -340.0, 180.0], [-900.0, 1100.0, 240.0]])
    llh, jac = FRAME.to_geodetic(xyz)
    _, d_par, d_xyz = observe_rpc(img, p, llh, jac)
    for k in range(3):
        h = np.zeros(3)
        h[k] = 0.01
        up = observe_rpc(img, p, *FRAME.to_geodetic(xyz + h))[0]
        dn = observe_rpc(img, p, *FRAME.to_geodetic(xyz - h))[0]
        np.testing.assert_allclose(d_xyz[:, :, k], (up - dn) / 0.02, rtol=1e-6, atol=1e-5)
    for k in range(6):
        h = np.zeros(6)
        h[k] = 1e-3
        up = observe_rpc(img, p + h, llh, jac)[0]
        dn = observe_rpc(img, p - h, llh, jac)[0]
        np.testing.assert_allclose(d_par[:, :, k], (up - dn) / 2e-3, rtol=1e-7, atol=1e-9)


def test_shift_bias_and_points_recovered():
    true = np.array([[3.0, 0, 0, -2.0, 0, 0], [-1.5, 0, 0, 2.5, 0, 0]])
    prob, xyz, ctrl = simulate("shift", true, seed=1)
    res = adjust(prob)
    n_obs, n_unk = prob.counts()
    # 4 image observations per point, 3 priors per control point; 2 x 2 bias unknowns
    assert n_obs == 4 * 60 + 3 * 6 and n_unk == 4 + 3 * 60 and res.dof == n_obs - n_unk
    sd = np.sqrt(np.diagonal(res.eo_cov, axis1=1, axis2=2))
    free = np.array([True, False, False, True, False, False])
    assert np.all(np.abs(res.eo[:, free] - true[:, free]) < 4 * sd[:, free])
    assert np.all(sd[:, ~free] == 0.0) and np.all(res.eo[:, ~free] == 0.0)
    assert 0.6 < res.sigma0_squared < 1.5
    tie = ~ctrl
    psd = np.sqrt(np.diagonal(res.point_cov[tie], axis1=1, axis2=2))
    z = np.abs(res.xyz[tie] - xyz[tie]) / psd
    assert np.mean(z < 1.645) > 0.8


@pytest.mark.slow
@pytest.mark.parametrize("bias,true", [
    ("shift", [[3.0, 0, 0, -2.0, 0, 0], [-1.5, 0, 0, 2.5, 0, 0]]),
    ("shift+drift", [[3.0, 0, 1.2, -2.0, 0, -0.8], [-1.5, 0, -0.6, 2.5, 0, 0.9]]),
    ("affine", [[3.0, 0.7, 1.2, -2.0, -0.4, -0.8], [-1.5, 0.3, -0.6, 2.5, 0.5, 0.9]]),
])
def test_bias_coverage_monte_carlo(bias, true):
    """Each estimated bias parameter lies within its 90 % interval about 90 % of the time."""
    true = np.asarray(true)
    hits, n = [], 0
    for seed in range(150):
        prob, _, _ = simulate(bias, true, seed=seed)
        res = adjust(prob)
        free = ~prob.eo_fixed
        sd = np.sqrt(np.diagonal(res.eo_cov, axis1=1, axis2=2))[free]
        hits.append(np.abs(res.eo[free] - true[free]) < 1.645 * sd)
        n += 1
    rate = np.mean(hits)
    assert 0.85 <= rate <= 0.95, rate


def test_affine_without_enough_control_is_refused():
    from vectoradjust.adjust.intersection import check_bias_determined, pts_have_prior

    true = np.zeros((2, 6))
    prob, _, _ = simulate("affine", true, seed=3, n_control=1)
    with pytest.raises(ProjectError, match=r"bias = 'affine' cannot be determined.*has 1") as e:
        check_bias_determined(prob.sensors, prob.eo_sigma, prob.obs_point, prob.obs_image,
                              prob.obs_xy, pts_have_prior(prob.prior_weight), ["P1", "P2"])
    assert "bias_sigma" in e.value.mend and "'P1'" in e.value.what
    # a prior on the bias parameters determines it: no refusal
    check_bias_determined(prob.sensors, np.full((2, 6), 2.0), prob.obs_point, prob.obs_image,
                          prob.obs_xy, pts_have_prior(prob.prior_weight), ["P1", "P2"])


def test_check_points_intersected_through_rpc():
    true = np.array([[3.0, 0, 0, -2.0, 0, 0], [-1.5, 0, 0, 2.5, 0, 0]])
    prob, xyz, ctrl = simulate("shift", true, seed=5, sigma_px=0.05)
    res = adjust(prob)
    tie = np.flatnonzero(~ctrl)[:10]
    sel = np.isin(prob.obs_point, tie)
    pos = np.searchsorted(tie, prob.obs_point[sel])
    got, cov = intersect(res.eo, pos, prob.obs_image[sel], prob.obs_xy[sel],
                         prob.obs_sigma[sel], len(tie), np.nan, (0, 0),
                         eo_cov_full=res.eo_cofactor(), sensors=prob.sensors)
    assert np.abs(got - xyz[tie]).max() < 0.3
    assert np.all(np.isfinite(cov))


def _quickbird():
    folder = RPC_DATA / "quickbird2"
    if not (folder / "qb2_basic1b.tif").is_file():
        pytest.skip(f"QuickBird sample not found: {folder} (shared data absent)")
    pytest.importorskip("rasterio")
    from vectoradjust.files.rpc import read_rpc

    rpc = read_rpc(folder / "qb2_basic1b.tif")
    gcps = json.loads((folder / "gcps.geojson").read_text())["features"]
    llh = np.array([g["geometry"]["coordinates"] for g in gcps], float)
    # ji is in the raw RPC (pixel centre) convention of the orthority project
    # (tests/test_rpc.py); the product measures in GDAL's, half a pixel further
    ji = np.array([g["properties"]["ji"] for g in gcps], float) + 0.5
    return rpc, llh, ji


@pytest.mark.io
def test_quickbird_shift_leave_one_out():
    """Real QuickBird GCPs: the raw RPC misses by ~3 px; a shift estimated in the bundle
    from the other in-image GCPs predicts each held-out GCP within 0.3 px."""
    rpc, llh, ji = _quickbird()
    inside = (ji[:, 1] >= 0) & (ji[:, 0] >= 0)
    frame = EnuFrame(*llh[inside].mean(axis=0))
    xyz = frame.from_geodetic(llh)
    raw = rpc.project(llh[:, 0], llh[:, 1], llh[:, 2])
    miss = (raw - ji)[inside]
    assert np.all(np.abs(miss.mean(axis=0) - [2.98, 2.09]) < 0.05), miss  # README's ~3 / 2.1
    misses = []
    for out in np.flatnonzero(inside):
        use = np.flatnonzero(inside & (np.arange(len(ji)) != out))
        w = np.repeat(np.eye(3)[None] / 0.1**2, len(use), axis=0)
        prob = BundleProblem(np.nan, (0, 0), np.zeros((1, 6)), np.full((1, 6), np.inf),
                             xyz[use], xyz[use], w, np.arange(len(use)), np.zeros(len(use), int),
                             ji[use], np.full((len(use), 2), 0.5),
                             sensors=SensorSet([RpcImage(rpc, "shift")], frame))
        res = adjust(prob)
        pred, _, _ = observe_rpc(prob.sensors.rpc[0], res.eo[0], *frame.to_geodetic(xyz[[out]]))
        misses.append(float(np.hypot(*(pred[0] - ji[out]))))
    assert max(misses) < 0.3, misses


def rpc_project(seed: int = 0, bias: str = "shift", sigma_px: float = 0.3):
    """A whole project in memory: an RPC pair, 8 GCPs (2 of them check points) and a
    road database 1.5 m off with 0.7 m noise, its vertices measured with 0.3 m
    identification error; returns the ProjectData and the true vertices."""
    from vectoradjust.model import (
        Camera,
        ControlPoints,
        ImageSpec,
        LineLayer,
        Measurements,
        ProjectData,
        VectorSpec,
    )

    rng = np.random.default_rng(seed)
    true_bias = np.array([[3.0, 0, 0, -2.0, 0, 0], [-1.5, 0, 0, 2.5, 0, 0]])
    imgs = [ImageSpec(n, np.zeros(3), np.zeros(3), model="rpc", rpc=RpcImage(toy_rpc(t), bias))
            for n, t in (("P1", 0.3), ("P2", -0.3))]
    gcp = np.column_stack([rng.uniform(-1500, 1500, 8), rng.uniform(-1500, 1500, 8),
                           rng.uniform(150, 250, 8)])
    nf, nv = 12, 6
    start = rng.uniform(-1200, 1200, (nf, 2))
    d = rng.normal(0, 1, (nf, 2))
    d /= np.linalg.norm(d, axis=1)[:, None]
    xy = start[:, None, :] + (np.arange(nv) * 80.0)[None, :, None] * d[:, None, :]
    true = np.concatenate([xy.reshape(-1, 2), (200 + 0.01 * xy[..., 0]).reshape(-1, 1)], axis=1)
    db = true + np.array([1.5, -1.0, 0.0]) + rng.normal(0, 0.7, true.shape) * [1, 1, 0.1]
    vf, vi = np.repeat(np.arange(nf), nv), np.tile(np.arange(nv), nf)
    layer = LineLayer("OSM", np.array([f"r{i}" for i in range(nf)]),
                      {"name": [f"road {i}" for i in range(nf)]}, db, vf, vi,
                      np.zeros(len(vf), int), crs="local ENU")
    ident = np.column_stack([rng.normal(0, 0.3, (len(true), 2)), np.zeros(len(true))])
    pts = np.concatenate([gcp, true + ident])
    ids = [f"G{i}" for i in range(8)] + [f"r{f}_{v}" for f, v in zip(vf, vi)]
    llh, jac = FRAME.to_geodetic(pts)
    pid, iid, obs = [], [], []
    for i, im in enumerate(imgs):
        cr, _, _ = observe_rpc(im.rpc, true_bias[i], llh, jac)
        pid += ids
        iid += [im.id] * len(ids)
        obs.append(cr + rng.normal(0, sigma_px, cr.shape))
    meas = Measurements(np.array(pid), np.array(iid), np.concatenate(obs), sigma_px)
    ctrl = ControlPoints(np.array(ids[:8]), gcp, 0.05, np.array(["control"] * 6 + ["check"] * 2))
    spec = VectorSpec("OSM", sigma=(5.0, 5.0, 1.0), identification_sigma=(0.3, 0.0),
                      offset="none")
    data = ProjectData(crs="local", camera=Camera(float("nan")), images=imgs,
                       measurements=meas, control=ctrl, vectors=[(spec, layer)],
                       ground_frame=FRAME)
    return data, true, true_bias


def test_pipeline_runs_an_rpc_project():
    from vectoradjust import pipeline

    data, true, true_bias = rpc_project(0)
    out = pipeline.run(data)
    entry = out.summary["images"][0]
    assert entry["model"] == "rpc" and set(entry["bias"]) == {"a0", "b0"}
    assert abs(entry["bias"]["a0"] - 3.0) < 4 * entry["sigma_bias"]["a0"]
    assert entry["significance"]["significant"] is True
    v = out.databases[0].vertices
    assert np.all(v["Adjusted"] == 1)
    adj = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])
    # the database was 1.5 m off with 0.7 m noise; the adjusted vertices are decimetres off
    assert np.sqrt(np.mean(np.sum((adj - true)[:, :2] ** 2, axis=1))) < 0.6


@pytest.mark.slow
def test_vertex_ce90_le90_cover_the_truth_on_rpc_pairs():
    """CE90/LE90 of road vertices on RPC pairs with a known bias cover about 90 %."""
    from vectoradjust import pipeline

    ce, le = [], []
    for seed in range(30):
        data, true, _ = rpc_project(seed)
        v = pipeline.run(data).databases[0].vertices
        e = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]]) - true
        ce.append(np.hypot(e[:, 0], e[:, 1]) <= v["CE90"])
        le.append(np.abs(e[:, 2]) <= v["LE90"])
    assert 0.85 <= np.mean(ce) <= 0.95, np.mean(ce)
    assert 0.85 <= np.mean(le) <= 0.95, np.mean(le)


def test_points_outside_the_rpc_domain_warn_far_outside_refused():
    from vectoradjust import pipeline

    data, _, _ = rpc_project(1)
    data.control.xyz[:, 2] += 700.0  # 1.3-1.5 height scales from HEIGHT_OFF
    out = pipeline.run(data)
    assert any("outside the RPC's validity domain" in w for w in out.summary["warnings"])
    data, _, _ = rpc_project(1)
    data.control.xyz[:, 2] += 3000.0  # e.g. heights in feet or another datum's numbers
    with pytest.raises(ProjectError, match="far outside the RPC's validity domain") as e:
        pipeline.run(data)
    assert "ellipsoidal" in e.value.mend and "crs" in e.value.mend


@pytest.mark.io
def test_satellite_sample_end_to_end(tmp_path):
    """`vectoradjust adjust` on the satellite sample: the bias recovered, corrected RPCs
    that reproduce the biased projection, the chi-square test passed."""
    import csv

    from vectoradjust.cli import main
    from vectoradjust.files.rpc import read_rpc

    sample = Path(__file__).resolve().parents[1] / "resources" / "sample" / "satellite"
    assert main(["adjust", str(sample / "project.toml"), "-o", str(tmp_path), "-q",
                 "--no-bands"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["chi_square"]["passed"] is True
    with open(sample / "truth_bias.csv", newline="") as fh:
        truth = {r["image_id"]: r for r in csv.DictReader(fh)}
    for entry in summary["images"]:
        t = truth[entry["id"]]
        for p in ("a0", "b0"):
            assert abs(entry["bias"][p] - float(t[p])) < 4 * entry["sigma_bias"][p]
        raw = read_rpc(sample / f"{entry['id']}_rpc.txt")
        fixed = read_rpc(tmp_path / entry["corrected_rpc"]["file"])
        lon, lat, h = raw.long_off, raw.lat_off, raw.height_off
        shift = fixed.project(lon, lat, h) - raw.project(lon, lat, h)
        np.testing.assert_allclose(shift[0], [entry["bias"]["a0"], entry["bias"]["b0"]],
                                   atol=1e-6)
    osm = summary["databases"][0]["truth"]
    assert 0.8 <= osm["share_within_ce90"] <= 0.97 and osm["improvement"] > 0.7


@pytest.mark.io
def test_mixed_block_frame_pair_and_satellite_image(tmp_path):
    """A block that mixes the frame sample's pair (mm, collinearity) with one satellite
    image of the same ground (pixels, RPC with a shift): both models in one adjustment,
    the frame cameras' orientation and the satellite image's bias estimated together."""
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    sample = Path(__file__).resolve().parents[1] / "resources" / "sample"
    text = (sample / "project.toml").read_text()
    text = text.replace('crs = "EPSG:32616"', 'crs = "EPSG:32616"\nheights = "ellipsoidal"')
    for name in ("rc10.toml", "gcps.csv", "osm_roads.shp", "tnm_roads.shp", "tiger_roads.shp",
                 "dem.tif", "truth_osm.csv", "truth_tnm.csv", "truth_tiger.csv",
                 "truth_roads.shp"):
        text = text.replace(f'"{name}"', f'"{(sample / name).as_posix()}"')
    text = text.replace('path = "image_points.csv"', 'path = "mixed_points.csv"')
    text = text.replace("[measurements]", '[[images]]\nid = "S1"\nmodel = "rpc"\nrpc = "'
                        + (sample / "satellite" / "S1_rpc.txt").as_posix()
                        + '"\nbias = "shift"\n\n[measurements]')
    (tmp_path / "project.toml").write_text(text)
    frame_rows = (sample / "image_points.csv").read_text().splitlines()
    # the satellite image's control, check and tie points (its road vertices were imaged
    # with identification errors of their own, which the frame pair's do not share)
    known = {r.split(",")[0] for r in (sample / "truth_points.csv").read_text().splitlines()[1:]}
    sat_rows = [r for r in (sample / "satellite" / "image_points.csv").read_text().splitlines()[1:]
                if ",S1," in r and r.split(",")[0] in known]
    (tmp_path / "mixed_points.csv").write_text("\n".join(frame_rows + sat_rows) + "\n")

    data = load_project_data(tmp_path / "project.toml")
    assert [im.model for im in data.images] == ["frame", "frame", "rpc"]
    out = run(data)
    prob = out.result.problem
    assert prob.is_rpc.tolist() == [False, False, True]
    sat = [e for e in out.summary["images"] if e["id"] == "S1"][0]
    with open(sample / "satellite" / "truth_bias.csv") as fh:
        truth = {r.split(",")[0]: r.split(",") for r in fh.read().splitlines()[1:]}
    assert abs(sat["bias"]["a0"] - float(truth["S1"][1])) < 4 * sat["sigma_bias"]["a0"]
    assert abs(sat["bias"]["b0"] - float(truth["S1"][4])) < 4 * sat["sigma_bias"]["b0"]
    frames = [e for e in out.summary["images"] if e["id"] in ("L", "R")]
    assert all(len(e["position"]) == 3 for e in frames)
    assert out.summary["chi_square"]["passed"] is True
    # the satellite image's residuals are pixels of about the simulated 0.3 px
    on_sat = prob.obs_image == 2
    rms = np.sqrt(np.mean(out.result.v_image[on_sat] ** 2, axis=0))
    assert np.all((rms > 0.15) & (rms < 0.45)), rms


def test_unmeasured_vertices_of_rpc_projects_are_conflated():
    """Vertices measured on no RPC image are corrected from the measured ones (conflation)
    and come closer to the truth than the database, with a CE90 that holds them."""
    from vectoradjust import pipeline
    from vectoradjust.model import Measurements

    data, true, _ = rpc_project(2)
    m = data.measurements
    keep = np.array([not p.startswith(("r0_", "r1_", "r2_")) for p in m.point_id])
    data.measurements = Measurements(m.point_id[keep], m.image_id[keep], m.xy[keep],
                                     m.sigma[keep])
    v = pipeline.run(data).databases[0].vertices
    un = np.isin(v["feature_id"].astype(str), ["r0", "r1", "r2"])
    assert set(v["Source"][un]) <= {"interpolated", "extrapolated"}
    e_adj = np.hypot(*(np.column_stack([v["AdjX"], v["AdjY"]])[un] - true[un, :2]).T)
    e_db = np.hypot(*(data.vectors[0][1].coords[un, :2] - true[un, :2]).T)
    assert np.sqrt(np.mean(e_adj**2)) < 0.6 * np.sqrt(np.mean(e_db**2))
    assert np.mean(e_adj <= v["CE90"][un]) >= 0.8


def test_frame_only_methods_refuse_rpc_images():
    from vectoradjust import pipeline
    from vectoradjust.accuracy import derived

    out = pipeline.run(rpc_project(4)[0])
    for call in (lambda: derived.equal_error_grid(out, 50.0),
                 lambda: derived.compare_two_step(out, ["P1", "P2"])):
        with pytest.raises(ProjectError, match="frame camera methods") as e:
            call()
        assert "'P1'" in e.value.what and "--images" in e.value.mend


@pytest.mark.io
def test_corrected_rpcs_never_replace_the_inputs(tmp_path):
    """Adjusting into the folder that holds the project's own S?_rpc.txt keeps them and
    writes S?_corrected_rpc.txt instead (named in the summary)."""
    import shutil

    from vectoradjust.cli import main

    sample = Path(__file__).resolve().parents[1] / "resources" / "sample"
    work = tmp_path / "satellite"
    shutil.copytree(sample / "satellite", work)
    text = (work / "project.toml").read_text().replace('"../', f'"{sample.as_posix()}/')
    (work / "project.toml").write_text(text)
    before = (work / "S1_rpc.txt").read_bytes()
    assert main(["adjust", str(work / "project.toml"), "-o", str(work), "-q", "--no-bands"]) == 0
    assert (work / "S1_rpc.txt").read_bytes() == before
    summary = json.loads((work / "summary.json").read_text())
    entry = summary["images"][0]["corrected_rpc"]
    assert entry["file"] == "S1_corrected_rpc.txt" and "renamed" in entry["note"]
    assert (work / "S1_corrected_rpc.txt").is_file()
