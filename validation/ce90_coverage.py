"""On-demand validation of vectoradjust.accuracy.stats CE90/LE90 (larger than the test suite).

Run:  PYTHONPATH=core python validation/ce90_coverage.py [--n 1000000] [--seed 1]
      [--cases 300] [--fast] [--sigma-scale 1.0] [--json FILE]

``--fast`` (the fast tier of tests/test_validation.py): 40 000 draws (20 000 with a bias),
30 mpmath cases.

Prints:
1. the g(rho) = CE90/sigma_max table error at all table mid-points and at random
   ratios (against direct root finding);
2. the quadrature error of P(|e| <= R) against 30-digit mpmath quadrature on random
   cases with thin ellipses and large biases (skipped without mpmath);
3. Monte Carlo coverage of ce90 (random covariances), ce90_exact with bias, le90 with
   bias: the fraction of sampled errors inside, with its binomial standard error;
4. the deviation of the Ager and Doucette approximations from the exact values;
5. timings (for information: no criterion).

Acceptance criteria (exit status 1 when one is missed; validation/acceptance.py):

a. the table's relative error (mid-points and random ratios) is below 1e-8, as
   stats.ce90_ratio_factor states;
b. the quadrature agrees with mpmath within 2e-11 in P (stats states 1e-11 measured;
   skipped without mpmath);
c. each Monte Carlo coverage (ce90, ce90_exact with bias, le90 with bias; iid draws, the
   target exactly 0.9) within ``z`` binomial standard errors of 0.9, ``z`` for a
   two-sided 0.01 / 3: the three pass together with >= 99 %. ``--sigma-scale 0.8``
   (every radius 0.8 times) covers ~0.77-0.81 and fails by hundreds of standard errors;
d. the published approximations as implemented: Ager CE90 (circular, mu/sigma 0-10)
   within 1 % of the exact value, Ager LE90 (0-10) within 0.2 %, Doucette (b/a 0.6-1)
   between -4.5 % and 0 (measured 0.89 %, 0.12 %, -4.17..0 %: a wrong coefficient moves
   them).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import ncx2

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

from acceptance import Criteria, z_two_sided  # noqa: E402

from vectoradjust.accuracy import stats as S  # noqa: E402

#: statistical criteria (the three coverages): each at 0.01 / 3
N_COVERAGES = 3


def _random_cov(rng, n):
    smax = np.exp(rng.uniform(np.log(0.01), np.log(10.0), n))
    rho = rng.uniform(0.0, 1.0, n)
    rho[: n // 10] = 10 ** rng.uniform(-4, -1, n // 10)
    th = rng.uniform(0, np.pi, n)
    c, s = np.cos(th), np.sin(th)
    a = c * c * smax**2 + s * s * (rho * smax) ** 2
    d = s * s * smax**2 + c * c * (rho * smax) ** 2
    b = c * s * (smax**2 - (rho * smax) ** 2)
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 0, 1], cov[:, 1, 0] = a, d, b, b
    return cov, smax, rho, th


def _sample(rng, smax, rho, th, bias=None):
    n = smax.size
    u = smax * rng.standard_normal(n)
    v = rho * smax * rng.standard_normal(n)
    x = np.cos(th) * u - np.sin(th) * v
    y = np.sin(th) * u + np.cos(th) * v
    if bias is not None:
        x, y = x + bias[:, 0], y + bias[:, 1]
    return x, y


def _coverage(label, inside, crit):
    n = inside.size
    f = inside.mean()
    se = math.sqrt(0.09 / n)
    print(f"  {label:40s} {f:.5f}  (n = {n}, se {se:.5f}, z = {(f - 0.9) / se:+.2f})")
    z = z_two_sided(0.01 / N_COVERAGES)
    crit.add(f"coverage of {label}", f, 0.9 - z * se, 0.9 + z * se)


def table_error(rng, crit) -> None:
    """1. the table of g(rho) against direct root finding."""
    print("1. CE90 table (linear interpolation, 4097 nodes) vs direct root finding")
    t = time.perf_counter()
    rho_t, g_t = S._ce90_table()
    print(f"  table build {time.perf_counter() - t:.3f} s")
    mid = 0.5 * (rho_t[1:] + rho_t[:-1])
    rnd = rng.uniform(0, 1, 10_000)
    for name, r in (("mid-points", mid), ("random ratios", rnd)):
        ones, zeros = np.ones_like(r), np.zeros_like(r)
        direct = S._solve_radius(0.9, ones, r, zeros, zeros)
        err = np.abs(S.ce90_ratio_factor(r) / direct - 1)
        print(f"  {name:14s} max rel error {err.max():.2e} at rho = {r[err.argmax()]:.4f}")
        crit.add(f"CE90 table: max relative error at {name}", err.max(), None, 1e-8)
    for r in (0.0, 0.45, 0.5, 1.0):
        print(f"  g({r}) = {S.ce90_ratio_factor(r):.7f}")


def quadrature_error(rng, crit, cases: int) -> None:
    """2. P(|e| <= R) against 30-digit mpmath quadrature."""
    print("2. quadrature vs mpmath (30 digits)")
    try:
        import mpmath as mp
    except ImportError:  # pragma: no cover
        print("  mpmath not installed: skipped")
        return
    mp.mp.dps = 30

    def ref(R, sa, sb, ma, mb):
        R, sa, sb, ma, mb = map(mp.mpf, (R, sa, sb, ma, mb))

        def f(y):
            h = mp.sqrt(max(R * R - y * y, 0))
            return mp.npdf(y, mb, sb) * (mp.ncdf((h - ma) / sa) - mp.ncdf((-h - ma) / sa))

        pts = sorted({-R, R} | {p for p in (mb, mb - 8 * sb, mb + 8 * sb) if -R < p < R})
        return float(mp.quad(f, pts, maxdegree=10))

    worst = 0.0
    for _ in range(cases):
        rho = 10 ** rng.uniform(-4, 0) if rng.random() < 0.5 else rng.uniform(0, 1)
        k = 10 ** rng.uniform(-2, 2.5) if rng.random() < 0.8 else 0.0
        ang = rng.uniform(0, 2 * np.pi)
        ma, mb = k * math.cos(ang), k * math.sin(ang)
        R = math.hypot(ma, mb) + rng.uniform(0.5, 3.0)
        got = S.circular_error_probability(R, 1.0, rho, ma, mb)
        worst = max(worst, abs(got - ref(R, 1.0, rho, ma, mb)))
    print(f"  {cases} cases (rho 1e-4..1, bias to 300 sigma): max |dP| = {worst:.2e}")
    crit.add(f"quadrature vs mpmath: max |dP| over {cases} cases", worst, None, 2e-11)


def coverage(rng, crit, n: int, scale: float) -> dict:
    """3. Monte Carlo coverage of ``scale`` times ce90, ce90_exact and le90; timings."""
    print("3. Monte Carlo coverage (target 0.9)" + (f", radii x {scale}" if scale != 1 else ""))
    cov, smax, rho, th = _random_cov(rng, n)
    x, y = _sample(rng, smax, rho, th)
    t = time.perf_counter()
    r90 = S.ce90(cov)
    times = {"ce90": time.perf_counter() - t}
    _coverage("ce90, random covariances", np.hypot(x, y) <= scale * r90, crit)
    m = min(n // 2, 200_000)
    sig = smax[:m] * np.sqrt(1 + rho[:m] ** 2)
    ang = rng.uniform(0, 2 * np.pi, m)
    k = rng.uniform(0, 5, m)
    bias = np.stack([k * sig * np.cos(ang), k * sig * np.sin(ang)], -1)
    x, y = _sample(rng, smax[:m], rho[:m], th[:m], bias)
    t = time.perf_counter()
    rb = S.ce90_exact(cov[:m], bias)
    times["exact"] = time.perf_counter() - t
    _coverage("ce90_exact with bias (0..5 sigma)", np.hypot(x, y) <= scale * rb, crit)
    s = np.exp(rng.uniform(np.log(0.01), np.log(20), n))
    mu = s * rng.uniform(-5, 5, n)
    e = mu + s * rng.standard_normal(n)
    t = time.perf_counter()
    l90 = S.le90(s, mu)
    times["le90"] = time.perf_counter() - t
    _coverage("le90 with bias (0..5 sigma)", np.abs(e) <= scale * l90, crit)
    return {"n": n, "m": m, **times}


def approximations(rng, crit, nn: int) -> None:
    """4. the Ager and Doucette approximations against the exact values."""
    print("4. approximations vs exact")
    k = np.linspace(0, 10, 10001)
    ex = np.sqrt(ncx2.ppf(0.9, 2, np.maximum(k * k, 1e-300)))
    ex[0] = S.CE90_CIRCULAR_FACTOR
    dev = S.ager_ce90(k, 1.0) / ex - 1
    for lo, hi in ((0, 0.1), (0.1, 3), (3, 10), (0, 10)):
        sel = (k >= lo) & (k <= hi)
        i = np.argmax(np.abs(dev[sel]))
        print(
            f"  Ager CE90 circular, mu/sigma in [{lo}, {hi}]: max {100 * dev[sel][i]:+.3f} %"
            f" at {k[sel][i]:.3f}"
        )
    crit.add("Ager CE90 circular, mu/sigma 0-10: max |deviation| (%)",
             100 * np.abs(dev).max(), None, 1.0)
    for kk in (20, 50, 100):
        e1 = S.ce90_exact(np.eye(2), [kk, 0])
        d1 = 100 * (S.ager_ce90(kk, 1) / e1 - 1)
        print(f"  Ager CE90 circular, mu/sigma = {kk}: {d1:+.3f} %")
    rr = rng.uniform(0.6, 1.0, nn)
    kk = rng.uniform(0, 3, nn)
    aa = rng.uniform(0, np.pi / 2, nn)
    cv = np.zeros((nn, 2, 2))
    cv[:, 0, 0], cv[:, 1, 1] = 1.0, rr**2
    sc = 0.5 * (1 + rr)
    dev = S.ager_ce90(kk * sc, sc) / S.ce90_exact(
        cv, np.stack([kk * sc * np.cos(aa), kk * sc * np.sin(aa)], -1)
    ) - 1
    print(
        f"  Ager CE90 ellipse b/a >= 0.6, mu/sigma_c <= 3: [{100 * dev.min():+.2f}, "
        f"{100 * dev.max():+.2f}] %"
    )
    kz = np.linspace(0, 10, 10001)
    dz = S.ager_le90(kz, 1.0) / S.le90(np.ones_like(kz), kz) - 1
    print(f"  Ager LE90, |mu|/sigma in [0, 10]: max {100 * np.abs(dz).max():.3f} %"
          f" at {kz[np.argmax(np.abs(dz))]:.3f}")
    crit.add("Ager LE90, |mu|/sigma 0-10: max |deviation| (%)", 100 * np.abs(dz).max(),
             None, 0.2)
    rq = np.linspace(0.6, 1.0, 401)
    dd = 2.1460 * 0.5 * (1 + rq) / S.ce90_ratio_factor(rq) - 1
    print(f"  Doucette, b/a in [0.6, 1]: [{100 * dd.min():+.2f}, {100 * dd.max():+.2f}] %")
    crit.add("Doucette, b/a 0.6-1: lowest deviation (%)", 100 * dd.min(), -4.5, 0.0)
    crit.add("Doucette, b/a 0.6-1: highest deviation (%)", 100 * dd.max(), -4.5, 0.01)


def main(argv=None) -> int:
    """Print the sections and the criteria; 1 if one is missed."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=None,
                    help="Monte Carlo draws (default 1000000, --fast 40000)")
    ap.add_argument("--cases", type=int, default=None,
                    help="mpmath cases (default 300, --fast 30)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fast", action="store_true", help="the fast tier")
    ap.add_argument("--sigma-scale", type=float, default=1.0,
                    help="count against this multiple of every radius (0.8 must fail)")
    ap.add_argument("--json", help="write the criteria to this file")
    args = ap.parse_args(argv)
    n = args.n or (40_000 if args.fast else 1_000_000)
    cases = args.cases or (30 if args.fast else 300)
    rng = np.random.default_rng(args.seed)
    crit = Criteria(f"CE90/LE90 computations, {n} draws, {cases} quadrature cases")
    table_error(rng, crit)
    quadrature_error(rng, crit, cases)
    t = coverage(rng, crit, n, args.sigma_scale)
    approximations(rng, crit, min(50_000, max(n // 4, 1000)))
    print("5. timings")
    print(f"  ce90 ({t['n']} covariances): {t['ce90']:.3f} s")
    print(f"  ce90_exact with bias ({t['m']}): {t['exact']:.3f} s")
    print(f"  le90 with bias ({t['n']}): {t['le90']:.3f} s")
    return crit.report(args.json, t)


if __name__ == "__main__":
    sys.exit(main())
