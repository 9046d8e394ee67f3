"""Monte Carlo validation of CE90, LE90 and sigma0^2 over many simulated adjustments.

Run on demand (not in the test suite; the suite runs a 40-seed version in
tests/test_pipeline.py):

    python validation/monte_carlo_coverage.py --runs 2000

Each run simulates the sample set-up (RC10 stereo pair, 24 GCPs, tie points) with a
road database whose errors are iid N(0, 3 m) per axis, adjusts it with the correct
stochastic model (shape-point sigma 3 m horizontally, the run's RMS of DEM height
minus true height vertically), and counts the adjusted shape points whose true
position lies inside their CE90 circle / LE90 interval. It also averages sigma0^2 and
counts the chi-square test's acceptances.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np

from vectoradjust.pipeline import run
from vectoradjust.simulate import DatabaseModel, make_scenario

IID = DatabaseModel("IID", "iid_id", "iid", 20.0, 0.4, (0.0, 0.0), 0.0, 0.0, 3.0)


def one_run(seed: int, free_eo: bool = False) -> dict:
    kw = {"sigma_position": None, "sigma_attitude": None} if free_eo else {}
    sc = make_scenario(seed, databases=(IID,), **kw)
    data = sc.to_project_data()
    spec, layer = data.vectors[0]
    sz = float(np.sqrt(np.mean((layer.coords[:, 2] - sc.truth["IID"][1][:, 2]) ** 2)))
    data.vectors[0] = (replace(spec, sigma=(3.0, 3.0, sz)), layer)
    r = run(data)
    d = r.databases[0]
    adj = d.vertices["Adjusted"] == 1
    t = sc.truth["IID"][1][adj]
    eh = np.hypot(d.vertices["AdjX"][adj] - t[:, 0], d.vertices["AdjY"][adj] - t[:, 1])
    ev = np.abs(d.vertices["AdjZ"][adj] - t[:, 2])
    cp = r.control_points
    chk = (cp["role"] == "check") & (cp["Used"] == 1)
    ct = sc.control_true[chk]
    ceh = np.hypot(cp["AdjX"][chk] - ct[:, 0], cp["AdjY"][chk] - ct[:, 1])
    return {
        "n": int(adj.sum()),
        "in_ce90": int((eh <= d.vertices["CE90"][adj]).sum()),
        "in_le90": int((ev <= d.vertices["LE90"][adj]).sum()),
        "n_check": int(chk.sum()),
        "check_in_ce90": int((ceh <= cp["CE90"][chk]).sum()),
        "sigma0_squared": r.summary["sigma0_squared"],
        "chi2_passed": bool(r.summary["chi_square"]["passed"]),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=2000)
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--json", help="write the figures to this file")
    p.add_argument("--free-eo", action="store_true",
                   help="no EO priors (the default 100 m / 5 deg priors are uninformative and "
                        "add degrees of freedom with ~zero residual, biasing sigma0^2 low)")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = []
    for i, seed in enumerate(range(args.first_seed, args.first_seed + args.runs)):
        rows.append(one_run(seed, args.free_eo))
        if (i + 1) % 100 == 0:
            print(f"  {i + 1} runs, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    n = sum(r["n"] for r in rows)
    s0 = np.array([r["sigma0_squared"] for r in rows])
    out = {
        "runs": len(rows),
        "points": n,
        "ce90_coverage": sum(r["in_ce90"] for r in rows) / n,
        "le90_coverage": sum(r["in_le90"] for r in rows) / n,
        "check_points": sum(r["n_check"] for r in rows),
        "check_ce90_coverage": sum(r["check_in_ce90"] for r in rows)
        / max(1, sum(r["n_check"] for r in rows)),
        "mean_sigma0_squared": float(s0.mean()),
        "sd_of_mean_sigma0_squared": float(s0.std(ddof=1) / np.sqrt(len(s0))),
        "chi_square_acceptance": float(np.mean([r["chi2_passed"] for r in rows])),
        "seconds": time.perf_counter() - t0,
    }
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
