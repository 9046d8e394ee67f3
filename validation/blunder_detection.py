"""On-demand validation of vectoradjust.adjust.reliability: the w-test's false alarms and power.

Run:  PYTHONPATH=core python validation/blunder_detection.py [--seeds 200] [--blunder 5]
      [--alpha0 0.001] [--big] [--stereo-seeds N] [--fast] [--json FILE]

``--fast`` (the fast tier of tests/test_validation.py): 40 resection seeds, 4 stereo seeds.

What is achievable (the numbers to compare with): a blunder ``e`` on an observation with
standard deviation ``sigma`` and redundancy number ``r`` shifts its w by ``e sqrt(r) /
sigma``; the two-sided test at ``alpha0 = 0.001`` (critical 3.2905) flags it with
probability ``Phi(5 sqrt(r) - 3.29) + Phi(-5 sqrt(r) - 3.29)`` for ``e = 5 sigma``: 0.60 at
r = 0.5, 0.88 at r = 0.8, 0.96 at r = 1. A detection rate of 95 % for a 5-sigma blunder
needs ``r >= 0.974``; and a run with K tested observations has no false alarm with
probability about ``(1 - alpha0)^K``, >= 99 % only for K <= 10. Both at once need an
adjustment with at most ten observations that are all nearly fully redundant, which a
photogrammetric adjustment (6 unknowns per image, 3 per point) never is.

Studies (every random draw seeded):

A. Single-image resection (the set-up of Dewitt's resect.dat, simulated): RC10 camera at
   1:4000, 5 control points held by 1e-6 m priors, image sigma 15 um; 10 tested image
   coordinates, 4 degrees of freedom. The smallest case where the per-run false-alarm
   requirement is meaningful. Clean runs: share without any flag. Blunder runs: a 5-sigma
   blunder in (a) one randomly chosen coordinate per seed, (b) each of the 10 coordinates
   in turn; measured rate of "flagged" (its |w| > critical) and "identified" (flagged and
   the largest |w|), against the theoretical rate from its redundancy number.
   Also the same statistics with two WRONG definitions of w (a-posteriori sigma0, i.e.
   Pope's tau against the normal critical value; and v / sigma without sqrt(r)) to show
   that the test in the suite can tell.

B. The stereo pair of the sample project (simulate.make_scenario, 2 images, 24 GCPs, 10
   tie points, one road database with iid N(0, 3 m) errors whose prior sigma is the true
   one): clean runs (share without a flag, per-observation false-alarm rate, mean w^2) and
   a 5-sigma blunder in one random image coordinate (uniform over all), and in one random
   coordinate of each class (control / shape / tie point, x / y).

C. (--big) Time of reliability() at 10^5 shape points.

Acceptance criteria (exit status 1 when one is missed; validation/acceptance.py; each
statistical band at ``alpha = 0.01 / 9``, so a correct implementation passes all with
>= 99 %):

0. the power table gives the figures above (0.60 at r = 0.5, 0.88 at 0.8, 0.96 at 1,
   r >= 0.974 for 95 %), to 0.005;
A1. clean resections without any flag: at least ``(1 - alpha0)^10`` (0.990; the w's
   are correlated, which only raises the share: Sidak's inequality), less the binomial
   sampling of the seeds;
A2. 5-sigma blunders in each coordinate in turn: the flagged rate equals the mean of
   the theoretical rates within ``z`` standard errors (the binomial variance of the
   theoretical rates, times a design effect of 1.5: the ten blunders of one seed share
   its noise);
A3. (with 20 resection seeds or more) the suite's test can tell a wrong w: with Pope's
   tau against the normal critical value, and with v / sigma (no sqrt(r)), the flagged
   rate is more than ``z`` standard errors from the theory (about 7 of them at 20
   seeds, 10 at 40);
B1. the stereo pair's per-observation false-alarm rate is alpha0 (binomial band on the
   tested values over a design effect of 2);
B2. mean w^2 is 1 within ``z sqrt(2 deff / n)``;
B3. a blunder in one random image coordinate: flagged rate = theory (as A2);
B4. one blunder per observation class (control, shape, tie point; x, y), pooled:
   flagged rate = theory (as A2);
B5. clean stereo runs: at least ``(1 - alpha0)^K`` (K ~ 1500 tested values), less
   the binomial sampling.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

from acceptance import Criteria, mean_band, share_band, z_two_sided  # noqa: E402

from vectoradjust.adjust.bundle import BundleProblem, adjust  # noqa: E402
from vectoradjust.adjust.reliability import (  # noqa: E402
    critical_value,
    detection_power,
    reliability,
)
from vectoradjust.sensor.collinearity import project, rotation_matrix  # noqa: E402

FOCAL = 152.4
SIGMA = 0.015
FLYING_HEIGHT = 609.6
TERRAIN = 188.0
#: statistical criteria (A1-A3 count 3, B1-B5 5, plus one for the two wrong w's): the
#: level of each band
ALPHA = 0.01 / 9
#: design effects: blunders of one seed share its noise; the w of one stereo run are
#: correlated through the adjustment
DEFF_BLUNDER = 1.5
DEFF_W = 2.0


def resection_problem(seed: int, n_points: int = 5, sigma: float = SIGMA) -> BundleProblem:
    """A simulated single-image resection with fixed (1e-6 m) control points."""
    rng = np.random.default_rng([seed, 4242])
    eo = np.r_[rng.normal(0.0, 3.0, 2), TERRAIN + FLYING_HEIGHT + rng.normal(0.0, 1.5),
               np.radians(rng.normal(0.0, 0.3, 3))]
    xy = rng.uniform(-100.0, 100.0, (n_points, 2))
    z = TERRAIN + rng.normal(0.0, 3.0, n_points)
    m = rotation_matrix(*eo[3:])
    d = np.column_stack([xy, np.full(n_points, -FOCAL)]) @ m  # M^T v, row-wise
    xyz = eo[:3] + ((z - eo[2]) / d[:, 2])[:, None] * d
    obs = project(np.tile(eo, (n_points, 1)), xyz, FOCAL) + rng.normal(0.0, sigma, (n_points, 2))
    eo0 = np.r_[np.round(eo[:3]), 0.0, 0.0, 0.0]
    return BundleProblem(FOCAL, (0.0, 0.0), eo0[None], np.full((1, 6), np.inf), xyz, xyz,
                         np.tile(np.eye(3) / 1e-6**2, (n_points, 1, 1)), np.arange(n_points),
                         np.zeros(n_points, int), obs, np.full((n_points, 2), sigma))


def stereo_problem(seed: int):
    """The sample project's stereo set-up with one iid road database (true sigmas)."""
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import DatabaseModel, make_scenario

    iid = DatabaseModel("IID", "iid_id", "iid", 20.0, 0.4, (0.0, 0.0), 0.0, 0.0, 3.0)
    sc = make_scenario(seed, databases=(iid,))
    data = sc.to_project_data()
    data.settings.reweight = "none"
    spec, layer = data.vectors[0]
    sz = float(np.sqrt(np.mean((layer.coords[:, 2] - sc.truth["IID"][1][:, 2]) ** 2)))
    data.vectors[0] = (replace(spec, sigma=(3.0, 3.0, sz)), layer)
    out = run(data)
    return out.problem, out.point_kind


