"""Benchmark: a satellite triplet with 10^5 road vertices, adjusted with covariances.

Run on demand (not part of the test suite), from the repository root:

    python benchmarks/bench_rpc_block.py                      # ENU and UTM frames
    python benchmarks/bench_rpc_block.py --frame utm --repeat 3 --profile
    python benchmarks/bench_rpc_block.py --vertices 100000 --pipeline

The scene (:func:`vectoradjust.simulate.satellite.satellite_scenario` with explicit
:class:`~vectoradjust.simulate.satellite.GroundPoints`): the default 3 x 3 km area near
lon -87.0, lat 40.4 (smooth terrain 150-250 m ellipsoidal), ``--gcps`` control points
and ``--vertices`` road vertices on random gently curving roads (~10 m vertex spacing),
a forward / nadir / backward triplet (B/H 0.6, 0.5 m GSD, 8000 x 8000 px) with RPCs
fitted to the pushbroom sensors, a true shift bias per image (8 px) and 0.3 px noise.
Every point is seen on all three images.

The :class:`~vectoradjust.adjust.bundle.BundleProblem`: ground frame either
:class:`~vectoradjust.sensor.ground.EnuFrame` at the scene centre (``enu``) or
:func:`vectoradjust.files.rpc.crs_frame` of ``EPSG:32616`` (``utm``, pyproj through a
:class:`~vectoradjust.sensor.ground.CallableFrame`); a ``shift`` bias per image without
prior; GCPs with 5 cm priors; road vertices with light priors (5 m in X and Y, 1 m in
Z: the database, i.e. the truth plus noise of those sigmas), started at their priors.

Timed: :func:`vectoradjust.adjust.bundle.adjust` with point covariances (median and
range of ``--repeat`` runs, wall and CPU), the frame's ``to_geodetic`` alone on all the
points, and with ``--profile`` one cProfile run of ``adjust`` (the functions with the
most cumulative and own time). ``--pipeline`` also times :func:`vectoradjust.pipeline.run`
on a :class:`~vectoradjust.model.ProjectData` of the same observations (the vertices
as one road database, offset "none"). The target of the issue: <= 5 s for the
adjustment with covariances.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from vectoradjust.adjust.bundle import BundleProblem, adjust  # noqa: E402
from vectoradjust.sensor.models import RpcImage, SensorSet  # noqa: E402
from vectoradjust.simulate.satellite import (  # noqa: E402
    GroundPoints,
    SceneArea,
    satellite_scenario,
)

UTM = "EPSG:32616"
GCP_SIGMA = 0.05
ROAD_SIGMA = np.array([5.0, 5.0, 1.0])


def _roads(n_vertices: int, half: float, rng: np.random.Generator):
    """Local x, y (m) of ``n_vertices`` road vertices: random roads of 100 vertices,
    ~10 m apart, heading drifting slowly, folded back into the square ``[-half, half]``."""
    per = 100
    n_roads = -(-n_vertices // per)
    start = rng.uniform(-0.9 * half, 0.9 * half, (n_roads, 2))
    heading = rng.uniform(0, 2 * np.pi, n_roads)[:, None] + np.cumsum(
        rng.normal(0, 0.03, (n_roads, per)), axis=1)
    step = rng.uniform(8.0, 12.0, (n_roads, 1))
    xy = start[:, None, :] + np.cumsum(
        step[:, :, None] * np.stack([np.cos(heading), np.sin(heading)], axis=-1), axis=1)
    xy = xy.reshape(-1, 2)[:n_vertices]
    # fold into the square (a road leaving it comes back mirrored)
    period = 4.0 * half
    xy = np.abs(((xy + half) % period) - 2 * half) - half
    return xy[:, 0], xy[:, 1]


def build_scenario(n_vertices: int, n_gcps: int, seed: int = 1):
    """The simulated triplet (:class:`SatelliteScenario`) and the ids of its GCPs."""
    area = SceneArea()
    rng = np.random.default_rng(seed)
    half = 0.5 * area.size_m
    gx = rng.uniform(-0.9 * half, 0.9 * half, n_gcps)
    gy = rng.uniform(-0.9 * half, 0.9 * half, n_gcps)
    rx, ry = _roads(n_vertices, half, rng)
    x, y = np.concatenate([gx, rx]), np.concatenate([gy, ry])
    lon, lat = area.to_lonlat(x, y)
    ids = [f"GCP{i:02d}" for i in range(n_gcps)] + [f"V{i}" for i in range(n_vertices)]
    kind = ["control"] * n_gcps + ["road"] * n_vertices
    pts = GroundPoints(ids, lon, lat, area.height(x, y), kind)
    return satellite_scenario(3, "shift", 8.0, seed=seed, ground=pts, sigma_px=0.3)


def make_frame(kind: str, sc):
    """The ground frame: ``enu`` at the scene centre or ``utm`` (pyproj, EPSG:32616)."""
    if kind == "enu":
        from vectoradjust.sensor.ground import EnuFrame

        return EnuFrame(sc.area.lon, sc.area.lat, sc.area.h_mean)
    from vectoradjust.files.rpc import crs_frame

    return crs_frame(UTM, near=(sc.area.lon, sc.area.lat))


def build_problem(sc, frame, seed: int = 2):
    """The BundleProblem of the scenario in ``frame``, and the true object coordinates."""
    rng = np.random.default_rng(seed)
    true = frame.from_geodetic(np.column_stack([sc.lon, sc.lat, sc.h]))
    ctrl = sc.kind == "control"
    sig = np.where(ctrl[:, None], GCP_SIGMA, ROAD_SIGMA[None, :])
    prior = true + rng.normal(0.0, 1.0, true.shape) * sig
    w = np.zeros((len(true), 3, 3))
    w[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sig**2
    images = [RpcImage(r, "shift") for r in sc.rpcs]
    n = len(images)
    prob = BundleProblem(np.nan, (0, 0), np.zeros((n, 6)), np.full((n, 6), np.inf), prior,
                         prior, w, sc.obs_point, sc.obs_image,
                         np.column_stack([sc.obs_col, sc.obs_row]),
                         np.column_stack([sc.obs_sigma, sc.obs_sigma]),
                         sensors=SensorSet(images, frame))
    return prob, true


def time_adjust(prob, repeat: int) -> dict:
    """Median, least and largest wall time and median CPU time of ``adjust`` with
    covariances, and the last result."""
    walls, cpus, res = [], [], None
    for _ in range(repeat):
        res = None
        t0, c0 = time.perf_counter(), time.process_time()
        res = adjust(prob, compute_covariance=True)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return {"wall": statistics.median(walls), "min": min(walls), "max": max(walls),
            "cpu": statistics.median(cpus), "result": res}


def profile_adjust(prob, top: int = 22) -> str:
    """One cProfile run of ``adjust``: the top functions by cumulative and own time."""
    pr = cProfile.Profile()
    pr.enable()
    adjust(prob, compute_covariance=True)
    pr.disable()
    out = io.StringIO()
    st = pstats.Stats(pr, stream=out)
    st.sort_stats("cumulative").print_stats(top)
    st.sort_stats("tottime").print_stats(top)
    return out.getvalue()


def _strip_profile(text: str) -> str:
    """The profile's table lines with the repository path shortened."""
    keep = [ln.replace(str(ROOT) + "/", "") for ln in text.splitlines()
            if ln.strip() and not ln.startswith("   Ordered") and "function calls" not in ln]
    return "\n".join(keep)


