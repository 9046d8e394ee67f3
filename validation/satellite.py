"""Monte Carlo coverage of the RPC bias and of road vertices' CE90/LE90 on satellite blocks.

Run on demand (the suite runs a reduced version in tests/test_satellite_coverage.py):

    python validation/satellite.py --runs 300
    python validation/satellite.py --fast    # the fast tier: 10 runs, pair, shift
    python validation/satellite.py --runs 100 --models affine --geometries triplet
    # a misstated error model fails (exit status 1): CE90 covers ~63 %
    python validation/satellite.py --runs 40 --geometries pair --models shift \
        --identification 0.4 --stated-identification 0.25

For every geometry (an along-track ``pair`` or ``triplet`` of the pushbroom simulator,
vectoradjust.simulate.satellite.satellite_scenario, RPCs fitted once per geometry) and
bias model, each run redraws the true image-space bias and the pixel noise
(vectoradjust.simulate.satellite_project.redraw), builds the project
(scenario_project_data: 6 GCPs, 10 check points, 30 tie points, 60 road vertices in 3
features of a database 1.5 m off with honest sigma, identification error) and adjusts it
with vectoradjust.pipeline.run. It counts

- bias: each estimated bias parameter (run.result.eo, eo_cov) within 1.645 sigma of
  the truth;
- CE90 / LE90: each adjusted road vertex (run.databases[0].vertices) within its CE90
  circle / LE90 interval of the real vertex.

The table gives the coverage, its 95 % binomial (Wilson) interval on the effective
number of samples (samples of one run share the run's bias and offset errors: the
design effect ``deff`` is the variance of the coverage between runs over the binomial
variance, at least 1), and the coverage the intervals would have with every sigma 20 %
smaller (x0.8) or larger (x1.2).

Acceptance criteria: every coverage (bias, CE90, LE90 of every geometry and bias model)
inside the acceptance band widened for the sample. The band is the true coverage that
counts as correct: that of intervals whose sigma is within +-5 % (``TOL``) of the true
one, ``2 Phi(1.645 k) - 1`` = 0.882-0.916 for the bias and LE90, ``1 - 0.1^(k^2)`` =
0.875-0.921 for CE90 (``--band LO HI`` sets another, e.g. 0.85 0.95); it is widened to
the binomial quantiles of ``n / deff`` samples (``deff`` the measured design effect, at
least ``DEFF_MIN``: 2.0 for the bias, 1.6 for the vertices, what 30 repetitions of
tests/test_satellite_coverage.py measured) at ``alpha = 0.01 / rows``
(validation/acceptance.py), so that a correct implementation passes all rows with
>= 99 %. With 300 runs this gives about 0.84-0.96 for the bias and 0.86-0.94 for the
vertices; with the 10 runs of ``--fast`` about 0.6-1 for the bias (40 samples) and
0.8-0.97 for the vertices. One PASS/FAIL line per row; exit status 1 when one fails.

OpenBLAS runs single-threaded here unless OPENBLAS_NUM_THREADS says otherwise: the small
least-squares fits of the simulator (RPC fits) and of the summary (folding the bias into
corrected RPCs) took 4-17x the CPU time with two threads on a busy 2-core machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is imported

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "core"))

from acceptance import Criteria, coverage_1d, coverage_2d, share_band  # noqa: E402

from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate.satellite import satellite_scenario  # noqa: E402
from vectoradjust.simulate.satellite_project import (  # noqa: E402
    bias_errors,
    redraw,
    scenario_project_data,
    vertex_errors,
)

GEOMETRIES = {"pair": 2, "triplet": 3}
MODELS = ("shift", "shift+drift", "affine")
QUANTITIES = (("bias", "z"), ("CE90", "ratio"), ("LE90", "ratio"))
Z90 = 1.6448536269514722
NAMES = np.array(["a0", "a1", "a2", "b0", "b1", "b2"])
#: the smallest design effect assumed for the acceptance band, per kind of quantity
DEFF_MIN = {"z": 2.0, "ratio": 1.6}
#: the sigma error still called correct
TOL = 0.05
#: the true coverage that counts as correct, per quantity (without --band)
CORRECT = {"bias": (coverage_1d(1 - TOL), coverage_1d(1 + TOL)),
           "CE90": (coverage_2d(1 - TOL), coverage_2d(1 + TOL)),
           "LE90": (coverage_1d(1 - TOL), coverage_1d(1 + TOL))}


def wilson(p: float, n: float, z: float = 1.959963984540054) -> tuple[float, float]:
    """The Wilson score interval of a binomial share ``p`` of ``n`` samples."""
    if n <= 0:
        return float("nan"), float("nan")
    d = 1.0 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def inside(errors: np.ndarray, kind: str, scale: float = 1.0) -> np.ndarray:
    """Boolean: the error lies inside its (scaled) 90 % interval."""
    a = np.abs(np.asarray(errors, float))
    return a <= (Z90 * scale if kind == "z" else scale)


def summarise(per_run: list, kind: str, band: tuple[float, float],
              alpha: float = 0.01) -> dict:
    """Coverage, design effect, interval, acceptance band and verdict from the runs'
    errors (``alpha``: the band's two-sided level)."""
    hits = [inside(e, kind) for e in per_run]
    n_r = np.array([h.size for h in hits], float)
    h_r = np.array([h.sum() for h in hits], float)
    n = float(n_r.sum())
    p = float(h_r.sum() / n)
    runs = len(hits)
    var_binom = p * (1 - p) / n if 0 < p < 1 else 1.0 / n**2
    var_cluster = (float(np.sum((h_r - p * n_r) ** 2)) / n**2 * runs / (runs - 1)
                   if runs > 1 else var_binom)
    deff = max(var_cluster / var_binom, 1.0)
    lo, hi = wilson(p, n / deff)
    allx = np.concatenate([np.ravel(e) for e in per_run])
    accept = share_band(n, band[0], band[1], alpha, max(deff, DEFF_MIN[kind]))
    return {"n": int(n), "runs": runs, "coverage": p, "ci95": [lo, hi], "deff": deff,
            "x0.8": float(np.mean(inside(allx, kind, 0.8))),
            "x1.2": float(np.mean(inside(allx, kind, 1.2))), "accept": list(accept),
            "passed": bool(accept[0] <= p <= accept[1])}


_BASES: dict = {}


def base_scenario(n_images: int, args):
    """The scene, images and fitted RPCs of a geometry (fitted once, kept)."""
    key = (n_images, args.geometry_seed, args.sigma_px)
    if key not in _BASES:
        _BASES[key] = satellite_scenario(n_images, "shift", args.bias_size, args.geometry_seed,
                                         sigma_px=args.sigma_px)
    return _BASES[key]


def one_config(n_images: int, model: str, args) -> dict:
    """All runs of one geometry and bias model: the runs' errors."""
    base = base_scenario(n_images, args)
    out: dict = {"bias": [], "CE90": [], "LE90": [], "names": [], "sigma0_squared": [],
                 "variance_factor": []}
    for k in range(args.runs):
        sc = redraw(base, args.first_seed + k, model, args.bias_size)
        data, truth = scenario_project_data(
            sc, database_sigma=args.database_sigma, database_shift=args.database_shift,
            identification_sigma=args.identification, offset=args.offset,
            reweight=args.reweight, stated_database_sigma=args.stated_database_sigma,
            stated_identification_sigma=args.stated_identification)
        r = run(data)
        out["bias"].append(bias_errors(r, truth))
        ce, le = vertex_errors(r, truth)
        out["CE90"].append(ce)
        out["LE90"].append(le)
        out["sigma0_squared"].append(float(r.result.sigma0_squared))
        out["variance_factor"].append(float(r.result.variance_factor))
        out["names"] = np.tile(NAMES[truth.free[0]], (len(truth.image_ids), 1))
    return out


def _row(geometry, model, quantity, s) -> str:
    flag = "ok" if s["passed"] else "OUTSIDE BAND"
    return (f"{geometry:8s} {model:12s} {quantity:9s} {s['n']:7d} {s['coverage']:8.4f} "
            f"[{s['ci95'][0]:.4f}, {s['ci95'][1]:.4f}] {s['deff']:5.2f} "
            f"{s['x0.8']:7.4f} {s['x1.2']:7.4f}  {flag}")


def _parameter_rows(geometry, model, res, band) -> list:
    """Informational rows: the bias coverage of each parameter name over the images."""
    rows = []
    for name in res["names"][0]:
        per_run = [b[res["names"] == name] for b in res["bias"]]
        s = summarise(per_run, "z", band)
        rows.append(f"{'':8s} {'':12s} {'  ' + name:9s} {s['n']:7d} {s['coverage']:8.4f} "
                    f"[{s['ci95'][0]:.4f}, {s['ci95'][1]:.4f}] {s['deff']:5.2f} "
                    f"{s['x0.8']:7.4f} {s['x1.2']:7.4f}")
    return rows


def parse(argv=None) -> argparse.Namespace:
    """The command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=None,
                   help="runs per geometry and bias model (default 300, --fast 10)")
    p.add_argument("--models", nargs="+", default=None, choices=MODELS,
                   help="default all (--fast: shift)")
    p.add_argument("--geometries", nargs="+", default=None, choices=list(GEOMETRIES),
                   help="default both (--fast: pair)")
    p.add_argument("--fast", action="store_true", help="the fast tier")
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--geometry-seed", type=int, default=0,
                   help="seed of the scene, attitude and RPCs (kept for all runs)")
    p.add_argument("--bias-size", type=float, default=8.0, help="sd of the true shifts (px)")
    p.add_argument("--sigma-px", type=float, default=0.3)
    p.add_argument("--database-sigma", type=float, nargs=3, default=(2.0, 2.0, 1.0))
    p.add_argument("--database-shift", type=float, nargs=3, default=(1.5, -1.0, 0.0))
    p.add_argument("--identification", type=float, default=0.15,
                   help="horizontal identification sigma (m)")
    p.add_argument("--stated-identification", type=float, default=None,
                   help="identification sigma the project states (default: the simulated one)")
    p.add_argument("--stated-database-sigma", type=float, nargs=3, default=None,
                   help="database sigma the project states (default: the simulated one)")
    p.add_argument("--offset", default="shift", help="the database's offset model")
    p.add_argument("--reweight", default="none", choices=("none", "two-pass", "vce"))
    p.add_argument("--band", type=float, nargs=2, default=None,
                   help="the true coverage that counts as correct (default: that of a "
                        "sigma within +-5 %%)")
    p.add_argument("--per-parameter", action="store_true",
                   help="also the bias coverage of each parameter (not tested)")
    p.add_argument("--json", help="write the table and the criteria to this file")
    args = p.parse_args(argv)
    args.runs = args.runs or (10 if args.fast else 300)
    args.models = args.models or (["shift"] if args.fast else list(MODELS))
    args.geometries = args.geometries or (["pair"] if args.fast else list(GEOMETRIES))
    return args


def main(argv=None) -> int:
    """Run the Monte Carlo, print the table and the criteria; 1 when a coverage is outside
    its acceptance band."""
    args = parse(argv)
    alpha = 0.01 / (len(args.geometries) * len(args.models) * len(QUANTITIES))
    crit = Criteria(f"satellite Monte Carlo, {args.runs} runs per row")
    band = "+-5 % sigma" if args.band is None else f"{args.band[0]:.2f}-{args.band[1]:.2f}"
    print(f"runs per row {args.runs}; band {band}; offset "
          f"{args.offset!r}, reweight {args.reweight!r}; database sigma "
          f"{tuple(args.database_sigma)} shift {tuple(args.database_shift)}; identification "
          f"{args.identification} m; pixel sigma {args.sigma_px}"
          + ("" if args.stated_identification is None and args.stated_database_sigma is None
             else f"; STATED identification {args.stated_identification}, database sigma "
                  f"{args.stated_database_sigma}"))
    print(f"{'geometry':8s} {'model':12s} {'quantity':9s} {'n':>7s} {'coverage':>8s} "
          f"{'95 % interval':18s} {'deff':>5s} {'x0.8':>7s} {'x1.2':>7s}")
    table, t0 = [], time.perf_counter()
    for geometry in args.geometries:
        for model in args.models:
            res = one_config(GEOMETRIES[geometry], model, args)
            for quantity, kind in QUANTITIES:
                s = summarise(res[quantity], kind,
                              CORRECT[quantity] if args.band is None else args.band, alpha)
                crit.add(f"{geometry} {model} {quantity} coverage (deff {s['deff']:.2f})",
                         s["coverage"], *s["accept"])
                print(_row(geometry, model, quantity, s), flush=True)
                table.append({"geometry": geometry, "model": model, "quantity": quantity,
                              **s})
            if args.per_parameter:
                print("\n".join(_parameter_rows(geometry, model, res,
                                                CORRECT["bias"] if args.band is None
                                                else args.band)))
            print(f"{'':8s} {'':12s} mean sigma0^2 {np.mean(res['sigma0_squared']):.3f}, "
                  f"mean variance factor of the covariances "
                  f"{np.mean(res['variance_factor']):.3f} ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    return crit.report(args.json, {"arguments": dict(vars(args)), "table": table})


if __name__ == "__main__":
    sys.exit(main())
