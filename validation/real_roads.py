"""Validation on REAL road geometry (OSM centrelines of central Helsinki) over seeds.

Run:  PYTHONPATH=core python validation/real_roads.py [--seeds 1 2 3 4 5] [--cases one four]
      [--fast] [--json FILE]

``--fast`` (the fast tier of tests/test_validation.py): seed 1, case ``one``
(tests/test_real_roads.py runs seed 1 of both cases).

The true roads of the simulated stereo model are the 600 m x 600 m window in
``tests/data/helsinki`` (OpenStreetMap data, ODbL 1.0, (c) OpenStreetMap contributors),
centred on the model (``make_scenario(..., true_roads=...)``). Every database has its
offset estimated (``offset = "shift"``) and ``identification_sigma = (0.5, 0)`` (the simulated
identification error is horizontal: the measured point lies on the terrain); the
analyst's identification error is simulated with ``pointing_sigma = 0.5``. Cases:

- ``one``: one database, 3 m to the north-east, 1.5 m noise per axis, ~3000 object
  points; modes ``none`` with the real horizontal prior (1.5, 1.5, 3.5) m, ``none``
  with 3.5 m on every axis (``none/3.5``), ``two-pass`` and ``vce`` (from 3.5 m);
- ``four``: OSM-like (3 m NE, noise 1.5), TNM-like (2 m NW, 1.0), TIGER-like
  (12 m E, 14 m S, 3.0) and CITY (0.9 m, 0.5), ~8000 object points; modes ``none``
  (prior = each database's noise horizontally, 3.5 m vertically), ``two-pass``, ``vce``.

Prints one row per seed, case, mode and database: measured vertices, the estimated
offset and the true mean displacement at the measured vertices (and their difference
in units of the offset's sigma), CE90 and LE90 coverage of the truth, the check point
RMSE ratio with / without the roads, sigma0^2 and the improvement
``1 - RMSE(adjusted - truth) / RMSE(database - truth)``; then the range over the seeds
with ``!`` where a coverage leaves 0.85-0.95, the ratio exceeds 1.05 or the offset is
more than 4 sigma + 2 cm off (per seed, for information: one seed's check ratio rests on
a few check points, seeds 1-5 gave 0.83-1.06).

Acceptance criteria over the ``n`` seeds (exit status 1 when one is missed;
validation/acceptance.py; ``z`` for a two-sided ``0.01 / 40``: the 32 coverages, the
ratios and the harm count pass together with >= 99 % when the implementation is right):

1. CE90 and LE90, pooled over the seeds for every case, mode and database, cover the
   truth 85-95 %, widened by ``z SD / sqrt(n)`` with the per-seed scatter ``SEED_SD``
   (seeds 1-5 measured at most 0.0064 for CE90, 0.020 for LE90);
2. the check points are no worse with the roads: the mean check ratio over the seeds
   at most 1.05 + ``z SD / sqrt(n)`` for every case and mode (per-seed SD 0.069-0.088
   measured);
3. the runs that roads_and_control calls harmed (its own test at alpha = 0.05): no
   more than the binomial upper quantile of 5 %;
4. every estimated offset within 4 sigma + 2 cm of the database's true mean
   displacement at the measured vertices (every seed, case, mode and database).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from acceptance import Criteria, share_band, z_two_sided  # noqa: E402

from vectoradjust.adjust.shapepoints import lookup  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import DatabaseModel, make_scenario, read_road_lines  # noqa: E402

DATA = ROOT / "tests" / "data" / "helsinki" / "helsinki_roads.geojson"
R2 = math.sqrt(2.0)
OSM = DatabaseModel("OSM", "osm_id", "osm", 20.0, 0.5, (3.0 / R2, 3.0 / R2), 0.0, 0.0, 1.5)
FOUR = (
    OSM,
    DatabaseModel("TNM", "permanent_", "tnm", 15.0, 0.5, (-2.0 / R2, 2.0 / R2), 0.0, 0.0, 1.0),
    DatabaseModel("TIGER", "tlid", "tiger", 30.0, 0.5, (12.0, -14.0), 0.0, 0.0, 3.0),
    DatabaseModel("CITY", "city_id", "city", 10.0, 0.5, (0.5, -0.8), 0.0, 0.0, 0.5),
)
CASES = {"one": ((OSM,), 3000, ("none", "none/3.5", "two-pass", "vce")),
         "four": (FOUR, 8000, ("none", "two-pass", "vce"))}
#: per-seed standard deviations (a margin above seeds 1-5's largest)
SEED_SD = {"ce": 0.01, "le": 0.025, "ratio": 0.10}
ALPHA = 0.01 / 40


def _project(sc, mode, ident=0.5):
    data = sc.to_project_data()
    vecs = []
    for spec, layer in data.vectors:
        m = sc.databases[spec.name]
        sigma = (m.noise, m.noise, 3.5) if mode == "none" else (3.5, 3.5, 3.5)
        vecs.append((replace(spec, sigma=sigma, offset="shift", identification_sigma=(ident, 0.0)),
                     layer))
    reweight = mode.split("/")[0]
    return replace(data, vectors=vecs, settings=replace(data.settings, reweight=reweight))


def _rows(seed, case, mode, data, out):
    ratio = out.summary["roads_and_control"]["check_ratio"]
    harm = bool(out.summary["roads_and_control"]["harm"])
    s0 = out.summary["sigma0_squared"]
    rows = []
    for d, entry in zip(out.databases, out.summary["databases"]):
        tid, txyz = data.truth[d.name]
        ti = lookup(tid, d.shape.vertex_ids)
        sel = (d.vertices["Adjusted"] == 1) & (ti >= 0)
        mean = (d.shape.layer.coords[sel] - txyz[ti[sel]]).mean(axis=0)[:2]
        # (X, Y; the DEM heights' own height offset, where estimated, is not the database's)
        est = np.asarray(entry["offset"]["values"][:2])
        sig = np.asarray(entry["offset"]["sigma"][:2])
        z = float(np.max(np.abs(est - mean) / sig))
        off_ok = bool(np.all(np.abs(est - mean) < 4.0 * sig + 0.02))
        t = d.truth
        rows.append(dict(seed=seed, case=case, mode=mode, db=d.name, n=t["count"], est=est,
                         mean=mean, z=z, off_ok=off_ok, ce=t["share_within_ce90"],
                         le=t["share_within_le90"], ratio=ratio, harm=harm, s0=s0,
                         impr=t["improvement"]))
    return rows


def _print_row(r):
    print(f"{r['seed']:>4} {r['case']:>4} {r['mode']:>8} {r['db']:>5} {r['n']:>5} "
          f"({r['est'][0]:6.2f},{r['est'][1]:6.2f}) ({r['mean'][0]:6.2f},{r['mean'][1]:6.2f}) "
          f"{r['z']:5.1f} {r['ce']:6.3f} {r['le']:6.3f} {r['ratio']:6.3f} {r['s0']:6.3f} "
          f"{r['impr']:6.3f}", flush=True)


def _flag(lo, hi, ok_lo, ok_hi):
    return f"{lo:.3f}-{hi:.3f}" + ("" if ok_lo <= lo and hi <= ok_hi else " !")


def _summary(rows):
    print("\nRange over the seeds (! = outside 0.85-0.95, ratio > 1.05, offset > 4 sigma, harm:"
          " roads_and_control says the roads made the solution worse):")
    print(f"{'case':>4} {'mode':>8} {'db':>5} {'n':>11} {'CE90 cov':>13} {'LE90 cov':>13} "
          f"{'check ratio':>13} {'sigma0^2':>11} {'improvement':>11} offset")
    keys = dict.fromkeys((r["case"], r["mode"], r["db"]) for r in rows)
    for key in keys:
        sel = [r for r in rows if (r["case"], r["mode"], r["db"]) == key]
        col = {k: np.array([r[k] for r in sel]) for k in ("n", "ce", "le", "ratio", "s0", "impr")}
        bad_off = sum(not r["off_ok"] for r in sel)
        harm = sum(r["harm"] for r in sel)
        print(f"{key[0]:>4} {key[1]:>8} {key[2]:>5} {col['n'].min():>5}-{col['n'].max():<5} "
              f"{_flag(col['ce'].min(), col['ce'].max(), 0.85, 0.95):>13} "
              f"{_flag(col['le'].min(), col['le'].max(), 0.85, 0.95):>13} "
              f"{_flag(col['ratio'].min(), col['ratio'].max(), 0.0, 1.05):>13} "
              f"{col['s0'].min():.3f}-{col['s0'].max():.3f} "
              f"{col['impr'].min():.2f}-{col['impr'].max():.2f}  "
              + (f"{bad_off}/{len(sel)} beyond 4 sigma !" if bad_off else
                 f"within 4 sigma (max {max(r['z'] for r in sel):.1f})")
              + f"  harm {harm}/{len(sel)}" + (" !" if harm else ""))


def criteria(rows: list) -> Criteria:
    """The acceptance criteria of the module docstring."""
    seeds = sorted({r["seed"] for r in rows})
    n = len(seeds)
    z = z_two_sided(ALPHA)
    crit = Criteria(f"real road geometry, seeds {seeds}")
    keys = list(dict.fromkeys((r["case"], r["mode"], r["db"]) for r in rows))
    for q, label in (("ce", "CE90"), ("le", "LE90")):
        pooled = {}
        for key in keys:
            sel = [r for r in rows if (r["case"], r["mode"], r["db"]) == key]
            w = np.array([r["n"] for r in sel], float)
            pooled[key] = float(np.sum(np.array([r[q] for r in sel]) * w) / w.sum())
        h = z * SEED_SD[q] / math.sqrt(n)
        lo, hi = min(pooled, key=pooled.get), max(pooled, key=pooled.get)
        crit.add(f"lowest {label} pooled ({' '.join(lo)})", pooled[lo], 0.85 - h, 1.0)
        crit.add(f"highest {label} pooled ({' '.join(hi)})", pooled[hi], 0.0,
                 min(0.95 + h, 1.0))
    runs = list(dict.fromkeys((r["seed"], r["case"], r["mode"]) for r in rows))
    first = [next(r for r in rows if (r["seed"], r["case"], r["mode"]) == k) for k in runs]
    ratio = {}
    for r in first:
        ratio.setdefault((r["case"], r["mode"]), []).append(r["ratio"])
    worst = max(ratio, key=lambda k: np.mean(ratio[k]))
    crit.add(f"highest mean check ratio ({' '.join(worst)})", np.mean(ratio[worst]), 0.0,
             1.05 + z * SEED_SD["ratio"] / math.sqrt(n))
    crit.add("share of runs roads_and_control calls harmed", np.mean([r["harm"] for r in first]),
             0.0, share_band(len(first), 0.0, 0.05, ALPHA)[1])
    crit.add("offsets beyond 4 sigma + 2 cm of the truth (count)",
             sum(not r["off_ok"] for r in rows), 0, 0)
    return crit


def main(argv=None) -> int:
    """Run the cases over the seeds, print the table and the criteria."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="default 1 2 3 4 5 (--fast: 1)")
    ap.add_argument("--cases", nargs="+", default=None, choices=list(CASES),
                    help="default both (--fast: one)")
    ap.add_argument("--fast", action="store_true", help="the fast tier")
    ap.add_argument("--json", help="write the criteria to this file")
    ap.add_argument("--identification", type=float, default=0.5,
                    help="simulated and stated identification error per horizontal axis (m)")
    args = ap.parse_args(argv)
    seeds = args.seeds or ([1] if args.fast else [1, 2, 3, 4, 5])
    cases = args.cases or (["one"] if args.fast else list(CASES))
    roads = read_road_lines(DATA)
    print(f"true roads: {DATA.relative_to(ROOT)} ({len(roads.lines)} lines; OpenStreetMap "
          "data, ODbL 1.0, (c) OpenStreetMap contributors)")
    print(f"{'seed':>4} {'case':>4} {'mode':>8} {'db':>5} {'n':>5} {'offset estimate':>15} "
          f"{'true mean':>15} {'|d|/s':>5} {'CE90':>6} {'LE90':>6} {'ratio':>6} "
          f"{'s0^2':>6} {'impr':>6}")
    rows = []
    t0 = time.perf_counter()
    for seed in seeds:
        for case in cases:
            models, n_pts, modes = CASES[case]
            sc = make_scenario(seed, databases=models, n_shape_points=n_pts,
                               pointing_sigma=args.identification,
                               shape_sigma=(3.5, 3.5, 3.5), true_roads=roads)
            for mode in modes:
                data = _project(sc, mode, args.identification)
                new = _rows(seed, case, mode, data, run(data))
                for r in new:
                    _print_row(r)
                rows += new
    _summary(rows)
    print(f"\n{time.perf_counter() - t0:.0f} s")
    return criteria(rows).report(args.json, {"rows": rows})


if __name__ == "__main__":
    sys.exit(main())