def _with_blunder(prob: BundleProblem, k: int, a: int, size: float) -> BundleProblem:
    xy = prob.obs_xy.copy()
    xy[k, a] += size
    return replace(prob, obs_xy=xy)


def _rate(hits: int, n: int) -> str:
    p = hits / n if n else float("nan")
    se = math.sqrt(max(p * (1 - p), 1e-12) / n) if n else float("nan")
    return f"{100 * p:6.2f} % ({hits}/{n}, se {100 * se:.2f} %)"


def study_resection(seeds, blunder: float, alpha0: float) -> dict:
    crit = critical_value(alpha0)
    clean = 0
    wrong_clean = {"tau": 0, "no_sqrt_r": 0}
    one = {"flag": 0, "ident": 0, "theory": 0.0, "var": 0.0, "n": 0}
    each = {"flag": 0, "ident": 0, "theory": 0.0, "var": 0.0, "n": 0,
            "wrong_tau": 0, "wrong_no_sqrt_r": 0}
    per_coord = np.zeros((10, 3))
    r_all = []
    for s in seeds:
        prob = resection_problem(s)
        res = adjust(prob)
        rel = reliability(res, alpha0=alpha0)
        clean += rel.n_flagged == 0
        s0 = math.sqrt(res.sigma0_squared) / SIGMA
        wrong_clean["tau"] += bool((np.abs(rel.w_image / s0) > crit).any())
        wrong_clean["no_sqrt_r"] += bool((np.abs(res.v_image / SIGMA) > crit).any())
        r_all.append(rel.r_image.ravel())
        pick = int(np.random.default_rng([s, 777]).integers(10))
        for c in range(10):
            k, a = divmod(c, 2)
            r2 = adjust(_with_blunder(prob, k, a, blunder * SIGMA))
            rb = reliability(r2, alpha0=alpha0)
            aw = np.abs(np.nan_to_num(rb.w_image))
            flag = bool(rb.flag_image[k, a])
            ident = flag and int(np.argmax(aw)) == c
            th = float(detection_power(blunder * math.sqrt(rel.r_image[k, a]), alpha0))
            each["flag"] += flag
            each["ident"] += ident
            each["theory"] += th
            each["var"] += th * (1 - th)
            each["n"] += 1
            per_coord[c] += (flag, th, rel.r_image[k, a])
            s0b = math.sqrt(r2.sigma0_squared) / SIGMA
            each["wrong_tau"] += bool(abs(rb.w_image[k, a] / s0b) > crit)
            each["wrong_no_sqrt_r"] += bool(abs(r2.v_image[k, a] / SIGMA) > crit)
            if c == pick:
                one["flag"] += flag
                one["ident"] += ident
                one["theory"] += th
                one["var"] += th * (1 - th)
                one["n"] += 1
    n = len(seeds)
    r_all = np.concatenate(r_all)
    print("A. single-image resection, 5 fixed control points, 10 image coordinates, 4 dof")
    print(f"   redundancy numbers: min {r_all.min():.3f}, median {np.median(r_all):.3f}, "
          f"max {r_all.max():.3f}")
    print(f"   clean runs without any flag      {_rate(clean, n)}   "
          f"(binomial approximation (1 - alpha0)^10 = {100 * (1 - alpha0) ** 10:.2f} %)")
    print(f"   {blunder:g}-sigma blunder, one random coordinate per seed:")
    print(f"     flagged    {_rate(one['flag'], one['n'])}   theory "
          f"{100 * one['theory'] / one['n']:.2f} %")
    print(f"     identified {_rate(one['ident'], one['n'])}")
    print(f"   {blunder:g}-sigma blunder in each coordinate in turn:")
    print(f"     flagged    {_rate(each['flag'], each['n'])}   theory "
          f"{100 * each['theory'] / each['n']:.2f} %")
    print(f"     identified {_rate(each['ident'], each['n'])}")
    print("     per coordinate (point, axis): mean r, measured, theory")
    for c in range(10):
        f, th, r = per_coord[c] / n
        print(f"       {c // 2} {'xy'[c % 2]}  r {r:.3f}  {100 * f:6.1f} %  {100 * th:6.1f} %")
    print("   wrong definitions of w (for comparison):")
    print(f"     Pope's tau vs normal critical: flagged {_rate(each['wrong_tau'], each['n'])}, "
          f"clean {_rate(n - wrong_clean['tau'], n)}")
    print(f"     v / sigma (no sqrt r):         flagged "
          f"{_rate(each['wrong_no_sqrt_r'], each['n'])}, clean "
          f"{_rate(n - wrong_clean['no_sqrt_r'], n)}")
    return {"clean": clean / n, "n": n, "one": one, "each": each}


