"""Benchmark: the conflation stage alone for 10^5 and 10^6 vertices.

Run on demand (not part of the test suite):

    PYTHONPATH=core python benchmarks/bench_conflation.py [--vertices 100000 1000000]

Builds a synthetic road database (straight and wiggly lines on a square, 10 m vertex
spacing, a constant shift + a smooth field + noise) and an adjustment-like result in
which a share of the object points (``--measured``, default 10 %) is "measured" (the
database position minus the error plus image noise, with a covariance and a prior
weight), then times :func:`vectoradjust.conflation.conflate_database`: the
semivariogram fit, the k-nearest collocation at every unmeasured vertex, the
leave-one-out cross-validation and the table updates. Prints the time per stage call
and the peak memory. The bundle adjustment is not part of it (``bench_adjust.py``).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from vectoradjust.accuracy.tables import cov_stats  # noqa: E402
from vectoradjust.adjust.shapepoints import extract_shape_points  # noqa: E402
from vectoradjust.conflation import ConflationSettings, conflate_database  # noqa: E402
from vectoradjust.model import LineLayer, VectorSpec  # noqa: E402
from vectoradjust.results import DatabaseResult  # noqa: E402
from vectoradjust.simulate.conflation import smooth_field  # noqa: E402


def _layer(n_vertices: int, seed: int) -> LineLayer:
    """Lines of 100 vertices (10 m apart) with random starts and headings."""
    rng = np.random.default_rng(seed)
    per = 100
    nf = max(n_vertices // per, 1)
    side = 10.0 * np.sqrt(n_vertices) * 1.5
    start = rng.uniform(0, side, (nf, 2))
    head = rng.uniform(0, 2 * np.pi, nf)[:, None] + np.cumsum(
        rng.normal(0, 0.05, (nf, per)), axis=1)
    step = 10.0 * np.stack([np.cos(head), np.sin(head)], axis=-1)
    xy = (start[:, None, :] + np.cumsum(step, axis=1)).reshape(-1, 2)
    xyz = np.column_stack([xy, np.full(len(xy), 200.0)])
    vf = np.repeat(np.arange(nf), per)
    vi = np.tile(np.arange(per), nf)
    return LineLayer("bench", np.arange(nf), {}, xyz, vf, vi, np.zeros_like(vf))


def _run(n_vertices: int, measured: float, seed: int = 1):
    """The synthetic run and database (measured object points = bundle points)."""
    layer = _layer(n_vertices, seed)
    sp = extract_shape_points(layer)
    rng = np.random.default_rng(seed + 1)
    nobj = sp.n_objects
    err = np.column_stack([3.0 + smooth_field(sp.object_xyz[:, :2], 2.0, 300.0, seed)[:, 0],
                           -2.0 + smooth_field(sp.object_xyz[:, :2], 2.0, 300.0, seed + 9)[:, 1],
                           rng.normal(0, 0.3, nobj)])
    meas = np.flatnonzero(rng.random(nobj) < measured)
    m = len(meas)
    cov = np.broadcast_to(np.diag([0.003, 0.003, 0.03]), (m, 3, 3)).copy()
    xyz = sp.object_xyz[meas] - err[meas] + rng.normal(0, 0.05, (m, 3))
    result = SimpleNamespace(xyz=xyz, point_cov=cov, variance_factor=1.0,
                             covariance_scale="a-priori")
    problem = SimpleNamespace(prior_weight=np.broadcast_to(np.eye(3) * 0.01, (m, 3, 3)).copy(),
                              prior_xyz=sp.object_xyz[meas].copy())
    omap = np.full(nobj, -1)
    omap[meas] = np.arange(m)
    vp = omap[sp.vertex_object]
    d = DatabaseResult(VectorSpec("bench", identification_sigma=(0.3, 0.1)), sp, vp)
    _tables(d, xyz, cov)
    out = SimpleNamespace(result=result, problem=problem, summary={}, data=SimpleNamespace())
    return out, d


def _tables(d, xyz, cov) -> None:
    """The vertex columns the statistics stage would have written."""
    lay = d.shape.layer
    nv = len(lay.coords)
    mv = d.vertex_point >= 0
    adj = lay.coords.copy()
    adj[mv] = xyz[d.vertex_point[mv]]
    c = np.full((nv, 3, 3), np.nan)
    c[mv] = cov[d.vertex_point[mv]]
    sig, ce, le = cov_stats(c)
    v = adj - lay.coords
    v[~mv] = np.nan
    d.vertices = {"AdjX": adj[:, 0], "AdjY": adj[:, 1], "AdjZ": adj[:, 2],
                  "Vx": v[:, 0], "Vy": v[:, 1], "Vz": v[:, 2], "SigmaX": sig[:, 0],
                  "SigmaY": sig[:, 1], "SigmaZ": sig[:, 2], "CE90": ce, "LE90": le,
                  "Adjusted": mv.astype(np.int64)}
    d.features = {}
    d.adjusted_coords = adj


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--vertices", type=int, nargs="+", default=[100_000, 1_000_000])
    p.add_argument("--measured", type=float, default=0.1, help="share of measured points")
    p.add_argument("--k", type=int, default=12)
    args = p.parse_args(argv)
    print(f"{'vertices':>9s} {'measured':>9s} {'predicted':>9s} {'set-up s':>8s} "
          f"{'conflation s':>12s} {'peak MB':>8s}")
    for n in args.vertices:
        t0 = time.perf_counter()
        out, d = _run(n, args.measured)
        t1 = time.perf_counter()
        e = conflate_database(out, d, None, ConflationSettings(k=args.k))
        t2 = time.perf_counter()
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        pred = e["vertices"]["interpolated"] + e["vertices"]["extrapolated"]
        print(f"{n:9d} {e['vertices']['measured']:9d} {pred:9d} {t1 - t0:8.1f} "
              f"{t2 - t1:12.1f} {peak:8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