def project_data(sc, frame, prior: np.ndarray):
    """A ProjectData of the same observations: GCPs as control, the road vertices as one
    database (the priors as the layer, 5 m / 1 m sigmas, offset "none")."""
    from vectoradjust.model import (
        Camera,
        ControlPoints,
        ImageSpec,
        LineLayer,
        Measurements,
        ProjectData,
        VectorSpec,
    )
    from vectoradjust.sensor.ground import EnuFrame

    crs = "local ENU" if isinstance(frame, EnuFrame) else UTM
    ctrl = np.flatnonzero(sc.kind == "control")
    road = np.flatnonzero(sc.kind == "road")
    names = ["forward", "nadir", "backward"]
    imgs = [ImageSpec(names[i], np.zeros(3), np.zeros(3), model="rpc",
                      rpc=RpcImage(r, "shift")) for i, r in enumerate(sc.rpcs)]
    per = 100
    vf = np.arange(len(road)) // per
    vi = np.arange(len(road)) % per
    nf = int(vf.max()) + 1
    fids = np.array([f"road{i}" for i in range(nf)])
    layer = LineLayer("DB", fids, {"name": list(fids)}, prior[road], vf, vi,
                      np.zeros(len(road), int), crs=crs)
    vid = np.array([f"{fids[f]}_{v}" for f, v in zip(vf, vi)])
    pid = np.asarray(sc.point_ids, dtype=object).copy()
    pid[road] = vid
    meas = Measurements(pid[sc.obs_point], np.array(names)[sc.obs_image],
                        np.column_stack([sc.obs_col, sc.obs_row]), sc.sigma_px)
    control = ControlPoints(np.asarray(sc.point_ids)[ctrl], prior[ctrl], GCP_SIGMA,
                            np.array(["control"] * len(ctrl)))
    spec = VectorSpec("DB", sigma=tuple(ROAD_SIGMA), identification_sigma=(0.0, 0.0),
                      offset="none")
    return ProjectData(crs=crs, camera=Camera(float("nan")), images=imgs,
                       measurements=meas, control=control, vectors=[(spec, layer)],
                       ground_frame=frame)