def study_stereo(seeds, blunder: float, alpha0: float) -> dict:
    classes = [(kd, a) for kd in ("control", "shape", "tie") for a in (0, 1)]
    stats = {c: [0, 0, 0.0, 0, 0.0] for c in classes}  # flag, ident, theory, n, var
    rnd = [0, 0, 0.0, 0, 0.0]
    clean = 0
    tested = 0
    flags = 0
    w2 = []
    for s in seeds:
        prob, kind = stereo_problem(s)
        res = adjust(prob)
        rel = reliability(res, alpha0=alpha0)
        clean += rel.n_flagged == 0
        ws = np.concatenate([rel.w_image.ravel(), rel.w_point.ravel()])
        ws = ws[np.isfinite(ws)]
        tested += ws.size
        flags += int((np.abs(ws) > rel.critical).sum())
        w2.append(ws**2)
        rng = np.random.default_rng([s, 999])
        okind = kind[prob.obs_point]
        jobs = [("random", int(rng.integers(len(prob.obs_point))), int(rng.integers(2)))]
        for kd, a in classes:
            cand = np.flatnonzero(okind == kd)
            jobs.append(((kd, a), int(rng.choice(cand)), a))
        for key, k, a in jobs:
            rb = reliability(adjust(_with_blunder(prob, k, a, blunder * SIGMA)), alpha0=alpha0)
            aw = np.abs(np.nan_to_num(rb.w_image))
            flag = bool(rb.flag_image[k, a])
            ident = flag and int(np.argmax(aw)) == 2 * k + a
            th = float(detection_power(blunder * math.sqrt(max(rel.r_image[k, a], 0.0)),
                                       alpha0))
            tgt = rnd if key == "random" else stats[key]
            tgt[0] += flag
            tgt[1] += ident
            tgt[2] += th
            tgt[3] += 1
            tgt[4] += th * (1 - th)
    n = len(seeds)
    w2 = np.concatenate(w2)
    print("B. stereo pair of the sample project (24 GCPs, 10 ties, iid road database)")
    print(f"   tested observations per run (image coordinates and point priors): "
          f"{tested / n:.0f}")
    print(f"   clean runs without any flag      {_rate(clean, n)}   "
          f"((1 - alpha0)^K = {100 * (1 - alpha0) ** (tested / n):.1f} %)")
    print(f"   per-observation false-alarm rate {flags / tested:.5f} (alpha0 = {alpha0}); "
          f"mean w^2 {w2.mean():.4f} over {w2.size} values")
    print(f"   {blunder:g}-sigma blunder in one random image coordinate:")
    print(f"     flagged    {_rate(rnd[0], rnd[3])}   theory {100 * rnd[2] / rnd[3]:.2f} %")
    print(f"     identified {_rate(rnd[1], rnd[3])}")
    print("   by class (one random observation of the class per seed):")
    for (kd, a), (f, i, th, m, _) in stats.items():
        print(f"     {kd:8s} {'xy'[a]}: flagged {_rate(f, m)}, theory {100 * th / m:.1f} %, "
              f"identified {_rate(i, m)}")
    return {"clean": clean / n, "n": n, "false_alarm": flags / tested, "tested": tested,
            "w2": float(w2.mean()), "n_w2": int(w2.size), "random": rnd, "classes": stats}


