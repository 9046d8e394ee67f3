"""Benchmark table of issue 13: the solver, the whole CLI run, the 200-image block.

Run on demand (not part of the test suite), from the repository root:

    python benchmarks/run.py                 # 10^4, 10^5, 10^6 shape points + block
    python benchmarks/run.py --max 1e5       # skip the 10^6 rows and the block
    python benchmarks/run.py --no-cli        # solver rows only
    python benchmarks/run.py --cli-max 1e5   # the whole-CLI column up to 10^5 only
    python benchmarks/run.py --core /path/to/other/checkout/core   # time another version
    python benchmarks/run.py --repeat 3      # each whole-CLI run 3 times: median, range

Rows (each measurement in its own child process; ``solve s`` is wall time, ``CPU s`` the
CPU time of the solving process, all its threads - on a machine shared with other jobs
the wall time depends on the load, the CPU time much less):

Peak memory comes from ``resource.getrusage(RUSAGE_CHILDREN)`` of a small wrapper
process whose only child is the measured command; so does ``CLI CPU s``, the user +
system time of the whole CLI run with every process it forked (band processes, report,
``[truth]``). That CPU time divided by the cores is the least wall time any overlap of
the stages could reach. With ``--repeat N`` each CLI run is taken N times: ``CLI s`` is
the median wall time (the range is printed below the table), ``CLI CPU s`` the median
CPU time and ``CLI MB`` the largest peak.

* ``pair N``: a stereo pair with N shape points (:func:`vectoradjust.simulate.block.make_block`,
  60 % forward overlap, control and tie points): the time of
  :func:`vectoradjust.adjust.bundle.adjust` with point covariances, then the CE90 / LE90
  of every point as the run tables compute them (:func:`vectoradjust.accuracy.stats.ce90`,
  the exact CE90 tabulated to 1e-8); and, unless
  ``--no-cli``, ``vectoradjust adjust`` with its default outputs on a simulated project
  of N shape points (:func:`vectoradjust.simulate.make_scenario`), wall time of the whole
  child process.
* ``block 200``: 10 strips of 20 images (60 % / 30 % overlap) with ``--block-points``
  shape points, the solve with covariances and CE90 / LE90.
* ``least_squares``: :func:`scipy.optimize.least_squares` on the 10^4 pair (same
  observations and weights, the analytic sparse Jacobian, ``trf`` + ``lsmr``), its time
  beside the solver's and the largest coordinate difference of the two solutions.

The problem files are generated with the checkout this script belongs to; ``--core``
only changes the code that solves them (and runs the CLI), so that two versions are
timed on identical inputs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CORE = HERE.parent / "core"

# child: solve a saved problem, print JSON with the timings
_SOLVE_CHILD = r"""
import json, sys, time
import numpy as np
from vectoradjust.adjust.bundle import BundleProblem, adjust
from vectoradjust.accuracy.stats import ce90
z = np.load(sys.argv[1])
prob = BundleProblem(float(z["focal_length"]), z["principal_point"], z["eo0"], z["eo_sigma"],
                     z["xyz0"], z["prior_xyz"], z["prior_weight"], z["obs_point"],
                     z["obs_image"], z["obs_xy"], z["obs_sigma"])
t0, c0 = time.perf_counter(), time.process_time()
res = adjust(prob)
t1, c1 = time.perf_counter(), time.process_time()
cov = res.point_cov
ce = ce90(cov[:, :2, :2])
le = 1.6449 * np.sqrt(cov[:, 2, 2])
t2 = time.perf_counter()
err = np.abs(res.xyz - z["true_xyz"]).max()
print(json.dumps({"adjust": t1 - t0, "adjust_cpu": c1 - c0, "ce90": t2 - t1,
                  "iterations": res.iterations,
                  "sigma0_squared": res.sigma0_squared, "max_error": float(err),
                  "points": int(prob.n_points), "observations": int(len(prob.obs_point)),
                  "ce90_median": float(np.median(ce)), "le90_median": float(np.median(le))}))