def time_pipeline(sc, frame, prior) -> float:
    """Wall time of :func:`vectoradjust.pipeline.run` on the scenario's ProjectData."""
    from vectoradjust import pipeline

    data = project_data(sc, frame, prior)
    t0 = time.perf_counter()
    pipeline.run(data)
    return time.perf_counter() - t0


def _row(label: str, prob, true, frame, args) -> None:
    pts = prob.xyz0
    t0 = time.perf_counter()
    frame.to_geodetic(pts)
    t_geo = time.perf_counter() - t0
    rec = time_adjust(prob, args.repeat)
    res = rec["result"]
    err = res.xyz - true
    sd = np.sqrt(np.diagonal(res.point_cov, axis1=1, axis2=2))
    free = ~prob.eo_fixed
    d_bias = np.abs(res.eo[free] - args.sc.true_bias[free]).max()
    print(f"{label:5s} {prob.n_points:8d} {len(prob.obs_point):8d} {rec['wall']:7.2f} "
          f"{rec['min']:5.2f}-{rec['max']:<5.2f} {rec['cpu']:7.2f} {t_geo:8.3f} "
          f"{res.iterations:3d} {res.sigma0_squared:6.3f} "
          f"{np.sqrt(np.mean(err[:, :2] ** 2)):6.3f} {np.median(sd[:, 2]):6.3f} "
          f"{d_bias:6.3f}", flush=True)
    if args.profile:
        print(_strip_profile(profile_adjust(prob)))
    if args.pipeline:
        print(f"pipeline.run ({label}): {time_pipeline(args.sc, frame, prob.prior_xyz):.2f} s",
              flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=100_000, help="road vertices (1e5)")
    ap.add_argument("--gcps", type=int, default=20, help="control points (20)")
    ap.add_argument("--frame", choices=("enu", "utm", "both"), default="both")
    ap.add_argument("--repeat", type=int, default=3, help="adjust() runs per frame (3)")
    ap.add_argument("--profile", action="store_true", help="one cProfile run per frame")
    ap.add_argument("--pipeline", action="store_true", help="also time pipeline.run")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    print(f"# RPC block benchmark, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"{os.cpu_count()} cores, load average {load:.2f}")
    t0 = time.perf_counter()
    args.sc = sc = build_scenario(args.vertices, args.gcps)
    print(f"# scenario: {len(sc.lon)} points, {len(sc.obs_point)} observations, RPC fit "
          f"rms {sc.fit_rms_px.max():.1e} px, built in {time.perf_counter() - t0:.1f} s")
    print(f"{'frame':5s} {'points':>8s} {'obs':>8s} {'adjust':>7s} {'range':>11s} "
          f"{'CPU s':>7s} {'to_geo s':>8s} {'it':>3s} {'s0^2':>6s} {'rmsXY':>6s} "
          f"{'sdZ':>6s} {'dbias':>6s}")
    for kind in (("enu", "utm") if args.frame == "both" else (args.frame,)):
        frame = make_frame(kind, sc)
        prob, true = build_problem(sc, frame)
        _row(kind, prob, true, frame, args)
    print(f"# load average at the end {os.getloadavg()[0]:.2f}; 'adjust' is the median "
          f"wall time (s) of {args.repeat} runs with covariances, 'to_geo s' one "
          "frame.to_geodetic of all points, rmsXY (m) the adjusted points against the "
          "truth, sdZ (m) the median posterior sigma of Z, dbias (px) the largest error of an "
          "estimated shift")
    return 0


if __name__ == "__main__":
    sys.exit(main())