def power_table(blunder: float, alpha0: float) -> dict:
    """C. the w-test's power by redundancy number; the power at r = 0.5, 0.8, 1 and the r
    that 95 % power needs."""
    k = critical_value(alpha0)
    print(f"C. power of the w-test (alpha0 = {alpha0}, critical {k:.4f}) for a {blunder:g}-sigma "
          "blunder")
    for r in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.975, 1.0):
        p = float(detection_power(blunder * math.sqrt(r), alpha0))
        print(f"   r = {r:5.3f}: {100 * p:5.1f} %")
    from scipy.stats import norm

    need = k + float(norm.ppf(0.95))
    print(f"   95 % power needs a shift of {need:.3f}: r >= {(need / blunder) ** 2:.3f} for "
          f"{blunder:g} sigma, or a blunder of {need / math.sqrt(0.5):.2f} sigma at r = 0.5")
    return {r: float(detection_power(blunder * math.sqrt(r), alpha0)) for r in (0.5, 0.8, 1.0)} \
        | {"r95": (need / blunder) ** 2}


def _vs_theory(crit: Criteria, name: str, hits: float, theory: float, var: float,
               n: int) -> None:
    """Flagged rate minus the mean theoretical rate, within z standard errors."""
    se = math.sqrt(max(var, 1e-12) * DEFF_BLUNDER) / n
    crit.band(f"{name}: flagged minus theory", (hits - theory) / n,
              mean_band(0.0, 0.0, se, ALPHA))


