"""Validation of the conflation (every vertex corrected) over seeds and scenarios.

Run:  PYTHONPATH=core python validation/conflation.py [--seeds 1-20] [--scenarios smooth]
      [--true-covariance | --true-nugget] [--fast] [--json FILE]

``--fast`` (the fast tier of tests/test_validation.py): seed 1 of the four scenarios.

Scenarios (``vectoradjust.simulate.conflation.conflation_scenario``, one database
``OSM``, offset ``shift`` estimated, identification error 0.3 m simulated and stated;
``measured_fraction`` of the object points measured on the images, the rest predicted):

- ``smooth``: 3.6 m constant shift + a smooth field (2 m per axis, correlation length
  150 m) + 0.3 m white noise, on the synthetic street grid;
- ``shift``: the same shift and noise, no field;
- ``helsinki``: the smooth field on REAL road geometry (OSM centrelines of central
  Helsinki, ``tests/data/helsinki``; ODbL 1.0, (c) OpenStreetMap contributors);
- ``helsinki-10``: as ``helsinki`` with only 10 % of the vertices measured;
- ``helsinki-0.3`` (for information): as ``helsinki`` but the database states only its
  white noise (0.3 m) as its sigma, not its real error after the shift (2 m): the
  adjustment is strained, the images' positions err more than their covariance says;
- ``helsinki-waves``: on the Helsinki geometry a long-wavelength field instead of the
  150 m one: three plane waves per axis of wavelengths 300-1500 m (2 m per axis,
  ``vectoradjust.simulate.conflation.wave_field``);
- ``helsinki-waves-clusters`` and ``helsinki-long-clusters`` (for information): the
  waves, or a Gaussian-process field of correlation length 500 m, measured only in
  three patches of 120 m radius (30 % of the vertices there), so that the predicted
  vertices lie 0 to 500 m from the nearest measured one.

The database states its real error once the shift is removed (``hypot(2, 0.3)`` m, the
shift-only database 0.3 m) and its heights are DEM heights (0.1 m error) stated 3 m.

Prints per seed and scenario: measured / predicted vertices, RMSE of the predicted
vertices to the truth before (database) and after, the reduction, CE90 and LE90
coverage of the truth at the predicted vertices, the leave-one-out cross-validation
(RMSE, share inside the predicted 90 % radius), two invariants: the largest change of
a measured vertex against the same run without conflation, and the largest distance
between vertices of one object point (coincident vertices); and the RMS step of the
displacement between a measured vertex and its unmeasured neighbour on a road, without
conflation (its whole V) > with it (what is left: mostly the database's white noise,
which no prediction can know); and the height RMSE of the predicted vertices before >
after (the database's heights are DEM heights here). ``!`` marks a reduction
below 70 % or a coverage outside 0.85-0.95. Last, per scenario, the database noise
``n_db``: its estimate's mean and SD over the seeds against the true 0.09 m^2 and
``z = (true - estimate) / posterior SD`` (about 0 +- 1 when the CE90's mixing over
``n_db`` is honest; :func:`noise_table`).

Acceptance criteria (docs/experiments.md section 7; exit status 1 when one is missed;
validation/acceptance.py). For each of the four scenarios (``helsinki-0.3`` is for
information: it shows what a misstated sigma does), over the ``n`` seeds:

1. CE90 pooled over the seeds covers the predicted vertices 85-95 %, widened by
   ``z SD / sqrt(n)`` with ``SD`` the per-seed scatter seeds 1-20 measured
   (``SEED_SD``; one seed's coverage rests on its fitted covariance: with one seed the
   band is about 0.62-1 for the synthetic scenarios, with 20 seeds 0.80-1);
2. LE90 pooled at least 0.85 (less ``z SD / sqrt(n)``): too wide is documented and
   kept (the DEM heights are better than the images');
3. mean RMSE reduction at least 70 % (less ``z SD / sqrt(n)``);
4. measured vertices unchanged by the conflation and coincident vertices together:
   both at most 1e-6 m in every seed (deterministic);
5. the step between a measured and an unmeasured neighbour: after / before at most 0.3
   in every seed (4.2-5.0 m -> 0.5-0.7 m measured);
6. height RMSE of the predicted vertices after / before, mean over the seeds, at most
   1.05 (not worse than the DEM's);
7. (issue 30) CE90 pooled per distance band of the predicted vertices from the nearest
   measured one (0-50, 50-100, 100-200, > 200 m; bands with fewer than ``MIN_BAND``
   vertices over the seeds are skipped) within 85-95 %, widened by ``z SD / sqrt(n)``
   with the band's per-seed SD (``BAND_SD``) and ``z`` for ``0.01 / 20``, also for
   ``helsinki-waves``.

The per-band table (CE90 and LE90 pooled, vertices per band) is printed for every
scenario, the clustered ones included.

``z`` is for a two-sided ``0.01 / 12`` (three statistical criteria, four scenarios): a
correct implementation passes all with >= 99 %.
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

from acceptance import Criteria, z_two_sided  # noqa: E402

from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import read_road_lines  # noqa: E402
from vectoradjust.simulate.conflation import conflation_scenario  # noqa: E402

ROADS = ROOT / "tests" / "data" / "helsinki" / "helsinki_roads.geojson"
#: per-seed standard deviations (CE90, LE90, reduction) of the scenarios with acceptance
#: criteria; seeds 1-20 measured (0.065, 0.011, 0.055), (0.066, 0.011, 0.007),
#: (0.031, 0.042, 0.024), (0.048, 0.025, 0.026): these are ~10 % larger (an SD from 20
#: seeds is uncertain by +-16 %)
SEED_SD = {"smooth": (0.07, 0.015, 0.06), "shift": (0.07, 0.015, 0.01),
           "helsinki": (0.035, 0.05, 0.03), "helsinki-10": (0.055, 0.03, 0.03)}
ALPHA = 0.01 / 12
#: fewest predicted vertices (over the seeds) a distance band needs for criterion 7
MIN_BAND = 100
#: the band criteria's own two-sided level: at most 20 bands (five scenarios x four)
BAND_ALPHA = 0.01 / 20
#: per-seed SD of a band's CE90 coverage (bands 0-50, 50-100, 100-200, > 200 m)
BAND_SD = {"smooth": (0.07, 0.1, 0.15, 0.15), "shift": (0.07, 0.1, 0.15, 0.15),
           "helsinki": (0.035, 0.1, 0.15, 0.15), "helsinki-10": (0.055, 0.08, 0.15, 0.15),
           "helsinki-waves": (0.05, 0.1, 0.15, 0.15)}


def scenarios():
    roads = read_road_lines(ROADS)
    return {
        "smooth": {},
        "shift": {"amplitude": 0.0},
        "helsinki": {"true_roads": roads},
        "helsinki-10": {"true_roads": roads, "measured_fraction": 0.1},
        # not one of the four: the database states only its white noise (0.3 m) although
        # a 2 m field is present, so the adjustment itself is strained (sigma0^2 7-12)
        "helsinki-0.3": {"true_roads": roads, "stated_sigma": 0.3},
        # issue 30: long-wavelength fields, and predictions far from measured patches
        "helsinki-waves": {"true_roads": roads, "field": "waves"},
        "helsinki-waves-clusters": {"true_roads": roads, "field": "waves",
                                    "layout": "clusters"},
        "helsinki-long-clusters": {"true_roads": roads, "length": 500.0,
                                   "layout": "clusters"},
    }


def invariants(out, ref) -> tuple:
    """Largest change of a measured vertex (vs ``ref``) and spread of coincident vertices."""
    d, r = out.databases[0], ref.databases[0]
    m = d.vertices["Adjusted"] == 1
    adj = np.column_stack([d.vertices[f"Adj{a}"] for a in "XYZ"])
    radj = np.column_stack([r.vertices[f"Adj{a}"] for a in "XYZ"])
    moved = float(np.nanmax(np.abs(adj[m] - radj[m]))) if m.any() else 0.0
    vo = d.shape.vertex_object
    first = d.shape.object_vertex[vo]
    spread = float(np.nanmax(np.abs(adj[:, :2] - adj[first, :2]))) if len(vo) else 0.0
    return moved, spread


def boundary_step(d) -> tuple:
    """RMS step of the displacement across measured/unmeasured neighbours of a feature:
    before conflation (the measured vertex's V: the unmeasured one stayed) and after."""
    v, lay = d.vertices, d.shape.layer
    m = v["Adjusted"] == 1
    same = (lay.vertex_feature[1:] == lay.vertex_feature[:-1]) & (m[1:] != m[:-1])
    i = np.arange(len(m) - 1)[same]
    meas = np.where(m[i + 1], i + 1, i)
    other = np.where(m[i + 1], i, i + 1)
    vv = np.column_stack([v["Vx"], v["Vy"]])
    if not len(i):
        return float("nan"), float("nan")
    before = np.hypot(*vv[meas].T)
    after = np.hypot(*(vv[meas] - vv[other]).T)
    return float(np.sqrt(np.mean(before ** 2))), float(np.sqrt(np.mean(after ** 2)))


def one(name: str, kw: dict, seed: int) -> dict:
    data = conflation_scenario(seed, **kw)
    t0 = time.perf_counter()
    out = run(data)
    el = time.perf_counter() - t0
    ref = run(replace(data, conflation={"enabled": False}))
    e = out.summary["conflation"]["databases"][0]
    tr = e["truth"]
    cv = e["cross_validation"]["horizontal"]
    fit = e["covariance"]["horizontal"]
    moved, spread = invariants(out, ref)
    step0, step1 = boundary_step(out.databases[0])
    return {"scenario": name, "seed": seed, "measured": e["vertices"]["measured"],
            "predicted": e["vertices"]["interpolated"] + e["vertices"]["extrapolated"],
            "predicted_truth": tr["count"],
            "rmse_db": tr["rmse_database_truth_horizontal"],
            "rmse_conf": tr["rmse_conflated_truth_horizontal"], "reduction": tr["reduction"],
            "ce90": tr["share_within_ce90"], "le90": tr["share_within_le90"],
            "z_db": tr["rmse_database_truth_z"], "z_conf": tr["rmse_conflated_truth_z"],
            "cv_rmse": cv["rmse"], "cv_share": cv["share_within_90"], "moved": moved,
            "spread": spread, "step0": step0, "step1": step1, "seconds": el,
            "nugget": fit["nugget"], "nugget_sd": fit.get("nugget_sd", 0.0),
            "true_nugget": kw.get("noise", 0.3) ** 2,
            "sill": fit["sill"], "length": fit["length"],
            "model": fit["model"], "bands": tr["bands"]}


def noise_table(rows: list, names: list) -> None:
    """The database noise ``n_db`` per scenario over the seeds: its estimate's mean and
    scatter against the scenario's true value, the posterior SD the run states
    (``nugget_sd``), and ``z = (true - estimate) / posterior SD`` (mean and SD over the
    seeds; about 0 and 1 when the estimate is unbiased and its stated uncertainty
    honest, the condition for the CE90's mixing over ``n_db``, :func:`ce90_factor`)."""
    print("\ndatabase noise n_db (m^2; true: the scenario's white noise squared; "
          "z = (true - estimate) / posterior SD):")
    for name in names:
        sel = [r for r in rows if r["scenario"] == name]
        if not sel:
            continue
        est = np.array([r["nugget"] for r in sel], float)
        sd = np.array([r["nugget_sd"] for r in sel], float)
        true = sel[0]["true_nugget"]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(sd > 0, (true - est) / sd, np.nan)
        z = z[np.isfinite(z)]
        ddof = 1 if len(est) > 1 else 0
        zt = (f"z mean {z.mean():+.2f} SD {z.std(ddof=1) if len(z) > 1 else 0.0:.2f}"
              if z.size else "z -")
        print(f"{name:24s} true {true:.3f} estimate mean {est.mean():.3f} SD "
              f"{est.std(ddof=ddof):.3f} | posterior SD mean {sd.mean():.3f} | {zt}")


def pooled_bands(sel: list) -> list:
    """Per distance band over the rows ``sel``: ``(band, count, CE90, LE90)`` pooled
    over all predicted vertices of all seeds (None where a band is empty)."""
    out = []
    for j, b in enumerate(sel[0]["bands"]):
        n = sum(r["bands"][j]["count"] for r in sel)
        ce = sum((r["bands"][j]["ce90"] or 0.0) * r["bands"][j]["count"] for r in sel)
        le = sum((r["bands"][j]["le90"] or 0.0) * r["bands"][j]["count"] for r in sel)
        out.append((b["band"], n, ce / n if n else None, le / n if n else None))
    return out


def band_table(rows: list, names: list) -> None:
    """Print CE90 / LE90 coverage pooled per distance band from the nearest measured
    vertex, per scenario, and the per-seed CE90 range per band."""
    print("\nper distance band from the nearest measured vertex (pooled over the seeds; "
          "CE90 per seed min-max):")
    for name in names:
        sel = [r for r in rows if r["scenario"] == name]
        if not sel:
            continue
        cells = []
        for j, (band, n, ce, le) in enumerate(pooled_bands(sel)):
            if not n:
                cells.append(f"{band} m: -")
                continue
            per = [r["bands"][j]["ce90"] for r in sel if r["bands"][j]["count"]]
            cells.append(f"{band} m: n {n} CE90 {ce:.3f} ({min(per):.2f}-{max(per):.2f}) "
                         f"LE90 {le:.3f}")
        print(f"{name:24s} " + " | ".join(cells))


def summary(rows: list, names: list) -> None:
    """Per scenario over the seeds: min-max, mean and SD of the per-seed figures, the
    coverage pooled over all predicted vertices of all seeds, and how many seeds fall
    outside 0.85-0.95 (one seed's coverage scatters by itself: its field, its database
    noise and its covariance parameters are estimated from 50-350 measured points)."""
    print("\nover the seeds (per-seed figures: min-max, mean +- SD; pooled: all predicted "
          "vertices of all seeds; out: seeds outside 0.85-0.95):")
    for name in names:
        sel = [r for r in rows if r["scenario"] == name]
        if not sel:
            continue
        n = np.array([r["predicted_truth"] for r in sel], float)

        def stat(k, sel=sel, n=n, band=False):
            v = np.array([r[k] for r in sel], float)
            txt = (f"{k.upper()} {v.min():.2f}-{v.max():.2f} mean {v.mean():.3f}"
                   f"+-{v.std(ddof=1) if len(v) > 1 else 0.0:.3f}")
            if band:
                txt += (f" pooled {np.sum(v * n) / n.sum():.3f}"
                        f" out {int(np.sum((v < 0.85) | (v > 0.95)))}/{len(v)}")
            return txt

        worse = sum(r["z_conf"] > 1.1 * r["z_db"] for r in sel)
        zr = np.mean([r["z_conf"] / r["z_db"] for r in sel])
        print(f"{name:12s} {stat('reduction')}\n{'':12s} {stat('ce90', band=True)}\n"
              f"{'':12s} {stat('le90', band=True)}\n{'':12s} {stat('cv_share')}  "
              f"height RMSE after/before {zr:.2f}, > 1.1 in {worse}/{len(sel)} seeds")


def criteria(rows: list, names: list) -> Criteria:
    """The acceptance criteria of the module docstring, per scenario with criteria."""
    z = z_two_sided(ALPHA)
    crit = Criteria("conflation: predicted vertices against the truth")
    for name in names:
        sel = [r for r in rows if r["scenario"] == name]
        if name not in SEED_SD or not sel:
            continue
        k = len(sel)
        w = np.array([r["predicted_truth"] for r in sel], float)
        col = {c: np.array([r[c] for r in sel], float)
               for c in ("ce90", "le90", "reduction", "moved", "spread", "step0", "step1",
                         "z_db", "z_conf")}
        sd = [v * z / math.sqrt(k) for v in SEED_SD[name]]
        tag = f"{name} ({k} seeds)"
        crit.add(f"{tag}: CE90 pooled", np.sum(col["ce90"] * w) / w.sum(), 0.85 - sd[0],
                 min(0.95 + sd[0], 1.0), "docs/experiments.md 7")
        crit.add(f"{tag}: LE90 pooled", np.sum(col["le90"] * w) / w.sum(), 0.85 - sd[1], 1.0)
        crit.add(f"{tag}: mean RMSE reduction", col["reduction"].mean(), 0.70 - sd[2], 1.0)
        crit.add(f"{tag}: measured vertices moved (m, max)", col["moved"].max(), 0.0, 1e-6)
        crit.add(f"{tag}: coincident vertices apart (m, max)", col["spread"].max(), 0.0, 1e-6)
        crit.add(f"{tag}: boundary step after / before (max)",
                 np.max(col["step1"] / col["step0"]), 0.0, 0.3)
        crit.add(f"{tag}: height RMSE after / before (mean)",
                 np.mean(col["z_conf"] / col["z_db"]), 0.0, 1.05)
    for name in names:  # 7: per distance band
        sel = [r for r in rows if r["scenario"] == name]
        if name not in BAND_SD or not sel:
            continue
        for sd, (band, n, ce, _) in zip(BAND_SD[name], pooled_bands(sel)):
            if n >= MIN_BAND:
                w = z_two_sided(BAND_ALPHA) * sd / math.sqrt(len(sel))
                crit.add(f"{name} ({len(sel)} seeds): CE90 pooled at {band} m ({n})", ce,
                         0.85 - w, min(0.95 + w, 1.0), "issue 30")
    return crit


def _seeds(text: list) -> list:
    """``1 2 5`` or ``1-20``."""
    out = []
    for t in text:
        a, _, b = t.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def use_true_covariance(nugget_only: bool = False) -> None:
    """``--true-covariance``: the horizontal field's covariance is the scenario's own
    (Gaussian, sill ``amplitude^2``, length ``sqrt(2) * 150`` m, database noise 0.09 m^2)
    instead of the fit; what then scatters from seed to seed is the finite, correlated
    sample of vertices alone, and a bias of the variance formulas shows without the
    fit's noise. The scenarios must keep their default field (all of them here do).
    ``nugget_only`` (``--true-nugget``): only the database noise is the true 0.09 m^2,
    the signal's sill and length stay fitted (which parameter's error moves a seed)."""
    import vectoradjust.conflation as conf
    import vectoradjust.conflation.fields as conf_fields  # where it is looked up

    fit = conf_fields.fit_covariance

    def true_fit(xy, resid, known, kind="auto", k=12, max_targets=1000, corr=None):
        f = fit(xy, resid, known, kind, k, max_targets, corr=corr)
        if resid.shape[1] != 2:  # heights: fitted
            return f
        if nugget_only:
            return replace(f, nugget=0.3 ** 2, nugget_posterior=None,
                           fit={**f.fit, "status": "true nugget"})
        sill = _TRUE["amplitude"] ** 2
        return conf.CovarianceModel("gaussian", sill, 150.0 * np.sqrt(2) if sill else 0.0,
                                    0.3 ** 2, f.known_noise, {**f.fit, "status": "true"})

    conf_fields.fit_covariance = true_fit


_TRUE = {"amplitude": 2.0}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", nargs="+", default=None,
                   help="seeds, e.g. 1 2 3 or 1-20 (default 1-20; --fast: 1)")
    p.add_argument("--scenarios", nargs="+", default=None,
                   help="default: all (--fast: the four with criteria)")
    p.add_argument("--fast", action="store_true", help="the fast tier")
    p.add_argument("--json", help="write the criteria to this file")
    p.add_argument("--true-covariance", action="store_true",
                   help="the scenario's true horizontal covariance instead of the fit")
    p.add_argument("--true-nugget", action="store_true",
                   help="only the database noise true (0.09 m^2), sill and length fitted")
    args = p.parse_args(argv)
    if args.true_covariance or args.true_nugget:
        use_true_covariance(nugget_only=not args.true_covariance)
    args.seeds = _seeds(args.seeds or (["1"] if args.fast else ["1-20"]))
    if args.fast and args.scenarios is None:
        args.scenarios = list(SEED_SD)
    todo = {k: v for k, v in scenarios().items()
            if args.scenarios is None or k in args.scenarios}
    head = (f"{'scenario':12s} {'seed':>4s} {'meas':>5s} {'pred':>5s} {'db m':>6s} "
            f"{'conf m':>6s} {'reduc':>6s} {'CE90':>5s} {'LE90':>5s} {'cvRMSE':>6s} "
            f"{'cv90':>5s} {'moved':>7s} {'spread':>7s} {'step':>9s} {'Z m':>9s} {'run s':>5s} "
            f"{'n_db':>6s} {'sill':>5s} {'L':>5s}")
    print(head)
    rows = []
    for name, kw in todo.items():
        _TRUE["amplitude"] = kw.get("amplitude", 2.0)
        for seed in args.seeds:
            r = one(name, kw, seed)
            rows.append(r)
            flag = "!" if (r["reduction"] < 0.7 or not 0.85 <= r["ce90"] <= 0.95
                           or not 0.85 <= r["le90"] <= 0.95) else ""
            print(f"{name:12s} {seed:4d} {r['measured']:5d} {r['predicted']:5d} "
                  f"{r['rmse_db']:6.2f} {r['rmse_conf']:6.2f} {r['reduction']:6.1%} "
                  f"{r['ce90']:5.2f} {r['le90']:5.2f} {r['cv_rmse']:6.2f} {r['cv_share']:5.2f} "
                  f"{r['moved']:7.1e} {r['spread']:7.1e} {r['step0']:4.1f}>{r['step1']:4.1f} "
                  f"{r['z_db']:4.2f}>{r['z_conf']:4.2f} "
                  f"{r['seconds']:5.1f} {r['nugget']:6.3f} {r['sill']:5.2f} {r['length']:5.0f} "
                  f"{flag}")
    summary(rows, list(todo))
    band_table(rows, list(todo))
    noise_table(rows, list(todo))
    if args.true_covariance or args.true_nugget:
        print("(the criteria are those of the fitted covariance; here for information)")
    return criteria(rows, list(todo)).report(args.json, {"rows": rows})


if __name__ == "__main__":
    raise SystemExit(main())