np.save(sys.argv[2], res.xyz)
"""


#: runs one command as its only child and writes that child's peak RSS (kB) to a file
_WRAP = (
    "import resource, subprocess, sys\n"
    "rc = subprocess.call(sys.argv[2:])\n"
    "u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
    "open(sys.argv[1], 'w').write(f'{u.ru_maxrss} {u.ru_utime + u.ru_stime}')\n"
    "sys.exit(rc)\n"
)


def _child(cmd: list, env: dict, cpu: bool = False):
    """Run ``cmd``; wall time (s), peak RSS (MB) of the largest process, its stdout (and
    with ``cpu`` the user + system time of it and every process it waited for)."""
    with tempfile.NamedTemporaryFile(suffix=".rss", delete=False) as fh:
        rss_file = fh.name
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _WRAP, rss_file, *cmd], env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    maxrss, cpu_s = Path(rss_file).read_text().split()
    os.unlink(rss_file)
    if cpu:
        return wall, int(maxrss) / 1024.0, proc.stdout, float(cpu_s)
    return wall, int(maxrss) / 1024.0, proc.stdout


def _env(core: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(core) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH")
                                     else "")
    return env


def _save_problem(path: Path, blk) -> None:
    import numpy as np

    p = blk.problem
    np.savez(path, focal_length=p.focal_length, principal_point=p.principal_point, eo0=p.eo0,
             eo_sigma=p.eo_sigma, xyz0=p.xyz0, prior_xyz=p.prior_xyz,
             prior_weight=p.prior_weight, obs_point=p.obs_point, obs_image=p.obs_image,
             obs_xy=p.obs_xy, obs_sigma=p.obs_sigma, true_xyz=blk.true_xyz)


def _solve_row(label: str, blk, work: Path, core: Path) -> dict:
    prob_file = work / f"{label.replace(' ', '_')}.npz"
    _save_problem(prob_file, blk)
    script = work / "solve_child.py"
    script.write_text(_SOLVE_CHILD)
    xyz_file = work / f"{label.replace(' ', '_')}_xyz.npy"
    _, rss, out = _child([sys.executable, str(script), str(prob_file), str(xyz_file)],
                         _env(core))
    rec = json.loads(out.strip().splitlines()[-1])
    rec.update(label=label, solve_rss=rss, xyz_file=str(xyz_file))
    return rec


def _cli_row(n: int, work: Path, core: Path, repeat: int = 1) -> dict:
    """``vectoradjust adjust`` on the simulated project of ``n`` shape points, ``repeat``
    times: median, least and largest wall time, median CPU time, largest peak."""
    import statistics

    from vectoradjust.simulate import make_scenario, write_project

    proj = work / f"project_{n}"
    if not (proj / "project.toml").exists():
        sc = make_scenario(1, n_shape_points=n, databases=("OSM", "TNM"))
        write_project(sc, proj)
    runs = [_child([sys.executable, "-m", "vectoradjust.cli", "adjust",
                    str(proj / "project.toml"), "--out", str(work / f"out_{n}"), "-q"],
                   _env(core), cpu=True) for _ in range(max(1, repeat))]
    walls = [r[0] for r in runs]
    return {"wall": statistics.median(walls), "min": min(walls), "max": max(walls),
            "cpu": statistics.median(r[3] for r in runs), "rss": max(r[1] for r in runs),
            "runs": len(runs)}


def _least_squares(blk, ours_xyz):
    """scipy least_squares on the same problem; (seconds, max |dXYZ| to ours, cost)."""
    import numpy as np
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    from vectoradjust.sensor.collinearity import partials, project

    p = blk.problem
    n, m, k = p.n_images, p.n_points, len(p.obs_point)
    has = np.flatnonzero(p.has_prior)
    chol = np.linalg.cholesky(p.prior_weight[has])  # W = L L', residual L'(x - prior)
    lt = np.transpose(chol, (0, 2, 1))
    we = np.sqrt(p.eo_weight.ravel())
    sel = np.flatnonzero(we > 0)
    sw = 1.0 / p.obs_sigma

    def split(x):
        return x[:6 * n].reshape(n, 6), x[6 * n:].reshape(m, 3)

    def fun(x):
        eo, xyz = split(x)
        r_img = (project(eo[p.obs_image], xyz[p.obs_point], p.focal_length,
                         p.principal_point) - p.obs_xy) * sw
        r_pt = np.einsum("mij,mj->mi", lt, xyz[has] - p.prior_xyz[has])
        r_eo = we[sel] * (eo.ravel()[sel] - p.eo0.ravel()[sel])
        return np.concatenate([r_img.ravel(), r_pt.ravel(), r_eo])

    rows_i = np.repeat(np.arange(2 * k), 9)
    cols_i = np.concatenate([6 * p.obs_image[:, None] + np.arange(6),
                             6 * n + 3 * p.obs_point[:, None] + np.arange(3)], axis=1)
    cols_i = np.repeat(cols_i[:, None, :], 2, axis=1).ravel()
    rows_p = 2 * k + np.repeat(np.arange(3 * len(has)), 3)
    cols_p = (6 * n + 3 * has[:, None, None] + np.zeros((1, 3, 1), int)
              + np.arange(3)[None, None, :]).ravel()
    rows_e = 2 * k + 3 * len(has) + np.arange(len(sel))
    shape = (2 * k + 3 * len(has) + len(sel), 6 * n + 3 * m)

    def jac(x):
        eo, xyz = split(x)
        a_eo, a_pt = partials(eo[p.obs_image], xyz[p.obs_point], p.focal_length)
        a = np.concatenate([a_eo, a_pt], axis=2) * sw[:, :, None]
        vals = np.concatenate([a.ravel(), lt.ravel(), we[sel]])
        return sp.csr_matrix((vals, (np.concatenate([rows_i, rows_p, rows_e]),
                                     np.concatenate([cols_i, cols_p, sel]))), shape=shape)

    x0 = np.concatenate([p.eo0.ravel(), p.xyz0.ravel()])
    t0 = time.perf_counter()
    sol = least_squares(fun, x0, jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    dt = time.perf_counter() - t0
    _, xyz = split(sol.x)
    return dt, float(np.abs(xyz - ours_xyz).max()), float(2 * sol.cost), sol.nfev


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max", type=float, default=1e6, help="largest pair size (default 1e6)")
    ap.add_argument("--block-points", type=float, default=1e6,
                    help="shape points of the 200-image block (0: skip the block)")
    ap.add_argument("--no-cli", action="store_true", help="skip the whole-CLI column")
    ap.add_argument("--cli-max", type=float, default=1e6,
                    help="largest pair size that also gets the whole-CLI run")
    ap.add_argument("--no-scipy", action="store_true", help="skip the least_squares row")
    ap.add_argument("--core", type=Path, default=CORE,
                    help="core/ directory of the version to time (default: this checkout)")
    ap.add_argument("--work", type=Path, help="keep problems and outputs here")
    ap.add_argument("--repeat", type=int, default=1,
                    help="whole-CLI runs per row (median and range; default 1)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(CORE))
    from vectoradjust.simulate.block import make_block

    work = args.work or Path(tempfile.mkdtemp(prefix="va-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in (1e4, 1e5, 1e6) if s <= args.max]
    print(f"# vectoradjust benchmark, solver code from {args.core}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} cores")
    print(f"{'row':14s} {'points':>9s} {'obs':>9s} {'solve s':>8s} {'CPU s':>7s} "
          f"{'CE/LE s':>8s} "
          f"{'solve MB':>9s} {'CLI s':>8s} {'CLI CPU s':>10s} {'CLI MB':>8s} {'it':>3s} "
          f"{'s0^2':>7s}")
    ranges = []
    pair_1e4 = None
    rows = [(f"pair {n:.0e}", dict(n_strips=1, images_per_strip=2, n_shape_points=n))
            for n in sizes]
    if args.block_points > 0:
        rows.append(("block 200", dict(n_strips=10, images_per_strip=20,
                                       n_shape_points=int(args.block_points))))
    for label, kw in rows:
        blk = make_block(**kw, seed=1)
        rec = _solve_row(label, blk, work, args.core)
        nan = float("nan")
        cli = {"wall": nan, "cpu": nan, "rss": nan}
        if label.startswith("pair") and not args.no_cli and kw["n_shape_points"] <= args.cli_max:
            cli = _cli_row(kw["n_shape_points"], work, args.core, args.repeat)
            if cli["runs"] > 1:
                ranges.append(f"{label}: {cli['runs']} CLI runs, {cli['min']:.1f}-"
                              f"{cli['max']:.1f} s")
        print(f"{label:14s} {rec['points']:9d} {rec['observations']:9d} {rec['adjust']:8.2f} "
              f"{rec.get('adjust_cpu', float('nan')):7.2f} "
              f"{rec['ce90']:8.2f} {rec['solve_rss']:9.0f} {cli['wall']:8.1f} "
              f"{cli['cpu']:10.1f} {cli['rss']:8.0f} "
              f"{rec['iterations']:3d} {rec['sigma0_squared']:7.4f}", flush=True)
        if label == "pair 1e+04":
            pair_1e4 = (blk, rec)
    if pair_1e4 is not None and not args.no_scipy:
        import numpy as np

        blk, rec = pair_1e4
        dt, diff, cost, nfev = _least_squares(blk, np.load(rec["xyz_file"]))
        print(f"least_squares on pair 1e4 (trf/lsmr, analytic sparse Jacobian): {dt:.2f} s "
              f"({nfev} evaluations) vs {rec['adjust']:.2f} s: ratio {dt / rec['adjust']:.1f}; "
              f"largest coordinate difference {diff:.2e} m")
    for line in ranges:
        print(f"# {line}")
    print(f"# files in {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