def criteria(power: dict, a: dict, b: dict, blunder: float, alpha0: float) -> Criteria:
    """The acceptance criteria of the module docstring."""
    crit = Criteria(f"w-test, {a['n']} resections, {b['n']} stereo runs")
    if blunder == 5.0 and alpha0 == 0.001:
        for r, want in ((0.5, 0.60), (0.8, 0.88), (1.0, 0.96)):
            crit.add(f"0 power of a 5-sigma blunder at r = {r}", power[r], want - 0.005,
                     want + 0.005)
        crit.add("0 r needed for 95 % power", power["r95"], 0.969, 0.979)
    crit.add("A1 resection: clean runs without a flag", a["clean"],
             share_band(a["n"], (1 - alpha0) ** 10, 1.0, ALPHA)[0], 1.0)
    e = a["each"]
    _vs_theory(crit, "A2 resection, blunder in each coordinate", e["flag"], e["theory"],
               e["var"], e["n"])
    se = math.sqrt(max(e["var"], 1e-12) * DEFF_BLUNDER) / e["n"]
    z = z_two_sided(ALPHA)
    for key, label in (("wrong_tau", "Pope's tau"), ("wrong_no_sqrt_r", "v / sigma")):
        if a["n"] < 20:  # fewer seeds cannot tell v / sigma (~17 %) from theory (~44 %)
            continue
        crit.add(f"A3 a wrong w ({label}) is told apart: |rate - theory| / se",
                 abs(e[key] - e["theory"]) / e["n"] / se, z, None)
    tested = b["tested"]
    crit.band("B1 stereo: per-observation false-alarm rate", b["false_alarm"],
              share_band(tested, alpha0, alpha0, ALPHA, DEFF_W))
    crit.band("B2 stereo: mean w^2", b["w2"],
              mean_band(1.0, 1.0, math.sqrt(2.0 * DEFF_W / b["n_w2"]), ALPHA))
    r = b["random"]
    _vs_theory(crit, "B3 stereo, blunder in a random coordinate", r[0], r[2], r[4], r[3])
    cls = np.sum([v for v in b["classes"].values()], axis=0)
    _vs_theory(crit, "B4 stereo, blunder in each class (pooled)", cls[0], cls[2], cls[4],
               int(cls[3]))
    crit.add("B5 stereo: clean runs without a flag", b["clean"],
             share_band(b["n"], (1 - alpha0) ** (tested / b["n"]), 1.0, ALPHA)[0], 1.0)
    return crit


def timing_big() -> None:
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    sc = make_scenario(0, n_shape_points=100_000, databases=("OSM",))
    data = sc.to_project_data()
    data.settings.reweight = "none"
    out = run(data)
    t = time.perf_counter()
    rel = reliability(out.result)
    dt = time.perf_counter() - t
    print(f"D. reliability() at {out.problem.n_points} points, {len(out.problem.obs_point)} "
          f"image measurements: {dt:.2f} s; sum r = {rel.sum_r:.6f}, dof = {out.result.dof}")


def main(argv=None) -> int:
    """The studies, the power table and the criteria; 1 if a criterion is missed."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=None,
                    help="resection seeds (default 200, --fast 40)")
    ap.add_argument("--stereo-seeds", type=int, default=None,
                    help="stereo seeds (default: --seeds; --fast 4)")
    ap.add_argument("--fast", action="store_true", help="the fast tier")
    ap.add_argument("--blunder", type=float, default=5.0, help="blunder size in sigmas")
    ap.add_argument("--alpha0", type=float, default=0.001)
    ap.add_argument("--big", action="store_true", help="also time 10^5 points")
    ap.add_argument("--json", help="write the criteria to this file")
    args = ap.parse_args(argv)
    n_a = args.seeds or (40 if args.fast else 200)
    n_b = args.stereo_seeds or (4 if args.fast else n_a)
    t = time.perf_counter()
    power = power_table(args.blunder, args.alpha0)
    a = study_resection(list(range(n_a)), args.blunder, args.alpha0)
    b = study_stereo(list(range(n_b)), args.blunder, args.alpha0)
    if args.big:
        timing_big()
    print(f"({time.perf_counter() - t:.1f} s)")
    crit = criteria(power, a, b, args.blunder, args.alpha0)
    return crit.report(args.json, {"resection": a, "stereo": {k: v for k, v in b.items()
                                                             if k != "classes"}})


if __name__ == "__main__":
    sys.exit(main())
